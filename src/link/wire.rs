//! The wire: the protocol version, the errors, and the little-endian field writer and
//! reader every frame layout uses. The bottom of the link: it knows no frame.

/// The protocol version carried in byte 0 of every frame; any other value is rejected.
///
/// Version 2 (from 1) added the move command to [`SensorFrame`](super::SensorFrame), the
/// position report to [`ActuationFrame`](super::ActuationFrame), the commissioning frames
/// ([`CommissioningRequest`](super::CommissioningRequest),
/// [`CommissioningReport`](super::CommissioningReport)), and, on the board link, the format of the drive's own words
/// to [`CaptureChunk`](super::board::CaptureChunk) (1: SI `f32` converted on the target),
/// the move command to [`BoardCommand`](super::board::BoardCommand) (flag
/// [`BOARD_FLAG_MOVE`](super::board::BOARD_FLAG_MOVE), 12 to 20 bytes) and the position
/// report to [`BoardTelemetry`](super::board::BoardTelemetry) (44 to 59 bytes).
pub const PROTOCOL_VERSION: u8 = 2;

/// `true` for a duty the link carries: within `[0, 1]`.
pub(super) fn duty_ok(d: f32) -> bool {
    (0.0..=1.0).contains(&d)
}

/// Why a received frame was dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkError {
    /// More bytes than [`RX_CAPACITY`](super::RX_CAPACITY) before a delimiter (the rest is skipped up to
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
    /// unknown drive-state code, or move, estimate or position bytes (or the idle flag)
    /// sent without their flag.
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

/// Writes little-endian fields in sequence; never panics, notes a short buffer.
pub(super) struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
    fits: bool,
}

impl<'a> Writer<'a> {
    pub(super) fn new(buf: &'a mut [u8]) -> Self {
        Writer { buf, pos: 0, fits: true }
    }
    pub(super) fn bytes(&mut self, bytes: &[u8]) {
        let end = self.pos.saturating_add(bytes.len());
        match self.buf.get_mut(self.pos..end) {
            // Element by element: the lengths are equal, but `copy_from_slice`'s length
            // check is a panic path the optimiser cannot always remove (`.ci/no-panic`).
            Some(dst) => dst.iter_mut().zip(bytes).for_each(|(d, s)| *d = *s),
            None => self.fits = false,
        }
        self.pos = end;
    }
    pub(super) fn u8(&mut self, x: u8) {
        self.bytes(&[x]);
    }
    pub(super) fn u16(&mut self, x: u16) {
        self.bytes(&x.to_le_bytes());
    }
    pub(super) fn u32(&mut self, x: u32) {
        self.bytes(&x.to_le_bytes());
    }
    pub(super) fn f32(&mut self, x: f32) {
        self.bytes(&x.to_le_bytes());
    }
    /// `Ok` when everything fit and exactly `len` bytes were written.
    pub(super) fn finish(self, len: usize) -> Result<(), EncodeError> {
        if self.fits && self.pos == len && self.buf.len() == len {
            Ok(())
        } else {
            Err(EncodeError::BufferTooSmall { needed: len })
        }
    }
}

/// Reads little-endian fields from a payload whose length was checked. Reads past the
/// end yield zeros (cannot happen after the check).
pub(super) struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    /// A reader over `payload`, which must be exactly `len` bytes.
    pub(super) fn new(payload: &'a [u8], len: usize) -> Result<Self, LinkError> {
        if payload.len() == len { Ok(Reader { buf: payload, pos: 0 }) } else { Err(LinkError::Length) }
    }
    /// Reads the version byte and checks it.
    pub(super) fn version(&mut self) -> Result<(), LinkError> {
        if self.u8() == PROTOCOL_VERSION { Ok(()) } else { Err(LinkError::Version) }
    }
    pub(super) fn bytes<const N: usize>(&mut self) -> [u8; N] {
        let end = self.pos.saturating_add(N);
        let out = self.buf.get(self.pos..end).and_then(|s| <[u8; N]>::try_from(s).ok()).unwrap_or([0; N]);
        self.pos = end;
        out
    }
    pub(super) fn u8(&mut self) -> u8 {
        let [b] = self.bytes::<1>();
        b
    }
    pub(super) fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.bytes())
    }
    pub(super) fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.bytes())
    }
    pub(super) fn finite_f32(&mut self) -> Result<f32, LinkError> {
        let x = f32::from_le_bytes(self.bytes());
        if x.is_finite() { Ok(x) } else { Err(LinkError::Value) }
    }
    pub(super) fn duty(&mut self) -> Result<f32, LinkError> {
        let x = f32::from_le_bytes(self.bytes());
        if duty_ok(x) { Ok(x) } else { Err(LinkError::Value) }
    }
}
