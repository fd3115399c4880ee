//! What the drive needs of a board, as small traits, and the boards that provide it.
//!
//! - [`PhaseSensors`]: phase currents and DC-bus voltage of the latest PWM period.
//! - [`PowerStage`]: three duty cycles, bridge on, bridge off.
//! - The serial link is `embedded_io::{Read, Write}` (embedded-hal 1.0 left serial to
//!   embedded-io); a status LED is an `embedded_hal::digital::OutputPin`.
//!
//! Boards: [`fake::FakeBoard`] (all targets; a scripted sensor source and a recorder of
//! what the control step commanded, with fault injection, for host tests),
//! [`virtual_motor::VirtualBoard`] (all targets; the library's virtual motor in place of
//! a power stage, for a drive image with no hardware) and, on Arm
//! only, `mps2` (QEMU's MPS2 AN385/AN386 UART) and `b_g431b_esc1` (ST's drive board). The
//! Arm modules are the only code in the firmware that touches registers.

pub mod fake;
pub mod virtual_motor;

#[cfg(target_arch = "arm")]
#[allow(unsafe_code)]
pub mod mps2;

#[cfg(all(target_arch = "arm", feature = "esc1"))]
#[allow(unsafe_code)]
pub mod b_g431b_esc1;

/// Phase currents and DC-bus voltage sampled at one PWM carrier valley, SI units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PhaseSample {
    /// Phase currents a, b, c (A), positive into the motor.
    pub i_abc_a: [f32; 3],
    /// DC-bus voltage (V).
    pub vdc_v: f32,
}

/// What the control step reads from a board.
pub trait PhaseSensors {
    /// The latest sample (called from the control interrupt once the conversion of this
    /// period has finished). Values are passed on as measured: range and finiteness
    /// checks are the drive's, which trips on them.
    fn sample(&mut self) -> PhaseSample;
}

/// What the control step drives on a board: three half-bridges.
pub trait PowerStage {
    /// High-side on-time of each leg as a fraction of the PWM period (0..=1), for the
    /// next period. Implementations clamp values outside [0, 1] (a board may hold a lower
    /// maximum, e.g. the ESC1's 0.95 for its current-sampling window) and treat NaN as 0.5.
    fn set_duties(&mut self, duties: [f32; 3]);
    /// Connects the gate signals (main output enable).
    fn enable_bridge(&mut self);
    /// All six switches off at once.
    fn disable_bridge(&mut self);
    /// Whether a protection in the power stage itself (e.g. over-current comparators on
    /// the timer's break input) has switched the bridge off. Latched: it stays `true`, and
    /// [`PowerStage::enable_bridge`] stays without effect, until
    /// [`PowerStage::clear_hardware_trip`] re-arms it. Boards without one: always `false`.
    fn hardware_trip(&mut self) -> bool {
        false
    }
    /// Re-arms the latched hardware trip (called when the drive's faults are cleared). If
    /// its cause is still present the trip stays latched. Boards without one: nothing.
    fn clear_hardware_trip(&mut self) {}
}
