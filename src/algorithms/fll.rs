//! Frequency-locked loop (FLL): the electrical frequency from the flux vector's
//! rotation, independent of the DCFO's notch tuning. It tunes the notch, feeds the PLL
//! forward, and finds a moving mover from a cold start.
//!
//! ## The discriminator
//! From the DCFO's band-pass output `x1 = D psi` (its flux estimate) and the increment
//! `dpsi_i` of its integrator (the back-EMF `e dt` plus the observer's DC correction):
//!
//! ```text
//! dtheta = Im(conj(x1) dpsi_i) / max(|x1|^2, psi_ref^2)    (rad per sample)
//! ```
//!
//! For any notch `w_n > 0`, `D(jw) = 1 / (1 + jX)` has `Re D = |D|^2`, so
//! `Im(conj(D psi) j w psi) = w |x1|^2`: while `|x1| >= psi_ref`, `dtheta / dt` is
//! exactly `w` (rad/s) in either direction, whatever the notch error (the phase it puts
//! on `x1`, see [`crate::algorithms::observer::Dcfo`], cancels). Sampling adds a relative
//! error up to `(|w| dt / 2) |tan phi|`, `phi` the band-pass phase: none once the notch
//! is on. Below `psi_ref` the `max` weights a measurement down: a weak or absent flux
//! reads as "no rotation", so the notch sweeps *down*.
//!
//! What biases it: `dtheta / dt` is `e_q / |psi|`, so any back-EMF error along q reads as
//! speed. A DC offset `dc` (V) ripples it at `w` by `|dc| / |psi|` rad/s while the DCFO
//! removes the offset; a resistance error `dR` (ohm) biases it by `dR i_q / psi_f` rad/s.
//! The PLL on `x1` has neither, so in the estimator (`NotchTuning::AcquireWithFll`) the
//! FLL acquires and takes over in speed transients, and the PLL holds the steady state.
//!
//! ## The loop
//! Two first-order trackers at the rate `g = gain_per_omega * w_n` (1/s, capped at
//! `g dt = 1/2` so that every period is stable), the same shape at every speed:
//!
//! ```text
//! omega    += g (dtheta - omega dt)          signed frequency (rad/s)
//! omega_n  += g (r - omega_n dt)             notch frequency, in [floor, start] (rad/s)
//! r         = |dtheta| + m (s dtheta - |dtheta|),  s = sign(omega),  m = min(c |omega| / omega_n, 1)
//! ```
//!
//! The notch reads the rotation along the direction found (`s dtheta`, linear in the
//! noise) once `|omega|` is a `1 / c` share of the notch (`c` = [`DIRECTION_SHARE_GAIN`]),
//! and `|dtheta|` before that (from reset, through a reversal), blended so that f32 and
//! fixed point have no threshold to part at. `|dtheta|` alone is biased at low speed,
//! where the sensors' noise through `Ls di` is comparable to the rotation per sample:
//! the mean of `|x + n|` exceeds `|x|` (by 17 % for noise the size of the rotation), and
//! a notch above the mover makes the DCFO's angle lag. The notch must also follow fast
//! (`gain_per_omega = 4`): on the instantaneous frequency the SOGI passes a
//! constant-amplitude flux of *any* frequency trajectory exactly, so the DCFO's transient
//! angle error is the notch's error `dw` through `dw / (zeta w)`, and a tracker lags a
//! ramp of `a` (rad/s^2) by `a / g` (rad/s).
//!
//! ## Noise: where the notch can stay above the mover
//! If noise makes the mean of `|dtheta|` `rho` times the rotation, the notch has a second
//! equilibrium (`m < 1`) at a root of `omega_n^2 - rho |w| omega_n + c (rho - 1) w^2`,
//! real when `rho^2 >= 4 c (rho - 1)`. With `c = 1` that is any `rho`: from `rho > 2` the
//! sweep from above meets the root `(rho - 1) |w|` first, and a notch held there
//! attenuates the flux, which raises the noise further. With `c = 4` the root needs
//! `rho >= 8 + 4 sqrt(3) = 14.9`. `c = 4` applies while the FLL steers the DCFO's notch
//! ([`Fll::set_steering`]); once the PLL steers, `c = 1` holds a doubled resistance better.
//!
//! ## Acquisition: start high, sweep down
//! From reset the notch starts at `start_omega_rad_s`, above any speed the motor reaches,
//! where the band-pass soon forgets the integrator's unknown initial flux and passes any
//! slower flux's rotation intact. With no usable flux it sweeps down as
//! `d w_n / dt = -gain w_n^2`, reaching `w` after about `1 / (2 pi gain)` electrical
//! periods; with a flux it converges on `|w|` at `g`. No search logic: the same update.
//!
//! ## Settled and undisturbed
//! [`FllOutput::frequency_settled`]: full-weight measurements, `|omega|` and the notch
//! within [`FllConfig::settle_tolerance`]. [`FllOutput::settled`] adds a steady flux
//! amplitude (an offset `c` in `x1` swings `|x1|^2` by `2 c |psi|`; its mean deviation
//! must stay below 0.3 of the mean, `c` under about `0.24 |psi|`, 14 deg), held for
//! [`FllConfig::settle_guard_rad`] of electrical angle (15 rad by default, four time
//! constants of the DCFO's slowest pole) so that a decaying acquisition transient is not
//! taken for a lock. [`FllOutput::undisturbed`], which the estimator's `locked` flag
//! requires, sees a DC step while it is being removed, with two detectors filtered at
//! `w_n` (a sixth of a period): the frequency's ripple within [`MAX_OMEGA_RIPPLE`] (a DC
//! error of about a tenth of the back-EMF), and the held peak of `|x1|^2`'s deviation
//! within [`MAX_FLUX_SQ_PEAK`] (an offset of about `0.1 |psi|`, 6 deg, seen within a
//! quarter period in any direction). A real speed change trips it too, so the notch's
//! tuning does not wait on it.
//!
//! ## Accuracy and cost
//! `tests/fll.rs` checks the discriminator through a mistuned notch in either direction,
//! the sweep without a flux, and the notch under noise of one, five and ten times the
//! rotation; `dcfo acquire` and `dcfo paper` measure what it gives the estimator. Its
//! cost is part of the estimator's step, printed by `bench_qemu` (`docs/cost-budget.md`).

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
        // A rotation along the direction found reads `|dtheta|` whatever the share: the
        // share's division is formed only for one against it (noise, a reversal).
        let rotation = dtheta.abs();
        let reading = if along >= rotation {
            rotation
        } else {
            let share = match (self.direction_share_gain * self.omega.abs()).checked_div(self.notch) {
                Some(x) => x.min(T::ONE),
                None => T::ZERO,
            };
            // share in [0, 1] (the notch is positive): no saturation check.
            rotation + (along - rotation).mul_unit(share)
        };
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
