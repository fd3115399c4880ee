//! The unit system the control code runs in: SI, or per-unit for fixed point.
//!
//! The algorithms are unit-consistent: every equation holds in SI and equally in a
//! per-unit system whose bases satisfy `flux = voltage / omega`, `impedance =
//! voltage / current`, `inductance = impedance / omega` and `time = 1 / omega`. So the
//! same generic code runs on SI `f32`/`f64` ([`Base::SI`]) and on per-unit [`Q24`]
//! ([`Base::for_motor`]), where every signal sits near 1 and the fixed-point
//! resolution is used well. Configuration stays in SI `f32`; a [`Base`] converts it once,
//! when a block is built. Angles ([`Angle`]) and duty cycles are dimensionless and
//! identical in every unit system.
//!
//! [`Q24`]: crate::num::Q24
//! [`Angle`]: crate::num::Angle

use crate::motor::MotorParams;
use crate::num::Scalar;

/// Base values of a per-unit system (all SI). A quantity's working value is its SI
/// value divided by its base.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Base {
    /// Voltage base, V.
    pub voltage_v: f32,
    /// Current base, A.
    pub current_a: f32,
    /// Angular-frequency base, rad/s (electrical). Time base is `1 / omega_rad_s` s.
    pub omega_rad_s: f32,
}

impl Base {
    /// The identity: working values are SI (V, A, rad/s, s, Wb, ohm, H).
    pub const SI: Base = Base { voltage_v: 1.0, current_a: 1.0, omega_rad_s: 1.0 };

    /// The per-unit system used for fixed point on `motor`:
    /// voltage base = rated phase peak voltage (`rated_voltage_v * sqrt(2/3)`),
    /// current base = rated peak current (`rated_current_a * sqrt(2)`),
    /// omega base = the speed at which the back-EMF equals the voltage base
    /// (`voltage_v / psi_f_wb`), so the magnet flux is 1 per unit.
    ///
    /// Paper motor: 179.6 V, 2.97 A, 1122.6 rad/s; then 2x rated current is 2.0 pu,
    /// 2x the paper's top speed (0.9 m/s, 188.5 rad/s) is 0.17 pu, the DC bus (311 V)
    /// is 1.73 pu and the time step (100 us) is 0.112 pu: all well inside Q8.24's
    /// +-128, with 2^-24 resolution.
    pub fn for_motor(motor: &MotorParams) -> Base {
        let voltage_v = motor.rated_voltage_v * 0.816_496_6;
        Base {
            voltage_v,
            current_a: motor.rated_current_a * core::f32::consts::SQRT_2,
            omega_rad_s: voltage_v / motor.psi_f_wb,
        }
    }

    /// Flux base, Wb (`voltage_v / omega_rad_s`).
    pub fn flux_wb(&self) -> f32 {
        self.voltage_v / self.omega_rad_s
    }
    /// Impedance base, ohm (`voltage_v / current_a`).
    pub fn impedance_ohm(&self) -> f32 {
        self.voltage_v / self.current_a
    }
    /// Inductance base, H (`impedance_ohm / omega_rad_s`).
    pub fn inductance_h(&self) -> f32 {
        self.impedance_ohm() / self.omega_rad_s
    }
    /// Time base, s (`1 / omega_rad_s`).
    pub fn time_s(&self) -> f32 {
        1.0 / self.omega_rad_s
    }

    /// A voltage in V as a working value.
    pub fn voltage<T: Scalar>(&self, volts: f32) -> T {
        T::from_f32(volts / self.voltage_v)
    }
    /// A current in A as a working value.
    pub fn current<T: Scalar>(&self, amperes: f32) -> T {
        T::from_f32(amperes / self.current_a)
    }
    /// An angular frequency in rad/s as a working value.
    pub fn omega<T: Scalar>(&self, rad_per_s: f32) -> T {
        T::from_f32(rad_per_s / self.omega_rad_s)
    }
    /// A rate in 1/s (e.g. a PLL's second-order gain per unit of omega) as a working
    /// value; the same scaling as an angular frequency.
    pub fn rate<T: Scalar>(&self, per_s: f32) -> T {
        T::from_f32(per_s / self.omega_rad_s)
    }
    /// A time in s as a working value.
    pub fn time<T: Scalar>(&self, seconds: f32) -> T {
        T::from_f32(seconds * self.omega_rad_s)
    }
    /// A flux linkage in Wb as a working value.
    pub fn flux<T: Scalar>(&self, webers: f32) -> T {
        T::from_f32(webers / self.flux_wb())
    }
    /// A resistance in ohm as a working value.
    pub fn resistance<T: Scalar>(&self, ohms: f32) -> T {
        T::from_f32(ohms / self.impedance_ohm())
    }
    /// An inductance in H as a working value.
    pub fn inductance<T: Scalar>(&self, henries: f32) -> T {
        T::from_f32(henries / self.inductance_h())
    }

    /// A working voltage back in V.
    pub fn to_volts<T: Scalar>(&self, v: T) -> f32 {
        v.to_f32() * self.voltage_v
    }
    /// A working current back in A.
    pub fn to_amperes<T: Scalar>(&self, i: T) -> f32 {
        i.to_f32() * self.current_a
    }
    /// A working angular frequency back in rad/s.
    pub fn to_rad_per_s<T: Scalar>(&self, w: T) -> f32 {
        w.to_f32() * self.omega_rad_s
    }
    /// A working flux back in Wb.
    pub fn to_webers<T: Scalar>(&self, psi: T) -> f32 {
        psi.to_f32() * self.flux_wb()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn per_unit_bases_are_consistent_and_paper_figures_fit() {
        let m = MotorParams::paper();
        let b = Base::for_motor(&m);
        // psi_f is 1 pu by construction.
        assert!((m.psi_f_wb / b.flux_wb() - 1.0).abs() < 1e-6);
        // L = Z / omega, and R * t has the dimension of L.
        assert!((b.inductance_h() * b.omega_rad_s - b.impedance_ohm()).abs() < 1e-4);
        // 2x rated peak current is 2 pu by construction; with 2x top speed and the 311 V
        // bus, every figure stays far inside Q8.24's +-128.
        assert!((2.0 * m.rated_current_a * core::f32::consts::SQRT_2 / b.current_a - 2.0).abs() < 1e-6);
        assert!(m.omega_e_from_speed(0.9) / b.omega_rad_s < 0.2);
        assert!(311.0 / b.voltage_v < 2.0);
    }
}
