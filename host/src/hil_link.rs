//! The host end of the hardware-in-the-loop link ([`SerialController`]): the plant
//! simulation in lock-step with a drive behind the serial link of [`dcfo::link`] — the
//! firmware on QEMU's `mps2-an386` (Cortex-M4F, f32)
//! or `mps2-an385` (Cortex-M3, Q8.24) board, UART0 on QEMU's standard I/O, or a board on
//! a serial port.
//!
//! Per PWM period the host sends one [`SensorFrame`] and waits for the
//! [`ActuationFrame`] with the same sequence number; the plant then runs the period with
//! the duties of the previous answer ([`crate::closed_loop`]), exactly as in the
//! in-process simulation ([`crate::simulation::run_with`]). The firmware runs the same drive code as
//! [`crate::simulation::LocalDrive`] of the same numeric type, so the angle estimates equal the
//! in-process run's bit for bit: f32 is IEEE on both sides, and Q8.24 is integer
//! arithmetic (the f32 conversions at its edges are IEEE too, in software on the M3).

use crate::simulation::{ControlStep, Controller, SimError};
use dcfo::link::{ActuationFrame, CommissioningReport, CommissioningRequest, Receiver, SensorFrame, encode};
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use crate::qemu::{GuestClock, QemuCpu, QemuSession, build_qemu_example, qemu_example_elf};
use crate::target::ANSWER_TIMEOUT;
use std::process::ChildStdin;
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Until the target has answered once, how long to wait before sending the frame again.
pub const START_RESEND: Duration = Duration::from_millis(500);

/// A drive behind a byte-stream link: frames out through `writer`, bytes in from a
/// reader thread.
pub struct SerialController<W: Write> {
    writer: W,
    incoming: mpsc::Receiver<std::io::Result<Vec<u8>>>,
    pending: VecDeque<u8>,
    receiver: Receiver<ActuationFrame>,
    /// Frames that arrived with a sequence number other than the one awaited (dropped).
    pub stale_frames: u64,
    /// Lock-step round trips completed.
    pub round_trips: u64,
    started: Instant,
    /// The last frame written, as sent (for the start-up resend).
    last_sent: Vec<u8>,
    /// Sequence number of the next commissioning request.
    request_sequence: u16,
}

/// Reads `reader` on a thread of its own and hands what arrives to the returned
/// channel, chunk by chunk, so that a link's owner can wait with a timeout; the end of
/// the stream arrives as an `UnexpectedEof` error, a read error as itself, and the
/// thread ends after either (or when the receiver is dropped). Shared by `dcfo hil`
/// and `dcfo board`.
pub(crate) fn spawn_reader(
    mut reader: impl Read + Send + 'static,
) -> mpsc::Receiver<std::io::Result<Vec<u8>>> {
    let (tx, incoming) = mpsc::channel();
    std::thread::spawn(move || {
        let mut buf = [0u8; 1024];
        loop {
            match reader.read(&mut buf) {
                Ok(0) => {
                    let _ =
                        tx.send(Err(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "link closed")));
                    return;
                }
                Ok(n) => {
                    if tx.send(Ok(buf[..n].to_vec())).is_err() {
                        return;
                    }
                }
                Err(e) => {
                    let _ = tx.send(Err(e));
                    return;
                }
            }
        }
    });
    incoming
}

impl<W: Write> SerialController<W> {
    /// A controller writing to `writer` and reading from `reader` (moved to a thread).
    pub fn new(writer: W, reader: impl Read + Send + 'static) -> Self {
        let incoming = spawn_reader(reader);
        SerialController {
            writer,
            incoming,
            pending: VecDeque::new(),
            receiver: Receiver::new(),
            stale_frames: 0,
            round_trips: 0,
            started: Instant::now(),
            last_sent: Vec::new(),
            request_sequence: 0,
        }
    }

    /// Sends a commissioning request (`start`: the settings to start with; `None`: a
    /// query) and waits for its report. The request is numbered here. Until the first
    /// lock-step answer has arrived (the target may be booting) the request is sent again
    /// every [`START_RESEND`]: a start that arrives twice before any sensor frame builds
    /// the same drive twice, and a query changes nothing.
    ///
    /// # Errors
    /// The link fails or no report arrives within [`ANSWER_TIMEOUT`].
    pub fn commissioning(
        &mut self,
        start: Option<dcfo::drive::CommissioningConfig>,
    ) -> Result<CommissioningReport, SimError> {
        let sequence = self.request_sequence;
        self.request_sequence = self.request_sequence.wrapping_add(1);
        let request = CommissioningRequest { sequence, start };
        let mut buf = [0u8; CommissioningRequest::WIRE_LEN];
        let n = encode(&request, &mut buf).map_err(|e| SimError::Controller(format!("encoding: {e}")))?;
        self.send_raw(&buf[..n])?;
        // The report is longer than the lock-step receiver's buffer: frames are split
        // at their delimiters here and decoded as reports; anything else is dropped.
        let mut frame = Vec::with_capacity(CommissioningReport::WIRE_LEN);
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        let mut resend_at = Instant::now() + START_RESEND;
        loop {
            while let Some(byte) = self.pending.pop_front() {
                if byte != 0 {
                    frame.push(byte);
                    continue;
                }
                let got = dcfo::link::decode_in_place::<CommissioningReport>(&mut frame);
                frame.clear();
                match got {
                    Ok(report) if report.sequence == sequence => return Ok(report),
                    Ok(_) => self.stale_frames += 1,
                    Err(_) => {}
                }
            }
            if !self.receive_more(deadline, &mut resend_at, &buf[..n])? {
                return Err(SimError::Controller(format!(
                    "no answer to commissioning request {sequence} within {} s",
                    ANSWER_TIMEOUT.as_secs()
                )));
            }
        }
    }

    /// Waits for more bytes from the link (into the pending queue) until `deadline`.
    /// Until the session's first lock-step answer (the target may still be booting),
    /// `frame` is sent again at `resend_at`, which then moves on by [`START_RESEND`].
    /// `Ok(false)`: the deadline passed with nothing received.
    fn receive_more(
        &mut self,
        deadline: Instant,
        resend_at: &mut Instant,
        frame: &[u8],
    ) -> Result<bool, SimError> {
        let starting = self.round_trips == 0;
        let now = Instant::now();
        let left = deadline.saturating_duration_since(now);
        let wait = if starting { left.min(resend_at.saturating_duration_since(now)) } else { left };
        match self.incoming.recv_timeout(wait) {
            Ok(Ok(bytes)) => {
                self.pending.extend(bytes);
                Ok(true)
            }
            Ok(Err(e)) => Err(SimError::Controller(format!("link read failed: {e}"))),
            Err(_) if starting && Instant::now() < deadline => {
                self.send_raw(frame)?;
                *resend_at = Instant::now() + START_RESEND;
                Ok(true)
            }
            Err(_) => Ok(false),
        }
    }

    /// Writes `bytes` to the link as they are, expecting no answer (fault injection: a
    /// corrupted or replayed frame). An answer the target sends anyway is met by the next
    /// [`Controller::step`] as a frame of another sequence number and counted in
    /// [`SerialController::stale_frames`].
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<(), SimError> {
        self.writer
            .write_all(bytes)
            .and_then(|_| self.writer.flush())
            .map_err(|e| SimError::Controller(format!("link write failed: {e}")))
    }

    /// Lock-step round trips per second since the controller was created.
    pub fn round_trips_per_s(&self) -> f64 {
        self.round_trips as f64 / self.started.elapsed().as_secs_f64().max(1e-9)
    }

    /// Waits for the answer to `sequence`. Until the first answer has arrived, the frame
    /// is sent again every [`START_RESEND`]: a target that is still booting (QEMU takes
    /// about a second) can lose or garble the first bytes, of the frame or of its answer;
    /// the drive answers a duplicate of the frame it took last with the same bytes
    /// without stepping (`LinkServer::on_byte`), so a resend never steps it twice.
    fn await_answer(&mut self, sequence: u16) -> Result<ActuationFrame, SimError> {
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        let mut resend_at = Instant::now() + START_RESEND;
        loop {
            while let Some(byte) = self.pending.pop_front() {
                match self.receiver.push(byte) {
                    Some(Ok(frame)) if frame.sequence == sequence => return Ok(frame),
                    Some(Ok(_)) => self.stale_frames += 1,
                    Some(Err(_)) | None => {}
                }
            }
            let sent = std::mem::take(&mut self.last_sent);
            let more = self.receive_more(deadline, &mut resend_at, &sent);
            self.last_sent = sent;
            if !more? {
                return Err(SimError::Controller(format!(
                    "no answer to frame {sequence} within {} s (link stats: {:?})",
                    ANSWER_TIMEOUT.as_secs(),
                    self.receiver.stats()
                )));
            }
        }
    }
}

impl<W: Write> Controller for SerialController<W> {
    fn set_observer_offsets(&mut self, _u_v: [f64; 2], _i_a: [f64; 2]) -> Result<(), SimError> {
        Err(SimError::Controller(
            "the HIL link carries no observer offsets: the dc-u, dc-i and resistance scenarios run in-process only"
                .into(),
        ))
    }

    fn reset_estimator(&mut self) -> Result<(), SimError> {
        Err(SimError::Controller(
            "the HIL link cannot reset the drive's estimator: that scenario runs in-process only".into(),
        ))
    }

    fn step(&mut self, sensor: &SensorFrame) -> Result<ControlStep, SimError> {
        let mut buf = [0u8; SensorFrame::WIRE_LEN];
        let n = encode(sensor, &mut buf).map_err(|e| SimError::Controller(format!("encoding: {e}")))?;
        self.last_sent.clear();
        self.last_sent.extend_from_slice(&buf[..n]);
        self.send_raw(&buf[..n])?;
        let frame = self.await_answer(sensor.sequence)?;
        self.round_trips += 1;
        Ok(ControlStep { frame, detail: None })
    }
}

impl QemuSession {
    /// Starts `qemu-system-arm` on `cpu`'s board with the HIL firmware `elf`; returns the
    /// session and a lock-step controller talking to its UART0. The image has no timer
    /// (it steps per frame; its watchdog counts the sequence numbers the host skips):
    /// [`GuestClock::Untimed`].
    pub fn start(elf: &Path, cpu: QemuCpu) -> Result<(QemuSession, SerialController<ChildStdin>), SimError> {
        let (session, stdin, stdout) = QemuSession::spawn(elf, cpu, GuestClock::Untimed)?;
        Ok((session, SerialController::new(stdin, stdout)))
    }

    /// [`QemuSession::start`] with `cmdline` for the image (e.g. the stroke axis,
    /// `crate::commands::stroke::qemu_cmdline`).
    pub fn start_with_cmdline(
        elf: &Path,
        cpu: QemuCpu,
        cmdline: &str,
    ) -> Result<(QemuSession, SerialController<ChildStdin>), SimError> {
        let (session, stdin, stdout) =
            QemuSession::spawn_with_cmdline(elf, cpu, GuestClock::Untimed, Some(cmdline))?;
        Ok((session, SerialController::new(stdin, stdout)))
    }
}

/// The HIL firmware ELF for `cpu`, in the workspace's target directory.
pub fn default_qemu_elf(workspace: &Path, cpu: QemuCpu) -> PathBuf {
    qemu_example_elf(workspace, cpu, "qemu_hil")
}

/// Builds the QEMU HIL firmware (`examples/qemu_hil`) for `cpu` with cargo (release).
pub fn build_qemu_firmware(workspace: &Path, cpu: QemuCpu) -> Result<PathBuf, SimError> {
    build_qemu_example(workspace, cpu, "qemu_hil")
}
