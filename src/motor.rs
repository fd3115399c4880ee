//! Motor parameters, with units in their names, validated when built.
//!
//! Field names are the keys of the motor file (`docs/motor-format.md`).
//! Values are SI and `f32`: this is configuration, converted once into the numeric
//! type and unit system of the control code (see `num::units`, which imports this
//! module: the motor's parameters stand on the ground floor and import nothing).

/// Which motor parameter was refused, and why. Returned by [`MotorParams::new`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ParamError {
    /// The field's name, as spelled in the motor file (e.g. `"ld_h"`).
    pub field: &'static str,
    /// What is wrong with its value.
    pub reason: ParamFault,
}

/// The ways a parameter value can be wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ParamFault {
    /// NaN or infinite.
    NotFinite,
    /// Zero or negative where only a positive value is physical.
    NotPositive,
    /// Negative where zero is allowed but a negative value is not.
    Negative,
}

impl core::fmt::Display for ParamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let why = match self.reason {
            ParamFault::NotFinite => "must be a finite number",
            ParamFault::NotPositive => "must be greater than zero",
            ParamFault::Negative => "must not be negative",
        };
        write!(f, "motor parameter `{}` {}", self.field, why)
    }
}

/// Electrical and mechanical parameters of a PMSLM (SI units, amplitude-invariant
/// Clarke convention). Build with [`MotorParams::new`], which validates every field.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotorParams {
    /// Stator resistance per phase, ohm (> 0).
    pub rs_ohm: f32,
    /// d-axis inductance, henry (> 0).
    pub ld_h: f32,
    /// q-axis inductance, henry (> 0). The observers use it to form the active flux.
    pub lq_h: f32,
    /// Permanent-magnet flux linkage, weber, amplitude-invariant (> 0).
    pub psi_f_wb: f32,
    /// Pole pitch, metre: distance between adjacent N and S poles (> 0);
    /// `omega_e = pi * v / pole_pitch_m`.
    pub pole_pitch_m: f32,
    /// Mover mass, kilogram (> 0; used by plant models and speed-loop tuning).
    pub mass_kg: f32,
    /// Viscous friction coefficient B, N·s/m (>= 0).
    pub viscous_n_s_per_m: f32,
    /// Rated phase current, ampere RMS (> 0).
    pub rated_current_a: f32,
    /// Rated line voltage, volt RMS (> 0).
    pub rated_voltage_v: f32,
}

/// `Ok` if `value` is finite and `> 0`, else why not, naming `field`. Never inlined (nor
/// [`non_negative`]): [`MotorParams::new`] runs it on nine fields when a motor image is
/// read, and inlined at each it cost 176 B of flash on the ESC1 image.
#[inline(never)]
fn positive(field: &'static str, value: f32) -> Result<(), ParamError> {
    if !value.is_finite() {
        Err(ParamError { field, reason: ParamFault::NotFinite })
    } else if value <= 0.0 {
        Err(ParamError { field, reason: ParamFault::NotPositive })
    } else {
        Ok(())
    }
}

/// `Ok` if `value` is finite and `>= 0`, else why not, naming `field` (never inlined, as
/// [`positive`]).
#[inline(never)]
fn non_negative(field: &'static str, value: f32) -> Result<(), ParamError> {
    if !value.is_finite() {
        Err(ParamError { field, reason: ParamFault::NotFinite })
    } else if value < 0.0 {
        Err(ParamError { field, reason: ParamFault::Negative })
    } else {
        Ok(())
    }
}

impl MotorParams {
    /// Validates `params` field by field and returns it unchanged if every value is
    /// physical; otherwise the first refused field, by name.
    pub fn new(params: MotorParams) -> Result<Self, ParamError> {
        positive("rs_ohm", params.rs_ohm)?;
        positive("ld_h", params.ld_h)?;
        positive("lq_h", params.lq_h)?;
        positive("psi_f_wb", params.psi_f_wb)?;
        positive("pole_pitch_m", params.pole_pitch_m)?;
        positive("mass_kg", params.mass_kg)?;
        non_negative("viscous_n_s_per_m", params.viscous_n_s_per_m)?;
        positive("rated_current_a", params.rated_current_a)?;
        positive("rated_voltage_v", params.rated_voltage_v)?;
        Ok(params)
    }

    /// The paper's test motor (docs/method.md §1), preset name `paper`. Pole pitch is
    /// 0.015 m so that 0.3 m/s is 10 Hz electrical, as the experiments state.
    pub const fn paper() -> Self {
        MotorParams {
            rs_ohm: 5.0,
            ld_h: 0.0085,
            lq_h: 0.0085,
            psi_f_wb: 0.16,
            pole_pitch_m: 0.015,
            mass_kg: 0.66,
            viscous_n_s_per_m: 0.5,
            rated_current_a: 2.1,
            rated_voltage_v: 220.0,
        }
    }

    /// Looks up a named preset (`"paper"`); `None` for an unknown name.
    pub fn preset(name: &str) -> Option<Self> {
        match name {
            "paper" => Some(Self::paper()),
            _ => None,
        }
    }

    /// Electrical angular speed for a linear speed: `omega_e = pi * v / pole_pitch_m`,
    /// rad/s for `speed_m_per_s` in m/s.
    pub fn omega_e_from_speed(&self, speed_m_per_s: f32) -> f32 {
        core::f32::consts::PI * speed_m_per_s / self.pole_pitch_m
    }

    /// Electrical radians per metre of travel, `pi / pole_pitch_m` (rad/m): a pole pitch
    /// is half an electrical turn. Electrical speed (rad/s) per linear speed (m/s) too.
    pub fn rad_per_m(&self) -> f32 {
        core::f32::consts::PI / self.pole_pitch_m
    }

    /// Thrust constant `1.5 * (pi / pole_pitch_m) * psi_f_wb`, N/A (for i_d = 0, Ld = Lq).
    pub fn thrust_constant_n_per_a(&self) -> f32 {
        1.5 * core::f32::consts::PI / self.pole_pitch_m * self.psi_f_wb
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_preset_is_valid_and_gives_10_hz_at_0_3_m_per_s() {
        let m = MotorParams::new(MotorParams::paper()).unwrap();
        let f_hz = m.omega_e_from_speed(0.3) / (2.0 * core::f32::consts::PI);
        assert!((f_hz - 10.0).abs() < 1e-4, "{f_hz}");
    }

    #[test]
    fn each_bad_field_is_named() {
        let base = MotorParams::paper();
        let cases: [(&str, MotorParams, ParamFault); 5] = [
            ("rs_ohm", MotorParams { rs_ohm: 0.0, ..base }, ParamFault::NotPositive),
            ("ld_h", MotorParams { ld_h: -1e-3, ..base }, ParamFault::NotPositive),
            ("lq_h", MotorParams { lq_h: f32::NAN, ..base }, ParamFault::NotFinite),
            ("pole_pitch_m", MotorParams { pole_pitch_m: -0.01, ..base }, ParamFault::NotPositive),
            ("viscous_n_s_per_m", MotorParams { viscous_n_s_per_m: -0.1, ..base }, ParamFault::Negative),
        ];
        for (field, params, reason) in cases {
            assert_eq!(MotorParams::new(params), Err(ParamError { field, reason }));
        }
        assert_eq!(
            MotorParams::new(MotorParams { psi_f_wb: f32::INFINITY, ..base }).unwrap_err().field,
            "psi_f_wb"
        );
    }
}
