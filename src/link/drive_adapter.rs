//! The drive adapter: the only part of the link that knows the drive. It maps frames to
//! the drive's [`Commands`] and [`Measurements`], a step's output to an
//! [`ActuationFrame`], the frames' state codes and fault bits to [`DriveState`] and
//! [`Faults`] (with the drive's own conversions), and runs the controller side of the
//! lock-step link ([`LinkServer`]).

use super::board::{BoardCommand, BoardTelemetry};
use super::codec::{Receiver, decode_raw, encode};
use super::frame::{
    ActuationFrame, COMMISSIONING_ERROR_CODES, CommissioningReport, CommissioningRequest,
    CommissioningStatus, EstimateReport, PositionReport, STATE_CODES, SensorFrame,
};
use super::session::{LinkStats, LinkWatchdog, SequenceOrder, SequenceTracker};
use super::wire::LinkError;
use crate::algorithms::motion::MotionError;
use crate::drive::{Commands, CommissioningError, Drive, DriveState, Faults, Measurements, StepOutput};
use crate::num::Scalar;
use crate::num::units::Base;

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

/// The report code of a commissioning error (`1..=`[`COMMISSIONING_ERROR_CODES`]) and
/// its detail (the fault bits of [`CommissioningError::DriveFault`], else 0).
const fn error_code(e: CommissioningError) -> (u8, u16) {
    match e {
        CommissioningError::BadSetting(_) => (1, 0),
        CommissioningError::BusOutOfRange => (2, 0),
        CommissioningError::NonFinite => (3, 0),
        CommissioningError::OpenPhase => (4, 0),
        CommissioningError::ShortedPhase => (5, 0),
        CommissioningError::RunawayCurrent => (6, 0),
        CommissioningError::NoBackEmf => (7, 0),
        CommissioningError::NotAMotor => (8, 0),
        CommissioningError::DriveFault(bits) => (9, bits),
    }
}

/// The setting a [`CommissioningError::BadSetting`] received over the link names: the
/// link carries the error's code, not the setting's name.
pub const BAD_SETTING_OVER_THE_LINK: &str = "a setting (named on the controller only)";

impl CommissioningReport {
    /// The report on `drive`'s commissioning for request `sequence`; `refused`: the
    /// request's start was refused with this error.
    pub fn of<T: Scalar>(sequence: u16, drive: &Drive<T>, refused: Option<CommissioningError>) -> Self {
        let (status, error, result) = match (refused, drive.commissioning_result()) {
            (Some(e), _) => (CommissioningStatus::Refused, Some(e), None),
            (None, Some(Ok(r))) => (CommissioningStatus::Done, None, Some(r)),
            (None, Some(Err(e))) => (CommissioningStatus::Failed, Some(e), None),
            (None, None) if drive.commissioning_pending() => (CommissioningStatus::Running, None, None),
            (None, None) => (CommissioningStatus::Idle, None, None),
        };
        let (error_code, error_detail) = error.map_or((0, 0), error_code);
        CommissioningReport { sequence, status, error_code, error_detail, result }
    }

    /// Why commissioning failed or the start was refused ([`CommissioningStatus::Failed`],
    /// [`CommissioningStatus::Refused`]); `None` otherwise. A `BadSetting` names
    /// [`BAD_SETTING_OVER_THE_LINK`].
    pub fn error(&self) -> Option<CommissioningError> {
        if !self.status.has_error() {
            return None;
        }
        Some(match self.error_code {
            1 => CommissioningError::BadSetting(BAD_SETTING_OVER_THE_LINK),
            2 => CommissioningError::BusOutOfRange,
            3 => CommissioningError::NonFinite,
            4 => CommissioningError::OpenPhase,
            5 => CommissioningError::ShortedPhase,
            6 => CommissioningError::RunawayCurrent,
            7 => CommissioningError::NoBackEmf,
            8 => CommissioningError::NotAMotor,
            _ => CommissioningError::DriveFault(self.error_detail),
        })
    }
}

const _: () = assert!(error_code(CommissioningError::DriveFault(0)).0 == COMMISSIONING_ERROR_CODES);

/// A frame the controller receives.
enum Incoming {
    Sensor(SensorFrame),
    Request(CommissioningRequest),
}

/// The larger of two lengths (for a `const`).
const fn max_len(a: usize, b: usize) -> usize {
    if a > b { a } else { b }
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
    /// The last answer to a sensor frame (wire bytes) and its length: sent again for a
    /// duplicate of the frame it answered, whose answer the host may have lost.
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
    /// Bytes of the answer buffer [`on_byte`](Self::on_byte) writes: the longer of the
    /// [`ActuationFrame`] and the [`CommissioningReport`] on the wire.
    pub const REPLY_LEN: usize = max_len(ActuationFrame::WIRE_LEN, CommissioningReport::WIRE_LEN);

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
    /// counted, never acted on), runs `drive.step_after_missed` with the periods whose
    /// frames were lost since the last accepted one (the sequence numbers skipped: the
    /// plant ran them on the last answered duties), encodes the actuation frame into `out`
    /// and returns its length in bytes. A duplicate of the last accepted frame is not acted on but
    /// answered again with the same bytes (its answer may have been lost: a host that
    /// resends an unanswered frame then gets it, and the drive still steps once). Otherwise
    /// `None` (partial, rejected or out-of-order frames are counted, never acted on).
    /// `base` is the drive's working-unit base.
    ///
    /// A [`CommissioningRequest`] (told apart by its length) is answered with a
    /// [`CommissioningReport`] and never steps the drive. A start request is taken only
    /// from a disabled drive (else the report says `Refused`): the drive is replaced by
    /// the one commissioning is told about ([`Drive::for_commissioning`]: the ratings,
    /// bus and pole pitch of the request, nothing of the image's motor; its base is SI
    /// if `base` is, else the per-unit base of the told ratings), and the sensor frames'
    /// sequence starts anew. Building the drive is bounded work outside any control
    /// period (the drive is disabled). Read the new drive's base back with
    /// [`Drive::base`] for the next call.
    pub fn on_byte<T: Scalar>(
        &mut self,
        byte: u8,
        drive: &mut Drive<T>,
        base: &Base,
        out: &mut [u8; Self::REPLY_LEN],
    ) -> Option<usize> {
        let raw = match self.rx.push_raw(byte)? {
            Ok(raw) => raw,
            Err(_) => return None,
        };
        let decoded = if raw.len() == CommissioningRequest::RAW_LEN {
            decode_raw::<CommissioningRequest>(raw).map(Incoming::Request)
        } else {
            decode_raw::<SensorFrame>(raw).map(Incoming::Sensor)
        };
        let frame = match decoded {
            Ok(Incoming::Sensor(frame)) => frame,
            Ok(Incoming::Request(request)) => return self.on_request(&request, drive, base, out),
            Err(e) => {
                self.rx.stats_mut().record(e);
                return None;
            }
        };
        let skipped = match self.sequence.check(frame.sequence) {
            SequenceOrder::InOrder { skipped } => skipped,
            SequenceOrder::Duplicate if self.last_reply_len > 0 => {
                self.rx.stats_mut().record_out_of_order();
                out.iter_mut().zip(&self.last_reply).for_each(|(o, b)| *o = *b);
                return Some(self.last_reply_len);
            }
            _ => {
                self.rx.stats_mut().record_out_of_order();
                return None;
            }
        };
        // Sequence numbers the host skipped were periods without a frame reaching the
        // drive: a silent link of that many periods, tripped before the step as the
        // periodic tick would have tripped it during the silence. (An image without a
        // timer, the lock-step one on QEMU, has only this measure of a silence.)
        if self.watchdog.frame_after(skipped)
            && !matches!(drive.state(), DriveState::Disabled | DriveState::Fault)
        {
            drive.trip(Faults::EXTERNAL);
        }
        if frame.apply_commands(drive).is_err() {
            self.moves_rejected = self.moves_rejected.wrapping_add(1);
        }
        // Frames lost in between were periods the plant ran on the last answer's duties.
        let step = drive.step_after_missed(&frame.measurements(base), skipped);
        let mut reply = ActuationFrame::from_step(frame.sequence, &step, base, self.rx.stats());
        reply.position = PositionReport::of(drive, self.moves_rejected);
        let n = encode(&reply, &mut self.last_reply).ok()?;
        out.iter_mut().zip(&self.last_reply).for_each(|(o, b)| *o = *b);
        self.last_reply_len = n;
        Some(n)
    }

    /// A commissioning request: start (from a disabled drive) or query, then the report.
    /// Never inlined: building a drive takes about 10 KB of stack, which inlined into
    /// [`on_byte`](Self::on_byte) would sit above every control step's frames too.
    #[inline(never)]
    fn on_request<T: Scalar>(
        &mut self,
        request: &CommissioningRequest,
        drive: &mut Drive<T>,
        base: &Base,
        out: &mut [u8; Self::REPLY_LEN],
    ) -> Option<usize> {
        self.watchdog.period(true);
        let refused = match request.start {
            None => None,
            Some(_) if drive.state() != DriveState::Disabled => {
                Some(CommissioningError::BadSetting("drive state (not disabled)"))
            }
            Some(config) => match Drive::for_commissioning(config, base) {
                Ok(commissioning) => {
                    *drive = commissioning;
                    self.sequence.reset();
                    self.last_reply_len = 0;
                    None
                }
                Err(e) => Some(e),
            },
        };
        let report = CommissioningReport::of(request.sequence, drive, refused);
        match encode(&report, out) {
            Ok(n) => Some(n),
            Err(_) => {
                // Never for a report of the drive's own values (they are finite).
                self.rx.stats_mut().record(LinkError::Value);
                None
            }
        }
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
    use crate::algorithms::motion::Move;
    use crate::algorithms::observer::ObserverKind;
    use crate::drive::{DriveConfig, MOVE_QUEUE, PAPER_AXIS_BUS_V};
    use crate::motor::MotorParams;

    /// Sends `frame` to `server` and decodes the answer.
    fn exchange<T: Scalar>(
        server: &mut LinkServer,
        drive: &mut Drive<T>,
        frame: &SensorFrame,
    ) -> ActuationFrame {
        let mut wire = [0u8; SensorFrame::WIRE_LEN];
        let n = encode(frame, &mut wire).unwrap_or(0);
        let mut out = [0u8; LinkServer::REPLY_LEN];
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
        let mut speed = Drive::<f32>::new(&m, &DriveConfig::paper_axis(ObserverKind::Dcfo), &Base::SI)
            .expect("speed drive");
        let mut server = LinkServer::new();
        let a = exchange(&mut server, &mut speed, &frame(0, Some(mv)));
        assert_eq!(a.position, None);
        assert_eq!(server.moves_rejected(), 1);
    }

    /// A lock-step host numbers its frames by control period: a frame that skips 10
    /// numbers ends a silence of 10 periods, and an active drive trips (EXTERNAL, bridge
    /// off) before stepping on it, as a periodic tick would have tripped it; a gap of 9
    /// (lost frames) does not; a disabled drive is left alone; a tick and a skipped number
    /// stand for the same period, so the two do not add up.
    #[test]
    fn a_frame_that_skips_the_silent_link_limit_trips_an_active_drive_first() {
        let m = MotorParams::paper();
        let config = DriveConfig::paper_axis(ObserverKind::Dcfo);
        let frame = |k: u16, enable| SensorFrame {
            sequence: k,
            i_a: 0.0,
            i_b: 0.0,
            i_c: 0.0,
            vdc: PAPER_AXIS_BUS_V,
            speed_ref: 0.3,
            enable,
            clear_faults: false,
            move_to: None,
        };
        let limit = super::super::SILENT_LINK_PERIODS;
        let mut drive = Drive::<f32>::new(&m, &config, &Base::SI).expect("drive");
        let mut server = LinkServer::new();
        assert_eq!(exchange(&mut server, &mut drive, &frame(0, true)).state(), DriveState::Calibrating);
        // Nine numbers skipped: lost frames, not a silent link.
        let a = exchange(&mut server, &mut drive, &frame(limit, true));
        assert_eq!((a.state(), a.faults()), (DriveState::Calibrating, Faults::NONE));
        // Five ticks, then a frame five numbers on: five silent periods, not ten.
        for _ in 0..5 {
            assert!(!server.silent_period(&mut drive));
        }
        let a = exchange(&mut server, &mut drive, &frame(limit + 6, true));
        assert_eq!(a.faults(), Faults::NONE);
        // Ten skipped: tripped before the step, which reports it.
        let a = exchange(&mut server, &mut drive, &frame(2 * limit + 7, true));
        assert_eq!(a.state(), DriveState::Fault);
        assert!(a.faults().contains(Faults::EXTERNAL) && !a.bridge_enabled);
        // A disabled drive: a long gap changes nothing.
        let mut drive = Drive::<f32>::new(&m, &config, &Base::SI).expect("drive");
        let mut server = LinkServer::new();
        exchange(&mut server, &mut drive, &frame(0, false));
        let a = exchange(&mut server, &mut drive, &frame(1000, false));
        assert_eq!((a.state(), a.faults()), (DriveState::Disabled, Faults::NONE));
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

#[cfg(test)]
mod commissioning_tests {
    use super::*;
    use crate::algorithms::observer::ObserverKind;
    use crate::drive::{CommissioningConfig, CommissioningResult, DriveConfig, VoltageErrorPoint};
    use crate::link::{Frame, decode_in_place};
    use crate::motor::MotorParams;

    fn told() -> CommissioningConfig {
        CommissioningConfig { rated_current_a: 3.0, rated_voltage_v: 24.0, bus_v: 34.0, pole_pitch_m: 0.015 }
    }

    fn wire<F: Frame>(frame: &F) -> ([u8; 256], usize) {
        let mut buf = [0u8; 256];
        let n = encode(frame, &mut buf).unwrap();
        (buf, n)
    }

    fn decode<F: Frame>(bytes: &[u8]) -> Result<F, LinkError> {
        let mut b = [0u8; 256];
        b[..bytes.len() - 1].copy_from_slice(&bytes[..bytes.len() - 1]);
        decode_in_place::<F>(&mut b[..bytes.len() - 1])
    }

    fn result() -> CommissioningResult {
        let mut curve = [VoltageErrorPoint::default(); crate::drive::SWEEP_LEVELS];
        for (k, p) in curve.iter_mut().enumerate() {
            *p = VoltageErrorPoint { current_a: 4.0 / (k as f32 + 1.0), error_v: 0.5 - 0.01 * k as f32 };
        }
        CommissioningResult {
            rs_ohm: 0.41,
            ld_h: 1.2e-3,
            lq_h: 1.7e-3,
            psi_f_wb: 0.021,
            voltage_error_v: 0.37,
            current_band_a: 0.05,
            bus_v: 33.9,
            curve,
            direction: 1,
            duration_s: 4.1,
        }
    }

    #[test]
    fn requests_and_reports_round_trip_exactly() {
        for request in [
            CommissioningRequest { sequence: 7, start: Some(told()) },
            CommissioningRequest { sequence: 65535, start: None },
        ] {
            let (buf, n) = wire(&request);
            assert_eq!(n, CommissioningRequest::WIRE_LEN);
            assert_eq!(decode::<CommissioningRequest>(&buf[..n]), Ok(request));
        }
        let done = CommissioningReport {
            sequence: 3,
            status: CommissioningStatus::Done,
            error_code: 0,
            error_detail: 0,
            result: Some(result()),
        };
        let (buf, n) = wire(&done);
        assert_eq!(n, CommissioningReport::WIRE_LEN);
        let back = decode::<CommissioningReport>(&buf[..n]).unwrap();
        assert_eq!(back, done);
        // Bit for bit, not just equal as numbers.
        let (a, b) = (back.result.unwrap(), result());
        assert_eq!(a.rs_ohm.to_bits(), b.rs_ohm.to_bits());
        assert_eq!(a.curve[11].error_v.to_bits(), b.curve[11].error_v.to_bits());
        for e in [
            CommissioningError::BadSetting("x"),
            CommissioningError::BusOutOfRange,
            CommissioningError::NonFinite,
            CommissioningError::OpenPhase,
            CommissioningError::ShortedPhase,
            CommissioningError::RunawayCurrent,
            CommissioningError::NoBackEmf,
            CommissioningError::NotAMotor,
            CommissioningError::DriveFault(0x0123),
        ] {
            let (code, detail) = error_code(e);
            let failed = CommissioningReport {
                sequence: 1,
                status: CommissioningStatus::Failed,
                error_code: code,
                error_detail: detail,
                result: None,
            };
            let (buf, n) = wire(&failed);
            let back = decode::<CommissioningReport>(&buf[..n]).unwrap();
            let expected = if let CommissioningError::BadSetting(_) = e {
                CommissioningError::BadSetting(BAD_SETTING_OVER_THE_LINK)
            } else {
                e
            };
            assert_eq!(back.error(), Some(expected));
        }
    }

    #[test]
    fn inconsistent_reports_and_requests_are_neither_sent_nor_accepted() {
        let ok = CommissioningReport {
            sequence: 0,
            status: CommissioningStatus::Running,
            error_code: 0,
            error_detail: 0,
            result: None,
        };
        let mut buf = [0u8; 256];
        let bad = [
            CommissioningReport { error_code: 4, ..ok },
            CommissioningReport { status: CommissioningStatus::Failed, ..ok },
            CommissioningReport { status: CommissioningStatus::Failed, error_code: 10, ..ok },
            CommissioningReport { status: CommissioningStatus::Failed, error_code: 4, error_detail: 1, ..ok },
            CommissioningReport { status: CommissioningStatus::Done, ..ok },
            CommissioningReport { result: Some(result()), ..ok },
            CommissioningReport {
                status: CommissioningStatus::Done,
                result: Some(CommissioningResult { ld_h: f32::NAN, ..result() }),
                ..ok
            },
        ];
        for r in bad {
            assert_eq!(encode(&r, &mut buf), Err(crate::link::EncodeError::InvalidValue), "{r:?}");
        }
        let nan = CommissioningRequest {
            sequence: 0,
            start: Some(CommissioningConfig { bus_v: f32::INFINITY, ..told() }),
        };
        assert_eq!(encode(&nan, &mut buf), Err(crate::link::EncodeError::InvalidValue));
        // Raw payloads a careless sender might produce, CRC set right: refused by value.
        let raw = |payload: &[u8]| {
            let mut raw = payload.to_vec();
            raw.extend_from_slice(&crate::num::checksum::crc16(payload).to_le_bytes());
            raw
        };
        let mut report = [0u8; CommissioningReport::PAYLOAD_LEN];
        report[0] = crate::link::PROTOCOL_VERSION;
        assert!(decode_raw::<CommissioningReport>(&raw(&report)).is_ok());
        report[3] = 5; // unknown status
        assert_eq!(decode_raw::<CommissioningReport>(&raw(&report)), Err(LinkError::Value));
        report[3] = 0;
        report[20] = 1; // result bytes without a result
        assert_eq!(decode_raw::<CommissioningReport>(&raw(&report)), Err(LinkError::Value));
        let mut request = [0u8; CommissioningRequest::PAYLOAD_LEN];
        request[0] = crate::link::PROTOCOL_VERSION;
        assert_eq!(decode_raw::<CommissioningRequest>(&raw(&request)).map(|r| r.start), Ok(None));
        request[3] = 2; // unknown action
        assert_eq!(decode_raw::<CommissioningRequest>(&raw(&request)), Err(LinkError::Flags));
        request[3] = 0;
        request[5] = 1; // a query with values
        assert_eq!(decode_raw::<CommissioningRequest>(&raw(&request)), Err(LinkError::Value));
        request[0] = 1; // version 1 knew no commissioning
        assert_eq!(decode_raw::<CommissioningRequest>(&raw(&request)), Err(LinkError::Version));
    }

    /// Feeds `bytes` to the server; the answers' lengths.
    fn feed<T: Scalar>(
        server: &mut LinkServer,
        drive: &mut Drive<T>,
        bytes: &[u8],
        out: &mut [u8; LinkServer::REPLY_LEN],
    ) -> Option<usize> {
        let mut answer = None;
        for &b in bytes {
            let base = *drive.base();
            if let Some(n) = server.on_byte(b, drive, &base, out) {
                answer = Some(n);
            }
        }
        answer
    }

    fn report(
        server: &mut LinkServer,
        drive: &mut Drive<f32>,
        request: CommissioningRequest,
    ) -> CommissioningReport {
        let (buf, n) = wire(&request);
        let mut out = [0u8; LinkServer::REPLY_LEN];
        let len = feed(server, drive, &buf[..n], &mut out).expect("an answer");
        decode::<CommissioningReport>(&out[..len]).unwrap()
    }

    fn sensor(sequence: u16, enable: bool) -> ([u8; 256], usize) {
        wire(&SensorFrame {
            sequence,
            i_a: 0.0,
            i_b: 0.0,
            i_c: 0.0,
            vdc: 34.0,
            speed_ref: 0.0,
            enable,
            clear_faults: false,
            move_to: None,
        })
    }

    #[test]
    fn a_start_request_builds_the_told_drive_and_later_ones_are_refused_while_it_runs() {
        let m = MotorParams::paper();
        let mut drive =
            Drive::<f32>::new(&m, &DriveConfig::paper_axis(ObserverKind::Dcfo), &Base::SI).unwrap();
        let mut server = LinkServer::new();
        let mut out = [0u8; LinkServer::REPLY_LEN];
        // A HIL run has numbered its frames up to 500.
        for k in 0..=500u16 {
            let (buf, n) = sensor(k, false);
            assert!(feed(&mut server, &mut drive, &buf[..n], &mut out).is_some());
        }
        let query = CommissioningRequest { sequence: 1, start: None };
        assert_eq!(report(&mut server, &mut drive, query).status, CommissioningStatus::Idle);
        let start = CommissioningRequest { sequence: 2, start: Some(told()) };
        let r = report(&mut server, &mut drive, start);
        assert_eq!((r.sequence, r.status, r.result), (2, CommissioningStatus::Running, None));
        // The drive is the one `Drive::for_commissioning` builds: same state after steps.
        let mut expected = Drive::<f32>::for_commissioning(told(), &Base::SI).unwrap();
        // The sequence started anew: frame 0 is in order.
        for k in 0..3u16 {
            let (buf, n) = sensor(k, true);
            let len = feed(&mut server, &mut drive, &buf[..n], &mut out).expect("answered");
            let a = decode::<ActuationFrame>(&out[..len]).unwrap();
            expected.apply(&Commands { enable: true, clear_faults: false, speed_ref_m_per_s: 0.0 });
            let e = expected.step(&Measurements::from_si([0.0; 3], 34.0, &Base::SI));
            assert_eq!((a.sequence, a.state()), (k, e.state));
        }
        assert_eq!(drive.state(), DriveState::Calibrating);
        let again =
            report(&mut server, &mut drive, CommissioningRequest { sequence: 3, start: Some(told()) });
        assert_eq!(again.status, CommissioningStatus::Refused);
        assert_eq!(again.error(), Some(CommissioningError::BadSetting(BAD_SETTING_OVER_THE_LINK)));
        // Refusing touched nothing: still running.
        assert_eq!(report(&mut server, &mut drive, query).status, CommissioningStatus::Running);
        assert_eq!(drive.state(), DriveState::Calibrating);
        // Disabled by the host: commissioning is dropped, nothing was identified.
        let (buf, n) = sensor(3, false);
        feed(&mut server, &mut drive, &buf[..n], &mut out);
        assert_eq!(report(&mut server, &mut drive, query).status, CommissioningStatus::Idle);
    }

    #[test]
    fn a_start_with_unphysical_settings_is_refused_by_name_code() {
        let m = MotorParams::paper();
        let mut drive =
            Drive::<f32>::new(&m, &DriveConfig::paper_axis(ObserverKind::Dcfo), &Base::SI).unwrap();
        let mut server = LinkServer::new();
        let bad = CommissioningConfig { rated_current_a: -1.0, ..told() };
        let r = report(&mut server, &mut drive, CommissioningRequest { sequence: 9, start: Some(bad) });
        assert_eq!(r.status, CommissioningStatus::Refused);
        assert!(matches!(r.error(), Some(CommissioningError::BadSetting(_))));
        // The image's drive is kept.
        assert_eq!(drive.state(), DriveState::Disabled);
        assert!(!drive.commissioning_pending());
    }
}
