//! A board made of memory, for host tests of the control loop: the test sets the next
//! sample (or injects a fault into it) and reads back what the loop commanded.

use super::{PhaseSample, PhaseSensors, PowerStage};

/// A fault to inject into the next samples of a [`FakeBoard`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum InjectedFault {
    /// Phase-a current reads NaN (a broken conversion).
    NanCurrent,
    /// Phase-b current reads this many amperes.
    CurrentSpike(f32),
    /// The bus reads this many volts.
    BusVoltage(f32),
}

/// Scripted sensors and a recording power stage.
#[derive(Clone, Debug, Default)]
pub struct FakeBoard {
    /// The sample the next [`PhaseSensors::sample`] returns (before any injected fault).
    pub next: PhaseSample,
    /// Applied to every sample while set.
    pub fault: Option<InjectedFault>,
    /// Last duties commanded.
    pub duties: Option<[f32; 3]>,
    /// Whether the gate signals are connected now.
    pub bridge_on: bool,
    /// How many times the bridge was switched on / off.
    pub enables: u32,
    /// See `enables`.
    pub disables: u32,
    /// A hardware protection's input (e.g. an over-current comparator) is active: it
    /// switches the bridge off at once and latches [`FakeBoard::hardware_tripped`].
    pub break_input: bool,
    /// The latched hardware trip ([`PowerStage::hardware_trip`]).
    pub hardware_tripped: bool,
}

impl PhaseSensors for FakeBoard {
    fn sample(&mut self) -> PhaseSample {
        let mut s = self.next;
        match self.fault {
            Some(InjectedFault::NanCurrent) => s.i_abc_a[0] = f32::NAN,
            Some(InjectedFault::CurrentSpike(a)) => s.i_abc_a[1] = a,
            Some(InjectedFault::BusVoltage(v)) => s.vdc_v = v,
            None => {}
        }
        s
    }
}

impl PowerStage for FakeBoard {
    fn set_duties(&mut self, duties: [f32; 3]) {
        self.duties = Some(duties.map(|d| if d.is_nan() { 0.5 } else { d.clamp(0.0, 1.0) }));
    }
    fn enable_bridge(&mut self) {
        if self.hardware_trip() {
            return;
        }
        self.bridge_on = true;
        self.enables += 1;
    }
    fn disable_bridge(&mut self) {
        self.bridge_on = false;
        self.disables += 1;
    }
    fn hardware_trip(&mut self) -> bool {
        if self.break_input {
            self.hardware_tripped = true;
            self.bridge_on = false;
        }
        self.hardware_tripped
    }
    fn clear_hardware_trip(&mut self) {
        self.hardware_tripped = self.break_input;
    }
}
