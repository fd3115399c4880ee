//! Parameter sets of the plant: motor and mechanics ([`PlantParams`]), two-level
//! inverter ([`InverterParams`]), sensors ([`SensorParams`]), and the bundle
//! [`SimParams`]. All values are `f64` SI; units are in the field names.
//!
//! Every realistic default says where its number comes from. None of them is
//! tuned to make an observer look good: they are order-of-magnitude values of
//! a small 600 V IGBT drive with Hall current sensors and a 12-bit ADC.

use dcfo::motor::MotorParams;

/// Why a plant parameter or a plant input was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlantError {
    /// A parameter is out of its physical or numerical range.
    #[error("plant parameter `{field}` {reason}")]
    InvalidParam {
        /// The field's name, as spelled in the parameter struct.
        field: &'static str,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A value handed to a setter (position, speed, current) is NaN or infinite.
    #[error("plant input `{what}` must be a finite number")]
    NotFinite {
        /// Which input.
        what: &'static str,
    },
}

fn check(ok: bool, field: &'static str, reason: &'static str) -> Result<(), PlantError> {
    if ok { Ok(()) } else { Err(PlantError::InvalidParam { field, reason }) }
}

fn positive(field: &'static str, x: f64) -> Result<(), PlantError> {
    check(x.is_finite(), field, "must be a finite number")?;
    check(x > 0.0, field, "must be greater than zero")
}

fn non_negative(field: &'static str, x: f64) -> Result<(), PlantError> {
    check(x.is_finite(), field, "must be a finite number")?;
    check(x >= 0.0, field, "must not be negative")
}

fn finite(field: &'static str, x: f64) -> Result<(), PlantError> {
    check(x.is_finite(), field, "must be a finite number")
}

/// Electrical radians per metre of `motor`'s travel, `pi / pole_pitch_m` (rad/m), in
/// `f64`: the plant's and the tools' figure (the drive's is
/// [`MotorParams::rad_per_m`], in `f32`).
pub fn rad_per_m(motor: &MotorParams) -> f64 {
    core::f64::consts::PI / f64::from(motor.pole_pitch_m)
}

/// Rated thrust, newton, of a motor at its rated RMS current with `i_d = 0`:
/// `1.5 (pi / tau) psi_f sqrt(2) I_rated`. About 149 N for the paper motor.
pub fn rated_thrust_n(motor: &MotorParams) -> f64 {
    1.5 * core::f64::consts::PI / f64::from(motor.pole_pitch_m)
        * f64::from(motor.psi_f_wb)
        * core::f64::consts::SQRT_2
        * f64::from(motor.rated_current_a)
}

/// Smallest value of the 1-2-5 series that is `>= x` (x > 0). Used to pick
/// sensor full-scale ranges the way a board designer would.
fn ceil_125(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return 1.0;
    }
    let decade = 10f64.powf(x.log10().floor());
    for m in [1.0, 2.0, 5.0, 10.0] {
        if m * decade >= x * (1.0 - 1e-12) {
            return m * decade;
        }
    }
    10.0 * decade
}

/// PMSLM and mechanical load: the dq model of docs/method.md §1 plus Coulomb/static
/// friction and end-effect thrust ripple.
///
/// Mechanics: `M dv/dt = F_e - B v - F_c sign(v) - F_load - F_em cos(2 pi x / tau)`,
/// with the mover held (stiction) while `|v| = 0` and the net driving force is
/// at most `static_friction_n`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlantParams {
    /// Stator resistance per phase, ohm.
    pub rs_ohm: f64,
    /// d-axis inductance, henry.
    pub ld_h: f64,
    /// q-axis inductance, henry.
    pub lq_h: f64,
    /// Permanent-magnet flux linkage, weber (amplitude-invariant).
    pub psi_f_wb: f64,
    /// Pole pitch tau, metre; `theta_e = pi x / tau + theta_offset_rad`.
    pub pole_pitch_m: f64,
    /// Mover mass M, kilogram.
    pub mass_kg: f64,
    /// Viscous friction coefficient B, newton-second per metre.
    pub viscous_n_s_per_m: f64,
    /// Kinetic (Coulomb) friction force F_c, newton, opposing motion.
    pub coulomb_friction_n: f64,
    /// Break-away (static) friction, newton (>= `coulomb_friction_n`): at zero
    /// speed the mover stays put while the net driving force is at most this.
    pub static_friction_n: f64,
    /// End-effect thrust ripple amplitude F_em, newton; the ripple force
    /// `-F_em cos(2 pi x / tau)` acts on the mover (period tau in position).
    pub end_effect_ripple_n: f64,
    /// Electrical angle at x = 0, radian.
    pub theta_offset_rad: f64,
    /// d-axis saturation `c`, 1/A (>= 0, at most 10): the incremental d inductance is
    /// `L_d (1 - 0.5 tanh(2 c i_d))`, so it falls with a current that magnetises along
    /// the magnet (`i_d > 0`) and rises with one against it, by `c L_d` per ampere at
    /// `i_d = 0` and within `[0.5, 1.5] L_d` at any current; the d flux is its integral,
    /// `psi_f + L_d (i_d - (1 / 4c) ln cosh(2 c i_d))`. What magnet-polarity detection
    /// reads. 0 (the default) is the linear model, computed exactly as without this
    /// field. [`PlantParams::d_saturation_for`] derives `c` from a drop at a current.
    /// With saturation, the energy ledger's magnetic energy is the linear model's.
    pub ld_saturation_per_a: f64,
}

impl PlantParams {
    /// The motor's electrical and mass/viscous parameters with realistic
    /// friction and end-effect defaults:
    ///
    /// - Coulomb friction = 3 % of the rated thrust ([`rated_thrust_n`]; 4.5 N for
    ///   the paper motor). An iron-core PMSLM pulls its mover onto the guides with
    ///   a magnetic normal force of several times its rated thrust; preloaded
    ///   ball-rail guides (friction coefficient of a few thousandths) plus wipers
    ///   and cable chain give friction of a few per cent of rated thrust.
    /// - Static friction = 1.3 x Coulomb: break-away of lubricated rolling guides
    ///   is typically 1.2-1.5 times the running friction.
    /// - End-effect ripple F_em = 3 % of rated thrust (4.5 N): iron-core PMSLMs
    ///   with the usual countermeasures (skew, end-tooth shaping) are quoted with
    ///   a few per cent of ripple; without them 5-10 % and more.
    ///
    /// These are engineering estimates, not measurements of the paper's rig.
    pub fn from_motor(motor: &MotorParams) -> Self {
        let f_rated = rated_thrust_n(motor);
        let coulomb = 0.03 * f_rated;
        PlantParams {
            coulomb_friction_n: coulomb,
            static_friction_n: 1.3 * coulomb,
            end_effect_ripple_n: 0.03 * f_rated,
            ..Self::ideal_from_motor(motor)
        }
    }

    /// The motor's parameters with only viscous friction: no Coulomb or static
    /// friction and no end-effect ripple (for "ideal" runs and tests).
    pub fn ideal_from_motor(motor: &MotorParams) -> Self {
        PlantParams {
            rs_ohm: f64::from(motor.rs_ohm),
            ld_h: f64::from(motor.ld_h),
            lq_h: f64::from(motor.lq_h),
            psi_f_wb: f64::from(motor.psi_f_wb),
            pole_pitch_m: f64::from(motor.pole_pitch_m),
            mass_kg: f64::from(motor.mass_kg),
            viscous_n_s_per_m: f64::from(motor.viscous_n_s_per_m),
            coulomb_friction_n: 0.0,
            static_friction_n: 0.0,
            end_effect_ripple_n: 0.0,
            theta_offset_rad: 0.0,
            ld_saturation_per_a: 0.0,
        }
    }

    /// The saturation `c` (1/A) for which the incremental d inductance is `1 - drop`
    /// times `L_d` at `i_d = current_a` (A, > 0; `drop` in (0, 0.5)):
    /// `c = atanh(2 drop) / (2 current_a)`. 10 % at the rated peak current of
    /// `motors/salient.toml` gives 0.0239 /A.
    pub fn d_saturation_for(drop: f64, current_a: f64) -> f64 {
        (2.0 * drop).atanh() / (2.0 * current_a)
    }

    /// Checks every field; the first refused field by name.
    pub fn validate(&self) -> Result<(), PlantError> {
        positive("rs_ohm", self.rs_ohm)?;
        positive("ld_h", self.ld_h)?;
        positive("lq_h", self.lq_h)?;
        non_negative("psi_f_wb", self.psi_f_wb)?;
        positive("pole_pitch_m", self.pole_pitch_m)?;
        positive("mass_kg", self.mass_kg)?;
        non_negative("viscous_n_s_per_m", self.viscous_n_s_per_m)?;
        non_negative("coulomb_friction_n", self.coulomb_friction_n)?;
        non_negative("static_friction_n", self.static_friction_n)?;
        check(
            self.static_friction_n >= self.coulomb_friction_n,
            "static_friction_n",
            "must be at least coulomb_friction_n",
        )?;
        non_negative("end_effect_ripple_n", self.end_effect_ripple_n)?;
        finite("theta_offset_rad", self.theta_offset_rad)?;
        non_negative("ld_saturation_per_a", self.ld_saturation_per_a)?;
        check(self.ld_saturation_per_a <= 10.0, "ld_saturation_per_a", "must be at most 10 per ampere")
    }
}

/// Three-phase two-level voltage-source inverter with centre-aligned PWM.
///
/// Each leg's upper switch is commanded on for `d * Ts`, centred on the carrier
/// peak (mid-period); at the carrier valley (period start, the sampling instant)
/// every leg with `d < 1` has its lower switch commanded on. Every turn-on is
/// delayed by the dead time; while both switches of a leg are off the leg
/// voltage follows the phase-current sign through the free-wheeling diodes.
/// Conducting devices drop `threshold + slope * |i|`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InverterParams {
    /// Mean DC-bus voltage, volt.
    pub dc_bus_v: f64,
    /// Peak amplitude of the sinusoidal DC-bus ripple, volt.
    pub bus_ripple_v: f64,
    /// Frequency of the DC-bus ripple, hertz.
    pub bus_ripple_hz: f64,
    /// PWM period Ts, second (one carrier period, valley to valley).
    pub pwm_period_s: f64,
    /// Effective dead time (blanking between one switch's turn-off and the other's
    /// turn-on, net of device switching delays), second. Must be below Ts / 2.
    pub dead_time_s: f64,
    /// IGBT on-state threshold voltage V_CE0, volt.
    pub igbt_threshold_v: f64,
    /// IGBT on-state slope resistance r_CE, ohm.
    pub igbt_slope_ohm: f64,
    /// Free-wheeling diode threshold voltage V_F0, volt.
    pub diode_threshold_v: f64,
    /// Free-wheeling diode slope resistance r_F, ohm.
    pub diode_slope_ohm: f64,
    /// Longest integration step, second: each PWM period is split at its
    /// switching instants and every sub-interval is integrated with RK4 steps
    /// no longer than this.
    pub max_substep_s: f64,
}

impl InverterParams {
    /// Realistic defaults for a drive of `motor`:
    ///
    /// - DC bus = sqrt(2) x rated line voltage (311 V for 220 V): a diode-rectified
    ///   single-phase 220 V mains supply, the supply such a 220 V-rated motor is
    ///   built for; it also gives exactly the rated phase voltage at the edge of
    ///   linear SVPWM (Vdc / sqrt(3) = 180 V peak).
    /// - Bus ripple 1 % of the bus (3.1 V peak) at 100 Hz: 50 Hz mains, full-wave
    ///   rectified; about 100 W drawn at 311 V from a 470 uF capacitor gives
    ///   I / (2 f C) = 6.8 V peak to peak.
    /// - Ts = 100 us (10 kHz), the usual carrier for a TMS320F28335 drive and the
    ///   task's default.
    /// - Dead time 2 us: 600 V IGBT intelligent power modules ask for a minimum
    ///   dead time of roughly 1-3 us; 2 us is a common firmware setting.
    /// - Device drops V_CE = 1.0 V + 0.12 ohm * |i|, V_F = 0.9 V + 0.12 ohm * |i|:
    ///   representative of the output and diode curves of small (5-10 A) 600 V
    ///   IGBT modules, about 1.3-1.6 V at a few amperes.
    /// - 2 us maximum RK4 step: at least 50 steps per 100 us period, and a 2 us
    ///   dead-time interval is one step of its own.
    pub fn from_motor(motor: &MotorParams) -> Self {
        let dc_bus_v = core::f64::consts::SQRT_2 * f64::from(motor.rated_voltage_v);
        InverterParams {
            dc_bus_v,
            bus_ripple_v: 0.01 * dc_bus_v,
            bus_ripple_hz: 100.0,
            pwm_period_s: 100e-6,
            dead_time_s: 2e-6,
            igbt_threshold_v: 1.0,
            igbt_slope_ohm: 0.12,
            diode_threshold_v: 0.9,
            diode_slope_ohm: 0.12,
            max_substep_s: 2e-6,
        }
    }

    /// An ideal inverter on a constant `dc_bus_v` bus: no ripple, no dead time,
    /// no device drops; Ts = 100 us, 2 us maximum step.
    pub fn ideal(dc_bus_v: f64) -> Self {
        InverterParams {
            dc_bus_v,
            bus_ripple_v: 0.0,
            bus_ripple_hz: 0.0,
            pwm_period_s: 100e-6,
            dead_time_s: 0.0,
            igbt_threshold_v: 0.0,
            igbt_slope_ohm: 0.0,
            diode_threshold_v: 0.0,
            diode_slope_ohm: 0.0,
            max_substep_s: 2e-6,
        }
    }

    /// The classic dead-time voltage error magnitude `dead_time_s / pwm_period_s *
    /// dc_bus_v`, volt: the period-average leg-voltage error for a phase current
    /// that keeps one sign through the period.
    pub fn dead_time_error_v(&self) -> f64 {
        self.dead_time_s / self.pwm_period_s * self.dc_bus_v
    }

    /// Checks every field; the first refused field by name.
    pub fn validate(&self) -> Result<(), PlantError> {
        positive("dc_bus_v", self.dc_bus_v)?;
        non_negative("bus_ripple_v", self.bus_ripple_v)?;
        check(self.bus_ripple_v < self.dc_bus_v, "bus_ripple_v", "must be below dc_bus_v")?;
        non_negative("bus_ripple_hz", self.bus_ripple_hz)?;
        positive("pwm_period_s", self.pwm_period_s)?;
        non_negative("dead_time_s", self.dead_time_s)?;
        check(
            self.dead_time_s < 0.5 * self.pwm_period_s,
            "dead_time_s",
            "must be below half the PWM period",
        )?;
        non_negative("igbt_threshold_v", self.igbt_threshold_v)?;
        non_negative("igbt_slope_ohm", self.igbt_slope_ohm)?;
        non_negative("diode_threshold_v", self.diode_threshold_v)?;
        non_negative("diode_slope_ohm", self.diode_slope_ohm)?;
        positive("max_substep_s", self.max_substep_s)?;
        check(
            self.pwm_period_s / self.max_substep_s <= 1e6,
            "max_substep_s",
            "must be at least a millionth of the PWM period",
        )
    }
}

/// Which phase currents have a sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CurrentSensing {
    /// Sensors on phases a and b; the firmware forms `i_c = -(i_a + i_b)`, the usual
    /// arrangement for an isolated-neutral motor.
    TwoPhase,
    /// A sensor on each phase; each reading carries its own errors.
    ThreePhase,
}

/// Phase-current and DC-bus voltage measurement chains.
///
/// Current reading of phase k: `quantise((1 + gain_error[k]) i_k + offset[k] + noise)`,
/// with noise white Gaussian of the given RMS and quantisation by a bipolar ADC
/// of `current_adc_bits` over `[-current_full_scale_a, +current_full_scale_a)`
/// (readings saturate at the ends). The bus reading is alike with a unipolar ADC
/// over `[0, bus_full_scale_v)`. `None` for the ADC bits means no quantisation
/// and no saturation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorParams {
    /// Which phases are measured.
    pub current_sensing: CurrentSensing,
    /// Current offset per phase a, b, c, ampere.
    pub current_offset_a: [f64; 3],
    /// Relative gain error per phase a, b, c, dimensionless (0.01 = reads 1 % high).
    pub current_gain_error: [f64; 3],
    /// White Gaussian current noise per reading, ampere RMS.
    pub current_noise_rms_a: f64,
    /// Current ADC resolution, bits (1..=24), or `None` for an unquantised reading.
    pub current_adc_bits: Option<u32>,
    /// Current ADC range, ampere: readings span +-this.
    pub current_full_scale_a: f64,
    /// DC-bus voltage offset, volt.
    pub bus_offset_v: f64,
    /// DC-bus relative gain error, dimensionless.
    pub bus_gain_error: f64,
    /// White Gaussian DC-bus noise per reading, volt RMS.
    pub bus_noise_rms_v: f64,
    /// DC-bus ADC resolution, bits (1..=24), or `None` for an unquantised reading.
    pub bus_adc_bits: Option<u32>,
    /// DC-bus ADC range, volt: readings span 0..this.
    pub bus_full_scale_v: f64,
}

impl SensorParams {
    /// Realistic defaults for a drive of `motor`:
    ///
    /// - Two sensors (a, b), Hall-effect transducers into a 12-bit ADC (the
    ///   TMS320F28335's ADC is 12-bit).
    /// - Current full scale: the 1-2-5 value at or above 3.3 x the rated peak
    ///   current (+-10 A for the paper motor, 4.9 mA per LSB), room for start-up
    ///   transients and the overcurrent trip.
    /// - Offsets +0.2 %, -0.15 %, +0.1 % of full scale (20, -15, 10 mA): what is
    ///   left of a Hall sensor's offset after a power-up zero calibration once it
    ///   has drifted with temperature.
    /// - Gain errors +0.5 %, -0.8 %, +0.3 %: Hall transducers are specified to
    ///   about +-0.5-1 % overall accuracy, plus burden-resistor tolerance.
    /// - Noise 0.1 % of full scale RMS (10 mA, about 2 LSB): switching noise
    ///   coupled into the sampling.
    /// - Bus: resistive divider into the 12-bit ADC, full scale the 1-2-5 value at
    ///   or above 1.3 x the bus (500 V, 0.12 V per LSB); gain error +1 % (1 %
    ///   divider resistors), offset 0.5 V, noise 0.3 V RMS.
    pub fn from_motor(motor: &MotorParams) -> Self {
        let i_peak = core::f64::consts::SQRT_2 * f64::from(motor.rated_current_a);
        let fs_a = ceil_125(3.3 * i_peak);
        let vdc = core::f64::consts::SQRT_2 * f64::from(motor.rated_voltage_v);
        SensorParams {
            current_sensing: CurrentSensing::TwoPhase,
            current_offset_a: [0.002 * fs_a, -0.0015 * fs_a, 0.001 * fs_a],
            current_gain_error: [0.005, -0.008, 0.003],
            current_noise_rms_a: 0.001 * fs_a,
            current_adc_bits: Some(12),
            current_full_scale_a: fs_a,
            bus_offset_v: 0.5,
            bus_gain_error: 0.01,
            bus_noise_rms_v: 0.3,
            bus_adc_bits: Some(12),
            bus_full_scale_v: ceil_125(1.3 * vdc),
        }
    }

    /// Ideal sensors: every reading equals the true value (three-phase sensing,
    /// no offset, gain error, noise or quantisation).
    pub fn ideal() -> Self {
        SensorParams {
            current_sensing: CurrentSensing::ThreePhase,
            current_offset_a: [0.0; 3],
            current_gain_error: [0.0; 3],
            current_noise_rms_a: 0.0,
            current_adc_bits: None,
            current_full_scale_a: 1e9,
            bus_offset_v: 0.0,
            bus_gain_error: 0.0,
            bus_noise_rms_v: 0.0,
            bus_adc_bits: None,
            bus_full_scale_v: 1e9,
        }
    }

    /// Checks every field; the first refused field by name.
    pub fn validate(&self) -> Result<(), PlantError> {
        for x in self.current_offset_a {
            finite("current_offset_a", x)?;
        }
        for g in self.current_gain_error {
            finite("current_gain_error", g)?;
            check(g > -1.0, "current_gain_error", "must be above -1")?;
        }
        non_negative("current_noise_rms_a", self.current_noise_rms_a)?;
        if let Some(bits) = self.current_adc_bits {
            check((1..=24).contains(&bits), "current_adc_bits", "must be 1..=24")?;
        }
        positive("current_full_scale_a", self.current_full_scale_a)?;
        finite("bus_offset_v", self.bus_offset_v)?;
        finite("bus_gain_error", self.bus_gain_error)?;
        check(self.bus_gain_error > -1.0, "bus_gain_error", "must be above -1")?;
        non_negative("bus_noise_rms_v", self.bus_noise_rms_v)?;
        if let Some(bits) = self.bus_adc_bits {
            check((1..=24).contains(&bits), "bus_adc_bits", "must be 1..=24")?;
        }
        positive("bus_full_scale_v", self.bus_full_scale_v)
    }
}

/// Everything a [`super::Plant`] is built from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimParams {
    /// Motor and mechanics.
    pub plant: PlantParams,
    /// Inverter and DC bus.
    pub inverter: InverterParams,
    /// Measurement chains.
    pub sensors: SensorParams,
    /// Seed of the sensor-noise generator (PCG64): equal seeds give equal runs.
    pub seed: u64,
}

impl SimParams {
    /// Realistic plant, inverter and sensors for `motor` (each `from_motor`), seed 1.
    pub fn from_motor(motor: &MotorParams) -> Self {
        SimParams {
            plant: PlantParams::from_motor(motor),
            inverter: InverterParams::from_motor(motor),
            sensors: SensorParams::from_motor(motor),
            seed: 1,
        }
    }

    /// Every non-ideality off: viscous friction only, ideal inverter on the same
    /// bus voltage as [`InverterParams::from_motor`], ideal sensors; seed 1.
    pub fn ideal_from_motor(motor: &MotorParams) -> Self {
        let bus = InverterParams::from_motor(motor).dc_bus_v;
        SimParams {
            plant: PlantParams::ideal_from_motor(motor),
            inverter: InverterParams::ideal(bus),
            sensors: SensorParams::ideal(),
            seed: 1,
        }
    }

    /// Longest RK4 step actually used, second: `max_substep_s`, shortened to half
    /// the fastest electrical time constant `min(Ld, Lq) / Rs` if that is shorter
    /// (RK4 is unstable beyond about 2.8 time constants).
    pub fn effective_max_step_s(&self) -> f64 {
        // With d saturation the incremental d inductance goes down to half of L_d.
        let ld = if self.plant.ld_saturation_per_a > 0.0 { 0.5 * self.plant.ld_h } else { self.plant.ld_h };
        let tau_e = ld.min(self.plant.lq_h) / self.plant.rs_ohm;
        self.inverter.max_substep_s.min(0.5 * tau_e)
    }

    /// Checks the three parameter sets, and that a PWM period needs at most a
    /// million integration steps.
    pub fn validate(&self) -> Result<(), PlantError> {
        self.plant.validate()?;
        self.inverter.validate()?;
        self.sensors.validate()?;
        check(
            self.inverter.pwm_period_s / self.effective_max_step_s() <= 1e6,
            "ld_h",
            "gives an electrical time constant below a millionth of the PWM period",
        )
    }
}
