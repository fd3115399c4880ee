//! The control interrupt's work, independent of any board: apply the setpoints, read
//! the board's sensors, run one [`Drive::step`], drive the bridge, hand telemetry to the
//! lower-priority context.
//!
//! ```text
//!  thread / low-priority context            control interrupt (highest priority)
//!  ----------------------------            -----------------------------------
//!  Setpoints::set_* (atomic stores)  --->  ControlLoop::step(board, setpoints, tx)
//!  Consumer<ActuationFrame>::dequeue <---  Producer::enqueue every `telemetry_every`
//! ```
//!
//! Nothing here blocks or waits: setpoints are atomics the interrupt reads once per
//! step (a move to queue waits in a one-slot mailbox the interrupt empties into
//! [`Drive::push_move`]), telemetry goes through a fixed-capacity [`crate::queue::Queue`] whose full
//! state the interrupt counts and moves on from. The step's time is bounded by the
//! drive's (no loops over data, no allocation, no panics).

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use dcfo::algorithms::motion::Move;
use dcfo::drive::{Commands, Drive, DriveState, Faults, Measurements, StepOutput};
use dcfo::link::{ActuationFrame, LinkStats, PositionReport};
use dcfo::num::Scalar;
use dcfo::num::units::Base;

use crate::board::{PhaseSample, PhaseSensors, PowerStage};
use crate::queue::Producer;

/// Commands from a lower-priority context to the control interrupt, lock-free.
/// Power-on state: disabled, speed reference 0 m/s, no move.
///
/// Moves go through a one-slot mailbox: one context ([`Setpoints::post_move`], the
/// thread) fills it when empty, the control interrupt empties it
/// ([`Setpoints::take_move`]) into the drive's queue. A move that finds the mailbox full,
/// or that the drive refuses, is counted ([`Setpoints::moves_rejected`]), never waited
/// for.
#[derive(Debug)]
pub struct Setpoints {
    speed_m_per_s_bits: AtomicU32,
    enable: AtomicBool,
    clear_faults: AtomicBool,
    move_target_m_bits: AtomicU32,
    move_dwell_s_bits: AtomicU32,
    /// The mailbox holds a move (set last by the writer, cleared by the interrupt).
    move_posted: AtomicBool,
    moves_rejected: AtomicU32,
}

impl Default for Setpoints {
    fn default() -> Self {
        Self::new()
    }
}

impl Setpoints {
    /// Disabled, 0 m/s.
    pub const fn new() -> Self {
        Setpoints {
            speed_m_per_s_bits: AtomicU32::new(0),
            enable: AtomicBool::new(false),
            clear_faults: AtomicBool::new(false),
            move_target_m_bits: AtomicU32::new(0),
            move_dwell_s_bits: AtomicU32::new(0),
            move_posted: AtomicBool::new(false),
            moves_rejected: AtomicU32::new(0),
        }
    }

    /// Posts a move (target m, dwell s) for the control interrupt to queue at its next
    /// period. Call from one context only (the thread). Refused (`false`) and counted in
    /// [`moves_rejected`](Self::moves_rejected) when a value is not finite or the
    /// mailbox still holds the previous move (at most one move per control period).
    pub fn post_move(&self, m: Move) -> bool {
        if !(m.target_m.is_finite() && m.dwell_s.is_finite()) || self.move_posted.load(Ordering::Acquire) {
            self.count_rejected_move();
            return false;
        }
        self.move_target_m_bits.store(m.target_m.to_bits(), Ordering::Relaxed);
        self.move_dwell_s_bits.store(m.dwell_s.to_bits(), Ordering::Relaxed);
        self.move_posted.store(true, Ordering::Release);
        true
    }

    /// Takes the posted move, if any (from the control interrupt, once per period),
    /// emptying the mailbox.
    pub fn take_move(&self) -> Option<Move> {
        if !self.move_posted.load(Ordering::Acquire) {
            return None;
        }
        let m = Move {
            target_m: f32::from_bits(self.move_target_m_bits.load(Ordering::Relaxed)),
            dwell_s: f32::from_bits(self.move_dwell_s_bits.load(Ordering::Relaxed)),
        };
        self.move_posted.store(false, Ordering::Release);
        Some(m)
    }

    /// Counts one refused move (the mailbox was full, or the drive refused it).
    pub fn count_rejected_move(&self) {
        self.moves_rejected.fetch_add(1, Ordering::Relaxed);
    }

    /// Moves refused since power-on (mailbox full, not finite, or refused by the drive:
    /// queue full, target outside the stroke, a speed drive), wrapping at 65 536.
    pub fn moves_rejected(&self) -> u16 {
        self.moves_rejected.load(Ordering::Relaxed) as u16
    }

    /// Sets the linear speed reference (m/s). A non-finite value is refused (`false`)
    /// and the previous reference kept.
    pub fn set_speed_m_per_s(&self, speed_m_per_s: f32) -> bool {
        if !speed_m_per_s.is_finite() {
            return false;
        }
        self.speed_m_per_s_bits.store(speed_m_per_s.to_bits(), Ordering::Relaxed);
        true
    }

    /// Asks the drive to run (`true`) or to switch the bridge off and stop (`false`).
    pub fn set_enable(&self, run: bool) {
        self.enable.store(run, Ordering::Relaxed);
    }

    /// Asks the control interrupt to clear latched faults once (at its next step).
    pub fn request_clear_faults(&self) {
        self.clear_faults.store(true, Ordering::Relaxed);
    }

    /// The speed reference, m/s.
    pub fn speed_m_per_s(&self) -> f32 {
        f32::from_bits(self.speed_m_per_s_bits.load(Ordering::Relaxed))
    }

    /// Stores `commands`: a clear-faults request (kept until the control interrupt takes
    /// it), enable, and the speed reference (a non-finite one is refused, `false`, and
    /// the previous reference kept; the rest is stored anyway).
    pub fn set_commands(&self, commands: &Commands) -> bool {
        if commands.clear_faults {
            self.request_clear_faults();
        }
        self.set_enable(commands.enable);
        self.set_speed_m_per_s(commands.speed_ref_m_per_s)
    }

    /// The commands for this control period (call once per period, from the control
    /// interrupt): takes the clear-faults request, so it is applied once.
    pub fn take_commands(&self) -> Commands {
        Commands {
            clear_faults: self.clear_faults.swap(false, Ordering::Relaxed),
            enable: self.enable.load(Ordering::Relaxed),
            speed_ref_m_per_s: self.speed_m_per_s(),
        }
    }
}

/// The drive and its bridge bookkeeping, owned by the control interrupt.
#[derive(Clone, Debug)]
pub struct ControlLoop<T> {
    drive: Drive<T>,
    base: Base,
    telemetry_every: u16,
    countdown: u16,
    sequence: u16,
    telemetry_dropped: u32,
}

impl<T: Scalar> ControlLoop<T> {
    /// Wraps `drive`; a telemetry record is queued every `telemetry_every` steps
    /// (at least 1).
    pub fn new(drive: Drive<T>, telemetry_every: u16) -> Self {
        let base = *drive.base();
        let mut drive = drive;
        drive.set_speed_reference(T::ZERO);
        ControlLoop {
            drive,
            base,
            telemetry_every: telemetry_every.max(1),
            countdown: 1,
            sequence: 0,
            telemetry_dropped: 0,
        }
    }

    /// One control period (call from the interrupt that follows the current sampling):
    /// setpoints, sensors, [`Drive::step`], then the bridge — duties before enable, or
    /// disable before centring the duties, every period (idempotent, so a missed
    /// transition cannot leave the bridge on). A latched trip of the board's own
    /// protection ([`PowerStage::hardware_trip`]) trips the drive (`OVER_CURRENT` and
    /// `EXTERNAL`) in the same period; the board refuses to switch the bridge on while it
    /// is latched, so setting the bridge on every period cannot override it. Returns the
    /// drive's state after the step.
    pub fn step<B: PhaseSensors + PowerStage, const N: usize>(
        &mut self,
        board: &mut B,
        setpoints: &Setpoints,
        telemetry: &mut Producer<'_, ActuationFrame, N>,
    ) -> DriveState {
        let (out, _) = self.period(board, setpoints);
        self.countdown = self.countdown.saturating_sub(1);
        if self.countdown == 0 {
            self.countdown = self.telemetry_every;
            let record = ActuationFrame::from_step(self.sequence, &out, &self.base, LinkStats::default());
            self.sequence = self.sequence.wrapping_add(1);
            if telemetry.enqueue(record).is_err() {
                self.telemetry_dropped = self.telemetry_dropped.saturating_add(1);
            }
        }
        out.state
    }

    /// [`ControlLoop::step`] without the telemetry queue: one control period, returning
    /// the drive's full output and the board's sample it was computed from (for a
    /// capture, or telemetry of another form).
    pub fn period<B: PhaseSensors + PowerStage>(
        &mut self,
        board: &mut B,
        setpoints: &Setpoints,
    ) -> (StepOutput<T>, PhaseSample) {
        self.apply(setpoints, board);
        let s = board.sample();
        // A trip of the power stage's own protection (on the ESC1 the over-current
        // comparators on TIM1's break input, which cleared MOE in hardware) is latched by
        // the board; the drive latches it too, so it reports it and stays off until the
        // faults are cleared: OVER_CURRENT together with EXTERNAL (the board saw it).
        if board.hardware_trip() {
            self.drive.trip(Faults::OVER_CURRENT);
            self.drive.trip(Faults::EXTERNAL);
        }
        // Fixed point has no NaN: catch a broken conversion before it becomes a number.
        if !(s.i_abc_a.iter().all(|i| i.is_finite()) && s.vdc_v.is_finite()) {
            self.drive.trip(Faults::NON_FINITE);
        }
        let m = Measurements::from_si(s.i_abc_a, s.vdc_v, &self.base);
        let out = self.drive.step(&m);
        if out.bridge_enabled {
            board.set_duties([out.duties.a.to_f32(), out.duties.b.to_f32(), out.duties.c.to_f32()]);
            board.enable_bridge();
        } else {
            board.disable_bridge();
            board.set_duties([0.5; 3]);
        }
        (out, s)
    }

    fn apply<B: PowerStage>(&mut self, setpoints: &Setpoints, board: &mut B) {
        let commands = setpoints.take_commands();
        if commands.clear_faults {
            // The board's latch first: if its cause is still there it latches again and
            // the check in `step` trips the drive again in this same period.
            board.clear_hardware_trip();
        }
        // The drive converts the speed reference only when it changed.
        self.drive.apply(&commands);
        // A posted move joins the drive's queue (bounded: one per period); a refusal
        // (full queue, outside the stroke, a speed drive) is counted, not waited on.
        if let Some(m) = setpoints.take_move()
            && self.drive.push_move(m).is_err()
        {
            setpoints.count_rejected_move();
        }
    }

    /// A positioning drive's position report (x̂, the reference, the queue, and the
    /// moves refused so far as counted in `setpoints`); `None` for a speed drive.
    pub fn position_report(&self, setpoints: &Setpoints) -> Option<PositionReport> {
        PositionReport::of(&self.drive, setpoints.moves_rejected())
    }

    /// Telemetry records dropped because the queue was full.
    pub fn telemetry_dropped(&self) -> u32 {
        self.telemetry_dropped
    }

    /// The drive (for inspection).
    pub fn drive(&self) -> &Drive<T> {
        &self.drive
    }

    /// The drive's working-unit base.
    pub fn base(&self) -> &Base {
        &self.base
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::fake::{FakeBoard, InjectedFault};
    use crate::queue::Queue;
    use dcfo::algorithms::observer::ObserverKind;
    use dcfo::drive::DriveConfig;
    use dcfo::motor::MotorParams;
    use dcfo::num::Q24;

    const BUS_V: f32 = 311.0;

    fn control<T: Scalar>(base: &Base) -> ControlLoop<T> {
        let motor = MotorParams::paper();
        let drive =
            Drive::new(&motor, &DriveConfig::for_motor(&motor, BUS_V, ObserverKind::Dcfo), base).unwrap();
        ControlLoop::new(drive, 10)
    }

    fn quiet_board() -> FakeBoard {
        FakeBoard { next: PhaseSample { i_abc_a: [0.0; 3], vdc_v: BUS_V }, ..FakeBoard::default() }
    }

    /// Runs until the drive reaches `state` (at most `limit` steps); returns the steps.
    fn run_until<T: Scalar>(
        c: &mut ControlLoop<T>,
        board: &mut FakeBoard,
        sp: &Setpoints,
        state: DriveState,
        limit: usize,
    ) -> Option<usize> {
        let mut q: Queue<ActuationFrame, 4> = Queue::new();
        let (mut tx, mut rx) = q.split();
        for k in 1..=limit {
            let s = c.step(board, sp, &mut tx);
            while rx.dequeue().is_some() {}
            if s == state {
                return Some(k);
            }
        }
        None
    }

    fn check_bridge_follows_the_drive<T: Scalar>(base: &Base) {
        let mut c = control::<T>(base);
        let mut board = quiet_board();
        let sp = Setpoints::new();
        // Disabled: bridge off, duties centred.
        assert_eq!(run_until(&mut c, &mut board, &sp, DriveState::Starting, 50), None);
        assert!(!board.bridge_on && board.enables == 0);
        assert_eq!(board.duties, Some([0.5; 3]));
        // Enabled: calibration (bridge off), then the catch on enable (zero current, to
        // find a mover that may be moving) switches it on, then start-up.
        sp.set_enable(true);
        assert!(sp.set_speed_m_per_s(0.3));
        assert!(run_until(&mut c, &mut board, &sp, DriveState::Reacquiring, 10_000).is_some());
        // The step that ends calibration enters the catch; the next one modulates.
        assert!(!board.bridge_on);
        assert_eq!(run_until(&mut c, &mut board, &sp, DriveState::Reacquiring, 1), Some(1));
        assert!(board.bridge_on);
        assert!(run_until(&mut c, &mut board, &sp, DriveState::Starting, 10_000).is_some());
        assert!(board.bridge_on);
        // Each injected fault: bridge off at once, latched with its bit, and it stays off
        // after the cause goes away until the faults are cleared.
        for (fault, bit) in [
            (InjectedFault::NanCurrent, Faults::NON_FINITE),
            (InjectedFault::CurrentSpike(20.0), Faults::OVER_CURRENT),
            (InjectedFault::BusVoltage(BUS_V * 2.0), Faults::BUS_OVER_VOLTAGE),
            (InjectedFault::BusVoltage(BUS_V * 0.2), Faults::BUS_UNDER_VOLTAGE),
        ] {
            board.fault = Some(fault);
            assert_eq!(run_until(&mut c, &mut board, &sp, DriveState::Fault, 1), Some(1), "{fault:?}");
            assert!(!board.bridge_on, "{fault:?}");
            assert!(c.drive().faults().contains(bit), "{fault:?}: {:?}", c.drive().faults());
            board.fault = None;
            assert_eq!(run_until(&mut c, &mut board, &sp, DriveState::Starting, 100), None);
            assert!(!board.bridge_on);
            sp.request_clear_faults();
            // Cleared: disabled (enable is re-read at once), then calibration and start.
            assert!(run_until(&mut c, &mut board, &sp, DriveState::Starting, 10_000).is_some(), "{fault:?}");
            assert_eq!(run_until(&mut c, &mut board, &sp, DriveState::Starting, 1), Some(1));
            assert!(board.bridge_on && c.drive().faults() == Faults::NONE);
        }
        // Disable: bridge off on the next step.
        sp.set_enable(false);
        assert_eq!(run_until(&mut c, &mut board, &sp, DriveState::Disabled, 1), Some(1));
        assert!(!board.bridge_on);
    }

    #[test]
    fn bridge_follows_the_drive_in_f32() {
        check_bridge_follows_the_drive::<f32>(&Base::SI);
    }

    #[test]
    fn bridge_follows_the_drive_in_q24() {
        let base = Base::for_motor(&MotorParams::paper());
        check_bridge_follows_the_drive::<Q24>(&base);
    }

    #[test]
    fn telemetry_never_blocks_and_counts_what_it_drops() {
        let mut c = control::<f32>(&Base::SI);
        let mut board = quiet_board();
        let sp = Setpoints::new();
        let mut q: Queue<ActuationFrame, 4> = Queue::new();
        let capacity = q.capacity();
        let (mut tx, mut rx) = q.split();
        // Nobody reads: 100 steps make 10 records, `capacity` fit.
        for _ in 0..100 {
            c.step(&mut board, &sp, &mut tx);
        }
        assert_eq!(c.telemetry_dropped() as usize, 10 - capacity);
        let sequences: heapless::Vec<u16, 8> =
            core::iter::from_fn(|| rx.dequeue()).map(|r| r.sequence).collect();
        assert_eq!(sequences.len(), capacity);
        assert!(sequences.iter().enumerate().all(|(i, &s)| usize::from(s) == i));
    }

    /// A hardware protection of the board (the ESC1's over-current comparators on the
    /// TIM1 break input) trips the drive in the period it fires, keeps the bridge off
    /// after its cause is gone, and stays latched through a clear while the cause is
    /// still there.
    #[test]
    fn hardware_trip_latches_and_is_not_overridden() {
        let mut c = control::<f32>(&Base::SI);
        let mut board = quiet_board();
        let sp = Setpoints::new();
        sp.set_enable(true);
        assert!(sp.set_speed_m_per_s(0.3));
        assert!(run_until(&mut c, &mut board, &sp, DriveState::Starting, 10_000).is_some());
        assert!(board.bridge_on);
        let both = Faults::OVER_CURRENT | Faults::EXTERNAL;
        // The comparator fires (hardware cleared MOE): fault in this same period.
        board.break_input = true;
        assert_eq!(run_until(&mut c, &mut board, &sp, DriveState::Fault, 1), Some(1));
        assert!(!board.bridge_on && c.drive().faults() == both);
        // The current decays, the comparator releases: still off, still latched.
        board.break_input = false;
        assert_eq!(run_until(&mut c, &mut board, &sp, DriveState::Starting, 200), None);
        assert!(!board.bridge_on && board.hardware_tripped);
        // A clear while the cause is present: latched again at once.
        board.break_input = true;
        sp.request_clear_faults();
        assert_eq!(run_until(&mut c, &mut board, &sp, DriveState::Fault, 1), Some(1));
        assert!(!board.bridge_on && c.drive().faults() == both);
        // Cause gone, cleared: the drive starts again.
        board.break_input = false;
        sp.request_clear_faults();
        assert!(run_until(&mut c, &mut board, &sp, DriveState::Starting, 10_000).is_some());
        assert_eq!(run_until(&mut c, &mut board, &sp, DriveState::Starting, 1), Some(1));
        assert!(board.bridge_on && !board.hardware_tripped && c.drive().faults() == Faults::NONE);
    }

    #[test]
    fn setpoints_refuse_non_finite_speeds() {
        let sp = Setpoints::new();
        assert!(sp.set_speed_m_per_s(-0.25));
        assert!(!sp.set_speed_m_per_s(f32::NAN));
        assert!(!sp.set_speed_m_per_s(f32::INFINITY));
        assert_eq!(sp.speed_m_per_s(), -0.25);
    }
}
