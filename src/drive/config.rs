//! Drive settings (SI) and the controller gains derived from them.

use crate::algorithms::dead_time::DeadTimeCompensation;
use crate::algorithms::hfi::HfiConfig;
use crate::algorithms::motion::{ProfileField, ProfileLimits};
use crate::algorithms::observer::ObserverKind;
use crate::estimator::EstimatorConfig;
use crate::motor::MotorParams;
use crate::motor_image::MotorImage;
use crate::num::{non_negative, positive};

/// Open-loop (I/f) start-up: a current vector of fixed amplitude turned at a
/// ramping frequency drags the mover up to a speed where the back-EMF is observable.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StartupConfig {
    /// Current amplitude while accelerating, A (peak, > 0).
    pub current_a: f32,
    /// Current amplitude the start-up vector is ramped down to during the dwell, A
    /// (peak, > 0, <= `current_a`). The I/f vector lies mostly on the rotor's d axis at
    /// light load, so an angle error `e` at hand-over shows as `|I| sin e` of false
    /// thrust current: lowering `|I|` first makes the hand-over smooth.
    pub handover_current_a: f32,
    /// Acceleration of the open-loop frequency, m/s^2 (> 0).
    pub accel_m_per_s2: f32,
    /// Speed at which the drive hands over to the estimator, m/s (> 0).
    pub handover_speed_m_per_s: f32,
    /// Minimum time at the hand-over speed before handing over, s (lets the observer
    /// and PLL converge; docs/method.md §8: 0.5-1 s from cold at 8-10 Hz).
    pub dwell_s: f32,
    /// After hand-over, time over which the d-axis current of the start-up vector is
    /// ramped to zero, s (> 0).
    pub id_ramp_s: f32,
    /// Catching a moving mover on enable: after calibration the drive first holds zero
    /// current (`Reacquiring`) while the estimator acquires; if after this time (s, > 0)
    /// the flux estimate is below half the magnet flux, nothing moves and the I/f start
    /// begins; otherwise the drive enters `Running` once the estimate tracks, or trips
    /// `LOCK_LOST` after `faults.reacquire_timeout_s`. `None`: always start by I/f.
    pub catch_probe_s: Option<f32>,
    /// The I/f start trips `LOCK_LOST` when the estimator has not taken over after this
    /// many dwells at the hand-over speed (count, >= 1; default 10): long enough for a
    /// slow acquisition, short enough that a stalled mover is not dragged for long.
    pub timeout_dwells: u16,
    /// Shortest start-up timeout, s (> 0; default 1 s): with a short (or zero) dwell,
    /// `timeout_dwells` dwells would not leave the observer and PLL time to converge
    /// (0.5-1 s from cold, docs/method.md §8).
    pub min_timeout_s: f32,
}

/// Which current the inverter compensation takes its per-phase signs from (see
/// `Drive::compensation_current` for the measurements behind both).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CompensationSigns {
    /// The measured current: within the compensation's band its sign is proportional to
    /// the current sensors' noise as well.
    Measured,
    /// The current reference where it is clear of the sensors' noise (above
    /// [`super::COMPENSATION_REFERENCE_FROM_BANDS`] bands, fully from twice that), the
    /// measured current near zero: the default. It needs the PWM ripple at the switching
    /// edges modelled ([`crate::algorithms::dead_time`]), without which it loses at 1.0-1.5 m/s; with
    /// it, it beats [`Self::Measured`] on the paper axis's steady state at every speed and
    /// in the cold starts (`docs/inverter-compensation.md`).
    ReferenceAboveNoise,
}

/// Protection thresholds.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FaultConfig {
    /// Phase-current trip level, A (peak, > 0).
    pub overcurrent_a: f32,
    /// Minimum DC-bus voltage, V.
    pub bus_min_v: f32,
    /// Maximum DC-bus voltage, V.
    pub bus_max_v: f32,
    /// Longest time the PLL may be unlocked while running sensorless, s (> 0).
    pub lock_loss_s: f32,
    /// Time the drive waits in `Reacquiring` for the estimator to lock again before it
    /// trips `LOCK_LOST`, s (> 0).
    pub reacquire_timeout_s: f32,
    /// Samples averaged by the current-offset calibration (bridge off), count (> 0).
    pub calibration_samples: u16,
    /// Largest acceptable current offset, A (> 0).
    pub max_offset_a: f32,
    /// Current-control supervision, A (peak, positive): the loops' voltage command on
    /// the bridge's limit while the measured current vector is more than this off its
    /// reference for longer than `current_error_s` trips `CURRENT_CONTROL`. Catches what the
    /// overcurrent trip cannot see: an open phase, and a stuck current sensor (with two
    /// sensors the third current is computed, so a current that the stuck sensor hides
    /// can grow to the bus over the winding resistance).
    pub current_error_a: f32,
    /// See `current_error_a`, s (positive).
    pub current_error_s: f32,
    /// Averaging time of the phase-loss check, s (> 0). Each phase's measured and
    /// reference current magnitudes are low-passed with this time constant; a phase
    /// whose reference averages above `current_error_a` but which carries less than a
    /// quarter of it, while another phase carries at least half of its own, for longer
    /// than `current_error_s` trips `CURRENT_CONTROL`: an open phase (its current is
    /// zero whatever the bridge applies), seen before the voltage reaches its limit.
    /// Default 10 ms: a lost phase is named `tau ln 4 + current_error_s` (19 ms) after
    /// its reference averages above the threshold; both magnitudes pass the same filter,
    /// so the time constant only averages noise and ripple (module `phase_loss`).
    pub phase_loss_filter_s: f32,
    /// Overload supervision, s (> 0): the thrust-current reference on its limit (within
    /// 2 %) in the direction the speed error asks for, with the speed off its reference
    /// by more than `handover_speed_tolerance` of it (of the hand-over speed near zero),
    /// continuously for this long, trips `OVERLOAD` rather than letting the load push the
    /// mover on (or a flying restart push into it again). Default 0.1 s: the speed
    /// reference is ramped at `accel_limit_m_per_s2` and a positioning profile is checked
    /// against the limit ([`DriveConfig::check_profile`]), so a healthy axis reaches the
    /// limit only for a transient, and follows within the tolerance while it does.
    pub overload_s: f32,
}

/// Everything the drive needs besides the motor, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DriveConfig {
    /// Control (PWM) period, s (> 0).
    pub control_period_s: f32,
    /// The speed loop runs every this many control periods (>= 1).
    pub speed_loop_divider: u16,
    /// Current-loop bandwidth, rad/s: `kp = L w_c`, `ki = R w_c` (pole-zero cancellation).
    pub current_bandwidth_rad_s: f32,
    /// Speed-loop crossover, rad/s: `kp = w_s M / K_f`, PI zero at `speed_zero_ratio *
    /// w_s`. Keep it
    /// well below `1 / (3 tau_g)`: the DCFO's angle estimate lags transients by its
    /// band-pass group delay `tau_g = 1 / (zeta w)` (22.5 ms at 10 Hz).
    pub speed_bandwidth_rad_s: f32,
    /// Total moving mass the speed loop accelerates, kg (> 0): mover plus carriage and
    /// payload.
    pub moving_mass_kg: f32,
    /// Time constant of the speed-feedback filter, s (> 0).
    pub speed_filter_s: f32,
    /// Thrust-current limit, A (peak, > 0).
    pub current_limit_a: f32,
    /// Acceleration limit of the speed reference, m/s^2 (> 0).
    pub accel_limit_m_per_s2: f32,
    /// Fraction of the linear modulation range `Vdc / sqrt(3)` the current loops may use.
    pub modulation_limit: f32,
    /// The speed PI's zero as a fraction of the crossover `speed_bandwidth_rad_s`
    /// (dimensionless, in `(0, 1]`; default 0.25): `ki = kp w_s * speed_zero_ratio`. A
    /// zero a quarter of the crossover leaves about 76 deg of phase margin against the
    /// integrator's lag.
    pub speed_zero_ratio: f32,
    /// The estimate may be handed to the closed loops (from the I/f start, or from the
    /// low-speed mode to the position loop) once its speed is within this fraction of
    /// the reference (dimensionless, in `(0, 1)`; default 0.2): close enough that the
    /// speed PI, preset to the present current, takes over without a jerk.
    pub handover_speed_tolerance: f32,
    /// The inverse Park advances the angle by this many control periods (in `[0, 4]`;
    /// default 1.5): the duties computed at the carrier valley `t_k` are applied over
    /// `[t_{k+1}, t_{k+2})`, whose middle is 1.5 periods ahead (module docs, Timing).
    pub delay_compensation_periods: f32,
    /// Open-loop start-up.
    pub startup: StartupConfig,
    /// Inverter compensation; `None` feeds the command uncompensated.
    pub dead_time_compensation: Option<DeadTimeCompensation>,
    /// Which current the inverter compensation takes its signs from.
    pub compensation_signs: CompensationSigns,
    /// Protection.
    pub faults: FaultConfig,
    /// Observer and PLL.
    pub estimator: EstimatorConfig,
    /// Positioning on a finite stroke (moves through zero speed, position estimate and
    /// loop); `None`: a speed drive started by I/f (see [`super::Drive`]).
    pub motion: Option<MotionConfig>,
}

/// A positioning axis: profile limits, the low-speed (current-vector) mode and the
/// position loop. See the `drive` module docs and its `positioning` module.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotionConfig {
    /// Speed and acceleration limits of the moves and the stroke the targets must lie in.
    pub limits: ProfileLimits,
    /// Below this reference speed the drive runs the low-speed mode, m/s (> 0).
    pub low_speed_m_per_s: f32,
    /// The low-speed mode is left above `low_speed_exit_ratio * low_speed_m_per_s`
    /// (dimensionless, > 1): the hysteresis.
    pub low_speed_exit_ratio: f32,
    /// Amplitude of the current vector in the low-speed mode, A (peak, > 0, at most the
    /// current limit).
    pub low_speed_current_a: f32,
    /// Amplitude of the vector at the edge of the low-speed band, A (peak, > 0, at most
    /// `low_speed_current_a`): the amplitude falls linearly with the reference speed
    /// from `low_speed_current_a` at rest to this.
    pub exit_current_a: f32,
    /// Rate at which the current reference moves between the sensorless and the
    /// low-speed vectors, A/s (> 0).
    pub current_slew_a_per_s: f32,
    /// Position-loop bandwidth (proportional gain), rad/s (> 0).
    pub position_bandwidth_rad_s: f32,
    /// High-frequency injection for a salient motor: with `Some`, the low-speed mode is
    /// closed loop on the HFI angle (alignment without moving the mover, polarity,
    /// position and speed loops at standstill) instead of the open-loop current vector;
    /// see the `positioning` docs. `None`: the current vector.
    pub hfi: Option<HfiConfig>,
}

/// The bus voltage the fault limits of `drive` centre on, V.
fn nominal_bus_v(drive: &DriveConfig) -> f32 {
    0.5 * (drive.faults.bus_min_v / 0.6 + drive.faults.bus_max_v / 1.3)
}

/// The default hysteresis of the low-speed band ([`MotionConfig::low_speed_exit_ratio`],
/// dimensionless): the band is left at 1.25 times the speed it is entered below.
pub const LOW_SPEED_EXIT_RATIO: f32 = 1.25;

/// The back-EMF floor of `motor` in `drive`, m/s: the speed at which the back-EMF `w
/// psi_f` equals the inverter's voltage error before compensation (`dead_time / Ts *
/// V_bus + drop`, at the bus the fault limits centre on), or four times the DCFO's notch
/// floor, whichever is higher. Below it a back-EMF estimate rests entirely on the
/// compensation's accuracy; above it the estimator is expected to hold the angle. The
/// positioning drive's low-speed threshold.
pub fn back_emf_floor_m_per_s(motor: &MotorParams, drive: &DriveConfig) -> f32 {
    let voltage_error_v = drive
        .dead_time_compensation
        .map_or(0.0, |c| c.dead_time_s / drive.control_period_s * nominal_bus_v(drive) + c.device_drop_v);
    let omega = (voltage_error_v / motor.psi_f_wb).max(4.0 * drive.estimator.dcfo.omega_floor_rad_s);
    omega / motor.rad_per_m()
}

impl MotionConfig {
    /// Defaults for `motor` driven with `drive` (its current limit, mass and inverter
    /// compensation) over `limits`:
    /// - low-speed threshold: the speed at which the back-EMF `w psi_f` equals the
    ///   inverter's voltage error before compensation (`dead_time / Ts * V_bus +
    ///   drop`, at the bus the fault limits centre on), or four times the DCFO's notch
    ///   floor, whichever is higher: below it the estimate rests entirely on the
    ///   compensation's accuracy, and the observer's slowest pole (`0.26 w`) is too slow
    ///   to re-lock within 50 ms. Paper axis: 50 rad/s, 0.24 m/s. Exit at 1.25 times it.
    /// - low-speed current: the current limit. The mover trails the vector by
    ///   `asin(F / (K_f I))` and rests within `F_static / (K_f I)` of it, so both the
    ///   thrust margin and the accuracy at rest scale with `I` (paper axis, 5.9 A: 9 deg
    ///   for 47 N, 2.5 deg for 13 N of break-away friction; rated current gives 5 deg at
    ///   rest, above the 3 deg end-position floor). Thermally a transient: a long dwell
    ///   at the limit is the user's choice to lower it. Measured cost: a wrong `Rs` reads
    ///   as an angle error `dR I_d / (w psi_f)` while the vector is on d (26 deg at the
    ///   exit threshold for +20 % on the paper motor), which the hand-over inherits.
    /// - exit current: twice the thrust current of the profile's acceleration, at least
    ///   half rated peak, at most the low-speed current. The vector lies mostly on d, and
    ///   through a resistance error `dR` the estimator reads `dR I_d / (w psi_f)` of
    ///   angle while it does (26 deg at the exit speed at 5.9 A for +20 % on the paper
    ///   motor): the hand-over needs a small `I_d`, the hold a large one.
    /// - current slew: rated peak current in 5 ms (2 % of rated a period).
    /// - position loop: a quarter of the speed loop's crossover.
    /// - HFI ([`HfiConfig::for_motor`]) for a salient motor (`L_q / L_d >= 1.15`),
    ///   tuned for the control period and the nominal bus, and to follow the mover up to
    ///   the band's exit speed; none otherwise.
    ///
    /// Not inlined: a drive image calls it from `DriveConfig::for_image` and from
    /// `Drive::new` (a speed drive's low-speed mode), one copy for both.
    #[inline(never)]
    pub fn for_drive(motor: &MotorParams, drive: &DriveConfig, limits: ProfileLimits) -> Self {
        let bus_v = nominal_bus_v(drive);
        let rated_peak = motor.rated_current_a * core::f32::consts::SQRT_2;
        let accel_current =
            drive.moving_mass_kg * limits.max_accel_m_per_s2 / motor.thrust_constant_n_per_a();
        let low_speed_current_a = drive.current_limit_a;
        let low_speed_m_per_s = back_emf_floor_m_per_s(motor, drive);
        // HFI runs up to the low-speed band's exit speed.
        let exit_omega_rad_s = low_speed_m_per_s * LOW_SPEED_EXIT_RATIO * motor.rad_per_m();
        MotionConfig {
            limits,
            low_speed_m_per_s,
            low_speed_exit_ratio: LOW_SPEED_EXIT_RATIO,
            low_speed_current_a,
            exit_current_a: (2.0 * accel_current).max(0.5 * rated_peak).min(low_speed_current_a),
            current_slew_a_per_s: rated_peak / 0.005,
            position_bandwidth_rad_s: 0.25 * drive.speed_bandwidth_rad_s,
            hfi: HfiConfig::for_motor(motor, drive.control_period_s, bus_v, exit_omega_rad_s).ok(),
        }
    }
}

impl DriveConfig {
    /// Defaults for `motor` on a bus of nominal `bus_v` volts with the given observer,
    /// at 10 kHz, moving the motor's own mass. Current loop at 1500 rad/s (a tenth of
    /// the sampling rate, leaving phase margin for the 1.5-period delay); speed loop at
    /// 20 rad/s: below the estimator's speed bandwidth (its group delay is `1/(zeta w)`,
    /// 20 ms at 8 Hz) yet fast enough to ride through a 40 N load step on the simulated
    /// 10.7 kg axis (10 rad/s stalled it); twice rated peak current, or less where the
    /// bus cannot drive that through the winding ([`DriveConfig::bus_current_limit_a`]:
    /// a high-resistance motor on a low bus, such as an ironless one on 48 V, whose
    /// current loops would otherwise saturate at standstill and trip `CURRENT_CONTROL`);
    /// start-up at rated peak current (at most the limit) to 0.25 m/s (8.3 Hz on the
    /// paper motor, where the DCFO + PLL converge in well under a second), lowered to
    /// 30 % during a 1 s dwell;
    /// a 50 ms catch probe on enable (the FLL's acquisition sweep from its start
    /// frequency down to the notch floor takes about `1 / (4 w_floor)` = 20 ms);
    /// acceleration limited to 0.5 m/s^2; protection at 3x rated current and
    /// 60-130 % of the nominal bus; current control lost when the voltage sits on its
    /// limit with the current 10 % of rated peak off its reference for 5 ms (an open
    /// phase or a stuck sensor: `dcfo faults`).
    pub fn for_motor(motor: &MotorParams, bus_v: f32, observer: ObserverKind) -> Self {
        let rated_peak = motor.rated_current_a * core::f32::consts::SQRT_2;
        let mut config = DriveConfig {
            control_period_s: 1e-4,
            speed_loop_divider: 10,
            current_bandwidth_rad_s: 1500.0,
            speed_bandwidth_rad_s: 20.0,
            moving_mass_kg: motor.mass_kg,
            speed_filter_s: 1e-3,
            current_limit_a: 2.0 * rated_peak,
            accel_limit_m_per_s2: 0.5,
            modulation_limit: 0.95,
            speed_zero_ratio: 0.25,
            handover_speed_tolerance: 0.2,
            delay_compensation_periods: 1.5,
            startup: StartupConfig {
                current_a: rated_peak,
                handover_current_a: 0.3 * rated_peak,
                accel_m_per_s2: 0.5,
                handover_speed_m_per_s: 0.25,
                dwell_s: 1.0,
                id_ramp_s: 0.05,
                catch_probe_s: Some(0.05),
                timeout_dwells: 10,
                min_timeout_s: 1.0,
            },
            dead_time_compensation: None,
            compensation_signs: CompensationSigns::ReferenceAboveNoise,
            faults: FaultConfig {
                overcurrent_a: 3.0 * rated_peak,
                bus_min_v: 0.6 * bus_v,
                bus_max_v: 1.3 * bus_v,
                lock_loss_s: 0.05,
                overload_s: 0.1,
                reacquire_timeout_s: 0.5,
                calibration_samples: 1024,
                max_offset_a: 0.1 * rated_peak,
                current_error_a: 0.1 * rated_peak,
                current_error_s: 0.005,
                phase_loss_filter_s: 0.01,
            },
            estimator: EstimatorConfig::for_motor(motor, observer),
            motion: None,
        };
        // Where the bus bounds the limit below rated peak, the start-up current (and its
        // hand-over share) scales down with it (a factor of exactly 1 otherwise).
        let limit_a = config.current_limit_a.min(config.bus_current_limit_a(motor));
        let start_scale = limit_a.min(rated_peak) / rated_peak;
        config.current_limit_a = limit_a;
        config.startup.current_a *= start_scale;
        config.startup.handover_current_a *= start_scale;
        config
    }
}

impl DriveConfig {
    /// The paper motor on the simulated test axis of `dcfo paper`, as both the host
    /// simulation and the HIL firmware run it: rectified 220 V mains (311.1 V bus), the
    /// 0.66 kg mover plus a 10 kg carriage and load, and compensation of a 2 us dead time
    /// and 0.95 V mean device drop from the measured current (band 0.01 A, about one
    /// current-sensor noise sigma). The host checks these against its plant model.
    pub fn paper_axis(observer: ObserverKind) -> Self {
        let motor = MotorParams::paper();
        let mut config = DriveConfig::for_motor(&motor, PAPER_AXIS_BUS_V, observer);
        config.moving_mass_kg = motor.mass_kg + PAPER_AXIS_PAYLOAD_KG;
        config.dead_time_compensation =
            Some(DeadTimeCompensation { dead_time_s: 2e-6, device_drop_v: 0.95, current_band_a: 0.01 });
        config
    }
}

/// The stroke `dcfo stroke` runs, m: moves between 0 and this position.
pub const STROKE_AXIS_STROKE_M: f32 = 0.3;

/// The profile limits of the stroke axis ([`DriveConfig::stroke_axis`]): 0.5 m/s,
/// 3 m/s^2, and the profile's stroke 1 cm beyond either end of
/// [`STROKE_AXIS_STROKE_M`].
pub const STROKE_AXIS_LIMITS: ProfileLimits = ProfileLimits {
    max_speed_m_per_s: 0.5,
    max_accel_m_per_s2: 3.0,
    stroke_min_m: -0.01,
    stroke_max_m: STROKE_AXIS_STROKE_M + 0.01,
};

impl DriveConfig {
    /// The positioning drive of `dcfo stroke` for `motor` on a bus of nominal `bus_v`
    /// volts, tuned from the motor alone: [`DriveConfig::for_motor`] (DCFO) moving the
    /// motor's mass plus the [`PAPER_AXIS_PAYLOAD_KG`] carriage, the paper axis's
    /// inverter compensation (2 us dead time, 0.95 V mean device drop, 0.01 A band), and
    /// [`MotionConfig::for_drive`] with [`STROKE_AXIS_LIMITS`]. The host's in-process
    /// stroke and the HIL firmware build it with this one function, so both run the same
    /// drive.
    pub fn stroke_axis(motor: &MotorParams, bus_v: f32) -> Self {
        let mut d = DriveConfig::for_motor(motor, bus_v, ObserverKind::Dcfo);
        d.moving_mass_kg = motor.mass_kg + PAPER_AXIS_PAYLOAD_KG;
        d.dead_time_compensation =
            Some(DeadTimeCompensation { dead_time_s: 2e-6, device_drop_v: 0.95, current_band_a: 0.01 });
        d.motion = Some(MotionConfig::for_drive(motor, &d, STROKE_AXIS_LIMITS));
        d
    }
}

impl DriveConfig {
    /// Whether the motor can follow a profile with `limits` in this drive: the
    /// acceleration of the moving mass ([`DriveConfig::moving_mass_kg`]) must need less
    /// thrust current than [`DriveConfig::current_limit_a`], and the back-EMF at the top
    /// speed must stay below the phase voltage the bridge applies at the lowest bus of
    /// the fault limits (`faults.bus_min_v`, linear modulation scaled by
    /// `modulation_limit`). The limits themselves are [`ProfileLimits::validate`]'s.
    /// [`super::Drive::new`] refuses a positioning drive on this check, and a motor
    /// image's axis ([`crate::motor_image::MotorImage::with_axis`]) is refused on it.
    ///
    /// # Errors
    /// The limit the motor cannot follow: [`ProfileField::MaxAccel`] or
    /// [`ProfileField::MaxSpeed`] (or the first field [`ProfileLimits::validate`] names).
    pub fn check_profile(&self, motor: &MotorParams, limits: &ProfileLimits) -> Result<(), ProfileField> {
        limits.validate()?;
        let accel_current = self.moving_mass_kg * limits.max_accel_m_per_s2 / motor.thrust_constant_n_per_a();
        // Anything but "less" refuses, a NaN too.
        let below = |x: f32, limit: f32| x.partial_cmp(&limit) == Some(core::cmp::Ordering::Less);
        if !below(accel_current, self.current_limit_a) {
            return Err(ProfileField::MaxAccel);
        }
        if !below(limits.max_speed_m_per_s, self.bus_speed_limit_m_per_s(motor)) {
            return Err(ProfileField::MaxSpeed);
        }
        Ok(())
    }

    /// The speed at which `motor`'s back-EMF takes the whole phase voltage the lowest
    /// allowed bus drives in the linear range (`bus_min_v * modulation_limit / sqrt 3`),
    /// m/s: no profile may reach it.
    pub fn bus_speed_limit_m_per_s(&self, motor: &MotorParams) -> f32 {
        self.max_phase_voltage_v() / (motor.rad_per_m() * motor.psi_f_wb)
    }

    /// The current the lowest allowed bus drives through `motor`'s winding at standstill
    /// in the linear range (`bus_min_v * modulation_limit / sqrt 3 / Rs`), A: a larger
    /// current limit is one the current loops cannot reach, their voltage on its limit
    /// before the mover moves ([`DriveConfig::for_motor`] stays below it).
    pub fn bus_current_limit_a(&self, motor: &MotorParams) -> f32 {
        self.max_phase_voltage_v() / motor.rs_ohm
    }

    /// The phase voltage amplitude the lowest allowed bus drives in the linear range
    /// (`bus_min_v * modulation_limit / sqrt 3`), V.
    fn max_phase_voltage_v(&self) -> f32 {
        self.faults.bus_min_v * self.modulation_limit * <f32 as crate::num::Scalar>::INV_SQRT3
    }

    /// The drive a board runs for a motor image, the one function every drive image
    /// builds its drive with (`dcfo-firmware`'s images and the host's checks):
    /// [`DriveConfig::for_motor`] (DCFO) of the image's motor at its bus voltage, with the
    /// board's control period `control_period_s` (s) and the inverter compensation
    /// `compensation` the board uses (the image's, a board default, or `None` for an
    /// ideal virtual inverter: the board decides). With an axis in the image
    /// ([`MotorImage::axis`]) it is a positioning drive: the moving mass is the motor's
    /// plus the axis's payload, and [`MotionConfig::for_drive`] with the axis's limits
    /// (checked by [`DriveConfig::check_profile`]); without one, a speed drive moving the
    /// motor's own mass. The result is validated ([`DriveConfig::validate`]).
    ///
    /// # Errors
    /// The setting that is out of range, named (`motion.limits.max_accel_m_per_s2` for
    /// an axis the motor cannot accelerate, ...).
    pub fn for_image(
        image: &MotorImage,
        control_period_s: f32,
        compensation: Option<DeadTimeCompensation>,
    ) -> Result<Self, DriveConfigError> {
        let motor = &image.motor;
        let mut d = DriveConfig::for_motor(motor, image.bus_v, ObserverKind::Dcfo);
        d.control_period_s = control_period_s;
        d.dead_time_compensation = compensation;
        if let Some(axis) = image.axis {
            d.moving_mass_kg = motor.mass_kg + axis.payload_kg;
            d.check_profile(motor, &axis.limits).map_err(|f| DriveConfigError { field: f.config_path() })?;
            d.motion = Some(MotionConfig::for_drive(motor, &d, axis.limits));
        }
        d.validate()?;
        Ok(d)
    }

    /// Whether the motor of `image` can follow its axis (`Ok` without one): the check
    /// [`DriveConfig::for_image`] makes, for a tool that writes an image without knowing
    /// the board's period ([`DriveConfig::check_profile`] on the drive `for_image` builds,
    /// moving the payload too: the acceleration within the current limit, the top speed's
    /// back-EMF within the lowest bus). `Err` names the axis's field.
    pub fn check_image_axis(image: &MotorImage) -> Result<(), ProfileField> {
        let Some(axis) = image.axis else {
            return Ok(());
        };
        let mut d = DriveConfig::for_motor(&image.motor, image.bus_v, ObserverKind::Dcfo);
        d.moving_mass_kg = image.motor.mass_kg + axis.payload_kg;
        d.check_profile(&image.motor, &axis.limits)
    }
}

/// DC bus of the simulated paper axis, V: `sqrt(2) * 220`.
pub const PAPER_AXIS_BUS_V: f32 = 311.127;

/// Carriage and load the simulated paper axis moves besides the mover, kg.
///
/// The paper states only the mover's 0.66 kg. Alone, it would accelerate at 60 m/s^2
/// under the 40 N load step, so any back-EMF estimator (whose angle lags transients by
/// 15-30 ms at 8-15 Hz) would see speed dips of several tenths of a m/s, not the
/// 0.034-0.039 m/s the paper reports: its test axis moved far more mass. 10 kg is a
/// typical carriage plus load for a 150 N-class linear motor; it was not fitted to any
/// figure.
pub const PAPER_AXIS_PAYLOAD_KG: f32 = 10.0;

/// Why a drive could not be built; names the setting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DriveConfigError {
    /// The setting's field name (e.g. `"control_period_s"`).
    pub field: &'static str,
}

impl core::fmt::Display for DriveConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "drive setting `{}` is out of range", self.field)
    }
}

/// `Ok` if `ok`, else the error naming `field`. [`DriveConfig::validate`] runs its checks
/// one after the other through it, returning at the first that fails: the same answer as
/// evaluating them all into a table and naming the first false one, without the table
/// built in place (a name stored per check: 96 B of flash on the ESC1 image).
fn require(ok: bool, field: &'static str) -> Result<(), DriveConfigError> {
    if ok { Ok(()) } else { Err(DriveConfigError { field }) }
}

impl DriveConfig {
    /// Checks every setting; the first bad one is named.
    pub fn validate(&self) -> Result<(), DriveConfigError> {
        let (pos, non_neg) = (positive, non_negative);
        require(pos(self.control_period_s), "control_period_s")?;
        require(self.speed_loop_divider >= 1, "speed_loop_divider")?;
        require(pos(self.current_bandwidth_rad_s), "current_bandwidth_rad_s")?;
        require(pos(self.speed_bandwidth_rad_s), "speed_bandwidth_rad_s")?;
        require(pos(self.speed_filter_s), "speed_filter_s")?;
        require(pos(self.moving_mass_kg), "moving_mass_kg")?;
        require(pos(self.current_limit_a), "current_limit_a")?;
        require(pos(self.accel_limit_m_per_s2), "accel_limit_m_per_s2")?;
        require(pos(self.modulation_limit) && self.modulation_limit <= 1.0, "modulation_limit")?;
        require(pos(self.speed_zero_ratio) && self.speed_zero_ratio <= 1.0, "speed_zero_ratio")?;
        require(
            pos(self.handover_speed_tolerance) && self.handover_speed_tolerance < 1.0,
            "handover_speed_tolerance",
        )?;
        require(
            non_neg(self.delay_compensation_periods) && self.delay_compensation_periods <= 4.0,
            "delay_compensation_periods",
        )?;
        require(pos(self.startup.current_a), "startup.current_a")?;
        require(
            pos(self.startup.handover_current_a) && self.startup.handover_current_a <= self.startup.current_a,
            "startup.handover_current_a",
        )?;
        require(pos(self.startup.accel_m_per_s2), "startup.accel_m_per_s2")?;
        require(pos(self.startup.handover_speed_m_per_s), "startup.handover_speed_m_per_s")?;
        require(non_neg(self.startup.dwell_s), "startup.dwell_s")?;
        require(pos(self.startup.id_ramp_s), "startup.id_ramp_s")?;
        require(self.startup.catch_probe_s.is_none_or(pos), "startup.catch_probe_s")?;
        require(self.startup.timeout_dwells >= 1, "startup.timeout_dwells")?;
        require(pos(self.startup.min_timeout_s), "startup.min_timeout_s")?;
        require(pos(self.faults.overcurrent_a), "faults.overcurrent_a")?;
        require(
            pos(self.faults.bus_min_v) && self.faults.bus_max_v > self.faults.bus_min_v,
            "faults.bus_max_v",
        )?;
        require(pos(self.faults.lock_loss_s), "faults.lock_loss_s")?;
        require(pos(self.faults.overload_s), "faults.overload_s")?;
        require(pos(self.faults.reacquire_timeout_s), "faults.reacquire_timeout_s")?;
        require(self.faults.calibration_samples > 0, "faults.calibration_samples")?;
        require(pos(self.faults.max_offset_a), "faults.max_offset_a")?;
        require(pos(self.faults.current_error_a), "faults.current_error_a")?;
        require(pos(self.faults.current_error_s), "faults.current_error_s")?;
        require(pos(self.faults.phase_loss_filter_s), "faults.phase_loss_filter_s")?;
        if let Some(m) = self.motion {
            m.limits.validate().map_err(|f| DriveConfigError { field: f.config_path() })?;
            let checks = [
                (pos(m.low_speed_m_per_s), "motion.low_speed_m_per_s"),
                (
                    m.low_speed_exit_ratio.is_finite() && m.low_speed_exit_ratio > 1.0,
                    "motion.low_speed_exit_ratio",
                ),
                (
                    pos(m.low_speed_current_a) && m.low_speed_current_a <= self.current_limit_a,
                    "motion.low_speed_current_a",
                ),
                (pos(m.exit_current_a) && m.exit_current_a <= m.low_speed_current_a, "motion.exit_current_a"),
                (pos(m.current_slew_a_per_s), "motion.current_slew_a_per_s"),
                (pos(m.position_bandwidth_rad_s), "motion.position_bandwidth_rad_s"),
                (
                    m.hfi.is_none_or(|h| h.validate().is_ok() && h.pwm_period_s == self.control_period_s),
                    "motion.hfi",
                ),
            ];
            for (ok, field) in checks {
                if !ok {
                    return Err(DriveConfigError { field });
                }
            }
        }
        if let Some(c) = self.dead_time_compensation {
            if !(non_neg(c.dead_time_s) && c.dead_time_s < self.control_period_s) {
                return Err(DriveConfigError { field: "dead_time_compensation.dead_time_s" });
            }
            if !non_neg(c.device_drop_v) {
                return Err(DriveConfigError { field: "dead_time_compensation.device_drop_v" });
            }
            if !pos(c.current_band_a) {
                return Err(DriveConfigError { field: "dead_time_compensation.current_band_a" });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_current_limit_is_what_the_lowest_bus_drives_through_the_winding() {
        // Paper motor on 311 V: the bus drives 20 A through 5 ohm; twice rated peak holds.
        let paper = MotorParams::paper();
        let c = DriveConfig::for_motor(&paper, PAPER_AXIS_BUS_V, ObserverKind::Dcfo);
        let rated_peak = paper.rated_current_a * core::f32::consts::SQRT_2;
        assert_eq!(c.current_limit_a, 2.0 * rated_peak);
        assert_eq!((c.startup.current_a, c.startup.handover_current_a), (rated_peak, 0.3 * rated_peak));
        // A high-resistance motor on 48 V (an ironless one's 4 ohm and 4 A rms; twice its
        // rated peak, 11.3 A, would take 45 V at standstill): the lowest allowed bus (60 %,
        // 28.8 V) drives 28.8 * 0.95 / sqrt 3 = 15.8 V of phase amplitude, 3.95 A
        // through 4 ohm.
        let motor = MotorParams { rs_ohm: 4.0, rated_current_a: 4.0, rated_voltage_v: 48.0, ..paper };
        let c = DriveConfig::for_motor(&motor, 48.0, ObserverKind::Dcfo);
        let expected_a = 0.6 * 48.0 * 0.95 / 3f32.sqrt() / motor.rs_ohm;
        assert!((c.current_limit_a - expected_a).abs() < 1e-5, "{}", c.current_limit_a);
        assert!((c.current_limit_a - 3.95).abs() < 0.005, "{}", c.current_limit_a);
        // The start-up stays within the limit, its hand-over share with it.
        assert_eq!(c.startup.current_a, c.current_limit_a);
        assert!((c.startup.handover_current_a - 0.3 * c.current_limit_a).abs() < 1e-6);
        assert_eq!(c.validate(), Ok(()));
    }

    #[test]
    fn tuning_fields_default_to_the_former_constants_and_are_validated() {
        let c = DriveConfig::paper_axis(ObserverKind::Dcfo);
        assert_eq!(c.speed_zero_ratio, 0.25);
        assert_eq!(c.handover_speed_tolerance, 0.2);
        assert_eq!(c.delay_compensation_periods, 1.5);
        assert_eq!((c.startup.timeout_dwells, c.startup.min_timeout_s), (10, 1.0));
        assert_eq!(c.validate(), Ok(()));
        type Spoil = fn(&mut DriveConfig);
        let bad: [(Spoil, &str); 8] = [
            (|c| c.speed_zero_ratio = 0.0, "speed_zero_ratio"),
            (|c| c.speed_zero_ratio = 1.5, "speed_zero_ratio"),
            (|c| c.handover_speed_tolerance = 1.0, "handover_speed_tolerance"),
            (|c| c.handover_speed_tolerance = f32::NAN, "handover_speed_tolerance"),
            (|c| c.delay_compensation_periods = -0.5, "delay_compensation_periods"),
            (|c| c.delay_compensation_periods = f32::INFINITY, "delay_compensation_periods"),
            (|c| c.startup.timeout_dwells = 0, "startup.timeout_dwells"),
            (|c| c.startup.min_timeout_s = 0.0, "startup.min_timeout_s"),
        ];
        for (spoil, field) in bad {
            let mut c = DriveConfig::paper_axis(ObserverKind::Dcfo);
            spoil(&mut c);
            assert_eq!(c.validate(), Err(DriveConfigError { field }));
        }
    }

    /// `for_image` builds the drive `stroke_axis` builds when the image holds the stroke
    /// axis (same motor, bus, compensation, limits and payload), and the speed drive of
    /// `for_motor` without an axis.
    #[test]
    fn a_motor_image_with_an_axis_gives_the_positioning_drive() {
        use crate::motor_image::{MotorAxis, MotorImage};
        let motor = MotorParams::paper();
        let comp = DeadTimeCompensation { dead_time_s: 2e-6, device_drop_v: 0.95, current_band_a: 0.01 };
        let image = MotorImage::new(motor, PAPER_AXIS_BUS_V).unwrap();
        let axis = MotorAxis { limits: STROKE_AXIS_LIMITS, payload_kg: PAPER_AXIS_PAYLOAD_KG };
        let positioning = DriveConfig::for_image(&image.with_axis(axis).unwrap(), 1e-4, Some(comp)).unwrap();
        assert_eq!(positioning, DriveConfig::stroke_axis(&motor, PAPER_AXIS_BUS_V));
        let speed = DriveConfig::for_image(&image, 1e-4, Some(comp)).unwrap();
        let mut expected = DriveConfig::for_motor(&motor, PAPER_AXIS_BUS_V, ObserverKind::Dcfo);
        expected.dead_time_compensation = Some(comp);
        assert_eq!(speed, expected);
        assert_eq!(speed.motion, None);
        // The control period enters the motion settings (HFI's PWM period, the
        // low-speed threshold through the compensation's dead time).
        let at_20k = DriveConfig::for_image(&image.with_axis(axis).unwrap(), 5e-5, Some(comp)).unwrap();
        assert_eq!(at_20k.control_period_s, 5e-5);
        assert!(at_20k.motion.is_some());
        // An axis the motor cannot follow is refused by name: 300 m/s^2 of 10.66 kg needs
        // 3.2 kN, far above the current limit's thrust; 10 m/s is 2 kV of back-EMF on a
        // 311 V bus; 200 kg of payload need more than the current limit at 3 m/s^2.
        for (spoil, field) in [
            (
                MotorAxis {
                    limits: ProfileLimits { max_accel_m_per_s2: 300.0, ..STROKE_AXIS_LIMITS },
                    ..axis
                },
                ProfileField::MaxAccel,
            ),
            (
                MotorAxis { limits: ProfileLimits { max_speed_m_per_s: 10.0, ..STROKE_AXIS_LIMITS }, ..axis },
                ProfileField::MaxSpeed,
            ),
            (MotorAxis { payload_kg: 200.0, ..axis }, ProfileField::MaxAccel),
        ] {
            let image = image.with_axis(spoil).unwrap();
            assert_eq!(DriveConfig::check_image_axis(&image), Err(field), "{spoil:?}");
            assert_eq!(
                DriveConfig::for_image(&image, 1e-4, None),
                Err(DriveConfigError { field: field.config_path() })
            );
        }
        assert_eq!(
            DriveConfig::check_image_axis(&image.with_axis(MotorAxis { payload_kg: 0.0, ..axis }).unwrap()),
            Ok(())
        );
        assert_eq!(DriveConfig::check_image_axis(&image), Ok(()));
        let too_fast =
            MotorAxis { limits: ProfileLimits { max_accel_m_per_s2: 300.0, ..STROKE_AXIS_LIMITS }, ..axis };
        let bad = MotorImage { axis: Some(too_fast), ..image };
        assert_eq!(
            DriveConfig::for_image(&bad, 1e-4, None),
            Err(DriveConfigError { field: "motion.limits.max_accel_m_per_s2" })
        );
    }
}
