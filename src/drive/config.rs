//! Drive settings (SI) and the controller gains derived from them.

use crate::estimator::EstimatorConfig;
use crate::motor::MotorParams;
use crate::observer::ObserverKind;

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
    /// and PLL converge; digest §8: 0.5-1 s from cold at 8-10 Hz).
    pub dwell_s: f32,
    /// After hand-over, time over which the d-axis current of the start-up vector is
    /// ramped to zero, s (> 0).
    pub id_ramp_s: f32,
}

/// Compensation of the inverter's dead time and device drops, added to the voltage
/// command per phase as `(dead_time / Ts * Vdc + device_drop) * sign(i)`, with the
/// sign taken smoothly from the current reference (digest §8).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeadTimeCompensation {
    /// Effective dead time, s (>= 0).
    pub dead_time_s: f32,
    /// Average device voltage drop, V (>= 0).
    pub device_drop_v: f32,
    /// Current over which the sign changes linearly from -1 to 1, A (> 0).
    pub current_band_a: f32,
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
    /// Speed-loop crossover, rad/s: `kp = w_s M / K_f`, PI zero at `w_s / 4`. Keep it
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
    /// Open-loop start-up.
    pub startup: StartupConfig,
    /// Inverter compensation; `None` feeds the command uncompensated.
    pub dead_time_compensation: Option<DeadTimeCompensation>,
    /// Protection.
    pub faults: FaultConfig,
    /// Observer and PLL.
    pub estimator: EstimatorConfig,
}

impl DriveConfig {
    /// Defaults for `motor` on a bus of nominal `bus_v` volts with the given observer,
    /// at 10 kHz, moving the motor's own mass. Current loop at 1500 rad/s (a tenth of
    /// the sampling rate, leaving phase margin for the 1.5-period delay); speed loop at
    /// 20 rad/s: below the estimator's speed bandwidth (its group delay is `1/(zeta w)`,
    /// 20 ms at 8 Hz) yet fast enough to ride through a 40 N load step on the simulated
    /// 10.7 kg axis (10 rad/s stalled it); twice rated current;
    /// start-up at rated current to 0.25 m/s (8.3 Hz on the paper motor, where the
    /// DCFO + PLL converge in well under a second), lowered to 30 % during a 1 s dwell;
    /// acceleration limited to 0.5 m/s^2; protection at 3x rated current and
    /// 60-130 % of the nominal bus.
    pub fn for_motor(motor: &MotorParams, bus_v: f32, observer: ObserverKind) -> Self {
        let rated_peak = motor.rated_current_a * core::f32::consts::SQRT_2;
        DriveConfig {
            control_period_s: 1e-4,
            speed_loop_divider: 10,
            current_bandwidth_rad_s: 1500.0,
            speed_bandwidth_rad_s: 20.0,
            moving_mass_kg: motor.mass_kg,
            speed_filter_s: 1e-3,
            current_limit_a: 2.0 * rated_peak,
            accel_limit_m_per_s2: 0.5,
            modulation_limit: 0.95,
            startup: StartupConfig {
                current_a: rated_peak,
                handover_current_a: 0.3 * rated_peak,
                accel_m_per_s2: 0.5,
                handover_speed_m_per_s: 0.25,
                dwell_s: 1.0,
                id_ramp_s: 0.05,
            },
            dead_time_compensation: None,
            faults: FaultConfig {
                overcurrent_a: 3.0 * rated_peak,
                bus_min_v: 0.6 * bus_v,
                bus_max_v: 1.3 * bus_v,
                lock_loss_s: 0.05,
                reacquire_timeout_s: 0.5,
                calibration_samples: 1024,
                max_offset_a: 0.1 * rated_peak,
            },
            estimator: EstimatorConfig::for_motor(motor, observer),
        }
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

impl DriveConfig {
    /// Checks every setting; the first bad one is named.
    pub fn validate(&self) -> Result<(), DriveConfigError> {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        let non_neg = |x: f32| x.is_finite() && x >= 0.0;
        let checks: [(bool, &'static str); 21] = [
            (pos(self.control_period_s), "control_period_s"),
            (self.speed_loop_divider >= 1, "speed_loop_divider"),
            (pos(self.current_bandwidth_rad_s), "current_bandwidth_rad_s"),
            (pos(self.speed_bandwidth_rad_s), "speed_bandwidth_rad_s"),
            (pos(self.speed_filter_s), "speed_filter_s"),
            (pos(self.moving_mass_kg), "moving_mass_kg"),
            (pos(self.current_limit_a), "current_limit_a"),
            (pos(self.accel_limit_m_per_s2), "accel_limit_m_per_s2"),
            (pos(self.modulation_limit) && self.modulation_limit <= 1.0, "modulation_limit"),
            (pos(self.startup.current_a), "startup.current_a"),
            (
                pos(self.startup.handover_current_a)
                    && self.startup.handover_current_a <= self.startup.current_a,
                "startup.handover_current_a",
            ),
            (pos(self.startup.accel_m_per_s2), "startup.accel_m_per_s2"),
            (pos(self.startup.handover_speed_m_per_s), "startup.handover_speed_m_per_s"),
            (non_neg(self.startup.dwell_s), "startup.dwell_s"),
            (pos(self.startup.id_ramp_s), "startup.id_ramp_s"),
            (pos(self.faults.overcurrent_a), "faults.overcurrent_a"),
            (pos(self.faults.bus_min_v) && self.faults.bus_max_v > self.faults.bus_min_v, "faults.bus_max_v"),
            (pos(self.faults.lock_loss_s), "faults.lock_loss_s"),
            (pos(self.faults.reacquire_timeout_s), "faults.reacquire_timeout_s"),
            (self.faults.calibration_samples > 0, "faults.calibration_samples"),
            (pos(self.faults.max_offset_a), "faults.max_offset_a"),
        ];
        for (ok, field) in checks {
            if !ok {
                return Err(DriveConfigError { field });
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
