//! A virtual board: the library's [`VirtualMotor`] (a PMSLM and an averaged inverter,
//! `dcfo::plant`) behind the same [`PhaseSensors`] and [`PowerStage`] traits as
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
//! simulation's one-period computation delay (`dcfo_host::closed_loop`).
//!
//! No register is touched: it builds on every target and is tested on the host.

use dcfo::plant::VirtualMotor;

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

#[cfg(test)]
mod tests {
    use super::*;
    use dcfo::motor::MotorParams;
    use dcfo::plant::VirtualAxis;

    fn board() -> VirtualBoard {
        let axis = VirtualAxis { payload_kg: 10.0, load_n: 0.0, bus_v: 311.0, period_s: 1e-4 };
        VirtualBoard::new(VirtualMotor::new(&MotorParams::paper(), &axis).unwrap())
    }

    /// Duties set after the sample at `t_k` switch the bridge during
    /// `[t_{k+1}, t_{k+2})`: the sample at `t_{k+1}` still shows the period before, the
    /// one at `t_{k+2}` their current. A disable takes the present period too.
    #[test]
    fn duties_act_one_period_later_and_a_disable_at_once() {
        let mut b = board();
        assert_eq!(b.sample().i_abc_a, [0.0; 3]);
        b.set_duties([0.6, 0.4, 0.4]);
        b.enable_bridge();
        assert_eq!(b.sample().i_abc_a, [0.0; 3], "the period that just ended ran with the bridge off");
        let s = b.sample();
        // u_alpha = 311 (2 0.6 - 0.8) / 3 V into 5 ohm and 8.5 mH for 100 us, mover at
        // rest: i = u / R (1 - exp(-R Ts / L)), the exponential by its series (no_std).
        let u = 311.0f32 * 0.4 / 3.0;
        let x = 5.0f32 * 1e-4 / 0.0085;
        let one_minus_exp = x - x * x / 2.0 + x * x * x / 6.0 - x * x * x * x / 24.0;
        let expected = u / 5.0 * one_minus_exp;
        assert!((s.i_abc_a[0] - expected).abs() < 0.01 * expected, "{s:?} vs {expected}");
        // Balanced: b and c carry half of it back.
        assert!(
            (s.i_abc_a[1] + 0.5 * s.i_abc_a[0]).abs() < 1e-6 && (s.i_abc_a[1] - s.i_abc_a[2]).abs() < 1e-6
        );
        assert_eq!(s.vdc_v, 311.0);
        b.disable_bridge();
        assert_eq!(b.sample().i_abc_a, [0.0; 3]);
    }
}
