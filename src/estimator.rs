//! The sensorless estimator: a flux observer, the PLL and (for the DCFO) the FLL, composed
//! as the drive runs them every control period and as trace replay runs them on recorded
//! data. Having the composition in one place is what makes a replayed trace reproduce a
//! closed-loop run's estimates bit for bit.
//!
//! Per sample the observer takes the voltage applied during the period that just ended
//! and the currents sampled now; its flux estimate feeds the PLL (angle and speed) and
//! the FLL of [`crate::algorithms::fll`] (the frequency from the flux's rotation); one of
//! the two tunes the DCFO's notch for the *next* sample. The method and its notation are
//! in `docs/method.md`; why each part below exists, what it costs, and the alternatives
//! measured against it are in `docs/estimator-design.md`.
//!
//! ## Who tunes the notch ([`NotchTuning`], default `AcquireWithFll`)
//! ```text
//!            reset / reacquire()
//!                   |
//!                   v
//!   FLL steers: notch = FLL, PLL fed forward with the FLL's frequency  <---------+
//!      |  PLL locked, FLL frequency settled, above 1.5 notch floors (and,         |
//!      |  after zero speed, not accelerating): PLL integrator := FLL frequency     |
//!      v                                                     FLL below 1.25 notch |
//!                                                            floors --------------+
//!   PLL steers: notch = PLL integrator (the paper's loop, see crate::algorithms::pll)
//!               + its lag on the ramp the drive commands (set_commanded_acceleration),
//!               the integrator held within zeta * NOTCH_PHASE_BUDGET_RAD (7 %) of a
//!               settled FLL's frequency (20 % while only its frequency has settled),
//!               while the flux amplitude is undisturbed, as far as no DC
//!               offset is read in the flux (the FLL's trust, below)
//! ```
//! - **The FLL** reads the frequency whatever the notch's tuning, so it finds a moving
//!   mover from the zero state (the paper's loop, its notch at the floor, never pulls in
//!   above about 20 Hz) and follows speed changes the PLL's slow integrator lags. Back-EMF
//!   errors along q bias it (a wrong `Rs` under load; a DC step, while the observer
//!   settles, as a ripple at `w`), which the PLL is not. So the PLL keeps the steady
//!   state, and the FLL bounds how far the PLL's integrator may stray from it: the excess
//!   over the band is taken out at the FLL's own rate `4 w`, continuously in the
//!   disagreement (no threshold for f32 and Q8.24 to part at) and never in one step (the
//!   integrator is the speed estimate).
//!
//! ## Through zero speed
//! The flux turns too slowly for the PLL's integrator to follow a reversal. Below
//! [`ZERO_SPEED_PER_NOTCH_FLOOR`] notch floors the FLL takes the notch again and feeds
//! the PLL forward (its integrator cleared, so the PLL's frequency does not jump), as
//! while acquiring but without the circle fit (a mover passing through zero speed draws
//! no circle) and without [`Estimate::acquiring`] (the frequency is known). The PLL
//! takes the notch back above [`HANDOVER_PER_NOTCH_FLOOR`] notch floors once the FLL's
//! reading agrees with its mean (the mover no longer accelerates).
//!
//! ## Phase compensation of the angle output
//! This and the next section's correction are open paths: the PLL, the FLL, the notch
//! and the flags see the uncorrected flux, and each is armed in proportion to the
//! travel with [`Estimate::locked`] set since the PLL took the notch
//! ([`COMPENSATION_ARM_RAD`]).
//!
//! A notch off by `dw` turns the observer's phase by `dw / (zeta w)` (`docs/method.md`
//! §8). The PLL's full frequency `omega_hat = integral + kp eps` follows an uncommanded
//! speed change (a load step) that the integrator, and so the notch, lags; `(w_notch -
//! omega_hat) / (zeta |w_notch|)` estimates the phase, and the angle output is turned
//! back by it. It cannot tune the notch or drive the PLL: that closes the loop the
//! [`crate::algorithms::pll`] docs show unstable (`c kp = 8 > 1`). Since it is `c kp`
//! times the PLL's error, it is applied only as far as the FLL's frequency confirms the
//! notch is off the same way ([`COMPENSATION_FLL_SHARE`], scaled by the FLL's trust,
//! below), with its ripple at `w` notched out ([`COMPENSATION_NOTCH_DAMPING`]), less a
//! dead band, within a limit, faded in over a period of tracking and out over a quarter
//! period when tracking stops.
//!
//! ## The DC offset's angle
//! A DC step in the observer's inputs leaves an offset `delta` in the flux estimate,
//! which the DCFO removes through its slowest pole (`0.26 w`); meanwhile the angle is
//! off by the offset's part across the flux. The same offset shows at once in the
//! estimate's magnitude: with `delta_dq = delta e^{-j theta}`, `|psi_hat| = psi_f +
//! Re(delta_dq)` to first order and `d Re(delta_dq) / dt = w Im(delta_dq)`, so the
//! angle error is the magnitude's rate over `w |psi_hat|`, which a mover turning
//! steadily does not have. Three uses:
//! - the angle output is turned back by [`OFFSET_PHASE_SHARE`] of that reading
//!   (band-passed at `w`, less [`OFFSET_PHASE_DEADBAND_RAD`], within
//!   [`OFFSET_PHASE_LIMIT_RAD`]);
//! - the DCFO feeds the magnitude's deviation back along the flux
//!   ([`crate::algorithms::observer::Dcfo::set_magnitude_feedback`]): what is radial
//!   now was across the flux a quarter period ago;
//! - the FLL is trusted as far as the reading's held peak stays within
//!   [`FLL_TRUST_OFFSET_RAD`] (or [`FLL_TRUST_LEVEL_MULTIPLE`] times its own recent
//!   level), not at all as much again beyond: the trust scales the FLL's band and its
//!   confirmation of the compensation, because a DC step ripples the FLL's reading at
//!   `w` by about the offset's share of the flux, which would drag the notch and
//!   confirm a wrong compensation.
//!
//! A speed change the drive did not command (a replayed recording, a load) also swings
//! the flux magnitude: the notch lags the mover and the band-pass passes it off its
//! centre. The reading cannot tell that from an offset within the quarter period that
//! matters, but the thrust can: a mover changes speed only under a change of force, and
//! a DC error in the inputs moves the FLL's reading without moving the thrust current
//! (the drive's speed loop, answering the ripple it reads, pushes the current *against*
//! it). So the trust is also the share [`THRUST_CHANGE_PER_RATED_CURRENT`] of the rated
//! current that the thrust current `(psi x i) / psi_f` has changed by over about a
//! period (a low-pass at [`THRUST_FAST_RATE_PER_RAD`] less one at
//! [`THRUST_SLOW_RATE_PER_RAD`] of the travel), counted only the way the FLL's frequency
//! departs from the PLL's integrator (a speed-up with a thrust towards the motion, a
//! slow-down with one against it), whichever of the two trusts more.
//!
//! For a salient motor the readings first take out the active flux's `(Ld - Lq) i_d`
//! (`(Ld - Lq) d(i . psi)` to first order), or a current ripple would read as an
//! offset.
//!
//! ## Cold starts: the circle fit ([`crate::algorithms::arc_fit`])
//! From reset and on [`Estimator::reacquire`] the integrated back-EMF's arc is fitted
//! with a circle through the start; about a third of a period later the fit gives the
//! mover flux's angle and frequency and the DC error in the inputs (the circle's
//! centre), and the estimator seeds itself with them as a drive seeds it after an
//! open-loop segment: the observer on the flux with its disturbance estimate holding the
//! DC error, the FLL on the frequency, the PLL on the angle; the flags are earned again.
//! Without it the DCFO removes the integrator's unknown initial flux, an offset as large
//! as the flux, through its slowest pole. After a seed the hand-over to the PLL takes
//! the FLL's mean frequency, not its reading, which ripples while the observer takes on
//! the DC state the seed left out. An explicit [`Estimator::seed`] stops the fit;
//! [`Estimator::fitting`] tells when it is over.
//!
//! ## Two flags
//! - [`Estimate::tracking`]: the PLL is locked and, with an FLL, both frequencies agree.
//!   What a drive may close its loops on (the hand-over from I/f, the lock supervision).
//! - [`Estimate::locked`]: what a user may trust the angle by, within [`LOCK_ANGLE_RAD`]
//!   (the replay trace's `locked` column). `tracking`, and:
//!   - the FLL [settled](crate::algorithms::fll::FllOutput::settled) and
//!     [undisturbed](crate::algorithms::fll::FllOutput::undisturbed): the flux steady,
//!     for the DCFO's settling time;
//!   - the observer's DC estimate quiet: the increment of the disturbance estimate `d`,
//!     low-passed at the notch frequency, below [`MAX_DISTURBANCE_DRIFT`] of the
//!     back-EMF `w |psi| dt`. After a DC step both loops agree on a wrong angle while the
//!     observer moves its DC state, and the drift of `d` is that uncancelled voltage
//!     itself; a mistuned notch's leak passes the filter too (`tests/lock_flag.rs`);
//!   - a quarter period ([`CALM_ANGLE_RAD`]) since any of those checks last failed;
//!   - a resistance error up to [`EstimatorConfig::resistance_uncertainty_ohm`] unable
//!     to turn the angle beyond [`LOCK_ANGLE_RAD`] at the present current, speed and
//!     flux: the flag is down while a large current lies along the flux at low speed (an
//!     I/f start, a low-speed mode), where the other checks pass with the angle far off.
//!
//!   The observers without an FLL (the pure integrator, the CFO, the paper's plain
//!   DCFO) have only the PLL's lock and this check, and one more, for a quarter period:
//!   the errors the estimator can bound add up to less than [`LOCK_ANGLE_RAD`]. They are
//!   an offset in the flux estimate (a DC error the observer integrated, a drift), read
//!   from the swing of `|psi|^2` about its mean as the flux turns; the CFO's own phase
//!   lead `atan(w_c / w)`; the PLL's phase error; and the resistance's, as above. On the
//!   paper's 10 Hz the CFO's lead alone is 14 deg, so it is vouched for at higher speeds
//!   only.
//!
//! ## Accuracy and cost
//! The figures are the tools' own and are not restated here: `dcfo paper` (the paper's
//! scenarios), `dcfo acquire` (cold starts), `dcfo track` (reversals and sharp speed
//! steps, with the known limit: on a low-resistance motor a wide speed step through a
//! 20 ms prefilter still costs more than the 8 degrees asked) and `bench_qemu`
//! (instructions per period, `results/cost.md`).
//! Q8.24 follows f32 on the same inputs within the bounds `tests/` assert.

use crate::algorithms::arc_fit::{ArcFit, ArcFitOutcome};
use crate::algorithms::fll::{Fll, FllConfig, FllConfigError};
use crate::algorithms::observer::{
    AnyObserver, Dcfo, DcfoConfig, DcfoConfigError, FluxEstimate, FluxObserver, LpfConfigError, LpfObserver,
    ObserverFault, ObserverInput, ObserverKind, ObserverMotor, PureIntegrator,
};
use crate::algorithms::pll::{Pll, PllConfig, PllConfigError, PllFault, PllOutput};
use crate::algorithms::transforms::{AlphaBeta, CosSin};
use crate::motor::MotorParams;
use crate::num::units::Base;
use crate::num::{Angle, Scalar};

/// Largest drift of the observer's disturbance estimate, relative to the back-EMF
/// `w |psi|` (dimensionless), for [`Estimate::locked`]: an uncancelled DC voltage of a
/// twentieth of the back-EMF (module docs). 0.1 left 147 samples of the paper's +2 V
/// step locked above 15 deg (one event phase of eight), 0.05 none.
pub const MAX_DISTURBANCE_DRIFT: f32 = 0.05;

/// Largest phase error (rad) the PLL-tuned notch's mistuning may cost the DCFO while
/// a settled FLL reads the frequency: the notch is kept within `zeta` times this of the
/// FLL's frequency (a notch off by `dw` turns the phase by `dw / (zeta w)`; module docs).
/// 0.07 rad (4 deg) measured best over the paper's scenarios at eight event phases
/// each (with the band's correction applied in one step): a wider band lets the PLL lag
/// a load step longer (0.1: 11.6 deg median, 0.15: 15.5), a narrower one lets the FLL's
/// ripple under a DC current offset into the notch (0.05: +0.2 A step 11.8 deg, steady
/// 1.75 deg).
pub const NOTCH_PHASE_BUDGET_RAD: f32 = 0.07;

/// Frequency, in notch floors (dimensionless), below which the FLL tunes the notch and
/// feeds the PLL forward again (module docs, "Through zero speed"): there the flux turns
/// too slowly for the PLL's integrator to follow a reversal, while the FLL reads the
/// rotation whatever its rate and direction.
pub const ZERO_SPEED_PER_NOTCH_FLOOR: f32 = 1.25;

/// Frequency, in notch floors (dimensionless), above which the PLL may take the notch
/// back: above [`ZERO_SPEED_PER_NOTCH_FLOOR`], so that a mover near that speed does not
/// hand the notch to and fro, and below the lowest speed a cold start is asked to lock
/// at (`dcfo acquire`: 0.1 m/s on the paper motor, 1.7 notch floors).
pub const HANDOVER_PER_NOTCH_FLOOR: f32 = 1.5;

/// Rate at which the PLL's integrator is brought back into the FLL's band, per rad/s of
/// the frequency (dimensionless): the FLL's own tracker rate `4 w` (`crate::algorithms::fll`).
pub const CORRECTION_RATE_PER_OMEGA: f32 = 4.0;

/// Part of the notch's phase error the angle output leaves uncompensated (rad; module
/// docs, "Phase compensation"). The compensation is `c kp = 8` times the PLL's phase
/// error, whose steady ripple (0.2-0.25 deg at 0.3 m/s: end-effect thrust ripple,
/// harmonics) it would turn into 1.6-2 deg of angle noise; 0.03 rad leaves that alone.
/// Measured over the paper scenarios at eight event phases each (closed loop, without
/// the FLL check): 0.01 let the speed step reach 7.9 deg, 0.045 let the load step back
/// to 8.4 deg median.
pub const NOTCH_PHASE_DEADBAND_RAD: f32 = 0.03;

/// Largest phase compensation applied to the angle output (rad): 17 deg, above the
/// largest notch phase error the band about the FLL lets through in the paper's load
/// step (12 deg) and below where the first-order phase `dw / (zeta w)` stops holding.
pub const NOTCH_PHASE_COMPENSATION_LIMIT_RAD: f32 = 0.3;

/// Share of the PLL's reading of the notch's phase error that the FLL's reading must
/// show, the same way, for the full compensation (dimensionless; below it the
/// compensation shrinks in proportion, module docs). The FLL lags a fast speed change,
/// so it confirms rather than measures. Measured over the paper scenarios at eight
/// event phases and `dcfo faults`: without the check a 65 % bus sag rode through with
/// 5.7 deg (3.9 without compensation), with a share of 1/2 the load step reached
/// 7.9 deg median (8.1 at the defined instant) and corrupted link frames 5.8 deg;
/// 1/4 keeps every ride-through within its 5 deg and the load step at 7.0.
pub const COMPENSATION_FLL_SHARE: f32 = 0.25;

/// Electrical angle over which the compensation fades in while the estimate tracks
/// (rad): one period. What is applied is that share times the share armed
/// ([`COMPENSATION_ARM_RAD`]).
pub const COMPENSATION_FADE_RAD: f32 = 2.0 * core::f32::consts::PI;

/// Electrical angle (rad) of travel with [`Estimate::locked`] set over which the
/// compensation is armed, in proportion: one period. It is not armed at once by the
/// first locked sample: a flag set for one sample in Q8.24 and not in f32 on the same
/// inputs (the paper's doubled-resistance scenario, 0.2 s before f32 locks) lets the
/// compensation fade in for one of them only, 2.1 deg apart. Nor once the flag has held
/// a quarter period (set in all, or without a break): the two still part where the flag
/// flickers (1.2 and 2.6 deg at 3.3 Hz on the salient example motor). In proportion, a
/// sample's flag moves the compensation by `w dt / 2 pi` of itself.
pub const COMPENSATION_ARM_RAD: f32 = 2.0 * core::f32::consts::PI;

/// Electrical angle over which the compensation fades out once the estimate stops
/// tracking (rad): a quarter period. It does not drop out at once: a tracking flag that
/// flips for one sample in Q8.24 and not in f32 on the same inputs (the paper's +2 V
/// step) would put the two 14 deg apart for that sample.
pub const COMPENSATION_FADE_OUT_RAD: f32 = 0.5 * core::f32::consts::PI;

/// Damping of the notch at the fundamental in the phase compensation (dimensionless):
/// narrow (0.3), so that the compensation of a speed change (its spectrum below `w`)
/// passes while the PLL error's ripple at `w` that a DC offset in the flux estimate causes
/// is taken out. Measured in replay of the paper scenarios (without the FLL check): 0.7 and
/// 1.5 delayed the compensation of the load step (7.6 and 8.5 deg median against 6.5).
pub const COMPENSATION_NOTCH_DAMPING: f32 = 0.3;

/// Share of the DC offset's angle, read from the rate of the flux magnitude, that the
/// angle output is turned back by (dimensionless; module docs, "The DC offset's angle").
/// In the linear model (`docs/dc_step_analysis.py`, section 5) 0.7 and 1.0 give 6.2 and
/// 6.9 deg on the +2 V step; in the closed-loop drive (the paper scenarios at eight event
/// phases each, measured without the band-pass and the arming, dead band 0.02) 1.0 lets
/// it reach 23.9 deg at one phase (12.3 median), 0.7 keeps it at 14.5 (10.9).
pub const OFFSET_PHASE_SHARE: f32 = 0.7;

/// Part of the DC offset's angle reading left uncorrected (rad): the rate of the flux
/// magnitude also carries the inverter's harmonics and the sensors' noise, which the
/// reading turns into angle noise, most at low speed. Without the band-pass, 0.02 kept
/// 12 of the 48 cold starts at 0.1 m/s from locking within their budget (`dcfo acquire`,
/// paper motor) and 0.04 none. With it, 0.015 and 0.03 keep none over; Q8.24 0.84 and
/// 0.67 deg off f32 there, the +2 V step 12.0 and 12.5 deg median over eight phases.
pub const OFFSET_PHASE_DEADBAND_RAD: f32 = 0.03;

/// Largest DC offset's angle correction (rad): that of an offset of 0.3 of the flux.
pub const OFFSET_PHASE_LIMIT_RAD: f32 = 0.3;

/// Damping of the band-pass at the fundamental that the magnitude's rate is read
/// through (dimensionless): a DC offset's signature is a ripple at `w`, the inverter's
/// harmonics ripple the magnitude at `6 w` (passed at 0.32). In the linear model the
/// band-pass costs the +2 V step nothing (6.3 deg at the worst phase with and without).
pub const OFFSET_BANDPASS_DAMPING: f32 = 1.0;

/// The DC offset's angle reading (rad, its band-passed value's recent peak) up to which
/// the FLL's frequency is trusted in full, for the notch's band and the phase
/// compensation's confirmation, on a drive whose reading is quiet; the trust falls
/// linearly to zero over as much again, at the reading's dead band
/// [`OFFSET_PHASE_DEADBAND_RAD`] (module docs, "The DC offset's angle"). Over the
/// paper's scenarios at eight event phases each (median / max), 0.01, 0.015 and 0.02
/// gave the +2 V step 9.2 / 10.3, 9.5 / 10.4 and 10.3 / 12.8 deg, the 40 N load step
/// 5.7 / 5.7 each; 0.03 gave 11.2 / 13.2.
pub const FLL_TRUST_OFFSET_RAD: f32 = 0.5 * OFFSET_PHASE_DEADBAND_RAD;

/// Multiple of the offset reading's own recent level (the mean of its magnitude over
/// about eight periods, [`OFFSET_READING_MEAN_RATE_PER_RAD`]) above which the FLL's trust
/// starts to fall, where that is above [`FLL_TRUST_OFFSET_RAD`] (dimensionless): a DC
/// step raises the reading above where it was, a drive whose speed keeps swinging
/// reads that swing all the time. On the paper motor without payload
/// (`scenarios/bare-mover.toml`: its speed loop rings through the 0.4 -> 0.8 m/s step,
/// and the flux magnitude with it) the drive keeps 5.6 deg with the trust from the level
/// (2 and 3 alike, as without any trust), 15.5 with the fixed limit alone.
pub const FLL_TRUST_LEVEL_MULTIPLE: f32 = 2.0;

/// Change of the thrust current, relative to the motor's rated current
/// (dimensionless), at which the FLL is trusted in full whatever the offset reading,
/// when it goes the way the FLL's frequency departs from the PLL's (module docs, "The DC
/// offset's angle"). Measured with `dcfo track` (sharp / wide step, paper motor and
/// `motors/low_r.toml`) and `paper_phases` (+2 V and +0.2 A, median / worst of eight
/// event phases): 0.2 gave 7.1 / 7.0 and 8.7 / 23.6 deg, +0.2 A 4.7 / **7.0**; 0.3 gave
/// 7.2 / 7.0 and 10.1 / 23.6, +2 V 9.5 / 10.5, +0.2 A 4.7 / 5.3; 0.4 gave 7.6 / 7.0 and
/// 11.1 / 23.6 (as without: 11.6 / 21.0 and 26.2 / 36.3, +2 V 9.5 / 10.5, +0.2 A
/// 4.8 / 5.8). Counted in either direction instead, 0.2 gave the +2 V step 10.4 / 12.0
/// and 0.4 9.7 / 11.0: the speed loop's answer to the offset's ripple is a thrust change
/// too.
pub const THRUST_CHANGE_PER_RATED_CURRENT: f32 = 0.3;

/// Rate of the thrust current's fast low-pass per radian of electrical travel (1/rad):
/// a time constant of a third of a period.
pub const THRUST_FAST_RATE_PER_RAD: f32 = 0.5;

/// Rate of the thrust current's slow low-pass per radian of electrical travel (1/rad):
/// about 1.3 periods. The difference of the two is the thrust's change over about a
/// period, with a DC current offset's ripple at `w` taken down to a third.
pub const THRUST_SLOW_RATE_PER_RAD: f32 = 0.125;

/// Rate of the offset reading's mean magnitude per radian of electrical travel
/// (dimensionless): about eight periods. 0.05 moved the +0.2 A step's median over eight
/// event phases 4.7 -> 4.8 deg and its worst 5.3 -> 5.6.
pub const OFFSET_READING_MEAN_RATE_PER_RAD: f32 = 0.02;

/// Decay of the offset reading's held peak per radian of electrical travel
/// (dimensionless): the band-passed reading of an offset crosses zero twice a period,
/// and a hold decaying at half the fundamental keeps 0.46 of a peak over the quarter
/// period to the next. 0.25 and 1.0 gave the +2 V step 9.5 / 10.4 and 9.9 / 12.2 deg
/// (median / max over eight event phases).
pub const OFFSET_PEAK_DECAY_PER_RAD: f32 = 0.5;

/// One sample of a band-pass at the fundamental (a SOGI, semi-implicit Euler, stable for
/// `h = w dt < 2`): `(output, quadrature)` after `input`, with gain `k` (twice the
/// damping), both states held within `+-limit` (rad).
fn band_pass_step<T: Scalar>((bp, q): (T, T), input: T, k: T, h: T, limit: T) -> (T, T) {
    let bp = (bp + h * (k * (input - bp) - q)).clamp_to(-limit, limit);
    let q = (q + h * bp).clamp_to(-limit, limit);
    (bp, q)
}

/// `|v|` within 12 % (`max + min / 2`, no square root): for thresholds.
fn approx_norm<T: Scalar>(v: AlphaBeta<T>) -> T {
    let (a, b) = (v.alpha.abs(), v.beta.abs());
    a.max(b) + a.min(b).mul_unit(T::HALF)
}

/// How long no disturbance check may have failed before [`Estimate::locked`] is set
/// again, electrical angle (rad): a quarter period.
pub const CALM_ANGLE_RAD: f32 = core::f32::consts::FRAC_PI_2;

/// Estimator settings, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EstimatorConfig {
    /// Which flux observer.
    pub observer: ObserverKind,
    /// DCFO tuning (used when `observer` is [`ObserverKind::Dcfo`]).
    pub dcfo: DcfoConfig,
    /// CFO low-pass cut-off (rad/s; used when `observer` is [`ObserverKind::Cfo`]).
    pub cfo_cutoff_rad_s: f32,
    /// PLL tuning.
    pub pll: PllConfig,
    /// What tunes the DCFO's notch (see the module docs).
    pub notch_tuning: NotchTuning,
    /// The frequency-locked loop (used by the DCFO unless `notch_tuning` is
    /// [`NotchTuning::Pll`]).
    pub fll: FllConfig,
    /// How far the motor's resistance, as the observer sees it, may be from the motor
    /// file's (ohm): what [`Estimate::locked`] allows for (see [`LOCK_ANGLE_RAD`]).
    pub resistance_uncertainty_ohm: f32,
}

/// The angle error [`Estimate::locked`] vouches for (rad): 15 deg.
///
/// A resistance error `dR` reads as a voltage `dR i` the observer integrates: a flux
/// error `dR i / (j w)`, whose part across the flux turns the angle by
/// `atan(dR i_d / (w psi_f))`. With the estimate within this angle of the flux,
/// `|i_d| <= |i_d_hat| + |i| sin(LOCK_ANGLE_RAD)`, so the flag requires
/// `dR (|i_d_hat| + |i| sin(LOCK_ANGLE_RAD)) <= tan(LOCK_ANGLE_RAD) |w_hat| psi_f`
/// (the motor file's flux: a flux estimate the error inflates does not loosen it),
/// the left side held at its peak and let decay at [`LOCK_ERROR_DECAY_PER_RAD`]: the
/// flux error a voltage error left behind outlasts it (at the hand-over from an I/f
/// start, 16 deg for 7 ms after the current left d on `motors/low_r.toml`).
/// The flag thus
/// drops while a large current lies along the flux at low speed (an I/f start, the
/// low-speed mode) and wherever the resistance could turn the angle this far.
pub const LOCK_ANGLE_RAD: f32 = 15.0 * core::f32::consts::PI / 180.0;

/// `sin(`[`LOCK_ANGLE_RAD`]`)` (dimensionless; a constant, so that fixed point folds it).
pub const LOCK_ANGLE_SIN: f32 = 0.258_819_04;

/// `tan(`[`LOCK_ANGLE_RAD`]`)` (dimensionless).
pub const LOCK_ANGLE_TAN: f32 = 0.267_949_2;

/// [`EstimatorConfig::resistance_uncertainty_ohm`] per ohm of the motor file's
/// resistance (dimensionless): the flag vouches for a resistance up to twice the file's. A
/// copper winding gains 39 % from 20 to 120 deg C, and a motor file leaves out the leads
/// and the inverter's on-state slope resistance (on `motors/low_r.toml` with the
/// simulated inverter's 0.12 ohm, 40 % of the file's 0.3 ohm before any heating).
pub const RESISTANCE_UNCERTAINTY_SHARE: f32 = 1.0;

/// How fast the held voltage error of [`LOCK_ANGLE_RAD`]'s check decays, per radian of
/// electrical travel (dimensionless): the DCFO's slowest pole at its default tuning,
/// `0.26 w` ([`Dcfo`]), rounded down.
pub const LOCK_ERROR_DECAY_PER_RAD: f32 = 0.25;

/// Rate of the mean of `|psi|^2` that the lock flag of the observers without an FLL
/// measures the flux's steadiness against, and decay of the held peak of the deviation
/// from it, per radian of electrical travel (dimensionless; an eighth, formed exactly
/// from halves in every arithmetic). The mean follows over about 1.3 periods, so that an
/// offset's ripple at the fundamental leaks into it by an eighth. An offset's deviation
/// peaks where the offset lies along the flux and vanishes where it lies across, where it
/// turns the angle most, a quarter period later: by then the hold keeps `exp(-pi / 16)`,
/// 0.82, of the peak, which the check allows for.
pub const FLUX_SQ_RATE_PER_RAD: f32 = 0.125;

/// `exp(-FLUX_SQ_RATE_PER_RAD pi / 2)` (dimensionless): the share of a peak of `|psi|^2`'s
/// deviation the hold keeps a quarter period on ([`FLUX_SQ_RATE_PER_RAD`]).
pub const FLUX_SQ_HOLD_AT_QUARTER: f32 = 0.821_725;

/// What tunes the DCFO's notch frequency (and feeds the PLL forward).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NotchTuning {
    /// The PLL's frequency integrator, always: the paper's method. From a cold start the
    /// notch sits at its floor and finds a fast mover slowly or never.
    Pll,
    /// The FLL while acquiring (from reset, a seed or [`Estimator::reacquire`]), then the
    /// PLL's frequency integrator once locked, held within a band about the FLL's
    /// frequency (module docs). The default.
    AcquireWithFll,
    /// The FLL, always, with its frequency fed forward to the PLL: the fastest transients
    /// (the 40 N load step: 3.8 deg instead of 27), but a DC step in the observer's input
    /// disturbs it more, and the closed-loop drive oscillates with a plant resistance
    /// twice the motor file's (see [`crate::algorithms::fll`]).
    Fll,
}

impl EstimatorConfig {
    /// Defaults for `motor` with the given observer: [`DcfoConfig::default`],
    /// [`PllConfig::for_flux`], and a CFO cut-off of `2 pi * 2.5 Hz` (15.7 rad/s). The
    /// paper gives no cut-off; this one makes the CFO's phase lead at 10 Hz the 14
    /// degrees of the paper's Fig. 17 (`atan(15.7 / 62.8)`).
    /// [`NotchTuning::AcquireWithFll`] with [`FllConfig::for_motor`] (the motor's rated
    /// phase peak voltage, the DCFO's notch floor).
    pub fn for_motor(motor: &MotorParams, observer: ObserverKind) -> Self {
        let dcfo = DcfoConfig::default();
        EstimatorConfig {
            observer,
            dcfo,
            cfo_cutoff_rad_s: 2.0 * core::f32::consts::PI * 2.5,
            pll: PllConfig::for_flux(motor.psi_f_wb),
            notch_tuning: NotchTuning::AcquireWithFll,
            fll: FllConfig::for_motor(
                motor.psi_f_wb,
                Base::for_motor(motor).voltage_v,
                dcfo.omega_floor_rad_s,
            ),
            resistance_uncertainty_ohm: RESISTANCE_UNCERTAINTY_SHARE * motor.rs_ohm,
        }
    }
}

/// Why an estimator could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EstimatorConfigError {
    /// The DCFO settings were refused.
    Dcfo(DcfoConfigError),
    /// The CFO cut-off was refused.
    Cfo(LpfConfigError),
    /// The PLL settings were refused.
    Pll(PllConfigError),
    /// The FLL settings were refused.
    Fll(FllConfigError),
}

/// Why the estimator refused a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EstimatorFault {
    /// The observer refused the sample.
    Observer(ObserverFault),
    /// The PLL refused the observer's output.
    Pll(PllFault),
}

/// One sample of estimator output, in working units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate<T> {
    /// Estimated electrical angle at this sample.
    pub theta_e: Angle,
    /// Cosine and sine of `theta_e` (dimensionless), from the PLL.
    pub cos_sin: CosSin<T>,
    /// Estimated electrical speed (rad/s).
    pub omega_e: T,
    /// Estimated linear speed (m/s, SI in every unit system).
    pub speed_m_per_s: T,
    /// Estimated mover flux (Wb).
    pub psi_ab: AlphaBeta<T>,
    /// The observer's disturbance estimate (Wb), where it has one.
    pub disturbance_ab: Option<AlphaBeta<T>>,
    /// `true` while the estimate can be trusted to within [`LOCK_ANGLE_RAD`]: the PLL is
    /// locked, for the DCFO with an FLL the FLL agrees, and the resistance allowance
    /// holds (see the module docs, "Two flags").
    pub locked: bool,
    /// `true` while the FLL tunes the notch to find a frequency not yet known (from reset
    /// or [`Estimator::reacquire`], or always with [`NotchTuning::Fll`]); not while it
    /// carries a known frequency through zero speed (module docs).
    pub acquiring: bool,
    /// `true` while the loops track the flux: the PLL is locked and, with an FLL, the
    /// frequencies agree. Weaker than `locked` (it does not wait for the flux estimate
    /// to be steady): what a drive may close its loops on, e.g. out of an open-loop
    /// start whose mover still swings.
    pub tracking: bool,
}

impl<T: Copy> Estimate<T> {
    fn from_parts(
        out: &PllOutput<T>,
        flux: &FluxEstimate<T>,
        locked: bool,
        tracking: bool,
        acquiring: bool,
    ) -> Self {
        Estimate {
            theta_e: out.theta_e,
            cos_sin: out.cos_sin,
            omega_e: out.omega_e,
            speed_m_per_s: out.speed_m_per_s,
            psi_ab: flux.psi_ab,
            disturbance_ab: flux.disturbance_ab,
            locked,
            tracking,
            acquiring,
        }
    }
}

/// Observer + PLL. See the module documentation.
#[derive(Clone, Debug)]
pub struct Estimator<T> {
    observer: AnyObserver<T>,
    pll: Pll<T>,
    /// The DCFO's frequency-locked loop (`None` for the other observers and for
    /// [`NotchTuning::Pll`], which run the paper's plain PLL).
    fll: Option<Fll<T>>,
    tuning: NotchTuning,
    /// The FLL tunes the notch and feeds the PLL forward (the PLL's integrator then holds
    /// only what the feed-forward misses).
    fll_steers: bool,
    /// [`ZERO_SPEED_PER_NOTCH_FLOOR`] notch floors (rad/s).
    zero_speed: T,
    /// [`HANDOVER_PER_NOTCH_FLOOR`] notch floors (rad/s).
    handover_floor: T,
    /// The FLL carries the estimate through zero speed (it took the notch below the
    /// zero-speed floor, not from reset or [`Estimator::reacquire`]): the frequency is
    /// known, the estimate is not [acquiring](Estimate::acquiring).
    through_zero: bool,
    /// Relative frequency disagreement that counts (dimensionless).
    agreement_tolerance: T,
    /// The smallest frequency the agreement is measured against (rad/s).
    agreement_floor: T,
    /// How far the PLL-tuned notch may be from a settled FLL's frequency, relative
    /// (dimensionless): `zeta * NOTCH_PHASE_BUDGET_RAD`.
    notch_band: T,
    /// How fast an excess over the band is taken out, per rad/s of frequency
    /// (dimensionless; `4`: the FLL's own tracking rate).
    correction_rate: T,
    /// `1 / zeta` of the DCFO's notch (dimensionless): its phase moves by `dw / (zeta w)`.
    inv_zeta: T,
    /// [`NOTCH_PHASE_DEADBAND_RAD`].
    phase_deadband: T,
    /// [`NOTCH_PHASE_COMPENSATION_LIMIT_RAD`].
    phase_limit: T,
    /// `1 /` [`COMPENSATION_FLL_SHARE`] (dimensionless).
    fll_confirmation: T,
    /// Damping of the notch that takes the fundamental out of the phase compensation
    /// (dimensionless): [`COMPENSATION_NOTCH_DAMPING`].
    compensation_notch_k: T,
    /// That notch's band-pass output (rad): what is taken out.
    compensation_bp: T,
    /// That notch's quadrature state (rad).
    compensation_q: T,
    /// Share of the compensation armed (dimensionless, 0 to 1): the electrical angle
    /// travelled while [`Estimate::locked`] since the PLL took the notch, over
    /// [`COMPENSATION_ARM_RAD`].
    compensation_armed: T,
    /// `1 /` [`COMPENSATION_ARM_RAD`] (1/rad).
    compensation_arm_rate: T,
    /// Share of the compensation faded in (dimensionless, 0 to 1): it fades in over
    /// [`COMPENSATION_FADE_RAD`] of travel while tracking; what is applied is this share
    /// times the share armed.
    compensation_weight: T,
    /// `1 /` [`COMPENSATION_FADE_RAD`] (1/rad).
    compensation_fade: T,
    /// `1 /` [`COMPENSATION_FADE_OUT_RAD`] (1/rad).
    compensation_fade_out: T,
    /// The last compensation before its weight (rad): what fades out.
    compensation_phase: T,
    /// What was applied when tracking last stopped, still fading out once tracking has
    /// resumed (weight, phase in rad): the new reading fades in from zero beside it.
    compensation_fading: (T, T),
    /// The last sample tracked (for the resumption).
    compensation_tracking: bool,
    /// Magnet flux (Wb), for seeding.
    psi_f: T,
    /// Commanded electrical acceleration (rad/s^2, working units): the ramp the notch
    /// is fed forward with.
    commanded_accel: T,
    /// The PLL's linear model on the commanded ramp: phase error (rad) and integrator
    /// lag (rad/s, added to the notch).
    ramp_phase: T,
    ramp_lag: T,
    /// Electrical angle (rad) travelled since a disturbance check last failed, up to
    /// [`CALM_ANGLE_RAD`].
    calm_angle: T,
    /// [`CALM_ANGLE_RAD`] in working units.
    calm_needed: T,
    /// The observer's disturbance estimate at the last sample (Wb).
    disturbance_prev: AlphaBeta<T>,
    /// Its increment per sample, low-passed at the notch frequency (Wb).
    disturbance_drift: AlphaBeta<T>,
    /// [`MAX_DISTURBANCE_DRIFT`] (dimensionless).
    max_drift: T,
    /// The circle fit that seeds the observer from a cold start or a re-acquisition
    /// ([`crate::algorithms::arc_fit`]); with the FLL only.
    arc_fit: Option<ArcFit<T>>,
    /// The observer was seeded by the circle fit and the PLL has not taken the notch
    /// since: the hand-over takes the FLL's mean frequency.
    fitted: bool,
    /// The observer's flux estimate at the last sample (Wb): its increment gives the
    /// magnitude's rate.
    flux_prev: AlphaBeta<T>,
    /// [`OFFSET_PHASE_SHARE`] (dimensionless).
    offset_share: T,
    /// `Ld - Lq` (H).
    saliency: T,
    /// The current along the flux times the flux, `i . psi`, at the last sample (A Wb).
    current_along_flux_prev: T,
    /// [`OFFSET_PHASE_DEADBAND_RAD`].
    offset_deadband: T,
    /// [`OFFSET_PHASE_LIMIT_RAD`].
    offset_limit: T,
    /// `2` [`OFFSET_BANDPASS_DAMPING`] (dimensionless).
    offset_bandpass_k: T,
    /// The band-pass's output (rad) and quadrature state (rad).
    offset_bp: T,
    offset_q: T,
    /// Held peak of `|offset_bp|` (rad), decaying at [`OFFSET_PEAK_DECAY_PER_RAD`].
    offset_peak: T,
    /// [`OFFSET_PEAK_DECAY_PER_RAD`].
    offset_peak_decay: T,
    /// [`FLL_TRUST_OFFSET_RAD`] (rad) and its reciprocal (1/rad).
    fll_trust_offset: T,
    inv_fll_trust_offset: T,
    /// Mean of `|offset_bp|` (rad), at [`OFFSET_READING_MEAN_RATE_PER_RAD`].
    offset_level: T,
    /// [`OFFSET_READING_MEAN_RATE_PER_RAD`].
    offset_level_rate: T,
    /// [`FLL_TRUST_LEVEL_MULTIPLE`].
    fll_trust_level_multiple: T,
    /// `psi x i` (Wb A, the thrust current times the flux), low-passed at
    /// [`THRUST_FAST_RATE_PER_RAD`] and at [`THRUST_SLOW_RATE_PER_RAD`] of the travel.
    thrust_fast: T,
    thrust_slow: T,
    /// Those two rates (1/rad).
    thrust_fast_rate: T,
    thrust_slow_rate: T,
    /// `1 / (psi_f THRUST_CHANGE_PER_RATED_CURRENT I_rated)` (1/(Wb A)): the FLL's trust
    /// per unit of `thrust_fast - thrust_slow`.
    inv_thrust_change: T,
    /// [`EstimatorConfig::resistance_uncertainty_ohm`] over `tan(`[`LOCK_ANGLE_RAD`]`)`
    /// (ohm).
    lock_resistance: T,
    /// [`LOCK_ANGLE_SIN`] and [`LOCK_ANGLE_TAN`] (formed once: a conversion is a routine
    /// in fixed point).
    lock_angle_sin: T,
    lock_angle_tan: T,
    /// [`LOCK_ERROR_DECAY_PER_RAD`].
    lock_error_decay_per_rad: T,
    /// The held voltage error of the lock check over `tan(`[`LOCK_ANGLE_RAD`]`)`, times
    /// `|psi|` (V Wb).
    lock_error: T,
    /// The observers without an FLL: the mean of `|psi|^2` (Wb^2, from `psi_f^2`), the
    /// held peak of the deviation from it (Wb^2), and `2 psi_f^2 exp(-FLUX_SQ_RATE_PER_RAD
    /// pi / 2)` (Wb^2): the held peak an offset of `psi_f` leaves a quarter period on
    /// (`Estimator::flux_steady`).
    flux_sq_mean: T,
    flux_sq_peak: T,
    flux_sq_peak_per_offset: T,
}

impl<T: Scalar> Estimator<T> {
    /// Builds the estimator for `motor` in the working units of `base`.
    pub fn new(
        motor: &MotorParams,
        config: &EstimatorConfig,
        base: &Base,
    ) -> Result<Self, EstimatorConfigError> {
        let m = ObserverMotor::new(motor, base);
        let observer = match config.observer {
            ObserverKind::PureIntegrator => AnyObserver::PureIntegrator(PureIntegrator::new(m)),
            ObserverKind::Cfo => AnyObserver::Cfo(
                LpfObserver::new(m, base.omega(config.cfo_cutoff_rad_s))
                    .map_err(EstimatorConfigError::Cfo)?,
            ),
            ObserverKind::Dcfo => {
                AnyObserver::Dcfo(Dcfo::new(m, &config.dcfo, base).map_err(EstimatorConfigError::Dcfo)?)
            }
        };
        let pll = Pll::new(&config.pll, motor.pole_pitch_m, base).map_err(EstimatorConfigError::Pll)?;
        let fll = match (config.observer, config.notch_tuning) {
            (ObserverKind::Dcfo, NotchTuning::AcquireWithFll | NotchTuning::Fll) => {
                Some(Fll::new(&config.fll, base).map_err(EstimatorConfigError::Fll)?)
            }
            _ => None,
        };
        let fll_steers = fll.is_some();
        let arc_fit = fll.as_ref().map(|_| ArcFit::new(motor.psi_f_wb, config.fll.floor_rad_s, base));
        let psi_f: T = base.flux(motor.psi_f_wb);
        Ok(Estimator {
            observer,
            pll,
            fll,
            tuning: config.notch_tuning,
            fll_steers,
            zero_speed: base.omega(ZERO_SPEED_PER_NOTCH_FLOOR * config.fll.floor_rad_s),
            handover_floor: base.omega(HANDOVER_PER_NOTCH_FLOOR * config.fll.floor_rad_s),
            through_zero: false,
            agreement_tolerance: T::from_f32(2.0 * config.fll.settle_tolerance),
            agreement_floor: base.omega(config.fll.floor_rad_s),
            notch_band: T::from_f32(config.dcfo.zeta * NOTCH_PHASE_BUDGET_RAD),
            correction_rate: T::from_f32(CORRECTION_RATE_PER_OMEGA),
            inv_zeta: T::from_f32(1.0 / config.dcfo.zeta),
            phase_deadband: T::from_f32(NOTCH_PHASE_DEADBAND_RAD),
            phase_limit: T::from_f32(NOTCH_PHASE_COMPENSATION_LIMIT_RAD),
            fll_confirmation: T::from_f32(1.0 / COMPENSATION_FLL_SHARE),
            compensation_notch_k: T::from_f32(2.0 * COMPENSATION_NOTCH_DAMPING),
            compensation_bp: T::ZERO,
            compensation_q: T::ZERO,
            compensation_armed: T::ZERO,
            compensation_arm_rate: T::from_f32(1.0 / COMPENSATION_ARM_RAD),
            compensation_weight: T::ZERO,
            compensation_fade: T::from_f32(1.0 / COMPENSATION_FADE_RAD),
            compensation_fade_out: T::from_f32(1.0 / COMPENSATION_FADE_OUT_RAD),
            compensation_phase: T::ZERO,
            compensation_fading: (T::ZERO, T::ZERO),
            compensation_tracking: false,
            psi_f,
            commanded_accel: T::ZERO,
            ramp_phase: T::ZERO,
            ramp_lag: T::ZERO,
            calm_angle: T::ZERO,
            calm_needed: T::from_f32(CALM_ANGLE_RAD),
            disturbance_prev: AlphaBeta::default(),
            disturbance_drift: AlphaBeta::default(),
            max_drift: T::from_f32(MAX_DISTURBANCE_DRIFT),
            arc_fit,
            fitted: false,
            flux_prev: AlphaBeta::default(),
            offset_share: T::from_f32(OFFSET_PHASE_SHARE),
            saliency: base.inductance(motor.ld_h - motor.lq_h),
            current_along_flux_prev: T::ZERO,
            offset_deadband: T::from_f32(OFFSET_PHASE_DEADBAND_RAD),
            offset_limit: T::from_f32(OFFSET_PHASE_LIMIT_RAD),
            offset_bandpass_k: T::from_f32(2.0 * OFFSET_BANDPASS_DAMPING),
            offset_bp: T::ZERO,
            offset_q: T::ZERO,
            offset_peak: T::ZERO,
            offset_peak_decay: T::from_f32(OFFSET_PEAK_DECAY_PER_RAD),
            fll_trust_offset: T::from_f32(FLL_TRUST_OFFSET_RAD),
            inv_fll_trust_offset: T::from_f32(1.0 / FLL_TRUST_OFFSET_RAD),
            offset_level: T::ZERO,
            offset_level_rate: T::from_f32(OFFSET_READING_MEAN_RATE_PER_RAD),
            fll_trust_level_multiple: T::from_f32(FLL_TRUST_LEVEL_MULTIPLE),
            thrust_fast: T::ZERO,
            thrust_slow: T::ZERO,
            thrust_fast_rate: T::from_f32(THRUST_FAST_RATE_PER_RAD),
            thrust_slow_rate: T::from_f32(THRUST_SLOW_RATE_PER_RAD),
            inv_thrust_change: T::ONE
                .checked_div(
                    base.flux::<T>(motor.psi_f_wb)
                        * base.current::<T>(THRUST_CHANGE_PER_RATED_CURRENT * motor.rated_current_a),
                )
                .unwrap_or(T::ZERO),
            lock_resistance: base.resistance(config.resistance_uncertainty_ohm / LOCK_ANGLE_TAN),
            lock_angle_sin: T::from_f32(LOCK_ANGLE_SIN),
            lock_angle_tan: T::from_f32(LOCK_ANGLE_TAN),
            lock_error_decay_per_rad: T::from_f32(LOCK_ERROR_DECAY_PER_RAD),
            lock_error: T::ZERO,
            flux_sq_mean: psi_f * psi_f,
            flux_sq_peak: T::ZERO,
            flux_sq_peak_per_offset: psi_f * psi_f * T::from_f32(2.0 * FLUX_SQ_HOLD_AT_QUARTER),
        })
    }

    /// One sample: `u_applied` is the voltage applied during the period that just ended
    /// (V), `i` the currents sampled now (A), `dt` that period's length (s).
    pub fn update(
        &mut self,
        u_applied: AlphaBeta<T>,
        i: AlphaBeta<T>,
        dt: T,
    ) -> Result<Estimate<T>, EstimatorFault> {
        let notch = self.notch_omega();
        // The DCFO's radial feedback, armed with the angle's compensations (module docs,
        // "The DC offset's angle"): off while acquiring.
        let radial_weight = if self.fll_steers { T::ZERO } else { self.compensation_armed };
        self.observer.set_magnitude_feedback(radial_weight);
        let input = ObserverInput { u_ab: u_applied, i_ab: i, omega_e: notch, dt };
        let flux = self.observer.update(&input).map_err(EstimatorFault::Observer)?;
        let fitted = match (&mut self.arc_fit, flux.emf_increment_ab) {
            (Some(fit), Some(increment)) => {
                // A commanded speed change: the back-EMF draws no circle (arc_fit).
                if self.commanded_accel != T::ZERO {
                    fit.stop_dc_fit();
                }
                fit.update(increment, dt)
            }
            _ => ArcFitOutcome::Pending,
        };
        let estimate = self.track(&flux, i, notch, dt)?;
        if let ArcFitOutcome::Found { theta_e, omega_e, dc_voltage } = fitted {
            // The observer restarts on the fitted flux now, holding the fitted DC error;
            // the PLL on where it will be at the next sample.
            let next = theta_e + (omega_e * dt).radians_to_angle();
            self.seed_at(theta_e, next, omega_e, i, dc_voltage);
            self.fitted = true;
        }
        Ok(estimate)
    }

    /// The loops after the observer: FLL, PLL, the notch's tuning, the flags.
    fn track(
        &mut self,
        flux: &FluxEstimate<T>,
        i: AlphaBeta<T>,
        notch: T,
        dt: T,
    ) -> Result<Estimate<T>, EstimatorFault> {
        if self.fll_steers && self.fll.is_some() {
            self.clear_ramp_model();
        } else {
            self.advance_ramp_model(dt);
        }
        // Electrical travel over the sample at the notch frequency (rad): the rate of the
        // filters below, which run in travel so that they have one shape at every speed.
        // The thrust's filters run on every sample, the FLL steering or not, so that they
        // have settled when the PLL takes the notch.
        let travel = notch.abs().max(self.agreement_floor) * dt;
        let thrust_change = self.thrust_change(flux.psi_ab, i, travel);
        let (Some(fll), Some(increment)) = (&mut self.fll, flux.flux_increment_ab) else {
            let out = self.pll.update(flux.psi_ab, dt).map_err(EstimatorFault::Pll)?;
            let locked =
                out.locked && self.flux_allows_lock(i, flux.psi_ab, out.omega_e, dt, Some(out.error));
            return Ok(Estimate::from_parts(&out, flux, locked, out.locked, false));
        };
        fll.set_steering(self.fll_steers);
        let f = fll.update(flux.psi_ab, increment, dt);
        let psi_prev = core::mem::replace(&mut self.flux_prev, flux.psi_ab);
        let along = i.alpha * flux.psi_ab.alpha + i.beta * flux.psi_ab.beta;
        let along_prev = core::mem::replace(&mut self.current_along_flux_prev, along);
        // Drift of the disturbance estimate: while the observer is still moving its DC
        // state (after a DC step in its inputs) its angle is off although the loops agree.
        let quiet = match flux.disturbance_ab {
            Some(d) => {
                let inc = AlphaBeta::new(
                    d.alpha - self.disturbance_prev.alpha,
                    d.beta - self.disturbance_prev.beta,
                );
                self.disturbance_prev = d;
                // The notch frequency is signed while the PLL tunes it.
                let w_dt = notch.abs() * dt;
                let rate = w_dt.min(T::ONE);
                // rate in [0, 1]: products without a saturation check.
                self.disturbance_drift = AlphaBeta::new(
                    self.disturbance_drift.alpha + (inc.alpha - self.disturbance_drift.alpha).mul_unit(rate),
                    self.disturbance_drift.beta + (inc.beta - self.disturbance_drift.beta).mul_unit(rate),
                );
                approx_norm(self.disturbance_drift) <= self.max_drift * w_dt * approx_norm(flux.psi_ab)
            }
            None => true,
        };
        // A disturbance clears `locked` at once; it is restored only after a quarter period
        // without one (a detector that dips below its limit mid-disturbance does not re-arm
        // the flag).
        self.calm_angle = if quiet && f.undisturbed {
            (self.calm_angle + notch.abs() * dt).min(self.calm_needed)
        } else {
            T::ZERO
        };
        let calm = self.calm_angle >= self.calm_needed;
        let acquiring = self.fll_steers && !self.through_zero;
        let (out, locked, tracking) = if self.fll_steers {
            let out = self
                .pll
                .update_with_feedforward(flux.psi_ab, f.omega_e, f.notch_omega, dt)
                .map_err(EstimatorFault::Pll)?;
            let tracking = out.locked && f.frequency_settled;
            // Through zero speed the PLL takes the notch back only once the mover no
            // longer accelerates (the FLL's reading within the agreement tolerance of
            // its mean): its integrator lags an acceleration the feed-forward follows.
            let steady = !self.through_zero
                || (f.omega_e - fll.omega_mean()).abs() <= self.agreement_tolerance * f.omega_e.abs();
            if tracking
                && steady
                && self.tuning == NotchTuning::AcquireWithFll
                && f.omega_e.abs() >= self.handover_floor
            {
                // Hand the notch to the PLL: its integrator takes the FLL's frequency (the
                // notch does not jump; the residual it held was the feed-forward's error).
                // After a seed by the circle fit the FLL's reading ripples at `w` while the
                // observer settles the DC state the seed left out, on a mover the fit saw
                // turn at a steady rate: its mean is taken, not a ripple's sample (the
                // 'Cold starts' section). Elsewhere (a re-acquisition in a transient) the
                // mean would lag the speed: the reading is taken.
                let omega = if self.fitted { fll.omega_mean() } else { f.omega_e };
                self.pll.set_integral(omega);
                self.fitted = false;
                self.fll_steers = false;
                self.through_zero = false;
                self.clear_compensation();
            }
            (out, out.locked && f.settled && calm, tracking)
        } else {
            // The FLL reads the frequency whatever the notch's tuning; the PLL's integrator
            // lags a speed change nobody commanded (a load step). A notch off by `dw`
            // turns the observer's phase by `dw / (zeta w)`, so the PLL-tuned notch is
            // kept within `zeta * NOTCH_PHASE_BUDGET_RAD` of a settled FLL's frequency
            // (within the 20 % agreement tolerance of one whose frequency has settled
            // but whose flux is not yet steady, e.g. right after re-acquisition): when
            // the integrator leaves that band, the excess over it is taken out at the
            // FLL's tracking rate. The correction is continuous in the disagreement (no decision
            // near a threshold, so f32 and fixed point stay together), and it is withheld
            // while the flux amplitude is disturbed (a DC step being removed: the FLL
            // then reads the offset as a ripple at `w`), and only as far as the FLL is
            // trusted (the DC offset's angle reading, module docs).
            let offset = self.offset_phase(flux.psi_ab, psi_prev, along - along_prev, notch, travel, dt);
            // The PLL's frequency (its integrator plus the lag on a commanded ramp, as the
            // notch uses it) less the FLL's: what the band bounds.
            let excess = self.pll.omega_integral() + self.ramp_lag - f.omega_e;
            // A thrust change the way the FLL departs (excess < 0: a speed-up in the
            // positive direction, a thrust change > 0) restores the trust.
            let thrust_share =
                (if excess > T::ZERO { -thrust_change } else { thrust_change }).clamp_to(T::ZERO, T::ONE);
            let fll_trust = self.fll_trust(travel).max(thrust_share);
            if f.frequency_settled && f.flux_undisturbed {
                let reference = f.omega_e.abs().max(self.agreement_floor);
                let tolerance = if f.settled { self.notch_band } else { self.agreement_tolerance };
                let band = tolerance * reference;
                if excess.abs() > band {
                    // The excess is taken out at the FLL's own tracking rate, 4 w (a time
                    // constant of a quarter radian of travel), not in one step: the
                    // integrator is the speed estimate, which must not jump.
                    let rate = (self.correction_rate * reference * dt).min(T::ONE) * fll_trust;
                    let outside = excess - excess.clamp_to(-band, band);
                    self.pll.set_integral(self.pll.omega_integral() - rate * outside);
                }
            }
            let out = self.pll.update(flux.psi_ab, dt).map_err(EstimatorFault::Pll)?;
            // The estimate is trusted while the PLL's frequency (its integrator plus the
            // lag on a commanded ramp, as the notch uses it) agrees with the FLL's.
            let reference = f.omega_e.abs().max(self.agreement_floor);
            let agree = (self.pll.omega_integral() + self.ramp_lag - f.omega_e).abs()
                <= self.agreement_tolerance * reference;
            let mut out = out;
            if out.locked && agree {
                self.compensate_notch_phase(&mut out, notch, f.omega_e, fll_trust, travel);
            } else {
                // Not tracking: nothing new to compensate. What was applied fades out over
                // a quarter period rather than at once (a flag that flips for a sample in
                // one arithmetic and not the other must not move the angle by the whole
                // compensation), and fades in again once tracking.
                self.fade_out_compensation(&mut out, travel);
            }
            // The DC offset's angle, armed with the notch's phase compensation but kept
            // while not tracking: a DC step is what makes the loops disagree.
            if offset != T::ZERO {
                out.theta_e = out.theta_e - offset.radians_to_angle();
                out.cos_sin = CosSin::inline(out.theta_e);
            }
            let locked = out.locked && agree && f.settled && calm;
            // Armed in proportion to the travel while locked: a flag set for a sample in
            // one arithmetic and not the other arms them a sample's share apart.
            if locked {
                self.compensation_armed =
                    (self.compensation_armed + notch.abs() * dt * self.compensation_arm_rate).min(T::ONE);
            }
            // Through zero speed (module docs): below the floor the FLL takes the notch
            // from the next sample on, the PLL fed forward with its frequency (the
            // integrator cleared: the PLL's frequency does not jump); the circle fit is
            // not asked again (a mover passing through zero speed accelerates: it draws
            // no circle).
            if f.omega_e.abs() < self.zero_speed && self.tuning == NotchTuning::AcquireWithFll {
                self.pll.set_integral(T::ZERO);
                self.fll_steers = true;
                self.through_zero = true;
                self.clear_compensation();
            }
            (out, locked, out.locked && agree)
        };
        let locked = locked && self.flux_allows_lock(i, flux.psi_ab, out.omega_e, dt, None);
        Ok(Estimate::from_parts(&out, flux, locked, tracking, acquiring))
    }

    /// Whether the flux estimate `psi` (Wb) allows [`Estimate::locked`] at current `i`
    /// (A) and frequency `omega_e` (rad/s) over `dt` (s):
    /// - a resistance error within [`EstimatorConfig::resistance_uncertainty_ohm`]
    ///   leaves the angle within [`LOCK_ANGLE_RAD`], updating the held error. Multiplied
    ///   through by `|psi|` (no division): the current along the flux is
    ///   `i . psi / |psi|`; `|i|` and `|psi|` come from [`approx_norm`] (at most 12 %
    ///   high: `|i|` on the safe side, `|psi|` on both sides of the inequality);
    /// - `without_fll` (the observers without the FLL's checks) carries the PLL's phase
    ///   error (the sine, dimensionless), and the errors that add to the angle's are
    ///   bounded together within the lock angle ([`Estimator::flux_steady`]: an offset
    ///   read from the swing of the estimate's magnitude, the CFO's phase lead, the
    ///   PLL's error).
    ///
    /// Not inlined: one copy for its two callers.
    #[inline(never)]
    fn flux_allows_lock(
        &mut self,
        i: AlphaBeta<T>,
        psi: AlphaBeta<T>,
        omega_e: T,
        dt: T,
        without_fll: Option<T>,
    ) -> bool {
        let i_norm = approx_norm(i);
        let psi_norm = approx_norm(psi);
        let along = (i.alpha * psi.alpha + i.beta * psi.beta).abs();
        let error = self.lock_resistance * (along + self.lock_angle_sin * i_norm * psi_norm);
        let w = omega_e.abs();
        let decay = (self.lock_error_decay_per_rad * w * dt).min(T::ONE);
        self.lock_error = error.max(self.lock_error - self.lock_error.mul_unit(decay));
        let resistance_ok = self.lock_error <= w * self.psi_f * psi_norm;
        let Some(pll_error) = without_fll else {
            return resistance_ok;
        };
        let square = psi.alpha * psi.alpha + psi.beta * psi.beta;
        resistance_ok && self.flux_steady(square, w, dt, pll_error, psi_norm)
    }

    /// For the observers without the FLL's checks: whether the angle is within
    /// [`LOCK_ANGLE_RAD`] by the four errors this estimator can bound, together, and has
    /// been for [`CALM_ANGLE_RAD`]. With `square` the estimate's `|psi|^2` (Wb^2), `w` the
    /// PLL's `|w|` (rad/s), `dt` the period (s), `pll_error` the PLL's phase error (the
    /// sine of its angle from the estimate's, dimensionless) and `psi_norm` the estimate's
    /// magnitude within 12 % (Wb):
    /// - an offset `delta` in the estimate (a DC error the observer integrated, a drift)
    ///   swings `|psi|^2` about its mean by `2 psi_f |delta| cos(phi)` as the flux turns,
    ///   and turns the angle by up to `asin(|delta| / psi_f)`: `|delta| / psi_f <= p / P`,
    ///   `p` the swing's held peak and `P` the held peak an offset of `psi_f` leaves (the
    ///   `flux_sq_peak_per_offset` field). A flux estimate of the wrong magnitude that
    ///   does not swing is not an angle error;
    /// - the CFO's low-pass leads by `atan(w_c / w)`
    ///   ([`AnyObserver::steady_lead_cutoff`]);
    /// - the PLL lags the estimate by `asin(pll_error)`;
    /// - a resistance error within the allowance turns it by `atan(t_r)`, with `t_r = tan(
    ///   LOCK_ANGLE) lock_error / (w psi_f |psi|)` from the resistance check's held error.
    ///
    /// Each angle is at most its sine or tangent times `LOCK_ANGLE / sin(LOCK_ANGLE)`
    /// while that is at most `sin(LOCK_ANGLE)` (`asin(x) / x` grows with `x`, and
    /// `atan(x) <= x`), so the four sum to at most the lock angle where
    /// `p / P + w_c / w + |pll_error| + t_r <= sin(LOCK_ANGLE)`; multiplied through by
    /// `w P psi_f |psi|` (no division): `p w psi_f |psi| + tan(LOCK_ANGLE) lock_error P <=
    /// (sin(LOCK_ANGLE) w - w_c - |pll_error| w) P psi_f |psi|`. Where a product saturates
    /// (a swing of several `psi_f^2`), the left side does and the check fails. Without the
    /// resistance's share, the CFO's closed loop on the paper axis still had 111 to 305
    /// false-lock samples in its load step, lock loss and reversal.
    fn flux_steady(&mut self, square: T, w: T, dt: T, pll_error: T, psi_norm: T) -> bool {
        let travel = w * dt;
        // FLUX_SQ_RATE_PER_RAD of the travel, in [0, 1]: products without a saturation
        // check.
        let rate = travel.mul_unit(T::HALF).mul_unit(T::HALF).mul_unit(T::HALF).min(T::ONE);
        self.flux_sq_mean = self.flux_sq_mean + (square - self.flux_sq_mean).mul_unit(rate);
        let deviation = (square - self.flux_sq_mean).abs();
        self.flux_sq_peak = deviation.max(self.flux_sq_peak - self.flux_sq_peak.mul_unit(rate));
        // |pll_error| <= 1 (the PLL clamps it).
        let room = self.lock_angle_sin * w - self.observer.steady_lead_cutoff() - w.mul_unit(pll_error.abs());
        let per_offset = self.flux_sq_peak_per_offset;
        let flux_sq = self.psi_f * psi_norm;
        let used = self.flux_sq_peak * w * flux_sq + self.lock_angle_tan * self.lock_error * per_offset;
        let steady = used <= room * per_offset * flux_sq;
        self.calm_angle = if steady { (self.calm_angle + travel).min(self.calm_needed) } else { T::ZERO };
        self.calm_angle >= self.calm_needed
    }

    /// Restarts [`Estimator::flux_steady`]'s mean at the magnet's flux and its peak and
    /// calm at zero. The calm is the steadiness check's without an FLL; with one it is
    /// the disturbance checks' (`track`), which keep their own.
    fn clear_flux_steadiness(&mut self) {
        self.flux_sq_mean = self.psi_f * self.psi_f;
        self.flux_sq_peak = T::ZERO;
        if self.fll.is_none() {
            self.calm_angle = T::ZERO;
        }
    }

    /// Turns the output angle back by the phase the notch's mistuning gives the flux
    /// (module docs, "Phase compensation"): `(notch - omega_hat) / (zeta |notch|)` while
    /// the FLL's frequency says the notch is off the same way (as far as the FLL is
    /// trusted, `fll_trust` in 0..1), its fundamental notched out, less a dead band,
    /// limited, faded in and armed in proportion. `travel` is the sample's electrical
    /// travel at the notch frequency (rad, `max(|notch|, floor) dt`).
    fn compensate_notch_phase(
        &mut self,
        out: &mut PllOutput<T>,
        notch: T,
        fll_omega: T,
        fll_trust: T,
        travel: T,
    ) {
        let w = notch.abs().max(self.agreement_floor);
        // Both readings by the one `w` (in Q8.24 one reciprocal and two products).
        let (pll_share, fll_share) = (notch - out.omega_e).checked_div_pair(notch - fll_omega, w);
        let phase =
            |share: Option<T>| share.map_or(T::ZERO, |x| (x * self.inv_zeta).clamp_to(-T::ONE, T::ONE));
        // The PLL's reading, as far as the FLL's confirms it: in full while the FLL shows
        // at least COMPENSATION_FLL_SHARE of it the same way, down to zero (continuously,
        // so f32 and fixed point do not part at a threshold) as the FLL's goes to zero
        // or the other way.
        let (from_pll, from_fll) = (phase(pll_share), phase(fll_share));
        let confirmed = (from_fll * self.fll_confirmation).mul_unit(fll_trust);
        let raw = if from_pll > T::ZERO {
            from_pll.min(confirmed.max(T::ZERO))
        } else {
            from_pll.max(confirmed.min(T::ZERO))
        };
        // Notch at the fundamental (a SOGI, semi-implicit Euler, stable for w dt < 2; w dt
        // is at most 0.13 at the PLL's speed limit and 10 kHz). It runs while tracking.
        let h = travel;
        (self.compensation_bp, self.compensation_q) = band_pass_step(
            (self.compensation_bp, self.compensation_q),
            raw,
            self.compensation_notch_k,
            h,
            T::TWO,
        );
        if !self.compensation_tracking {
            // Tracking again: what is still applied from before fades out on its own and
            // the new reading fades in from zero, so the angle is continuous whichever
            // sample the flag resumes at (f32 and fixed point may take it a sample apart).
            self.compensation_fading =
                (self.compensation_weight * self.compensation_armed, self.compensation_phase);
            self.compensation_weight = T::ZERO;
            self.compensation_tracking = true;
        }
        let (fading_weight, fading_phase) = self.compensation_fading;
        let fading_weight = (fading_weight - h * self.compensation_fade_out).max(T::ZERO);
        self.compensation_fading = (fading_weight, fading_phase);
        let phi = raw - self.compensation_bp;
        self.compensation_weight = (self.compensation_weight + h * self.compensation_fade).min(T::ONE);
        let excess = phi - phi.clamp_to(-self.phase_deadband, self.phase_deadband);
        self.compensation_phase = excess.clamp_to(-self.phase_limit, self.phase_limit);
        let phi = self.weighted_compensation(fading_weight, fading_phase);
        out.theta_e = out.theta_e - phi.radians_to_angle();
        out.cos_sin = CosSin::inline(out.theta_e);
    }

    /// The compensation applied (rad): the present one at its arming and weight, plus
    /// `fading_phase` (rad) at `fading_weight`. Every weight is in [0, 1], so the
    /// products are taken without a saturation check.
    fn weighted_compensation(&self, fading_weight: T, fading_phase: T) -> T {
        self.compensation_phase.mul_unit(self.compensation_armed.mul_unit(self.compensation_weight))
            + fading_phase.mul_unit(fading_weight)
    }

    /// The angle error a DC offset in the flux estimate causes, read from the rate of its
    /// magnitude (module docs, "The DC offset's angle"): `(d|psi| / dt) / (w |psi|)` for
    /// the flux `psi` after `psi_prev` one sample of `dt` earlier at the signed notch
    /// frequency `notch`, less a dead band, limited, times the share and the arming.
    fn offset_phase(
        &mut self,
        psi: AlphaBeta<T>,
        psi_prev: AlphaBeta<T>,
        d_along: T,
        notch: T,
        travel: T,
        dt: T,
    ) -> T {
        if self.compensation_armed <= T::ZERO {
            return T::ZERO;
        }
        let (da, db) = (psi.alpha - psi_prev.alpha, psi.beta - psi_prev.beta);
        // |psi| d|psi| = psi . dpsi, less what the current along the flux makes of a
        // salient motor's active flux: |psi| (Ld - Lq) d i_d = (Ld - Lq) d(i . psi) to
        // first order in i_d.
        // The increment is taken against the sample's midpoint, (psi + psi_prev) / 2, which
        // makes it the change of |psi|^2 / 2 exactly (against psi alone a steady rotation
        // would read w dt / 2).
        let mid = AlphaBeta::new(psi.alpha - da * T::HALF, psi.beta - db * T::HALF);
        let radial = da * mid.alpha + db * mid.beta - self.saliency * d_along;
        let square = psi.alpha * psi.alpha + psi.beta * psi.beta;
        let rate = match radial.checked_div(square * notch * dt) {
            Some(rate) => rate.clamp_to(-self.offset_limit, self.offset_limit),
            None => T::ZERO,
        };
        // Band-pass at the fundamental.
        (self.offset_bp, self.offset_q) =
            band_pass_step((self.offset_bp, self.offset_q), rate, self.offset_bandpass_k, travel, T::ONE);
        let phase = self.offset_bp;
        let excess = phase - phase.clamp_to(-self.offset_deadband, self.offset_deadband);
        // OFFSET_PHASE_SHARE and the arming are in [0, 1].
        excess.mul_unit(self.offset_share.mul_unit(self.compensation_armed))
    }

    /// The thrust current's change over about a period, in units of
    /// [`THRUST_CHANGE_PER_RATED_CURRENT`] of the rated current (dimensionless, signed:
    /// positive towards positive rotation), from the flux `psi` (Wb) and the current `i`
    /// (A) over a sample of electrical `travel` (rad); module docs, "The DC offset's
    /// angle". The filters' rates are in [0, 1]: products without a saturation check.
    ///
    /// Not inlined: the estimator's update is inlined at more than one call site of the
    /// drive's control step, and a copy each costs the ESC1 image 150 B of its flash.
    #[inline(never)]
    fn thrust_change(&mut self, psi: AlphaBeta<T>, i: AlphaBeta<T>, travel: T) -> T {
        let thrust = psi.alpha * i.beta - psi.beta * i.alpha;
        let fast = (self.thrust_fast_rate * travel).min(T::ONE);
        let slow = (self.thrust_slow_rate * travel).min(T::ONE);
        self.thrust_fast = self.thrust_fast + (thrust - self.thrust_fast).mul_unit(fast);
        self.thrust_slow = self.thrust_slow + (thrust - self.thrust_slow).mul_unit(slow);
        (self.thrust_fast - self.thrust_slow) * self.inv_thrust_change
    }

    /// How far the FLL's frequency is trusted (0..1) while a DC offset is read in the flux
    /// (module docs, "The DC offset's angle"): in full while the held peak of the
    /// band-passed offset reading stays within [`FLL_TRUST_OFFSET_RAD`] or within
    /// [`FLL_TRUST_LEVEL_MULTIPLE`] times the reading's own mean magnitude, whichever is
    /// larger, falling linearly to none over [`FLL_TRUST_OFFSET_RAD`] beyond. The peak
    /// decays at [`OFFSET_PEAK_DECAY_PER_RAD`] and the mean follows at
    /// [`OFFSET_READING_MEAN_RATE_PER_RAD`] of the sample's electrical `travel` (rad).
    fn fll_trust(&mut self, travel: T) -> T {
        let magnitude = self.offset_bp.abs();
        let decay = (self.offset_peak_decay * travel).min(T::ONE);
        // decay and rate in [0, 1]: products without a saturation check.
        self.offset_peak = magnitude.max(self.offset_peak - self.offset_peak.mul_unit(decay));
        let rate = (self.offset_level_rate * travel).min(T::ONE);
        self.offset_level = self.offset_level + (magnitude - self.offset_level).mul_unit(rate);
        let threshold = self.fll_trust_offset.max(self.fll_trust_level_multiple * self.offset_level);
        (T::ONE - (self.offset_peak - threshold) * self.inv_fll_trust_offset).clamp_to(T::ZERO, T::ONE)
    }

    /// While not tracking: the last compensation, its weight falling to zero over
    /// [`COMPENSATION_FADE_OUT_RAD`] of electrical angle.
    /// `travel` is the sample's electrical travel at the notch frequency (rad).
    fn fade_out_compensation(&mut self, out: &mut PllOutput<T>, travel: T) {
        let h = travel;
        // Both what fades since this loss of tracking and what still faded from the last.
        let (fading_weight, fading_phase) = self.compensation_fading;
        let fading_weight = (fading_weight - h * self.compensation_fade_out).max(T::ZERO);
        self.compensation_fading = (fading_weight, fading_phase);
        self.compensation_tracking = false;
        self.compensation_weight = (self.compensation_weight - h * self.compensation_fade_out).max(T::ZERO);
        if self.compensation_weight > T::ZERO || fading_weight > T::ZERO {
            let phi = self.weighted_compensation(fading_weight, fading_phase);
            out.theta_e = out.theta_e - phi.radians_to_angle();
            out.cos_sin = CosSin::new(out.theta_e);
        }
    }

    fn clear_compensation(&mut self) {
        self.offset_bp = T::ZERO;
        self.offset_q = T::ZERO;
        self.offset_peak = T::ZERO;
        self.offset_level = T::ZERO;
        self.compensation_bp = T::ZERO;
        self.compensation_q = T::ZERO;
        self.compensation_armed = T::ZERO;
        self.compensation_weight = T::ZERO;
        self.compensation_phase = T::ZERO;
        self.compensation_fading = (T::ZERO, T::ZERO);
        self.compensation_tracking = false;
    }

    /// Sets the PLL's angle (for its next sample) and speed (rad/s, working units),
    /// e.g. from an open-loop start-up; the observer keeps its state.
    pub fn preset_pll(&mut self, theta_e: Angle, omega_e: T) {
        if let Some(fll) = &mut self.fll {
            fll.preset(omega_e);
        }
        if self.fll_steers {
            self.pll.preset(theta_e, T::ZERO);
        } else {
            self.pll.preset(theta_e, omega_e);
        }
    }

    /// Starts every stage from a mover known to be at angle `theta_e` (for the next
    /// sample) moving at `omega_e` (rad/s) with current `i_ab` (A) flowing: the observer
    /// in the steady state of that flux ([`AnyObserver::seed`]), the PLL on the angle and
    /// the FLL on the frequency, acquiring (the notch is the FLL's, the lock flags are
    /// earned again by the measurements). For a drive leaving an open-loop segment whose
    /// trajectory it knows.
    pub fn seed(&mut self, theta_e: Angle, omega_e: T, i_ab: AlphaBeta<T>) {
        if let Some(fit) = &mut self.arc_fit {
            fit.stop();
        }
        self.seed_at(theta_e, theta_e, omega_e, i_ab, AlphaBeta::default());
    }

    /// [`Estimator::seed`] with the observer on the flux at `theta_now` (this sample's),
    /// holding the DC voltage error `dc_voltage` (V; the DCFO only), and the PLL on
    /// `theta_next` (the next sample's).
    fn seed_at(
        &mut self,
        theta_now: Angle,
        theta_next: Angle,
        omega_e: T,
        i_ab: AlphaBeta<T>,
        dc_voltage: AlphaBeta<T>,
    ) {
        self.fitted = false;
        let cs = CosSin::<T>::new(theta_now);
        let psi = AlphaBeta::new(self.psi_f * cs.cos, self.psi_f * cs.sin);
        self.observer.seed(psi, i_ab, omega_e, dc_voltage);
        self.disturbance_prev = AlphaBeta::default();
        self.disturbance_drift = AlphaBeta::default();
        self.clear_compensation();
        if let Some(fll) = &mut self.fll {
            fll.preset(omega_e);
            self.fll_steers = true;
        }
        if self.fll_steers {
            self.pll.preset(theta_next, T::ZERO);
        } else {
            self.pll.preset(theta_next, omega_e);
        }
    }

    /// Acquires again without forgetting: the FLL takes the notch back from its present
    /// frequency estimate (it reads the frequency whatever the notch's tuning) and the
    /// lock is declared again only once both loops agree. For a drive that has lost
    /// lock with the mover still moving (flying restart). No effect without an FLL.
    pub fn reacquire(&mut self) {
        self.through_zero = false;
        self.fitted = false;
        if let Some(fit) = &mut self.arc_fit {
            fit.restart();
        }
        if let Some(fll) = &mut self.fll {
            if !self.fll_steers {
                self.pll.set_integral(T::ZERO);
                self.fll_steers = true;
            }
            fll.restart_acquisition();
        }
        self.clear_compensation();
    }

    /// Back to the initial state; clears latched faults.
    pub fn reset(&mut self) {
        self.through_zero = false;
        self.clear_ramp_model();
        self.commanded_accel = T::ZERO;
        self.observer.reset();
        self.disturbance_prev = AlphaBeta::default();
        self.disturbance_drift = AlphaBeta::default();
        self.pll.reset();
        if let Some(fll) = &mut self.fll {
            fll.reset();
        }
        self.fll_steers = self.fll.is_some();
        self.fitted = false;
        if let Some(fit) = &mut self.arc_fit {
            fit.restart();
        }
        self.clear_compensation();
        self.lock_error = T::ZERO;
        self.clear_flux_steadiness();
    }

    /// `true` while the circle fit of [`crate::algorithms::arc_fit`] is still looking for the mover
    /// (from reset and [`Estimator::reacquire`] until it seeds the estimator or gives
    /// up): the angle until then is the unseeded acquisition's.
    pub fn fitting(&self) -> bool {
        self.arc_fit.as_ref().is_some_and(ArcFit::is_running)
    }

    /// The frequency the observer's notch will be tuned to at the next sample (rad/s,
    /// working units): the FLL's while it steers, the PLL integrator's otherwise, plus
    /// the integrator's lag on a commanded ramp ([`Estimator::set_commanded_acceleration`]).
    pub fn notch_omega(&self) -> T {
        match &self.fll {
            Some(fll) if self.fll_steers => fll.notch_omega(),
            _ => self.pll.omega_integral() + self.ramp_lag,
        }
    }

    /// Advances the PLL's linear model on the commanded ramp `a` by one sample of `dt`
    /// (s): `u += (a - ki x) dt`, `x += (u - kp x) dt` (see [`crate::algorithms::pll`]); bounded by
    /// the speed range.
    fn advance_ramp_model(&mut self, dt: T) {
        if self.commanded_accel == T::ZERO && self.ramp_lag == T::ZERO && self.ramp_phase == T::ZERO {
            return;
        }
        let (kp, ki) = self.pll.gains();
        let limit = self.pll.max_omega();
        let step = (self.commanded_accel - ki * self.ramp_phase) * dt;
        self.ramp_lag = (self.ramp_lag + step).clamp_to(-limit, limit);
        self.ramp_phase =
            (self.ramp_phase + (self.ramp_lag - kp * self.ramp_phase) * dt).clamp_to(-T::ONE, T::ONE);
    }

    fn clear_ramp_model(&mut self) {
        self.ramp_phase = T::ZERO;
        self.ramp_lag = T::ZERO;
    }

    /// Tells the estimator the electrical acceleration (rad/s^2, working units, signed)
    /// the drive is commanding from the next sample on (its speed reference ramp, a
    /// move's acceleration): the PLL-tuned notch is led by the integrator's lag on that
    /// ramp (`kp a / ki` once it has lasted, see [`crate::algorithms::pll`]), so a commanded ramp
    /// costs the observer little phase. Zero (the default) for none; a non-finite value
    /// is ignored. Replay needs it too: traces carry it (host `trace` module).
    pub fn set_commanded_acceleration(&mut self, alpha_e: T) {
        if alpha_e.is_valid() {
            self.commanded_accel = alpha_e;
        }
    }

    /// The commanded electrical acceleration the next sample will use (rad/s^2,
    /// working units).
    pub fn commanded_acceleration(&self) -> T {
        self.commanded_accel
    }

    /// The FLL's signed frequency estimate (rad/s, working units), where it runs.
    pub fn fll_omega(&self) -> Option<T> {
        self.fll.as_ref().map(|f| f.omega())
    }

    /// Which observer runs.
    pub fn observer_kind(&self) -> ObserverKind {
        self.observer.kind()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::algorithms::observer::ObserverKind;

    const DT: f64 = 1e-4;

    /// The lock check's constants are the sine and tangent of its angle, and the steadiness
    /// check's hold is the exponential of its rate, to f32.
    #[test]
    fn lock_angle_constants_are_its_sine_and_tangent() {
        let a = f64::from(LOCK_ANGLE_RAD);
        assert!((f64::from(LOCK_ANGLE_SIN) - a.sin()).abs() < 1e-7);
        assert!((f64::from(LOCK_ANGLE_TAN) - a.tan()).abs() < 1e-7);
        let hold = (-f64::from(FLUX_SQ_RATE_PER_RAD) * core::f64::consts::FRAC_PI_2).exp();
        assert!((f64::from(FLUX_SQ_HOLD_AT_QUARTER) - hold).abs() < 1e-7);
        // `Estimator::flux_steady` forms the rate as three halves, exactly.
        assert_eq!(FLUX_SQ_RATE_PER_RAD.to_bits(), (0.5f32 * 0.5 * 0.5).to_bits());
    }

    /// The steadiness check of the observers without an FLL against the geometry of an
    /// offset `delta` on a flux turning at `hz`: `(allowed at the end, allowed on a
    /// sample whose angle is off by more than LOCK_ANGLE_RAD)` over four periods, the
    /// offset's angle to the flux at the start `phase` (rad).
    fn steadiness(kind: ObserverKind, hz: f64, offset_angle_deg: f64, phase: f64) -> (bool, bool) {
        let motor = MotorParams::paper();
        let config = EstimatorConfig::for_motor(&motor, kind);
        let mut e = Estimator::<f64>::new(&motor, &config, &Base::SI).unwrap();
        let psi_f = f64::from(motor.psi_f_wb);
        let delta = psi_f * offset_angle_deg.to_radians().sin();
        let w = 2.0 * core::f64::consts::PI * hz;
        // The CFO's low-pass leads by atan(w_c / w): the flux it reports is the mover's
        // turned by that (the check is told of the lead, not shown it).
        let lead =
            if kind == ObserverKind::Cfo { (f64::from(config.cfo_cutoff_rad_s) / w).atan() } else { 0.0 };
        let (mut allowed, mut false_lock) = (false, false);
        let periods = 4.0;
        for n in 0..(periods / (hz * DT)) as usize {
            let th = w * DT * n as f64;
            let psi = AlphaBeta::new(
                psi_f * (th + lead).cos() + delta * phase.cos(),
                psi_f * (th + lead).sin() + delta * phase.sin(),
            );
            allowed = e.flux_allows_lock(AlphaBeta::default(), psi, w, DT, Some(0.0));
            let error = (psi.beta.atan2(psi.alpha) - th + core::f64::consts::PI)
                .rem_euclid(2.0 * core::f64::consts::PI)
                - core::f64::consts::PI;
            false_lock |= allowed && error.abs() > f64::from(LOCK_ANGLE_RAD);
        }
        (allowed, false_lock)
    }

    #[test]
    fn an_offset_that_turns_the_angle_beyond_the_lock_angle_withdraws_the_lock() {
        for phase in [0.0, 1.0, 2.0, 3.0, 4.0, 5.0] {
            // Within the lock angle's budget: vouched for once steady.
            let (end, false_lock) = steadiness(ObserverKind::PureIntegrator, 10.0, 5.0, phase);
            assert!(end && !false_lock, "5 deg offset, phase {phase}");
            // Beyond it (the angle off by up to 20 and 30 deg): never locked while off
            // by more than 15 deg, nor at the end.
            for offset in [20.0, 30.0] {
                let (end, false_lock) = steadiness(ObserverKind::PureIntegrator, 10.0, offset, phase);
                assert!(!end && !false_lock, "{offset} deg offset, phase {phase}");
            }
        }
    }

    /// A pure integrator's drift: an offset growing from zero to 0.6 `psi_f` over eight
    /// periods at 10 Hz (the angle off by up to 37 deg at the end). The flag is up while
    /// the drift is small, never while the angle is off by more than the lock angle, and
    /// down at the end. A steady flux of the wrong magnitude (1.3 `psi_f`, at the right
    /// angle) is vouched for: the magnitude is not the angle.
    #[test]
    fn a_drifting_flux_is_vouched_for_only_while_its_angle_is_within_the_lock_angle() {
        let motor = MotorParams::paper();
        let config = EstimatorConfig::for_motor(&motor, ObserverKind::PureIntegrator);
        let psi_f = f64::from(motor.psi_f_wb);
        let w = 2.0 * core::f64::consts::PI * 10.0;
        let samples = (8.0 / (10.0 * DT)) as usize;
        let run = |scale: f64, drift: f64| {
            let mut e = Estimator::<f64>::new(&motor, &config, &Base::SI).unwrap();
            let (mut first_allowed, mut last, mut false_lock) = (None, false, false);
            for n in 0..samples {
                let th = w * DT * n as f64;
                let delta = drift * psi_f * n as f64 / samples as f64;
                let psi = AlphaBeta::new(
                    scale * psi_f * th.cos() + delta * 0.7f64.cos(),
                    scale * psi_f * th.sin() + delta * 0.7f64.sin(),
                );
                last = e.flux_allows_lock(AlphaBeta::default(), psi, w, DT, Some(0.0));
                let error = (psi.beta.atan2(psi.alpha) - th + core::f64::consts::PI)
                    .rem_euclid(2.0 * core::f64::consts::PI)
                    - core::f64::consts::PI;
                false_lock |= last && error.abs() > f64::from(LOCK_ANGLE_RAD);
                if last && first_allowed.is_none() {
                    first_allowed = Some(n);
                }
            }
            (first_allowed, last, false_lock)
        };
        let (first, end, false_lock) = run(1.0, 0.6);
        assert!(first.is_some_and(|n| n < samples / 4), "first allowed at {first:?}");
        assert!(!end && !false_lock);
        let (first, end, false_lock) = run(1.3, 0.0);
        assert!(first.is_some() && end && !false_lock);
    }

    #[test]
    fn the_cfos_phase_lead_counts_against_the_lock_angle() {
        // The CFO's 2.5 Hz cut-off leads by 14.0 deg at 10 Hz, 26.6 at 5 Hz, 7.1 at 20 Hz.
        let (end, false_lock) = steadiness(ObserverKind::Cfo, 5.0, 0.0, 0.0);
        assert!(!end && !false_lock);
        let (end, false_lock) = steadiness(ObserverKind::Cfo, 10.0, 0.0, 0.0);
        assert!(end && !false_lock);
        // At 20 Hz an offset worth 5 deg fits the 7.9 deg the lead leaves; one of 10 does
        // not, and is never locked where the two add beyond 15 deg.
        let (end, false_lock) = steadiness(ObserverKind::Cfo, 20.0, 5.0, 1.0);
        assert!(end && !false_lock);
        for phase in [0.0, 1.0, 2.0, 3.0, 4.0, 5.0] {
            let (end, false_lock) = steadiness(ObserverKind::Cfo, 20.0, 10.0, phase);
            assert!(!end && !false_lock, "phase {phase}");
        }
    }

    #[test]
    fn the_thrust_change_reads_a_step_of_thrust_current_and_not_a_dc_current_offset() {
        let motor = MotorParams::paper();
        let mut e = armed(&motor);
        let psi_f = f64::from(motor.psi_f_wb);
        let rated = f64::from(motor.rated_current_a);
        let w = 2.0 * core::f64::consts::PI * 10.0;
        let travel = w * DT;
        let run = |e: &mut Estimator<f64>, i_q: f64, offset: f64, n: usize| {
            let mut extreme = 0.0f64;
            for k in 0..n {
                let th = w * DT * k as f64;
                let psi = AlphaBeta::new(psi_f * th.cos(), psi_f * th.sin());
                // i_q along the flux's quadrature, plus a DC offset on i_beta.
                let i = AlphaBeta::new(-i_q * th.sin(), i_q * th.cos() + offset);
                let c = e.thrust_change(psi, i, travel);
                extreme = if c.abs() > extreme.abs() { c } else { extreme };
            }
            extreme
        };
        // Settled at no thrust, then a step of half the rated current.
        run(&mut e, 0.0, 0.0, 10_000);
        let step = run(&mut e, 0.5 * rated, 0.0, 2_000);
        // The two low-passes' step responses differ by exp(-b x) - exp(-a x) over the
        // travel x, at most r^(b / (a - b)) - r^(a / (a - b)) with r = b / a (0.472).
        let (a, b) = (f64::from(THRUST_FAST_RATE_PER_RAD), f64::from(THRUST_SLOW_RATE_PER_RAD));
        let r = b / a;
        let peak = r.powf(b / (a - b)) - r.powf(a / (a - b));
        let share = 0.5 / f64::from(THRUST_CHANGE_PER_RATED_CURRENT);
        assert!((step / (share * peak) - 1.0).abs() < 0.02, "{step} against {}", share * peak);
        // A DC offset of a tenth of the rated current on i_beta ripples the thrust at `w`
        // (one rad per rad of travel), through |a / (a + j) - b / (b + j)| (0.333).
        let mut e = armed(&motor);
        run(&mut e, 0.0, 0.1 * rated, 10_000);
        let ripple = run(&mut e, 0.0, 0.1 * rated, 2_000).abs();
        let gain = (a / (a * a + 1.0) - b / (b * b + 1.0)).hypot(1.0 / (a * a + 1.0) - 1.0 / (b * b + 1.0));
        let expected = 0.1 / f64::from(THRUST_CHANGE_PER_RATED_CURRENT) * gain;
        assert!((ripple / expected - 1.0).abs() < 0.03, "{ripple} against {expected}");
    }

    fn armed(motor: &MotorParams) -> Estimator<f64> {
        let config = EstimatorConfig::for_motor(motor, ObserverKind::Dcfo);
        let mut e = Estimator::<f64>::new(motor, &config, &Base::SI).unwrap();
        e.compensation_armed = 1.0;
        e
    }

    /// What the output is turned back by for a true angle error `err` (rad).
    fn expected(err: f64) -> f64 {
        let db = OFFSET_PHASE_DEADBAND_RAD as f64;
        OFFSET_PHASE_SHARE as f64 * (err - err.clamp(-db, db))
    }

    /// A flux estimate carrying a constant offset `delta` (a tenth of the flux) turning
    /// at `w` either way: after the band-pass has settled, the reading follows the angle
    /// error the offset causes, `atan2` of its parts across and along the true flux.
    #[test]
    fn a_constant_offset_is_read_as_the_angle_error_it_causes() {
        let motor = MotorParams::paper();
        for w in [2.0 * core::f64::consts::PI * 10.0, -2.0 * core::f64::consts::PI * 10.0] {
            for phi in [0.0, 1.0, 2.5] {
                let mut e = armed(&motor);
                let psi_f = motor.psi_f_wb as f64;
                let delta = (0.1 * psi_f * f64::cos(phi), 0.1 * psi_f * f64::sin(phi));
                let period = (2.0 * core::f64::consts::PI / (w.abs() * DT)) as usize;
                let mut prev = AlphaBeta::new(psi_f + delta.0, delta.1);
                let mut worst = 0.0f64;
                for n in 1..4 * period {
                    let th = w * n as f64 * DT;
                    let psi = AlphaBeta::new(psi_f * th.cos() + delta.0, psi_f * th.sin() + delta.1);
                    let read = e.offset_phase(psi, prev, 0.0, w, w.abs().max(e.agreement_floor) * DT, DT);
                    prev = psi;
                    // Angle of the estimate less the true angle.
                    let err = f64::atan2(
                        -delta.0 * th.sin() + delta.1 * th.cos(),
                        psi_f + delta.0 * th.cos() + delta.1 * th.sin(),
                    );
                    if n > 3 * period {
                        worst = worst.max((read - expected(err)).abs());
                    }
                }
                // The reading is the first-order angle (an offset of 0.1 of the flux
                // leaves a second-order part) through the band-pass (its phase at
                // w dt = 0.006): 0.0038 rad at the worst measured.
                assert!(worst < 0.006, "w {w}, offset at {phi} rad: {worst} rad off");
            }
        }
    }

    /// A salient motor's active flux grows with the current along it, `(Ld - Lq) i_d`:
    /// a ripple of `i_d` is not an offset, and the reading stays in its dead band; read
    /// without the saliency term it would not.
    #[test]
    fn a_salient_motors_current_ripple_is_not_read_as_an_offset() {
        let motor = MotorParams { ld_h: 0.006, lq_h: 0.012, ..MotorParams::paper() };
        let w = 2.0 * core::f64::consts::PI * 10.0;
        let psi_f = motor.psi_f_wb as f64;
        let saliency = (motor.ld_h - motor.lq_h) as f64;
        let run = |compensated: bool| {
            let mut e = armed(&motor);
            if !compensated {
                e.saliency = 0.0;
            }
            let mut prev = AlphaBeta::new(psi_f, 0.0);
            let mut along_prev = 0.0;
            let mut worst = 0.0f64;
            for n in 1..4000 {
                let th = w * n as f64 * DT;
                // i_d swings by 2 A at 2 w: the active flux by 0.012 Wb.
                let i_d = 2.0 * (2.0 * th).sin();
                let m = psi_f + saliency * i_d;
                let psi = AlphaBeta::new(m * th.cos(), m * th.sin());
                let i = AlphaBeta::new(i_d * th.cos(), i_d * th.sin());
                let along = i.alpha * psi.alpha + i.beta * psi.beta;
                worst = worst.max(
                    e.offset_phase(psi, prev, along - along_prev, w, w.abs().max(e.agreement_floor) * DT, DT)
                        .abs(),
                );
                prev = psi;
                along_prev = along;
            }
            worst
        };
        assert!(run(true) < 1e-3, "compensated: {}", run(true));
        assert!(run(false) > 0.01, "uncompensated: {}", run(false));
    }

    /// The FLL's trust follows the DC offset's angle reading: withdrawn while an offset
    /// of a tenth of the flux turns with it (from half a period, as the band-pass builds
    /// up, over the period after; the DCFO's slowest pole, `0.26 w`, removes a step's
    /// offset with a time constant of 0.6 of a period), kept through a speed
    /// change like the paper's 40 N load step (a third of the speed lost in about 90 ms)
    /// on a flux without one. An offset that stays becomes the reading's level, and the
    /// trust comes back within a few seconds.
    #[test]
    fn a_dc_offset_withdraws_the_flls_trust_and_a_speed_change_keeps_it() {
        let motor = MotorParams::paper();
        let psi_f = motor.psi_f_wb as f64;
        let w0 = 2.0 * core::f64::consts::PI * 10.0;
        // The lowest and highest trust from `from` to `to` seconds, and the last.
        let run = |offset: f64, drop: f64, (from, to): (f64, f64)| {
            let mut e = armed(&motor);
            let (mut th, mut prev) = (0.0f64, AlphaBeta::new(psi_f + offset, 0.0));
            let (mut range, mut last) = ((1.0f64, 0.0f64), 0.0);
            for n in 1..(to / DT) as usize {
                let t = n as f64 * DT;
                let w = w0 * (1.0 - drop * (1.0 - (-t / 0.03).exp()));
                th += w * DT;
                let psi = AlphaBeta::new(psi_f * th.cos() + offset, psi_f * th.sin());
                e.offset_phase(psi, prev, 0.0, w, w.abs().max(e.agreement_floor) * DT, DT);
                last = e.fll_trust(w.abs().max(e.agreement_floor) * DT);
                prev = psi;
                if t > from {
                    range = (range.0.min(last), range.1.max(last));
                }
            }
            (range, last)
        };
        assert_eq!(run(0.1 * psi_f, 0.0, (0.05, 0.15)).0, (0.0, 0.0), "offset: trust kept");
        assert_eq!(run(0.0, 0.35, (0.0, 0.3)).0, (1.0, 1.0), "speed change: trust withdrawn");
        assert_eq!(run(0.0, 0.0, (0.0, 0.3)).0, (1.0, 1.0), "steady: trust withdrawn");
        assert_eq!(run(0.1 * psi_f, 0.0, (0.05, 5.0)).1, 1.0, "lasting offset: trust never back");
    }

    /// The paper motor at 10 Hz on ideal inputs, locked and armed, then a +2 V step on
    /// `u_alpha` at 16 phases of a period: the largest deviation of the notch frequency
    /// from the mover's and the largest angle error over 0.3 s after it, with the FLL's
    /// trust as built or, with `trusting`, the FLL trusted whatever the offset.
    fn dc_step_on_ideal_inputs(trusting: bool) -> (f64, f64) {
        let motor = MotorParams::paper();
        let config = EstimatorConfig::for_motor(&motor, ObserverKind::Dcfo);
        let (r, l, psi_f) = (motor.rs_ohm as f64, motor.ld_h as f64, motor.psi_f_wb as f64);
        let w = 2.0 * core::f64::consts::PI * 10.0;
        let i_q = 0.5;
        let (mut notch_worst, mut angle_worst) = (0.0f64, 0.0f64);
        for phase in 0..16 {
            let mut e = Estimator::<f64>::new(&motor, &config, &Base::SI).unwrap();
            if trusting {
                e.inv_fll_trust_offset = 0.0;
            }
            let t_step = 1.5 + phase as f64 / 16.0 * 0.1;
            for n in 0..((t_step + 0.3) / DT) as usize {
                let t = n as f64 * DT;
                let (s, c) = (w * t).sin_cos();
                // i = j i_q e^{j w t}; u = R i + L di/dt + j w psi_f e^{j w t}.
                let i = AlphaBeta::new(-i_q * s, i_q * c);
                let du = if t >= t_step { 2.0 } else { 0.0 };
                let u = AlphaBeta::new(
                    r * i.alpha - l * i_q * w * c - w * psi_f * s + du,
                    r * i.beta - l * i_q * w * s + w * psi_f * c,
                );
                let est = e.update(u, i, DT).unwrap();
                if t >= t_step {
                    let err = (est.theta_e.to_radians::<f64>() - w * t + core::f64::consts::PI)
                        .rem_euclid(2.0 * core::f64::consts::PI)
                        - core::f64::consts::PI;
                    angle_worst = angle_worst.max(err.abs().to_degrees());
                    notch_worst = notch_worst.max((e.notch_omega() / w - 1.0).abs());
                } else if t > 1.4 {
                    assert!(est.locked && !est.acquiring, "not locked before the step");
                }
            }
        }
        (notch_worst, angle_worst)
    }

    /// While a DC step's offset turns in the flux, the FLL reads it as a ripple at `w`
    /// (the [`crate::algorithms::fll`] docs) and its band would drag the notch; trusted only as far as
    /// the offset reading allows, it leaves the notch to the PLL's integrator. Measured:
    /// the notch at most 0.102 of the mover's frequency off (0.145 trusting the FLL), the
    /// angle 9.60 deg (12.42); the rest of the notch's excursion is the PLL integrator's
    /// response to the offset's angle. The angle is held to the issue's +2 V floor (10 deg).
    #[test]
    fn a_dc_step_does_not_drag_the_notch_through_the_fll() {
        let (notch, angle) = dc_step_on_ideal_inputs(false);
        let (notch_trusting, angle_trusting) = dc_step_on_ideal_inputs(true);
        assert!(notch < 0.8 * notch_trusting, "notch {notch} ({notch_trusting} trusting)");
        assert!(angle < angle_trusting && angle <= 10.0, "{angle} deg ({angle_trusting} trusting)");
    }
}
