//! Phase-locked loop on the mover-flux estimate (docs/method.md §4): angle and speed.
//!
//! ```text
//! eps   = -psi_a sin(theta_hat) + psi_b cos(theta_hat) = |psi| sin(theta - theta_hat)
//! eps_n = eps / |psi|
//! omega_hat = kp eps_n + ki integral(eps_n)
//! d theta_hat / dt = omega_hat,      v_hat = omega_hat * pole_pitch / pi
//! ```
//!
//! Normalising by `|psi|` makes the small-signal loop `(kp s + ki)/(s^2 + kp s + ki)`
//! whatever the flux level, so `kp = 2 zeta_p w_p`, `ki = w_p^2` set its bandwidth.
//! Discrete form per sample: `eps_n` from the predicted angle, the integrator by
//! forward Euler, then the angle advances by `omega_hat * dt` on a binary [`Angle`]
//! (exact wrapping). A flux below a floor gives no usable error: the loop then
//! coasts (angle advances at the integrator's speed, nothing is integrated) and says so.
//!
//! ## Tuning the DCFO's notch: use [`Pll::omega_integral`]
//! The DCFO's phase at the fundamental moves by about `1/(zeta w)` rad per rad/s of
//! notch-frequency error (docs/method.md §8), so the PLL and the notch form a loop. With an
//! instantaneous phase shift `c (w_notch - w)`, `c = 1/(zeta w)`:
//! - notch at the full `omega_hat = kp eps_n + integral`: characteristic polynomial
//!   `(1 - c kp) s^2 + (kp - c ki) s + ki`, which needs `2 zeta_p w_p < zeta w` — a PLL
//!   slower than the fundamental. Measured with `w_p = 2 pi 20`, `zeta_p = 1` at 10 Hz:
//!   a sustained +-10 degree oscillation.
//! - notch at the integrator alone ([`Pll::omega_integral`], the loop's frequency
//!   estimate without the phase correction): `s^2 + (kp - c ki) s + ki`, stable while
//!   `w_p < 2 zeta_p zeta w`. Its cost is on ramps: on a ramp of `a` rad/s^2 the
//!   integrator lags by `kp a / ki` (`8 a / w` with the defaults below), the notch is
//!   detuned by that, and the observer's angle lags by `c kp a / ki = 8 a / w^2` rad:
//!   11.4 deg predicted and 11-12 deg measured on the paper's 0.24 -> 0.45 m/s step at
//!   0.5 m/s^2, the whole of that scenario's error; 80 deg at a positioning axis's
//!   3 m/s^2. A ramp the drive *commands* is known in advance: the estimator runs the
//!   loop's linear model `x' = u - kp x, u' = a - ki x` on the commanded ramp `a` (its
//!   `u` is the integrator's lag `w - integral`, `kp a / ki` once the ramp has lasted,
//!   built up with the loop's own slow pole) and adds `u` to the notch
//!   (the estimator's `Estimator::set_commanded_acceleration`) — a feed-forward, no loop.
//!   Estimating the lag from the loop's own error instead (`integral + kp eps_f`,
//!   `eps_f` low-passed) closes the notch loop through the observer's phase response
//!   (a step of notch error reaches its static phase shift after about `2.4 / w` and
//!   overshoots by 18 %), and with `c kp = 8` it is stable on an ideal flux only for a
//!   filter slower than `w / 2` and makes the closed-loop drive oscillate at 4 Hz even
//!   at `w / 4`; the FLL's derivative as the acceleration is worse. This is what the
//!   drive uses in steady state; while
//!   acquiring and in speed transients the FLL of [`crate::algorithms::fll`] tunes the notch and
//!   feeds this loop forward ([`Pll::update_with_feedforward`], see the
//!   estimator).
//!
//! ## Bandwidth scaled with speed
//! That condition ties the PLL's bandwidth to the electrical speed, so the gains are
//! scheduled on the frequency estimate: `w_p = beta |omega_hat|` (limited to a range),
//! `kp = 2 zeta_p w_p`, `ki = w_p^2` — the same loop shape at every speed, as the
//! DCFO's `h = eta Ls w` gives the observer.
//!
//! ## Default tuning: beta = 1, zeta_p = 4
//! The estimator's speed output feeds the drive's speed loop, so its response to real
//! speed changes must be flat, not just stable. Measured on a synthetic 10 Hz motor with
//! a sinusoidal speed wobble (DCFO zeta = 0.707): `beta = 1.5, zeta_p = 1.5` peaks at
//! |v_hat / v| = 1.77 near 30 rad/s, and the closed-loop drive limit-cycled there;
//! `beta = 1, zeta_p = 4` peaks at 1.16 with -19 degrees at 15 rad/s. The coupling bound
//! `beta < 2 zeta_p zeta` is then met eightfold. Poles at `-0.13 w` and `-7.9 w`: the
//! frequency estimate converges slowly (130 ms at 10 Hz), the phase quickly. The cost is
//! on ramps: the notch lags by `kp a / ki` rad/s during a ramp of `a` rad/s^2, which a
//! drive bounds by limiting its acceleration. Limits `2 pi [3, 40] Hz`.

use crate::algorithms::transforms::{AlphaBeta, CosSin};
use crate::num::units::Base;
use crate::num::{Angle, Scalar, positive};

/// PLL tuning, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PllConfig {
    /// Natural frequency `w_p` of the closed loop per unit of estimated electrical
    /// speed (dimensionless, > 0): `w_p = bandwidth_per_omega * |omega_hat|`, limited to
    /// `[min_bandwidth_rad_s, max_bandwidth_rad_s]`.
    pub bandwidth_per_omega: f32,
    /// Lowest natural frequency (rad/s, > 0), used at and near standstill.
    pub min_bandwidth_rad_s: f32,
    /// Highest natural frequency (rad/s, >= min).
    pub max_bandwidth_rad_s: f32,
    /// Damping `zeta_p` of the closed loop (dimensionless, > 0).
    pub damping: f32,
    /// Flux magnitude below which the phase error is not used (Wb, > 0).
    pub min_flux_wb: f32,
    /// Speed-estimate limit (rad/s electrical, > 0): the integrator is held inside
    /// `+-max_omega_rad_s`.
    pub max_omega_rad_s: f32,
    /// Time constant of the lock detector's error filter (s, > 0).
    pub lock_filter_s: f32,
    /// The loop counts as locked while the filtered `|sin(error)|` is below this
    /// (dimensionless, in (0, 1)).
    pub lock_threshold: f32,
}

impl PllConfig {
    /// The default tuning for a motor of magnet flux `psi_f_wb` (see the module docs):
    /// `w_p = |omega_hat|` within `2 pi [3, 40] Hz`, `zeta_p = 4`, flux floor
    /// `psi_f / 10`, speed limit `2 pi 200 Hz`, lock declared below `sin(10 deg)` of error
    /// filtered over 20 ms.
    pub fn for_flux(psi_f_wb: f32) -> Self {
        PllConfig {
            bandwidth_per_omega: 1.0,
            min_bandwidth_rad_s: 2.0 * core::f32::consts::PI * 3.0,
            max_bandwidth_rad_s: 2.0 * core::f32::consts::PI * 40.0,
            damping: 4.0,
            min_flux_wb: 0.1 * psi_f_wb,
            max_omega_rad_s: 2.0 * core::f32::consts::PI * 200.0,
            lock_filter_s: 0.02,
            lock_threshold: 0.173_648_18,
        }
    }
}

/// Why a PLL could not be built; names the setting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PllConfigError {
    /// A bandwidth setting or `damping` is not a valid positive number, or the
    /// bandwidth range is empty.
    BadGain,
    /// `min_flux_wb` is not a valid positive number.
    BadFluxFloor,
    /// `max_omega_rad_s` is not a valid positive number.
    BadSpeedLimit,
    /// `lock_filter_s` or `lock_threshold` out of range.
    BadLockDetector,
}

/// Why the PLL refused a sample (state unchanged).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PllFault {
    /// The flux input was NaN, infinite or out of range.
    InvalidInput,
    /// The period was not a valid positive number.
    InvalidPeriod,
}

/// One sample of PLL output, in working units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PllOutput<T> {
    /// Estimated electrical angle at this sample (the one the error was measured with).
    pub theta_e: Angle,
    /// Cosine and sine of `theta_e` (dimensionless), computed for the phase detector
    /// and handed on so that a Park transform at the same angle need not recompute them.
    pub cos_sin: CosSin<T>,
    /// Estimated electrical speed (rad/s).
    pub omega_e: T,
    /// Estimated linear speed (m/s, SI in every unit system): `omega_e * pole_pitch / pi`.
    pub speed_m_per_s: T,
    /// Normalised phase error `sin(theta - theta_hat)` (dimensionless); zero while coasting.
    pub error: T,
    /// `false` while the flux is below the floor and the loop coasts.
    pub tracking: bool,
    /// `true` while the filtered phase error is below the lock threshold.
    pub locked: bool,
}

/// The PLL. See the module documentation.
#[derive(Clone, Debug)]
pub struct Pll<T> {
    beta: T,
    two_zeta: T,
    min_wp: T,
    max_wp: T,
    /// The smallest flux amplitude that steers, squared (working units).
    min_flux_sq: T,
    max_omega: T,
    speed_per_omega: T,
    lock_rate: T,
    lock_threshold: T,
    theta: Angle,
    integral: T,
    /// What the integrator's updates added below its resolution, times
    /// [`INTEGRAL_RESIDUE_SCALE`] (rad/s, working units).
    integral_residue: T,
    /// `1 / INTEGRAL_RESIDUE_SCALE`, exact in every type.
    inv_residue_scale: T,
    /// [`INTEGRAL_RESIDUE_SCALE`].
    residue_scale: T,
    lock_metric: T,
}

/// How finely the frequency integrator's updates are kept below its working unit's
/// resolution (dimensionless, a power of two): the integrator carries a residue in
/// 64ths of its least step. In Q8.24 at 0.1 m/s on the paper motor's base an update
/// `w_p^2 dt eps` is about 650 LSB times the phase error, so without the residue errors
/// below 0.00076 rad leave the integrator where it is and the loop holds the frequency
/// with `kp eps` instead: the integrator, which tunes the DCFO's notch, stays anywhere
/// within 0.13 rad/s (0.6 %) of the mover's frequency, and rounded down it drifts to the
/// edge (`dcfo acquire` at 0.1 m/s: a notch 0.6 % off, 0.35 deg of flux angle from
/// f32's). A 64th takes that down to 0.002 rad/s. In `f32` the residue is always zero
/// (the scaling by a power of two is exact), so the update is the plain one bit for
/// bit.
pub const INTEGRAL_RESIDUE_SCALE: f32 = 64.0;

impl<T: Scalar> Pll<T> {
    /// A PLL for a motor of pole pitch `pole_pitch_m` (m), tuned by `config` and
    /// converted with `base`. Starts at angle 0, speed 0, unlocked.
    pub fn new(config: &PllConfig, pole_pitch_m: f32, base: &Base) -> Result<Self, PllConfigError> {
        if !(positive(config.bandwidth_per_omega)
            && positive(config.min_bandwidth_rad_s)
            && positive(config.damping)
            && config.max_bandwidth_rad_s >= config.min_bandwidth_rad_s
            && config.max_bandwidth_rad_s.is_finite())
        {
            return Err(PllConfigError::BadGain);
        }
        if !positive(config.min_flux_wb) {
            return Err(PllConfigError::BadFluxFloor);
        }
        if !positive(config.max_omega_rad_s) {
            return Err(PllConfigError::BadSpeedLimit);
        }
        if !(positive(config.lock_filter_s) && positive(config.lock_threshold) && config.lock_threshold < 1.0)
        {
            return Err(PllConfigError::BadLockDetector);
        }
        Ok(Pll {
            beta: T::from_f32(config.bandwidth_per_omega),
            two_zeta: T::from_f32(2.0 * config.damping),
            min_wp: base.omega(config.min_bandwidth_rad_s),
            max_wp: base.omega(config.max_bandwidth_rad_s),
            min_flux_sq: {
                let m: T = base.flux(config.min_flux_wb);
                m * m
            },
            max_omega: base.omega(config.max_omega_rad_s),
            speed_per_omega: T::from_f32(base.omega_rad_s * pole_pitch_m / core::f32::consts::PI),
            lock_rate: base.rate(1.0 / config.lock_filter_s),
            lock_threshold: T::from_f32(config.lock_threshold),
            theta: Angle::ZERO,
            integral: T::ZERO,
            integral_residue: T::ZERO,
            inv_residue_scale: T::from_f32(1.0 / INTEGRAL_RESIDUE_SCALE),
            residue_scale: T::from_f32(INTEGRAL_RESIDUE_SCALE),
            lock_metric: T::ONE,
        })
    }

    /// Processes the flux estimate `psi_ab` (Wb) of this sample, `dt` (s) after the
    /// previous one: the paper's loop, its gains scheduled on its own frequency estimate.
    pub fn update(&mut self, psi_ab: AlphaBeta<T>, dt: T) -> Result<PllOutput<T>, PllFault> {
        let schedule = self.integral.abs();
        self.update_with_feedforward(psi_ab, T::ZERO, schedule, dt)
    }

    /// Processes `psi_ab` (Wb) with a frequency feed-forward `omega_ff` (rad/s, from an
    /// independent frequency estimate such as [`crate::algorithms::fll`]): the angle advances at
    /// `omega_ff + integral + kp eps_n`, so the integrator only tracks what the
    /// feed-forward misses and a speed ramp that the feed-forward follows costs no
    /// phase. `schedule_omega` (rad/s, >= 0) sets the bandwidth, `w_p = beta
    /// schedule_omega` within the configured range.
    pub fn update_with_feedforward(
        &mut self,
        psi_ab: AlphaBeta<T>,
        omega_ff: T,
        schedule_omega: T,
        dt: T,
    ) -> Result<PllOutput<T>, PllFault> {
        if !dt.is_valid() || dt <= T::ZERO {
            return Err(PllFault::InvalidPeriod);
        }
        if !psi_ab.is_valid() || !omega_ff.is_valid() || !schedule_omega.is_valid() {
            return Err(PllFault::InvalidInput);
        }
        let theta = self.theta;
        let cos_sin = CosSin::inline(theta);
        let eps = psi_ab.beta.mul_unit(cos_sin.cos) - psi_ab.alpha.mul_unit(cos_sin.sin);
        // eps / |psi| as eps * (|psi|^2)^-1/2: no square root and no division (both are
        // software routines in fixed point on an FPU-less core).
        let magnitude_sq = psi_ab.alpha * psi_ab.alpha + psi_ab.beta * psi_ab.beta;
        let normalised = if magnitude_sq >= self.min_flux_sq {
            magnitude_sq.inv_sqrt().map(|inv| eps * inv)
        } else {
            None
        };
        let (error, tracking) = match normalised {
            Some(e) => (e.clamp_to(-T::ONE, T::ONE), true),
            None => (T::ZERO, false),
        };
        // Gains scheduled on the frequency estimate: kp = 2 zeta_p w_p, ki = w_p^2 (in
        // working units both scale with the omega base as they should).
        let wp = (self.beta * schedule_omega.abs()).clamp_to(self.min_wp, self.max_wp);
        let kp = self.two_zeta * wp;
        if tracking {
            // integral += w_p^2 dt error, with what falls below the integrator's
            // resolution carried to the next sample ([`INTEGRAL_RESIDUE_SCALE`]); each
            // product rounded to nearest, so no bias accumulates either.
            let residue = self.integral_residue + (wp * wp * dt * self.residue_scale).mul_nearest(error);
            let carry = residue.mul_nearest(self.inv_residue_scale);
            self.integral_residue = residue - carry * self.residue_scale;
            self.integral = (self.integral + carry).clamp_to(-self.max_omega, self.max_omega);
            let rate = (self.lock_rate * dt).min(T::ONE);
            self.lock_metric = self.lock_metric + (error.abs() - self.lock_metric).mul_unit(rate);
        }
        // |error| <= 1 (clamped above).
        let omega = omega_ff + self.integral + kp.mul_unit(error);
        self.theta = theta + (omega * dt).radians_to_angle();
        Ok(PllOutput {
            theta_e: theta,
            cos_sin,
            omega_e: omega,
            speed_m_per_s: omega * self.speed_per_omega,
            error,
            tracking,
            locked: tracking && self.lock_metric < self.lock_threshold,
        })
    }

    /// Sets the estimate to angle `theta_e` and speed `omega_e` (rad/s, working units),
    /// e.g. at hand-over from open-loop start-up; the lock detector starts unlocked.
    pub fn preset(&mut self, theta_e: Angle, omega_e: T) {
        self.theta = theta_e;
        self.integral = omega_e.clamp_to(-self.max_omega, self.max_omega);
        self.integral_residue = T::ZERO;
        self.lock_metric = T::ONE;
    }

    /// Sets the frequency integrator to `omega_e` (rad/s, working units), keeping the
    /// angle and the lock detector: moves the frequency between a feed-forward and the
    /// integrator.
    pub fn set_integral(&mut self, omega_e: T) {
        // The residue (below one LSB of the integrator) is kept: the estimator nudges the
        // integrator with this every sample while it is outside the FLL's band, and
        // clearing it each time would bring back the updates' dead zone.
        self.integral = omega_e.clamp_to(-self.max_omega, self.max_omega);
    }

    /// Back to angle 0, speed 0, unlocked.
    pub fn reset(&mut self) {
        self.preset(Angle::ZERO, T::ZERO);
    }

    /// The angle the next sample's error will be measured against.
    pub fn predicted_angle(&self) -> Angle {
        self.theta
    }

    /// The speed-estimate limit (rad/s, working units).
    pub fn max_omega(&self) -> T {
        self.max_omega
    }

    /// The loop's gains at its present frequency estimate: `(kp, ki)` = `(2 zeta_p w_p,
    /// w_p^2)` (1/s and 1/s^2 in working units), `w_p = beta |integral|` within range.
    pub fn gains(&self) -> (T, T) {
        let wp = (self.beta * self.integral.abs()).clamp_to(self.min_wp, self.max_wp);
        (self.two_zeta * wp, wp * wp)
    }

    /// The integrator's speed (rad/s, working units): the loop's frequency estimate
    /// without the proportional phase correction. Tune the DCFO's notch with this, not
    /// with the full estimate (see the module docs).
    pub fn omega_integral(&self) -> T {
        self.integral
    }
}
