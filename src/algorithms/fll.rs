//! Frequency-locked loop (FLL): the electrical frequency from the flux vector's
//! rotation, independent of the DCFO's notch tuning. It tunes the notch, feeds the PLL
//! forward, and finds a moving mover from a cold start.
//!
//! ## The discriminator
//! The DCFO's band-pass output `x1 = D psi` (its flux estimate) and the increment of its
//! integrator `dpsi_i` (the back-EMF `e dt` plus the observer's slow DC correction)
//! give, per sample,
//!
//! ```text
//! dtheta = Im(conj(x1) dpsi_i) / max(|x1|^2, psi_ref^2)    (rad per sample)
//! ```
//!
//! For a flux vector `psi = |psi| e^{j w t}` (either direction) and a band-pass tuned to
//! any `w_n > 0`, `D(jw) = 1 / (1 + jX)`, so `Re D = |D|^2` and
//! `Im(conj(D psi) j w psi) = w |psi|^2 |D|^2 = w |x1|^2`: while `|x1| >= psi_ref`,
//! `dtheta / dt` is **exactly** `w`, whatever the notch error. The phase error that a
//! mistuned notch puts on `x1` (`dw / (zeta w)`, see [`crate::algorithms::observer::Dcfo`]) cancels
//! out. Sampled, the increment is a chord centred half a sample before `x1`, so the
//! band-pass phase `phi` is read as `phi + w dt / 2`: a relative error up to
//! `(|w| dt / 2) |tan phi|` while the notch is off (1.5 % at 400 rad/s with the notch at
//! half the frequency), none once it is on (`tests/fll.rs`).
//!
//! ## What biases it
//! The discriminator is `e_q / |psi|`: the back-EMF component along the rotation. Any
//! error in the back-EMF along q reads as speed. In steady state a DC offset `dc` in the
//! observer's voltage is cancelled inside `dpsi_i` by the DCFO's feedback
//! (`dc + (h/Ls) d = 0`), but while the DCFO settles it puts a ripple at `w` of
//! amplitude `|dc| / |psi|` rad/s on the reading (12.5 rad/s for the paper's +2 V at
//! 0.16 Wb). A resistance error `dR` reads as `dR i_q / psi_f` rad/s (31 rad/s per
//! ampere for a doubled Rs on the paper motor), a bias that grows with thrust. The
//! PLL on `x1` has neither: it follows the rotation of the estimate, whatever its
//! amplitude. Hence the estimator's `NotchTuning::AcquireWithFll`: the FLL finds
//! the frequency and takes over in speed transients; the PLL holds the steady state.
//! Tried and not kept: the rotation rate of `x1` itself (`Im(conj(x1) dx1)`, unbiased,
//! but it closes a loop through the band-pass phase: 1.7x peaking and a closed-loop
//! drive that lost lock), a notch at `w` on the reading, subtracting the drift of the
//! DCFO's DC estimate from `dpsi_i` (neither moved the +2 V step), and an
//! acceleration state (below).
//!
//! ## The loop
//! Two first-order trackers with the rate `g = gain_per_omega * w_n` (1/s), scaled
//! with the notch frequency `w_n` so the loop has the same shape at every speed:
//!
//! ```text
//! omega    += g (dtheta - omega dt)          signed frequency (rad/s)
//! omega_n  += g (r - omega_n dt)             notch frequency, in [floor, start] (rad/s)
//! r         = |dtheta| + m (s dtheta - |dtheta|),  s = sign(omega),  m = min(c |omega| / omega_n, 1)
//! ```
//!
//! The notch's reading `r` is the rotation along the direction the signed frequency has
//! found (`s dtheta`, linear in the noise) once that frequency is a `1 / c` share of the
//! notch (`m = 1`; `c` = [`DIRECTION_SHARE_GAIN`] = 4, below), and `|dtheta|` while it
//! is not (from reset, through a reversal), so that
//! the notch sweeps and follows whatever the direction; `m` moves the one into the other
//! continuously (no threshold for f32 and fixed point to part at). The reading is not
//! `|dtheta|` always, because that is biased: at low speed the per-sample rotation is
//! comparable to the noise on the increment (the current sensors' noise through
//! `Ls di`), and the mean of `|x + n|` exceeds `|x|` (by 17 % for noise of the
//! rotation's size), so the notch sits above the mover, the DCFO's angle lags by
//! `dw / (zeta w)` and the two frequencies never agree. On the salient example motor at
//! 3.3 Hz a rectified reading holds the notch at 25 rad/s on a 21 rad/s mover, 10 deg of
//! steady error, and 3 of 48 cold starts lock within their window (none within budget;
//! `dcfo acquire --motor motors/salient.toml`); `tests/fll.rs` checks the bias.
//!
//! ## Noise: where the notch can stay above the mover
//! Let the noise make the mean of `|dtheta|` `rho` times the rotation (`rho >= 1`; 1.17
//! for noise of the rotation's size, as above). Besides `omega_n = |w|` the notch's
//! update has an equilibrium with `m < 1` where `omega_n = (1 - m) rho |w| + m |w|`, `m
//! = c |w| / omega_n`, i.e. `omega_n^2 - rho |w| omega_n + c (rho - 1) w^2 = 0`, which
//! has roots when `rho^2 >= 4 c (rho - 1)`. With `c = 1` that is
//! `(rho - 2)^2 >= 0`: for any `rho > 2` the notch can stay at `(rho - 1) |w|`, and the
//! sweep from above meets that root first. Its band-pass then attenuates the flux the
//! FLL reads, which makes the noise larger still. On a motor with `Lq I / psi_f` 1.2
//! (30 mH, 0.1 Wb) at 3.3 Hz with a current offset `c = 1` holds the notch at
//! 80-140 rad/s on a 21 rad/s mover, the angle 110-130 deg off for all of the 1.8 s
//! window. With `c = 4` the high root exists only for `rho >= 8 + 4 sqrt(3) = 14.9`.
//! `dcfo acquire` on that motor: 30 of 576 cold starts never lock (73 with `c = 1`, 23
//! to 38 with `c` from 2 to 8, the sensors' realisation); the paper motor, both example
//! motors and a 230 V motor are the same with `c = 1` and `c = 4`, `dcfo faults` all met
//! (`tests/fll.rs` checks the notch at noise five and ten times the rotation). `c = 4`
//! applies while the FLL steers the DCFO's notch ([`Fll::set_steering`]): once the PLL
//! does, the FLL's notch only scales its trackers' rate and its settle check, and there
//! `c = 1` keeps the paper's doubled-resistance scenario at 7.9 deg (median over eight
//! event phases) where `c = 4` takes it to 11.1.
//!
//! Below `psi_ref` a measurement is weighted down by `|x1|^2 / psi_ref^2` (the `max` in
//! the denominator): a weak or absent flux reads as "no rotation", so the notch sweeps
//! *down*. Divisions: the reciprocals of a quantity bounded below and of the period,
//! and `|omega| / omega_n` (`omega_n` is at least the floor).
//!
//! ## Why the notch must follow fast: `gain_per_omega = 4`
//! With the notch exactly on the instantaneous frequency, the SOGI passes a
//! constant-amplitude flux vector of *any* frequency trajectory without error (its
//! complex envelope equations hold `x1 = psi` exactly). The DCFO's transient angle
//! error is therefore the notch's error `dw`, seen through `dw / (zeta w)`. A tracker
//! of rate `g` lags a ramp of `a` rad/s^2 by `a / g`, so `g` should be as large as the
//! noise allows. Measured on a synthetic 10 Hz flux whose speed wobbles by +-7 rad/s at
//! 6 Hz (estimator alone, ideal voltage, the FLL tuning the notch throughout): max
//! angle error 8.8 deg at `g = 0.25 w`, 7.7 at `w`, 4.8 at `2 w`, 2.4 at `4 w`; its
//! phase-modulation response stays within 1.00-1.19 in gain and 0 to -17 deg up to 8 Hz
//! (PLL-tuned notch: -29 deg at 4 Hz). In the closed-loop drive with the FLL always
//! tuning the notch, `4 w` takes the paper's 40 N load step to 3.8 deg (PLL-tuned
//! notch: 26.8 deg). An added acceleration state (critically damped alpha-beta tracker)
//! made the wobble worse (11 deg at `w`): its double pole sits at `g / 2`. `g dt` stays
//! below 1/2 for any period (at the paper motor's start frequency and 10 kHz: 0.45).
//!
//! ## Acquisition: start high, sweep down
//! From reset the notch starts at `start_omega_rad_s`, above any speed the motor reaches
//! (default: the speed at which the back-EMF equals the rated phase voltage). There the
//! DCFO's band-pass settles within a few `1 / w_n` — the integrator's unknown initial
//! flux is a step that a high-frequency band-pass forgets quickly — and every flux
//! below it is passed with its rotation intact (attenuated by `2 zeta w / w_n`). With no
//! usable flux the notch sweeps down as `d w_n / dt = -gain w_n^2`, reaching a speed `w`
//! after about `1 / (gain w)`, i.e. `1 / (2 pi gain)` electrical periods; with a flux
//! it converges on `|w|` at the rate `g`. The sweep needs no knowledge of the speed and
//! no search logic: it is the same update.
//!
//! ## Settled
//! [`FllOutput::frequency_settled`]: the measurement has had full weight, and `|omega|`
//! and the notch frequency agree within [`FllConfig::settle_tolerance`], both filtered
//! at `g / 4`. [`FllOutput::settled`] adds that the flux estimate is trustworthy:
//! - its amplitude is steady: an offset `c` left in `x1` (the integrator's initial flux,
//!   a DC step not yet removed) modulates `|x1|^2` at `w` by `2 c |psi|`, so the mean
//!   absolute deviation of `|x1|^2` from its mean (over about three periods) must stay
//!   below 0.3 of that mean (`c / |psi|` below about 0.24, 14 deg); the deviation rises
//!   within a sixth of a period and decays over two thirds of one;
//! - and it has been so for [`FllConfig::settle_guard_rad`] of electrical angle (default
//!   15 rad, 2.4 periods): four time constants of the DCFO's slowest pole (`0.263 w` for
//!   `zeta = 1`, `h = -0.2 Ls w`), the time it needs to remove what acquisition left in
//!   its integrator. Without the guard the acquisition sweep claims lock on
//!   decaying 17 deg transients in 213 of 576 cold starts; with it, in none.
//!
//! ## Undisturbed
//! [`FllOutput::undisturbed`] says that no disturbance is being removed right now; the
//! estimator's `locked` flag requires it (the notch's tuning does not: a real speed
//! change trips it too, and then the FLL must be free to bound the notch). Two fast
//! detectors, both filtered at the notch frequency (about a sixth of a period):
//! - the frequency estimate's ripple `| omega - mean |`, mean and ripple filtered at
//!   `w_n`: a DC error `e` in the back-EMF puts a ripple of `|e| / |psi|` rad/s at `w` on
//!   the reading (above), read at about `0.45 |e| / |psi|` after the filters; the limit,
//!   [`MAX_OMEGA_RIPPLE`] = 0.05 of `w_n`, is a DC error of about a tenth of the
//!   back-EMF;
//! - the flux amplitude's peak deviation from its mean, held and decaying at `w_n`: an
//!   offset `c` in `x1` swings `|x1|^2` by `2 c |psi|` twice a period, and the held peak
//!   sees it within a quarter period whatever the offset's direction; the limit,
//!   [`MAX_FLUX_SQ_PEAK`] = 0.2 of the mean, is an offset of about `0.1 |psi|` (6 deg).
//!
//! The slower steadiness check of [`FllOutput::settled`] (a mean absolute deviation over
//! two thirds of a period) sees the paper's +2 V step too late: the angle error passes
//! 15 deg within 25 ms of the step, and on that check alone the flag stays set for 66 ms
//! of it. Measured with both detectors and the estimator's drift check: no sample
//! locked above 15 deg in the paper's scenarios (eight event phases each) and in the
//! 576 cold starts of `dcfo acquire`, and the flag as available there as without them.

use crate::algorithms::transforms::AlphaBeta;
use crate::num::units::Base;
use crate::num::{Scalar, positive};

/// Largest mean absolute deviation of the frequency estimate from its mean, relative to
/// the notch frequency (dimensionless), for [`FllOutput::undisturbed`] (module docs).
pub const MAX_OMEGA_RIPPLE: f32 = 0.05;

/// Largest recent peak deviation of `|x1|^2` from its mean, relative to the mean
/// (dimensionless), for [`FllOutput::undisturbed`]: an offset of about `0.1 |psi|`.
pub const MAX_FLUX_SQ_PEAK: f32 = 0.2;

/// How far the signed frequency must have reached towards the notch frequency for the
/// notch to follow the reading along its direction alone, while the FLL steers the
/// DCFO's notch ([`Fll::set_steering`]; dimensionless): the share of that reading is
/// `min(DIRECTION_SHARE_GAIN |omega| / w_n, 1)` (module docs, "The loop"). At 1 a noisy
/// flux holds the notch at a multiple of the mover's frequency for good: the high
/// equilibrium exists for any noise (module docs, "Noise"); at 4 only
/// once the noise rectifies to 15 times the rotation. While the PLL steers, 1.
pub const DIRECTION_SHARE_GAIN: f32 = 4.0;

/// Rate of the frequency-ripple and amplitude-peak filters per unit of notch frequency
/// (dimensionless): a time constant of `1 / w_n`, a sixth of a period.
const OMEGA_RIPPLE_RATE: f32 = 1.0;

/// Rate of the flux-amplitude mean once the measurement has its full weight, as a share
/// of its rate before (dimensionless): the mean then follows over about three periods.
const SETTLED_MEAN_SHARE: f32 = 0.2;

/// FLL tuning, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FllConfig {
    /// Tracking rate per unit of notch frequency (dimensionless, > 0): the trackers'
    /// rate is `gain_per_omega * w_n` (1/s).
    pub gain_per_omega: f32,
    /// Notch frequency at reset (rad/s, > floor): the top of the acquisition sweep.
    pub start_omega_rad_s: f32,
    /// Lowest notch frequency (rad/s, > 0).
    pub floor_rad_s: f32,
    /// Flux amplitude from which a measurement counts fully (Wb, > 0).
    pub ref_flux_wb: f32,
    /// Electrical angle the estimate must have stayed settled over before `settled` is
    /// claimed (rad, >= 0): time for the DCFO to remove what acquisition left in its
    /// integrator (see the module docs).
    pub settle_guard_rad: f32,
    /// Relative disagreement between `|omega|` and the notch frequency below which the
    /// FLL counts as settled (dimensionless, in (0, 1)).
    pub settle_tolerance: f32,
}

impl FllConfig {
    /// Defaults for a motor of magnet flux `psi_f_wb` (Wb) and rated phase peak voltage
    /// `phase_peak_v` (V), with notch floor `floor_rad_s` (rad/s): start at
    /// `phase_peak_v / psi_f_wb` (the speed where the back-EMF reaches the rated
    /// voltage), trackers at `4 w_n` (see the module docs), full weight from
    /// `psi_f / 2`, settled within 10 %.
    pub fn for_motor(psi_f_wb: f32, phase_peak_v: f32, floor_rad_s: f32) -> Self {
        FllConfig {
            gain_per_omega: 4.0,
            start_omega_rad_s: (phase_peak_v / psi_f_wb).max(4.0 * floor_rad_s),
            floor_rad_s,
            ref_flux_wb: 0.5 * psi_f_wb,
            settle_tolerance: 0.1,
            settle_guard_rad: 15.0,
        }
    }
}

/// Why an FLL could not be built; names the setting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FllConfigError {
    /// A gain is not a valid number in range.
    BadGain,
    /// The floor or the start frequency is not valid (`0 < floor < start`).
    BadRange,
    /// `ref_flux_wb` is not a valid positive number.
    BadFlux,
    /// `settle_tolerance` is not in (0, 1), or `settle_guard_rad` is negative or not finite.
    BadTolerance,
}

/// One sample of FLL output, in working units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FllOutput<T> {
    /// Signed electrical frequency estimate (rad/s).
    pub omega_e: T,
    /// Notch frequency for the next sample (rad/s, >= floor).
    pub notch_omega: T,
    /// The frequency estimate is usable: full-weight flux, `|omega|` and the notch agree
    /// (see the module docs).
    pub frequency_settled: bool,
    /// `frequency_settled`, and the flux amplitude is steady (see the module docs).
    pub settled: bool,
    /// No sign of a disturbance being removed (see the module docs): the frequency
    /// estimate's ripple is below [`MAX_OMEGA_RIPPLE`] of the notch frequency and the
    /// flux amplitude's recent peak deviation below [`MAX_FLUX_SQ_PEAK`] of its mean. A
    /// real speed change can clear it too while it lasts.
    pub undisturbed: bool,
    /// The flux amplitude part of `undisturbed` alone: its recent peak deviation is
    /// below [`MAX_FLUX_SQ_PEAK`] of its mean. A DC offset in the flux estimate (a DC
    /// step being removed) trips it; a speed change, which leaves the amplitude alone,
    /// does not: so it gates the FLL's bound on the PLL-tuned notch (in the estimator).
    pub flux_undisturbed: bool,
}

/// The FLL. See the module documentation.
#[derive(Clone, Debug)]
pub struct Fll<T> {
    gain: T,
    start: T,
    floor: T,
    ref_flux_sq: T,
    inv_ref_flux_sq: T,
    tolerance: T,
    settled_weight: T,
    /// Rate of the settle detector's filter relative to the trackers' rate.
    settle_rate: T,
    /// [`DIRECTION_SHARE_GAIN`] while steering, 1 otherwise ([`Fll::set_steering`]).
    direction_share_gain: T,
    /// [`DIRECTION_SHARE_GAIN`].
    steering_share_gain: T,
    omega: T,
    notch: T,
    /// Filtered disagreement `| |omega| - notch |` (rad/s).
    disagreement: T,
    /// Filtered measurement weight (dimensionless, 0..1).
    weight: T,
    /// Rate of the flux-amplitude filters per unit of notch frequency.
    ripple_rate: T,
    /// [`SETTLED_MEAN_SHARE`] (formed once: a conversion is a routine in fixed point).
    settled_mean_share: T,
    /// [`OMEGA_RIPPLE_RATE`].
    omega_ripple_rate: T,
    /// Largest flux-amplitude ripple, relative, for `settled`.
    max_ripple: T,
    /// Filtered `|x1|^2` (Wb^2).
    flux_sq_mean: T,
    /// Filtered `| |x1|^2 - mean |` (Wb^2).
    flux_sq_ripple: T,
    /// Largest ripple of the frequency estimate, relative to the notch frequency, for
    /// `settled`.
    max_omega_ripple: T,
    /// The frequency estimate low-passed at the notch frequency (rad/s).
    omega_mean: T,
    /// Filtered `|omega - omega_mean|` (rad/s).
    omega_ripple: T,
    /// Peak of `| |x1|^2 - mean |` (Wb^2), decaying at the notch frequency.
    flux_sq_peak: T,
    /// Largest `flux_sq_peak` relative to the mean, for `undisturbed`.
    max_flux_sq_peak: T,
    /// The last period (s) and its reciprocal (1/s).
    dt: T,
    inv_dt: T,
    /// Electrical angle travelled while settled (rad), up to `guard`.
    settled_angle: T,
    /// `settle_guard_rad`.
    guard: T,
}

impl<T: Scalar> Fll<T> {
    /// An FLL tuned by `config` (converted with `base`), at its acquisition start.
    pub fn new(config: &FllConfig, base: &Base) -> Result<Self, FllConfigError> {
        if !positive(config.gain_per_omega) {
            return Err(FllConfigError::BadGain);
        }
        if !(positive(config.floor_rad_s)
            && config.start_omega_rad_s.is_finite()
            && config.start_omega_rad_s > config.floor_rad_s)
        {
            return Err(FllConfigError::BadRange);
        }
        if !positive(config.ref_flux_wb) {
            return Err(FllConfigError::BadFlux);
        }
        if !(positive(config.settle_tolerance)
            && config.settle_tolerance < 1.0
            && config.settle_guard_rad.is_finite()
            && config.settle_guard_rad >= 0.0)
        {
            return Err(FllConfigError::BadTolerance);
        }
        let start = base.omega(config.start_omega_rad_s);
        let r: T = base.flux(config.ref_flux_wb);
        let mut fll = Fll {
            gain: T::from_f32(config.gain_per_omega),
            start,
            floor: base.omega(config.floor_rad_s),
            ref_flux_sq: r * r,
            inv_ref_flux_sq: {
                let r_pu = config.ref_flux_wb / base.flux_wb();
                T::from_f32(1.0 / (r_pu * r_pu))
            },
            tolerance: T::from_f32(config.settle_tolerance),
            settled_weight: T::from_f32(0.9),
            settle_rate: T::from_f32(0.25),
            direction_share_gain: T::from_f32(DIRECTION_SHARE_GAIN),
            steering_share_gain: T::from_f32(DIRECTION_SHARE_GAIN),
            omega: T::ZERO,
            notch: start,
            disagreement: start,
            weight: T::ZERO,
            ripple_rate: T::from_f32(0.25),
            settled_mean_share: T::from_f32(SETTLED_MEAN_SHARE),
            omega_ripple_rate: T::from_f32(OMEGA_RIPPLE_RATE),
            max_ripple: T::from_f32(0.3),
            flux_sq_mean: T::ZERO,
            flux_sq_ripple: T::ZERO,
            max_omega_ripple: T::from_f32(MAX_OMEGA_RIPPLE),
            omega_mean: T::ZERO,
            omega_ripple: T::ZERO,
            flux_sq_peak: T::ZERO,
            max_flux_sq_peak: T::from_f32(MAX_FLUX_SQ_PEAK),
            settled_angle: T::ZERO,
            guard: T::from_f32(config.settle_guard_rad),
            dt: T::ZERO,
            inv_dt: T::ZERO,
        };
        fll.reset();
        Ok(fll)
    }

    /// One sample: `flux` is the DCFO's flux estimate `x1` (Wb), `increment` its
    /// integrator's increment over the sample (Wb), `dt` the period (s). Inputs are
    /// assumed valid (the observer has checked them); the state stays bounded.
    pub fn update(&mut self, flux: AlphaBeta<T>, increment: AlphaBeta<T>, dt: T) -> FllOutput<T> {
        let cross = flux.alpha * increment.beta - flux.beta * increment.alpha;
        let mag_sq = flux.alpha * flux.alpha + flux.beta * flux.beta;
        let denominator = mag_sq.max(self.ref_flux_sq);
        // denominator >= ref_flux_sq > 0: the reciprocal exists (None only on a
        // degenerate configuration, read as "no measurement").
        let dtheta = match denominator.recip() {
            Some(inv) => cross * inv,
            None => T::ZERO,
        };
        let weight = (mag_sq * self.inv_ref_flux_sq).min(T::ONE);
        // The period rarely changes: its reciprocal is cached (a division per sample
        // saved).
        if dt != self.dt {
            let Some(inv) = dt.recip() else {
                return self.output();
            };
            self.dt = dt;
            self.inv_dt = inv;
        }
        let inv_dt = self.inv_dt;
        // Tracker rate g (1/s), with g dt <= 1/2 so that any period is stable.
        let g = (self.gain * self.notch).min(T::HALF * inv_dt);
        let omega = self.omega + g * (dtheta - self.omega * dt);
        // The notch's reading: along the signed frequency's direction as far as that
        // frequency has reached a quarter of the notch, |dtheta| otherwise (module docs).
        let along = if self.omega < T::ZERO { -dtheta } else { dtheta };
        let share = match (self.direction_share_gain * self.omega.abs()).checked_div(self.notch) {
            Some(x) => x.min(T::ONE),
            None => T::ZERO,
        };
        // share in [0, 1] (the notch is positive): no saturation check.
        let reading = dtheta.abs() + (along - dtheta.abs()).mul_unit(share);
        let notch = (self.notch + g * (reading - self.notch * dt)).clamp_to(self.floor, self.start);
        // Settle detector: relative disagreement and weight, filtered at g / 4.
        // g dt <= 1/2 (above) and the settle rate is 1/4: rate in [0, 1/8], and the
        // products with it need no saturation check.
        let rate = (g * dt).mul_unit(self.settle_rate);
        let diff = (omega.abs() - notch).abs();
        // Flux-amplitude ripple: an offset c in x1 modulates |x1|^2 at w by 2 c |psi|.
        let slow = self.notch * dt * self.ripple_rate;
        // The mean follows over about three periods (so that a disturbance shows as a
        // deviation from it), the ripple rises within a sixth of a period and decays over
        // two thirds of one.
        // Until the measurement has full weight the mean follows at the fast rate, so
        // that it starts from the flux it sees rather than from zero.
        let mean_rate = if self.weight > self.settled_weight { slow * self.settled_mean_share } else { slow };
        // From a preset or reset (mean zero) the mean starts at the first measurement.
        self.flux_sq_mean = if self.flux_sq_mean == T::ZERO {
            mag_sq
        } else {
            self.flux_sq_mean + mean_rate * (mag_sq - self.flux_sq_mean)
        };
        self.flux_sq_ripple =
            self.flux_sq_ripple + slow * ((mag_sq - self.flux_sq_mean).abs() - self.flux_sq_ripple);
        self.disagreement = self.disagreement + (diff - self.disagreement).mul_unit(rate);
        self.weight = self.weight + (weight - self.weight).mul_unit(rate);
        self.omega = omega.clamp_to(-self.start, self.start);
        // Frequency ripple: a DC error e in the back-EMF reads as a ripple of |e| / |psi|
        // rad/s at w (module docs), filtered like the amplitude ripple.
        let fast = self.notch * dt * self.omega_ripple_rate;
        self.omega_mean = self.omega_mean + fast * (self.omega - self.omega_mean);
        self.omega_ripple =
            self.omega_ripple + fast * ((self.omega - self.omega_mean).abs() - self.omega_ripple);
        // Amplitude peak: an offset c in x1 swings |x1|^2 by 2 c |psi| twice a period,
        // the angle error it causes peaks a quarter period apart; a peak held over about
        // a period's sixth sees it at once.
        let deviation = (mag_sq - self.flux_sq_mean).abs();
        self.flux_sq_peak = deviation.max(self.flux_sq_peak - fast * self.flux_sq_peak);
        self.notch = notch;
        self.settled_angle = if self.steady() {
            (self.settled_angle + self.notch * dt).min(self.guard + self.guard)
        } else {
            T::ZERO
        };
        self.output()
    }

    fn frequency_settled(&self) -> bool {
        self.disagreement < self.tolerance * self.notch && self.weight > self.settled_weight
    }

    fn steady(&self) -> bool {
        self.frequency_settled() && self.flux_sq_ripple < self.max_ripple * self.flux_sq_mean
    }

    fn flux_undisturbed(&self) -> bool {
        self.flux_sq_peak < self.max_flux_sq_peak * self.flux_sq_mean
    }

    fn output(&self) -> FllOutput<T> {
        FllOutput {
            omega_e: self.omega,
            notch_omega: self.notch,
            frequency_settled: self.frequency_settled(),
            settled: self.steady() && self.settled_angle >= self.guard,
            undisturbed: self.omega_ripple < self.max_omega_ripple * self.notch && self.flux_undisturbed(),
            flux_undisturbed: self.flux_undisturbed(),
        }
    }

    /// The notch frequency to use for the next sample (rad/s).
    pub fn notch_omega(&self) -> T {
        self.notch
    }

    /// The frequency estimate low-passed at the notch frequency (rad/s, time constant
    /// `1 / w_n`): what the estimator's PLL takes at the hand-over after a seed by
    /// [`crate::algorithms::arc_fit`], where the estimate's ripple is the observer settling, not
    /// the speed.
    pub fn omega_mean(&self) -> T {
        self.omega_mean
    }

    /// Whether the FLL's notch frequency is what the DCFO's notch is tuned to (`true`,
    /// the default: acquisition, the estimator's `NotchTuning::Fll`) or only a
    /// reference for another loop's (`false`: the PLL steers). While steering, the notch
    /// follows the signed frequency's direction from a quarter of the notch on
    /// ([`DIRECTION_SHARE_GAIN`]), so that noise cannot hold it (and the DCFO's
    /// band-pass) at a multiple of the mover's frequency; otherwise from the notch itself:
    /// over the paper's scenarios at eight event phases the doubled-resistance one takes
    /// 7.9 deg (median) so against 11.1 with the quarter.
    pub fn set_steering(&mut self, steering: bool) {
        self.direction_share_gain = if steering { self.steering_share_gain } else { T::ONE };
    }

    /// The signed frequency estimate (rad/s).
    pub fn omega(&self) -> T {
        self.omega
    }

    /// Sets the estimate to `omega_e` (rad/s), e.g. from an open-loop start-up whose
    /// frequency is known; the notch follows `|omega_e|` (at least the floor).
    pub fn preset(&mut self, omega_e: T) {
        self.omega = omega_e.clamp_to(-self.start, self.start);
        self.notch = omega_e.abs().clamp_to(self.floor, self.start);
        self.disagreement = self.notch;
        self.weight = T::ZERO;
        self.flux_sq_mean = T::ZERO;
        self.flux_sq_ripple = T::ZERO;
        self.omega_mean = self.omega;
        self.omega_ripple = T::ZERO;
        self.flux_sq_peak = T::ZERO;
        self.settled_angle = T::ZERO;
    }

    /// Acquires again from the present frequency estimate: the settle detector starts
    /// over (unsettled), the trackers keep their state.
    pub fn restart_acquisition(&mut self) {
        self.disagreement = self.notch;
        self.weight = T::ZERO;
        self.flux_sq_ripple = self.flux_sq_mean;
        self.omega_ripple = self.notch;
        self.flux_sq_peak = self.flux_sq_mean;
        self.settled_angle = T::ZERO;
    }

    /// Back to the acquisition start: frequency unknown, notch at the top of the sweep.
    pub fn reset(&mut self) {
        self.omega = T::ZERO;
        self.notch = self.start;
        self.disagreement = self.start;
        self.weight = T::ZERO;
        self.flux_sq_mean = T::ZERO;
        self.flux_sq_ripple = T::ZERO;
        self.omega_mean = T::ZERO;
        self.omega_ripple = T::ZERO;
        self.flux_sq_peak = T::ZERO;
        self.settled_angle = T::ZERO;
    }
}
