//! Where the mover's flux was when the estimator started, and the DC error in its inputs:
//! circle fits to the arc the integrated back-EMF draws and to the back-EMF itself, which
//! seed the observer after about a third of an electrical period.
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
//! as the flux. The DCFO ([`crate::algorithms::observer::Dcfo`]) removes it only through
//! its slowest pole, over more than an electrical period, while the FLL reads the
//! observer's own correction `(h / Ls) d` as a ripple on the frequency. The offset is the
//! one unknown of a known geometry, so it is fitted instead of waited for.
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
//! Five running means, a 2 x 2 solve by the adjugate, no square root. The fit is taken
//! once the arc has turned enough for `G` to be well conditioned (its eigenvalues' ratio
//! `q` reaches [`MIN_SPREAD_RATIO`], tested as `det G >= q / (1 + q)^2 (tr G)^2`) and the
//! chord has reached [`MIN_CHORD_SHARE`] of the magnet flux, so that noise on a still
//! mover is never fitted. Then `psi(t) = p(t) - c` gives the mover's angle, and the angle
//! turned since the start over the time elapsed the frequency, in either direction.
//!
//! A DC error in `u` or `i` (an offset, a wrong `Rs` under load) makes `p` drift and bends
//! this fit; over a third of a period the drift is too poorly conditioned to fit as well,
//! so the back-EMF's circle reads it (below). Guards: the radius `|c|` within
//! [`RADIUS_RANGE`] of the magnet flux, the chord within [`MAX_CHORD_SHARE`] of it (a
//! larger drift is not an arc), and the fit within [`MAX_FIT_TURNS`] periods of the notch
//! floor; otherwise the fit gives up and the estimator acquires without it.
//!
//! ## DC errors: the back-EMF's circle
//! The back-EMF `e = (u - Rs i) - Ls di/dt` with a DC error `du` (V) in it (a current
//! offset `di` is `du = -Rs di`) is `j w psi + du`: a circle whose *centre* is the DC
//! error (the derivative turns the chord's drift `du t` into a constant). So beside the
//! chord, the back-EMF is low-passed ([`EMF_FILTER_PER_FLOOR`]: the sensors' noise
//! through `Ls di/dt`) and, once the filter has settled ([`EMF_FILTER_SETTLE`]) and the
//! points spread ([`EMF_MIN_SPREAD_RATIO`]), a general circle (`|e|^2 = 2 c . e + k`,
//! linear in `c` and `k`) is fitted to it each sample. Its centre is `du`, and the angle
//! of `e - du` leads the flux by a quarter turn (less the filters' known lags). A circle
//! passes when:
//! - its radius matches `|w| psi_f` within [`EMF_RADIUS_RANGE`];
//! - the chord since the start, less `du t`, is the arc from the start to the fitted
//!   angle within [`EMF_CHORD_TOLERANCE`] of the motor file's flux (which also refuses a
//!   circle the inverter's error has bent at light load). A transient at the start taken
//!   for a DC error (a current loop ringing after a lost angle, the inverter's dead time
//!   near zero current) fails this check. The chord then gives the frequency: integrated,
//!   it barely moves with the flux harmonics that make the back-EMF's circle wobble.
//!
//! The seed is the mean of the circles that pass over the next [`EMF_CONFIRM_SHARE`] of
//! the fit's time after the first: one circle's angle moves by about a degree per sample
//! at 0.1 m/s, and f32 and Q8.24 pass a sample apart. Up to [`EMF_FIT_MAX_PER_FLOOR`]
//! times the notch floor, where a DC error is large beside the back-EMF, a chord fit is
//! held back and taken only if the back-EMF fit gives up or is not borne out; above, the
//! chord's fit comes first. The seed starts the observer with its disturbance estimate
//! holding the DC error ([`crate::algorithms::observer::Dcfo::seed`]).
//!
//! ## Noise: the back-EMF fit takes its variance out
//! The back-EMF carries the current sensors' noise through `Ls di/dt` (`sqrt(2) Ls
//! sigma_i / Ts` per sample, V), as large as the back-EMF at 3 Hz on a motor with much
//! inductive flux per ampere of sensor noise. Noise of variance `s^2` per axis adds
//! `s^2 I` to the points' covariance `C` (and `2 s^2 mean` to `b`), which on a third of a
//! turn pulls an algebraic (Kasa) fit's centre towards the arc: a small circle and a wrong
//! DC error. So the fit estimates `s^2` as Taubin's fit does, as the smallest root `x` of
//! its cubic (Chernov's form, a few Newton steps from zero, one more running mean), and
//! solves and tests the spread with `C - x I` and `b - 2 x mean`. In fixed point the
//! running means round to nearest ([`Scalar::mul_nearest`]): a product rounded down biases
//! them by half an LSB an update, which over a thousand updates turns the fitted angle.
//!
//! ## Accuracy and cost
//! The tests in this file check both fits on exact and noisy arcs, in f32 and Q8.24, and
//! `dcfo acquire` measures what they give a cold start. Each sample is bounded
//! ([`ArcFit::update`]); the back-EMF circle's solve is the estimator's worst step (the
//! chord's check and the seed come a sample later), printed by `bench_qemu`
//! (`docs/cost-budget.md`).
#![forbid(unsafe_code)]

use crate::algorithms::transforms::AlphaBeta;
use crate::num::units::Base;
use crate::num::{Angle, Scalar};

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

/// Cut-off of the low-pass the back-EMF is fitted through, per rad/s of the notch
/// floor (dimensionless): 50, i.e. 100 Hz at the default 2 Hz floor. The back-EMF of one
/// sample carries the sensors' noise through `Ls di / dt`; on the acquisition sweep a
/// cut-off of 300 Hz doubled the angle error at a third of a period at 0.1 m/s (10 deg
/// instead of 5), 1 kHz made it 35 deg. The filter's phase at the fitted frequency is
/// taken back exactly (module docs).
pub const EMF_FILTER_PER_FLOOR: f32 = 50.0;

/// Smallest ratio of the back-EMF points' spread across to along (dimensionless) at
/// which their circle is fitted; see [`MIN_SPREAD_RATIO`] for the chord's.
pub const EMF_MIN_SPREAD_RATIO: f32 = 0.06;

/// The back-EMF circle's radius must lie between these multiples of what the fitted
/// frequency and the magnet flux give (`|w| psi_f`, less the filter's gain): narrower
/// than the chord's [`RADIUS_RANGE`], because a fit whose points are still mostly noise
/// is refused here and tried again on the next sample. At (0.5, 2), fits after a sixth of
/// a period at 0.1 m/s, half of the radius and 50 % off in frequency, passed.
pub const EMF_RADIUS_RANGE: (f32, f32) = (0.8, 1.25);

/// Ratio of the back-EMF fit's filter cut-off to that of the slower filter the angle at
/// the fit is read from, once it has settled (dimensionless).
pub const EMF_ANGLE_FILTER_RATIO: f32 = 4.0;

/// How far the chord integrated since the start may be from what the back-EMF fit
/// predicts for it, relative to the magnet flux, and the chord's frequency from the
/// back-EMF fit's, relative (dimensionless): a quarter (see `ArcFit::chord_frequency`).
pub const EMF_CHORD_TOLERANCE: f32 = 0.25;

/// Time the filter is given to settle before its output is fitted, in its time constants
/// (dimensionless): its start from zero decays as `exp(-t wc)`, to 0.7 % after 5.
pub const EMF_FILTER_SETTLE: f32 = 5.0;

/// Highest electrical frequency the back-EMF fit is used at, per rad/s of the notch floor
/// (dimensionless): 8, i.e. 16 Hz at the default floor, where the filter's settling is an
/// eighth of a period (`2 pi * 8 * 5 / 50`); above it the chord's fit comes first and DC
/// errors are small beside the back-EMF (+2 V is 9 % of the paper motor's at 16 Hz).
pub const EMF_FIT_MAX_PER_FLOOR: f32 = 8.0;

/// Once a back-EMF circle first passes its checks, the fit goes on for this share of
/// the time it has fitted so far and takes the mean of the circles that pass in it
/// (dimensionless; see `Confirm`).
pub const EMF_CONFIRM_SHARE: f32 = 0.125;

/// Newton steps for the noise's variance in the back-EMF fit (`EmfFit::noise_variance`):
/// from zero, the polynomial's smallest root is reached to rounding in three on the
/// acquisition sweep's arcs; four bound the time.
pub const NOISE_NEWTON_STEPS: usize = 4;

/// What one sample of the fits gave.
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
        /// DC error in the back-EMF the observer integrates (V, working units, alpha-beta):
        /// what the observer's disturbance estimate must hold from the seed on. Zero when
        /// the chord's arc was fitted (it cannot tell a DC error from the arc).
        dc_voltage: AlphaBeta<T>,
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
    /// Magnet flux (Wb), for the back-EMF fit's check against the chord.
    psi_f: T,
    /// `EMF_CHORD_TOLERANCE psi_f` (Wb).
    chord_tolerance: T,
    /// `(MAX_CHORD_SHARE psi_f)^2` (Wb^2).
    max_chord_sq: T,
    /// Radius bounds squared (Wb^2).
    min_radius_sq: T,
    max_radius_sq: T,
    running: bool,
    /// The back-EMF circle's fit, run beside the chord's (module docs, "DC errors").
    emf: EmfFit<T>,
    /// A chord fit held back while the back-EMF fit runs: its angle, frequency and
    /// `elapsed_rad` then; taken, advanced to the present, if the back-EMF fit gives up.
    deferred: Option<(Angle, T, T)>,
    /// The back-EMF fit's result of the last sample (angle, frequency, DC error), to be
    /// checked against the chord at this one: the check, and the seed that follows it,
    /// do not share the sample of the circle's solve, the fit's costliest. A check that
    /// fails sends the fit on in the same sample (its retries as often as before).
    emf_found: Option<(Angle, T, AlphaBeta<T>)>,
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
            psi_f: psi,
            chord_tolerance: psi * T::from_f32(EMF_CHORD_TOLERANCE),
            max_chord_sq: psi * psi * T::from_f32(MAX_CHORD_SHARE * MAX_CHORD_SHARE),
            min_radius_sq: psi * psi * T::from_f32(r_min * r_min),
            max_radius_sq: psi * psi * T::from_f32(r_max * r_max),
            running: true,
            emf: EmfFit::new(psi_f_wb, floor_rad_s, base),
            deferred: None,
            emf_found: None,
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
        self.deferred = None;
        self.emf_found = None;
        self.emf.restart(T::ZERO);
    }

    /// Stops the back-EMF fit until the next [`ArcFit::restart`]; the chord's goes on
    /// alone, as without it. Its circle is a circle only while the speed holds: for a
    /// commanded acceleration (an open-loop start dragging the mover up to speed).
    pub fn stop_dc_fit(&mut self) {
        self.emf.running = false;
        self.emf_found = None;
    }

    /// Stops the fit (the estimator was told where the mover is).
    pub fn stop(&mut self) {
        self.running = false;
        self.emf.running = false;
        self.emf_found = None;
    }

    /// The fit is running (either of its two circles).
    pub fn is_running(&self) -> bool {
        self.running || self.emf_busy()
    }

    /// The back-EMF fit runs, or its circle awaits the chord's check.
    fn emf_busy(&self) -> bool {
        self.emf.running || self.emf_found.is_some()
    }

    /// One sample: `emf_increment` is the increment of the model flux over the sample
    /// without any observer correction, `(u - Rs i) dt - Ls di` (Wb), `dt` the period
    /// (s). Bounded time: a fixed number of operations, two `f32` reciprocals, and at
    /// most one solve of each fit per sample (the chord's once: two divisions, two
    /// arctangents; the back-EMF's every sample from its spread test until its mean is
    /// taken ([`EMF_CONFIRM_SHARE`]): a division, six reciprocals (four of them the
    /// noise's Newton steps, [`NOISE_NEWTON_STEPS`]), four arctangents and an `f32`
    /// reciprocal for the mean; once, in the sample after its circle's (so that the
    /// solve does not share a sample with the check and the estimator's seed on its
    /// result; a check that fails lets the fit solve again in its sample), the chord's
    /// check `ArcFit::chord_frequency` (three divisions, an arctangent, a sine, no root)
    /// and one division more).
    pub fn update(&mut self, emf_increment: AlphaBeta<T>, dt: T) -> ArcFitOutcome<T> {
        if !self.is_running() && self.deferred.is_none() {
            return ArcFitOutcome::Pending;
        }
        self.elapsed_rad = self.elapsed_rad + self.floor * dt;
        self.chord =
            AlphaBeta::new(self.chord.alpha + emf_increment.alpha, self.chord.beta + emf_increment.beta);
        if let Some((theta_e, omega_e, dc_voltage)) = self.emf_found.take() {
            // The circle of the last sample, turned on to this one.
            let theta_e = theta_e + (omega_e * dt).radians_to_angle();
            match self.chord_frequency(theta_e, omega_e, dc_voltage) {
                Some(omega_e) => {
                    self.running = false;
                    self.deferred = None;
                    // The mean angle was turned on from the circles' mean time at the
                    // first circle's frequency; the chord's is the better one (module
                    // docs): turn it on at that instead, (w - w_ref) (floor t) / floor.
                    let theta_e = match self.emf.confirm {
                        Some(c) => {
                            let lag = self.elapsed_rad - c.centroid_rad;
                            match ((omega_e - c.reference_omega) * lag).checked_div(self.floor) {
                                Some(turn) => theta_e + turn.radians_to_angle(),
                                None => theta_e,
                            }
                        }
                        None => theta_e,
                    };
                    return ArcFitOutcome::Found { theta_e, omega_e, dc_voltage };
                }
                // Not borne out: the back-EMF fit goes on while no chord fit is held back
                // (more of the arc, less of a transient at the start); with one held
                // back, that one is taken below.
                None if self.deferred.is_none() => self.emf.running = true,
                None => {}
            }
        }
        let emf = self.emf.update(emf_increment, dt, self.elapsed_rad, self.max_elapsed_rad);
        if let ArcFitOutcome::Found { theta_e, omega_e, dc_voltage } = emf {
            self.emf_found = Some((theta_e, omega_e, dc_voltage));
        }
        match self.chord_update() {
            // Below the back-EMF fit's highest frequency a DC error bends the chord's arc
            // and the back-EMF fit tells it: wait for that one while it runs.
            // Its own frequency is bent too: held back up to twice the range.
            ArcFitOutcome::Found { theta_e, omega_e, .. }
                if self.emf_busy() && omega_e.abs() < self.emf.max_omega + self.emf.max_omega =>
            {
                self.deferred = Some((theta_e, omega_e, self.elapsed_rad));
                ArcFitOutcome::Pending
            }
            found @ ArcFitOutcome::Found { .. } => {
                self.emf.running = false;
                self.emf_found = None;
                found
            }
            _ if self.emf_busy() || self.running => ArcFitOutcome::Pending,
            // Both have stopped: a chord fit held back is taken, turned on to now
            // (w t = w (floor t) / floor).
            _ => match self.deferred.take() {
                Some((theta_e, omega_e, at)) => {
                    match (omega_e * (self.elapsed_rad - at)).checked_div(self.floor) {
                        Some(turned) => ArcFitOutcome::Found {
                            theta_e: theta_e + turned.radians_to_angle(),
                            omega_e,
                            dc_voltage: AlphaBeta::default(),
                        },
                        None => ArcFitOutcome::GaveUp,
                    }
                }
                None => ArcFitOutcome::GaveUp,
            },
        }
    }

    /// The frequency the chord integrated since the start gives, with the back-EMF
    /// fit's angle now `theta_e`, direction (the sign of `omega_e`) and DC error; `None`
    /// when the chord does not bear the fit out. With the DC error taken out, the chord
    /// is `p = psi(t) - psi(0) = 2 j psi_f sin(w t / 2) e^(j (th_now + th_start) / 2)`:
    /// its direction gives the angle at the start, and the angle turned since, `w t`,
    /// follows; its length must be `2 psi_f |sin(w t / 2)|` within
    /// [`EMF_CHORD_TOLERANCE`] of the magnet flux, and the frequency within a quarter
    /// of the back-EMF fit's. The chord is integrated, so the harmonics that make the
    /// back-EMF's circle wobble (a flux harmonic of order `n` is `n` times larger in the
    /// back-EMF) barely move it: its `w` is the better one (the back-EMF fit's own is
    /// 20 % off at 0.1 m/s, where the chord's is within a few percent). And a transient
    /// at the start that the back-EMF fit took for a DC error (the drive's reaction to a
    /// lost angle: current spikes through `Ls di/dt`, the inverter's dead time near zero
    /// current) leaves a chord the fit does not explain.
    fn chord_frequency(&self, theta_e: Angle, omega_e: T, dc_voltage: AlphaBeta<T>) -> Option<T> {
        // du t = (du / floor) (floor t): time itself, hundreds of per-unit times after a
        // tenth of a second, is beyond fixed point's range (it saturated Q8.24 on the
        // salient motor's base at 0.1 s), the floor's angle is not.
        let drift_x = dc_voltage.alpha.checked_div(self.floor)? * self.elapsed_rad;
        let drift_y = dc_voltage.beta.checked_div(self.floor)? * self.elapsed_rad;
        let p = AlphaBeta::new(self.chord.alpha - drift_x, self.chord.beta - drift_y);
        let quarter = Angle::QUARTER_TURN;
        let forward = omega_e >= T::ZERO;
        // (th_now + th_start) / 2 = angle(p) -+ pi / 2 (mod pi); doubled, mod a turn.
        let bisector = T::atan2(p.beta, p.alpha) - if forward { quarter } else { -quarter };
        let theta_start = bisector + bisector - theta_e;
        let mut turned: T = (theta_e - theta_start).to_radians();
        // The turn has the fit's direction: within (0, 2 pi) forward, (-2 pi, 0) back.
        let full = T::angle_to_radians(Angle::HALF_TURN).abs() * T::TWO;
        if forward && turned < T::ZERO {
            turned = turned + full;
        } else if !forward && turned > T::ZERO {
            turned = turned - full;
        }
        let omega_chord = (turned * self.floor).checked_div(self.elapsed_rad)?;
        // Within the tolerance of the fit's frequency, |w_chord / w - 1| <= tol, without
        // the division (|w| is at least the floor here).
        if (omega_chord - omega_e).abs() > T::from_f32(EMF_CHORD_TOLERANCE) * omega_e.abs() {
            return None;
        }
        // The chord's length against the arc's, 2 psi_f |sin(w t / 2)|, within the
        // tolerance: |p|^2 between the squares of the arc less and plus it (no root).
        let (_, sin_half) = T::cos_sin(turned.mul_unit(T::HALF).radians_to_angle());
        let arc = (self.psi_f + self.psi_f) * sin_half.abs();
        let (short, long) = (arc - self.chord_tolerance, arc + self.chord_tolerance);
        let p_sq = p.alpha * p.alpha + p.beta * p.beta;
        (p_sq <= long * long && (short <= T::ZERO || p_sq >= short * short)).then_some(omega_chord)
    }

    /// One sample of the chord's arc fit (module docs, "The fit"); `elapsed_rad` and the
    /// chord have been advanced.
    fn chord_update(&mut self) -> ArcFitOutcome<T> {
        if !self.running {
            return ArcFitOutcome::Pending;
        }
        let p = self.chord;
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
        let inv_n = T::recip_count(self.samples);
        let mean = |m: T, x: T| m + (x - m).mul_nearest(inv_n);
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
            Some(omega_e) => ArcFitOutcome::Found { theta_e, omega_e, dc_voltage: AlphaBeta::default() },
            None => ArcFitOutcome::GaveUp,
        }
    }
}

/// The back-EMF circle's fit (module docs, "DC errors"): a general circle (centre and
/// radius free) through the low-passed back-EMF, whose centre is the DC voltage error.
#[derive(Clone, Debug)]
struct EmfFit<T> {
    /// Low-passed back-EMF over `psi_f * max_omega / 2` (dimensionless), alpha-beta:
    /// 2 at the highest frequency, a quarter at the floor, so that Q8.24 has both the
    /// range for the moments' cubes and the resolution for the spread's fourth powers.
    emf: AlphaBeta<T>,
    /// The same through a second, slower low-pass (cut-off `wc / EMF_ANGLE_FILTER_RATIO`),
    /// for the angle at the fit (dimensionless, scaled alike).
    emf_slow: AlphaBeta<T>,
    /// The slow filter's cut-off (rad/s) and its inverse (s/rad).
    slow_cutoff: T,
    inv_slow_cutoff: T,
    /// Its settling time, as the floor's angle (rad).
    slow_settle_rad: T,
    /// `2 / (psi_f * max_omega)` (1/V).
    scale: T,
    /// `psi_f * max_omega / 2` (V): the scaled back-EMF back to volts by a product (the
    /// fit's solve, every sample, does without 64-bit software divisions where the
    /// divisor is a constant or shared).
    unscale: T,
    /// Filter cut-off `wc` (rad/s).
    cutoff: T,
    /// `1 / wc` and `1 / max_omega` (s/rad).
    inv_cutoff: T,
    inv_max_omega: T,
    /// `EMF_FILTER_SETTLE` time constants, as the angle the floor turns in them (rad).
    settle_rad: T,
    /// Highest frequency the fit is used at (rad/s).
    max_omega: T,
    /// Floor frequency (rad/s): a circle turning slower is not fitted.
    floor: T,
    /// Running means of `e` (2), `e e^T` (3), `|e|^2` and `|e|^2 e` (2), with `e` scaled
    /// and measured from the first fitted sample (which keeps the centred moments from
    /// being small differences of large ones when the DC error is large).
    mx: T,
    my: T,
    sxx: T,
    sxy: T,
    syy: T,
    mr: T,
    rx: T,
    ry: T,
    /// Running mean of `(|e|^2 / 2)^2` (scaled, measured from the first fitted sample):
    /// the fourth moment the noise's variance is estimated from (`EmfFit::noise_variance`),
    /// a quarter of `|e|^4` so that it stays within Q8.24's range (`|e| <= 4`).
    mrr: T,
    samples: u32,
    /// When the fit started, as the floor's angle since the chord's start (rad).
    start_rad: T,
    /// The first fitted sample (scaled) and its time, as the floor's angle (rad).
    first: AlphaBeta<T>,
    first_rad: T,
    /// Largest `|e|^2` (scaled) the fit takes: 16, twice its highest frequency's back-EMF.
    max_sq: T,
    /// `q / (1 + q)^2` for `q = MIN_SPREAD_RATIO`.
    spread_factor: T,
    /// Least spread of the points (the trace of their covariance, scaled) before the
    /// spread test is tried: a quarter of the squared back-EMF at the floor frequency,
    /// `(2 floor / max_omega)^2 / 4`, what that back-EMF's arc spreads by after about a
    /// third of a turn; well above the filtered noise (at a sixteenth of it the first
    /// few samples' noise passed the spread test on the acquisition sweep).
    min_trace: T,
    /// Radius bounds squared, relative to the back-EMF the fitted frequency gives.
    min_ratio_sq: T,
    max_ratio_sq: T,
    /// The circles that passed their checks so far, averaged ([`EMF_CONFIRM_SHARE`]).
    confirm: Option<Confirm<T>>,
    /// [`EMF_CONFIRM_SHARE`].
    confirm_share: T,
    running: bool,
}

/// The back-EMF fit's circles averaged from the first that passed its checks: one
/// circle's angle moves by about a degree from one sample to the next at 0.1 m/s (the
/// noise the filters leave), so the first to pass is no better than its neighbours,
/// and two arithmetics that pass a sample apart would seed angles that far apart.
#[derive(Clone, Copy, Debug)]
struct Confirm<T> {
    /// The floor's angle since the chord's start at which the mean is taken (rad).
    until_rad: T,
    /// The first circle's angle, advanced every sample at its frequency.
    reference: Angle,
    /// Its frequency (rad/s).
    reference_omega: T,
    /// Means over the circles that passed: angle from `reference` (rad, small),
    /// frequency (rad/s) and DC error (V).
    offset: T,
    omega: T,
    dc_voltage: AlphaBeta<T>,
    /// Mean time of the circles that passed, as the floor's angle since the chord's
    /// start (rad): the mean angle is the angle then, and the reference turns on from it
    /// at the first circle's frequency, which the chord's corrects (`ArcFit::update`).
    centroid_rad: T,
    count: u32,
}

impl<T: Scalar> EmfFit<T> {
    fn new(psi_f_wb: f32, floor_rad_s: f32, base: &Base) -> Self {
        let max_omega_rad_s = EMF_FIT_MAX_PER_FLOOR * floor_rad_s;
        let cutoff_rad_s = EMF_FILTER_PER_FLOOR * floor_rad_s;
        let q = EMF_MIN_SPREAD_RATIO;
        let (r_min, r_max) = EMF_RADIUS_RANGE;
        EmfFit {
            emf: AlphaBeta::default(),
            emf_slow: AlphaBeta::default(),
            slow_cutoff: base.omega(cutoff_rad_s / EMF_ANGLE_FILTER_RATIO),
            inv_slow_cutoff: T::from_f32(1.0 / base.omega::<f32>(cutoff_rad_s / EMF_ANGLE_FILTER_RATIO)),
            slow_settle_rad: T::from_f32(
                EMF_FILTER_SETTLE * EMF_ANGLE_FILTER_RATIO * floor_rad_s / cutoff_rad_s,
            ),
            scale: base.voltage::<T>(0.5 * psi_f_wb * max_omega_rad_s).recip().unwrap_or(T::ZERO),
            unscale: base.voltage(0.5 * psi_f_wb * max_omega_rad_s),
            cutoff: base.omega(cutoff_rad_s),
            inv_cutoff: T::from_f32(1.0 / base.omega::<f32>(cutoff_rad_s)),
            inv_max_omega: T::from_f32(1.0 / base.omega::<f32>(max_omega_rad_s)),
            settle_rad: T::from_f32(EMF_FILTER_SETTLE * floor_rad_s / cutoff_rad_s),
            max_omega: base.omega(max_omega_rad_s),
            floor: base.omega(floor_rad_s),
            mx: T::ZERO,
            my: T::ZERO,
            sxx: T::ZERO,
            sxy: T::ZERO,
            syy: T::ZERO,
            mr: T::ZERO,
            mrr: T::ZERO,
            rx: T::ZERO,
            ry: T::ZERO,
            samples: 0,
            start_rad: T::ZERO,
            first: AlphaBeta::default(),
            first_rad: T::ZERO,
            max_sq: T::from_f32(16.0),
            spread_factor: T::from_f32(q / ((1.0 + q) * (1.0 + q))),
            min_trace: T::from_f32(1.0 / (EMF_FIT_MAX_PER_FLOOR * EMF_FIT_MAX_PER_FLOOR)),
            min_ratio_sq: T::from_f32(r_min * r_min),
            max_ratio_sq: T::from_f32(r_max * r_max),
            confirm: None,
            confirm_share: T::from_f32(EMF_CONFIRM_SHARE),
            running: true,
        }
    }

    /// Starts again at `start_rad`, the floor's angle since the chord's start (rad).
    fn restart(&mut self, start_rad: T) {
        self.start_rad = start_rad;
        self.emf = AlphaBeta::default();
        self.emf_slow = AlphaBeta::default();
        self.mx = T::ZERO;
        self.my = T::ZERO;
        self.sxx = T::ZERO;
        self.sxy = T::ZERO;
        self.syy = T::ZERO;
        self.mr = T::ZERO;
        self.mrr = T::ZERO;
        self.rx = T::ZERO;
        self.ry = T::ZERO;
        self.samples = 0;
        self.confirm = None;
        self.running = true;
    }

    /// One sample; `elapsed_rad` is the floor's angle since the start (already
    /// advanced), `max_elapsed_rad` the longest fit. Bounded time: a fixed number of
    /// operations, one `f32` reciprocal and, once, two divisions and three arctangents.
    fn update(
        &mut self,
        emf_increment: AlphaBeta<T>,
        dt: T,
        elapsed_rad: T,
        max_elapsed_rad: T,
    ) -> ArcFitOutcome<T> {
        if !self.running {
            return ArcFitOutcome::Pending;
        }
        // e_f += wc (e dt - e_f dt), scaled: the increment is e dt.
        let g = self.cutoff;
        let step = |x: T, inc: T| x + g * (inc * self.scale - x * dt);
        let e = AlphaBeta::new(
            step(self.emf.alpha, emf_increment.alpha),
            step(self.emf.beta, emf_increment.beta),
        );
        self.emf = e;
        let gs = self.slow_cutoff;
        let slow = |x: T, inc: T| x + gs * (inc * self.scale - x * dt);
        self.emf_slow = AlphaBeta::new(
            slow(self.emf_slow.alpha, emf_increment.alpha),
            slow(self.emf_slow.beta, emf_increment.beta),
        );
        if let Some(c) = self.confirm.as_mut() {
            c.reference = c.reference + (c.reference_omega * dt).radians_to_angle();
        }
        let e_sq = e.alpha * e.alpha + e.beta * e.beta;
        if e_sq > self.max_sq || elapsed_rad > max_elapsed_rad || !e_sq.is_valid() {
            if let Some(found) = self.confirmed() {
                self.running = false;
                return found;
            }
            // Too fast for this fit (the chord's fit takes it) or too slow to see.
            self.running = false;
            return ArcFitOutcome::GaveUp;
        }
        if elapsed_rad - self.start_rad < self.settle_rad {
            return ArcFitOutcome::Pending;
        }
        if self.samples == 0 {
            self.first = e;
            self.first_rad = elapsed_rad;
        }
        self.samples = self.samples.saturating_add(1);
        let p = AlphaBeta::new(e.alpha - self.first.alpha, e.beta - self.first.beta);
        let p_sq = p.alpha * p.alpha + p.beta * p.beta;
        if p_sq > self.max_sq {
            // Its cubes would leave Q8.24's range: no arc of this fit's speeds (the
            // circles that passed before, if any, are taken).
            self.running = false;
            return self.confirmed().unwrap_or(ArcFitOutcome::GaveUp);
        }
        self.accumulate(p, p_sq);
        // The centred moments: the points' covariance and that of |e|^2 with e.
        let cxx = self.sxx - self.mx * self.mx;
        let cxy = self.sxy - self.mx * self.my;
        let cyy = self.syy - self.my * self.my;
        let trace = cxx + cyy;
        let det = cxx * cyy - cxy * cxy;
        if trace < self.min_trace || det < self.spread_factor * trace * trace {
            return ArcFitOutcome::Pending;
        }
        // A candidate circle; until one passes the checks the fit goes on (more of the
        // arc, less of the noise), up to the fit's time; a frequency outside its range
        // ends it.
        let outcome = match self.solve(e, dt, elapsed_rad, trace, det) {
            ArcFitOutcome::Found { theta_e, omega_e, dc_voltage } => {
                self.average(theta_e, omega_e, dc_voltage, elapsed_rad);
                match self.confirm {
                    Some(c) if elapsed_rad >= c.until_rad => {
                        self.confirmed().unwrap_or(ArcFitOutcome::GaveUp)
                    }
                    _ => ArcFitOutcome::Pending,
                }
            }
            ArcFitOutcome::GaveUp => self.confirmed().unwrap_or(ArcFitOutcome::GaveUp),
            ArcFitOutcome::Pending => ArcFitOutcome::Pending,
        };
        if outcome != ArcFitOutcome::Pending {
            self.running = false;
        }
        outcome
    }

    /// Takes the point `p` (scaled, from the first fitted sample; `p_sq = |p|^2 <= 16`)
    /// into the running means, as the `samples`-th.
    fn accumulate(&mut self, p: AlphaBeta<T>, p_sq: T) {
        let inv_n = T::recip_count(self.samples);
        let mean = |m: T, x: T| m + (x - m).mul_nearest(inv_n);
        self.mx = mean(self.mx, p.alpha);
        self.my = mean(self.my, p.beta);
        self.sxx = mean(self.sxx, p.alpha * p.alpha);
        self.sxy = mean(self.sxy, p.alpha * p.beta);
        self.syy = mean(self.syy, p.beta * p.beta);
        self.mr = mean(self.mr, p_sq);
        self.rx = mean(self.rx, p_sq * p.alpha);
        self.ry = mean(self.ry, p_sq * p.beta);
        let p_sq_2 = p_sq * T::HALF;
        self.mrr = mean(self.mrr, p_sq_2 * p_sq_2);
    }

    /// Takes a circle that passed its checks into the mean (the first one starts it).
    fn average(&mut self, theta_e: Angle, omega_e: T, dc_voltage: AlphaBeta<T>, elapsed_rad: T) {
        let c = self.confirm.get_or_insert(Confirm {
            until_rad: elapsed_rad + (elapsed_rad - self.first_rad) * self.confirm_share,
            reference: theta_e,
            reference_omega: omega_e,
            offset: T::ZERO,
            omega: omega_e,
            dc_voltage,
            centroid_rad: elapsed_rad,
            count: 0,
        });
        c.count = c.count.saturating_add(1);
        let inv_n = T::recip_count(c.count);
        let mean = |m: T, x: T| m + (x - m).mul_nearest(inv_n);
        c.offset = mean(c.offset, (theta_e - c.reference).to_radians());
        c.omega = mean(c.omega, omega_e);
        c.dc_voltage = AlphaBeta::new(
            mean(c.dc_voltage.alpha, dc_voltage.alpha),
            mean(c.dc_voltage.beta, dc_voltage.beta),
        );
        c.centroid_rad = mean(c.centroid_rad, elapsed_rad);
    }

    /// The mean of the circles that passed, `None` before the first.
    fn confirmed(&self) -> Option<ArcFitOutcome<T>> {
        self.confirm.map(|c| ArcFitOutcome::Found {
            theta_e: c.reference + c.offset.radians_to_angle(),
            omega_e: c.omega,
            dc_voltage: c.dc_voltage,
        })
    }

    /// The points' covariance `cxx`, `cxy`, `cyy` (scaled squared) and the covariance of
    /// `|e|^2` with `e`, `bx`, `by` (scaled cubed), each over the trace of the points'
    /// covariance, given its reciprocal `inv_trace`: what the solve and
    /// [`EmfFit::noise_variance`] take.
    fn moments_over_trace(&self, inv_trace: T) -> [T; 5] {
        [
            (self.sxx - self.mx * self.mx) * inv_trace,
            (self.sxy - self.mx * self.my) * inv_trace,
            (self.syy - self.my * self.my) * inv_trace,
            (self.rx - self.mr * self.mx) * inv_trace,
            (self.ry - self.mr * self.my) * inv_trace,
        ]
    }

    /// The variance of the noise on the fitted points, relative to the trace of their
    /// covariance (dimensionless, in `[0, 1/2)`; 0 when it cannot be told): the smallest
    /// root of Taubin's characteristic polynomial ("Noise" in the module docs), by
    /// [`NOISE_NEWTON_STEPS`] Newton steps from zero. `cxx`, `cxy`, `cyy` are the points'
    /// covariance over its trace `1 / inv_trace`, `bx`, `by` the covariance of `|e|^2`
    /// with `e` over the trace, all scaled. Bounded time: a fixed number of operations
    /// and [`NOISE_NEWTON_STEPS`] reciprocals.
    fn noise_variance(&self, cxx: T, cxy: T, cyy: T, bx: T, by: T, inv_trace: T) -> T {
        let h = T::HALF;
        let (mx, my) = (self.mx, self.my);
        // Fourth central moment of the points, E[|e - mean|^4], over 4: from the running
        // means about the first point (E[|e|^4] - 4 E[|e|^2 q] + 4 E[q^2] + 2 M E[|e|^2]
        // - 3 M^2 with q = mean . e, M = |mean|^2). Scaled by a quarter, not less: at 0.1
        // m/s the points span a few hundredths of the scale, and Q8.24's running means
        // lose the centred moment to rounding (f32 and Q8.24 seeded 3 deg apart at a
        // sixty-fourth). A sum that leaves the range gives no estimate.
        let m = mx * mx + my * my;
        let m2 = m * h;
        let q2 = (mx * mx * h) * (self.sxx * h)
            + T::TWO * (mx * my * h) * (self.sxy * h)
            + (my * my * h) * (self.syy * h);
        let qr = (mx * h) * (self.rx * h) + (my * h) * (self.ry * h);
        // Small integers as exact sums (a conversion is a library routine in fixed point).
        let (three, four) = (T::TWO + T::ONE, T::TWO + T::TWO);
        let mzz_4 = self.mrr + four * (q2 - qr) + T::TWO * m2 * (self.mr * h) - three * m2 * m2;
        // The same over the trace squared (dimensionless), and the moments of |e|^2 about
        // the centroid with e: E[(e - mean) |e - mean|^2] = b - 2 C mean.
        let mzz = mzz_4 * inv_trace * inv_trace * four;
        if !(mzz_4.is_valid() && mzz.is_valid()) {
            return T::ZERO;
        }
        let mxz = bx - T::TWO * (mx * cxx + my * cxy);
        let myz = by - T::TWO * (mx * cxy + my * cyy);
        let (kxx, kxy, kyy) = (mxz * mxz * inv_trace, mxz * myz * inv_trace, myz * myz * inv_trace);
        let cov = cxx * cyy - cxy * cxy;
        let var_z = mzz - T::ONE;
        // Taubin's polynomial over the trace (Chernov's form; the trace is Mz):
        // P(x) = a0 + a1 x + a2 x^2 + 4 x^3.
        let a0 = kxx * cyy - T::TWO * kxy * cxy + kyy * cxx - var_z * cov;
        let a1 = var_z + four * cov - kxx - kyy;
        let a2 = T::ZERO - three - mzz;
        let mut x = T::ZERO;
        let mut y = a0;
        for _ in 0..NOISE_NEWTON_STEPS {
            let slope = a1 + x * (a2 + a2 + three * four * x);
            let Some(inv_slope) = slope.recip() else { break };
            let next = x - y * inv_slope;
            let y_next = a0 + next * (a1 + next * (a2 + four * next));
            // Newton from zero goes down the polynomial to its smallest root; a step that
            // climbs, leaves [0, 1/2) or overflows is not taken.
            if !(next.is_valid() && y_next.is_valid())
                || next < T::ZERO
                || next >= T::HALF
                || y_next.abs() > y.abs()
            {
                break;
            }
            x = next;
            y = y_next;
        }
        x
    }

    /// The circle through the points so far, checked against the motor (module docs):
    /// `Found`, `Pending` when its radius does not match its frequency (try again with
    /// the next sample), `GaveUp` when the frequency is outside the fit's range or the
    /// numbers are. Bounded time: one division, six reciprocals (four of them the noise's
    /// Newton steps), four arctangents.
    fn solve(&self, e: AlphaBeta<T>, dt: T, elapsed_rad: T, trace: T, det: T) -> ArcFitOutcome<T> {
        self.candidate(e, dt, elapsed_rad, trace, det).unwrap_or(ArcFitOutcome::GaveUp)
    }

    /// [`EmfFit::solve`], `None` for `GaveUp`.
    fn candidate(
        &self,
        e: AlphaBeta<T>,
        dt: T,
        elapsed_rad: T,
        trace: T,
        det: T,
    ) -> Option<ArcFitOutcome<T>> {
        // c = C^-1 b / 2 by the adjugate, with C and b over the trace (C's entries then
        // below 1, its determinant above the spread factor): in range for Q8.24.
        let inv_trace = trace.recip().filter(|_| det > T::ZERO)?;
        let [cxx, cxy, cyy, bx, by] = self.moments_over_trace(inv_trace);
        // The noise's share of the points' spread, over the trace, taken out of the
        // moments ("Noise" in the module docs): what is left is the arc's.
        let x = self.noise_variance(cxx, cxy, cyy, bx, by, inv_trace);
        let (dxx, dyy) = (cxx - x, cyy - x);
        let spread = T::ONE - x - x;
        let det = dxx * dyy - cxy * cxy;
        if spread < T::HALF || det < self.spread_factor * spread * spread {
            // The noise, not the arc, spreads the points (or as much as the arc does):
            // more of the arc is needed.
            return Some(ArcFitOutcome::Pending);
        }
        // det >= the spread factor times the spread squared, and the spread at least a
        // half, here: 1 / (2 det) is below 40.
        let inv_2det = (det + det).recip()?;
        let (bx, by) = (bx - (x + x) * self.mx, by - (x + x) * self.my);
        let px = (dyy * bx - cxy * by) * inv_2det;
        let py = (dxx * by - cxy * bx) * inv_2det;
        if !(px.is_valid() && py.is_valid()) {
            return None;
        }
        // The centre, from the first fitted sample's origin.
        let (cx, cy) = (self.first.alpha + px, self.first.beta + py);
        // The rotating part now and at the first fitted sample: the angle turned between
        // them (less than a turn: the spread test passes within about half of one) over
        // the time gives the frequency, both signs.
        let v = AlphaBeta::new(e.alpha - cx, e.beta - cy);
        let angle_now = T::atan2(v.beta, v.alpha);
        let turned: T = (angle_now - T::atan2(-py, -px)).to_radians();
        let omega_e = (self.floor * turned).checked_div(elapsed_rad - self.first_rad)?;
        if omega_e.abs() < self.floor || omega_e.abs() > self.max_omega {
            return None;
        }
        // The radius the fitted frequency gives, 2 |w| psi_f |G(jw)| / (psi_f max_omega)
        // scaled, squared: 4 (w / max_omega)^2 / (1 + (w / wc)^2); compared without
        // dividing.
        let w_rel = omega_e * self.inv_max_omega;
        let w_cut = omega_e * self.inv_cutoff;
        let expected_sq = (T::TWO + T::TWO) * w_rel * w_rel;
        let radius_sq_filtered = (v.alpha * v.alpha + v.beta * v.beta) * (T::ONE + w_cut * w_cut);
        if radius_sq_filtered < self.min_ratio_sq * expected_sq
            || radius_sq_filtered > self.max_ratio_sq * expected_sq
        {
            return Some(ArcFitOutcome::Pending);
        }
        // The back-EMF leads the flux by a quarter turn in the direction of motion; the
        // filter delays it: a discrete first-order low-pass `y += wc dt (x - y)` by
        // `atan(w (1 - wc dt) / wc)` (to second order in `w dt`), and its input, a
        // period's mean, is half a period old. The slow filter's output gives the angle
        // once it has settled, the fast one's before. The lag is added as the argument of
        // `1 + j w (1 - wc dt) / wc` (at most 0.64 in magnitude across the fit's range, so
        // the product stays in range): one arctangent of the rotated vector gives the
        // angle and its lag.
        let quarter = Angle::from_radians(T::from_f32(core::f32::consts::FRAC_PI_2));
        let lead = if omega_e < T::ZERO { -quarter } else { quarter };
        let half_sample = (omega_e * dt * T::HALF).radians_to_angle();
        let (w, w_per_cutoff, cutoff) = if elapsed_rad - self.start_rad >= self.slow_settle_rad {
            let slow = AlphaBeta::new(self.emf_slow.alpha - cx, self.emf_slow.beta - cy);
            (slow, omega_e * self.inv_slow_cutoff, self.slow_cutoff)
        } else {
            (v, w_cut, self.cutoff)
        };
        let lag_tan = w_per_cutoff * (T::ONE - cutoff * dt);
        let lagged = AlphaBeta::new(w.alpha - w.beta * lag_tan, w.beta + w.alpha * lag_tan);
        let theta_e = T::atan2(lagged.beta, lagged.alpha) - lead + half_sample;
        let (ux, uy) = (cx * self.unscale, cy * self.unscale);
        if !(ux.is_valid() && uy.is_valid()) {
            return None;
        }
        Some(ArcFitOutcome::Found { theta_e, omega_e, dc_voltage: AlphaBeta::new(ux, uy) })
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
        noisy_fit(base, omega, theta0, drift, 0.0, 0)
    }

    /// Gaussian samples (a sum of twelve uniforms) of standard deviation `sigma`, seeded.
    fn gauss(seed: &mut u32, sigma: f64) -> f64 {
        let mut sum = 0.0;
        for _ in 0..12 {
            *seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            sum += f64::from(*seed >> 8) / 16_777_216.0;
        }
        (sum - 6.0) * sigma
    }

    /// [`fit`] with white noise of `sigma` (Wb) on each axis of the flux the chord is
    /// taken from: what the current sensors' noise puts there through `Ls i` (the
    /// increments, and so the back-EMF, carry it differenced).
    fn noisy_fit<T: Scalar>(
        base: &Base,
        omega: f64,
        theta0: f64,
        drift: [f64; 2],
        sigma: f64,
        seed: u32,
    ) -> (ArcFitOutcome<T>, usize, f64) {
        let mut f = ArcFit::<T>::new(PSI as f32, FLOOR, base);
        let mut seed = seed;
        let mut noise = [0.0; 2];
        let flux = |k: usize, n: [f64; 2]| {
            let th = theta0 + omega * k as f64 * DT;
            [
                PSI * th.cos() + drift[0] * k as f64 * DT + n[0],
                PSI * th.sin() + drift[1] * k as f64 * DT + n[1],
            ]
        };
        for k in 1..100_000 {
            let next = [gauss(&mut seed, sigma), gauss(&mut seed, sigma)];
            let (a, b) = (flux(k - 1, noise), flux(k, next));
            noise = next;
            let inc = AlphaBeta::new(base.flux((b[0] - a[0]) as f32), base.flux((b[1] - a[1]) as f32));
            match f.update(inc, base.time(DT as f32)) {
                ArcFitOutcome::Pending => {}
                done => return (done, k, theta0 + omega * k as f64 * DT),
            }
        }
        (ArcFitOutcome::Pending, 0, 0.0)
    }

    /// The largest errors of the fits over both directions and eight start angles at
    /// each of `freqs_hz`, with the DC voltage `drift` (V): angle (deg), frequency
    /// (relative), DC voltage (V), and the longest fit (periods).
    fn sweep<T: Scalar>(base: &Base, freqs_hz: &[f64], drift: [f64; 2]) -> [f64; 4] {
        let to_si = base.omega_rad_s as f64;
        let mut worst = [0.0f64; 4];
        for &f_hz in freqs_hz {
            for sign in [1.0, -1.0] {
                for j in 0..8 {
                    let omega = sign * 2.0 * PI * f_hz;
                    let theta0 = j as f64 * PI / 4.0 + 0.1;
                    let (out, k, theta) = fit::<T>(base, omega, theta0, drift);
                    let ArcFitOutcome::Found { theta_e, omega_e, dc_voltage } = out else {
                        panic!("{f_hz} Hz, {sign}, {j}: {out:?}")
                    };
                    let err = (Angle::from_radians(theta as f32) - theta_e).to_degrees_f64();
                    let w = f64::from(omega_e.to_f32()) * to_si;
                    let u = [dc_voltage.alpha, dc_voltage.beta]
                        .map(|x| f64::from(x.to_f32()) * base.voltage_v as f64);
                    let dc_err = (u[0] - drift[0]).abs().max((u[1] - drift[1]).abs());
                    let errors = [err.abs(), (w - omega).abs() / omega.abs(), dc_err, k as f64 * DT * f_hz];
                    for (w, e) in worst.iter_mut().zip(errors) {
                        *w = w.max(e);
                    }
                }
            }
        }
        worst
    }

    /// Asserts each of `worst` below its `limit`.
    fn assert_within(what: &str, worst: [f64; 4], limit: [f64; 4]) {
        let names = ["angle (deg)", "frequency (rel.)", "DC voltage (V)", "periods"];
        for ((name, w), l) in names.iter().zip(worst).zip(limit) {
            assert!(w < l, "{what}: {name} {w} above {l} ({worst:?})");
        }
    }

    #[test]
    fn an_exact_arc_gives_the_flux_angle_and_frequency_within_half_a_period() {
        // Above the back-EMF fit's range (16 Hz at this floor) the chord's arc is fitted.
        // Its chords are exact, so the fit is: the angle within the rounding of the type,
        // the frequency within the one-sample offset of the time count; it sees no DC.
        let pu = Base { voltage_v: 179.6, current_a: 2.97, omega_rad_s: 1122.5 };
        let fast = [40.0, 67.0];
        assert_within("f64", sweep::<f64>(&Base::SI, &fast, [0.0; 2]), [1e-3, 1e-3, 1e-9, 0.5]);
        assert_within("f32", sweep::<f32>(&Base::SI, &fast, [0.0; 2]), [0.01, 1e-3, 1e-9, 0.5]);
        assert_within("Q24", sweep::<Q24>(&pu, &fast, [0.0; 2]), [0.05, 2e-3, 1e-9, 0.5]);
    }

    #[test]
    fn the_back_emf_circle_gives_the_dc_error_with_the_angle_and_frequency() {
        // Within the back-EMF fit's range, with and without a DC error of 60 % of the
        // back-EMF at 3 Hz (+2 V, -1 V; the chord's arc alone gives up or is bent by tens
        // of degrees there). The filtered back-EMF is exact but for the filter's start,
        // which has decayed to exp(-5) of the first value when the fit begins: that
        // residue in the first points sets the errors.
        let pu = Base { voltage_v: 179.6, current_a: 2.97, omega_rad_s: 1122.5 };
        let slow = [3.0, 6.0, 10.0, 15.0];
        // Measured (all three types alike since the running means round to nearest):
        // angle 0.23 / 0.30 deg, frequency (the chord's, which the angle error enters
        // twice) 0.39 / 0.51 %, DC 0.045 / 0.054 V, 0.45 periods (without / with the DC
        // error). The circle first passes its checks at 0.41 periods; the mean over the
        // next eighth of the fit's time (`EMF_CONFIRM_SHARE`) takes the errors down from
        // 0.25 / 0.33 deg, 0.51 / 0.66 %, 0.052 / 0.064 V. Rounded down instead, Q8.24 is
        // 1.0 deg and 1.8 % off on the same data: half an LSB of bias per update of each
        // running mean.
        let limit = [0.4, 0.008, 0.08, 0.5];
        // A base whose time unit is shorter (the salient example motor's, 1361 rad/s):
        // a tenth of a second is 136 per-unit times there, beyond Q8.24's range, and
        // the chord's check once saturated on it (the fit fell back to the chord's).
        let fast_base = Base { voltage_v: 163.3, current_a: 4.243, omega_rad_s: 1360.8 };
        for drift in [[0.0; 2], [2.0, -1.0]] {
            assert_within("f64", sweep::<f64>(&Base::SI, &slow, drift), limit);
            assert_within("f32", sweep::<f32>(&Base::SI, &slow, drift), limit);
            assert_within("Q24", sweep::<Q24>(&pu, &slow, drift), limit);
            assert_within("Q24, short time unit", sweep::<Q24>(&fast_base, &slow, drift), limit);
        }
    }

    #[test]
    fn the_chord_bears_out_a_true_fit_and_refuses_a_wrong_dc_error() {
        // The chord of an exact arc with a DC error of (1, -0.5) V at 5 Hz, both
        // directions, eight start angles, checked a third of a period in (where the
        // back-EMF fit ends): told the true angle, direction and DC error, the chord gives
        // the frequency; told a DC error 2 V or more off (a transient at the start made
        // the back-EMF fit believe in 2.2 V in the drive's flying restart), it refuses;
        // told a frequency 40 % off, too.
        let drift = [1.0, -0.5];
        let mut passed = [0; 4];
        for sign in [1.0, -1.0] {
            let omega = sign * 2.0 * PI * 5.0;
            for j in 0..8 {
                let theta0 = j as f64 * PI / 4.0 + 0.1;
                let mut f = ArcFit::<f64>::new(PSI as f32, FLOOR, &Base::SI);
                f.stop();
                let flux = |k: usize| {
                    let (t, th) = (k as f64 * DT, theta0 + omega * k as f64 * DT);
                    [PSI * th.cos() + drift[0] * t, PSI * th.sin() + drift[1] * t]
                };
                let n = (1.0 / 15.0 / DT) as usize;
                for k in 1..=n {
                    let (a, b) = (flux(k - 1), flux(k));
                    f.chord = AlphaBeta::new(f.chord.alpha + b[0] - a[0], f.chord.beta + b[1] - a[1]);
                    f.elapsed_rad += f64::from(FLOOR) * DT;
                }
                let theta = Angle::from_radians((theta0 + omega * n as f64 * DT) as f32);
                let du = AlphaBeta::new(drift[0], drift[1]);
                let w = f.chord_frequency(theta, omega, du).expect("the true fit");
                assert!((w - omega).abs() < 1e-4 * omega.abs(), "{sign} {j}: {w} rad/s");
                for (n, x) in [1.0, 1.5, 2.0, 2.5].into_iter().enumerate() {
                    for off in
                        [AlphaBeta::new(drift[0] + x, drift[1]), AlphaBeta::new(drift[0], drift[1] - x)]
                    {
                        if f.chord_frequency(theta, omega, off).is_some() {
                            passed[n] += 1;
                        }
                    }
                }
                assert_eq!(f.chord_frequency(theta, omega * 1.4, du), None, "{sign} {j}: w 40 % off");
            }
        }
        // Of the 32 (direction, start, axis of the error) a DC error 1 V off passes 10
        // times, 1.5 V off twice (its drift along the chord over 67 ms, 0.6 of the magnet
        // flux, can leave the chord's length and turn within tolerance), 2 V and more
        // never.
        assert!(passed[0] <= 10 && passed[1] <= 2, "{passed:?}");
        assert_eq!(passed[2..], [0, 0], "{passed:?}");
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

    /// The noise's variance from Taubin's polynomial against the variance put in: points
    /// on a third of a turn (the back-EMF fit's usual arc) and on a full circle, scaled as
    /// the fit scales them, with white noise of a known variance on each axis; none on
    /// exact points.
    fn noise_estimate<T: Scalar>(turn: f64, sigma: f64, seed: u32) -> f64 {
        let mut f = EmfFit::<T>::new(PSI as f32, FLOOR, &Base::SI);
        let mut seed = seed;
        let (radius, n) = (0.4, 4000);
        let point = |k: usize, seed: &mut u32| {
            let th = 0.3 + turn * 2.0 * PI * k as f64 / n as f64;
            let (x, y) = (radius * th.cos() + gauss(seed, sigma), radius * th.sin() + gauss(seed, sigma));
            (x - radius * 0.3f64.cos(), y - radius * 0.3f64.sin())
        };
        for k in 0..n {
            let (x, y) = point(k, &mut seed);
            let p = AlphaBeta::new(T::from_f32(x as f32), T::from_f32(y as f32));
            f.samples += 1;
            f.accumulate(p, p.alpha * p.alpha + p.beta * p.beta);
        }
        let trace = (f.sxx - f.mx * f.mx) + (f.syy - f.my * f.my);
        let inv = trace.recip().unwrap();
        let [cxx, cxy, cyy, bx, by] = f.moments_over_trace(inv);
        let x = f.noise_variance(cxx, cxy, cyy, bx, by, inv);
        f64::from((x * trace).to_f32())
    }

    #[test]
    fn the_noise_variance_is_read_from_the_points_themselves() {
        // Noise of a twentieth and a tenth of the radius per axis (the back-EMF fit's
        // points at 0.1 m/s on the salient example motor carry about a fifth, filtered).
        // Measured over five seeds, f32 and Q8.24 alike: within 3.5 % of the variance put
        // in, on the third of a turn as on the full circle (4000 points); on exact points
        // 1.7e-7 (f32) and 1.4e-6 (Q8.24: rounding in the running means) against a radius
        // squared of 0.16.
        for sigma in [0.02, 0.04] {
            for turn in [1.0 / 3.0, 1.0] {
                for seed in 1..=5 {
                    for (name, x) in [
                        ("f32", noise_estimate::<f32>(turn, sigma, seed)),
                        ("Q24", noise_estimate::<Q24>(turn, sigma, seed)),
                    ] {
                        let rel = x / (sigma * sigma) - 1.0;
                        assert!(
                            rel.abs() < 0.06,
                            "{name}, {turn} turn, sigma {sigma}, seed {seed}: {rel:+.3}"
                        );
                    }
                }
            }
        }
        for turn in [1.0 / 3.0, 1.0] {
            assert!(noise_estimate::<f32>(turn, 0.0, 1).abs() < 5e-6, "f32 exact");
            assert!(noise_estimate::<Q24>(turn, 0.0, 1).abs() < 5e-6, "Q24 exact");
        }
    }

    /// The largest angle (deg) and DC voltage (V) errors of the fit over both directions,
    /// eight start angles and five noise seeds at 3 and 5 Hz, with the DC error `drift`
    /// (V) and flux noise `sigma` (Wb); and how many fits were found.
    fn noisy_sweep<T: Scalar>(base: &Base, drift: [f64; 2], sigma: f64) -> ([f64; 2], usize) {
        let mut worst = [0.0f64; 2];
        let mut found = 0;
        for f_hz in [3.0, 5.0] {
            for sign in [1.0, -1.0] {
                for j in 0..8 {
                    for seed in 1..=5 {
                        let omega = sign * 2.0 * PI * f_hz;
                        let theta0 = j as f64 * PI / 4.0 + 0.1;
                        let (out, _, theta) = noisy_fit::<T>(base, omega, theta0, drift, sigma, seed);
                        let ArcFitOutcome::Found { theta_e, dc_voltage, .. } = out else { continue };
                        found += 1;
                        let err = (Angle::from_radians(theta as f32) - theta_e).to_degrees_f64().abs();
                        let u = [dc_voltage.alpha, dc_voltage.beta]
                            .map(|x| f64::from(x.to_f32()) * base.voltage_v as f64);
                        worst = [worst[0].max(err), worst[1].max((u[0] - drift[0]).hypot(u[1] - drift[1]))];
                    }
                }
            }
        }
        (worst, found)
    }

    #[test]
    fn with_noisy_currents_the_fit_takes_the_noise_out_of_the_circle() {
        // The paper motor's flux with a DC error of 60 % of the back-EMF at 3 Hz (+2 V,
        // -1 V) and white noise on the flux of 3.2e-4 Wb per axis: what current sensors
        // put there through `Ls i` on a motor whose inductive flux per sensor noise is
        // that of the noisier example motors, so that the back-EMF of one sample carries
        // noise of 1.5 times its own size. Measured (160 fits each, all found): f32
        // within 1.1 deg and 0.053 V (2 % of the back-EMF at 3 Hz), Q8.24 alike. The
        // plain algebraic fit (the noise's variance taken as zero) is biased towards
        // small circles: 12.8 deg and 0.66 V on the same data.
        let pu = Base { voltage_v: 179.6, current_a: 2.97, omega_rad_s: 1122.5 };
        let drift = [2.0, -1.0];
        for (name, (worst, found)) in [
            ("f32", noisy_sweep::<f32>(&Base::SI, drift, 3.2e-4)),
            ("Q24", noisy_sweep::<Q24>(&pu, drift, 3.2e-4)),
        ] {
            assert_eq!(found, 160, "{name}");
            assert!(
                worst[0] < 2.0 && worst[1] < 0.1,
                "{name}: angle {:.2} deg, DC {:.3} V",
                worst[0],
                worst[1]
            );
        }
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
