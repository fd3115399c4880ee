//! Space-vector PWM: a stationary-frame voltage and the DC-bus voltage in, three duty
//! cycles in `[0, 1]` out.
//!
//! Realised as min-max (zero-sequence) injection, which gives the same switching
//! pattern as symmetric SVPWM: phase references from the inverse Clarke transform,
//! shifted by `-(max + min) / 2` so the carrier is used symmetrically, then
//! `duty = 1/2 + v / Vdc`. Linear for `|u| <= Vdc / sqrt(3)`; a longer vector keeps its
//! angle and is shortened to that circle (never wrapped or clipped per phase, which
//! would distort the angle).

use crate::algorithms::transforms::{AlphaBeta, inverse_clarke};
use crate::num::Scalar;

/// Duty cycles of the three half-bridges: the fraction of the PWM period each upper
/// switch is on, dimensionless in `[0, 1]`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Duties<T> {
    /// Phase a upper-switch duty, `[0, 1]`.
    pub a: T,
    /// Phase b upper-switch duty, `[0, 1]`.
    pub b: T,
    /// Phase c upper-switch duty, `[0, 1]`.
    pub c: T,
}

/// The result of one modulation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Modulation<T> {
    /// Duty cycles, each in `[0, 1]`.
    pub duties: Duties<T>,
    /// The stationary-frame voltage actually produced (V or per-unit): the command, or
    /// the command shortened to `Vdc / sqrt(3)` when it was longer.
    pub u_applied: AlphaBeta<T>,
    /// `true` when the command was longer than `Vdc / sqrt(3)` and was shortened.
    pub limited: bool,
}

/// Why modulation was refused; the bridge should be switched off.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SvpwmError {
    /// The DC-bus voltage is not a valid positive number.
    BadDcBus,
    /// The voltage command is not a valid number.
    BadCommand,
}

impl<T: Scalar> Duties<T> {
    /// All three duties at 1/2: zero line-to-line voltage.
    pub fn centred() -> Self {
        Duties { a: T::HALF, b: T::HALF, c: T::HALF }
    }
}

/// The DC-bus voltage of one control period with its reciprocal: formed once per period
/// and shared by the modulator and the inverter compensation
/// ([`crate::algorithms::dead_time`]), so that the reciprocal, a software routine in
/// fixed point, is computed once.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DcBus<T> {
    /// The bus voltage, V or per-unit (> 0).
    voltage: T,
    /// `1 / voltage`, per V or per unit.
    inv_voltage: T,
}

impl<T: Scalar> DcBus<T> {
    /// The bus at `vdc` (V or per-unit); [`SvpwmError::BadDcBus`] unless `vdc` is a valid
    /// positive number whose reciprocal is representable.
    pub fn new(vdc: T) -> Result<Self, SvpwmError> {
        if !vdc.is_valid() || vdc <= T::ZERO {
            return Err(SvpwmError::BadDcBus);
        }
        // A reciprocal instead of divisions per duty: division is a software routine in
        // fixed point on an FPU-less core.
        let inv_voltage = vdc.recip().ok_or(SvpwmError::BadDcBus)?;
        Ok(DcBus { voltage: vdc, inv_voltage })
    }

    /// The bus voltage, V or per-unit (> 0).
    pub fn voltage(&self) -> T {
        self.voltage
    }

    /// `1 / voltage`, per V or per unit.
    pub fn inv_voltage(&self) -> T {
        self.inv_voltage
    }
}

/// Modulates `u` (V or per-unit) on a DC bus of `vdc` (same unit, > 0): [`svpwm_on`] on
/// [`DcBus::new`]`(vdc)`.
pub fn svpwm<T: Scalar>(u: AlphaBeta<T>, vdc: T) -> Result<Modulation<T>, SvpwmError> {
    svpwm_on(u, &DcBus::new(vdc)?)
}

/// Modulates `u` (V or per-unit, the bus's unit) on `bus`.
pub fn svpwm_on<T: Scalar>(u: AlphaBeta<T>, bus: &DcBus<T>) -> Result<Modulation<T>, SvpwmError> {
    if !u.is_valid() {
        return Err(SvpwmError::BadCommand);
    }
    let inv_vdc = bus.inv_voltage;
    let v_max = bus.voltage.mul_unit(T::INV_SQRT3);
    let m2 = u.norm_squared();
    let (u, limited) = if m2 > v_max * v_max {
        // |u| > v_max > 0, so the inverse square root exists; checked anyway. (The inverse
        // square root avoids a square root and a division.)
        let k = v_max * m2.inv_sqrt().ok_or(SvpwmError::BadCommand)?;
        (u.scale(k), true)
    } else {
        (u, false)
    };
    let p = inverse_clarke(u);
    let hi = p.a.max(p.b).max(p.c);
    let lo = p.a.min(p.b).min(p.c);
    let offset = (-(hi + lo)).mul_unit(T::HALF);
    let duty = |v: T| (T::HALF + (v + offset) * inv_vdc).clamp_to(T::ZERO, T::ONE);
    Ok(Modulation { duties: Duties { a: duty(p.a), b: duty(p.b), c: duty(p.c) }, u_applied: u, limited })
}
