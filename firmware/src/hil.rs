//! The firmware side of the lock-step HIL link on any board: received bytes in, encoded
//! answers out through a transmit queue, the silent-link watchdog in between.
//!
//! The receive interrupt calls [`HilServer::on_byte`] for each byte; a lower-priority
//! context moves the queue into the UART; a periodic timer calls
//! [`HilServer::watchdog_period`]. An answer goes into the queue whole or not at all (a
//! full queue drops it and counts it): half an answer on the wire would cost the next
//! one too.
//!
//! The link also counts the sequence numbers a frame skipped as silent periods
//! (`LinkWatchdog::frame_after`): the host numbers its frames by control period, so an
//! image with no timer (the QEMU one, whose clock must not be the host's) still trips on a
//! silence, measured in the host's periods rather than in anybody's wall clock.

use crate::queue::Producer;
use dcfo::drive::Drive;
use dcfo::link::{ActuationFrame, LinkServer, LinkStats};
use dcfo::num::Scalar;

/// The drive behind the HIL link, owned by the receive interrupt.
#[derive(Clone, Debug)]
pub struct HilServer<T> {
    drive: Drive<T>,
    link: LinkServer,
    reply: [u8; LinkServer::REPLY_LEN],
    answers_dropped: u32,
}

/// Bytes a transmit queue needs for `answers` lock-step answers, or one commissioning
/// report if that is longer.
pub const fn tx_queue_bytes(answers: usize) -> usize {
    let a = answers * ActuationFrame::WIRE_LEN;
    if a > LinkServer::REPLY_LEN { a } else { LinkServer::REPLY_LEN }
}

impl<T: Scalar> HilServer<T> {
    /// Serves `drive` (its working-unit base is taken from it).
    pub fn new(drive: Drive<T>) -> Self {
        HilServer { drive, link: LinkServer::new(), reply: [0; LinkServer::REPLY_LEN], answers_dropped: 0 }
    }

    /// One received byte. When it completes an in-order sensor frame, the drive steps
    /// once and its answer is queued for transmission; a commissioning request is
    /// answered with its report (a start replaces the drive: `LinkServer::on_byte`).
    pub fn on_byte<const N: usize>(&mut self, byte: u8, tx: &mut Producer<'_, u8, N>) {
        // The drive's own base: a start request may replace the drive and its base.
        let base = *self.drive.base();
        let Some(n) = self.link.on_byte(byte, &mut self.drive, &base, &mut self.reply) else {
            return;
        };
        let Some(answer) = self.reply.get(..n) else { return };
        if !tx.enqueue_all(answer) {
            self.answers_dropped = self.answers_dropped.saturating_add(1);
        }
    }

    /// One watchdog period (from a periodic timer): see
    /// [`LinkServer::silent_period`]. Returns `true` while the link is silent past the
    /// limit.
    pub fn watchdog_period(&mut self) -> bool {
        self.link.silent_period(&mut self.drive)
    }

    /// Trips the drive with an external fault (e.g. an interrupt without a handler).
    pub fn trip(&mut self) {
        self.drive.trip(dcfo::drive::Faults::EXTERNAL);
    }

    /// Answers dropped because the transmit queue was full.
    pub fn answers_dropped(&self) -> u32 {
        self.answers_dropped
    }

    /// The link statistics (bad frames, out-of-order frames).
    pub fn link_stats(&self) -> LinkStats {
        self.link.stats()
    }

    /// The drive (for inspection).
    pub fn drive(&self) -> &Drive<T> {
        &self.drive
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::queue::{Consumer, Queue};
    use dcfo::algorithms::observer::ObserverKind;
    use dcfo::drive::{DriveConfig, DriveState};
    use dcfo::link::{Receiver, SensorFrame, encode};
    use dcfo::motor::MotorParams;
    use dcfo::num::units::Base;

    fn server() -> HilServer<f32> {
        let m = MotorParams::paper();
        HilServer::new(
            Drive::new(&m, &DriveConfig::for_motor(&m, 311.0, ObserverKind::Dcfo), &Base::SI).unwrap(),
        )
    }

    fn frame(sequence: u16) -> heapless::Vec<u8, { SensorFrame::WIRE_LEN }> {
        let f = SensorFrame {
            sequence,
            i_a: 0.0,
            i_b: 0.0,
            i_c: 0.0,
            vdc: 311.0,
            speed_ref: 0.3,
            enable: true,
            clear_faults: false,
            move_to: None,
        };
        let mut wire = [0u8; SensorFrame::WIRE_LEN];
        let n = encode(&f, &mut wire).unwrap();
        heapless::Vec::from_slice(&wire[..n]).unwrap()
    }

    /// Every answer waiting in the transmit queue, decoded.
    fn answers<const N: usize>(rx: &mut Consumer<'_, u8, N>) -> heapless::Vec<ActuationFrame, 4> {
        let mut receiver = Receiver::<ActuationFrame>::new();
        core::iter::from_fn(|| rx.dequeue()).filter_map(|b| receiver.push(b)).map(|r| r.unwrap()).collect()
    }

    #[test]
    fn answers_are_queued_whole_or_dropped_and_counted() {
        let mut s = server();
        // Room for one answer and a bit, not two.
        let mut q: Queue<u8, { ActuationFrame::WIRE_LEN + 11 }> = Queue::new();
        let (mut tx, mut rx) = q.split();
        for b in frame(0) {
            s.on_byte(b, &mut tx);
        }
        for b in frame(1) {
            s.on_byte(b, &mut tx);
        }
        assert_eq!(s.answers_dropped(), 1);
        // What is queued is exactly one valid answer, to frame 0.
        let got = answers(&mut rx);
        assert_eq!(got.len(), 1);
        assert_eq!((got[0].sequence, got[0].state()), (0, DriveState::Calibrating));
        // With room again the next frame is answered.
        for b in frame(2) {
            s.on_byte(b, &mut tx);
        }
        assert_eq!(rx.len(), ActuationFrame::WIRE_LEN);
        assert_eq!(s.link_stats(), LinkStats::default());
    }

    #[test]
    fn a_duplicate_of_the_last_frame_is_answered_again_without_a_second_step() {
        let mut s = server();
        let mut q: Queue<u8, 256> = Queue::new();
        let (mut tx, mut rx) = q.split();
        // Frame 0, then the same frame again (a host whose answer got lost resends it).
        for _ in 0..2 {
            for b in frame(0) {
                s.on_byte(b, &mut tx);
            }
        }
        let bytes: heapless::Vec<u8, 256> = core::iter::from_fn(|| rx.dequeue()).collect();
        assert_eq!(bytes.len(), 2 * ActuationFrame::WIRE_LEN);
        let (first, second) = bytes.split_at(ActuationFrame::WIRE_LEN);
        assert_eq!(first, second, "the same answer, byte for byte");
        assert_eq!(s.link_stats().out_of_order, 1);
        // The drive stepped once: the next frame is answered as frame 1 of its run.
        for b in frame(1) {
            s.on_byte(b, &mut tx);
        }
        let got = answers(&mut rx);
        assert_eq!(got.len(), 1);
        assert_eq!(got[0].sequence, 1);
        // A frame behind the last one is still dropped, unanswered.
        for b in frame(0) {
            s.on_byte(b, &mut tx);
        }
        assert!(rx.dequeue().is_none());
    }

    #[test]
    fn the_watchdog_trips_an_active_drive() {
        let mut s = server();
        let mut q: Queue<u8, 128> = Queue::new();
        let (mut tx, _rx) = q.split();
        for b in frame(0) {
            s.on_byte(b, &mut tx);
        }
        assert_eq!(s.drive().state(), DriveState::Calibrating);
        let trips: usize =
            (0..dcfo::link::SILENT_LINK_PERIODS).map(|_| usize::from(s.watchdog_period())).sum();
        assert_eq!(trips, 1);
        assert_eq!(s.drive().state(), DriveState::Fault);
    }

    /// A frame that skips 10 sequence numbers (the host sent none for 10 periods) trips
    /// an active drive before it steps, and that frame's answer reports it; frames that
    /// follow each other never trip it, however long the host takes between them.
    #[test]
    fn a_frame_after_ten_silent_periods_is_answered_with_the_trip() {
        let mut s = server();
        let mut q: Queue<u8, 256> = Queue::new();
        let (mut tx, mut rx) = q.split();
        for seq in 0..20u16 {
            for b in frame(seq) {
                s.on_byte(b, &mut tx);
            }
            let got = answers(&mut rx);
            assert_ne!(got[0].state(), DriveState::Fault, "frame {seq}");
        }
        for b in frame(20 + dcfo::link::SILENT_LINK_PERIODS) {
            s.on_byte(b, &mut tx);
        }
        let got = answers(&mut rx);
        assert_eq!(got.len(), 1);
        assert_eq!(got[0].state(), DriveState::Fault);
        assert!(got[0].faults().contains(dcfo::drive::Faults::EXTERNAL));
    }
}
