//! The hardware-in-the-loop serial link: a versioned pair of frames for a byte stream
//! (UART), shared by the firmware and the host.
//!
//! The link runs in lock-step. Each PWM period the host (the simulated plant) sends a
//! [`SensorFrame`]; the controller runs one [`Drive::step`] and answers with an
//! [`ActuationFrame`] that echoes the sensor frame's sequence number.
//!
//! ## Framing
//! `frame = COBS(payload ‖ CRC) ‖ 0x00`. COBS removes every `0x00` from the frame, so
//! `0x00` delimits frames and a receiver resynchronises on the next one after any
//! corruption. Empty frames (two `0x00` in a row) are ignored, so a sender may also put a
//! `0x00` *before* each frame: then noise on the idle line ends before the frame starts
//! instead of corrupting it. A receiver that starts in the middle of a frame reports that
//! one partial frame as an error.
//!
//! **CRC-16/IBM-3740** (often called CRC-16/CCITT-FALSE: polynomial `0x1021`, initial
//! value `0xFFFF`, no reflection, no final XOR; check value `0x29B1`), over the payload,
//! sent little-endian. For frames this short (at most 43 bytes, 344 bits) the polynomial
//! has Hamming distance 4: every error of 1, 2 or 3 bits, every odd number of flipped
//! bits and every burst up to 16 bits is caught, and a random corruption that survives
//! COBS and the exact length check passes with probability 2⁻¹⁶. CRC-32 would catch more
//! but costs two more bytes on every frame of a link whose budget is bandwidth (see
//! below); the non-zero initial value makes leading zero bytes count.
//!
//! **Encoding: a fixed little-endian layout written by hand**, not `postcard`. Every
//! frame has one constant size known at compile time, so buffers are sized exactly, time
//! is bounded, truncation is caught by a length check, and any tool can parse the tables
//! below; postcard's varints make sizes data-dependent and bring serde into the
//! interrupt for no gain on a dozen fixed fields. `f32` travels as its IEEE-754 bits
//! (exact, no rounding); both ends are little-endian machines anyway.
//!
//! ## Sizes
//! | frame | payload | raw (payload + CRC) | on the wire (COBS + delimiter) |
//! |---|---|---|---|
//! | [`SensorFrame`] | 24 B | 26 B | 28 B |
//! | [`ActuationFrame`] | 41 B | 43 B | 45 B |
//! | [`board::BoardCommand`] | 12 B | 14 B | 16 B |
//! | [`board::BoardTelemetry`] | 44 B | 46 B | 48 B |
//! | [`board::CaptureChunk`] | 224 B | 226 B | 228 B |
//!
//! The board link's frames ([`board`]: a drive image operated from the host) share the
//! framing; every frame type has its own length.
//!
//! COBS adds exactly one byte to a raw frame shorter than 254 bytes, whatever its
//! content, so the wire sizes are constant. With 8N1 framing (10 bits a byte) and a
//! 100 µs period the link needs 2.8 Mbit/s host → controller and 4.5 Mbit/s back.
//!
//! ## Layouts (byte offsets, little-endian)
//! [`SensorFrame`] payload:
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | u8 | protocol version ([`PROTOCOL_VERSION`]) |
//! | 1 | u16 | sequence number |
//! | 3, 7, 11 | f32 | phase currents i_a, i_b, i_c (A) |
//! | 15 | f32 | DC-bus voltage (V) |
//! | 19 | f32 | speed reference (m/s) |
//! | 23 | u8 | command flags ([`SENSOR_FLAG_ENABLE`], [`SENSOR_FLAG_CLEAR_FAULTS`]) |
//!
//! [`ActuationFrame`] payload:
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | u8 | protocol version |
//! | 1 | u16 | sequence number (echo) |
//! | 3, 7, 11 | f32 | duties a, b, c (`[0, 1]`) |
//! | 15 | u8 | flags ([`ACTUATION_FLAG_BRIDGE_ENABLED`], [`ACTUATION_FLAG_ESTIMATE_VALID`]) |
//! | 16 | u8 | drive state ([`DriveState::code`]) |
//! | 17 | u16 | fault bits ([`Faults::bits`]) |
//! | 19 | f32 | θ̂ (electrical rad) |
//! | 23 | f32 | speed estimate (m/s) |
//! | 27, 31 | f32 | ψ_α, ψ_β (Wb) |
//! | 35, 37, 39 | u16 | frames dropped: malformed, bad CRC, out of order |
//!
//! Without an estimate the four estimate fields are sent as zero bytes.
//!
//! ## Rejected frames
//! A frame is checked in this order: COBS, length, CRC, version, flags (unknown bits are
//! an error), values (every `f32` finite, duties in `[0, 1]`, a known state code). A
//! failure at the CRC is counted as *bad CRC*, every other failure (including a frame
//! longer than the receive buffer) as *malformed*; see [`LinkStats`]. Encoding refuses
//! the same values, so a frame that was sent is never rejected for its content.
//!
//! ## Sequence numbers and the silent link
//! [`SequenceTracker`] keeps the last accepted sequence number (u16, wrapping) and
//! classifies the next with [`classify_sequence`]: one to 32 767 ahead is in order (a
//! gap means frames were lost), equal is a duplicate, anything else (behind) is out of
//! order. The controller acts only on in-order frames and counts the others as *out of
//! order*. [`LinkWatchdog`] counts control periods without an accepted frame; after
//! [`SILENT_LINK_PERIODS`] = 10 periods (1 ms at the 100 µs default period) the bridge
//! must be turned off: trip the drive with [`Faults::EXTERNAL`] and
//! [`reset`](SequenceTracker::reset) the tracker, so a restarted host is accepted again.
//!
//! ## Controller side, one PWM period
//! ```
//! use dcfo::link::{ActuationFrame, LinkWatchdog, Receiver, SensorFrame, SequenceOrder, SequenceTracker};
//!
//! let mut rx = Receiver::<SensorFrame>::new();
//! let mut sequence = SequenceTracker::new();
//! let mut watchdog = LinkWatchdog::default();
//! # let sent = SensorFrame { sequence: 7, i_a: 0.1, i_b: -0.05, i_c: -0.05, vdc: 48.0,
//! #     speed_ref: 0.3, enable: true, clear_faults: false };
//! # let mut uart = [0u8; SensorFrame::WIRE_LEN];
//! # let n = dcfo::link::encode(&sent, &mut uart).unwrap();
//! let mut accepted = None;
//! for &byte in &uart[..n] {
//!     if let Some(Ok(frame)) = rx.push(byte) {
//!         match sequence.check(frame.sequence) {
//!             SequenceOrder::InOrder { .. } => accepted = Some(frame),
//!             _ => rx.stats_mut().record_out_of_order(),
//!         }
//!     }
//! }
//! if watchdog.period(accepted.is_some()) {
//!     // drive.trip(Faults::EXTERNAL); sequence.reset();
//! }
//! if let Some(frame) = accepted {
//!     // frame.apply_commands(&mut drive);
//!     // let out = drive.step(&frame.measurements(&Base::SI));
//!     // let reply = ActuationFrame::from_step(frame.sequence, &out, &Base::SI, rx.stats());
//!     // let n = dcfo::link::encode(&reply, &mut tx_buffer)?;
//! #   assert_eq!(frame, sent);
//! }
//! ```

pub mod board;
pub mod cobs;

use core::marker::PhantomData;

use crc::{CRC_16_IBM_3740, Crc};

use crate::drive::{Drive, DriveState, Faults, Measurements, StepOutput};
use crate::num::Scalar;
use crate::transforms::Abc;
use crate::units::Base;

/// The protocol version carried in byte 0 of every frame; any other value is rejected.
pub const PROTOCOL_VERSION: u8 = 1;

/// Bytes of the CRC after the payload (CRC-16, little-endian).
pub const CRC_LEN: usize = 2;

/// [`SensorFrame`] command flag: the drive should run (clear: disable).
pub const SENSOR_FLAG_ENABLE: u8 = 1 << 0;
/// [`SensorFrame`] command flag: clear latched faults (hold it for one frame).
pub const SENSOR_FLAG_CLEAR_FAULTS: u8 = 1 << 1;
const SENSOR_FLAGS_KNOWN: u8 = SENSOR_FLAG_ENABLE | SENSOR_FLAG_CLEAR_FAULTS;

/// [`ActuationFrame`] flag: the bridge is enabled.
pub const ACTUATION_FLAG_BRIDGE_ENABLED: u8 = 1 << 0;
/// [`ActuationFrame`] flag: the estimate fields hold an estimate.
pub const ACTUATION_FLAG_ESTIMATE_VALID: u8 = 1 << 1;
const ACTUATION_FLAGS_KNOWN: u8 = ACTUATION_FLAG_BRIDGE_ENABLED | ACTUATION_FLAG_ESTIMATE_VALID;

/// Capacity of a [`Receiver`]'s buffer (bytes): the largest COBS-encoded frame, the
/// [`ActuationFrame`], without its delimiter. A longer frame is reported as
/// [`LinkError::Overflow`].
pub const RX_CAPACITY: usize = ActuationFrame::WIRE_LEN - 1;

/// The largest raw frame (payload + CRC, bytes): the board link's capture chunk.
const MAX_RAW_LEN: usize = board::CaptureChunk::RAW_LEN;

const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);

/// Wire length of a raw frame shorter than 254 bytes: one COBS overhead byte and the
/// delimiter.
const fn wire_len(raw_len: usize) -> usize {
    raw_len + 2
}

// COBS adds exactly one byte only below 254 raw bytes.
const _: () = assert!(MAX_RAW_LEN < 254);

/// Why a received frame was dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkError {
    /// More bytes than [`RX_CAPACITY`] before a delimiter (the rest is skipped up to
    /// the next `0x00`).
    Overflow,
    /// Invalid COBS encoding.
    Cobs,
    /// The decoded frame does not have the frame type's raw length.
    Length,
    /// The CRC does not match the payload.
    Crc,
    /// Unknown protocol version.
    Version,
    /// Unknown flag bits set.
    Flags,
    /// A value out of its range: a non-finite `f32`, a duty outside `[0, 1]`, an
    /// unknown drive-state code, or estimate bytes sent without an estimate.
    Value,
}

impl LinkError {
    /// `true` for [`LinkError::Crc`] (counted as bad CRC); every other error counts as
    /// malformed.
    pub const fn is_crc(self) -> bool {
        matches!(self, LinkError::Crc)
    }
}

impl core::fmt::Display for LinkError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            LinkError::Overflow => "frame longer than the receive buffer",
            LinkError::Cobs => "invalid COBS encoding",
            LinkError::Length => "wrong frame length",
            LinkError::Crc => "CRC mismatch",
            LinkError::Version => "unknown protocol version",
            LinkError::Flags => "unknown flag bits",
            LinkError::Value => "value out of range",
        })
    }
}

/// Why a frame could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError {
    /// The output buffer is shorter than `needed` bytes (the frame's `WIRE_LEN`).
    BufferTooSmall {
        /// Bytes the frame needs on the wire.
        needed: usize,
    },
    /// A field the receiver would reject: a non-finite `f32` or a duty outside `[0, 1]`.
    InvalidValue,
}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            EncodeError::BufferTooSmall { needed } => write!(f, "output buffer needs {needed} bytes"),
            EncodeError::InvalidValue => f.write_str("value out of range"),
        }
    }
}

/// Frames dropped by the controller, each count saturating at `u16::MAX`. Sent back in
/// every [`ActuationFrame`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkStats {
    /// Frames dropped as malformed: bad COBS, wrong length, wrong version, unknown
    /// flags, values out of range, or longer than the receive buffer (frames).
    pub malformed: u16,
    /// Frames dropped for a CRC mismatch (frames).
    pub bad_crc: u16,
    /// Valid frames dropped for their sequence number: duplicates and frames behind
    /// the last accepted one (frames).
    pub out_of_order: u16,
}

impl LinkStats {
    /// Counts one frame dropped for `error` (as bad CRC or malformed).
    pub fn record(&mut self, error: LinkError) {
        if error.is_crc() {
            self.bad_crc = self.bad_crc.saturating_add(1);
        } else {
            self.malformed = self.malformed.saturating_add(1);
        }
    }

    /// Counts one frame dropped for its sequence number.
    pub fn record_out_of_order(&mut self) {
        self.out_of_order = self.out_of_order.saturating_add(1);
    }
}

mod private {
    pub trait Sealed {}
    impl Sealed for super::SensorFrame {}
    impl Sealed for super::ActuationFrame {}
    impl Sealed for super::board::BoardCommand {}
    impl Sealed for super::board::BoardTelemetry {}
    impl Sealed for super::board::CaptureChunk {}
}

/// A frame type of the link: [`SensorFrame`] or [`ActuationFrame`] (sealed).
pub trait Frame: private::Sealed + Sized {
    /// Payload length (bytes), before the CRC.
    const PAYLOAD_LEN: usize;
    /// Raw length (bytes): payload and CRC.
    const RAW_LEN: usize = Self::PAYLOAD_LEN + CRC_LEN;
    /// Length on the wire (bytes): COBS-encoded raw frame and the `0x00` delimiter.
    const WIRE_LEN: usize = wire_len(Self::RAW_LEN);

    /// Writes the payload into `payload` (exactly [`Frame::PAYLOAD_LEN`] bytes).
    fn write_payload(&self, payload: &mut [u8]) -> Result<(), EncodeError>;

    /// Reads a payload of exactly [`Frame::PAYLOAD_LEN`] bytes whose CRC was checked.
    fn read_payload(payload: &[u8]) -> Result<Self, LinkError>;
}

/// Host → controller, once per PWM period: the plant's sensors and the commands.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SensorFrame {
    /// Sequence number, incremented (wrapping) by the host for each frame.
    pub sequence: u16,
    /// Phase-a current (A), finite.
    pub i_a: f32,
    /// Phase-b current (A), finite.
    pub i_b: f32,
    /// Phase-c current (A), finite.
    pub i_c: f32,
    /// DC-bus voltage (V), finite.
    pub vdc: f32,
    /// Speed reference (m/s), finite.
    pub speed_ref: f32,
    /// Command: the drive should run ([`Drive::enable`]); clear: [`Drive::disable`].
    pub enable: bool,
    /// Command: clear latched faults ([`Drive::clear_faults`]); send it for one frame.
    pub clear_faults: bool,
}

impl SensorFrame {
    /// Payload length (bytes).
    pub const PAYLOAD_LEN: usize = 24;
    /// Raw length (bytes): payload and CRC.
    pub const RAW_LEN: usize = Self::PAYLOAD_LEN + CRC_LEN;
    /// Length on the wire (bytes).
    pub const WIRE_LEN: usize = wire_len(Self::RAW_LEN);

    /// The measurements for [`Drive::step`], in the working units of `base`.
    pub fn measurements<T: Scalar>(&self, base: &Base) -> Measurements<T> {
        Measurements {
            i_abc: Abc { a: base.current(self.i_a), b: base.current(self.i_b), c: base.current(self.i_c) },
            vdc: base.voltage(self.vdc),
        }
    }

    /// Applies the commands to `drive`: clear faults (if asked), enable or disable,
    /// and the speed reference (m/s, converted with [`Drive::omega_from_speed`]).
    pub fn apply_commands<T: Scalar>(&self, drive: &mut Drive<T>) {
        if self.clear_faults {
            drive.clear_faults();
        }
        if self.enable {
            drive.enable();
        } else {
            drive.disable();
        }
        let omega = drive.omega_from_speed(self.speed_ref);
        drive.set_speed_reference(omega);
    }

    fn flags(&self) -> u8 {
        let mut flags = 0;
        if self.enable {
            flags |= SENSOR_FLAG_ENABLE;
        }
        if self.clear_faults {
            flags |= SENSOR_FLAG_CLEAR_FAULTS;
        }
        flags
    }
}

impl Frame for SensorFrame {
    const PAYLOAD_LEN: usize = SensorFrame::PAYLOAD_LEN;

    fn write_payload(&self, payload: &mut [u8]) -> Result<(), EncodeError> {
        let floats = [self.i_a, self.i_b, self.i_c, self.vdc, self.speed_ref];
        if !floats.iter().all(|x| x.is_finite()) {
            return Err(EncodeError::InvalidValue);
        }
        let mut w = Writer::new(payload);
        w.u8(PROTOCOL_VERSION);
        w.u16(self.sequence);
        for x in floats {
            w.f32(x);
        }
        w.u8(self.flags());
        w.finish(Self::PAYLOAD_LEN)
    }

    fn read_payload(payload: &[u8]) -> Result<Self, LinkError> {
        let mut r = Reader::new(payload, Self::PAYLOAD_LEN)?;
        r.version()?;
        let sequence = r.u16();
        let i_a = r.finite_f32()?;
        let i_b = r.finite_f32()?;
        let i_c = r.finite_f32()?;
        let vdc = r.finite_f32()?;
        let speed_ref = r.finite_f32()?;
        let flags = r.u8();
        if flags & !SENSOR_FLAGS_KNOWN != 0 {
            return Err(LinkError::Flags);
        }
        Ok(SensorFrame {
            sequence,
            i_a,
            i_b,
            i_c,
            vdc,
            speed_ref,
            enable: flags & SENSOR_FLAG_ENABLE != 0,
            clear_faults: flags & SENSOR_FLAG_CLEAR_FAULTS != 0,
        })
    }
}

/// The estimator's output as sent in an [`ActuationFrame`] (SI units).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EstimateReport {
    /// Estimated electrical angle θ̂ (rad, `[-π, π)` from the drive), finite.
    pub theta_hat: f32,
    /// Estimated linear speed (m/s), finite.
    pub speed: f32,
    /// Estimated mover flux, α component (Wb), finite.
    pub psi_alpha: f32,
    /// Estimated mover flux, β component (Wb), finite.
    pub psi_beta: f32,
}

impl EstimateReport {
    fn is_finite(&self) -> bool {
        [self.theta_hat, self.speed, self.psi_alpha, self.psi_beta].iter().all(|x| x.is_finite())
    }
}

/// Controller → host, the answer to one [`SensorFrame`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ActuationFrame {
    /// Sequence number of the sensor frame this answers.
    pub sequence: u16,
    /// Phase-a upper-switch duty for the next period, `[0, 1]`.
    pub duty_a: f32,
    /// Phase-b upper-switch duty for the next period, `[0, 1]`.
    pub duty_b: f32,
    /// Phase-c upper-switch duty for the next period, `[0, 1]`.
    pub duty_c: f32,
    /// `false`: every switch must be off.
    pub bridge_enabled: bool,
    /// The drive's state after the step (sent as [`DriveState::code`]).
    pub state: DriveState,
    /// Latched faults (sent as [`Faults::bits`]; unknown bits are kept).
    pub faults: Faults,
    /// The estimator's output, `None` while it is not running.
    pub estimate: Option<EstimateReport>,
    /// The controller's counts of dropped frames.
    pub stats: LinkStats,
}

impl ActuationFrame {
    /// Payload length (bytes).
    pub const PAYLOAD_LEN: usize = 41;
    /// Raw length (bytes): payload and CRC.
    pub const RAW_LEN: usize = Self::PAYLOAD_LEN + CRC_LEN;
    /// Length on the wire (bytes).
    pub const WIRE_LEN: usize = wire_len(Self::RAW_LEN);

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
            state: out.state,
            faults: out.faults,
            estimate,
            stats,
        }
    }

    fn flags(&self) -> u8 {
        let mut flags = 0;
        if self.bridge_enabled {
            flags |= ACTUATION_FLAG_BRIDGE_ENABLED;
        }
        if self.estimate.is_some() {
            flags |= ACTUATION_FLAG_ESTIMATE_VALID;
        }
        flags
    }
}

fn duty_ok(d: f32) -> bool {
    (0.0..=1.0).contains(&d)
}

/// The drive state with telemetry code `code` (the inverse of [`DriveState::code`]).
fn state_from_code(code: u8) -> Option<DriveState> {
    match code {
        0 => Some(DriveState::Disabled),
        1 => Some(DriveState::Calibrating),
        2 => Some(DriveState::Starting),
        3 => Some(DriveState::Running),
        4 => Some(DriveState::Fault),
        5 => Some(DriveState::Reacquiring),
        6 => Some(DriveState::LowSpeed),
        7 => Some(DriveState::Commissioning),
        _ => None,
    }
}

impl Frame for ActuationFrame {
    const PAYLOAD_LEN: usize = ActuationFrame::PAYLOAD_LEN;

    fn write_payload(&self, payload: &mut [u8]) -> Result<(), EncodeError> {
        let duties = [self.duty_a, self.duty_b, self.duty_c];
        if !duties.iter().all(|&d| duty_ok(d)) || !self.estimate.is_none_or(|e| e.is_finite()) {
            return Err(EncodeError::InvalidValue);
        }
        let e = self.estimate.unwrap_or_default();
        let mut w = Writer::new(payload);
        w.u8(PROTOCOL_VERSION);
        w.u16(self.sequence);
        for d in duties {
            w.f32(d);
        }
        w.u8(self.flags());
        w.u8(self.state.code());
        w.u16(self.faults.bits());
        for x in [e.theta_hat, e.speed, e.psi_alpha, e.psi_beta] {
            w.f32(x);
        }
        w.u16(self.stats.malformed);
        w.u16(self.stats.bad_crc);
        w.u16(self.stats.out_of_order);
        w.finish(Self::PAYLOAD_LEN)
    }

    fn read_payload(payload: &[u8]) -> Result<Self, LinkError> {
        let mut r = Reader::new(payload, Self::PAYLOAD_LEN)?;
        r.version()?;
        let sequence = r.u16();
        let duty_a = r.duty()?;
        let duty_b = r.duty()?;
        let duty_c = r.duty()?;
        let flags = r.u8();
        if flags & !ACTUATION_FLAGS_KNOWN != 0 {
            return Err(LinkError::Flags);
        }
        let state = state_from_code(r.u8()).ok_or(LinkError::Value)?;
        let faults = Faults::from_bits(r.u16());
        let estimate_bytes = r.bytes::<16>();
        let estimate = if flags & ACTUATION_FLAG_ESTIMATE_VALID != 0 {
            let mut e = Reader::new(&estimate_bytes, 16)?;
            Some(EstimateReport {
                theta_hat: e.finite_f32()?,
                speed: e.finite_f32()?,
                psi_alpha: e.finite_f32()?,
                psi_beta: e.finite_f32()?,
            })
        } else if estimate_bytes.iter().any(|&b| b != 0) {
            return Err(LinkError::Value);
        } else {
            None
        };
        let stats = LinkStats { malformed: r.u16(), bad_crc: r.u16(), out_of_order: r.u16() };
        Ok(ActuationFrame {
            sequence,
            duty_a,
            duty_b,
            duty_c,
            bridge_enabled: flags & ACTUATION_FLAG_BRIDGE_ENABLED != 0,
            state,
            faults,
            estimate,
            stats,
        })
    }
}

/// Writes little-endian fields in sequence; never panics, notes a short buffer.
struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
    fits: bool,
}

impl<'a> Writer<'a> {
    fn new(buf: &'a mut [u8]) -> Self {
        Writer { buf, pos: 0, fits: true }
    }
    fn bytes(&mut self, bytes: &[u8]) {
        let end = self.pos.saturating_add(bytes.len());
        match self.buf.get_mut(self.pos..end) {
            // Element by element: the lengths are equal, but `copy_from_slice`'s length
            // check is a panic path the optimiser cannot always remove (`.ci/no-panic`).
            Some(dst) => dst.iter_mut().zip(bytes).for_each(|(d, s)| *d = *s),
            None => self.fits = false,
        }
        self.pos = end;
    }
    fn u8(&mut self, x: u8) {
        self.bytes(&[x]);
    }
    fn u16(&mut self, x: u16) {
        self.bytes(&x.to_le_bytes());
    }
    fn u32(&mut self, x: u32) {
        self.bytes(&x.to_le_bytes());
    }
    fn f32(&mut self, x: f32) {
        self.bytes(&x.to_le_bytes());
    }
    /// `Ok` when everything fit and exactly `len` bytes were written.
    fn finish(self, len: usize) -> Result<(), EncodeError> {
        if self.fits && self.pos == len && self.buf.len() == len {
            Ok(())
        } else {
            Err(EncodeError::BufferTooSmall { needed: len })
        }
    }
}

/// Reads little-endian fields from a payload whose length was checked. Reads past the end yield zeros (cannot happen after the check).
struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    /// A reader over `payload`, which must be exactly `len` bytes.
    fn new(payload: &'a [u8], len: usize) -> Result<Self, LinkError> {
        if payload.len() == len { Ok(Reader { buf: payload, pos: 0 }) } else { Err(LinkError::Length) }
    }
    /// Reads the version byte and checks it.
    fn version(&mut self) -> Result<(), LinkError> {
        if self.u8() == PROTOCOL_VERSION { Ok(()) } else { Err(LinkError::Version) }
    }
    fn bytes<const N: usize>(&mut self) -> [u8; N] {
        let end = self.pos.saturating_add(N);
        let out = self.buf.get(self.pos..end).and_then(|s| <[u8; N]>::try_from(s).ok()).unwrap_or([0; N]);
        self.pos = end;
        out
    }
    fn u8(&mut self) -> u8 {
        let [b] = self.bytes::<1>();
        b
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.bytes())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.bytes())
    }
    fn finite_f32(&mut self) -> Result<f32, LinkError> {
        let x = f32::from_le_bytes(self.bytes());
        if x.is_finite() { Ok(x) } else { Err(LinkError::Value) }
    }
    fn duty(&mut self) -> Result<f32, LinkError> {
        let x = f32::from_le_bytes(self.bytes());
        if duty_ok(x) { Ok(x) } else { Err(LinkError::Value) }
    }
}

/// Encodes `frame` into `out`: COBS(payload ‖ CRC) followed by the `0x00` delimiter.
/// Returns the bytes written, always `F::WIRE_LEN`.
///
/// # Errors
/// [`EncodeError::BufferTooSmall`] when `out` is shorter than `F::WIRE_LEN`
/// ([`SensorFrame::WIRE_LEN`], [`ActuationFrame::WIRE_LEN`]);
/// [`EncodeError::InvalidValue`] for a field the receiver would reject.
pub fn encode<F: Frame>(frame: &F, out: &mut [u8]) -> Result<usize, EncodeError> {
    let too_small = EncodeError::BufferTooSmall { needed: F::WIRE_LEN };
    if out.len() < F::WIRE_LEN {
        return Err(too_small);
    }
    let mut raw_buf = [0u8; MAX_RAW_LEN];
    let raw = raw_buf.get_mut(..F::RAW_LEN).ok_or(too_small)?;
    let (payload, crc) = raw.split_at_mut_checked(F::PAYLOAD_LEN).ok_or(too_small)?;
    frame.write_payload(payload)?;
    let sum = CRC16.checksum(payload).to_le_bytes();
    if crc.len() != sum.len() {
        return Err(too_small);
    }
    crc.copy_from_slice(&sum);
    let n = cobs::encode(raw, out).ok_or(too_small)?;
    *out.get_mut(n).ok_or(too_small)? = 0;
    Ok(n + 1)
}

/// Decodes one raw frame (COBS already removed): length, CRC, then the payload.
///
/// # Errors
/// [`LinkError::Length`], [`LinkError::Crc`], [`LinkError::Version`],
/// [`LinkError::Flags`] or [`LinkError::Value`], checked in that order.
pub fn decode_raw<F: Frame>(raw: &[u8]) -> Result<F, LinkError> {
    if raw.len() != F::RAW_LEN {
        return Err(LinkError::Length);
    }
    let (payload, crc) = raw.split_at_checked(F::PAYLOAD_LEN).ok_or(LinkError::Length)?;
    let sent = u16::from_le_bytes(<[u8; 2]>::try_from(crc).map_err(|_| LinkError::Length)?);
    if CRC16.checksum(payload) != sent {
        return Err(LinkError::Crc);
    }
    F::read_payload(payload)
}

/// Decodes one COBS-encoded frame (without its `0x00` delimiter) in place: `encoded`
/// is overwritten with the raw frame.
///
/// # Errors
/// [`LinkError::Cobs`] for an invalid encoding, then as [`decode_raw`].
pub fn decode_in_place<F: Frame>(encoded: &mut [u8]) -> Result<F, LinkError> {
    let n = cobs::decode_in_place(encoded).ok_or(LinkError::Cobs)?;
    decode_raw(encoded.get(..n).ok_or(LinkError::Cobs)?)
}

/// A streaming receiver for frames of type `F`, fed one byte at a time (e.g. from the
/// UART interrupt). No allocation, no panic; the work per byte is constant except at a
/// delimiter, where decoding takes at most [`RX_CAPACITY`] bytes' worth (a few
/// microseconds on a Cortex-M4).
#[derive(Clone, Debug)]
pub struct Receiver<F> {
    buf: [u8; RX_CAPACITY],
    len: usize,
    /// Skipping to the next delimiter after an overflow.
    skipping: bool,
    stats: LinkStats,
    frame: PhantomData<fn() -> F>,
}

impl<F: Frame> Default for Receiver<F> {
    fn default() -> Self {
        Self::new()
    }
}

impl<F: Frame> Receiver<F> {
    /// An empty receiver with zero counts.
    pub const fn new() -> Self {
        Receiver {
            buf: [0; RX_CAPACITY],
            len: 0,
            skipping: false,
            stats: LinkStats { malformed: 0, bad_crc: 0, out_of_order: 0 },
            frame: PhantomData,
        }
    }

    /// Takes one byte from the line. Returns `None` while a frame is incomplete (and for
    /// empty frames), `Some(Ok(frame))` at the delimiter of a good frame, and
    /// `Some(Err(_))` for a dropped frame, which is also counted in
    /// [`stats`](Self::stats). An overflow is reported at the byte that overflows; the
    /// rest of that frame is skipped silently up to the next `0x00`.
    pub fn push(&mut self, byte: u8) -> Option<Result<F, LinkError>> {
        if byte == 0 {
            let len = core::mem::take(&mut self.len);
            if core::mem::take(&mut self.skipping) || len == 0 {
                return None;
            }
            let result = match self.buf.get_mut(..len) {
                Some(encoded) => decode_in_place::<F>(encoded),
                None => Err(LinkError::Overflow),
            };
            if let Err(e) = result {
                self.stats.record(e);
            }
            return Some(result);
        }
        if self.skipping {
            return None;
        }
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                *slot = byte;
                self.len += 1;
                None
            }
            None => {
                self.len = 0;
                self.skipping = true;
                self.stats.record(LinkError::Overflow);
                Some(Err(LinkError::Overflow))
            }
        }
    }

    /// The counts of dropped frames.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// The counts, for adding frames dropped for their sequence number
    /// ([`LinkStats::record_out_of_order`]).
    pub fn stats_mut(&mut self) -> &mut LinkStats {
        &mut self.stats
    }

    /// Forgets a partial frame (the counts are kept).
    pub fn reset(&mut self) {
        self.len = 0;
        self.skipping = false;
    }
}

/// Where a sequence number stands relative to the last accepted one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SequenceOrder {
    /// Ahead by 1 to 32 767 (wrapping): accept. `skipped` frames were lost in between
    /// (0 for the very next one).
    InOrder {
        /// Sequence numbers skipped (frames).
        skipped: u16,
    },
    /// The same number again: drop.
    Duplicate,
    /// Behind (or exactly 32 768 away): drop.
    OutOfOrder,
}

/// Classifies sequence number `next` against the last accepted `last` (u16, wrapping
/// serial-number arithmetic): `next - last` (mod 2¹⁶) of 1..=32 767 is in order, 0 a
/// duplicate, 32 768..=65 535 out of order.
pub const fn classify_sequence(last: u16, next: u16) -> SequenceOrder {
    match next.wrapping_sub(last) {
        0 => SequenceOrder::Duplicate,
        d @ 1..=0x7FFF => SequenceOrder::InOrder { skipped: d - 1 },
        _ => SequenceOrder::OutOfOrder,
    }
}

/// The last accepted sequence number; the first frame (and the first after
/// [`reset`](Self::reset)) is always in order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SequenceTracker {
    last: Option<u16>,
}

impl SequenceTracker {
    /// A tracker that has accepted nothing yet.
    pub const fn new() -> Self {
        SequenceTracker { last: None }
    }

    /// Classifies `sequence` and, when it is in order, accepts it as the new last.
    pub fn check(&mut self, sequence: u16) -> SequenceOrder {
        let order = match self.last {
            None => SequenceOrder::InOrder { skipped: 0 },
            Some(last) => classify_sequence(last, sequence),
        };
        if let SequenceOrder::InOrder { .. } = order {
            self.last = Some(sequence);
        }
        order
    }

    /// The last accepted sequence number.
    pub const fn last(&self) -> Option<u16> {
        self.last
    }

    /// Forgets the last accepted number (after the watchdog tripped: a restarted host
    /// starts its numbering anew).
    pub fn reset(&mut self) {
        self.last = None;
    }
}

/// Control periods without an accepted frame after which the bridge must be off: 10,
/// i.e. 1 ms at the 100 µs default control period. One corrupted frame costs one period;
/// ten in a row is a dead link, not noise.
pub const SILENT_LINK_PERIODS: u16 = 10;

/// Silent-link watchdog: counts consecutive control periods without an accepted frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkWatchdog {
    silent: u16,
    limit: u16,
}

impl Default for LinkWatchdog {
    /// Trips after [`SILENT_LINK_PERIODS`].
    fn default() -> Self {
        Self::new(SILENT_LINK_PERIODS)
    }
}

impl LinkWatchdog {
    /// A watchdog that trips after `limit_periods` consecutive silent periods (at least
    /// 1).
    pub const fn new(limit_periods: u16) -> Self {
        LinkWatchdog { silent: 0, limit: if limit_periods == 0 { 1 } else { limit_periods } }
    }

    /// Call once per control period, telling whether a frame was accepted in it.
    /// Returns `true` when the bridge must be off: from the `limit`-th consecutive
    /// period without a frame until a frame is accepted again.
    pub fn period(&mut self, frame_accepted: bool) -> bool {
        self.silent = if frame_accepted { 0 } else { self.silent.saturating_add(1) };
        self.tripped()
    }

    /// `true` when the last `limit` or more periods had no accepted frame.
    pub const fn tripped(&self) -> bool {
        self.silent >= self.limit
    }

    /// Consecutive periods without an accepted frame (saturating).
    pub const fn silent_periods(&self) -> u16 {
        self.silent
    }

    /// The number of silent periods that trips the watchdog.
    pub const fn limit_periods(&self) -> u16 {
        self.limit
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
}

impl Default for LinkServer {
    fn default() -> Self {
        Self::new()
    }
}

impl LinkServer {
    /// A server with an empty receiver, no sequence history and the default watchdog
    /// ([`SILENT_LINK_PERIODS`]).
    pub fn new() -> Self {
        LinkServer {
            rx: Receiver::new(),
            sequence: SequenceTracker::new(),
            watchdog: LinkWatchdog::default(),
            last_reply: [0; ActuationFrame::WIRE_LEN],
            last_reply_len: 0,
        }
    }

    /// Feeds one received byte. When it completes an in-order sensor frame, applies its
    /// commands, runs `drive.step`, encodes the actuation frame into `out` and returns
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
        frame.apply_commands(drive);
        let step = drive.step(&frame.measurements(base));
        let reply = ActuationFrame::from_step(frame.sequence, &step, base, self.rx.stats());
        let n = encode(&reply, out).ok()?;
        self.last_reply = *out;
        self.last_reply_len = n;
        Some(n)
    }

    /// One watchdog period (call from a periodic interrupt; frames accepted in between
    /// restart the count). After [`SILENT_LINK_PERIODS`] periods in a row without an
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
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_match_the_documented_layouts() {
        assert_eq!((SensorFrame::RAW_LEN, SensorFrame::WIRE_LEN), (26, 28));
        assert_eq!((ActuationFrame::RAW_LEN, ActuationFrame::WIRE_LEN), (43, 45));
        assert_eq!(<SensorFrame as Frame>::WIRE_LEN, SensorFrame::WIRE_LEN);
        assert_eq!(<ActuationFrame as Frame>::WIRE_LEN, ActuationFrame::WIRE_LEN);
        assert_eq!(RX_CAPACITY, 44);
    }

    #[test]
    fn crc_is_ibm_3740() {
        assert_eq!(CRC16.checksum(b"123456789"), 0x29B1);
    }

    #[test]
    fn state_codes_round_trip() {
        for s in [
            DriveState::Disabled,
            DriveState::Calibrating,
            DriveState::Starting,
            DriveState::Running,
            DriveState::Fault,
            DriveState::Reacquiring,
            DriveState::LowSpeed,
            DriveState::Commissioning,
        ] {
            assert_eq!(state_from_code(s.code()), Some(s));
        }
        assert_eq!(DriveState::Commissioning.code(), 7);
        assert_eq!(state_from_code(8), None);
    }
}
