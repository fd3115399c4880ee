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
//! Arm modules are the only code in the firmware that touches registers; what the ESC1's
//! set-up computes and decides is [`esc1_settings`] (all targets, tested on the host).
//!
//! A board whose start-up hands out its sensors and its power stage separately (as the
//! ESC1's does) gives the control loop both as one [`Bridge`]. What a new board
//! implements, with [`fake`] as the reference: `docs/new-board.md`.

pub mod esc1_settings;
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

/// A board's sensors and power stage as the one [`PhaseSensors`] + [`PowerStage`] that the
/// control loop runs on, for boards that bring them up as two parts. Every call is passed
/// on unchanged.
#[derive(Clone, Debug, Default)]
pub struct Bridge<S, P> {
    /// Phase currents and bus voltage.
    pub sensors: S,
    /// The three half-bridges.
    pub power: P,
}

impl<S: PhaseSensors, P> PhaseSensors for Bridge<S, P> {
    fn sample(&mut self) -> PhaseSample {
        self.sensors.sample()
    }
}

impl<S, P: PowerStage> PowerStage for Bridge<S, P> {
    fn set_duties(&mut self, duties: [f32; 3]) {
        self.power.set_duties(duties);
    }
    fn enable_bridge(&mut self) {
        self.power.enable_bridge();
    }
    fn disable_bridge(&mut self) {
        self.power.disable_bridge();
    }
    fn hardware_trip(&mut self) -> bool {
        self.power.hardware_trip()
    }
    fn clear_hardware_trip(&mut self) {
        self.power.clear_hardware_trip();
    }
}

#[cfg(test)]
mod tests {
    use super::fake::{FakeBoard, InjectedFault};
    use super::*;

    /// The bridge reads its sensors and drives its power stage, nothing else.
    #[test]
    fn bridge_passes_calls_to_its_parts() {
        let mut b = Bridge { sensors: FakeBoard::default(), power: FakeBoard::default() };
        b.sensors.next.vdc_v = 24.0;
        b.sensors.fault = Some(InjectedFault::CurrentSpike(3.0));
        assert_eq!(b.sample(), PhaseSample { i_abc_a: [0.0, 3.0, 0.0], vdc_v: 24.0 });
        b.set_duties([0.2, f32::NAN, 1.5]);
        b.enable_bridge();
        assert_eq!(b.power.duties, Some([0.2, 0.5, 1.0]));
        assert!(b.power.bridge_on && b.power.enables == 1 && !b.sensors.bridge_on);
        b.power.break_input = true;
        assert!(b.hardware_trip() && !b.power.bridge_on);
        b.power.break_input = false;
        b.clear_hardware_trip();
        assert!(!b.hardware_trip());
        b.disable_bridge();
        assert_eq!(b.power.disables, 1);
    }
}
