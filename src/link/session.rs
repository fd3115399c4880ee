//! The session: what the controller keeps between frames — the counts of dropped frames
//! ([`LinkStats`]), the sequence numbers ([`SequenceTracker`]) and the silent-link
//! watchdog ([`LinkWatchdog`]).

use super::wire::LinkError;

/// Frames dropped by the controller, each count saturating at `u16::MAX`. Sent back in
/// every [`ActuationFrame`](super::ActuationFrame).
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

    /// An in-order frame arrives after `skipped` sequence numbers for which no frame was
    /// accepted: those were control periods without one, in the host's own count. They are
    /// taken with the periods a periodic tick counted since the last frame, the larger of
    /// the two (a tick and a skipped number stand for the same period), and the frame then
    /// restarts the count. Returns `true` when that silence reached the limit: the bridge
    /// must be off before the frame is acted on. A host that numbers its frames by control
    /// period, as the lock-step host does, so measures a silence in its own time, which no
    /// wall clock on either side can stretch.
    pub fn frame_after(&mut self, skipped: u16) -> bool {
        let silent = self.silent.max(skipped);
        self.silent = 0;
        silent >= self.limit
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
