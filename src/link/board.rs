//! The board link: a drive image that runs its own control loop (a board's ADC
//! interrupt, or the virtual motor) operated from the host (`dcfo board`). Same framing
//! as the lock-step link (COBS, CRC-16/IBM-3740, little-endian, protocol version in byte
//! 0); the frame type is told by its length, which is distinct for every frame of
//! [`crate::link`].
//!
//! Request and answer: the host sends a [`BoardCommand`] (at least every
//! 0.5 s: the drive image disables the drive when commands stop); the image answers each
//! with one [`BoardTelemetry`], or, when the command asks for capture samples and the
//! capture is over, with one [`CaptureChunk`].
//!
//! [`BoardCommand`] payload (20 B):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | u8 | protocol version |
//! | 1 | u16 | sequence number |
//! | 3 | f32 | speed reference (m/s) |
//! | 7 | u8 | flags ([`BOARD_FLAG_ENABLE`], [`BOARD_FLAG_CLEAR_FAULTS`], [`BOARD_FLAG_ARM_CAPTURE`], [`BOARD_FLAG_MOVE`]) |
//! | 8 | u32 | capture read: index of the first sample wanted, [`NO_CAPTURE_READ`] for telemetry |
//! | 12 | f32 | move: target position (m); zero bytes without [`BOARD_FLAG_MOVE`] |
//! | 16 | f32 | move: dwell at the target (s); zero bytes without [`BOARD_FLAG_MOVE`] |
//!
//! [`BoardTelemetry`] payload (59 B):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | u8 | protocol version |
//! | 1 | u16 | sequence number of the command answered |
//! | 3 | u8 | drive state (code, `0..`[`STATE_CODES`](super::STATE_CODES)) |
//! | 4 | u16 | fault bits (the drive's `Faults::bits`) |
//! | 6 | u8 | flags ([`ACTUATION_FLAG_BRIDGE_ENABLED`], [`ACTUATION_FLAG_ESTIMATE_VALID`], [`ACTUATION_FLAG_POSITION_VALID`], [`ACTUATION_FLAG_MOTION_IDLE`]) |
//! | 7, 11 | f32 | θ̂ (electrical rad), speed estimate (m/s); zero without an estimate |
//! | 15, 19 | f32 | measured i_α, i_β (A) |
//! | 23 | f32 | DC-bus voltage (V) |
//! | 27 | f32 | speed reference in force (m/s) |
//! | 31 | u8 | capture state ([`CaptureState::code`]) |
//! | 32, 36 | u32 | capture: samples held, capacity |
//! | 40 | u32 | control periods run since boot (wrapping) |
//! | 44, 48, 52 | f32 | position report ([`PositionReport`]): x̂ (m), reference position (m), reference speed (m/s) |
//! | 56 | u8 | position report: moves queued (not counting the active one) |
//! | 57 | u16 | position report: moves refused since boot (wrapping) |
//!
//! The position fields (44 to 58) are zero bytes without [`ACTUATION_FLAG_POSITION_VALID`]
//! (a speed drive), and [`ACTUATION_FLAG_MOTION_IDLE`] is only set with it.
//!
//! [`CaptureChunk`] payload (225 B):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | u8 | protocol version |
//! | 1 | u16 | sequence number of the command answered |
//! | 3 | u32 | index of the first sample |
//! | 7 | u8 | samples in this chunk, 0 to [`CAPTURE_CHUNK_SAMPLES`] (0: past the end) |
//! | 8 | u8 | how the samples' words read ([`CaptureFormat::code`]: 0 `f32` SI, 1 Q8.24 per unit) |
//! | 9 | 6 × 36 B | [`CaptureSample::to_le_bytes`]: nine 32-bit words each, the drive's own bits; unused slots zero |

use super::frame::{
    ACTUATION_FLAG_BRIDGE_ENABLED, ACTUATION_FLAG_ESTIMATE_VALID, ACTUATION_FLAG_MOTION_IDLE,
    ACTUATION_FLAG_POSITION_VALID, CRC_LEN, Frame, PositionReport, state_code_ok, wire_len,
};
use super::wire::{EncodeError, LinkError, PROTOCOL_VERSION, Reader, Writer};
use crate::algorithms::motion::Move;
use crate::capture::{CaptureFormat, CaptureSample, CaptureState};

/// [`BoardCommand`] flag: the drive should run (clear: disable).
pub const BOARD_FLAG_ENABLE: u8 = 1 << 0;
/// [`BoardCommand`] flag: clear latched faults (send it in one command).
pub const BOARD_FLAG_CLEAR_FAULTS: u8 = 1 << 1;
/// [`BoardCommand`] flag: arm the capture (it starts at the estimator's next start).
pub const BOARD_FLAG_ARM_CAPTURE: u8 = 1 << 2;
/// [`BoardCommand`] flag: the move fields hold a move to queue ([`BoardCommand::move_to`]);
/// clear: they are zero bytes.
pub const BOARD_FLAG_MOVE: u8 = 1 << 3;
const BOARD_FLAGS_KNOWN: u8 =
    BOARD_FLAG_ENABLE | BOARD_FLAG_CLEAR_FAULTS | BOARD_FLAG_ARM_CAPTURE | BOARD_FLAG_MOVE;
const TELEMETRY_FLAGS_KNOWN: u8 = ACTUATION_FLAG_BRIDGE_ENABLED
    | ACTUATION_FLAG_ESTIMATE_VALID
    | ACTUATION_FLAG_POSITION_VALID
    | ACTUATION_FLAG_MOTION_IDLE;

/// [`BoardCommand::capture_read`] for "no samples, answer with telemetry".
pub const NO_CAPTURE_READ: u32 = u32::MAX;

/// Capture samples per [`CaptureChunk`] (the most that keep the raw frame under COBS's
/// 254-byte block).
pub const CAPTURE_CHUNK_SAMPLES: usize = 6;

/// Host → drive image: the commands, and a keep-alive.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BoardCommand {
    /// Sequence number, incremented (wrapping) by the host per command.
    pub sequence: u16,
    /// Speed reference, m/s (finite).
    pub speed_ref: f32,
    /// The drive should run; clear: disable.
    pub enable: bool,
    /// Clear latched faults.
    pub clear_faults: bool,
    /// Arm the capture.
    pub arm_capture: bool,
    /// Index of the first capture sample wanted, or [`NO_CAPTURE_READ`].
    pub capture_read: u32,
    /// Queue this move (target m, dwell s; both finite) on a positioning drive; send it
    /// in one command (a command sent again queues it again). `None`: no move.
    pub move_to: Option<Move>,
}

impl BoardCommand {
    /// Payload length (bytes).
    pub const PAYLOAD_LEN: usize = 20;
    /// Raw length (bytes): payload and CRC.
    pub const RAW_LEN: usize = Self::PAYLOAD_LEN + CRC_LEN;
    /// Length on the wire (bytes).
    pub const WIRE_LEN: usize = wire_len(Self::RAW_LEN);
}

impl Frame for BoardCommand {
    const PAYLOAD_LEN: usize = BoardCommand::PAYLOAD_LEN;

    fn write_payload(&self, payload: &mut [u8]) -> Result<(), EncodeError> {
        let m = self.move_to.unwrap_or(Move { target_m: 0.0, dwell_s: 0.0 });
        if ![self.speed_ref, m.target_m, m.dwell_s].iter().all(|x| x.is_finite()) {
            return Err(EncodeError::InvalidValue);
        }
        let mut flags = 0;
        for (on, bit) in [
            (self.enable, BOARD_FLAG_ENABLE),
            (self.clear_faults, BOARD_FLAG_CLEAR_FAULTS),
            (self.arm_capture, BOARD_FLAG_ARM_CAPTURE),
            (self.move_to.is_some(), BOARD_FLAG_MOVE),
        ] {
            if on {
                flags |= bit;
            }
        }
        let mut w = Writer::new(payload);
        w.u8(PROTOCOL_VERSION);
        w.u16(self.sequence);
        w.f32(self.speed_ref);
        w.u8(flags);
        w.u32(self.capture_read);
        w.f32(m.target_m);
        w.f32(m.dwell_s);
        w.finish(Self::PAYLOAD_LEN)
    }

    fn read_payload(payload: &[u8]) -> Result<Self, LinkError> {
        let mut r = Reader::new(payload, Self::PAYLOAD_LEN)?;
        r.version()?;
        let sequence = r.u16();
        let speed_ref = r.finite_f32()?;
        let flags = r.u8();
        if flags & !BOARD_FLAGS_KNOWN != 0 {
            return Err(LinkError::Flags);
        }
        let capture_read = r.u32();
        let move_to = super::frame::read_move(flags & BOARD_FLAG_MOVE != 0, &mut r)?;
        Ok(BoardCommand {
            sequence,
            speed_ref,
            enable: flags & BOARD_FLAG_ENABLE != 0,
            clear_faults: flags & BOARD_FLAG_CLEAR_FAULTS != 0,
            arm_capture: flags & BOARD_FLAG_ARM_CAPTURE != 0,
            capture_read,
            move_to,
        })
    }
}

/// Drive image → host: the drive's state, SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BoardTelemetry {
    /// Sequence number of the command answered.
    pub sequence: u16,
    /// Drive state, as its code `0..`[`STATE_CODES`](super::STATE_CODES) (the drive adapter converts:
    /// `BoardTelemetry::state`).
    pub state_code: u8,
    /// Latched faults, as bits (the drive adapter converts: `BoardTelemetry::faults`).
    pub fault_bits: u16,
    /// The bridge is switching.
    pub bridge_enabled: bool,
    /// Estimated angle θ̂ (electrical rad) and speed (m/s), `None` without an estimate.
    pub estimate: Option<(f32, f32)>,
    /// Measured stator current, α and β, A.
    pub i_ab_a: [f32; 2],
    /// DC-bus voltage, V.
    pub vdc_v: f32,
    /// Speed reference in force, m/s.
    pub speed_ref: f32,
    /// Capture state.
    pub capture: CaptureState,
    /// Capture samples held.
    pub capture_len: u32,
    /// Capture capacity, samples.
    pub capture_capacity: u32,
    /// Control periods run since boot (wrapping).
    pub periods: u32,
    /// A positioning drive's position and motion (x̂ and the reference in m, the queue,
    /// the moves refused since boot); `None` for a speed drive.
    pub position: Option<PositionReport>,
}

impl BoardTelemetry {
    /// Payload length (bytes).
    pub const PAYLOAD_LEN: usize = 59;
    /// Raw length (bytes): payload and CRC.
    pub const RAW_LEN: usize = Self::PAYLOAD_LEN + CRC_LEN;
    /// Length on the wire (bytes).
    pub const WIRE_LEN: usize = wire_len(Self::RAW_LEN);
}

impl Frame for BoardTelemetry {
    const PAYLOAD_LEN: usize = BoardTelemetry::PAYLOAD_LEN;

    fn write_payload(&self, payload: &mut [u8]) -> Result<(), EncodeError> {
        let (theta, speed) = self.estimate.unwrap_or((0.0, 0.0));
        let floats = [theta, speed, self.i_ab_a[0], self.i_ab_a[1], self.vdc_v, self.speed_ref];
        if !floats.iter().all(|x| x.is_finite())
            || !state_code_ok(self.state_code)
            || !self.position.is_none_or(|p| p.is_finite())
        {
            return Err(EncodeError::InvalidValue);
        }
        let mut flags = 0;
        if self.bridge_enabled {
            flags |= ACTUATION_FLAG_BRIDGE_ENABLED;
        }
        if self.estimate.is_some() {
            flags |= ACTUATION_FLAG_ESTIMATE_VALID;
        }
        flags |= PositionReport::flags(self.position);
        let mut w = Writer::new(payload);
        w.u8(PROTOCOL_VERSION);
        w.u16(self.sequence);
        w.u8(self.state_code);
        w.u16(self.fault_bits);
        w.u8(flags);
        for x in floats {
            w.f32(x);
        }
        w.u8(self.capture.code());
        w.u32(self.capture_len);
        w.u32(self.capture_capacity);
        w.u32(self.periods);
        PositionReport::write(self.position, &mut w);
        w.finish(Self::PAYLOAD_LEN)
    }

    fn read_payload(payload: &[u8]) -> Result<Self, LinkError> {
        let mut r = Reader::new(payload, Self::PAYLOAD_LEN)?;
        r.version()?;
        let sequence = r.u16();
        let state_code = r.u8();
        if !state_code_ok(state_code) {
            return Err(LinkError::Value);
        }
        let fault_bits = r.u16();
        let flags = r.u8();
        if flags & !TELEMETRY_FLAGS_KNOWN != 0 {
            return Err(LinkError::Flags);
        }
        let theta = r.finite_f32()?;
        let speed = r.finite_f32()?;
        let estimate = if flags & ACTUATION_FLAG_ESTIMATE_VALID != 0 {
            Some((theta, speed))
        } else if theta != 0.0 || speed != 0.0 {
            return Err(LinkError::Value);
        } else {
            None
        };
        let i_ab_a = [r.finite_f32()?, r.finite_f32()?];
        let vdc_v = r.finite_f32()?;
        let speed_ref = r.finite_f32()?;
        let capture = CaptureState::from_code(r.u8()).ok_or(LinkError::Value)?;
        let capture_len = r.u32();
        let capture_capacity = r.u32();
        if capture_len > capture_capacity {
            return Err(LinkError::Value);
        }
        let periods = r.u32();
        let position = PositionReport::read(flags, &mut r)?;
        Ok(BoardTelemetry {
            sequence,
            state_code,
            fault_bits,
            bridge_enabled: flags & ACTUATION_FLAG_BRIDGE_ENABLED != 0,
            estimate,
            i_ab_a,
            vdc_v,
            speed_ref,
            capture,
            capture_len,
            capture_capacity,
            periods,
            position,
        })
    }
}

/// Drive image → host: up to [`CAPTURE_CHUNK_SAMPLES`] consecutive capture samples.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CaptureChunk {
    /// Sequence number of the command answered.
    pub sequence: u16,
    /// Index of `samples[0]` in the capture.
    pub first: u32,
    /// Valid samples, `0..=CAPTURE_CHUNK_SAMPLES` (0: `first` is past the end).
    pub count: u8,
    /// How the samples' words read (the drive's number type and working units).
    pub format: CaptureFormat,
    /// The samples; those from `count` on are unused (zero).
    pub samples: [CaptureSample; CAPTURE_CHUNK_SAMPLES],
}

impl CaptureChunk {
    /// Payload length (bytes).
    pub const PAYLOAD_LEN: usize = 9 + CAPTURE_CHUNK_SAMPLES * CaptureSample::WIRE_LEN;
    /// Raw length (bytes): payload and CRC.
    pub const RAW_LEN: usize = Self::PAYLOAD_LEN + CRC_LEN;
    /// Length on the wire (bytes).
    pub const WIRE_LEN: usize = wire_len(Self::RAW_LEN);

    /// The valid samples.
    pub fn valid(&self) -> &[CaptureSample] {
        self.samples.get(..usize::from(self.count)).unwrap_or(&[])
    }
}

impl Frame for CaptureChunk {
    const PAYLOAD_LEN: usize = CaptureChunk::PAYLOAD_LEN;

    fn write_payload(&self, payload: &mut [u8]) -> Result<(), EncodeError> {
        if usize::from(self.count) > CAPTURE_CHUNK_SAMPLES {
            return Err(EncodeError::InvalidValue);
        }
        let mut w = Writer::new(payload);
        w.u8(PROTOCOL_VERSION);
        w.u16(self.sequence);
        w.u32(self.first);
        w.u8(self.count);
        w.u8(self.format.code());
        for (k, s) in self.samples.iter().enumerate() {
            if k < usize::from(self.count) {
                if !s.valid(self.format) {
                    return Err(EncodeError::InvalidValue);
                }
                w.bytes(&s.to_le_bytes());
            } else {
                w.bytes(&[0; CaptureSample::WIRE_LEN]);
            }
        }
        w.finish(Self::PAYLOAD_LEN)
    }

    fn read_payload(payload: &[u8]) -> Result<Self, LinkError> {
        let mut r = Reader::new(payload, Self::PAYLOAD_LEN)?;
        r.version()?;
        let sequence = r.u16();
        let first = r.u32();
        let count = r.u8();
        if usize::from(count) > CAPTURE_CHUNK_SAMPLES {
            return Err(LinkError::Value);
        }
        let format = CaptureFormat::from_code(r.u8()).ok_or(LinkError::Value)?;
        let mut samples = [CaptureSample::default(); CAPTURE_CHUNK_SAMPLES];
        for (k, slot) in samples.iter_mut().enumerate() {
            let bytes = r.bytes::<{ CaptureSample::WIRE_LEN }>();
            if k < usize::from(count) {
                let s = CaptureSample::from_le_bytes(&bytes);
                if !s.valid(format) {
                    return Err(LinkError::Value);
                }
                *slot = s;
            } else if bytes.iter().any(|&b| b != 0) {
                return Err(LinkError::Value);
            }
        }
        Ok(CaptureChunk { sequence, first, count, format, samples })
    }
}

impl super::frame::private::Sealed for BoardCommand {}
impl super::frame::private::Sealed for BoardTelemetry {}
impl super::frame::private::Sealed for CaptureChunk {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::{Receiver, decode_raw, encode};
    use crate::num::Angle;

    fn round_trip<F: Frame + PartialEq + core::fmt::Debug + Copy>(f: F) -> F {
        let mut wire = [0u8; 256];
        let n = encode(&f, &mut wire).unwrap();
        assert_eq!(n, F::WIRE_LEN);
        assert_eq!(wire[n - 1], 0);
        let mut raw = [0u8; 256];
        raw[..n - 1].copy_from_slice(&wire[..n - 1]);
        let m = super::super::cobs::decode_in_place(&mut raw[..n - 1]).unwrap();
        decode_raw::<F>(&raw[..m]).unwrap()
    }

    #[test]
    fn frames_round_trip_and_their_lengths_tell_them_apart() {
        let c = BoardCommand {
            sequence: 65_535,
            speed_ref: -0.3,
            enable: true,
            clear_faults: false,
            arm_capture: true,
            capture_read: 1234,
            move_to: None,
        };
        assert_eq!(round_trip(c), c);
        let with_move = BoardCommand { move_to: Some(Move { target_m: -0.012, dwell_s: 0.25 }), ..c };
        assert_eq!(round_trip(with_move), with_move);
        let t = BoardTelemetry {
            sequence: 7,
            state_code: 3,
            fault_bits: 1 << 5,
            bridge_enabled: true,
            estimate: Some((1.5, 0.29)),
            i_ab_a: [0.1, -0.2],
            vdc_v: 311.0,
            speed_ref: 0.3,
            capture: CaptureState::Recording,
            capture_len: 10,
            capture_capacity: 20,
            periods: 123_456,
            position: None,
        };
        assert_eq!(round_trip(t), t);
        for idle in [false, true] {
            let p = PositionReport {
                x_hat_m: 0.0101,
                x_ref_m: 0.01,
                v_ref_m_per_s: if idle { 0.0 } else { 0.05 },
                moves_queued: 3,
                idle,
                moves_rejected: 65_535,
            };
            let tp = BoardTelemetry { position: Some(p), ..t };
            assert_eq!(round_trip(tp), tp);
        }
        let s = CaptureSample {
            u_alpha: 3.0f32.to_bits(),
            theta_hat: Angle::from_bits(99),
            v_hat: 0.3f32.to_bits(),
            ..Default::default()
        };
        let mut samples = [CaptureSample::default(); CAPTURE_CHUNK_SAMPLES];
        samples[0] = s;
        samples[1] = s;
        let k = CaptureChunk { sequence: 3, first: 600, count: 2, format: CaptureFormat::F32, samples };
        assert_eq!(round_trip(k), k);
        assert_eq!(k.valid(), &[s, s]);
        // Q8.24 words: any bits, including those that are NaN as f32.
        samples[1].v_hat = f32::NAN.to_bits();
        samples[1].psi_beta_hat = i32::MIN as u32;
        let q = CaptureChunk { sequence: 4, first: 6, count: 2, format: CaptureFormat::Q24, samples };
        assert_eq!(round_trip(q), q);
        let lengths = [
            super::super::SensorFrame::RAW_LEN,
            super::super::ActuationFrame::RAW_LEN,
            BoardCommand::RAW_LEN,
            BoardTelemetry::RAW_LEN,
            CaptureChunk::RAW_LEN,
        ];
        for (i, a) in lengths.iter().enumerate() {
            assert!(lengths[i + 1..].iter().all(|b| b != a), "{lengths:?}");
        }
        // The drive image's receiver takes commands.
        let mut wire = [0u8; BoardCommand::WIRE_LEN];
        let n = encode(&c, &mut wire).unwrap();
        let mut rx = Receiver::<BoardCommand>::new();
        let got: Option<_> = wire[..n].iter().filter_map(|&b| rx.push(b)).next();
        assert_eq!(got, Some(Ok(c)));
    }

    #[test]
    fn bad_content_is_refused() {
        let mut samples = [CaptureSample::default(); CAPTURE_CHUNK_SAMPLES];
        samples[0].v_hat = f32::NAN.to_bits();
        let k = CaptureChunk { sequence: 0, first: 0, count: 1, format: CaptureFormat::F32, samples };
        assert_eq!(encode(&k, &mut [0u8; 256]), Err(EncodeError::InvalidValue));
        // An unknown format code: payload byte 8.
        let ok = CaptureChunk { format: CaptureFormat::Q24, ..k };
        let mut payload = [0u8; CaptureChunk::PAYLOAD_LEN];
        ok.write_payload(&mut payload).unwrap();
        assert_eq!(CaptureChunk::read_payload(&payload), Ok(ok));
        payload[8] = 2;
        assert_eq!(CaptureChunk::read_payload(&payload), Err(LinkError::Value));
        let k = CaptureChunk { count: 7, samples: [CaptureSample::default(); 6], ..k };
        assert_eq!(encode(&k, &mut [0u8; 256]), Err(EncodeError::InvalidValue));
        // A command with an unknown flag bit: payload byte 7.
        let c = BoardCommand {
            sequence: 1,
            speed_ref: 0.0,
            enable: false,
            clear_faults: false,
            arm_capture: false,
            capture_read: NO_CAPTURE_READ,
            move_to: None,
        };
        let mut payload = [0u8; BoardCommand::PAYLOAD_LEN];
        c.write_payload(&mut payload).unwrap();
        let clean = payload;
        payload[7] |= 1 << 6;
        assert_eq!(BoardCommand::read_payload(&payload), Err(LinkError::Flags));
        // Move bytes without the move flag (payload bytes 12 to 19) are refused.
        for k in 12..20 {
            let mut p = clean;
            p[k] = 1;
            assert_eq!(BoardCommand::read_payload(&p), Err(LinkError::Value), "byte {k}");
        }
        // A non-finite move is neither sent nor taken.
        for bad in [Move { target_m: f32::NAN, dwell_s: 0.0 }, Move { target_m: 0.0, dwell_s: f32::INFINITY }]
        {
            let m = BoardCommand { move_to: Some(bad), ..c };
            assert_eq!(encode(&m, &mut [0u8; 64]), Err(EncodeError::InvalidValue));
        }
        let mut p = clean;
        p[7] |= BOARD_FLAG_MOVE;
        p[12..16].copy_from_slice(&f32::NAN.to_le_bytes());
        assert_eq!(BoardCommand::read_payload(&p), Err(LinkError::Value));
    }
}
