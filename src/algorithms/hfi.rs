//! High-frequency injection (HFI): the mover angle of a *salient* motor at standstill
//! and low speed, where no back-EMF estimator sees anything, with magnet-polarity
//! detection.
//!
//! ## Choice: pulsating square-wave injection at half the PWM rate
//! A voltage `+U_h, -U_h, +U_h, ...` (one PWM period each) is added along the
//! *estimated* d axis `d^`. Against a rotating (sinusoidal) injection:
//! - **Highest injection frequency the inverter can make** (`f_h = f_pwm / 2`): the HF
//!   current, and so the torque ripple and the voltage it costs, is the smallest for a
//!   given signal; the separation from the fundamental (tens of hertz) is three decades.
//! - **Demodulation without filters**: the response of each period is the difference of
//!   two current samples; two consecutive responses of opposite sign cancel the
//!   fundamental's change exactly to first order (its slope), and the mean of two samples
//!   is the fundamental current the current loops see (the triangle's mean). No band-pass,
//!   no low-pass, no phase lag beyond the sampling: the tracking loop's bandwidth is set
//!   by the sensor noise (below), not by demodulation filters.
//! - **Along d^**: the injection produces almost no thrust (`d^` is the flux axis once
//!   converged), and on d it also reads the magnet's polarity by saturation (below).
//!   A rotating injection would put the HF on q as well (thrust ripple, noise).
//!
//! ## HF current response (what [`Hfi`] demodulates)
//! Let `dth = theta - theta^` (true minus estimated angle). Over one period `T` at
//! standstill or low speed the HF voltage dominates resistance, back-EMF and
//! cross-coupling, so in the *true* frame `L_d di_d/dt = u_d`, `L_q di_q/dt = u_q`. The
//! injected vector `(U, 0)` in the estimated frame is `(U cos dth, -U sin dth)` in the
//! true frame; the current steps by `U T (cos dth / L_d, -sin dth / L_q)`, which, back
//! in the estimated frame, is
//!
//! ```text
//! di_d^ = U T (S + D cos 2 dth)         S = (1/L_d + 1/L_q) / 2
//! di_q^ = U T  D sin 2 dth              D = (1/L_d - 1/L_q) / 2
//! ```
//!
//! per period, with the sign of the period's voltage (the samples alternate by that much
//! about the fundamental). Resistance makes the periodic steady state `2 (U / R)
//! tanh(R T / (2 L))` per axis: `U T / L` less `(R T / L)^2 / 12`, 0.09 % on
//! `motors/salient.toml`. `host/src/plant/tests.rs` checks the simulated plant, PWM and
//! dead time included, against these formulas.
//!
//! ## Demodulation and angle-error signal
//! The current sampled at `t_k` minus the one at `t_{k-1}` is the response to the
//! command of step `k - 2` (one period of computation delay): it is rotated into the
//! frame that command was injected in and multiplied by its sign. The mean of two such
//! responses (the command of `k - 2` and of `k - 3`, opposite signs) cancels the
//! fundamental's slope. Normalised by the nominal `U T D`:
//!
//! ```text
//! e = sign * di_q^ / (U_h T D)  =  sin 2 dth  ~  2 dth      (gain 2 / rad)
//! ```
//!
//! The signal's size is `U_h T D = U_h T (L_q - L_d) / (2 L_d L_q)` ampere per unit of
//! `sin 2 dth`: proportional to the injection voltage, to `1 / f_h`, and to the
//! saliency. With the default `U_h = 0.25 I_pk L_d / T` (the d current swings by 25 % of
//! the rated peak current `I_pk` each period) it is `0.125 I_pk (1 - L_d/L_q)`: 0.18 A per
//! unit on `motors/salient.toml` (`I_pk` 4.24 A, `L_q/L_d` 1.5, `U_h` 63.6 V). An error in `L_d`, `L_q`
//! changes the loop gain, not the zero of `e`: the equilibrium is the true d axis
//! whatever the motor file says. `e` is pi-periodic: the loop settles on the magnet's
//! axis, north or south, which the polarity test decides.
//!
//! Inverter: the dead time's voltage error is `-V_dt sign(i)` per phase. While a phase
//! current keeps its sign through the HF swing the error is the same in both half
//! periods and cancels in the demodulation; a phase whose current crosses zero with the
//! HF (its fundamental below the HF swing) loses up to `V_dt = V_bus t_dead / T` of its
//! HF voltage, which tilts the injected vector and biases `e` (measured in the plant
//! tests: 9-11 % of the response at 38 V). Hence `U_h` many times `V_dt`: 63.6 V against
//! 5.7 V on the salient motor; it may take up to 40 % of the linear voltage range, as
//! at standstill and low speed the fundamental needs little (`R I` and a small back-EMF).
//! The drive's inverter compensation takes the square wave's ramp at the switching edges
//! into account ([`crate::algorithms::dead_time`], "Under injection").
//!
//! ## Tracking loop
//! A PI on `e` drives the estimate: `omega^ = kp e + ki sum(e T)`, `theta^ += omega^ T`.
//! With `e ~ 2 dth` the closed loop is `s^2 + 2 kp s + 2 ki`: `kp = zeta w_n`,
//! `ki = w_n^2 / 2`. The injection is advanced by `1.5 T omega^` (to the middle of its
//! application window), so a moving mover is tracked without a lag. The bandwidth is a
//! trade against sensor noise: white noise `sigma` per current sample enters `e` as
//! `s_k (n_k - 2 n_{k-1} + n_{k-2}) / 2`, which at low frequency is white noise of
//! `2 sigma` (the sign alternates), i.e. `2 sigma / (U_h T D)` of `e` or
//! `sigma / (U_h T D)` of angle, filtered by the loop's noise bandwidth
//! `B_L = (w_n / 2)(zeta + 1 / 4 zeta)` Hz: angle RMS `sigma / (U_h T D) sqrt(2 B_L T)`.
//! Default `w_n = 2 pi f_pwm / 200` (314 rad/s, 50 Hz at 10 kHz), `zeta = 1`
//! (`B_L` = 196 Hz): 1.3 degrees RMS for the 20 mA of the simulated sensors on the
//! salient motor (at `f_pwm / 100` and `U_h` = 38 V: 3 degrees RMS predicted, up to
//! 16 degrees peak measured over 50 ms on the stroke's plant). The measurement's delay
//! (2.5 periods) costs 9 degrees of phase at `2 w_n`.
//!
//! ### Where the bus limits the injection
//! `U_h` is capped at [`MAX_SHARE_OF_LINEAR_RANGE`] of the linear range, which a motor of
//! large `L_d` on a low bus reaches: the signal `U_h T D` is then the share
//! `r = U_h / (0.25 I_pk L_d / T)` of the one the swing was chosen for, and at the full
//! bandwidth the angle noise is `1 / r` times that design's. The bandwidth is scaled by
//! `r` too. The angle noise then grows as `1 / sqrt r` only, and the hold's thrust-current
//! noise falls: its observer and PD scale with `w_n` (the drive's `HOLD_OBSERVER_SHARE`),
//! the position gain as `w_n^2`, so the current noise goes as `w_n^2.5 / U_h`, that is
//! `r^1.5`. The price is the loop's lag on a ramp (`2 zeta a / w_n`) and its speed limit
//! (`w_n`), so the bandwidth is kept at least [`TRACKING_MARGIN`] times the fastest
//! electrical speed the drive runs HFI at (the low-speed band's exit). On a 6 kg salient
//! motor of 32 mm pitch, 10 / 16 mH on a 283 V bus (`r` = 0.37; `w_n` = 126 rad/s, its
//! floor), at rest on the stroke's plant (`dcfo stroke`, 50 mA of sensor noise): 3.2
//! degrees RMS of angle noise and 0.7 A RMS of thrust current. At the full bandwidth the
//! same axis gives 5.2 degrees (4.4 predicted) and 3.2 A RMS, and its stroke overshoots
//! the profile's speed by twice the 10 % floor.
//!
//! ## Polarity at standstill: d-axis saturation
//! Once the loop has converged (held [`HfiConfig::settle_s`] and locked), two voltage
//! pulse pairs are applied on `d^` with the HF off, each after a rest of `M` periods
//! for the current to decay (the HF swing left as a start would bias the first peak:
//! measured, margins of 0.08 without a turn by pi against 0.035 with one): `+U_p` for `N`
//! periods then `-U_p` for `N` (the flux returns to where it started, and so does the
//! current), the rest, then `-U_p, +U_p`. `N` is chosen so that the pulse's flux
//! `U_p N T` drives about 1.5 times the rated peak current through `L_d` (at the rated
//! peak current the margins are 0.011 to 0.08 on the simulated salient axis).
//! Magnetising the d axis along the magnet saturates the iron further: the incremental
//! `L_d` drops and the current rises higher. So the peak of `i_d^` above its start in the
//! positive pulse, `P+`, exceeds the peak below it in the negative one, `P-`, when
//! `theta^` is on the north pole; otherwise `theta^` is turned by pi. The margin
//! `(P+ - P-) / (P+ + P-)` is reported; below [`HfiConfig::min_polarity_margin`] the test
//! is repeated (up to three times) and the result flagged uncertain. The test costs
//! `2 (2 N + M)` periods (32 ms on the salient motor) and no thrust (`i_q^ = 0`).
//!
//! ## Cost and safety
//! `no_std`, no allocation, no panics (no indexing, no division in the step), bounded
//! time (no loops in [`Hfi::step`]). Generic over [`Scalar`]: `f32`, `f64`, and `Q24`
//! in per-unit ([`Base`]).
#![forbid(unsafe_code)]

use crate::algorithms::transforms::{AlphaBeta, CosSin, Dq, inverse_park, park};
use crate::motor::MotorParams;
use crate::num::units::Base;
use crate::num::{Angle, Scalar, positive};

/// The smallest saliency `L_q / L_d` (dimensionless) HFI is offered for: below it the
/// signal `U_h T D` is under 7 % of the HF current and the estimate is noise- and
/// dead-time-dominated (issue 9).
pub const MIN_SALIENCY: f32 = 1.15;

/// The d current's swing per period the default injection aims at, as a share of the
/// rated peak current (dimensionless): `U_h = SWING_OF_RATED_PEAK I_pk L_d / T`.
pub const SWING_OF_RATED_PEAK: f32 = 0.25;

/// The largest share of the linear voltage range `V_bus / sqrt 3` the default injection
/// takes (dimensionless): at standstill and low speed the fundamental needs little.
pub const MAX_SHARE_OF_LINEAR_RANGE: f32 = 0.4;

/// The default tracking loop's bandwidth over the fastest electrical speed it must
/// follow (dimensionless): its speed limit is its bandwidth.
pub const TRACKING_MARGIN: f32 = 2.0;

/// HFI tuning, SI (see the module docs for the analysis behind each default).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HfiConfig {
    /// Amplitude `U_h` of the square-wave injection on the estimated d axis, V (> 0).
    pub u_hf_v: f32,
    /// PWM period `T`, s (> 0): one half period of the injection.
    pub pwm_period_s: f32,
    /// d-axis inductance `L_d`, H (> 0), as in the motor file.
    pub ld_h: f32,
    /// q-axis inductance `L_q`, H, `L_q / L_d >= MIN_SALIENCY`.
    pub lq_h: f32,
    /// Natural frequency `w_n` of the tracking loop, rad/s (> 0, below `0.2 / T`).
    pub bandwidth_rad_s: f32,
    /// Damping `zeta` of the tracking loop (dimensionless, > 0).
    pub damping: f32,
    /// Limit of the speed estimate, rad/s electrical (> 0).
    pub max_omega_rad_s: f32,
    /// Time the loop tracks before the polarity test, s (>= 0).
    pub settle_s: f32,
    /// Lock: `|e|` low-passed (`e = sin 2 dth`) below this (dimensionless, in (0, 1)).
    pub lock_threshold: f32,
    /// Lock detector's filter time constant, s (> 0).
    pub lock_filter_s: f32,
    /// Polarity pulse voltage `U_p`, V (> 0).
    pub pulse_v: f32,
    /// Polarity pulse length `N`, PWM periods (1..=1000).
    pub pulse_periods: u16,
    /// Rest after each pulse pair `M`, PWM periods (0..=20000).
    pub rest_periods: u16,
    /// Smallest `|P+ - P-| / (P+ + P-)` accepted as a polarity decision (dimensionless, in [0, 1)).
    pub min_polarity_margin: f32,
}

/// Why an [`HfiConfig`] was refused; names the setting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HfiConfigError {
    /// `L_q / L_d` below [`MIN_SALIENCY`] (or an inductance not positive): no usable signal.
    NotSalient,
    /// `u_hf_v`, `pulse_v` or `pwm_period_s` not a positive finite number.
    BadVoltageOrPeriod,
    /// `bandwidth_rad_s`, `damping` or `max_omega_rad_s` out of range.
    BadLoop,
    /// `settle_s`, the lock detector, the pulse counts or the margin out of range.
    BadSequence,
}

impl HfiConfig {
    /// The default tuning for `motor` on an inverter with PWM period `pwm_period_s` (s)
    /// and DC bus `bus_v` (V), from those alone (module docs):
    /// - `U_h = 0.25 I_pk L_d / T` (d current swing 25 % of the rated peak current,
    ///   [`SWING_OF_RATED_PEAK`]), at most 40 % of the linear range `V_bus / sqrt 3`
    ///   ([`MAX_SHARE_OF_LINEAR_RANGE`]);
    /// - `w_n = 2 pi / (200 T)` times the share of that swing's voltage the bus leaves
    ///   `U_h` (module docs, "Where the bus limits the injection"), but at least
    ///   [`TRACKING_MARGIN`] times `tracked_omega_rad_s` (the fastest electrical speed
    ///   the loop must follow, rad/s; 0, a negative speed or NaN for none) and at most
    ///   `2 pi / (200 T)`;
    ///   `zeta = 1`, speed limit `w_n`;
    /// - settle `30 / w_n`; lock below `sin(2 * 5 deg)` filtered over `5 / w_n`;
    /// - `U_p = 2 U_h` (at most half the linear range), `N = 1.5 L_d I_pk / (U_p T)` rounded
    ///   (2..=1000), rest `M = 5 L_d / (R T)` (five time constants, 10..=20000);
    ///   polarity margin 1 %.
    ///
    /// The lock is the angle-error signal `e` low-passed, `|e_f| < sin 10 deg`.
    ///
    /// `Err(NotSalient)` for `L_q / L_d < 1.15`.
    pub fn for_motor(
        motor: &MotorParams,
        pwm_period_s: f32,
        bus_v: f32,
        tracked_omega_rad_s: f32,
    ) -> Result<Self, HfiConfigError> {
        let t = pwm_period_s;
        if !(t.is_finite() && t > 0.0 && bus_v.is_finite() && bus_v > 0.0) {
            return Err(HfiConfigError::BadVoltageOrPeriod);
        }
        let i_pk = motor.rated_current_a * core::f32::consts::SQRT_2;
        let u_linear = bus_v * 0.577_350_26;
        let u_swing_v = SWING_OF_RATED_PEAK * i_pk * motor.ld_h / t;
        let u_hf_v = u_swing_v.min(MAX_SHARE_OF_LINEAR_RANGE * u_linear);
        let full_bandwidth_rad_s = 2.0 * core::f32::consts::PI / (200.0 * t);
        // A NaN or negative tracked speed sets no floor (`f32::max` returns the other).
        let bandwidth_rad_s = (full_bandwidth_rad_s * (u_hf_v / u_swing_v))
            .max(TRACKING_MARGIN * tracked_omega_rad_s)
            .min(full_bandwidth_rad_s);
        let pulse_v = (2.0 * u_hf_v).min(0.5 * u_linear);
        let pulse_periods = libm::roundf(1.5 * motor.ld_h * i_pk / (pulse_v * t)).clamp(2.0, 1000.0) as u16;
        let rest_periods = libm::roundf(5.0 * motor.ld_h / (motor.rs_ohm * t)).clamp(10.0, 20000.0) as u16;
        let config = HfiConfig {
            u_hf_v,
            pwm_period_s: t,
            ld_h: motor.ld_h,
            lq_h: motor.lq_h,
            bandwidth_rad_s,
            damping: 1.0,
            max_omega_rad_s: bandwidth_rad_s,
            settle_s: 30.0 / bandwidth_rad_s,
            lock_threshold: 0.173_648_18,
            lock_filter_s: 5.0 / bandwidth_rad_s,
            pulse_v,
            pulse_periods,
            rest_periods,
            min_polarity_margin: 0.01,
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks every setting; the first refused group by name.
    pub fn validate(&self) -> Result<(), HfiConfigError> {
        if !(positive(self.ld_h) && positive(self.lq_h) && self.lq_h >= MIN_SALIENCY * self.ld_h) {
            return Err(HfiConfigError::NotSalient);
        }
        if !(positive(self.u_hf_v) && positive(self.pulse_v) && positive(self.pwm_period_s)) {
            return Err(HfiConfigError::BadVoltageOrPeriod);
        }
        if !(positive(self.bandwidth_rad_s)
            && self.bandwidth_rad_s * self.pwm_period_s < 0.2
            && positive(self.damping)
            && positive(self.max_omega_rad_s))
        {
            return Err(HfiConfigError::BadLoop);
        }
        if !(self.settle_s.is_finite()
            && self.settle_s >= 0.0
            && self.settle_s / self.pwm_period_s < 1e7
            && positive(self.lock_filter_s)
            && positive(self.lock_threshold)
            && self.lock_threshold < 1.0
            && (1..=1000).contains(&self.pulse_periods)
            && self.rest_periods <= 20000
            && self.min_polarity_margin.is_finite()
            && (0.0..1.0).contains(&self.min_polarity_margin))
        {
            return Err(HfiConfigError::BadSequence);
        }
        Ok(())
    }
}

/// Where the estimator is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HfiPhase {
    /// Injecting and tracking; the angle is known modulo pi.
    Converging,
    /// Polarity pulses on d^ (no HF, the angle held).
    Polarity,
    /// Injecting and tracking with the polarity decided: the angle is the mover's.
    Tracking,
}

/// Why a sample was refused (state unchanged).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HfiFault {
    /// A current was NaN, infinite or saturated.
    InvalidInput,
}

/// One sample of the estimator, working units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HfiOutput<T> {
    /// Estimated electrical angle at this sample (modulo pi until the polarity is known).
    pub theta_e: Angle,
    /// Estimated electrical speed, rad/s (the loop's integrator plus its proportional
    /// correction: what advances the angle).
    pub omega_e: T,
    /// The tracking loop's integrator alone, rad/s: the speed estimate without the
    /// proportional path's share of the sensor noise (for a speed loop).
    pub omega_integral_e: T,
    /// Voltage to add to this step's command (applied from the next period), V, alpha-beta.
    pub u_inject_ab: AlphaBeta<T>,
    /// The fundamental current (the mean of the last two samples while injecting), A.
    pub i_fundamental_ab: AlphaBeta<T>,
    /// Angle-error signal `sin 2 dth` (dimensionless), zero when none was demodulated.
    pub error: T,
    /// The demodulated d^ response, A per period: `U_h T (S + D cos 2 dth)` nominally.
    pub response_d_a: T,
    /// The demodulated q^ response, A per period: `U_h T D sin 2 dth` nominally.
    pub response_q_a: T,
    /// Phase of the sequence.
    pub phase: HfiPhase,
    /// The low-passed error signal below the lock threshold.
    pub locked: bool,
    /// The polarity is decided and `theta_e` is the mover's angle.
    pub polarity_known: bool,
    /// The last polarity test's margin `(P+ - P-) / (P+ + P-)` (dimensionless; its sign
    /// is as measured, before any turn by pi), zero before any test.
    pub polarity_margin: T,
}

/// One command in the history: the frame it was injected in, its sign, and the
/// fundamental voltage commanded with it.
#[derive(Clone, Copy, Debug)]
struct Command<T> {
    frame: CosSin<T>,
    /// +1, -1: an HF half period; 0: anything else (pulse, nothing).
    sign: i8,
    /// The fundamental voltage of the same step (V, alpha-beta), as told by
    /// [`Hfi::set_fundamental_command`].
    u_fundamental: AlphaBeta<T>,
}

impl<T: Scalar> Command<T> {
    fn none() -> Self {
        Command { frame: CosSin { cos: T::ONE, sin: T::ZERO }, sign: 0, u_fundamental: AlphaBeta::default() }
    }
}

/// The HFI estimator. See the module docs.
#[derive(Clone, Debug)]
pub struct Hfi<T> {
    u_hf: T,
    u_pulse: T,
    /// `1 / (U_h T D)`, 1/A (working units).
    k_norm: T,
    /// `T / L_d`, `T / L_q`, A/V (working units): the current step a voltage makes.
    t_over_ld: T,
    t_over_lq: T,
    kp: T,
    ki_dt: T,
    dt: T,
    advance: T,
    max_omega: T,
    lock_rate: T,
    lock_threshold: T,
    min_margin: T,
    settle_samples: u32,
    pulse: u32,
    rest: u32,
    phase: HfiPhase,
    theta: Angle,
    integral: T,
    omega: T,
    lock_metric: T,
    counter: u32,
    tries: u8,
    i_prev: Option<AlphaBeta<T>>,
    i_prev2: Option<AlphaBeta<T>>,
    /// Commands of steps k-1, k-2, k-3 (before this step's is pushed).
    history: [Command<T>; 3],
    pulse_start: T,
    pulse_peak: T,
    peak_plus: T,
    polarity_known: bool,
    margin: T,
}

/// Polarity attempts before the result is taken as it is.
const POLARITY_TRIES: u8 = 3;

impl<T: Scalar> Hfi<T> {
    /// An estimator tuned by `config`, converted with `base`. Starts at angle 0, speed 0,
    /// [`HfiPhase::Converging`], polarity unknown.
    pub fn new(config: &HfiConfig, base: &Base) -> Result<Self, HfiConfigError> {
        config.validate()?;
        let t = config.pwm_period_s;
        let d_si = 0.5 * (1.0 / config.ld_h - 1.0 / config.lq_h);
        let k_norm_si = 1.0 / (config.u_hf_v * t * d_si);
        let wn = config.bandwidth_rad_s;
        Ok(Hfi {
            u_hf: base.voltage(config.u_hf_v),
            u_pulse: base.voltage(config.pulse_v),
            k_norm: T::from_f32(k_norm_si * base.current_a),
            t_over_ld: T::from_f32(t / config.ld_h * base.voltage_v / base.current_a),
            t_over_lq: T::from_f32(t / config.lq_h * base.voltage_v / base.current_a),
            kp: base.omega(config.damping * wn),
            ki_dt: base.omega(0.5 * wn * wn * t),
            dt: base.time(t),
            advance: base.time(1.5 * t),
            max_omega: base.omega(config.max_omega_rad_s),
            lock_rate: T::from_f32((t / config.lock_filter_s).min(1.0)),
            lock_threshold: T::from_f32(config.lock_threshold),
            min_margin: T::from_f32(config.min_polarity_margin),
            settle_samples: ceil_count(config.settle_s / t),
            pulse: u32::from(config.pulse_periods),
            rest: u32::from(config.rest_periods),
            phase: HfiPhase::Converging,
            theta: Angle::ZERO,
            integral: T::ZERO,
            omega: T::ZERO,
            lock_metric: T::ONE,
            counter: 0,
            tries: 0,
            i_prev: None,
            i_prev2: None,
            history: [Command::none(); 3],
            pulse_start: T::ZERO,
            pulse_peak: T::ZERO,
            peak_plus: T::ZERO,
            polarity_known: false,
            margin: T::ZERO,
        })
    }

    /// Restarts at `theta_e` and `omega_e` (rad/s, working units); `polarity_known`:
    /// the angle is the mover's (skip the polarity test) or only its axis.
    pub fn preset(&mut self, theta_e: Angle, omega_e: T, polarity_known: bool) {
        self.theta = theta_e;
        self.integral = omega_e.clamp_to(-self.max_omega, self.max_omega);
        self.omega = self.integral;
        self.lock_metric = T::ONE;
        self.counter = 0;
        self.tries = 0;
        self.i_prev = None;
        self.i_prev2 = None;
        self.history = [Command::none(); 3];
        self.polarity_known = polarity_known;
        self.phase = if polarity_known { HfiPhase::Tracking } else { HfiPhase::Converging };
    }

    /// Tells the estimator the fundamental voltage (V, alpha-beta, working units) the
    /// caller commands in this step besides the injection (after [`Hfi::step`], before
    /// the next): its changes from one period to the next are taken out of the
    /// demodulated response (module docs). Without it they are taken as zero.
    pub fn set_fundamental_command(&mut self, u_ab: AlphaBeta<T>) {
        if u_ab.is_valid() {
            self.history[0].u_fundamental = u_ab;
        }
    }

    /// Back to angle 0, speed 0, polarity unknown.
    pub fn reset(&mut self) {
        self.preset(Angle::ZERO, T::ZERO, false);
        self.margin = T::ZERO;
    }

    /// The present phase of the sequence.
    pub fn phase(&self) -> HfiPhase {
        self.phase
    }

    /// One PWM period: `i_ab` (A) sampled at this period's carrier valley. Returns the
    /// estimate and the voltage to add to this step's command. The command is taken as
    /// applied over the next period, as the drive does (see the module docs).
    pub fn step(&mut self, i_ab: AlphaBeta<T>) -> Result<HfiOutput<T>, HfiFault> {
        if !i_ab.is_valid() {
            return Err(HfiFault::InvalidInput);
        }
        let [h1, h2, h3] = self.history;
        // Demodulate the responses to the commands of k-2 (i_k - i_{k-1}) and k-3
        // (i_{k-1} - i_{k-2}), each in its own frame and with its own sign.
        let mut error = T::ZERO;
        let mut response = Dq::default();
        let mut demodulated = false;
        let mut i_fundamental = i_ab;
        if let (Some(p1), Some(p2)) = (self.i_prev, self.i_prev2)
            && h2.sign != 0
            && h3.sign == -h2.sign
        {
            let r2 = park(AlphaBeta::new(i_ab.alpha - p1.alpha, i_ab.beta - p1.beta), &h2.frame);
            let r3 = park(AlphaBeta::new(p1.alpha - p2.alpha, p1.beta - p2.beta), &h3.frame);
            let (r2, r3) =
                if h2.sign > 0 { (r2, Dq::new(-r3.d, -r3.q)) } else { (Dq::new(-r2.d, -r2.q), r3) };
            // A change of the fundamental voltage between the two commands changes the
            // fundamental's slope, which the pair would read as HF: take out its
            // expected effect, `sign T L^-1 (u_f(k-2) - u_f(k-3)) / 2` in the frame.
            let du = park(
                AlphaBeta::new(
                    h2.u_fundamental.alpha - h3.u_fundamental.alpha,
                    h2.u_fundamental.beta - h3.u_fundamental.beta,
                ),
                &h2.frame,
            );
            let (cd, cq) = (du.d * self.t_over_ld * T::HALF, du.q * self.t_over_lq * T::HALF);
            let (cd, cq) = if h2.sign > 0 { (cd, cq) } else { (-cd, -cq) };
            response = Dq::new((r2.d + r3.d) * T::HALF - cd, (r2.q + r3.q) * T::HALF - cq);
            error = (response.q * self.k_norm).clamp_to(-T::ONE, T::ONE);
            demodulated = true;
            i_fundamental =
                AlphaBeta::new((i_ab.alpha + p1.alpha) * T::HALF, (i_ab.beta + p1.beta) * T::HALF);
        }
        let theta_now = self.theta;
        let mut theta_out = theta_now;
        let mut command = Command::none();
        let mut u = AlphaBeta::default();
        match self.phase {
            HfiPhase::Converging | HfiPhase::Tracking => {
                if demodulated {
                    self.integral =
                        (self.integral + self.ki_dt * error).clamp_to(-self.max_omega, self.max_omega);
                    self.omega = self.integral + self.kp * error;
                    self.lock_metric = self.lock_metric + self.lock_rate * (error - self.lock_metric);
                }
                if self.phase == HfiPhase::Converging {
                    self.counter = self.counter.saturating_add(1);
                    if self.counter >= self.settle_samples && self.lock_metric.abs() < self.lock_threshold {
                        self.phase = HfiPhase::Polarity;
                        self.counter = 0;
                        self.tries = 0;
                    }
                }
                if self.phase != HfiPhase::Polarity {
                    // Inject along d^ at the middle of the application window.
                    let sign = if h1.sign > 0 { -1 } else { 1 };
                    let theta_inj = theta_now + (self.omega * self.advance).radians_to_angle();
                    let frame = CosSin::new(theta_inj);
                    let amplitude = if sign > 0 { self.u_hf } else { -self.u_hf };
                    u = inverse_park(Dq::new(amplitude, T::ZERO), &frame);
                    command = Command { frame, sign, u_fundamental: AlphaBeta::default() };
                }
                self.theta = theta_now + (self.omega * self.dt).radians_to_angle();
            }
            HfiPhase::Polarity => {
                self.omega = T::ZERO;
                let (pulse_u, frame) = self.polarity_step(i_ab);
                u = inverse_park(Dq::new(pulse_u, T::ZERO), &frame);
                command = Command { frame, sign: 0, u_fundamental: AlphaBeta::default() };
                // The angle is held during the test; a decision may have turned it by pi,
                // and the output must carry the angle the polarity flag vouches for.
                theta_out = self.theta;
            }
        }
        self.history = [command, h1, h2];
        self.i_prev2 = self.i_prev;
        self.i_prev = Some(i_ab);
        Ok(HfiOutput {
            theta_e: theta_out,
            omega_e: self.omega,
            omega_integral_e: self.integral,
            u_inject_ab: u,
            i_fundamental_ab: i_fundamental,
            error,
            response_d_a: response.d,
            response_q_a: response.q,
            phase: self.phase,
            locked: self.lock_metric.abs() < self.lock_threshold,
            polarity_known: self.polarity_known,
            polarity_margin: self.margin,
        })
    }

    /// One period of the polarity sequence `rest M, +N, -N, rest M, -N, +N`: the pulse
    /// voltage on d^ for this step and the frame; decides at the end.
    fn polarity_step(&mut self, i_ab: AlphaBeta<T>) -> (T, CosSin<T>) {
        let frame = CosSin::new(self.theta);
        let i_d = park(i_ab, &frame).d;
        let (n, m) = (self.pulse, self.rest);
        let c = self.counter;
        let half = 2 * n + m;
        // Start of each half's pulses: the current at rest, before any of them acts.
        if c == m || c == half + m {
            self.pulse_start = i_d;
            self.pulse_peak = T::ZERO;
        }
        if c < half {
            self.pulse_peak = self.pulse_peak.max(i_d - self.pulse_start);
        } else {
            self.pulse_peak = self.pulse_peak.max(self.pulse_start - i_d);
        }
        if c + 1 == half {
            self.peak_plus = self.pulse_peak;
        }
        // Each half: a rest of M periods (the injection's or the last pulse's current
        // decays, so both peaks are measured from rest), then the pulse pair.
        let k = if c < half { c } else { c - half };
        let sign_first = if c < half { self.u_pulse } else { -self.u_pulse };
        let u = if k < m {
            T::ZERO
        } else if k < m + n {
            sign_first
        } else {
            -sign_first
        };
        self.counter = c + 1;
        if self.counter >= 2 * half {
            self.decide_polarity();
        }
        (u, frame)
    }

    /// Ends a polarity test: turn by pi if the negative pulse saturated more; repeat a
    /// test whose margin is too small, up to [`POLARITY_TRIES`] times.
    fn decide_polarity(&mut self) {
        let plus = self.peak_plus;
        let minus = self.pulse_peak;
        let sum = plus + minus;
        self.margin = sum.recip().map_or(T::ZERO, |inv| (plus - minus) * inv);
        self.tries = self.tries.saturating_add(1);
        self.counter = 0;
        if self.margin.abs() < self.min_margin && self.tries < POLARITY_TRIES {
            return;
        }
        if self.margin < T::ZERO {
            self.theta = self.theta + Angle::HALF_TURN;
        }
        self.polarity_known = true;
        self.phase = HfiPhase::Tracking;
        self.history = [Command::none(); 3];
    }
}

/// The smallest whole count of samples at least `samples` (`ceil`, saturating at the
/// `u32` range; NaN gives 0): a comparison after the truncating cast, where libm's
/// `ceilf` is a routine of its own in the image.
fn ceil_count(samples: f32) -> u32 {
    let n = samples as u32;
    if (n as f32) < samples { n.saturating_add(1) } else { n }
}

#[cfg(test)]
mod tests {
    //! Against the analysis: an ideal discrete salient R-L motor at standstill (exact
    //! zero-order-hold solution per axis, one period of computation delay).
    use super::*;
    use crate::num::Q24;

    fn salient() -> MotorParams {
        MotorParams {
            rs_ohm: 2.0,
            ld_h: 0.006,
            lq_h: 0.009,
            psi_f_wb: 0.12,
            pole_pitch_m: 0.02,
            mass_kg: 1.2,
            viscous_n_s_per_m: 0.5,
            rated_current_a: 3.0,
            rated_voltage_v: 200.0,
        }
    }

    const T_S: f64 = 100e-6;

    /// Ideal motor at angle `theta` (rad), d saturating by `c` (1/A: incremental
    /// `L_d exp(-c i_d)`, integrated per period at the period's start current).
    struct Ideal {
        theta: f64,
        i_d: f64,
        i_q: f64,
        c: f64,
        m: MotorParams,
    }

    impl Ideal {
        fn step(&mut self, u_alpha: f64, u_beta: f64) {
            let (s, co) = self.theta.sin_cos();
            let u_d = co * u_alpha + s * u_beta;
            let u_q = -s * u_alpha + co * u_beta;
            let r = f64::from(self.m.rs_ohm);
            let ld = f64::from(self.m.ld_h) * (-self.c * self.i_d).exp();
            let lq = f64::from(self.m.lq_h);
            let (ad, aq) = ((-r * T_S / ld).exp(), (-r * T_S / lq).exp());
            self.i_d = ad * self.i_d + (1.0 - ad) * u_d / r;
            self.i_q = aq * self.i_q + (1.0 - aq) * u_q / r;
        }
        fn i_ab(&self) -> (f64, f64) {
            let (s, c) = self.theta.sin_cos();
            (c * self.i_d - s * self.i_q, s * self.i_d + c * self.i_q)
        }
    }

    /// Runs `n` periods; returns the final angle error (deg, modulo 180 when `mod_pi`),
    /// the last output, and the per-period outputs' errors.
    fn run<T: Scalar>(theta: f64, c: f64, n: usize, base: &Base) -> (Hfi<T>, Ideal, HfiOutput<T>) {
        let m = salient();
        let cfg = HfiConfig::for_motor(&m, T_S as f32, 283.0, 0.0).unwrap();
        let mut hfi = Hfi::<T>::new(&cfg, base).unwrap();
        let mut motor = Ideal { theta, i_d: 0.0, i_q: 0.0, c, m };
        let mut pending = (0.0, 0.0);
        let mut out = None;
        for _ in 0..n {
            let (a, b) = motor.i_ab();
            let i = AlphaBeta::new(
                T::from_f32((a / f64::from(base.current_a)) as f32),
                T::from_f32((b / f64::from(base.current_a)) as f32),
            );
            let o = hfi.step(i).unwrap();
            // The command of this step applies over the next period.
            motor.step(pending.0, pending.1);
            pending = (
                f64::from(o.u_inject_ab.alpha.to_f32()) * f64::from(base.voltage_v),
                f64::from(o.u_inject_ab.beta.to_f32()) * f64::from(base.voltage_v),
            );
            out = Some(o);
        }
        (hfi, motor, out.unwrap())
    }

    fn wrap_deg(x: f64, period: f64) -> f64 {
        let r = x.rem_euclid(period);
        if r >= period / 2.0 { r - period } else { r }
    }

    #[test]
    fn the_settling_count_is_the_ceiling_of_the_samples() {
        for x in [0.0f32, 0.25, 1.0, 1.0 + f32::EPSILON, 2.5, 99.999, 100.0, 3.0e9, 5.0e9] {
            let expected = f64::from(x).ceil().min(f64::from(u32::MAX)) as u32;
            assert_eq!(ceil_count(x), expected, "{x}");
        }
        assert_eq!(ceil_count(f32::NAN), 0);
        assert_eq!(ceil_count(-3.5), 0);
    }

    #[test]
    fn tuning_follows_the_motor_and_refuses_a_round_motor() {
        let m = salient();
        let cfg = HfiConfig::for_motor(&m, 100e-6, 283.0, 0.0).unwrap();
        // U_h = 0.25 * 4.243 A * 6 mH / 100 us = 63.6 V (below 0.4 * 283 / sqrt 3 = 65.4);
        // w_n = 2 pi 50 Hz.
        assert!((cfg.u_hf_v - 63.64).abs() < 0.05, "{}", cfg.u_hf_v);
        assert!((cfg.bandwidth_rad_s - 314.16).abs() < 0.1);
        // U_p = min(127, 0.5 * 163.4) = 81.7 V; N = 1.5 * 6 mH * 4.243 A / (81.7 V *
        // 100 us) = 4.7 -> 5; M = 5 * 3 ms / 100 us.
        assert!((cfg.pulse_v - 81.69).abs() < 0.05, "{}", cfg.pulse_v);
        assert_eq!(cfg.pulse_periods, 5);
        assert_eq!(cfg.rest_periods, 150);
        let round = MotorParams::paper();
        assert_eq!(HfiConfig::for_motor(&round, 100e-6, 311.0, 0.0), Err(HfiConfigError::NotSalient));
        let weak = MotorParams { lq_h: 0.0068, ..m };
        assert_eq!(HfiConfig::for_motor(&weak, 100e-6, 283.0, 0.0), Err(HfiConfigError::NotSalient));
    }

    #[test]
    fn a_bus_limited_injection_narrows_the_loop_down_to_the_tracking_floor() {
        let m = salient();
        let (t, bus) = (100e-6_f64, 141.5_f64);
        // The swing's voltage 0.25 * sqrt 2 * 3 A * 6 mH / 100 us = 63.6 V; the bus caps
        // U_h at 0.4 * 141.5 V / sqrt 3 = 32.7 V, r = 0.51 of it.
        let swing = 0.25 * 2f64.sqrt() * f64::from(m.rated_current_a) * f64::from(m.ld_h) / t;
        let cap = 0.4 * bus / 3f64.sqrt();
        let full = 2.0 * core::f64::consts::PI / (200.0 * t);
        let near = |x: f32, want: f64| (f64::from(x) - want).abs() <= 1e-5 * want;
        let cfg = HfiConfig::for_motor(&m, t as f32, bus as f32, 0.0).unwrap();
        assert!(near(cfg.u_hf_v, cap), "{}", cfg.u_hf_v);
        assert!(near(cfg.bandwidth_rad_s, full * cap / swing), "{}", cfg.bandwidth_rad_s);
        assert_eq!(cfg.max_omega_rad_s, cfg.bandwidth_rad_s);
        assert!(near(cfg.settle_s, 30.0 / (full * cap / swing)), "{}", cfg.settle_s);
        // A tracked speed of 100 rad/s asks for 200 (above 161): the floor decides.
        let floored = HfiConfig::for_motor(&m, t as f32, bus as f32, 100.0).unwrap();
        assert!(near(floored.bandwidth_rad_s, 200.0), "{}", floored.bandwidth_rad_s);
        // Never beyond the full bandwidth; no floor from a speed that is none.
        let fast = HfiConfig::for_motor(&m, t as f32, bus as f32, 1000.0).unwrap();
        assert!(near(fast.bandwidth_rad_s, full), "{}", fast.bandwidth_rad_s);
        for none in [f32::NAN, -50.0] {
            let c = HfiConfig::for_motor(&m, t as f32, bus as f32, none).unwrap();
            assert_eq!(c.bandwidth_rad_s, cfg.bandwidth_rad_s, "{none}");
        }
    }

    #[test]
    fn demodulated_response_matches_the_analysis_at_a_held_angle_error() {
        // Loop opened (the estimate held at 0 by a zero gain), the motor at dth:
        // response_q = U T D sin 2 dth, response_d = U T (S + D cos 2 dth), to the
        // resistive correction tanh(x)/x (x = R T / 2L), below 0.1 %.
        let m = salient();
        let mut cfg = HfiConfig::for_motor(&m, T_S as f32, 283.0, 0.0).unwrap();
        cfg.settle_s = 100.0; // never leaves Converging within the run
        let u = f64::from(cfg.u_hf_v);
        let (ld, lq) = (f64::from(m.ld_h), f64::from(m.lq_h));
        for dth_deg in [-60.0f64, -20.0, 5.0, 30.0, 75.0] {
            let mut hfi = Hfi::<f64>::new(&cfg, &Base::SI).unwrap();
            hfi.kp = 0.0;
            hfi.ki_dt = 0.0;
            let dth = dth_deg.to_radians();
            let mut motor = Ideal { theta: dth, i_d: 0.0, i_q: 0.0, c: 0.0, m };
            let mut pending = (0.0, 0.0);
            let mut last = None;
            for _ in 0..2000 {
                let (a, b) = motor.i_ab();
                let o = hfi.step(AlphaBeta::new(a, b)).unwrap();
                motor.step(pending.0, pending.1);
                pending = (o.u_inject_ab.alpha, o.u_inject_ab.beta);
                last = Some(o);
            }
            let o = last.unwrap();
            let s = 0.5 * (1.0 / ld + 1.0 / lq);
            let d = 0.5 * (1.0 / ld - 1.0 / lq);
            let q_expected = u * T_S * d * (2.0 * dth).sin();
            let d_expected = u * T_S * (s + d * (2.0 * dth).cos());
            let scale = u * T_S * s;
            assert!(
                (o.response_q_a - q_expected).abs() < 2e-3 * scale,
                "{dth_deg}: {} vs {q_expected}",
                o.response_q_a
            );
            assert!(
                (o.response_d_a - d_expected).abs() < 2e-3 * scale,
                "{dth_deg}: {} vs {d_expected}",
                o.response_d_a
            );
            assert!((o.error - (2.0 * dth).sin()).abs() < 5e-3, "{dth_deg}: e {}", o.error);
        }
    }

    #[test]
    fn converges_to_the_magnet_axis_and_finds_the_polarity_in_f64_f32_and_q24() {
        // Saturation: incremental L_d 10 % lower at the rated peak current.
        let i_pk = 3.0 * core::f64::consts::SQRT_2;
        let c = -(0.9f64).ln() / i_pk;
        let m = salient();
        let pu = Base::for_motor(&m);
        for theta_deg in [0.0f64, 37.0, 89.0, 135.0, 181.0, 250.0, 300.0, 359.0] {
            let theta = theta_deg.to_radians();
            let check = |name: &str, est: Angle, out_known: bool, margin: f32| {
                let err = wrap_deg(theta_deg - f64::from(est.to_degrees_f32()), 360.0);
                assert!(out_known, "{name} {theta_deg}: polarity not decided");
                assert!(err.abs() < 1.0, "{name} {theta_deg}: error {err} deg, margin {margin}");
                assert!(margin.abs() > 0.02, "{name} {theta_deg}: margin {margin}");
            };
            let (_, _, o) = run::<f64>(theta, c, 1500, &Base::SI);
            check("f64", o.theta_e, o.polarity_known, o.polarity_margin as f32);
            let (_, _, o) = run::<f32>(theta, c, 1500, &Base::SI);
            check("f32", o.theta_e, o.polarity_known, o.polarity_margin);
            let (_, _, o) = run::<Q24>(theta, c, 1500, &pu);
            check("Q24", o.theta_e, o.polarity_known, o.polarity_margin.to_f32());
        }
    }

    #[test]
    fn tracks_a_moving_mover_without_lag() {
        // The mover at 0.2 m/s on the salient motor (31.4 rad/s electrical); polarity
        // preset. The injection's 1.5 T advance and the integrator leave no lag.
        let m = salient();
        let cfg = HfiConfig::for_motor(&m, T_S as f32, 283.0, 0.0).unwrap();
        let mut hfi = Hfi::<f32>::new(&cfg, &Base::SI).unwrap();
        let w = core::f64::consts::PI * 0.2 / 0.02;
        let theta0 = 1.0;
        hfi.preset(Angle::from_radians(theta0 as f32 - 0.3), 0.0, true);
        let mut motor = Ideal { theta: theta0, i_d: 0.0, i_q: 0.0, c: 0.0, m };
        let mut pending = (0.0f64, 0.0f64);
        let mut worst_late = 0.0f64;
        for k in 0..3000 {
            let (a, b) = motor.i_ab();
            let o = hfi.step(AlphaBeta::new(a as f32, b as f32)).unwrap();
            // Rotate the state with the mover (the currents follow their axes).
            motor.step(pending.0, pending.1);
            motor.theta += w * T_S;
            pending = (f64::from(o.u_inject_ab.alpha), f64::from(o.u_inject_ab.beta));
            if k > 1500 {
                let err = wrap_deg(
                    (motor.theta - w * T_S).to_degrees() - f64::from(o.theta_e.to_degrees_f32()),
                    360.0,
                );
                worst_late = worst_late.max(err.abs());
                assert!((f64::from(o.omega_e) - w).abs() < 0.05 * w + 2.0, "{}", o.omega_e);
            }
        }
        assert!(worst_late < 0.5, "{worst_late} deg");
    }

    #[test]
    fn invalid_currents_are_refused_and_change_nothing() {
        let cfg = HfiConfig::for_motor(&salient(), 100e-6, 283.0, 0.0).unwrap();
        let mut hfi = Hfi::<f32>::new(&cfg, &Base::SI).unwrap();
        let before = hfi.clone().step(AlphaBeta::new(0.1, 0.0)).unwrap();
        assert_eq!(hfi.step(AlphaBeta::new(f32::NAN, 0.0)), Err(HfiFault::InvalidInput));
        assert_eq!(hfi.step(AlphaBeta::new(0.1, 0.0)).unwrap(), before);
    }
}
