//! The drive: one control step per PWM period, composing the library blocks into the
//! sensorless FOC loop of `docs/method.md` §5, with its start-up and protection state
//! machine.
//!
//! ```text
//! samples -> offsets -> Clarke -> estimator (observer + PLL) -> Park -> current PIs
//!         -> inverse Park (angle advanced `delay_compensation_periods`, 1.5) -> dead-time compensation
//!         -> SVPWM -> duties;   speed PI (and position loop) every `speed_loop_divider`
//!         periods, the motion profile in the period before
//! ```
//!
//! The same code runs in the host simulation, in trace replay (through the
//! [`Estimator`]) and in the firmware's PWM interrupt. It never reads a clock or touches
//! hardware: measurements come in, duties and a bridge-enable flag go out.
//!
//! ## Timing
//! [`Drive::step`] gets the currents sampled at the carrier valley `t_k`; the duties it
//! returns are applied during the *next* period `[t_{k+1}, t_{k+2})` (one period of
//! computation delay). So the voltage applied during the period that ended at `t_k` —
//! the observer's input — is the command of step `k - 2`, and the inverse Park uses the
//! angle advanced by 1.5 periods, the middle of the command's application window.
//!
//! ## States
//! `Disabled -> Calibrating (bridge off, current offsets averaged) -> Starting (I/f
//! open loop) -> Running (sensorless)`; any fault latches `Fault` with the bridge off
//! until [`Drive::clear_faults`]. Hand-over from I/f keeps the current vector continuous:
//! the current controllers' integrators are rotated into the estimated frame, the speed
//! controller is preset to the present thrust current, and the start-up vector's d-axis
//! part is ramped to zero. The drive closes its loops on [`Estimate::tracking`] (the
//! hand-over from I/f waits for it); when it is lost while running, the drive goes to
//! `Reacquiring` (no thrust, the estimator re-acquires) and back to `Running` from the
//! estimated speed, instead of tripping: `Running <-> Reacquiring -> Fault` only after
//! `faults.reacquire_timeout_s` without the estimate tracking again. Where its
//! rate-limited reference falls below the motor's back-EMF floor and stays there (a stop,
//! a reversal, a target inside that band), a speed drive runs the positioning drive's
//! low-speed mode, its profile following the speed reference, and hands back to `Running`
//! once the reference is above the band again and the estimate tracks: `Running <->
//! LowSpeed`.
//!
//! A *positioning* drive ([`DriveConfig::motion`]) replaces the I/f start by an
//! alignment and the speed reference by queued moves: `Calibrating -> LowSpeed (align,
//! hold, move slowly) <-> Running (sensorless position loop)`, through zero speed at
//! every reversal, with a position estimate (`positioning` module docs, [`Drive::push_move`],
//! [`Drive::position_m`]). A lock loss there falls back to `LowSpeed`.
//!
//! The drive tells the estimator the acceleration it commands (the speed reference's
//! ramp, a move's acceleration): the estimator's notch leads by the PLL's lag on that
//! ramp ([`Estimator::set_commanded_acceleration`]).

/// With [`CompensationSigns::ReferenceAboveNoise`], the inverter compensation takes its
/// signs from the measured current while the current reference is below this many
/// compensation bands, from the reference above twice as many, and from a linear blend
/// between (dimensionless; `Drive::compensation_current`). One band is one noise sigma on
/// the simulated axes, so the measured current's noise averages the compensation near
/// zero current, and the noise-free reference sets it where the current is clear of the
/// noise.
pub const COMPENSATION_REFERENCE_FROM_BANDS: f32 = 4.0;

mod commands;
mod commissioning;
mod config;
mod faults;
mod phase_loss;
mod positioning;

pub use commands::Commands;
pub use commissioning::{
    Commissioning, CommissioningConfig, CommissioningError, CommissioningResult, CommissioningStep,
    IF_FREQUENCY_HZ, SWEEP_FRACTIONS, SWEEP_LEVELS, VoltageErrorPoint,
};
pub use config::{
    CompensationSigns, DriveConfig, DriveConfigError, FaultConfig, LOW_SPEED_EXIT_RATIO, MotionConfig,
    PAPER_AXIS_BUS_V, PAPER_AXIS_PAYLOAD_KG, STROKE_AXIS_LIMITS, STROKE_AXIS_STROKE_M, StartupConfig,
    back_emf_floor_m_per_s,
};
pub use faults::Faults;
use phase_loss::PhaseLoss;
pub use positioning::MOVE_QUEUE;
use positioning::{HANDOVER_SPEED_AGREEMENT, Positioning};

/// The inverter compensation's settings, a part of [`DriveConfig`].
pub use crate::algorithms::dead_time::DeadTimeCompensation;
use crate::algorithms::dead_time::InverterErrorModel;
use crate::algorithms::hfi::Hfi;
use crate::algorithms::load_observer::{LoadObserver, LoadObserverConfig};
use crate::algorithms::motion::{Period, Profile, ProfileLimits};
use crate::algorithms::observer::ObserverKind;
use crate::algorithms::pi::Pi;
use crate::algorithms::svpwm::{DcBus, Duties, svpwm, svpwm_on};
use crate::algorithms::transforms::{Abc, AlphaBeta, CosSin, Dq, clarke, inverse_clarke, inverse_park, park};
use crate::estimator::{Estimate, Estimator};
use crate::motor::MotorParams;
use crate::num::units::Base;
use crate::num::{Angle, Scalar, sqrt_rounded};

/// Where the drive's state machine is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DriveState {
    /// Bridge off, waiting for [`Drive::enable`].
    Disabled,
    /// Bridge off, averaging the current sensors' offsets.
    Calibrating,
    /// Open-loop I/f start-up; the estimator runs but does not steer.
    Starting,
    /// Sensorless closed loop on the estimator's angle and speed.
    Running,
    /// Latched fault, bridge off.
    Fault,
    /// The estimate stopped tracking while running (for `lock_loss_s`, or at once if the
    /// estimator lost the frequency too): no thrust (zero current references, the bridge
    /// on and the current loops holding zero), the estimator re-acquires the moving mover,
    /// and the drive resumes `Running` from the estimated speed once it tracks again, or
    /// trips `LOCK_LOST` after [`FaultConfig::reacquire_timeout_s`] (flying restart).
    Reacquiring,
    /// Below the low-speed threshold the current vector follows the reference position
    /// (and holds it at rest), or HFI closes the loops on a salient motor; see the
    /// `positioning` docs of [`Drive`]. A positioning drive's alignment on enable, and a
    /// speed drive's passages through zero speed (its reference then follows the speed
    /// reference).
    LowSpeed,
    /// Identifying the motor and the inverter ([`Drive::start_commissioning`], the
    /// `commissioning` module): the bridge applies the commissioning's test voltages, with
    /// its own limits; it ends in `Disabled` with a result, or in `Fault`
    /// ([`Faults::COMMISSIONING`]) with a named error ([`Drive::commissioning_result`]).
    Commissioning,
}

/// One period's measurements, in working units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Measurements<T> {
    /// Phase currents sampled at the carrier valley (A), offsets not yet removed.
    pub i_abc: Abc<T>,
    /// DC-bus voltage (V).
    pub vdc: T,
}

/// What one control step produced, in working units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepOutput<T> {
    /// Duty cycles for the next period (1/2 on all legs while the bridge is off).
    pub duties: Duties<T>,
    /// `false`: every switch must be off.
    pub bridge_enabled: bool,
    /// State after this step.
    pub state: DriveState,
    /// Latched faults.
    pub faults: Faults,
    /// The estimator's output this step (`None` while it is not running).
    pub estimate: Option<Estimate<T>>,
    /// Angle the current loops used this step (open-loop or estimated).
    pub theta_control: Angle,
    /// Measured currents, offsets removed (A).
    pub i_ab: AlphaBeta<T>,
    /// Measured currents in the control frame (A).
    pub i_dq: Dq<T>,
    /// Current references (A).
    pub i_dq_ref: Dq<T>,
    /// Voltage being applied during the present period `[t_k, t_{k+1})` as the
    /// observer will see it (V): the previous step's command, without inverter
    /// compensation, plus any observer offset. The `u_alpha`, `u_beta` of a trace row.
    pub u_applied: AlphaBeta<T>,
    /// Currents as the observer saw them this step (A): `i_ab` plus any observer
    /// offset. The `i_alpha`, `i_beta` of a trace row.
    pub i_observer: AlphaBeta<T>,
    /// The commanded electrical acceleration the estimator used this step (rad/s^2;
    /// see [`Estimator::set_commanded_acceleration`]): a trace row's `alpha_e_ref`.
    pub alpha_e_ref: T,
}

/// Precomputed gains and limits in working units.
#[derive(Clone, Debug)]
struct Constants<T> {
    dt: T,
    ld: T,
    lq: T,
    psi_f: T,
    current_limit: T,
    overcurrent: T,
    bus_min: T,
    bus_max: T,
    max_offset: T,
    inv_calibration_samples: T,
    calibration_samples: u32,
    modulation_limit: T,
    speed_filter_rate: T,
    accel_step: T,
    speed_loop_divider: u16,
    startup_current: T,
    handover_current: T,
    startup_current_step: T,
    startup_accel_step: T,
    handover_omega: T,
    handover_tolerance: T,
    dwell_samples: u32,
    startup_timeout_samples: u32,
    id_ramp_step: T,
    lock_loss_samples: u32,
    /// `FaultConfig::overload_s` in periods; the thrust-current level (98 % of the
    /// limit, working units) that counts as on the limit.
    overload_samples: u32,
    overload_level: T,
    /// Current-control supervision: the error (A, working units) and the periods it may
    /// last with the voltage on its limit ([`FaultConfig::current_error_a`]).
    current_error: T,
    current_error_samples: u32,
    /// `0.98^2`: the voltage counts as on its limit above 98 % of it.
    at_limit_sq: T,
    reacquire_timeout_samples: u32,
    delay_periods: T,
    /// The inverter's error as compensated ([`crate::algorithms::dead_time`]); `None`: no
    /// compensation. Its `inv_band_sqrt` also measures the reference in bands
    /// ([`Drive::compensation_current`]).
    inverter: Option<InverterErrorModel<T>>,
    /// [`CompensationSigns::ReferenceAboveNoise`].
    signs_from_reference: bool,
    /// [`COMPENSATION_REFERENCE_FROM_BANDS`], and its reciprocal: the reference's weight
    /// in the compensation's current rises by this per band above it.
    compensation_reference_from: T,
    compensation_blend_rate: T,
    omega_per_speed: f32,
    base: Base,
    /// Control period, s (SI, for the motion profile).
    dt_s: f32,
    /// `1 / dt` (working units).
    inv_dt: T,
    /// Periods after enable at which a catch decides "at rest" (0: no catch), and the
    /// squared flux amplitude below which it does (Wb^2, working units).
    catch_probe_samples: u32,
    catch_flux_sq: T,
    /// `1 / omega_base` (s/rad): SI rad/s to working units.
    inv_omega_base: f32,
    /// A mover speed to the working electrical speed (working units per m/s):
    /// `omega_per_speed * inv_omega_base`, formed once, so that the positioning layer's
    /// conversion of a speed is one product (soft-float on Cortex-M3) instead of two.
    speed_to_omega: f32,
    /// A mover acceleration to the working electrical acceleration (working units per
    /// m/s^2): `omega_per_speed * inv_omega_base^2`, one product instead of three.
    accel_to_alpha: f32,
    /// One electrical turn, m (two pole pitches).
    metres_per_turn: f32,
    /// Electrical turns per metre: `1 / metres_per_turn`.
    turns_per_metre: f32,
    /// [`Constants::metres_per_turn`] in the working type (m, within its LSB): the
    /// position in the working type ([`Drive::position`]).
    metres_per_turn_working: T,
    /// Winding resistance (ohm, working units) and `1 / psi_f` (1/Wb, working units):
    /// the mover's speed read from the voltage while a current vector drags it (the I/f
    /// start, the low-speed mode).
    rs: T,
    inv_psi_f: T,
    /// Damping of a dragging current vector (the I/f start, the low-speed mode): the
    /// vector is retarded by `k dw_e` (rad) with `k = c / sqrt(|I|)`, damping ratio 0.7
    /// of the vector's spring on the moving mass (`c = 1.4 sqrt(M / (K_f dtheta/dx))`,
    /// s A^0.5). Held as `c / sqrt(I_base)` (s), for `|I|` in working units
    /// ([`Constants::vector_damping_s`]).
    damping_s_sqrt_unit: f32,
    /// The smallest vector amplitude (working units) the damping is formed for, so that
    /// `k` stays finite at zero current: 1 mA, or 1e-4 of the base current where that
    /// is more (its Q8.24 root then keeps 17 significant bits).
    damping_min_amplitude: T,
    /// Per-period rate of the low-pass on the mover's speed error during the I/f
    /// start: five times the spring's natural frequency at the start-up current.
    startup_speed_filter_rate: f32,
}

impl<T: Scalar> Constants<T> {
    /// The damping `k` (s) of a current vector of amplitude `amplitude` (working units)
    /// dragging the mover: `c / sqrt(|I|)` ([`Constants::damping_s_sqrt_unit`]), `|I|` at least
    /// `damping_min_amplitude`. The root is taken in the working type ([`Scalar::sqrt`]:
    /// in Q8.24 an integer root on the hardware divider, where an `f32` root in software
    /// on an FPU-less core costs several hundred instructions); accuracy that of `sqrt`
    /// and one `f32` division.
    #[inline(never)]
    fn vector_damping_s(&self, amplitude: T) -> f32 {
        self.damping_s_sqrt_unit / amplitude.max(self.damping_min_amplitude).sqrt().to_f32()
    }
}

/// The drive. See the module documentation.
#[derive(Clone, Debug)]
pub struct Drive<T> {
    k: Constants<T>,
    estimator: Estimator<T>,
    pi_d: Pi<T>,
    pi_q: Pi<T>,
    pi_speed: Pi<T>,
    state: DriveState,
    faults: Faults,
    enable_requested: bool,
    /// Speed reference, target and rate-limited (rad/s).
    omega_target: T,
    /// The m/s reference (f32 bits) `omega_target` was last converted from by
    /// [`Drive::apply`]; `None` after [`Drive::set_speed_reference`].
    applied_speed_ref_bits: Option<u32>,
    omega_ref: T,
    /// Filtered speed feedback (rad/s).
    omega_filtered: T,
    /// Consecutive periods the thrust-current reference has pushed on its limit towards
    /// the speed reference (`Running`; overload supervision).
    overload_count: u32,
    /// The speed integrator's thrust current when the estimate was lost (working
    /// units), resumed with after the re-acquisition.
    thrust_before_loss: T,
    i_dq_ref: Dq<T>,
    offsets: Abc<T>,
    offset_sum: Abc<T>,
    counter: u32,
    speed_divider_count: u16,
    /// Open-loop angle and speed during start-up.
    theta_ol: Angle,
    omega_ol: T,
    /// Intended voltage of the previous step (being applied now) and of the step
    /// before (applied during the period that just ended), as the observer sees them
    /// (V).
    u_prev: AlphaBeta<T>,
    u_prev2: AlphaBeta<T>,
    /// Offsets added to the observer's voltage and current inputs only (V, A).
    observer_u_offset: AlphaBeta<T>,
    observer_i_offset: AlphaBeta<T>,
    /// Positioning state, and a speed drive's low-speed mode (always `Some` once built;
    /// [`Positioning::follows_speed`] on a speed drive).
    positioning: Option<Positioning<T>>,
    /// Unwrapped control angle (binary-angle counts, 2^32 per electrical turn): the
    /// position estimate.
    position_counts: i64,
    /// The control angle of the last step.
    theta_previous: Angle,
    /// `Reacquiring` right after enable: catching a mover that may be moving.
    catching: bool,
    /// The current controllers' voltage command of the last step (V, control frame).
    u_dq_last: Dq<T>,
    /// The measured currents of the last step in its control frame (A).
    i_dq_measured: Dq<T>,
    /// In the low-speed mode, where the mover is expected (the position estimate
    /// follows it rather than the control angle).
    low_speed_mover_angle: Option<Angle>,
    /// Commissioning requested or under way.
    commissioning: Option<Commissioning>,
    /// The last commissioning's outcome.
    commissioning_outcome: Option<Result<CommissioningResult, CommissioningError>>,
    /// Consecutive periods with the current loops' voltage on its limit and the current
    /// off its reference (current-control supervision).
    current_error_count: u32,
    /// Phase-loss supervision ([`phase_loss`]).
    phase_loss: PhaseLoss<T>,
    /// During the I/f start: the mover's electrical speed less the open-loop speed,
    /// low-passed (rad/s, SI), read from the d voltage.
    startup_speed_error_rad_s: f32,
}

/// With HFI, the hold at rest: the load observer's bandwidth as a share of HFI's tracking
/// bandwidth (its position noise is filtered above that), and the PD hold's bandwidth as
/// a share of the observer's (a closed loop slower than the estimates it closes on). On
/// the salient test axis (HFI at 314 rad/s): observer 79 rad/s, hold 39 rad/s; a 60 N
/// load step (50 % rated) deflects the mover 2.8 mm and it is back within 0.05 mm. A
/// speed PI does not hold at rest: at twice the drive's speed bandwidth it takes HFI's
/// tracking-loop integrator as the speed, whose noise becomes ±5 A of thrust current, the
/// mover hunts by ±5 mm in stick-slip and the step deflects it 12.9 mm; a stiffer PI
/// (4x, 6x) deflects it more. With the observer at 0.15 of HFI's: 7.3 mm.
const HOLD_OBSERVER_SHARE: f32 = 0.25;
/// See [`HOLD_OBSERVER_SHARE`].
const HOLD_BANDWIDTH_SHARE: f32 = 0.5;
/// Time constant (s) of the load learned along the motion while running sensorless
/// (`Positioning::load_current`): several of the speed loop's periods and a fraction of
/// a move's acceleration, so that it follows friction and a slow load, not the
/// acceleration's residual.
const LOAD_LEARNING_TIME_S: f32 = 0.05;

/// `x` as a working value, or the configuration error naming `field` when the numeric
/// type cannot hold it within 1 % (e.g. beyond fixed point's range, or NaN).
fn representable<T: Scalar>(x: f32, field: &'static str) -> Result<T, DriveConfigError> {
    let v = T::from_f32(x);
    let back = v.to_f32();
    if x.is_finite() && (back - x).abs() <= 0.01 * x.abs() + 1e-6 {
        Ok(v)
    } else {
        Err(DriveConfigError { field })
    }
}

/// The longest gap of lost periods [`Drive::step_after_missed`] bridges (periods): the
/// observer's discretisation holds for `w (1 + n) dt / 2 <= 0.2`, up to 800 rad/s at 10
/// kHz with `n = 4` (the paper motor at 2 m/s turns at 419 rad/s); and the link watchdog
/// trips at ten.
pub const MAX_BRIDGED_PERIODS: u16 = 4;

impl<T: Scalar> Drive<T> {
    /// A drive for `motor` with `config`, computing in the working units of `base`.
    ///
    /// Always inlined: it builds a 1.75 KB value from several parts, and inlined into its
    /// caller the parts are built in place (the HIL image: main's frame 1,568 B and the
    /// commissioning request's 2,520 B inlined, against 4,056 B and 5,568 B plus
    /// Drive::new's own 1,784 B out of line).
    #[inline(always)]
    pub fn new(motor: &MotorParams, config: &DriveConfig, base: &Base) -> Result<Self, DriveConfigError> {
        config.validate()?;
        let estimator = Estimator::new(motor, &config.estimator, base)
            .map_err(|_| DriveConfigError { field: "estimator" })?;
        let ts = config.control_period_s;
        let speed_ts = ts * f32::from(config.speed_loop_divider);
        let omega_per_speed = motor.rad_per_m();
        // Current PI: kp = L w_c (V/A), ki = R w_c (V/(A s)).
        let v_per_a = base.current_a / base.voltage_v;
        let wc = config.current_bandwidth_rad_s;
        let kp_i = T::from_f32(motor.lq_h * wc * v_per_a);
        let ki_dt_i = T::from_f32(motor.rs_ohm * wc * ts * v_per_a);
        // Speed PI on electrical speed: d omega/dt = (pi/tau) K_f / M * i_q.
        let plant_gain = omega_per_speed * motor.thrust_constant_n_per_a() / config.moving_mass_kg;
        let ws = config.speed_bandwidth_rad_s;
        let kp_s = ws / plant_gain; // A per rad/s
        let a_per_omega = base.omega_rad_s / base.current_a;
        let pi_speed = Pi::new(
            T::from_f32(kp_s * a_per_omega),
            T::from_f32(kp_s * ws * config.speed_zero_ratio * speed_ts * a_per_omega),
            base.current(-config.current_limit_a),
            base.current(config.current_limit_a),
        )
        .map_err(|_| DriveConfigError { field: "speed_bandwidth_rad_s" })?;
        // Current PIs: limits set per step from the bus. The stored range only bounds a
        // preset integrator (a hand-over's, `Pi::preset`): the highest bus the drive
        // accepts, so a back-EMF or a resistive drop is carried over whole in any
        // working units (a fixed +-1 would be 1 V in SI and 180 V per unit on the paper
        // motor).
        let v_preset: T = representable(config.faults.bus_max_v / base.voltage_v, "faults.bus_max_v")?;
        let pi_d = Pi::new(kp_i, ki_dt_i, -v_preset, v_preset)
            .map_err(|_| DriveConfigError { field: "current_bandwidth_rad_s" })?;
        let samples = |s: f32| (s / ts) as u32;
        // The model's 1/band and Ts/2L in working units, checked representable first
        // (fixed point; 1/band enters as its square root, applied twice).
        let inverter = match config.dead_time_compensation {
            Some(c) => {
                representable::<T>(
                    sqrt_rounded(base.current_a / c.current_band_a),
                    "dead_time_compensation.current_band_a",
                )?;
                // The larger of the edge ripple's Ts / (Ld + Lq) and an injection's
                // Ts / 2 Ld (the larger where Ld < Lq).
                let ripple = InverterErrorModel::<T>::ripple_per_volt_si(ts, motor)
                    .max(InverterErrorModel::<T>::injection_ripple_per_volt_si(ts, motor));
                representable::<T>(ripple * base.impedance_ohm(), "control_period_s")?;
                Some(InverterErrorModel::for_drive(&c, ts, motor, base))
            }
            None => None,
        };
        let k = Constants {
            dt: base.time(ts),
            ld: base.inductance(motor.ld_h),
            lq: base.inductance(motor.lq_h),
            psi_f: base.flux(motor.psi_f_wb),
            current_limit: base.current(config.current_limit_a),
            overcurrent: base.current(config.faults.overcurrent_a),
            bus_min: base.voltage(config.faults.bus_min_v),
            bus_max: base.voltage(config.faults.bus_max_v),
            max_offset: base.current(config.faults.max_offset_a),
            inv_calibration_samples: T::from_f32(1.0 / f32::from(config.faults.calibration_samples)),
            calibration_samples: u32::from(config.faults.calibration_samples),
            modulation_limit: T::from_f32(config.modulation_limit * 0.577_350_26),
            speed_filter_rate: T::from_f32((ts / config.speed_filter_s).min(1.0)),
            accel_step: base.omega(config.accel_limit_m_per_s2 * omega_per_speed * ts),
            speed_loop_divider: config.speed_loop_divider,
            startup_current: base.current(config.startup.current_a),
            handover_current: base.current(config.startup.handover_current_a),
            startup_current_step: base.current(
                (config.startup.current_a - config.startup.handover_current_a) * ts
                    / config.startup.dwell_s.max(ts),
            ),
            startup_accel_step: base.omega(config.startup.accel_m_per_s2 * omega_per_speed * ts),
            handover_omega: base.omega(config.startup.handover_speed_m_per_s * omega_per_speed),
            handover_tolerance: T::from_f32(config.handover_speed_tolerance),
            dwell_samples: samples(config.startup.dwell_s),
            startup_timeout_samples: samples(config.startup.dwell_s)
                .saturating_mul(u32::from(config.startup.timeout_dwells))
                .max(samples(config.startup.min_timeout_s)),
            id_ramp_step: base.current(config.startup.current_a * ts / config.startup.id_ramp_s),
            lock_loss_samples: samples(config.faults.lock_loss_s).max(1),
            overload_samples: samples(config.faults.overload_s).max(1),
            overload_level: base.current(0.98 * config.current_limit_a),
            current_error: base.current(config.faults.current_error_a),
            current_error_samples: samples(config.faults.current_error_s).max(1),
            at_limit_sq: T::from_f32(0.98 * 0.98),
            reacquire_timeout_samples: samples(config.faults.reacquire_timeout_s).max(1),
            delay_periods: T::from_f32(config.delay_compensation_periods),
            inverter,
            signs_from_reference: config.compensation_signs == CompensationSigns::ReferenceAboveNoise,
            compensation_reference_from: T::from_f32(COMPENSATION_REFERENCE_FROM_BANDS),
            compensation_blend_rate: T::from_f32(1.0 / COMPENSATION_REFERENCE_FROM_BANDS),
            omega_per_speed,
            base: *base,
            dt_s: ts,
            catch_probe_samples: config.startup.catch_probe_s.map_or(0, |p| samples(p).max(1)),
            catch_flux_sq: {
                let half: T = base.flux(0.5 * motor.psi_f_wb);
                half * half
            },
            inv_dt: representable(1.0 / base.time::<f32>(ts), "control_period_s")?,
            inv_omega_base: 1.0 / base.omega_rad_s,
            speed_to_omega: omega_per_speed / base.omega_rad_s,
            accel_to_alpha: omega_per_speed / base.omega_rad_s / base.omega_rad_s,
            metres_per_turn: 2.0 * motor.pole_pitch_m,
            turns_per_metre: 0.5 / motor.pole_pitch_m,
            metres_per_turn_working: T::from_f32(2.0 * motor.pole_pitch_m),
            rs: base.resistance(motor.rs_ohm),
            inv_psi_f: T::from_f32(1.0 / base.flux::<f32>(motor.psi_f_wb)),
            // A current vector dragging the mover is a spring of stiffness K_f I pi/tau
            // (N/m) on the moving mass: natural frequency w_n = sqrt(K_f I pi / (tau M)).
            // Retarding the vector by k dw_e (rad) gives a force -K_f I k dw_e against
            // the swing: damping ratio 0.7 for k = 1.4 / w_n = 1.4 sqrt(M tau / (K_f pi))
            // / sqrt(I).
            damping_s_sqrt_unit: 1.4
                * sqrt_rounded(
                    config.moving_mass_kg
                        / (motor.thrust_constant_n_per_a() * omega_per_speed * base.current_a),
                ),
            damping_min_amplitude: T::from_f32((1e-3 / base.current_a).max(1e-4)),
            startup_speed_filter_rate: {
                let stiffness = motor.thrust_constant_n_per_a() * config.startup.current_a * omega_per_speed;
                (5.0 * sqrt_rounded(stiffness / config.moving_mass_kg) * ts).min(1.0)
            },
        };
        // A speed drive passes through zero speed (a reversal, a stop) in the same
        // low-speed mode, its profile following the speed reference: the defaults of
        // `MotionConfig::for_drive` with the speed reference's acceleration limit and the
        // speed the bus can drive (no stroke: the profile follows a speed, no targets).
        let follows_speed = config.motion.is_none();
        let motion = config.motion.unwrap_or_else(|| {
            MotionConfig::for_drive(
                motor,
                config,
                ProfileLimits {
                    max_speed_m_per_s: config.bus_speed_limit_m_per_s(motor),
                    max_accel_m_per_s2: config.accel_limit_m_per_s2,
                    stroke_min_m: f32::MIN,
                    stroke_max_m: f32::MAX,
                },
            )
        });
        let positioning = Some(motion).map(|m| -> Result<Positioning<T>, DriveConfigError> {
            // A profile the motor cannot follow is refused (`DriveConfig::check_profile`).
            if !follows_speed {
                config
                    .check_profile(motor, &m.limits)
                    .map_err(|f| DriveConfigError { field: f.config_path() })?;
            }
            // The low-speed vector at rest is a spring of stiffness K_f I pi / tau (N/m)
            // on the moving mass: its natural frequency w_n (rad/s) sets the damping,
            // the filters and the dither of the low-speed mode (`positioning` docs).
            let stiffness = motor.thrust_constant_n_per_a() * m.low_speed_current_a * omega_per_speed;
            let wn = sqrt_rounded(stiffness / config.moving_mass_kg);
            let profile =
                Profile::new(m.limits, 0.0).map_err(|_| DriveConfigError { field: "motion.limits" })?;
            let period = |dt_s: f32| Period::new(dt_s).ok_or(DriveConfigError { field: "control_period_s" });
            let control_period = period(ts)?;
            let speed_loop_period = period(ts * f32::from(config.speed_loop_divider))?;
            Ok(Positioning {
                profile,
                control_period,
                speed_loop_period,
                follows_speed,
                enter_omega: base.omega(m.low_speed_m_per_s * omega_per_speed),
                enter_m_per_s: m.low_speed_m_per_s,
                exit_m_per_s: m.low_speed_m_per_s * m.low_speed_exit_ratio,
                low_speed_current: base.current(m.low_speed_current_a),
                exit_current: base.current(m.exit_current_a),
                slew_step: base.current(m.current_slew_a_per_s * ts),
                position_gain: m.position_bandwidth_rad_s,
                position_gain_per_turn: representable(
                    m.position_bandwidth_rad_s * 2.0 * motor.pole_pitch_m * omega_per_speed
                        / base.omega_rad_s,
                    "motion.position_bandwidth_rad_s",
                )?,
                speed_limit: representable(
                    m.limits.max_speed_m_per_s * omega_per_speed / base.omega_rad_s,
                    "motion.limits",
                )?,
                accel_current_per_m_s2: config.moving_mass_kg
                    / motor.thrust_constant_n_per_a()
                    / base.current_a,
                speed_filter_rate: (5.0 * wn * ts).min(1.0),
                speed_error_rad_s: 0.0,
                speed_reading_abs_rad_s: 0.0,
                retard_rad: 0.0,
                retard_rate_rad_s: 0.0,
                current_loop_rate: (config.current_bandwidth_rad_s * ts).min(1.0),
                newtons_per_unit_current: motor.thrust_constant_n_per_a() * base.current_a,
                load_current: T::ZERO,
                // 50 ms, at the speed loop's rate.
                load_learning_rate: T::from_f32((speed_ts / LOAD_LEARNING_TIME_S).min(1.0)),
                mover_offset_rad: 0.0,
                rest_time_s: 0.0,
                // 0.8 w_n at rest (full current); decaying over three of its periods.
                dither_rad_s: 0.8 * wn,
                dither_decay_per_s: 0.8 * wn / (3.0 * 2.0 * core::f32::consts::PI),
                speed_loop_out: T::ZERO,
                accel_ff_applied: T::ZERO,
                accel_ff_target: T::ZERO,
                reference_omega: T::ZERO,
                mover_filter_rate: (wn * ts).min(1.0),
                hfi: match m.hfi {
                    Some(h) => {
                        Some(Hfi::new(&h, base).map_err(|_| DriveConfigError { field: "motion.hfi" })?)
                    }
                    None => None,
                },
                observer_speed_to_omega: match m.hfi {
                    Some(h) => base.omega(HOLD_OBSERVER_SHARE * h.bandwidth_rad_s * omega_per_speed),
                    None => T::ZERO,
                },
                holding: false,
                hold_observer: match m.hfi {
                    Some(h) => Some(
                        LoadObserver::new(&LoadObserverConfig {
                            mass_kg: config.moving_mass_kg,
                            bandwidth_rad_s: HOLD_OBSERVER_SHARE * h.bandwidth_rad_s,
                            dt_s: ts,
                            load_limit_n: config.current_limit_a * motor.thrust_constant_n_per_a(),
                            // The speed loop moves on the observer's speed on HFI, up
                            // to the profile's top speed when the hand-over waits.
                            speed_limit_m_per_s: 2.0
                                * m.low_speed_m_per_s.max(m.limits.max_speed_m_per_s).max(0.01),
                            // The thrust current in working units.
                            thrust_unit_n: motor.thrust_constant_n_per_a() * base.current_a,
                            hold_ratio: HOLD_BANDWIDTH_SHARE,
                        })
                        .map_err(|_| DriveConfigError { field: "motion.hfi" })?,
                    ),
                    None => None,
                },
                // A held swing of a radian on the spring reaches w_n; the inverter's
                // error reads as up to the low-speed threshold's speed.
                slip_margin_rad_s: wn + m.low_speed_m_per_s * omega_per_speed,
                slip_settle_s: 2.0 * core::f32::consts::TAU / wn,
                slip_guard_s: 0.0,
                anchor_angle: Angle::ZERO,
                anchor_x_m: 0.0,
                anchor_pending_m: 0.0,
                seeded: false,
                exit_agreement: T::from_f32(HANDOVER_SPEED_AGREEMENT),
                exit_agreement_periods: samples(config.estimator.pll.lock_filter_s).max(1),
                exit_disagreement: T::ZERO,
                exit_filter_rate: T::from_f32((ts / config.estimator.pll.lock_filter_s).min(1.0)),
                aligned: false,
            })
        });
        let positioning = match positioning {
            Some(p) => Some(p?),
            None => None,
        };
        let phase_loss =
            PhaseLoss::new(ts / config.faults.phase_loss_filter_s, k.current_error, k.current_error_samples);
        Ok(Drive {
            k,
            estimator,
            pi_q: pi_d,
            pi_d,
            pi_speed,
            state: DriveState::Disabled,
            faults: Faults::NONE,
            enable_requested: false,
            omega_target: T::ZERO,
            applied_speed_ref_bits: None,
            omega_ref: T::ZERO,
            omega_filtered: T::ZERO,
            overload_count: 0,
            thrust_before_loss: T::ZERO,
            i_dq_ref: Dq::default(),
            offsets: Abc::default(),
            offset_sum: Abc::default(),
            counter: 0,
            speed_divider_count: 0,
            theta_ol: Angle::ZERO,
            omega_ol: T::ZERO,
            u_prev: AlphaBeta::default(),
            u_prev2: AlphaBeta::default(),
            observer_u_offset: AlphaBeta::default(),
            observer_i_offset: AlphaBeta::default(),
            positioning,
            position_counts: 0,
            theta_previous: Angle::ZERO,
            catching: false,
            u_dq_last: Dq::default(),
            i_dq_measured: Dq::default(),
            low_speed_mover_angle: None,
            commissioning: None,
            commissioning_outcome: None,
            current_error_count: 0,
            phase_loss,
            startup_speed_error_rad_s: 0.0,
        })
    }

    /// Adds DC offsets to what the *observer* is given — voltage `u_offset` (V) and
    /// current `i_offset` (A) — while the current loops keep the true measurements: the
    /// disturbance experiments of the paper (Figs. 14-16). Zero for normal operation.
    pub fn set_observer_offsets(&mut self, u_offset: AlphaBeta<T>, i_offset: AlphaBeta<T>) {
        if u_offset.is_valid() && i_offset.is_valid() {
            self.observer_u_offset = u_offset;
            self.observer_i_offset = i_offset;
        }
    }

    /// Resets the estimator to its zero state, as if it had lost the mover: fault
    /// injection for tests of the flying restart (a running drive then goes through
    /// `Reacquiring`).
    pub fn reset_estimator(&mut self) {
        self.estimator.reset();
    }

    /// Asks the drive to run: from `Disabled` it calibrates, starts and runs.
    pub fn enable(&mut self) {
        self.enable_requested = true;
    }

    /// Starts commissioning (see the `commissioning` module): from `Disabled` only; the
    /// drive calibrates its current offsets, then identifies R, the inverter's voltage
    /// error, Ld, Lq and psi_f with the bridge on, and returns to `Disabled`. Read the
    /// outcome with [`Drive::commissioning_result`]. A bad setting or a drive that is not
    /// `Disabled` is refused (`BadSetting`).
    pub fn start_commissioning(&mut self, config: CommissioningConfig) -> Result<(), CommissioningError> {
        if self.state != DriveState::Disabled {
            return Err(CommissioningError::BadSetting("drive state (not disabled)"));
        }
        self.commissioning = Some(Commissioning::new(config, self.k.dt_s)?);
        self.commissioning_outcome = None;
        self.enable_requested = true;
        Ok(())
    }

    /// A drive for commissioning a motor it is told only `config` about, commissioning
    /// requested ([`Drive::start_commissioning`]): built for
    /// [`CommissioningConfig::placeholder_motor`] with
    /// [`DriveConfig::for_motor`]`(placeholder, config.bus_v, Dcfo)` (protections from
    /// the told ratings and bus), working in SI if `like` is [`Base::SI`], else in the
    /// per-unit base of the placeholder ([`Base::for_motor`]: the told ratings). This is
    /// the drive `dcfo identify` runs in process and the HIL link builds on a start
    /// request, so the two agree bit for bit.
    ///
    /// # Errors
    /// `BadSetting` naming the setting the drive refused, or the commissioning's own.
    pub fn for_commissioning(config: CommissioningConfig, like: &Base) -> Result<Self, CommissioningError> {
        let motor = config.placeholder_motor();
        let drive_config = DriveConfig::for_motor(&motor, config.bus_v, ObserverKind::Dcfo);
        let base = if *like == Base::SI { Base::SI } else { Base::for_motor(&motor) };
        let mut drive =
            Drive::new(&motor, &drive_config, &base).map_err(|e| CommissioningError::BadSetting(e.field))?;
        drive.start_commissioning(config)?;
        Ok(drive)
    }

    /// `true` while commissioning is requested or under way (it has not ended).
    pub fn commissioning_pending(&self) -> bool {
        self.commissioning.is_some()
    }

    /// The last commissioning's outcome: `None` before one has ended, else the result
    /// (SI) or why it stopped.
    pub fn commissioning_result(&self) -> Option<Result<CommissioningResult, CommissioningError>> {
        self.commissioning_outcome
    }

    /// Switches the bridge off at the next step and returns to `Disabled`.
    pub fn disable(&mut self) {
        self.enable_requested = false;
        self.commissioning = None;
        self.drop_moves();
    }

    /// Clears latched faults; the drive returns to `Disabled` (enable again to run).
    pub fn clear_faults(&mut self) {
        if self.state == DriveState::Fault {
            self.faults = Faults::NONE;
            self.state = DriveState::Disabled;
            self.enable_requested = false;
        }
    }

    /// Latches an externally detected fault (e.g. a silent link); bridge off.
    pub fn trip(&mut self, fault: Faults) {
        self.faults.insert(fault);
        self.state = DriveState::Fault;
        self.drop_moves();
    }

    /// Sets the speed reference (electrical rad/s, working units); the drive follows
    /// it at the configured acceleration limit.
    pub fn set_speed_reference(&mut self, omega_e: T) {
        if omega_e.is_valid() {
            self.omega_target = omega_e;
        }
        self.applied_speed_ref_bits = None;
    }

    /// A linear speed in m/s as the electrical speed reference in working units.
    pub fn omega_from_speed(&self, speed_m_per_s: f32) -> T {
        self.k.base.omega(speed_m_per_s * self.k.omega_per_speed)
    }

    /// An electrical speed in working units as the mover's linear speed, m/s: the
    /// inverse of [`Drive::omega_from_speed`].
    fn speed_from_omega(&self, omega_e: T) -> f32 {
        omega_e.to_f32() * self.k.base.omega_rad_s / self.k.omega_per_speed
    }

    /// The drive's estimator, for inspection (its notch and FLL frequencies, e.g. in
    /// diagnostics and tests).
    pub fn estimator(&self) -> &Estimator<T> {
        &self.estimator
    }

    /// The drive's state.
    pub fn state(&self) -> DriveState {
        self.state
    }

    /// Latched faults.
    pub fn faults(&self) -> Faults {
        self.faults
    }

    /// The working-unit base this drive computes in.
    pub fn base(&self) -> &Base {
        &self.k.base
    }

    /// [`Drive::step`] after `missed_periods` periods in which the plant ran on the last
    /// duties while the drive was not stepped (sensor frames lost on a link: the host
    /// holds the last answered duties). The estimator then integrates the whole time
    /// since the previous step, `(1 + n) dt`, on the voltages the plant applied in it:
    /// the command of two steps back for one period and the last one for `n`. Without
    /// that the angle falls behind by `n w dt` (with one period in 20 lost, enough to
    /// fail the fault campaign's corrupted-frames case). Gaps beyond
    /// [`MAX_BRIDGED_PERIODS`] are stepped as one period: a host that loses that many
    /// frames is the link watchdog's business.
    pub fn step_after_missed(&mut self, m: &Measurements<T>, missed_periods: u16) -> StepOutput<T> {
        let mut out = self.idle_output();
        self.step_bridging(
            m,
            if missed_periods <= MAX_BRIDGED_PERIODS { missed_periods } else { 0 },
            &mut out,
        );
        out
    }

    /// One control step; see the module documentation for timing and states.
    pub fn step(&mut self, m: &Measurements<T>) -> StepOutput<T> {
        let mut out = self.idle_output();
        self.step_bridging(m, 0, &mut out);
        out
    }

    /// The output of a step that applies nothing, as a step starts from. Formed in the
    /// caller's frame and filled in place by [`Drive::step_bridging`]: returned by value
    /// from there, the output (about 100 bytes) was copied once more every period (a
    /// `memcpy`, a few hundred instructions on the Cortex-M3).
    #[inline(always)]
    fn idle_output(&self) -> StepOutput<T> {
        StepOutput {
            duties: Duties::centred(),
            bridge_enabled: false,
            state: self.state,
            faults: self.faults,
            estimate: None,
            theta_control: self.theta_ol,
            i_ab: AlphaBeta::default(),
            i_dq: Dq::default(),
            i_dq_ref: self.i_dq_ref,
            u_applied: AlphaBeta::default(),
            i_observer: AlphaBeta::default(),
            alpha_e_ref: T::ZERO,
        }
    }

    /// One control step after `missed_periods` (at most [`MAX_BRIDGED_PERIODS`]) periods
    /// the drive was not stepped in, into `out` (from [`Drive::idle_output`]).
    fn step_bridging(&mut self, m: &Measurements<T>, missed_periods: u16, out: &mut StepOutput<T>) {
        if self.state != DriveState::Fault {
            self.check_measurements(m);
        }
        if !self.enable_requested && self.state != DriveState::Fault {
            self.state = DriveState::Disabled;
        }
        let i_abc = Abc {
            a: m.i_abc.a - self.offsets.a,
            b: m.i_abc.b - self.offsets.b,
            c: m.i_abc.c - self.offsets.c,
        };
        out.i_ab = clarke(i_abc);
        match self.state {
            DriveState::Fault => {}
            DriveState::Disabled => {
                if self.enable_requested {
                    self.state = DriveState::Calibrating;
                    self.counter = 0;
                    self.offset_sum = Abc::default();
                }
            }
            DriveState::Calibrating => self.calibrate(m),
            DriveState::Starting | DriveState::Running | DriveState::Reacquiring | DriveState::LowSpeed => {
                self.control(m, missed_periods, out)
            }
            DriveState::Commissioning => self.commission(m, out),
        }
        if self.state == DriveState::Fault
            && let Some(_) = self.commissioning.take()
        {
            // A protection of the drive's own stopped the commissioning.
            let f = self.faults;
            let e = if f.contains(Faults::BUS_UNDER_VOLTAGE) || f.contains(Faults::BUS_OVER_VOLTAGE) {
                CommissioningError::BusOutOfRange
            } else if f.contains(Faults::OVER_CURRENT) {
                CommissioningError::RunawayCurrent
            } else if f.contains(Faults::NON_FINITE) {
                CommissioningError::NonFinite
            } else {
                CommissioningError::DriveFault(f.bits())
            };
            self.commissioning_outcome = Some(Err(e));
            self.faults.insert(Faults::COMMISSIONING);
        }
        if !matches!(
            self.state,
            DriveState::Starting
                | DriveState::Running
                | DriveState::Reacquiring
                | DriveState::LowSpeed
                | DriveState::Commissioning
        ) {
            // Bridge off: nothing is applied, the history is cleared.
            self.u_prev = AlphaBeta::default();
            self.u_prev2 = AlphaBeta::default();
            out.duties = Duties::centred();
            out.bridge_enabled = false;
        }
        out.state = self.state;
        out.faults = self.faults;
        out.i_dq_ref = self.i_dq_ref;
    }

    /// Protection checks on raw measurements; latches faults.
    fn check_measurements(&mut self, m: &Measurements<T>) {
        let valid = m.i_abc.a.is_valid() && m.i_abc.b.is_valid() && m.i_abc.c.is_valid() && m.vdc.is_valid();
        if !valid {
            self.trip(Faults::NON_FINITE);
            return;
        }
        let trip = self.k.overcurrent;
        if m.i_abc.a.abs() > trip || m.i_abc.b.abs() > trip || m.i_abc.c.abs() > trip {
            self.trip(Faults::OVER_CURRENT);
        }
        if self.state != DriveState::Disabled {
            if m.vdc < self.k.bus_min {
                self.trip(Faults::BUS_UNDER_VOLTAGE);
            }
            if m.vdc > self.k.bus_max {
                self.trip(Faults::BUS_OVER_VOLTAGE);
            }
        }
    }

    fn calibrate(&mut self, m: &Measurements<T>) {
        self.offset_sum.a = self.offset_sum.a + m.i_abc.a;
        self.offset_sum.b = self.offset_sum.b + m.i_abc.b;
        self.offset_sum.c = self.offset_sum.c + m.i_abc.c;
        self.counter += 1;
        if self.counter < self.k.calibration_samples {
            return;
        }
        let n = self.k.inv_calibration_samples;
        let o = Abc { a: self.offset_sum.a * n, b: self.offset_sum.b * n, c: self.offset_sum.c * n };
        let lim = self.k.max_offset;
        if !(o.a.is_valid() && o.b.is_valid() && o.c.is_valid())
            || o.a.abs() > lim
            || o.b.abs() > lim
            || o.c.abs() > lim
        {
            self.trip(Faults::CALIBRATION);
            return;
        }
        self.offsets = o;
        if self.commissioning.is_some() {
            self.state = DriveState::Commissioning;
            self.counter = 0;
            return;
        }
        self.start();
        if !self.is_positioning() && self.k.catch_probe_samples > 0 {
            // Catch a mover that is already moving: hold zero current (the current loops
            // regulate it, so the voltage they apply is the back-EMF) and let the
            // estimator acquire, as in a flying restart.
            self.state = DriveState::Reacquiring;
            self.catching = true;
            self.i_dq_ref = Dq::default();
        }
    }

    /// Commissioning: one step of the identification, its voltage modulated.
    fn commission(&mut self, m: &Measurements<T>, out: &mut StepOutput<T>) {
        let base = self.k.base;
        let (i_alpha, i_beta) = (base.to_amperes(out.i_ab.alpha), base.to_amperes(out.i_ab.beta));
        let step = match self.commissioning.as_mut() {
            Some(c) => c.step(i_alpha, i_beta, base.to_volts(m.vdc)),
            None => CommissioningStep::Failed(CommissioningError::BadSetting("commissioning")),
        };
        match step {
            CommissioningStep::Apply(u_alpha, u_beta) => {
                let command = AlphaBeta::new(base.voltage(u_alpha), base.voltage(u_beta));
                match svpwm(command, m.vdc) {
                    Ok(modulation) => {
                        out.duties = modulation.duties;
                        out.bridge_enabled = true;
                        out.u_applied = self.u_prev;
                        self.u_prev = command;
                    }
                    Err(_) => {
                        self.commissioning = None;
                        self.commissioning_outcome = Some(Err(CommissioningError::NonFinite));
                        self.trip(Faults::COMMISSIONING | Faults::MODULATION);
                    }
                }
            }
            CommissioningStep::Done(result) => {
                self.commissioning = None;
                self.commissioning_outcome = Some(Ok(result));
                self.enable_requested = false;
                self.state = DriveState::Disabled;
            }
            CommissioningStep::Failed(e) => {
                self.commissioning = None;
                self.commissioning_outcome = Some(Err(e));
                self.trip(Faults::COMMISSIONING);
            }
        }
    }

    /// Enters `Starting` with every controller and the estimator at rest.
    fn start(&mut self) {
        self.estimator.reset();
        self.start_open_loop();
    }

    /// Enters `Starting` (or, for a positioning drive, the alignment) with every
    /// controller at rest; the estimator keeps its state.
    fn start_open_loop(&mut self) {
        self.state = DriveState::Starting;
        self.counter = 0;
        self.thrust_before_loss = T::ZERO;
        self.pi_d.reset();
        self.pi_q.reset();
        self.pi_speed.reset();
        self.theta_ol = Angle::ZERO;
        self.omega_ol = T::ZERO;
        self.omega_ref = T::ZERO;
        self.omega_filtered = T::ZERO;
        self.i_dq_ref = Dq::new(T::ZERO, self.k.startup_current);
        self.u_prev = AlphaBeta::default();
        self.u_prev2 = AlphaBeta::default();
        self.current_error_count = 0;
        self.phase_loss.reset();
        self.startup_speed_error_rad_s = 0.0;
        if self.is_positioning() {
            self.start_positioning();
        }
    }

    /// Starting and Running: estimator, references, current loops, modulation.
    /// `missed_periods`: periods the plant ran on the held duties since the previous step
    /// ([`Drive::step_after_missed`]; 0 normally).
    fn control(&mut self, m: &Measurements<T>, missed_periods: u16, out: &mut StepOutput<T>) {
        let k = &self.k;
        out.i_observer = AlphaBeta::new(
            out.i_ab.alpha + self.observer_i_offset.alpha,
            out.i_ab.beta + self.observer_i_offset.beta,
        );
        out.alpha_e_ref = self.estimator.commanded_acceleration();
        let (u_observer, dt_observer) = if missed_periods == 0 {
            (self.u_prev2, k.dt)
        } else {
            // u_prev2 for one period, u_prev (held) for the missed ones; 1/(1+n) formed
            // in f32 (n is a count).
            let n = f32::from(missed_periods);
            let (w_last, w_held) = (T::from_f32(1.0 / (1.0 + n)), T::from_f32(n / (1.0 + n)));
            (
                AlphaBeta::new(
                    self.u_prev2.alpha * w_last + self.u_prev.alpha * w_held,
                    self.u_prev2.beta * w_last + self.u_prev.beta * w_held,
                ),
                k.dt * T::from_f32(1.0 + n),
            )
        };
        let estimate = match self.estimator.update(u_observer, out.i_observer, dt_observer) {
            Ok(e) => e,
            Err(_) => {
                self.trip(Faults::ESTIMATOR);
                return;
            }
        };
        out.estimate = Some(estimate);
        // A salient motor's low-speed mode runs on HFI (`positioning` docs), its speed loop
        // on the hold observer's speed alone (set there): the back-EMF estimate, below its
        // floor and not yet seeded, is no speed to mix in.
        let hfi_steers =
            self.state == DriveState::LowSpeed && self.positioning.as_ref().is_some_and(|p| p.hfi.is_some());
        if !hfi_steers {
            // The rate is Ts / tau within (0, 1]: no saturation check.
            self.omega_filtered =
                self.omega_filtered + (estimate.omega_e - self.omega_filtered).mul_unit(k.speed_filter_rate);
        }
        let hfi = if hfi_steers { self.hfi_low_speed(&estimate, out.i_ab) } else { None };
        let (theta, omega) = match (hfi, self.state) {
            (Some((theta, omega, _)), _) => (theta, omega),
            (None, DriveState::Starting) => self.startup_references(&estimate),
            (None, DriveState::Reacquiring) => self.reacquiring_references(&estimate),
            (None, DriveState::LowSpeed) => self.low_speed_references(&estimate, out.i_observer),
            (None, _) => self.running_references(&estimate),
        };
        let hfi = hfi.map(|(_, _, step)| step);
        let position_angle = self.low_speed_mover_angle.take().unwrap_or(theta);
        self.track_position(position_angle);
        if self.state == DriveState::Fault {
            return;
        }
        let k = &self.k;
        out.theta_control = theta;
        // Running (also right after hand-over) controls at the PLL's angle, whose cos/sin
        // the PLL has already computed.
        let cs = if theta == estimate.theta_e { estimate.cos_sin } else { CosSin::new(theta) };
        // With HFI the loops see the fundamental current (the HF swing averaged out).
        let i_loop = hfi.map_or(out.i_ab, |h| h.i_fundamental);
        let i_dq = park(i_loop, &cs);
        out.i_dq = i_dq;
        self.i_dq_measured = i_dq;

        // Current loops with decoupling feed-forward (Running only: in open loop the
        // control frame is not the rotor frame), limited to the voltage circle.
        let (ff_d, ff_q) = if !matches!(self.state, DriveState::Starting | DriveState::LowSpeed) {
            (-omega * k.lq * i_dq.q, omega * (k.ld * i_dq.d + k.psi_f))
        } else {
            (T::ZERO, T::ZERO)
        };
        // modulation_limit / sqrt 3 is within (0, 0.58] (validated).
        let v_max = m.vdc.mul_unit(k.modulation_limit);
        // HFI aligning holds the loops: the bridge applies the injection alone.
        let loops_run = hfi.is_none_or(|h| h.ready);
        let (u_d, u_q) = if !loops_run {
            (T::ZERO, T::ZERO)
        } else {
            let u_d = ff_d + self.pi_d.update_within(self.i_dq_ref.d - i_dq.d, -v_max - ff_d, v_max - ff_d);
            let u_d = u_d.clamp_to(-v_max, v_max);
            let v_q_max = (v_max * v_max - u_d * u_d).sqrt();
            let u_q =
                ff_q + self.pi_q.update_within(self.i_dq_ref.q - i_dq.q, -v_q_max - ff_q, v_q_max - ff_q);
            (u_d, u_q.clamp_to(-v_q_max, v_q_max))
        };
        self.u_dq_last = Dq::new(u_d, u_q);
        // Current-control supervision: the voltage on its limit (within 2 %) and the
        // current still off its reference, period after period, means the loops have
        // lost control of the current (an open phase; a stuck sensor, behind which the
        // true current can grow to what the bus drives through the winding).
        let e = Dq::new(self.i_dq_ref.d - i_dq.d, self.i_dq_ref.q - i_dq.q);
        let at_limit = u_d * u_d + u_q * u_q >= v_max * v_max * k.at_limit_sq;
        let off = e.d * e.d + e.q * e.q > k.current_error * k.current_error;
        self.current_error_count =
            if at_limit && off { self.current_error_count.saturating_add(1) } else { 0 };
        if self.current_error_count > k.current_error_samples {
            self.trip(Faults::CURRENT_CONTROL);
            return;
        }
        // Phase loss: the loops run (HFI's alignment holds them) and one phase carries
        // far less than its reference while another carries its own: an open phase, whose
        // current is zero whatever the bridge applies. The check above sees it only once
        // the voltage saturates, which at light load comes after the wrong currents have
        // corrupted the flux estimate (FaultConfig::phase_loss_filter_s). Checked in
        // every fourth period (module `phase_loss`).
        if loops_run
            && self.phase_loss.due()
            && self
                .phase_loss
                .update(inverse_clarke(i_loop), inverse_clarke(inverse_park(self.i_dq_ref, &cs)))
        {
            self.trip(Faults::CURRENT_CONTROL);
            return;
        }
        let k = &self.k;

        // The command is applied from the next period on: rotate it to the middle of
        // its application window.
        let theta_apply = theta + (omega * k.dt * k.delay_periods).radians_to_angle();
        let cs_apply = CosSin::inline(theta_apply);
        let u_ab = inverse_park(Dq::new(u_d, u_q), &cs_apply);
        // The bus and its reciprocal once, for the compensation and the modulator.
        let bus = match DcBus::new(m.vdc) {
            Ok(bus) => bus,
            Err(_) => {
                self.trip(Faults::MODULATION);
                return;
            }
        };
        let comp = match &k.inverter {
            Some(model) if loops_run => {
                let i = inverse_clarke(inverse_park(self.compensation_current(model, i_dq), &cs_apply));
                // HFI's square wave, met by no back-EMF, ramps the current across each
                // period: the model takes it at the switching edges (`dead_time`, "Under
                // injection").
                let inject = hfi.map(|h| h.inject);
                let u = inject.map_or(u_ab, |v| AlphaBeta::new(u_ab.alpha + v.alpha, u_ab.beta + v.beta));
                model.compensation_injecting(u, inject, &bus, i)
            }
            _ => AlphaBeta::default(),
        };
        let command = AlphaBeta::new(u_ab.alpha + comp.alpha, u_ab.beta + comp.beta);
        let command = match hfi {
            Some(h) => {
                if let Some(hfi) = self.positioning.as_mut().and_then(|p| p.hfi.as_mut()) {
                    hfi.set_fundamental_command(command);
                }
                AlphaBeta::new(command.alpha + h.inject.alpha, command.beta + h.inject.beta)
            }
            None => command,
        };
        match svpwm_on(command, &bus) {
            Ok(modulation) => {
                out.duties = modulation.duties;
                out.bridge_enabled = true;
                // What the inverter is expected to produce: the (possibly shortened)
                // command less the compensation of the inverter's own error.
                let intended = AlphaBeta::new(
                    modulation.u_applied.alpha - comp.alpha + self.observer_u_offset.alpha,
                    modulation.u_applied.beta - comp.beta + self.observer_u_offset.beta,
                );
                out.u_applied = self.u_prev;
                self.u_prev2 = self.u_prev;
                self.u_prev = intended;
            }
            Err(_) => self.trip(Faults::MODULATION),
        }
    }

    /// The current the inverter compensation takes its signs from (A, control frame):
    /// `i_measured`, or with [`CompensationSigns::ReferenceAboveNoise`] the reference
    /// while it is clear of the sensors' noise, `i_measured` near zero, and a linear blend
    /// from [`COMPENSATION_REFERENCE_FROM_BANDS`] to twice that many compensation bands.
    ///
    /// Within its band the compensation is proportional to the current it reads, a gain
    /// of `amplitude / band` (about 600 V/A on the paper axis) from that current to the
    /// winding's voltage. Read from the measured current, it puts the current sensors'
    /// noise on the winding: at light load the phase currents spend part of every period
    /// within a few noise sigmas of zero, and the noise switches the compensation's full
    /// `(Td/Ts) Vdc` back and forth there (on the simulated axes that noise is most of the
    /// light-load steady error, and drives a 5 Hz speed swing on the salient motor's
    /// axis). The reference is noise-free and what the current loop makes flow. Near zero
    /// it is not: there the three currents lie within the PWM ripple at the switching
    /// edges, the inverter loses almost nothing, and the reference's clean sign would
    /// command the full amplitude anyway (after an estimator reset at speed, a 5 Hz swing
    /// through zero thrust current); the measured current's noise averages the
    /// compensation to about what the inverter loses there. The blend from 4 to 8 bands
    /// did better on the paper axis than 2 to 4 or the reference alone. It relies on the
    /// PWM ripple at the switching edges being modelled ([`crate::algorithms::dead_time`]); without
    /// that the reference's signs lost at 1.0-1.5 m/s. Filtering the measured current
    /// instead (at the current loop's bandwidth, in a frame turning with it) puts a lag
    /// inside that 600 V/A path and lost the steady state. `docs/inverter-compensation.md`
    /// has the measurements. The result is carried forward to the application window and
    /// handed to the inverter model per phase. Inlined into its one caller (out of line
    /// the Cortex-M3 image grew by about 300 B).
    #[inline(always)]
    fn compensation_current(&self, model: &InverterErrorModel<T>, i_measured: Dq<T>) -> Dq<T> {
        let k = &self.k;
        if !k.signs_from_reference {
            return i_measured;
        }
        let r = self.i_dq_ref;
        // |i_ref| in bands; saturates (far above the blend) where 1/band exceeds the range.
        let bands = (r.d * r.d + r.q * r.q).sqrt() * model.inv_band_sqrt * model.inv_band_sqrt;
        let w =
            ((bands - k.compensation_reference_from) * k.compensation_blend_rate).clamp_to(T::ZERO, T::ONE);
        Dq::new(
            i_measured.d + (r.d - i_measured.d).mul_unit(w),
            i_measured.q + (r.q - i_measured.q).mul_unit(w),
        )
    }

    /// Open-loop I/f: ramps the frequency to the hand-over speed in the direction of
    /// the speed reference, then hands over once the estimator has locked near it.
    fn startup_references(&mut self, estimate: &Estimate<T>) -> (Angle, T) {
        let k = &self.k;
        let target = if self.omega_target < T::ZERO { -k.handover_omega } else { k.handover_omega };
        let step = k.startup_accel_step;
        let omega_before = self.omega_ol;
        self.omega_ol = if self.omega_ol < target {
            (self.omega_ol + step).min(target)
        } else {
            (self.omega_ol - step).max(target)
        };
        // The ramp is commanded: the estimator knows the speed is changing (its notch
        // feed-forward, and no DC fit on a back-EMF that draws no circle).
        self.estimator.set_commanded_acceleration((self.omega_ol - omega_before) * k.inv_dt);
        // Damping: the vector drags the mover on a spring (stiffness K_f I pi/tau) that
        // nothing but friction damps, so the mover swings about the open-loop speed (a
        // bare paper mover between 0.1 and 0.4 m/s about 0.25 m/s) and can be where
        // friction stops it when the speed loop takes over. The mover's speed from the
        // d voltage of the last step: the vector lies on q, the mover's flux near it
        // (90 deg at no load), so its back-EMF lies on -d,
        // u_d = Rs i_d - w_ol Lq i_q - w psi_f; the inverter's error lies along the
        // current (q), so u_d is clean. The vector trails the open-loop angle by
        // k (w - w_ol) with k from the spring's natural frequency (damping ratio 0.7).
        let i = self.i_dq_measured;
        let omega_mover = -(self.u_dq_last.d - k.rs * i.d + self.omega_ol * k.lq * i.q) * k.inv_psi_f;
        let error_rad_s = (omega_mover - self.omega_ol).to_f32() * k.base.omega_rad_s;
        if error_rad_s.is_finite() {
            self.startup_speed_error_rad_s +=
                k.startup_speed_filter_rate * (error_rad_s - self.startup_speed_error_rad_s);
        }
        let damping_s = k.vector_damping_s(self.i_dq_ref.q.abs());
        let retard = (damping_s * self.startup_speed_error_rad_s).clamp(-0.5, 0.5);
        let theta = self.theta_ol - retard.radians_to_angle();
        self.theta_ol = self.theta_ol + (self.omega_ol * k.dt).radians_to_angle();
        if self.omega_ol != target || self.omega_target == T::ZERO {
            return (theta, self.omega_ol);
        }
        self.counter = self.counter.saturating_add(1);
        // Dwell: lower the open-loop current towards the hand-over level.
        self.i_dq_ref.q = (self.i_dq_ref.q - k.startup_current_step).max(k.handover_current);
        let close = (estimate.omega_e - target).abs() < target.abs() * k.handover_tolerance;
        if self.counter >= k.dwell_samples && estimate.tracking && close {
            self.hand_over(theta, estimate);
            return (estimate.theta_e, estimate.omega_e);
        }
        if self.counter > k.startup_timeout_samples {
            self.trip(Faults::LOCK_LOST);
        }
        (theta, self.omega_ol)
    }

    /// Moves the current loops from the open-loop frame at `theta_ol` to the estimated
    /// frame without a jump in the current vector or the voltage.
    fn hand_over(&mut self, theta_ol: Angle, estimate: &Estimate<T>) {
        let from = CosSin::new(theta_ol);
        let to = estimate.cos_sin;
        let rotate = |v: Dq<T>| park(inverse_park(v, &from), &to);
        let i_ref = rotate(self.i_dq_ref);
        let integral = rotate(Dq::new(self.pi_d.integral(), self.pi_q.integral()));
        let k = &self.k;
        // The decoupling feed-forward starts now: take it out of the integrators.
        let omega = estimate.omega_e;
        let ff_d = -omega * k.lq * i_ref.q;
        let ff_q = omega * (k.ld * i_ref.d + k.psi_f);
        self.pi_d.preset(integral.d - ff_d, T::ZERO);
        self.pi_q.preset(integral.q - ff_q, T::ZERO);
        self.i_dq_ref = i_ref;
        self.omega_ref = estimate.omega_e;
        self.omega_filtered = estimate.omega_e;
        // The speed controller starts from the start-up vector's thrust part in the
        // estimated frame (|I| sin e, e the vector's lead on the mover: what was pulling
        // the mover along, against friction and load), so the mover is not let go at
        // the hand-over; the d-axis current is ramped out.
        self.pi_speed.preset(i_ref.q, T::ZERO);
        self.state = DriveState::Running;
        self.counter = 0;
        self.speed_divider_count = 0;
        self.overload_count = 0;
    }

    /// Counts one control period towards the speed loop's: `true` in every
    /// `speed_loop_divider`-th (the period the speed loop runs in), which starts the count
    /// again. One count for every mode that runs the speed loop.
    fn speed_loop_due(&mut self) -> bool {
        self.speed_divider_count = self.speed_divider_count.saturating_add(1);
        let due = self.speed_divider_count >= self.k.speed_loop_divider;
        if due {
            self.speed_divider_count = 0;
        }
        due
    }

    /// Sensorless: rate-limited speed reference, speed loop at its divided rate, d-axis
    /// current ramped to zero, lock supervision.
    fn running_references(&mut self, estimate: &Estimate<T>) -> (Angle, T) {
        if self.is_positioning() {
            if let Some(low_speed) = self.positioning_references(estimate) {
                return low_speed;
            }
        } else {
            let k = &self.k;
            let diff = (self.omega_target - self.omega_ref).clamp_to(-k.accel_step, k.accel_step);
            self.omega_ref = self.omega_ref + diff;
            // The ramp is commanded, so known: the estimator's notch leads by its lag.
            self.estimator.set_commanded_acceleration(diff * k.inv_dt);
            if let Some(low_speed) = self.speed_reference_low_speed(estimate) {
                return low_speed;
            }
            if self.speed_loop_due() {
                self.i_dq_ref.q = self.pi_speed.update(self.omega_ref - self.omega_filtered);
            }
        }
        let k = &self.k;
        let d = self.i_dq_ref.d;
        self.i_dq_ref.d =
            if d > T::ZERO { (d - k.id_ramp_step).max(T::ZERO) } else { (d + k.id_ramp_step).min(T::ZERO) };
        let limit = k.current_limit;
        self.i_dq_ref.q = self.i_dq_ref.q.clamp_to(-limit, limit);
        if self.supervise_overload() {
            return (estimate.theta_e, estimate.omega_e);
        }
        let k = &self.k;
        if estimate.tracking {
            self.counter = 0;
        } else {
            self.counter = self.counter.saturating_add(1);
            // An estimator that has lost the frequency too (acquiring) has no angle to
            // ride through on: stop pushing at once. Otherwise allow `lock_loss_s`.
            let lost = self.counter > k.lock_loss_samples || estimate.acquiring;
            // A speed drive that came out of the low-speed mode (its estimate seeded
            // there) goes back to it likewise: a flying restart there lets go of a mover
            // that friction then stops before the estimator finds it (`LOCK_LOST`; see
            // docs/low-speed-operation.md, "A speed drive through zero speed").
            if lost && self.positioning.as_ref().is_some_and(|p| !p.follows_speed || p.seeded) {
                // A positioning drive has a reference to follow: back to the low-speed
                // mode (the vector on the reference position) until the estimate,
                // seeded again from the trajectory, tracks. The lost estimate's angle is
                // no place to start from (a reset estimator reads 0): the low-speed frame
                // starts on the last control angle, at the commanded speed, so neither
                // the current vector nor the position estimate jumps.
                self.counter = 0;
                let speed_m_per_s = if self.follows_speed() {
                    self.follow_speed_reference()
                } else {
                    self.speed_from_omega(self.omega_ref)
                };
                return self.enter_low_speed(self.theta_previous, self.omega_ref, speed_m_per_s);
            }
            if lost {
                // Flying restart: stop pushing on an angle that is not trusted, and
                // let the estimator find the mover again.
                self.state = DriveState::Reacquiring;
                self.counter = 0;
                self.i_dq_ref = Dq::default();
                // The thrust the axis needed (the speed integrator's share: friction,
                // load) is resumed with; the proportional share followed an angle that
                // was already going wrong.
                self.thrust_before_loss = self.pi_speed.integral();
                self.pi_speed.reset();
                self.estimator.reacquire();
            }
        }
        (estimate.theta_e, estimate.omega_e)
    }

    /// Overload supervision of a drive on its speed loop (`Running`, and the low-speed
    /// mode on HFI): pushing on the current limit towards the speed reference while the
    /// speed is off it by more than the hand-over's tolerance (of the reference, or of the
    /// hand-over speed near zero), for longer than `FaultConfig::overload_s`, trips
    /// `OVERLOAD`. An axis that follows its ramp or profile at the limit lags by less; a
    /// load that stops the mover or drives it back, by the whole reference. Returns
    /// `true` when it tripped. Not inlined: one copy for its two callers.
    #[inline(never)]
    fn supervise_overload(&mut self) -> bool {
        let k = &self.k;
        let q = self.i_dq_ref.q;
        let speed_error = self.omega_ref - self.omega_filtered;
        let tolerance = k.handover_tolerance * self.omega_ref.abs().max(k.handover_omega);
        let pushing = (q >= k.overload_level && speed_error > tolerance)
            || (q <= -k.overload_level && speed_error < -tolerance);
        self.overload_count = if pushing { self.overload_count.saturating_add(1) } else { 0 };
        if self.overload_count > k.overload_samples {
            self.trip(Faults::OVERLOAD);
            return true;
        }
        false
    }

    /// Reacquiring: zero current references (the current loops hold zero current on the
    /// estimated angle, with the back-EMF feed-forward, so the bridge neither pushes nor
    /// brakes), until the estimate tracks again; then `Running` resumes from the
    /// estimated speed (speed loop at rest, reference from the estimate, ramping to the
    /// target at the acceleration limit).
    fn reacquiring_references(&mut self, estimate: &Estimate<T>) -> (Angle, T) {
        let k = &self.k;
        self.i_dq_ref = Dq::default();
        self.counter = self.counter.saturating_add(1);
        if estimate.tracking {
            self.state = DriveState::Running;
            self.counter = 0;
            self.speed_divider_count = 0;
            self.overload_count = 0;
            // Bumpless in thrust: the load has not changed in the tens of milliseconds
            // of the re-acquisition (zero after a catch on enable). Restarting the
            // speed loop from zero crossed zero thrust current on the way back to the
            // load, where the inverter compensation's signs are the sensors' noise.
            self.pi_speed.preset(self.thrust_before_loss, T::ZERO);
            self.thrust_before_loss = T::ZERO;
            self.omega_ref = estimate.omega_e;
            self.omega_filtered = estimate.omega_e;
            self.catching = false;
        } else if self.catching && self.counter == k.catch_probe_samples {
            // Catching on enable: no flux after the acquisition sweep means no
            // back-EMF, a mover at rest (or too slow to observe): start by I/f.
            let psi = estimate.psi_ab;
            if psi.alpha * psi.alpha + psi.beta * psi.beta < k.catch_flux_sq {
                self.catching = false;
                // The estimator keeps what it has seen (no reset: a replayed trace,
                // which starts with the catch, must see the same estimator).
                self.start_open_loop();
                return (self.theta_ol, T::ZERO);
            }
        } else if self.counter > k.reacquire_timeout_samples {
            self.catching = false;
            self.trip(Faults::LOCK_LOST);
        }
        (estimate.theta_e, estimate.omega_e)
    }
}
