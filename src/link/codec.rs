//! The codec: a frame's payload and CRC-16 in COBS with a `0x00` delimiter
//! ([`encode`], [`decode_raw`], [`decode_in_place`]) and the streaming [`Receiver`].

use core::marker::PhantomData;

use crate::num::checksum::crc16;

use super::board;
use super::cobs;
use super::frame::{ActuationFrame, Frame};
use super::session::LinkStats;
use super::wire::{EncodeError, LinkError};

/// Capacity of a [`Receiver`]'s buffer (bytes): the largest COBS-encoded frame, the
/// [`ActuationFrame`], without its delimiter. A longer frame is reported as
/// [`LinkError::Overflow`].
/// (The [`CommissioningReport`](super::CommissioningReport) is longer: the host, which
/// receives it, decodes it with [`decode_in_place`] from a buffer of its own.)
pub const RX_CAPACITY: usize = ActuationFrame::WIRE_LEN - 1;

/// The largest raw frame (payload + CRC, bytes): the board link's capture chunk.
pub(super) const MAX_RAW_LEN: usize = board::CaptureChunk::RAW_LEN;

// COBS adds exactly one byte only below 254 raw bytes.
const _: () = assert!(MAX_RAW_LEN < 254);

/// Encodes `frame` into `out`: COBS(payload ‖ CRC) followed by the `0x00` delimiter.
/// Returns the bytes written, always `F::WIRE_LEN`.
///
/// # Errors
/// [`EncodeError::BufferTooSmall`] when `out` is shorter than `F::WIRE_LEN`
/// ([`SensorFrame::WIRE_LEN`](super::SensorFrame::WIRE_LEN), [`ActuationFrame::WIRE_LEN`]);
/// [`EncodeError::InvalidValue`] for a field the receiver would reject.
pub fn encode<F: Frame>(frame: &F, out: &mut [u8]) -> Result<usize, EncodeError> {
    let too_small = EncodeError::BufferTooSmall { needed: F::WIRE_LEN };
    if out.len() < F::WIRE_LEN {
        return Err(too_small);
    }
    let mut raw_buf = [0u8; MAX_RAW_LEN];
    let raw = raw_buf.get_mut(..F::RAW_LEN).ok_or(too_small)?;
    frame.write_payload(raw.get_mut(..F::PAYLOAD_LEN).ok_or(too_small)?)?;
    seal(raw, F::PAYLOAD_LEN, out).ok_or(too_small)
}

/// The frame-independent end of [`encode`]: the CRC of `raw[..payload_len]` into the
/// two bytes after it, then COBS into `out` and the delimiter; the bytes written, `None`
/// when `raw` or `out` is too short. Not inlined: one copy serves every frame type
/// (inlined into each `encode::<F>`, the CRC and COBS loops cost about 0.5 KB of flash
/// per frame type in an image).
#[inline(never)]
fn seal(raw: &mut [u8], payload_len: usize, out: &mut [u8]) -> Option<usize> {
    let (payload, crc) = raw.split_at_mut_checked(payload_len)?;
    let sum = crc16(payload).to_le_bytes();
    if crc.len() != sum.len() {
        return None;
    }
    crc.copy_from_slice(&sum);
    let n = cobs::encode(raw, out)?;
    *out.get_mut(n)? = 0;
    Some(n + 1)
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
    F::read_payload(checked_payload(raw, F::PAYLOAD_LEN)?)
}

/// The frame-independent start of [`decode_raw`]: the payload `raw[..payload_len]` if
/// the two bytes after it are its CRC. Not inlined, as [`seal`].
///
/// # Errors
/// [`LinkError::Length`] when `raw` is not `payload_len + 2` bytes, [`LinkError::Crc`].
#[inline(never)]
fn checked_payload(raw: &[u8], payload_len: usize) -> Result<&[u8], LinkError> {
    let (payload, crc) = raw.split_at_checked(payload_len).ok_or(LinkError::Length)?;
    let sent = u16::from_le_bytes(<[u8; 2]>::try_from(crc).map_err(|_| LinkError::Length)?);
    if crc16(payload) != sent {
        return Err(LinkError::Crc);
    }
    Ok(payload)
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
        let n = match self.take(byte)? {
            Ok(n) => n,
            Err(e) => return Some(Err(e)),
        };
        let result = self.buf.get(..n).ok_or(LinkError::Cobs).and_then(decode_raw::<F>);
        if let Err(e) = result {
            self.stats.record(e);
        }
        Some(result)
    }

    /// Takes one byte from the line like [`push`](Self::push), but at a delimiter
    /// returns the raw frame (COBS removed: payload and CRC, not yet checked) for the
    /// caller to decode as the frame type its length names ([`decode_raw`]): the
    /// controller receives [`SensorFrame`](super::SensorFrame)s and
    /// [`CommissioningRequest`](super::CommissioningRequest)s on one line. Only COBS
    /// and overflow errors are counted here; count the decoding's with
    /// [`stats_mut`](Self::stats_mut) ([`LinkStats::record`]).
    pub fn push_raw(&mut self, byte: u8) -> Option<Result<&[u8], LinkError>> {
        match self.take(byte)? {
            Ok(n) => Some(self.buf.get(..n).ok_or(LinkError::Cobs)),
            Err(e) => Some(Err(e)),
        }
    }

    /// The byte-level work of [`push`](Self::push): at a delimiter the COBS-decoded
    /// frame's length (the raw frame is then in `buf[..n]`) or the COBS or overflow
    /// error, counted here.
    fn take(&mut self, byte: u8) -> Option<Result<usize, LinkError>> {
        if byte == 0 {
            let len = core::mem::take(&mut self.len);
            if core::mem::take(&mut self.skipping) || len == 0 {
                return None;
            }
            let result = match self.buf.get_mut(..len) {
                Some(encoded) => cobs::decode_in_place(encoded).ok_or(LinkError::Cobs),
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
