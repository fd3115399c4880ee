//! The hardware-in-the-loop serial link: a versioned pair of frames for a byte stream
//! (UART), shared by the firmware and the host.
//!
//! The link runs in lock-step. Each PWM period the host (the simulated plant) sends a
//! [`SensorFrame`]; the controller runs one [`Drive::step`](crate::drive::Drive::step) and answers with an
//! [`ActuationFrame`] that echoes the sensor frame's sequence number. Between periods
//! the host may send a [`CommissioningRequest`] (start the drive's commissioning with
//! the ratings, bus and pole pitch it is told, or ask how it stands); the controller
//! answers with a [`CommissioningReport`] (status, error, and once done the identified
//! values) and does not step. The controller tells the two frames it receives apart by
//! their length.
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
//! sent little-endian. For the lock-step frames (at most 138 raw bytes, 1,104 bits) the polynomial
//! has Hamming distance 4: every error of 1, 2 or 3 bits, every odd number of flipped
//! bits and every burst up to 16 bits is caught, and a random corruption that survives
//! COBS and the exact length check passes with probability 2⁻¹⁶ (0x1021 keeps distance
//! 4 up to 32,751 bits, far beyond any frame here). CRC-32 would catch more
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
//! | [`SensorFrame`] | 32 B | 34 B | 36 B |
//! | [`ActuationFrame`] | 56 B | 58 B | 60 B |
//! | [`CommissioningRequest`] | 21 B | 23 B | 25 B |
//! | [`CommissioningReport`] | 136 B | 138 B | 140 B |
//! | [`board::BoardCommand`] | 20 B | 22 B | 24 B |
//! | [`board::BoardTelemetry`] | 59 B | 61 B | 63 B |
//! | [`board::CaptureChunk`] | 225 B | 227 B | 229 B |
//!
//! The board link's frames ([`board`]: a drive image operated from the host) share the
//! framing; every frame type has its own length.
//!
//! COBS adds exactly one byte to a raw frame shorter than 254 bytes, whatever its
//! content, so the wire sizes are constant. With 8N1 framing (10 bits a byte) and a
//! 100 µs period the link needs 3.6 Mbit/s host → controller and 6.0 Mbit/s back.
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
//! | 23 | u8 | command flags ([`SENSOR_FLAG_ENABLE`], [`SENSOR_FLAG_CLEAR_FAULTS`], [`SENSOR_FLAG_MOVE`]) |
//! | 24 | f32 | move: target position (m) |
//! | 28 | f32 | move: dwell at the target (s) |
//!
//! Without [`SENSOR_FLAG_MOVE`] the two move fields are sent as zero bytes. A move is
//! queued on a positioning drive ([`Drive::push_move`](crate::drive::Drive::push_move))
//! before the frame's step; the host sends one move per frame, and only while the last
//! answer's [`PositionReport::moves_queued`] shows room (the queue is fixed capacity: a
//! refused move is counted in [`PositionReport::moves_rejected`], never acted on).
//!
//! [`ActuationFrame`] payload:
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | u8 | protocol version |
//! | 1 | u16 | sequence number (echo) |
//! | 3, 7, 11 | f32 | duties a, b, c (`[0, 1]`) |
//! | 15 | u8 | flags ([`ACTUATION_FLAG_BRIDGE_ENABLED`], [`ACTUATION_FLAG_ESTIMATE_VALID`], [`ACTUATION_FLAG_POSITION_VALID`], [`ACTUATION_FLAG_MOTION_IDLE`]) |
//! | 16 | u8 | drive state code, `0..`[`STATE_CODES`] (the drive's [`DriveState::code`](crate::drive::DriveState::code)) |
//! | 17 | u16 | fault bits (the drive's [`Faults::bits`](crate::drive::Faults::bits)) |
//! | 19 | f32 | θ̂ (electrical rad) |
//! | 23 | f32 | speed estimate (m/s) |
//! | 27, 31 | f32 | ψ_α, ψ_β (Wb) |
//! | 35, 37, 39 | u16 | frames dropped: malformed, bad CRC, out of order |
//! | 41 | f32 | x̂, the position estimate (m) |
//! | 45 | f32 | reference position of the motion profile (m) |
//! | 49 | f32 | reference speed of the motion profile (m/s) |
//! | 53 | u8 | moves queued (not counting the active one) |
//! | 54 | u16 | moves refused since start |
//!
//! Without an estimate the four estimate fields are sent as zero bytes; without a
//! [`PositionReport`] (a speed drive) the five position fields are, and the idle flag is
//! clear.
//!
//! [`CommissioningRequest`] payload (since version 2):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | u8 | protocol version |
//! | 1 | u16 | sequence number (the requester's, echoed; not a control period's) |
//! | 3 | u8 | action: [`COMMISSIONING_QUERY`] (0) or [`COMMISSIONING_START`] (1) |
//! | 4, 8 | f32 | rated current (A RMS), rated line voltage (V RMS) |
//! | 12, 16 | f32 | nominal DC bus (V), pole pitch (m) |
//! | 20 | u8 | reserved, 0 (keeps the length apart from the board link's command) |
//!
//! A query sends the four values as zero bytes.
//!
//! [`CommissioningReport`] payload (since version 2):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | u8 | protocol version |
//! | 1 | u16 | sequence number (echo of the request's) |
//! | 3 | u8 | status code ([`CommissioningStatus::code`]: idle, running, done, failed, refused) |
//! | 4 | u8 | error code, `1..=`[`COMMISSIONING_ERROR_CODES`] when failed or refused, else 0 |
//! | 5 | u16 | error detail: the drive's fault bits for error 9 (a fault of its own), else 0 |
//! | 7 | i8 | direction (+1) |
//! | 8, 12, 16, 20 | f32 | R (ohm, terminal), Ld (H), Lq (H), ψ_f (Wb) |
//! | 24, 28 | f32 | inverter voltage error (V per phase), its current band (A) |
//! | 32, 36 | f32 | mean bus during the sweep (V), commissioning time (s) |
//! | 40 + 8k, 44 + 8k | f32 | voltage-error curve point k = 0..12: current (A), error (V) |
//!
//! Unless done, bytes 7.. are zero. Error codes: 1 a bad setting (its name stays on the
//! controller), 2 bus out of range, 3 non-finite measurement, 4 open phase, 5 shorted
//! phase, 6 runaway current, 7 no back-EMF, 8 not a motor, 9 a fault of the drive.
//!
//! ## Rejected frames
//! A frame is checked in this order: COBS, length, CRC, version, flags (unknown bits or
//! an unknown commissioning action are an error), values (every `f32` finite, duties in
//! `[0, 1]`, a known state or status code, an error code that fits the status, zero
//! bytes in the move, estimate and position fields whose flag is clear and wherever a
//! field is absent, no idle flag without the position flag). A
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
//! must be turned off: trip the drive with [`Faults::EXTERNAL`](crate::drive::Faults::EXTERNAL) and
//! [`reset`](SequenceTracker::reset) the tracker, so a restarted host is accepted again.
//! The periods are counted by a periodic tick on the controller, and by the sequence
//! numbers an in-order frame skipped ([`LinkWatchdog::frame_after`]): the host numbers
//! its frames by period, so a gap of 10 is a silence of 10 periods in the host's own
//! time, and the drive trips before it steps on that frame.
//!
//! ## Modules
//! The protocol knows nothing of the drive. From the bottom up, each importing only
//! those below it: [`wire`] (the protocol version, the errors, the field reader and
//! writer), [`session`] (statistics, sequence numbers, watchdog), [`frame`] (constants,
//! the [`Frame`] trait, the frame types and their layouts, plain data and codes), the
//! board link's frames ([`board`]), [`codec`] (CRC, COBS framing, [`Receiver`]).
//! [`drive_adapter`] alone maps frames to and from the drive ([`crate::drive::Commands`],
//! measurements, state codes) and holds the controller side of the lock-step link
//! ([`LinkServer`]).
//!
//! ## Controller side, one PWM period
//! ```
//! use dcfo::link::{ActuationFrame, LinkWatchdog, Receiver, SensorFrame, SequenceOrder, SequenceTracker};
//!
//! let mut rx = Receiver::<SensorFrame>::new();
//! let mut sequence = SequenceTracker::new();
//! let mut watchdog = LinkWatchdog::default();
//! # let sent = SensorFrame { sequence: 7, i_a: 0.1, i_b: -0.05, i_c: -0.05, vdc: 48.0,
//! #     speed_ref: 0.3, enable: true, clear_faults: false, move_to: None };
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
//!     // frame.apply_commands(&mut drive) (a refused move: count it);
//!     // let out = drive.step(&frame.measurements(&Base::SI));
//!     // let reply = ActuationFrame::from_step(frame.sequence, &out, &Base::SI, rx.stats());
//!     // let n = dcfo::link::encode(&reply, &mut tx_buffer)?;
//! #   assert_eq!(frame, sent);
//! }
//! ```

pub mod board;
pub mod cobs;
pub mod codec;
pub mod drive_adapter;
pub mod frame;
pub mod session;
pub mod wire;

pub use codec::{RX_CAPACITY, Receiver, decode_in_place, decode_raw, encode};
pub use drive_adapter::BAD_SETTING_OVER_THE_LINK;
pub use drive_adapter::LinkServer;
pub use frame::{
    ACTUATION_FLAG_BRIDGE_ENABLED, ACTUATION_FLAG_ESTIMATE_VALID, ACTUATION_FLAG_MOTION_IDLE,
    ACTUATION_FLAG_POSITION_VALID, ActuationFrame, COMMISSIONING_ERROR_CODES, COMMISSIONING_QUERY,
    COMMISSIONING_START, CRC_LEN, CommissioningReport, CommissioningRequest, CommissioningStatus,
    EstimateReport, Frame, PositionReport, SENSOR_FLAG_CLEAR_FAULTS, SENSOR_FLAG_ENABLE, SENSOR_FLAG_MOVE,
    STATE_CODES, SensorFrame,
};
pub use session::{
    LinkStats, LinkWatchdog, SILENT_LINK_PERIODS, SequenceOrder, SequenceTracker, classify_sequence,
};
pub use wire::{EncodeError, LinkError, PROTOCOL_VERSION};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_match_the_documented_layouts() {
        assert_eq!((SensorFrame::RAW_LEN, SensorFrame::WIRE_LEN), (34, 36));
        assert_eq!((ActuationFrame::RAW_LEN, ActuationFrame::WIRE_LEN), (58, 60));
        assert_eq!(<SensorFrame as Frame>::WIRE_LEN, SensorFrame::WIRE_LEN);
        assert_eq!(<ActuationFrame as Frame>::WIRE_LEN, ActuationFrame::WIRE_LEN);
        assert_eq!(RX_CAPACITY, 59);
        assert_eq!((CommissioningRequest::RAW_LEN, CommissioningRequest::WIRE_LEN), (23, 25));
        assert_eq!((CommissioningReport::RAW_LEN, CommissioningReport::WIRE_LEN), (138, 140));
        assert_eq!(LinkServer::REPLY_LEN, 140);
        // The controller receives requests in the sensor frames' buffer, told apart by
        // length.
        const { assert!(CommissioningRequest::WIRE_LEN - 1 <= RX_CAPACITY) };
        assert_ne!(CommissioningRequest::RAW_LEN, SensorFrame::RAW_LEN);
        assert_eq!((board::BoardCommand::RAW_LEN, board::BoardCommand::WIRE_LEN), (22, 24));
        assert_eq!((board::BoardTelemetry::RAW_LEN, board::BoardTelemetry::WIRE_LEN), (61, 63));
        assert_eq!((board::CaptureChunk::RAW_LEN, board::CaptureChunk::WIRE_LEN), (227, 229));
        // Every frame type of the shared framing has its own length.
        let raw = [
            SensorFrame::RAW_LEN,
            ActuationFrame::RAW_LEN,
            CommissioningRequest::RAW_LEN,
            CommissioningReport::RAW_LEN,
            board::BoardCommand::RAW_LEN,
            board::BoardTelemetry::RAW_LEN,
            board::CaptureChunk::RAW_LEN,
        ];
        for (i, a) in raw.iter().enumerate() {
            assert!(raw[i + 1..].iter().all(|b| b != a), "{raw:?}");
        }
    }
}
