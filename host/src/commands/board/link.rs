//! The host's end of the board link: the serial transport and the drive's clock.
//!
//! One command, one answer: every [`BoardCommand`] carries the whole wish (enable,
//! speed, and once each: clear faults, arm the capture) and is answered with telemetry or,
//! when it asks for samples of a finished capture, with a [`CaptureChunk`]. The host
//! sends one at least every [`POLL_PERIOD`]; the image disables the drive after 0.5 s
//! without one, so a host that dies or hangs leaves the drive off.
//!
//! Where the host waits for the drive to do something (reach a state, a target, a speed)
//! it waits on the drive's own time, the control periods its telemetry counts
//! ([`DriveClock`]), not on the wall clock: on QEMU the drive's time follows the
//! instructions executed (`crate::qemu`), so a loaded machine makes it slower, and a
//! wall-clock limit would fail a drive that is only late. The wall clock only catches a
//! drive whose periods stop coming ([`DRIVE_STALL_LIMIT`]).

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use dcfo::algorithms::motion::Move;
use dcfo::drive::DriveState;
use dcfo::link::board::{BoardCommand, BoardTelemetry, CaptureChunk, NO_CAPTURE_READ};
use dcfo::link::{LinkError, decode_raw};

use super::capture::CaptureData;
use crate::commands::sim::fault_names;
use crate::target::ANSWER_TIMEOUT;

/// How long to wait for an answer before sending the command again (a booting QEMU can
/// lose the first bytes).
pub const RESEND_AFTER: Duration = Duration::from_millis(500);

/// Telemetry poll period of the live display and the demo: 20 Hz.
pub const POLL_PERIOD: Duration = Duration::from_millis(50);

/// The control period of the drive images, s (10 kHz).
pub const CONTROL_PERIOD_S: f64 = 1e-4;

/// Wall-clock time without a new control period after which a wait on the drive's time
/// gives up: the drive has stopped (a hung image, a halted board), it is not merely slow.
pub const DRIVE_STALL_LIMIT: Duration = Duration::from_secs(20);

/// The drive's own time as its telemetry reports it (control periods since a start), for
/// waits that must not depend on how fast the target runs against the wall clock; it
/// fails a wait only when no new period has come for [`DRIVE_STALL_LIMIT`].
#[derive(Clone, Copy, Debug)]
pub struct DriveClock {
    start: u32,
    last: u32,
    last_progress: Instant,
}

impl DriveClock {
    /// The drive's time from the periods of `t`.
    pub fn start(t: &BoardTelemetry) -> Self {
        DriveClock { start: t.periods, last: t.periods, last_progress: Instant::now() }
    }

    /// The drive's time since the start at telemetry `t`, s.
    ///
    /// # Errors
    /// No new control period for [`DRIVE_STALL_LIMIT`] (what the drive was doing goes in
    /// the message).
    pub fn elapsed_s(&mut self, t: &BoardTelemetry) -> anyhow::Result<f64> {
        if t.periods != self.last {
            self.last = t.periods;
            self.last_progress = Instant::now();
        } else if self.last_progress.elapsed() > DRIVE_STALL_LIMIT {
            bail!(
                "the drive's control periods stopped: none for {} s (drive {:?}, faults {})",
                DRIVE_STALL_LIMIT.as_secs(),
                t.state(),
                fault_names(t.faults())
            );
        }
        Ok(f64::from(t.periods.wrapping_sub(self.start)) * CONTROL_PERIOD_S)
    }
}

/// How long the drive has to report itself disabled after the command (its own time,
/// s): a few control periods are needed; the rest is margin.
pub const DISABLE_WITHIN_S: f64 = 2.0;

/// One answer of the drive image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Answer {
    /// The drive's state.
    Telemetry(BoardTelemetry),
    /// Capture samples.
    Chunk(CaptureChunk),
}

/// The host's end of the board link: commands out through `writer`, bytes in from a
/// reader thread, frames told apart by their length.
pub struct BoardLink<W: Write> {
    writer: W,
    incoming: mpsc::Receiver<std::io::Result<Vec<u8>>>,
    pending: VecDeque<u8>,
    frame: Vec<u8>,
    sequence: u16,
    /// Frames dropped: not a board-link answer (e.g. the image's banner), bad COBS or CRC.
    pub dropped_frames: u64,
    /// Why the last frame was dropped.
    pub last_drop: Option<LinkError>,
    /// Answers that came for another command than the one awaited (dropped).
    pub stale_answers: u64,
    /// Commands answered.
    pub round_trips: u64,
}

impl<W: Write> BoardLink<W> {
    /// A link writing to `writer` and reading from `reader` (moved to a thread).
    pub fn new(writer: W, reader: impl Read + Send + 'static) -> Self {
        let incoming = crate::hil_link::spawn_reader(reader);
        BoardLink {
            writer,
            incoming,
            pending: VecDeque::new(),
            frame: Vec::new(),
            sequence: 0,
            dropped_frames: 0,
            last_drop: None,
            stale_answers: 0,
            round_trips: 0,
        }
    }

    /// Sends `command` (its sequence number is set here) and waits for its answer,
    /// sending it again every [`RESEND_AFTER`] (the image applies a repeated command
    /// again, which changes nothing: commands are states, not steps).
    ///
    /// # Errors
    /// No answer within [`ANSWER_TIMEOUT`], the link closed, or a write failed.
    pub fn exchange(&mut self, mut command: BoardCommand) -> anyhow::Result<Answer> {
        self.sequence = self.sequence.wrapping_add(1);
        command.sequence = self.sequence;
        let mut wire = [0u8; BoardCommand::WIRE_LEN];
        let n = dcfo::link::encode(&command, &mut wire)
            .map_err(|e| anyhow::anyhow!("encoding a command: {e}"))?;
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        loop {
            // A 0x00 first ends any garbage on the line before the frame.
            self.writer
                .write_all(&[0])
                .and_then(|_| self.writer.write_all(&wire[..n]))
                .and_then(|_| self.writer.flush())
                .context("board link: write failed")?;
            let resend_at = (Instant::now() + RESEND_AFTER).min(deadline);
            loop {
                if let Some(answer) = self.next_answer() {
                    let sequence = match answer {
                        Answer::Telemetry(t) => t.sequence,
                        Answer::Chunk(c) => c.sequence,
                    };
                    if sequence == command.sequence {
                        self.round_trips += 1;
                        return Ok(answer);
                    }
                    self.stale_answers += 1;
                    continue;
                }
                let now = Instant::now();
                if now >= resend_at {
                    break;
                }
                match self.incoming.recv_timeout(resend_at - now) {
                    Ok(Ok(bytes)) => self.pending.extend(bytes),
                    Ok(Err(e)) => bail!("board link: read failed: {e}"),
                    Err(mpsc::RecvTimeoutError::Timeout) => break,
                    Err(mpsc::RecvTimeoutError::Disconnected) => bail!("board link: closed"),
                }
            }
            if Instant::now() >= deadline {
                let why = match self.last_drop {
                    Some(e) => format!("; {} frames dropped, the last for: {e}", self.dropped_frames),
                    None => {
                        String::from("; nothing received (a drive image with the board link on this port?)")
                    }
                };
                bail!(
                    "board link: no answer to command {} within {} s{why}",
                    command.sequence,
                    ANSWER_TIMEOUT.as_secs()
                );
            }
        }
    }

    /// The next complete answer in the bytes received so far.
    fn next_answer(&mut self) -> Option<Answer> {
        while let Some(byte) = self.pending.pop_front() {
            if byte != 0 {
                if self.frame.len() < 1024 {
                    self.frame.push(byte);
                }
                continue;
            }
            let mut frame = std::mem::take(&mut self.frame);
            if frame.is_empty() {
                continue;
            }
            match decode_answer(&mut frame) {
                Ok(answer) => return Some(answer),
                Err(e) => {
                    self.dropped_frames += 1;
                    self.last_drop = Some(e);
                }
            }
        }
        None
    }
}

/// Decodes one COBS-encoded frame (without its delimiter) as a board-link answer: a
/// [`BoardTelemetry`] or a [`CaptureChunk`], by its length.
///
/// # Errors
/// The frame's [`LinkError`] (COBS, length, CRC, version, flags, value).
pub fn decode_answer(encoded: &mut [u8]) -> Result<Answer, LinkError> {
    let n = dcfo::link::cobs::decode_in_place(encoded).ok_or(LinkError::Cobs)?;
    let raw = encoded.get(..n).ok_or(LinkError::Cobs)?;
    match raw.len() {
        BoardTelemetry::RAW_LEN => decode_raw::<BoardTelemetry>(raw).map(Answer::Telemetry),
        CaptureChunk::RAW_LEN => decode_raw::<CaptureChunk>(raw).map(Answer::Chunk),
        _ => Err(LinkError::Length),
    }
}

/// What the host wants of the drive; sent whole in every command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wish {
    /// Run the drive.
    pub enable: bool,
    /// Speed reference, m/s.
    pub speed_m_per_s: f32,
}

/// A drive image behind a [`BoardLink`], with the host's wish.
pub struct Board<W: Write> {
    /// The link.
    pub link: BoardLink<W>,
    /// Sent with every command.
    pub wish: Wish,
    /// A move to send with the next telemetry poll (then cleared: a move is queued once).
    pub pending_move: Option<Move>,
}

impl<W: Write> Board<W> {
    /// A board behind `link`, wished disabled at 0 m/s.
    pub fn new(link: BoardLink<W>) -> Self {
        Board { link, wish: Wish { enable: false, speed_m_per_s: 0.0 }, pending_move: None }
    }

    fn command(&self, clear_faults: bool, arm_capture: bool, capture_read: u32) -> BoardCommand {
        BoardCommand {
            sequence: 0,
            speed_ref: self.wish.speed_m_per_s,
            enable: self.wish.enable,
            clear_faults,
            arm_capture,
            capture_read,
            move_to: None,
        }
    }

    /// Sends the wish (with the one-off requests) and returns the telemetry.
    ///
    /// # Errors
    /// The link failed, or the image answered with samples to a telemetry request.
    pub fn poll(&mut self, clear_faults: bool, arm_capture: bool) -> anyhow::Result<BoardTelemetry> {
        let command = BoardCommand {
            move_to: self.pending_move.take(),
            ..self.command(clear_faults, arm_capture, NO_CAPTURE_READ)
        };
        match self.link.exchange(command)? {
            Answer::Telemetry(t) => Ok(t),
            Answer::Chunk(c) => {
                bail!("board link: capture samples (from {}) answered a telemetry request", c.first)
            }
        }
    }

    /// Downloads the finished capture's `len` samples.
    ///
    /// # Errors
    /// The link failed, the capture is not finished, a chunk is not the one asked for,
    /// or chunks disagree on the samples' format.
    pub fn download_capture(&mut self, len: u32) -> anyhow::Result<CaptureData> {
        let mut data = CaptureData::default();
        self.download_more(&mut data, len, u32::MAX)?;
        Ok(data)
    }

    /// Appends the finished capture's next samples to `samples`, at most `chunks`
    /// commands' worth, up to `len` in all (for a live display that keeps polling
    /// between slices of a download).
    ///
    /// # Errors
    /// As [`Board::download_capture`].
    pub fn download_more(&mut self, data: &mut CaptureData, len: u32, chunks: u32) -> anyhow::Result<()> {
        let mut asked = 0;
        while (data.samples.len() as u32) < len && asked < chunks {
            asked += 1;
            let first = data.samples.len() as u32;
            match self.link.exchange(self.command(false, false, first))? {
                Answer::Chunk(c) if c.first == first && c.count > 0 => {
                    if first == 0 {
                        data.format = c.format;
                    } else if c.format != data.format {
                        bail!(
                            "board link: capture chunk from sample {first} in {}, the samples before in {}",
                            c.format.name(),
                            data.format.name()
                        );
                    }
                    data.samples.extend_from_slice(c.valid());
                }
                Answer::Chunk(c) => bail!(
                    "board link: capture chunk from sample {} with {} samples, asked for sample {first} of {len}",
                    c.first,
                    c.count
                ),
                Answer::Telemetry(t) => bail!(
                    "board link: telemetry instead of capture samples (capture {:?}, {} samples)",
                    t.capture,
                    t.capture_len
                ),
            }
        }
        data.samples.truncate(len as usize);
        Ok(())
    }

    /// Disables the drive and waits until it reports so, at most [`DISABLE_WITHIN_S`] of
    /// its own time.
    ///
    /// # Errors
    /// The link failed, the drive still runs [`DISABLE_WITHIN_S`] after the command, or its
    /// periods stopped ([`DriveClock`]).
    pub fn disable(&mut self) -> anyhow::Result<BoardTelemetry> {
        self.wish.enable = false;
        let mut t = self.poll(false, false)?;
        let mut clock = DriveClock::start(&t);
        loop {
            if matches!(t.state(), DriveState::Disabled | DriveState::Fault) && !t.bridge_enabled {
                return Ok(t);
            }
            if clock.elapsed_s(&t)? > DISABLE_WITHIN_S {
                bail!(
                    "the drive still reports {:?} {DISABLE_WITHIN_S} s (its time) after the disable command",
                    t.state()
                );
            }
            std::thread::sleep(Duration::from_millis(10));
            t = self.poll(false, false)?;
        }
    }
}

/// [`Board`] without its writer type, for `with_board`.
pub trait BoardOps {
    /// See [`Board::poll`].
    fn poll(&mut self, clear_faults: bool, arm_capture: bool) -> anyhow::Result<BoardTelemetry>;
    /// See [`Board::download_capture`].
    fn download_capture(&mut self, len: u32) -> anyhow::Result<CaptureData>;
    /// See [`Board::download_more`].
    fn download_more(&mut self, data: &mut CaptureData, len: u32, chunks: u32) -> anyhow::Result<()>;
    /// See [`Board::disable`].
    fn disable(&mut self) -> anyhow::Result<BoardTelemetry>;
    /// The wish sent with every command.
    fn wish_mut(&mut self) -> &mut Wish;
    /// Commands answered so far.
    fn round_trips(&self) -> u64;
    /// Sends `m` with the next [`poll`](BoardOps::poll) (once).
    fn queue_move(&mut self, m: Move);
}

impl<W: Write> BoardOps for Board<W> {
    fn poll(&mut self, clear_faults: bool, arm_capture: bool) -> anyhow::Result<BoardTelemetry> {
        Board::poll(self, clear_faults, arm_capture)
    }
    fn download_capture(&mut self, len: u32) -> anyhow::Result<CaptureData> {
        Board::download_capture(self, len)
    }
    fn download_more(&mut self, data: &mut CaptureData, len: u32, chunks: u32) -> anyhow::Result<()> {
        Board::download_more(self, data, len, chunks)
    }
    fn disable(&mut self) -> anyhow::Result<BoardTelemetry> {
        Board::disable(self)
    }
    fn wish_mut(&mut self) -> &mut Wish {
        &mut self.wish
    }
    fn round_trips(&self) -> u64 {
        self.link.round_trips
    }
    fn queue_move(&mut self, m: Move) {
        self.pending_move = Some(m);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dcfo::capture::CaptureState;
    use dcfo::drive::Faults;

    #[test]
    fn answers_are_told_apart_by_length_and_garbage_is_refused() {
        let t = BoardTelemetry {
            sequence: 3,
            state_code: DriveState::Running.code(),
            fault_bits: Faults::NONE.bits(),
            bridge_enabled: true,
            estimate: Some((0.5, 0.3)),
            i_ab_a: [1.0, 2.0],
            vdc_v: 311.0,
            speed_ref: 0.3,
            capture: CaptureState::Done,
            capture_len: 5,
            capture_capacity: 10,
            periods: 9,
            position: None,
        };
        let mut wire = [0u8; 300];
        let n = dcfo::link::encode(&t, &mut wire).unwrap();
        assert_eq!(decode_answer(&mut wire[..n - 1].to_vec()), Ok(Answer::Telemetry(t)));
        let mut banner = b"dcfo-firmware qemu_drive".to_vec();
        assert!(decode_answer(&mut banner).is_err());
    }

    /// An image that answers only garbage: the error names the command, the wait and
    /// why the last frame was dropped.
    #[test]
    fn no_answer_is_an_error_naming_the_last_bad_frame() {
        let (ours, mut theirs) = std::os::unix::net::UnixStream::pair().unwrap();
        let reader = ours.try_clone().unwrap();
        let t = BoardTelemetry {
            sequence: 1,
            state_code: DriveState::Disabled.code(),
            fault_bits: Faults::NONE.bits(),
            bridge_enabled: false,
            estimate: None,
            i_ab_a: [0.0; 2],
            vdc_v: 24.0,
            speed_ref: 0.0,
            capture: CaptureState::Idle,
            capture_len: 0,
            capture_capacity: 128,
            periods: 0,
            position: None,
        };
        let mut wire = [0u8; 64];
        let n = dcfo::link::encode(&t, &mut wire).unwrap();
        // One bit of the payload flipped under a valid COBS encoding: the CRC fails.
        let raw_len = dcfo::link::cobs::decode_in_place(&mut wire[..n - 1]).unwrap();
        wire[5] ^= 0x01;
        let mut corrupted = [0u8; 64];
        let m = dcfo::link::cobs::encode(&wire[..raw_len], &mut corrupted).unwrap();
        theirs.write_all(b"banner\0").unwrap();
        theirs.write_all(&corrupted[..m]).unwrap();
        theirs.write_all(&[0]).unwrap();
        let mut board = Board::new(BoardLink::new(ours, reader));
        let e = board.poll(false, false).unwrap_err().to_string();
        assert!(e.contains("no answer to command 1 within 5 s"), "{e}");
        assert!(e.contains("2 frames dropped, the last for: CRC mismatch"), "{e}");
        drop(theirs);
    }
}
