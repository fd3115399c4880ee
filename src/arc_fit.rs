//! Where the mover's flux was when the estimator started: a circle fit to the arc the
//! integrated back-EMF draws, which seeds the observer once about a third of an
//! electrical period has been seen.
//!
//! ## Why
//! A flux observer integrates `u - Rs i`; started from zero on a mover that is already
//! moving, its integral is the flux *less where the flux was at the start*:
//!
//! ```text
//! p(t) = integral_0^t (u - Rs i) dt - Ls (i(t) - i(0)) = psi(t) - psi(0)
//! ```
//!
//! `p` runs on a circle of radius `|psi|` whose centre is `-psi(0)`: an offset as large
//! as the flux itself. The DCFO removes it through its slowest pole, `-0.26 w` (digest
//! §3; [`crate::observer::Dcfo`]): about 1.5 electrical periods to bring the angle
//! error under 5 deg, of a budget of 2, and the FLL that tunes the notch meanwhile reads
//! the observer's own correction `(h / Ls) d` as a ripple of about `0.2 w` on the
//! frequency (measured: the notch 16 % off at the hand-over at 0.3 m/s). The offset is
//! the one unknown of a known geometry, so it is fitted instead of waited for.
//!
//! ## The fit
//! Every point of the arc satisfies `|p - c|^2 = r^2` with `|c| = r` (the arc starts at
//! the origin), i.e. `|p|^2 = 2 c . p`: linear in the centre `c`, with no radius to
//! know. Least squares over the samples so far:
//!
//! ```text
//! G c = b / 2,    G = mean(p p^T),    b = mean(|p|^2 p)
//! ```
//!
//! five running means, a 2 x 2 solve by the adjugate, no square root. `G` is the
//! arc's spread: it is well conditioned once the arc has turned. The fit is taken when
//! the smaller eigenvalue of `G` reaches [`MIN_SPREAD_RATIO`] of the larger, tested
//! without a square root as `det G >= q / (1 + q)^2 (tr G)^2` (for eigenvalues
//! `l1 >= l2` and `q = l2 / l1`, `det / tr^2 = q / (1 + q)^2` grows with `q`), and the
//! chord has reached [`MIN_CHORD_SHARE`] of the magnet flux (so noise on a still mover
//! is never fitted). On the acquisition sweep (`dcfo acquire`) that is 0.25-0.45 of a
//! period after the start. Then `psi(t) = p(t) - c`, its angle is the mover's, and the
//! angle turned since the start over the time elapsed is the frequency, both signs.
//!
//! ## What it cannot see, and the guards
//! - A DC error in `u` or `i` (an offset, a wrong `Rs` under load) makes `p` drift and
//!   bends the fit. Fitting the drift as well (five unknowns) was tried: over a third of
//!   a period it is too poorly conditioned (481 of 576 cold starts over budget against
//!   294 without a fit). The DCFO removes a DC error after the seed as it always does.
//! - The fitted radius `|c|` must lie within [`RADIUS_RANGE`] of the magnet flux, the
//!   chord within [`MAX_CHORD_SHARE`] of it (a drift of more than the flux is not an
//!   arc), and the fit must come within [`MAX_FIT_TURNS`] periods of the notch floor;
//!   otherwise the fit gives up and the estimator acquires as it would without it.
//! - The radius is fitted rather than taken from the motor file: a seed at the file's
//!   `psi_f` gave the same results (240 against 237 of 576 over budget) and depends on
//!   the file being right.
//!
//! Measured on `dcfo acquire` (576 cold starts, with the estimator's hand-over on the
//! FLL's mean frequency after a seed, `crate::estimator`): 204 over budget against 294
//! without the fit, no false lock, Q8.24 within 0.83 deg of f32; from 0.8 m/s up the
//! median lock time fell from 60-143 ms to 16-56 ms. What is left over budget is mostly
//! below 0.3 m/s, where the DC errors (+2 V is 60 % of the back-EMF at 0.1 m/s) bend
//! the arc and the DCFO's slow removal of them sets the time, and the steady error at
//! some speeds, which passes 5 deg now and then long after the lock (`dcfo acquire`
//! counts a start locked only once it stays below 5 deg to the end of its window).
#![forbid(unsafe_code)]

use crate::num::{Angle, Scalar};
use crate::transforms::AlphaBeta;
use crate::units::Base;

/// Smallest ratio of the arc's spread across to its spread along (eigenvalues of `G`,
/// dimensionless) at which the circle is fitted: 0.04. On the acquisition sweep 0.02
/// to 0.05 gave the same lock times, 0.07 and above waited longer than it gained.
pub const MIN_SPREAD_RATIO: f32 = 0.04;

/// Smallest mean squared chord, relative to the magnet flux squared (dimensionless),
/// before a fit is tried: 1/16, a chord of a quarter of the flux.
pub const MIN_CHORD_SHARE: f32 = 0.0625;

/// Largest chord relative to the magnet flux (dimensionless): beyond 3 (an arc spans at
/// most 2), a drift dominates and the fit gives up.
pub const MAX_CHORD_SHARE: f32 = 3.0;

/// The fitted radius must lie between these multiples of the magnet flux.
pub const RADIUS_RANGE: (f32, f32) = (0.5, 2.0);

/// Longest fit, in periods of the notch floor frequency: half a period there.
pub const MAX_FIT_TURNS: f32 = 0.5;

/// What one sample of the fit gave.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ArcFitOutcome<T> {
    /// Not fitted yet (or the fit is not running).
    Pending,
    /// The circle is fitted: the mover flux's angle at this sample and the mean
    /// electrical frequency since the start (rad/s, working units, signed).
    Found {
        /// Angle of the mover flux at this sample.
        theta_e: Angle,
        /// Electrical angular frequency (rad/s, working units).
        omega_e: T,
    },
    /// The arc did not fit (see the module docs); the fit has stopped.
    GaveUp,
}

/// The running circle fit. See the module documentation.
#[derive(Clone, Debug)]
pub struct ArcFit<T> {
    /// The chord `p` (Wb).
    chord: AlphaBeta<T>,
    /// Running means of `p p^T` (Wb^2) and of `|p|^2 p` (Wb^3).
    gxx: T,
    gxy: T,
    gyy: T,
    bx: T,
    by: T,
    /// Samples taken.
    samples: u32,
    /// Notch floor frequency (rad/s): time is counted as the angle it turns (rad), so
    /// that fixed point has room for it (half a second is hundreds of per-unit times).
    floor: T,
    /// `floor * (time since the start)` (rad).
    elapsed_rad: T,
    /// Longest fit, `MAX_FIT_TURNS` turns at the floor (rad).
    max_elapsed_rad: T,
    /// `q / (1 + q)^2` for `q = MIN_SPREAD_RATIO`.
    spread_factor: T,
    /// `MIN_CHORD_SHARE psi_f^2`, the least mean square chord (Wb^2).
    min_chord_sq: T,
    /// `(MAX_CHORD_SHARE psi_f)^2` (Wb^2).
    max_chord_sq: T,
    /// Radius bounds squared (Wb^2).
    min_radius_sq: T,
    max_radius_sq: T,
    running: bool,
}

impl<T: Scalar> ArcFit<T> {
    /// A fit for a motor of magnet flux `psi_f_wb` (Wb) whose notch floor is
    /// `floor_rad_s` (rad/s), in the working units of `base`; running.
    pub fn new(psi_f_wb: f32, floor_rad_s: f32, base: &Base) -> Self {
        let psi: T = base.flux(psi_f_wb);
        let q = MIN_SPREAD_RATIO;
        let (r_min, r_max) = RADIUS_RANGE;
        ArcFit {
            chord: AlphaBeta::default(),
            gxx: T::ZERO,
            gxy: T::ZERO,
            gyy: T::ZERO,
            bx: T::ZERO,
            by: T::ZERO,
            samples: 0,
            floor: base.omega(floor_rad_s),
            elapsed_rad: T::ZERO,
            max_elapsed_rad: T::from_f32(MAX_FIT_TURNS * 2.0 * core::f32::consts::PI),
            spread_factor: T::from_f32(q / ((1.0 + q) * (1.0 + q))),
            min_chord_sq: psi * psi * T::from_f32(MIN_CHORD_SHARE),
            max_chord_sq: psi * psi * T::from_f32(MAX_CHORD_SHARE * MAX_CHORD_SHARE),
            min_radius_sq: psi * psi * T::from_f32(r_min * r_min),
            max_radius_sq: psi * psi * T::from_f32(r_max * r_max),
            running: true,
        }
    }

    /// Starts a new fit from the present flux (the chord is measured from here).
    pub fn restart(&mut self) {
        self.chord = AlphaBeta::default();
        self.gxx = T::ZERO;
        self.gxy = T::ZERO;
        self.gyy = T::ZERO;
        self.bx = T::ZERO;
        self.by = T::ZERO;
        self.samples = 0;
        self.elapsed_rad = T::ZERO;
        self.running = true;
    }

    /// Stops the fit (the estimator was told where the mover is).
    pub fn stop(&mut self) {
        self.running = false;
    }

    /// The fit is running.
    pub fn is_running(&self) -> bool {
        self.running
    }

    /// One sample: `emf_increment` is the increment of the model flux over the sample
    /// without any observer correction, `(u - Rs i) dt - Ls di` (Wb), `dt` the period
    /// (s). Bounded time: a fixed number of operations, one `f32` reciprocal and,
    /// once, two divisions and two arctangents.
    pub fn update(&mut self, emf_increment: AlphaBeta<T>, dt: T) -> ArcFitOutcome<T> {
        if !self.running {
            return ArcFitOutcome::Pending;
        }
        let p = AlphaBeta::new(self.chord.alpha + emf_increment.alpha, self.chord.beta + emf_increment.beta);
        self.chord = p;
        self.elapsed_rad = self.elapsed_rad + self.floor * dt;
        let p_sq = p.alpha * p.alpha + p.beta * p.beta;
        if p_sq > self.max_chord_sq || self.elapsed_rad > self.max_elapsed_rad {
            self.running = false;
            return ArcFitOutcome::GaveUp;
        }
        self.samples = self.samples.saturating_add(1);
        // Running means: x += (sample - x) / n, so that every term stays of the order
        // of the flux's powers (fixed point has no room for sums over thousands of
        // samples).
        // 1 / n formed in f32 and converted: n itself (thousands) is beyond fixed
        // point's range, its reciprocal is not.
        let inv_n = T::from_f32(1.0 / self.samples as f32);
        let mean = |m: T, x: T| m + (x - m) * inv_n;
        self.gxx = mean(self.gxx, p.alpha * p.alpha);
        self.gxy = mean(self.gxy, p.alpha * p.beta);
        self.gyy = mean(self.gyy, p.beta * p.beta);
        self.bx = mean(self.bx, p_sq * p.alpha);
        self.by = mean(self.by, p_sq * p.beta);
        let trace = self.gxx + self.gyy;
        let det = self.gxx * self.gyy - self.gxy * self.gxy;
        if trace < self.min_chord_sq || det < self.spread_factor * trace * trace {
            return ArcFitOutcome::Pending;
        }
        self.running = false;
        // c = G^-1 b / 2 by the adjugate; det > 0 here (the spread test bounds it below).
        let (Some(cx), Some(cy)) = (
            (self.gyy * self.bx - self.gxy * self.by).checked_div(det + det),
            (self.gxx * self.by - self.gxy * self.bx).checked_div(det + det),
        ) else {
            return ArcFitOutcome::GaveUp;
        };
        let radius_sq = cx * cx + cy * cy;
        if radius_sq < self.min_radius_sq || radius_sq > self.max_radius_sq {
            return ArcFitOutcome::GaveUp;
        }
        // The flux now, and where it was at the start (-c).
        let theta_e = T::atan2(p.beta - cy, p.alpha - cx);
        let theta_0 = T::atan2(-cy, -cx);
        let turned: T = (theta_e - theta_0).to_radians();
        // w = turned / t = floor * turned / (floor t).
        match (self.floor * turned).checked_div(self.elapsed_rad) {
            Some(omega_e) => ArcFitOutcome::Found { theta_e, omega_e },
            None => ArcFitOutcome::GaveUp,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::num::Q24;
    use core::f64::consts::PI;

    const PSI: f64 = 0.16;
    const FLOOR: f32 = 4.0 * core::f32::consts::PI;
    const DT: f64 = 1e-4;

    /// Feeds the chord of a flux of amplitude `PSI` turning at `omega` (rad/s) from
    /// `theta0`, plus a constant drift `drift` (V), until the fit ends; returns the
    /// outcome, the sample it ended at and the true angle then.
    fn fit<T: Scalar>(
        base: &Base,
        omega: f64,
        theta0: f64,
        drift: [f64; 2],
    ) -> (ArcFitOutcome<T>, usize, f64) {
        let mut f = ArcFit::<T>::new(PSI as f32, FLOOR, base);
        let flux = |k: usize| {
            let th = theta0 + omega * k as f64 * DT;
            [PSI * th.cos() + drift[0] * k as f64 * DT, PSI * th.sin() + drift[1] * k as f64 * DT]
        };
        for k in 1..100_000 {
            let (a, b) = (flux(k - 1), flux(k));
            let inc = AlphaBeta::new(base.flux((b[0] - a[0]) as f32), base.flux((b[1] - a[1]) as f32));
            match f.update(inc, base.time(DT as f32)) {
                ArcFitOutcome::Pending => {}
                done => return (done, k, theta0 + omega * k as f64 * DT),
            }
        }
        (ArcFitOutcome::Pending, 0, 0.0)
    }

    fn check<T: Scalar>(base: &Base, angle_tol_deg: f64, omega_tol: f64) {
        let to_si = base.omega_rad_s as f64;
        let mut cases = 0;
        for f_hz in [3.0, 10.0, 40.0, 67.0] {
            for sign in [1.0, -1.0] {
                for j in 0..8 {
                    let omega = sign * 2.0 * PI * f_hz;
                    let theta0 = j as f64 * PI / 4.0 + 0.1;
                    let (out, k, theta) = fit::<T>(base, omega, theta0, [0.0; 2]);
                    let ArcFitOutcome::Found { theta_e, omega_e } = out else {
                        panic!("{f_hz} Hz, {sign}, {j}: {out:?}")
                    };
                    let turns = k as f64 * DT * f_hz;
                    assert!(turns < 0.5, "{f_hz} Hz: fitted after {turns} periods");
                    let err = (Angle::from_radians(theta as f32) - theta_e).to_degrees_f64();
                    assert!(err.abs() < angle_tol_deg, "{f_hz} Hz, {sign}, {j}: {err} deg");
                    let w = f64::from(omega_e.to_f32()) * to_si;
                    assert!((w - omega).abs() < omega_tol * omega.abs(), "{f_hz} Hz: {w} rad/s");
                    cases += 1;
                }
            }
        }
        assert_eq!(cases, 64);
    }

    #[test]
    fn an_exact_arc_gives_the_flux_angle_and_frequency_within_half_a_period() {
        // The arc's chords are exact, so the fit is: the angle within the rounding of
        // the type, the frequency within the one-sample offset of the time count.
        check::<f64>(&Base::SI, 1e-3, 1e-3);
        check::<f32>(&Base::SI, 0.01, 1e-3);
        let pu = Base { voltage_v: 179.6, current_a: 2.97, omega_rad_s: 1122.5 };
        check::<Q24>(&pu, 0.05, 2e-3);
    }

    #[test]
    fn a_still_mover_is_never_fitted_and_a_drift_gives_up() {
        // Measurement noise on a still mover: a random walk of 1e-5 Wb steps never
        // reaches a chord of a quarter of the flux within the fit's time.
        let mut f = ArcFit::<f32>::new(PSI as f32, FLOOR, &Base::SI);
        let mut seed = 12345u32;
        let mut outcome = ArcFitOutcome::Pending;
        for _ in 0..10_000 {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let n = |s: u32| ((s >> 8) as f32 / 16_777_216.0 - 0.5) * 2e-5;
            outcome = f.update(AlphaBeta::new(n(seed), n(seed.rotate_left(13))), DT as f32);
            if outcome != ArcFitOutcome::Pending {
                break;
            }
        }
        assert_eq!(outcome, ArcFitOutcome::GaveUp, "half a period of the floor, then it stops");
        assert!(!f.is_running());
        // A DC error on a still mover: the chord runs away along a line, no arc.
        let (out, _, _) = fit::<f32>(&Base::SI, 0.0, 0.3, [5.0, 1.0]);
        assert_eq!(out, ArcFitOutcome::GaveUp);
    }

    #[test]
    fn a_stopped_fit_waits_for_a_restart() {
        let mut f = ArcFit::<f32>::new(PSI as f32, FLOOR, &Base::SI);
        f.stop();
        assert_eq!(f.update(AlphaBeta::new(0.01, 0.01), DT as f32), ArcFitOutcome::Pending);
        f.restart();
        assert!(f.is_running());
    }
}
