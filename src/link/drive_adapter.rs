//! The drive adapter: the only part of the link that knows the drive. It maps frames to
//! the drive's [`Commands`] and [`Measurements`], a step's output to an
//! [`ActuationFrame`], the frames' state codes and fault bits to [`DriveState`] and
//! [`Faults`] (with the drive's own conversions), and runs the controller side of the
//! lock-step link ([`LinkServer`]).

use super::board::{BoardCommand, BoardTelemetry};
use super::codec::{Receiver, encode};
use super::frame::{ActuationFrame, EstimateReport, PositionReport, STATE_CODES, SensorFrame};
use super::session::{LinkStats, LinkWatchdog, SequenceOrder, SequenceTracker};
use crate::drive::{Commands, Drive, DriveState, Faults, Measurements, StepOutput};
use crate::motion::MotionError;
use crate::num::Scalar;
use crate::units::Base;

// The frames' state codes are exactly the drive's.
const _: () = assert!(DriveState::ALL.len() == STATE_CODES as usize);

/// The drive state of `code`; a code no state has (never in a decoded frame: the
/// decoder refuses it, and the encoder does not send it) reads as [`DriveState::Fault`].
fn state_of(code: u8) -> DriveState {
    DriveState::from_code(code).unwrap_or(DriveState::Fault)
}

impl SensorFrame {
    /// The frame's commands for the drive ([`Drive::apply`]): enable, clear faults and
    /// the speed reference (m/s).
    pub fn commands(&self) -> Commands {
        Commands { enable: self.enable, clear_faults: self.clear_faults, speed_ref_m_per_s: self.speed_ref }
    }

    /// The measurements for [`Drive::step`], in the working units of `base`.
    pub fn measurements<T: Scalar>(&self, base: &Base) -> Measurements<T> {
        Measurements::from_si([self.i_a, self.i_b, self.i_c], self.vdc, base)
    }

    /// Applies the frame's [`commands`](Self::commands) to `drive` ([`Drive::apply`]),
    /// then queues its move, if it carries one ([`Drive::push_move`]). `Err` when the
    /// move was refused (queue full, target outside the stroke, a speed drive): the
    /// commands are applied all the same, and the caller counts the refusal
    /// ([`PositionReport::moves_rejected`]).
    pub fn apply_commands<T: Scalar>(&self, drive: &mut Drive<T>) -> Result<(), MotionError> {
        drive.apply(&self.commands());
        match self.move_to {
            Some(m) => drive.push_move(m),
            None => Ok(()),
        }
    }
}

impl PositionReport {
    /// The report of a positioning `drive` (`None` for a speed drive): its position
    /// estimate, the profile's reference, its queue, and `moves_rejected`, the caller's
    /// count of refused moves. The queue length saturates at 255.
    pub fn of<T: Scalar>(drive: &Drive<T>, moves_rejected: u16) -> Option<Self> {
        let setpoint = drive.setpoint()?;
        Some(PositionReport {
            x_hat_m: drive.position_m(),
            x_ref_m: setpoint.position_m,
            v_ref_m_per_s: setpoint.speed_m_per_s,
            moves_queued: u8::try_from(drive.moves_queued().unwrap_or(0)).unwrap_or(u8::MAX),
            idle: drive.motion_idle(),
            moves_rejected,
        })
        .filter(PositionReport::is_finite)
    }
}

impl ActuationFrame {
    /// The answer to sensor frame `sequence` from one step's output `out`, computed in
    /// the working units of `base`. An estimate with a non-finite value is sent as
    /// `None`; duties are clamped to `[0, 1]` (a non-finite duty becomes 1/2).
    pub fn from_step<T: Scalar>(sequence: u16, out: &StepOutput<T>, base: &Base, stats: LinkStats) -> Self {
        let duty = |d: T| {
            let d = d.to_f32();
            if d.is_finite() { d.clamp(0.0, 1.0) } else { 0.5 }
        };
        let estimate = out
            .estimate
            .map(|e| EstimateReport {
                theta_hat: e.theta_e.to_radians::<f32>(),
                speed: e.speed_m_per_s.to_f32(),
                psi_alpha: base.to_webers(e.psi_ab.alpha),
                psi_beta: base.to_webers(e.psi_ab.beta),
            })
            .filter(EstimateReport::is_finite);
        ActuationFrame {
            sequence,
            duty_a: duty(out.duties.a),
            duty_b: duty(out.duties.b),
            duty_c: duty(out.duties.c),
            bridge_enabled: out.bridge_enabled,
            state_code: out.state.code(),
            fault_bits: out.faults.bits(),
            estimate,
            stats,
            position: None,
        }
    }

    /// The drive's state ([`DriveState::from_code`] of
    /// [`state_code`](Self::state_code); an unknown code reads as `Fault`).
    pub fn state(&self) -> DriveState {
        state_of(self.state_code)
    }

    /// The latched faults ([`Faults::from_bits`] of [`fault_bits`](Self::fault_bits)).
    pub fn faults(&self) -> Faults {
        Faults::from_bits(self.fault_bits)
    }
}

impl BoardCommand {
    /// The command's drive commands ([`Drive::apply`]): enable, clear faults and the
    /// speed reference (m/s).
    pub fn commands(&self) -> Commands {
        Commands { enable: self.enable, clear_faults: self.clear_faults, speed_ref_m_per_s: self.speed_ref }
    }
}

impl BoardTelemetry {
    /// The drive's state ([`DriveState::from_code`] of
    /// [`state_code`](Self::state_code); an unknown code reads as `Fault`).
    pub fn state(&self) -> DriveState {
        state_of(self.state_code)
    }

    /// The latched faults ([`Faults::from_bits`] of [`fault_bits`](Self::fault_bits)).
    pub fn faults(&self) -> Faults {
        Faults::from_bits(self.fault_bits)
    }
}

/// The controller side of the lock-step link: fed one received byte at a time, it
/// decodes sensor frames, keeps the sequence and the statistics, runs one control step
/// of the drive per in-order frame and encodes the answer. The firmware calls it from
/// its UART receive path; host tests call it from a fake firmware, so both run one code
/// path.
#[derive(Clone, Debug)]
pub struct LinkServer {
    rx: Receiver<SensorFrame>,
    sequence: SequenceTracker,
    watchdog: LinkWatchdog,
    /// The last answer sent (wire bytes) and its length: sent again for a duplicate of
    /// the frame it answered, whose answer the host may have lost.
    last_reply: [u8; ActuationFrame::WIRE_LEN],
    last_reply_len: usize,
    /// Moves refused by the drive (sent in the answers' [`PositionReport`]), wrapping.
    moves_rejected: u16,
}

impl Default for LinkServer {
    fn default() -> Self {
        Self::new()
    }
}

impl LinkServer {
    /// A server with an empty receiver, no sequence history and the default watchdog
    /// ([`SILENT_LINK_PERIODS`](super::SILENT_LINK_PERIODS)).
    pub fn new() -> Self {
        LinkServer {
            rx: Receiver::new(),
            sequence: SequenceTracker::new(),
            watchdog: LinkWatchdog::default(),
            last_reply: [0; ActuationFrame::WIRE_LEN],
            last_reply_len: 0,
            moves_rejected: 0,
        }
    }

    /// Feeds one received byte. When it completes an in-order sensor frame, applies its
    /// commands and queues its move ([`SensorFrame::apply_commands`]; a refused move is
    /// counted, never acted on), runs `drive.step`, encodes the actuation frame into `out` and returns
    /// its length in bytes. A duplicate of the last accepted frame is not acted on but
    /// answered again with the same bytes (its answer may have been lost: a host that
    /// resends an unanswered frame then gets it, and the drive still steps once). Otherwise
    /// `None` (partial, rejected or out-of-order frames are counted, never acted on).
    /// `base` is the drive's working-unit base.
    pub fn on_byte<T: Scalar>(
        &mut self,
        byte: u8,
        drive: &mut Drive<T>,
        base: &Base,
        out: &mut [u8; ActuationFrame::WIRE_LEN],
    ) -> Option<usize> {
        let frame = match self.rx.push(byte)? {
            Ok(frame) => frame,
            Err(_) => return None,
        };
        match self.sequence.check(frame.sequence) {
            SequenceOrder::InOrder { .. } => {}
            SequenceOrder::Duplicate if self.last_reply_len > 0 => {
                self.rx.stats_mut().record_out_of_order();
                *out = self.last_reply;
                return Some(self.last_reply_len);
            }
            _ => {
                self.rx.stats_mut().record_out_of_order();
                return None;
            }
        }
        self.watchdog.period(true);
        if frame.apply_commands(drive).is_err() {
            self.moves_rejected = self.moves_rejected.wrapping_add(1);
        }
        let step = drive.step(&frame.measurements(base));
        let mut reply = ActuationFrame::from_step(frame.sequence, &step, base, self.rx.stats());
        reply.position = PositionReport::of(drive, self.moves_rejected);
        let n = encode(&reply, out).ok()?;
        self.last_reply = *out;
        self.last_reply_len = n;
        Some(n)
    }

    /// One watchdog period (call from a periodic interrupt; frames accepted in between
    /// restart the count). After [`SILENT_LINK_PERIODS`](super::SILENT_LINK_PERIODS) periods in a row without an
    /// accepted frame it forgets the sequence, so that a restarted host is accepted, and
    /// — if the drive is active (calibrating, starting or running) — trips it with
    /// [`Faults::EXTERNAL`], bridge off. A disabled or faulted drive already has its
    /// bridge off and is left as it is, so a host that connects late finds the drive
    /// ready. Returns `true` while the link is silent past the limit.
    pub fn silent_period<T: Scalar>(&mut self, drive: &mut Drive<T>) -> bool {
        let tripped = self.watchdog.period(false);
        if tripped {
            if !matches!(drive.state(), DriveState::Disabled | DriveState::Fault) {
                drive.trip(Faults::EXTERNAL);
            }
            self.sequence.reset();
            self.last_reply_len = 0;
        }
        tripped
    }

    /// The link statistics so far.
    pub fn stats(&self) -> LinkStats {
        self.rx.stats()
    }

    /// Moves the drive refused so far (wrapping at 65 536).
    pub fn moves_rejected(&self) -> u16 {
        self.moves_rejected
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::{DriveConfig, MOVE_QUEUE, PAPER_AXIS_BUS_V};
    use crate::motion::Move;
    use crate::motor::MotorParams;

    /// Sends `frame` to `server` and decodes the answer.
    fn exchange<T: Scalar>(
        server: &mut LinkServer,
        drive: &mut Drive<T>,
        frame: &SensorFrame,
    ) -> ActuationFrame {
        let mut wire = [0u8; SensorFrame::WIRE_LEN];
        let n = encode(frame, &mut wire).unwrap_or(0);
        let mut out = [0u8; ActuationFrame::WIRE_LEN];
        let mut answer = None;
        for &b in &wire[..n] {
            if let Some(len) = server.on_byte(b, drive, &Base::SI, &mut out) {
                answer = Some(len);
            }
        }
        let len = answer.expect("an answer");
        super::super::codec::decode_in_place::<ActuationFrame>(&mut out[..len - 1]).expect("decodes")
    }

    #[test]
    fn moves_are_queued_and_a_full_queue_is_a_counted_refusal() {
        let m = MotorParams::paper();
        let mut drive = Drive::<f32>::new(&m, &DriveConfig::stroke_axis(&m, PAPER_AXIS_BUS_V), &Base::SI)
            .expect("stroke drive");
        let mut server = LinkServer::new();
        let frame = |k: u16, move_to| SensorFrame {
            sequence: k,
            i_a: 0.0,
            i_b: 0.0,
            i_c: 0.0,
            vdc: PAPER_AXIS_BUS_V,
            speed_ref: 0.0,
            enable: true,
            clear_faults: false,
            move_to,
        };
        // No move: an idle positioning drive at 0 m (enabled: calibrating).
        let a = exchange(&mut server, &mut drive, &frame(0, None));
        let p = a.position.expect("a positioning drive reports its position");
        assert_eq!((p.x_hat_m, p.moves_queued, p.idle, p.moves_rejected), (0.0, 0, true, 0));
        // Enabled, the drive calibrates its current sensors first: no move starts. The
        // queue takes MOVE_QUEUE moves, then refuses the next, counted, the queue kept.
        let mv = Move { target_m: 0.1, dwell_s: 0.0 };
        let mut seen = [(0u8, false, 0u16); MOVE_QUEUE + 1];
        for (k, s) in (1..).zip(seen.iter_mut()) {
            let p = exchange(&mut server, &mut drive, &frame(k, Some(mv))).position.expect("position");
            *s = (p.moves_queued, p.idle, p.moves_rejected);
        }
        let mut expected = [(0u8, false, 0u16); MOVE_QUEUE + 1];
        for (k, e) in (1u8..).zip(expected.iter_mut()) {
            *e = (k.min(MOVE_QUEUE as u8), false, u16::from(k > MOVE_QUEUE as u8));
        }
        assert_eq!(seen, expected);
        let k = MOVE_QUEUE as u16 + 2;
        // A target outside the stroke is refused too, and counted.
        let far = Move { target_m: 1.0, dwell_s: 0.0 };
        let p = exchange(&mut server, &mut drive, &frame(k, Some(far))).position.expect("position");
        assert_eq!((usize::from(p.moves_queued), p.moves_rejected), (MOVE_QUEUE, 2));
        assert_eq!(server.moves_rejected(), 2);

        // A speed drive reports no position, and refuses every move.
        let mut speed =
            Drive::<f32>::new(&m, &DriveConfig::paper_axis(crate::observer::ObserverKind::Dcfo), &Base::SI)
                .expect("speed drive");
        let mut server = LinkServer::new();
        let a = exchange(&mut server, &mut speed, &frame(0, Some(mv)));
        assert_eq!(a.position, None);
        assert_eq!(server.moves_rejected(), 1);
    }

    #[test]
    fn the_frames_state_codes_are_the_drives() {
        for code in 0..=u8::MAX {
            assert_eq!(
                DriveState::from_code(code).is_some(),
                super::super::frame::state_code_ok(code),
                "{code}"
            );
        }
        for s in DriveState::ALL {
            assert_eq!(state_of(s.code()), s);
        }
    }
}
