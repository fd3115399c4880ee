//! A virtual board: the library's [`VirtualMotor`] (a PMSLM and an averaged inverter,
//! `dcfo::virtual_motor`) behind the same [`PhaseSensors`] and [`PowerStage`] traits as
//! the real boards, so that a drive image runs its control loop unchanged with no power
//! stage: on QEMU (`examples/qemu_drive.rs`), or on a board whose bridge stays off.
//!
//! The model is in the library, not here, because it is physics and host tests check it
//! against analysis and run it closed loop with the drive; this module is only the
//! board's timing. Like a timer with preloaded compare registers, the duties set in
//! period `k` (after the sample at `t_k`) switch the bridge during `[t_{k+1}, t_{k+2})`:
//! each [`PhaseSensors::sample`] first runs the model over the period that just ended
//! with the duties that were in force in it, then takes the newly set ones into force,
//! then returns the currents and the bus at the period's end. This is the host
//! simulation's one-period computation delay (`dcfo_host::sim`).
//!
//! No register is touched: it builds on every target and is tested on the host.

use dcfo::virtual_motor::VirtualMotor;

use super::{PhaseSample, PhaseSensors, PowerStage};

/// A [`VirtualMotor`] as a board.
#[derive(Clone, Debug)]
pub struct VirtualBoard {
    motor: VirtualMotor,
    /// Duties and bridge in force during the present period.
    active: ([f32; 3], bool),
    /// Set by the control step for the next period.
    pending: ([f32; 3], bool),
}

impl VirtualBoard {
    /// The board around `motor`, bridge off.
    pub fn new(motor: VirtualMotor) -> Self {
        VirtualBoard { motor, active: ([0.5; 3], false), pending: ([0.5; 3], false) }
    }

    /// The motor (its true state, for tests and telemetry).
    pub fn motor(&self) -> &VirtualMotor {
        &self.motor
    }

    /// The motor, to change its load or push the mover.
    pub fn motor_mut(&mut self) -> &mut VirtualMotor {
        &mut self.motor
    }
}

impl PhaseSensors for VirtualBoard {
    fn sample(&mut self) -> PhaseSample {
        let (duties, on) = self.active;
        self.motor.step(duties, on);
        self.active = self.pending;
        PhaseSample { i_abc_a: self.motor.phase_currents_a(), vdc_v: self.motor.bus_v() }
    }
}

impl PowerStage for VirtualBoard {
    fn set_duties(&mut self, duties: [f32; 3]) {
        self.pending.0 = duties.map(|d| if d.is_nan() { 0.5 } else { d.clamp(0.0, 1.0) });
    }
    fn enable_bridge(&mut self) {
        self.pending.1 = true;
    }
    fn disable_bridge(&mut self) {
        // Off at once, as a real bridge's MOE: the present period too.
        self.pending.1 = false;
        self.active.1 = false;
    }
}
