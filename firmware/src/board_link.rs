//! The drive image's side of the board link (`dcfo::link::board`): commands from the
//! host in, one answer per command out (telemetry, or capture samples), the capture
//! filled in the control interrupt, and the command watchdog. Board-independent and
//! tested on the host; `examples/qemu_drive.rs` runs it on QEMU with the virtual motor.
//!
//! ```text
//!  thread                                           control interrupt (highest priority)
//!  ------                                           -----------------------------------
//!  BoardLinkServer::on_byte -> Setpoints (atomics)  ControlLoop::period(board, setpoints)
//!    in a critical section: arm / read the capture  Capture::record(output)   (O(1))
//!    and the last step's status                     DriveStatus::update(output, sample)
//!  BoardLinkServer::watchdog(periods)
//! ```
//!
//! The command watchdog counts the drive's control periods ([`LinkClock`]): on a board
//! they run in real time, so 5,000 periods are 0.5 s. On QEMU the drive's time follows the
//! instructions QEMU executes (`-icount`), as fast as it can, so a silence must also last
//! in the host's time ([`BoardLinkServer::with_host_clock`], the host's milliseconds read
//! through `board::mps2::HostClock`): the drive is disabled only when the host has sent
//! nothing for both 500 ms of its own time and 5,000 periods of the drive's. A host that is
//! merely slower than QEMU's drive is not silent, nor is one whose machine stalled QEMU with
//! it (no periods ran), nor one whose QEMU was descheduled (the periods did not run).
//!
//! The thread touches the capture and the status only inside short critical sections
//! (arming, copying [`CAPTURE_CHUNK_SAMPLES`] samples, copying the status), so the
//! control interrupt waits at most that long and never for the UART. Samples are read
//! only once the capture is [`CaptureState::Done`], when the interrupt no longer writes
//! them.

use dcfo::capture::{Capture, CaptureSample, CaptureState};
use dcfo::drive::{DriveState, Faults, StepOutput};
use dcfo::link::board::{BoardCommand, BoardTelemetry, CAPTURE_CHUNK_SAMPLES, CaptureChunk, NO_CAPTURE_READ};
use dcfo::link::{LinkStats, PositionReport, Receiver};
use dcfo::num::Scalar;
use dcfo::num::units::Base;

use crate::board::PhaseSample;
use crate::control::Setpoints;

/// What the last control step left for telemetry, SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriveStatus {
    /// Drive state.
    pub state: DriveState,
    /// Latched faults.
    pub faults: Faults,
    /// The bridge is switching.
    pub bridge_enabled: bool,
    /// θ̂ (electrical rad) and speed (m/s), `None` without an estimate.
    pub estimate: Option<(f32, f32)>,
    /// Measured i_α, i_β, A (offsets removed).
    pub i_ab_a: [f32; 2],
    /// DC-bus voltage, V.
    pub vdc_v: f32,
    /// Control periods run (wrapping).
    pub periods: u32,
    /// A positioning drive's position report (x̂ and the reference in m, the queue, the
    /// refused moves); `None` for a speed drive.
    pub position: Option<PositionReport>,
}

impl DriveStatus {
    /// Power-on: disabled, nothing measured.
    pub const fn new() -> Self {
        DriveStatus {
            state: DriveState::Disabled,
            faults: Faults::NONE,
            bridge_enabled: false,
            estimate: None,
            i_ab_a: [0.0; 2],
            vdc_v: 0.0,
            periods: 0,
            position: None,
        }
    }

    /// Takes one step's output and the drive's position report
    /// ([`ControlLoop::position_report`](crate::control::ControlLoop::position_report))
    /// (call from the control interrupt, every period).
    pub fn update<T: Scalar>(
        &mut self,
        out: &StepOutput<T>,
        sample: &PhaseSample,
        base: &Base,
        position: Option<PositionReport>,
    ) {
        let finite = |x: f32| if x.is_finite() { x } else { 0.0 };
        self.state = out.state;
        self.faults = out.faults;
        self.bridge_enabled = out.bridge_enabled;
        self.estimate =
            out.estimate.map(|e| (e.theta_e.to_radians::<f32>(), finite(e.speed_m_per_s.to_f32())));
        self.i_ab_a = [finite(base.to_amperes(out.i_ab.alpha)), finite(base.to_amperes(out.i_ab.beta))];
        self.vdc_v = finite(sample.vdc_v);
        self.periods = self.periods.wrapping_add(1);
        self.position = position;
    }
}

impl Default for DriveStatus {
    fn default() -> Self {
        Self::new()
    }
}

/// One answer of the drive image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BoardAnswer {
    /// The drive's state.
    Telemetry(BoardTelemetry),
    /// Capture samples.
    Chunk(CaptureChunk),
}

/// The answer to `command`: arms the capture if asked; capture samples if asked and the
/// capture is over, else telemetry. Call inside the critical section that guards
/// `capture` and `status`; bounded: at most [`CAPTURE_CHUNK_SAMPLES`] samples copied.
pub fn answer<const N: usize>(
    command: &BoardCommand,
    capture: &mut Capture<N>,
    status: &DriveStatus,
    setpoints: &Setpoints,
) -> BoardAnswer {
    if command.arm_capture {
        capture.arm();
    }
    if command.capture_read != NO_CAPTURE_READ && capture.state() == CaptureState::Done {
        let mut samples = [CaptureSample::default(); CAPTURE_CHUNK_SAMPLES];
        let mut count = 0u8;
        let first = command.capture_read as usize;
        for (k, slot) in samples.iter_mut().enumerate() {
            match capture.sample(first.saturating_add(k)) {
                Some(s) => {
                    *slot = *s;
                    count += 1;
                }
                None => break,
            }
        }
        return BoardAnswer::Chunk(CaptureChunk {
            sequence: command.sequence,
            first: command.capture_read,
            count,
            format: capture.format(),
            samples,
        });
    }
    BoardAnswer::Telemetry(BoardTelemetry {
        sequence: command.sequence,
        state_code: status.state.code(),
        fault_bits: status.faults.bits(),
        bridge_enabled: status.bridge_enabled,
        estimate: status.estimate,
        i_ab_a: status.i_ab_a,
        vdc_v: status.vdc_v,
        speed_ref: setpoints.speed_m_per_s(),
        capture: capture.state(),
        capture_len: capture.len() as u32,
        capture_capacity: capture.capacity() as u32,
        periods: status.periods,
        position: status.position,
    })
}

/// The command watchdog's clocks at one instant (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LinkClock {
    /// Control periods run (wrapping): the drive's own time.
    pub periods: u32,
    /// The host's milliseconds (wrapping) where the drive's time is not the host's (QEMU);
    /// `None` on a board, or when the host's clock could not be read.
    pub host_ms: Option<u32>,
}

impl LinkClock {
    /// The drive's periods alone (a board: they run in real time).
    pub const fn periods(periods: u32) -> Self {
        LinkClock { periods, host_ms: None }
    }
}

/// The thread's side: decodes commands, applies them to the setpoints, keeps the
/// command watchdog (on the clocks of [`LinkClock`]: see the module docs).
#[derive(Clone, Debug)]
pub struct BoardLinkServer {
    rx: Receiver<BoardCommand>,
    /// The clocks at the last command.
    last_command_at: LinkClock,
    timeout_periods: u32,
    /// The host's silence that must pass too (ms), `None`: periods alone.
    timeout_host_ms: Option<u32>,
    /// Sequence number of the last command whose move was posted: the host resends a
    /// command it got no answer to with the same number, and its move must not be
    /// queued twice.
    last_move_sequence: Option<u16>,
}

impl BoardLinkServer {
    /// A server whose watchdog disables the drive after `timeout_periods` control periods
    /// without a command (a board, whose periods run in real time).
    pub const fn new(timeout_periods: u32) -> Self {
        BoardLinkServer {
            rx: Receiver::new(),
            last_command_at: LinkClock::periods(0),
            timeout_periods,
            timeout_host_ms: None,
            last_move_sequence: None,
        }
    }

    /// A server whose watchdog disables the drive after `timeout_periods` control periods
    /// *and* `timeout_host_ms` of the host's time without a command (QEMU, where the
    /// drive's time follows the instructions executed). A [`LinkClock`] without the host's
    /// time counts as that time having passed.
    pub const fn with_host_clock(timeout_periods: u32, timeout_host_ms: u32) -> Self {
        BoardLinkServer { timeout_host_ms: Some(timeout_host_ms), ..Self::new(timeout_periods) }
    }

    /// One received byte; a complete valid command is applied to `setpoints` (clear
    /// faults, enable, speed; its move posted with [`Setpoints::post_move`] unless the
    /// same sequence number's move was posted already: a resent command) and returned,
    /// for the caller to [`answer`]. `now` is the watchdog's clocks.
    pub fn on_byte(&mut self, byte: u8, setpoints: &Setpoints, now: LinkClock) -> Option<BoardCommand> {
        let command = self.rx.push(byte)?.ok()?;
        setpoints.set_commands(&command.commands());
        if let Some(m) = command.move_to
            && self.last_move_sequence != Some(command.sequence)
        {
            self.last_move_sequence = Some(command.sequence);
            setpoints.post_move(m);
        }
        self.last_command_at = now;
        Some(command)
    }

    /// The command watchdog at `now`: with no command for more than the timeout (in
    /// periods, and in the host's time where it has one), disables the drive (bridge off)
    /// and returns `true`. A host that comes back enables it again with its next command.
    /// Call it after the bytes that have arrived are taken: a command that waited in the
    /// UART while the thread did not run is a host that was not silent.
    pub fn watchdog(&mut self, setpoints: &Setpoints, now: LinkClock) -> bool {
        let periods_silent = now.periods.wrapping_sub(self.last_command_at.periods) > self.timeout_periods;
        let host_silent = match (self.timeout_host_ms, now.host_ms, self.last_command_at.host_ms) {
            (None, _, _) => true,
            (Some(limit), Some(now_ms), Some(then_ms)) => now_ms.wrapping_sub(then_ms) > limit,
            // A host clock that cannot be read: no evidence the host was not silent.
            (Some(_), _, _) => true,
        };
        let silent = periods_silent && host_silent;
        if silent {
            setpoints.set_enable(false);
        }
        silent
    }

    /// Frames dropped (malformed, bad CRC).
    pub fn stats(&self) -> LinkStats {
        self.rx.stats()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::board::virtual_motor::VirtualBoard;
    use crate::control::ControlLoop;
    use dcfo::algorithms::observer::ObserverKind;
    use dcfo::drive::{Drive, DriveConfig, PAPER_AXIS_PAYLOAD_KG};
    use dcfo::link::encode;
    use dcfo::motor::MotorParams;
    use dcfo::plant::{VirtualAxis, VirtualMotor};

    const BUS_V: f32 = 311.0;

    fn command(sequence: u16, enable: bool, arm: bool, read: u32) -> BoardCommand {
        BoardCommand {
            sequence,
            speed_ref: 0.3,
            enable,
            clear_faults: false,
            arm_capture: arm,
            capture_read: read,
            move_to: None,
        }
    }

    fn feed(
        server: &mut BoardLinkServer,
        c: &BoardCommand,
        sp: &Setpoints,
        periods: u32,
    ) -> Option<BoardCommand> {
        let mut wire = [0u8; BoardCommand::WIRE_LEN];
        let n = encode(c, &mut wire).unwrap();
        wire[..n].iter().filter_map(|&b| server.on_byte(b, sp, LinkClock::periods(periods))).last()
    }

    /// The drive image on the virtual motor, commanded as `dcfo board` does: armed and
    /// enabled at 0.3 m/s, it reaches `Running`, the capture fills from the estimator's
    /// start, and reading it back chunk by chunk gives every sample once; telemetry
    /// reports the state; silence disables the drive.
    #[test]
    fn commands_run_the_virtual_motor_and_the_capture_reads_back() {
        let motor = MotorParams::paper();
        let mut config = DriveConfig::for_motor(&motor, BUS_V, ObserverKind::Dcfo);
        config.moving_mass_kg = motor.mass_kg + PAPER_AXIS_PAYLOAD_KG;
        let drive = Drive::<f32>::new(&motor, &config, &Base::SI).unwrap();
        let axis = VirtualAxis {
            payload_kg: PAPER_AXIS_PAYLOAD_KG,
            load_n: 0.0,
            bus_v: BUS_V,
            period_s: config.control_period_s,
        };
        let mut board = VirtualBoard::new(VirtualMotor::new(&motor, &axis).unwrap());
        let mut control = ControlLoop::new(drive, 1);
        let mut capture = Capture::<2000>::new();
        let mut status = DriveStatus::new();
        let sp = Setpoints::new();
        let mut server = BoardLinkServer::new(5000);
        let c = feed(&mut server, &command(1, true, true, NO_CAPTURE_READ), &sp, 0).unwrap();
        assert!(
            matches!(answer(&c, &mut capture, &status, &sp), BoardAnswer::Telemetry(t) if t.capture == CaptureState::Armed)
        );
        let mut running_at = None;
        for k in 0..40_000u32 {
            let (out, sample) = control.period(&mut board, &sp);
            capture.record(&out);
            status.update(&out, &sample, control.base(), control.position_report(&sp));
            if k % 1000 == 0 {
                assert!(
                    feed(
                        &mut server,
                        &command(2 + (k / 1000) as u16, true, false, NO_CAPTURE_READ),
                        &sp,
                        status.periods
                    )
                    .is_some()
                );
            }
            if out.state == DriveState::Running && running_at.is_none() {
                running_at = Some(k);
            }
        }
        let running_at = running_at.expect("the drive reaches Running on the virtual motor");
        assert_eq!(status.state, DriveState::Running, "faults {:?}", status.faults);
        let v = board.motor().state().v_m_per_s;
        assert!(
            (v - 0.3).abs() < 0.03,
            "the mover runs at the reference: {v} m/s (Running from step {running_at})"
        );
        assert_eq!((capture.state(), capture.len()), (CaptureState::Done, 2000));
        // Read it back as the host does.
        let mut read = 0usize;
        while read < 2000 {
            let c = command(100, true, false, read as u32);
            match answer(&c, &mut capture, &status, &sp) {
                BoardAnswer::Chunk(chunk) => {
                    assert_eq!(chunk.first as usize, read);
                    for (k, s) in chunk.valid().iter().enumerate() {
                        assert_eq!(Some(s), capture.sample(read + k));
                    }
                    assert!(chunk.count > 0);
                    read += usize::from(chunk.count);
                }
                BoardAnswer::Telemetry(t) => panic!("telemetry instead of samples: {t:?}"),
            }
        }
        assert_eq!(read, 2000);
        let past = answer(&command(101, true, false, 2000), &mut capture, &status, &sp);
        assert!(matches!(past, BoardAnswer::Chunk(c) if c.count == 0));
        // Silence: the watchdog disables the drive.
        let now = status.periods;
        assert!(!server.watchdog(&sp, LinkClock::periods(now)));
        assert!(server.watchdog(&sp, LinkClock::periods(now.wrapping_add(5001))));
        for _ in 0..2 {
            let (out, sample) = control.period(&mut board, &sp);
            status.update(&out, &sample, control.base(), control.position_report(&sp));
        }
        assert_eq!(status.state, DriveState::Disabled);
    }

    /// A positioning drive (`DriveConfig::stroke_axis`) on the virtual motor, operated
    /// as `dcfo board --move-to` does: a move in one command reaches the control
    /// interrupt through the mailbox, the position report follows it to the target
    /// (within tau / 20 = 0.75 mm), a resent command (same sequence) does not queue it
    /// twice, and a target outside the stroke is refused and counted.
    #[test]
    fn a_move_in_a_command_reaches_its_target_and_a_refused_one_is_counted() {
        let motor = MotorParams::paper();
        let mut config = DriveConfig::stroke_axis(&motor, BUS_V);
        config.dead_time_compensation = None;
        let drive = Drive::<f32>::new(&motor, &config, &Base::SI).unwrap();
        let axis = VirtualAxis {
            payload_kg: PAPER_AXIS_PAYLOAD_KG,
            load_n: 0.0,
            bus_v: BUS_V,
            period_s: config.control_period_s,
        };
        let mut board = VirtualBoard::new(VirtualMotor::new(&motor, &axis).unwrap());
        let mut control = ControlLoop::new(drive, 1);
        let mut capture = Capture::<16>::new();
        let mut status = DriveStatus::new();
        let sp = Setpoints::new();
        let mut server = BoardLinkServer::new(u32::MAX);
        let target = 0.03;
        let go = BoardCommand {
            speed_ref: 0.0,
            move_to: Some(dcfo::algorithms::motion::Move { target_m: target, dwell_s: 0.0 }),
            ..command(1, true, false, NO_CAPTURE_READ)
        };
        // Sent twice with one sequence number (a resend): one move.
        assert!(feed(&mut server, &go, &sp, 0).is_some());
        assert!(feed(&mut server, &go, &sp, 0).is_some());
        let (out, sample) = control.period(&mut board, &sp);
        status.update(&out, &sample, control.base(), control.position_report(&sp));
        let p = status.position.expect("a positioning drive reports its position");
        // Queued once (the profile holds it while the drive aligns).
        assert_eq!((p.moves_queued, p.moves_rejected), (1, 0), "{p:?}");
        let mut idle_at = None;
        for k in 0..30_000u32 {
            let (out, sample) = control.period(&mut board, &sp);
            status.update(&out, &sample, control.base(), control.position_report(&sp));
            if status.position.is_some_and(|p| p.idle) && idle_at.is_none() && k > 10 {
                idle_at = Some(k);
            }
        }
        assert_eq!(status.faults, Faults::NONE);
        let p = status.position.unwrap();
        let tol = motor.pole_pitch_m / 20.0;
        assert!(p.idle && p.x_ref_m == target, "{p:?}");
        assert!((p.x_hat_m - target).abs() < tol, "x_hat {} m, target {target} m", p.x_hat_m);
        let x = board.motor().state().x_m;
        assert!((x - target).abs() < tol, "the mover at {x} m, target {target} m (idle from {idle_at:?})");
        // Outside the stroke: refused by the drive, counted, reported.
        let far = BoardCommand {
            move_to: Some(dcfo::algorithms::motion::Move { target_m: 10.0, dwell_s: 0.0 }),
            ..command(2, true, false, NO_CAPTURE_READ)
        };
        let c = feed(&mut server, &far, &sp, status.periods).unwrap();
        let (out, sample) = control.period(&mut board, &sp);
        status.update(&out, &sample, control.base(), control.position_report(&sp));
        match answer(&c, &mut capture, &status, &sp) {
            BoardAnswer::Telemetry(t) => assert_eq!(t.position.map(|p| p.moves_rejected), Some(1)),
            a => panic!("{a:?}"),
        }
        // A full mailbox (two moves before a control period) is a counted refusal too.
        for seq in [3, 4] {
            let m = BoardCommand {
                move_to: Some(dcfo::algorithms::motion::Move { target_m: 0.0, dwell_s: 0.0 }),
                ..command(seq, true, false, NO_CAPTURE_READ)
            };
            feed(&mut server, &m, &sp, status.periods).unwrap();
        }
        assert_eq!(sp.moves_rejected(), 2);
    }

    /// With the host's clock (QEMU): a silence must last 5,000 of the drive's periods and
    /// 500 ms of the host's time. Periods alone (QEMU ran ahead of a slow host), host time
    /// alone (QEMU descheduled, or the machine stalled QEMU and host together) do not
    /// disable the drive; both do; a clock that cannot be read counts as time passed.
    #[test]
    fn with_the_hosts_clock_a_silence_must_last_in_both_clocks() {
        let sp = Setpoints::new();
        let mut server = BoardLinkServer::with_host_clock(5000, 500);
        let at = |periods, ms| LinkClock { periods, host_ms: Some(ms) };
        let c = command(1, true, false, NO_CAPTURE_READ);
        let mut wire = [0u8; BoardCommand::WIRE_LEN];
        let n = encode(&c, &mut wire).unwrap();
        assert!(wire[..n].iter().filter_map(|&b| server.on_byte(b, &sp, at(100, 10_000))).last().is_some());
        assert!(sp.take_commands().enable);
        assert!(!server.watchdog(&sp, at(100 + 50_000, 10_000 + 400)), "periods alone");
        assert!(!server.watchdog(&sp, at(100 + 4000, 10_000 + 60_000)), "host time alone");
        assert!(sp.take_commands().enable);
        assert!(server.watchdog(&sp, at(100 + 5001, 10_000 + 501)), "both");
        assert!(!sp.take_commands().enable);
        let mut server = BoardLinkServer::with_host_clock(5000, 500);
        assert!(server.watchdog(&sp, LinkClock::periods(5001)), "no host clock: time passed");
    }
}
