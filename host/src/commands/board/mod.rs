//! `dcfo board`: operate a drive image from the host over the board link
//! ([`dcfo::link::board`]): a board on a serial port, or the virtual-motor image
//! (`firmware/examples/qemu_drive.rs`) on QEMU.
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
//!
//! A downloaded capture ([`CaptureData`]: the drive's own words and their
//! [`CaptureFormat`]) becomes a trace in the trace format (docs/trace-format.md) (`t`, `u_alpha`, `u_beta`,
//! `i_alpha`, `i_beta` and the commanded acceleration `alpha_e_ref`, see
//! [`crate::trace::COMMANDED_ACCEL_COLUMN`]; SI as `f64`, which for Q8.24 words converts
//! back to the same bits; comment lines name the number type) starting at the
//! estimator's reset, so that `dcfo replay` (`--numeric q24` for the M3 image) reproduces
//! the drive's own estimates, which [`replay_matches`] checks bit for bit.

use std::collections::VecDeque;
use std::io::{BufRead, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use dcfo::capture::{Capture, CaptureFormat, CaptureSample, CaptureState, Quantity, SiSample};
use dcfo::drive::{DriveConfig, DriveState, PAPER_AXIS_BUS_V, PAPER_AXIS_PAYLOAD_KG, STROKE_AXIS_LIMITS};
use dcfo::link::board::{BoardCommand, BoardTelemetry, CaptureChunk, NO_CAPTURE_READ};
use dcfo::link::{LinkError, decode_raw};
use dcfo::motion::Move;
use dcfo::motor::MotorParams;
use dcfo::motor_image::{MotorAxis, MotorImage};
use dcfo::observer::ObserverKind;

use crate::commands::replay::{replay_trace_as, working_base};
use crate::commands::sim::fault_names;
use crate::qemu::{GuestClock, QemuSession, build_qemu_example};
use crate::trace::{COMMANDED_ACCEL_COLUMN, GroundTruth, InputTrace, InputTraceWriter, TraceRow};

/// How long to wait for an answer before sending the command again (a booting QEMU can
/// lose the first bytes).
pub const RESEND_AFTER: Duration = Duration::from_millis(500);
/// Telemetry poll period of the live display and the demo: 20 Hz.
pub const POLL_PERIOD: Duration = Duration::from_millis(50);
/// Capture chunks downloaded between two polls of the live display (about 0.1 s on
/// QEMU).
pub const DOWNLOAD_SLICE_CHUNKS: u32 = 40;
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

/// Set by Ctrl-C (SIGINT, SIGTERM) once [`catch_interrupt`] has installed the handler.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// Makes Ctrl-C end `dcfo board` cleanly: the interactive mode and the demo see it at
/// their next poll, disable the drive and exit. Without it the process would die at
/// once and the image's watchdog would switch the bridge off 0.5 s later.
///
/// # Errors
/// The handler could not be installed (e.g. one was already).
pub fn catch_interrupt() -> anyhow::Result<()> {
    ctrlc::set_handler(|| INTERRUPTED.store(true, Ordering::SeqCst)).context("installing the Ctrl-C handler")
}

fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::SeqCst)
}

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

/// A capture as downloaded: the drive's words and how they read.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CaptureData {
    /// The drive's number type and working units (the base then follows from the
    /// motor: [`working_base`]).
    pub format: CaptureFormat,
    /// The samples, from the estimator's first step.
    pub samples: Vec<CaptureSample>,
}

impl CaptureData {
    /// What `capture` holds (e.g. a drive run in this process).
    pub fn from_capture<const N: usize>(capture: &Capture<N>) -> Self {
        CaptureData {
            format: capture.format(),
            samples: (0..capture.len()).filter_map(|k| capture.sample(k).copied()).collect(),
        }
    }
}

/// The comment lines of a capture's trace: what was recorded, the number type and
/// working units, and the replay that reproduces it.
pub fn capture_comments(data: &CaptureData, motor: &MotorParams) -> Vec<String> {
    let base = working_base(data.format, motor);
    let units = match data.format {
        CaptureFormat::F32 => "f32 in SI units".to_string(),
        CaptureFormat::Q24 => format!(
            "Q8.24 in the motor's per-unit base (voltage {} V, current {} A, omega {} rad/s); \
             each value is exactly bits * 2^-24 * base as f64",
            base.voltage_v, base.current_a, base.omega_rad_s
        ),
    };
    vec![
        format!("dcfo capture: {} samples from the estimator's start", data.samples.len()),
        format!("numeric: {} ({units})", data.format.name()),
        format!(
            "replay bit for bit: dcfo replay --numeric {} --observer dcfo --motor <the drive's motor>",
            data.format.name()
        ),
    ]
}

/// The capture as a trace in the trace format (docs/trace-format.md): row `k` at `t = k Ts` (the estimator's
/// first step is `t = 0`), in SI ([`CaptureFormat::to_si`] in the working units of
/// `motor`), with the commanded acceleration column.
///
/// # Errors
/// Fewer than two samples, or a value the trace format refuses.
pub fn capture_trace(data: &CaptureData, motor: &MotorParams, period_s: f64) -> anyhow::Result<InputTrace> {
    let base = working_base(data.format, motor);
    let si: Vec<_> = data.samples.iter().map(|s| s.to_si(data.format, &base)).collect();
    let rows = si.iter().enumerate().map(|(k, s)| capture_row(k, s, period_s)).collect();
    let accel = si.iter().map(|s| s.alpha_e_ref).collect();
    Ok(InputTrace::from_rows(rows, "capture")?.with_commanded_acceleration(accel, "capture")?)
}

fn capture_row(k: usize, s: &SiSample, period_s: f64) -> TraceRow {
    TraceRow {
        t: k as f64 * period_s,
        u_alpha: s.u_alpha,
        u_beta: s.u_beta,
        i_alpha: s.i_alpha,
        i_beta: s.i_beta,
        theta: None,
        v: None,
        x: None,
    }
}

/// Writes the capture to `path` as a trace (see [`capture_trace`]; the comment lines of
/// [`capture_comments`] first), atomically.
///
/// # Errors
/// As [`InputTraceWriter`]: the file, the line and the column.
pub fn write_capture_trace(
    path: &Path,
    data: &CaptureData,
    motor: &MotorParams,
    period_s: f64,
) -> anyhow::Result<()> {
    let base = working_base(data.format, motor);
    let comments = capture_comments(data, motor);
    let comments: Vec<&str> = comments.iter().map(String::as_str).collect();
    let mut w = InputTraceWriter::create_with_comments(
        path,
        GroundTruth::NONE,
        &[COMMANDED_ACCEL_COLUMN],
        &comments,
    )?;
    for (k, s) in data.samples.iter().enumerate() {
        let s = s.to_si(data.format, &base);
        w.write(&capture_row(k, &s, period_s), &[s.alpha_e_ref])?;
    }
    w.finish()?;
    Ok(())
}

/// How a replay compares with the drive's own estimates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Comparison {
    /// Samples whose angle, speed or flux estimate differs in any bit.
    pub differing: usize,
    /// The first of them (0 is the estimator's first step), `None` when identical.
    pub first_differing: Option<usize>,
}

impl Comparison {
    /// Every sample identical (and there was at least one).
    pub fn identical(&self, samples: usize) -> bool {
        self.differing == 0 && samples > 0
    }
}

/// Replays `trace` through the estimator of `motor` (DCFO, in the capture's number
/// type: what `dcfo replay --numeric` runs) and compares, sample by sample, the angle,
/// speed and flux estimates with what the drive estimated on the target: the same words
/// bit for bit (compared in SI as `f64`, which is one to one with the words).
///
/// # Errors
/// The replay refused the trace.
pub fn replay_matches(
    trace: &InputTrace,
    motor: &MotorParams,
    data: &CaptureData,
) -> anyhow::Result<Comparison> {
    let replayed = replay_trace_as(trace, motor, ObserverKind::Dcfo, data.format)?;
    anyhow::ensure!(
        replayed.len() == data.samples.len(),
        "replay gave {} rows for {} samples",
        replayed.len(),
        data.samples.len()
    );
    let base = working_base(data.format, motor);
    let si = |w: u32, q: Quantity| data.format.to_si(w, q, &base).to_bits();
    let mut cmp = Comparison::default();
    for (k, (r, s)) in replayed.iter().zip(&data.samples).enumerate() {
        let same = r.theta_hat.to_bits() == s.theta_hat.to_radians::<f64>().to_bits()
            && r.v_hat.to_bits() == si(s.v_hat, Quantity::Speed)
            && r.psi_alpha_hat.to_bits() == si(s.psi_alpha_hat, Quantity::Flux)
            && r.psi_beta_hat.to_bits() == si(s.psi_beta_hat, Quantity::Flux);
        if !same {
            cmp.differing += 1;
            cmp.first_differing.get_or_insert(k);
        }
    }
    Ok(cmp)
}

/// The motor the QEMU drive image runs without a motor image (`examples/qemu_drive.rs`):
/// the paper motor, its drive tuned by `DriveConfig::for_motor` for the paper axis's bus;
/// the replay needs only the motor (its estimator is `EstimatorConfig::for_motor`, as
/// the drive's; the M3 image's Q8.24 drive runs in `Base::for_motor` of it, see
/// [`working_base`]).
pub fn qemu_drive_motor() -> MotorParams {
    MotorParams::paper()
}

pub use crate::target::{ANSWER_TIMEOUT, Target};

/// The motor image `dcfo board --qemu --move-to` gives the QEMU image when no `--image`
/// is: the paper motor at the paper axis's bus with the stroke axis of `dcfo stroke`
/// ([`STROKE_AXIS_LIMITS`], the [`PAPER_AXIS_PAYLOAD_KG`] carriage), so that the image
/// builds a positioning drive (`image_drive::drive_config`, as the ESC1 does from
/// flash).
pub fn qemu_positioning_image() -> MotorImage {
    let image = MotorImage::new(MotorParams::paper(), PAPER_AXIS_BUS_V).expect("the paper motor is valid");
    image
        .with_axis(MotorAxis { limits: STROKE_AXIS_LIMITS, payload_kg: PAPER_AXIS_PAYLOAD_KG })
        .expect("the stroke axis fits the paper motor")
}

/// The QEMU drive image's command line for `image`: `image <hex>` (the image reads it
/// through semihosting, `image_drive::motor_image_from_hex`).
pub fn qemu_image_cmdline(image: &MotorImage) -> String {
    let hex: String = image.encode().iter().map(|b| format!("{b:02x}")).collect();
    format!("image {hex}")
}

/// The motor image the QEMU drive image runs: `image` (`--image FILE`), else for a move
/// ([`qemu_positioning_image`]), else none (the image's paper speed drive).
pub fn qemu_image(image: Option<MotorImage>, move_to: bool) -> Option<MotorImage> {
    image.or_else(|| move_to.then(qemu_positioning_image))
}

/// A move the host sends: a finite target (m) and a finite, non-negative dwell (s).
/// The drive image checks the stroke itself (a target outside it is refused and
/// counted in the telemetry).
///
/// # Errors
/// What is wrong with the values, naming them.
pub fn check_move(target_m: f32, dwell_s: f32) -> Result<(), String> {
    if !target_m.is_finite() {
        return Err(format!("the move's target must be a finite number of m, not {target_m}"));
    }
    if !(dwell_s.is_finite() && dwell_s >= 0.0) {
        return Err(format!("the move's dwell must be a finite number of s, at least 0, not {dwell_s}"));
    }
    Ok(())
}

/// Tolerance on the final position of `dcfo board --demo --move-to`, m: a twentieth of
/// the motor's pole pitch (0.75 mm on the paper motor, 9 electrical degrees).
pub fn move_tolerance_m(motor: &MotorParams) -> f32 {
    motor.pole_pitch_m / 20.0
}

/// What `dcfo board --demo --move-to` did (its JSON line).
#[derive(Debug, serde::Serialize)]
pub struct MoveDemoReport {
    /// The most advanced state the drive reported.
    pub state_reached: String,
    /// Faults latched before the disable (`none`).
    pub faults: String,
    /// The move's target, m.
    pub target_m: f32,
    /// The drive's position estimate x̂ at the end, m.
    pub x_hat_m: f32,
    /// The profile's reference position at the end, m.
    pub x_ref_m: f32,
    /// `x_hat_m - target_m`, m.
    pub x_err_m: f32,
    /// The tolerance on `x_err_m` ([`move_tolerance_m`]), m.
    pub tolerance_m: f32,
    /// The reference came to rest at the target and x̂ is within the tolerance of it.
    pub move_reached: bool,
    /// Simulated time from the enable until the move was reached, s.
    pub move_s: Option<f64>,
    /// A move outside the stroke sent afterwards was refused and counted in the
    /// telemetry's position report.
    pub refused_move_reported: bool,
    /// Moves the drive image refused in all (its report's count).
    pub moves_rejected: u16,
    /// Control periods the image ran, as simulated time, s.
    pub simulated_s: f64,
    /// Wall-clock time from connecting to the disable, s.
    pub wall_s: f64,
}

/// `dcfo board --demo --move-to`: connect to a positioning drive image, enable at rest,
/// queue the move, poll until the reference is at rest at the target and x̂ has settled
/// within [`move_tolerance_m`] of it (or `timeout` of the drive's own time,
/// [`DriveClock`]), then send a move outside any stroke (1 km) and check the image
/// reports it refused, and disable.
///
/// # Errors
/// The link failed, the image reports no position (a speed drive), the drive tripped.
pub fn run_move_demo(
    target: &Target,
    image: Option<&MotorImage>,
    m: Move,
    timeout: Duration,
) -> anyhow::Result<MoveDemoReport> {
    let started = Instant::now();
    let motor = image.map_or_else(qemu_drive_motor, |i| i.motor);
    let tolerance_m = move_tolerance_m(&motor);
    with_board(target, image, |board| {
        let first = first_period(board)?;
        let Some(p0) = first.position else {
            let _ = board.disable();
            bail!(
                "the drive image reports no position: it runs a speed drive, which refuses every move; \
                 its motor image has no axis (a version-1 or -2 image, or written without one): write one with \
                 `dcfo motor-image ... --stroke-min-m --stroke-max-m --max-speed --max-accel --payload-kg`"
            );
        };
        *board.wish_mut() = Wish { enable: true, speed_m_per_s: 0.0 };
        board.queue_move(m);
        let mut t = board.poll(true, false)?;
        let enabled_at = t.periods;
        let mut best = t.state();
        let mut clock = DriveClock::start(&t);
        let mut reached_at = None;
        let mut settled = 0;
        loop {
            if t.state() == DriveState::Fault {
                let _ = board.disable();
                bail!("the drive tripped: {}", fault_names(t.faults()));
            }
            if interrupted() {
                let _ = board.disable();
                bail!("interrupted");
            }
            if let Some(p) = t.position
                && p.idle
                && p.x_ref_m == m.target_m
                && (p.x_hat_m - m.target_m).abs() < tolerance_m
            {
                reached_at.get_or_insert(t.periods);
                // Settled: within the tolerance for a few polls in a row.
                settled += 1;
                if settled >= 5 {
                    break;
                }
            } else {
                settled = 0;
                reached_at = None;
            }
            if clock.elapsed_s(&t)? > timeout.as_secs_f64() {
                break;
            }
            std::thread::sleep(POLL_PERIOD);
            t = board.poll(false, false)?;
            if state_rank(t.state()) > state_rank(best) {
                best = t.state();
            }
            eprint!("\r{}\x1b[K", status_line(&t));
        }
        eprintln!();
        let p = t.position.unwrap_or(p0);
        let rejected_before = p.moves_rejected;
        board.queue_move(Move { target_m: 1000.0, dwell_s: 0.0 });
        board.poll(false, false)?;
        // The refusal is counted at the image's next control period.
        std::thread::sleep(POLL_PERIOD);
        let after = board.poll(false, false)?;
        let rejected = after.position.map_or(rejected_before, |q| q.moves_rejected);
        let faults = fault_names(after.faults());
        let last = board.disable()?;
        let x_err_m = p.x_hat_m - m.target_m;
        Ok(MoveDemoReport {
            state_reached: format!("{best:?}"),
            faults,
            target_m: m.target_m,
            x_hat_m: p.x_hat_m,
            x_ref_m: p.x_ref_m,
            x_err_m,
            tolerance_m,
            move_reached: p.idle && p.x_ref_m == m.target_m && x_err_m.abs() < tolerance_m,
            move_s: reached_at.map(|k: u32| f64::from(k.wrapping_sub(enabled_at)) * CONTROL_PERIOD_S),
            refused_move_reported: rejected == rejected_before.wrapping_add(1),
            moves_rejected: rejected,
            simulated_s: f64::from(last.periods) * CONTROL_PERIOD_S,
            wall_s: started.elapsed().as_secs_f64(),
        })
    })
}

/// The first telemetry that follows a control period of the drive: the image may answer
/// before its control interrupt has run once (a host that connects at boot), and until
/// then its status is the power-on one (no position report even for a positioning drive).
///
/// # Errors
/// The link failed, or the drive's periods do not start ([`DriveClock`]).
fn first_period(board: &mut dyn BoardOps) -> anyhow::Result<BoardTelemetry> {
    let mut t = board.poll(false, false)?;
    let mut clock = DriveClock::start(&t);
    while t.periods == 0 {
        clock.elapsed_s(&t)?;
        std::thread::sleep(Duration::from_millis(10));
        t = board.poll(false, false)?;
    }
    Ok(t)
}

/// What `dcfo board --demo` did (its JSON line).
#[derive(Debug, serde::Serialize)]
pub struct DemoReport {
    /// The most advanced state the drive reported (`Running` when it ran sensorless).
    pub state_reached: String,
    /// The state when the demo disabled it.
    pub state_before_disable: String,
    /// Faults latched before the disable (`none`).
    pub faults: String,
    /// Speed estimate before the download, read once the drive has run long enough to
    /// finish its ramp to the reference and settle (`speed_settle_periods`), m/s.
    pub speed_m_per_s: Option<f32>,
    /// Samples captured and downloaded (full rate, from the estimator's start).
    pub capture_samples: usize,
    /// The drive's number type, as the capture reported it (`f32`, `q24`).
    pub numeric: &'static str,
    /// Every replayed estimate equals the drive's own, bit for bit.
    pub replay_identical: bool,
    /// Replayed samples that differ.
    pub replay_differing: usize,
    /// The first replayed sample that differs (0: the estimator's first step).
    pub replay_first_differing: Option<usize>,
    /// Time to download the capture, s.
    pub download_s: f64,
    /// Commands answered per second during the download.
    pub round_trips_per_s: f64,
    /// Control periods the image ran, as simulated time, s.
    pub simulated_s: f64,
    /// Wall-clock time from connecting to the disable, s.
    pub wall_s: f64,
    /// The trace written (`--record`).
    pub trace: Option<PathBuf>,
}

fn state_rank(s: DriveState) -> u8 {
    match s {
        DriveState::Fault => 0,
        DriveState::Disabled => 1,
        DriveState::Calibrating => 2,
        DriveState::Commissioning => 2,
        DriveState::Starting => 3,
        DriveState::Reacquiring => 4,
        DriveState::LowSpeed => 5,
        DriveState::Running => 6,
    }
}

/// Connects to `target`, then runs `f` with the board; QEMU is stopped afterwards. On
/// QEMU the image runs the drive of `image` (its command line, [`qemu_image_cmdline`]),
/// without one the paper motor's speed drive; a board reads its own from flash.
fn with_board<T>(
    target: &Target,
    image: Option<&MotorImage>,
    f: impl FnOnce(&mut dyn BoardOps) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    match target {
        Target::Qemu { cpu, elf } => {
            let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap_or(Path::new("."));
            let elf = match elf {
                Some(e) => e.clone(),
                None => build_qemu_example(workspace, *cpu, "qemu_drive")?,
            };
            let cmdline = image.map(qemu_image_cmdline);
            // The drive image's SysTick paces its control periods: its clock counts
            // instructions.
            let (_session, stdin, stdout) =
                QemuSession::spawn_with_cmdline(&elf, *cpu, GuestClock::Instructions, cmdline.as_deref())?;
            let mut board = Board::new(BoardLink::new(stdin, stdout));
            f(&mut board)
        }
        Target::Port { device, baud } => {
            let (serial, reader) = crate::target::open_serial(device, *baud)?;
            let mut board = Board::new(BoardLink::new(serial, reader));
            f(&mut board)
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

/// Settling time after the drive first reports `Running` before [`run_demo`] reads the
/// speed estimate, s: past the speed loop's response (a few times its `1/20` s time
/// constant).
pub const SPEED_SETTLE_S: f64 = 0.25;

/// Control periods from the first `Running` telemetry to the demo's speed reading: the
/// longest ramp to `speed` m/s (from rest, at the acceleration limit of the drive the
/// image builds from `image`, the paper motor's without one) plus [`SPEED_SETTLE_S`].
fn speed_settle_periods(image: Option<&MotorImage>, speed: f32) -> u32 {
    let motor = image.map_or_else(qemu_drive_motor, |i| i.motor);
    let accel = DriveConfig::for_motor(&motor, PAPER_AXIS_BUS_V, ObserverKind::Dcfo).accel_limit_m_per_s2;
    let ramp_s = f64::from(speed.abs()) / f64::from(accel);
    ((ramp_s + SPEED_SETTLE_S) / CONTROL_PERIOD_S).ceil() as u32
}

/// `dcfo board --demo`: connect, arm the capture, enable at `speed` m/s, wait for the
/// capture to finish (the drive reaching `Running` on the way), download it, replay it,
/// disable. `record`: also write the capture as a trace there.
///
/// # Errors
/// The link failed, or the capture did not finish within `timeout` of the drive's own
/// time ([`DriveClock`]).
pub fn run_demo(
    target: &Target,
    image: Option<&MotorImage>,
    speed: f32,
    record: Option<&Path>,
    timeout: Duration,
) -> anyhow::Result<DemoReport> {
    let started = Instant::now();
    with_board(target, image, |board| {
        let first = board.poll(false, false)?;
        eprintln!(
            "connected: drive {:?}, capture capacity {} samples",
            first.state(),
            first.capture_capacity
        );
        *board.wish_mut() = Wish { enable: true, speed_m_per_s: speed };
        let mut t = board.poll(true, true)?;
        let mut best = t.state();
        let mut clock = DriveClock::start(&t);
        while !(t.capture == CaptureState::Done && t.state() == DriveState::Running) {
            if clock.elapsed_s(&t)? > timeout.as_secs_f64() {
                let _ = board.disable();
                bail!(
                    "no finished capture with the drive running within {} s of its time: drive {:?} (faults {}), capture {:?} with {} samples",
                    timeout.as_secs(),
                    t.state(),
                    fault_names(t.faults()),
                    t.capture,
                    t.capture_len
                );
            }
            if t.state() == DriveState::Fault {
                let _ = board.disable();
                bail!("the drive tripped: {}", fault_names(t.faults()));
            }
            if interrupted() {
                let t = board.disable()?;
                bail!(
                    "interrupted: drive {:?}, bridge {}",
                    t.state(),
                    if t.bridge_enabled { "on" } else { "off" }
                );
            }
            std::thread::sleep(POLL_PERIOD);
            t = board.poll(false, false)?;
            if state_rank(t.state()) > state_rank(best) {
                best = t.state();
                eprintln!(
                    "drive {:?} after {:.2} s simulated",
                    t.state(),
                    f64::from(t.periods) * CONTROL_PERIOD_S
                );
            }
        }
        // The speed is read at a defined drive time, not at the first poll: the drive
        // ramps from its hand-over speed to the reference at its acceleration limit, and
        // where the wall clock's poll falls on that ramp depends on how fast the target
        // runs against it (QEMU's M3 is slower than its M4F).
        let settle_periods = speed_settle_periods(image, speed);
        let running_seen = t.periods;
        while t.periods.wrapping_sub(running_seen) < settle_periods {
            if t.state() != DriveState::Running || clock.elapsed_s(&t)? > timeout.as_secs_f64() {
                let _ = board.disable();
                bail!(
                    "the drive left Running (or the time ran out) while settling at the speed: drive {:?} (faults {})",
                    t.state(),
                    fault_names(t.faults())
                );
            }
            std::thread::sleep(POLL_PERIOD);
            t = board.poll(false, false)?;
        }
        let (state_before, faults, speed_now) = (t.state(), t.faults(), t.estimate.map(|e| e.1));
        let trips_before = board.round_trips();
        let download_started = Instant::now();
        let data = board.download_capture(t.capture_len)?;
        let download_s = download_started.elapsed().as_secs_f64();
        let round_trips_per_s = (board.round_trips() - trips_before) as f64 / download_s.max(1e-9);
        let last = board.disable()?;
        eprintln!(
            "downloaded {} samples ({}) in {download_s:.1} s ({round_trips_per_s:.0} round trips/s); drive {:?}",
            data.samples.len(),
            data.format.name(),
            last.state()
        );
        // Through the file, as `dcfo replay` reads it.
        let dir = tempfile::tempdir().context("temporary directory")?;
        let path = match record {
            Some(p) => p.to_path_buf(),
            None => dir.path().join("capture.csv"),
        };
        let motor = image.map_or_else(qemu_drive_motor, |i| i.motor);
        write_capture_trace(&path, &data, &motor, CONTROL_PERIOD_S)?;
        let trace = InputTrace::read_path(&path)?;
        let comparison = replay_matches(&trace, &motor, &data)?;
        Ok(DemoReport {
            state_reached: format!("{best:?}"),
            state_before_disable: format!("{state_before:?}"),
            faults: fault_names(faults),
            speed_m_per_s: speed_now,
            capture_samples: data.samples.len(),
            numeric: data.format.name(),
            replay_identical: comparison.identical(data.samples.len()),
            replay_differing: comparison.differing,
            replay_first_differing: comparison.first_differing,
            download_s,
            round_trips_per_s,
            simulated_s: f64::from(last.periods) * CONTROL_PERIOD_S,
            wall_s: started.elapsed().as_secs_f64(),
            trace: record.map(Path::to_path_buf),
        })
    })
}

/// One line of live state: drive state, faults, speed, currents, bus, angle, capture;
/// and for a positioning drive x̂ and the reference position (mm), the queue and the
/// refused moves.
pub fn status_line(t: &BoardTelemetry) -> String {
    let (theta, v) = match t.estimate {
        Some((theta, v)) => (format!("{:+7.1} deg", theta.to_degrees()), format!("{v:+.3} m/s")),
        None => ("    --".into(), "--".into()),
    };
    let position = match t.position {
        Some(p) => format!(
            "  x {:+8.3} mm ref {:+8.3} mm{} queued {} refused {}",
            p.x_hat_m * 1e3,
            p.x_ref_m * 1e3,
            if p.idle { " idle" } else { "" },
            p.moves_queued,
            p.moves_rejected
        ),
        None => String::new(),
    };
    format!(
        "{:<12} faults {:<10} v {v:<11} ref {:+.3} m/s  i_ab [{:+6.2} {:+6.2}] A  bus {:6.1} V  theta {theta}  bridge {}  capture {:?} {}/{}{position}",
        format!("{:?}", t.state()),
        fault_names(t.faults()),
        t.speed_ref,
        t.i_ab_a[0],
        t.i_ab_a[1],
        t.vdc_v,
        if t.bridge_enabled { "on " } else { "off" },
        t.capture,
        t.capture_len,
        t.capture_capacity
    )
}

/// A line typed in the interactive mode.
#[derive(Clone, Debug, PartialEq)]
pub enum Typed {
    /// `e`: enable.
    Enable,
    /// `d`: disable.
    Disable,
    /// `c`: clear faults.
    Clear,
    /// `s <m/s>`: speed reference.
    Speed(f32),
    /// `r`: arm the capture (downloaded to `--record FILE` when it is over).
    Record,
    /// `m <target m> [dwell s]`: queue a move on a positioning drive.
    MoveTo(Move),
    /// `q`, or the end of the input: disable and quit.
    Quit,
}

/// Parses one typed line.
///
/// # Errors
/// What is wrong with the line, naming it.
pub fn parse_typed(line: &str) -> Result<Typed, String> {
    let mut words = line.split_whitespace();
    let cmd = words.next().unwrap_or("");
    let typed = match cmd {
        "e" | "enable" => Typed::Enable,
        "d" | "disable" => Typed::Disable,
        "c" | "clear" => Typed::Clear,
        "r" | "record" => Typed::Record,
        "q" | "quit" => Typed::Quit,
        "s" | "speed" => {
            let arg = words.next().ok_or_else(|| format!("`{line}`: `s` needs a speed in m/s"))?;
            let v: f32 = arg.parse().map_err(|_| format!("`{line}`: `{arg}` is not a speed in m/s"))?;
            if !v.is_finite() {
                return Err(format!("`{line}`: the speed must be a finite number of m/s"));
            }
            Typed::Speed(v)
        }
        "m" | "move" => {
            let arg = words.next().ok_or_else(|| format!("`{line}`: `m` needs a target position in m"))?;
            let target_m: f32 =
                arg.parse().map_err(|_| format!("`{line}`: `{arg}` is not a position in m"))?;
            let dwell_s: f32 = match words.next() {
                Some(d) => d.parse().map_err(|_| format!("`{line}`: `{d}` is not a dwell in s"))?,
                None => 0.0,
            };
            check_move(target_m, dwell_s).map_err(|e| format!("`{line}`: {e}"))?;
            Typed::MoveTo(Move { target_m, dwell_s })
        }
        _ => {
            return Err(format!(
                "`{line}`: commands are e(nable), d(isable), c(lear), s(peed) <m/s>, m(ove) <m> [dwell s], r(ecord), q(uit)"
            ));
        }
    };
    if let Some(extra) = words.next() {
        return Err(format!("`{line}`: unexpected `{extra}`"));
    }
    Ok(typed)
}

/// `dcfo board` without `--demo`: live state on stderr at [`POLL_PERIOD`], commands read
/// line by line from stdin; `q`, the end of the input or Ctrl-C (with
/// [`catch_interrupt`]) disables the drive and exits.
///
/// # Errors
/// The link failed (the image's watchdog then disables the drive within 0.5 s).
pub fn run_interactive(
    target: &Target,
    image: Option<&MotorImage>,
    record: Option<&Path>,
    first_move: Option<Move>,
) -> anyhow::Result<()> {
    let (tx, typed) = mpsc::channel::<String>();
    std::thread::spawn(move || {
        let stdin = std::io::stdin();
        for line in stdin.lock().lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                return;
            }
        }
        let _ = tx.send("q".into());
    });
    eprintln!(
        "commands: e(nable), d(isable), c(lear faults), s(peed) <m/s>, m(ove) <m> [dwell s], r(ecord: arm the capture), q(uit)"
    );
    with_board(target, image, |board| {
        if let Some(m) = first_move {
            board.queue_move(m);
        }
        let mut clear = false;
        let mut arm = record.is_some();
        let mut downloaded = false;
        let mut data = CaptureData::default();
        let motor = image.map_or_else(qemu_drive_motor, |i| i.motor);
        loop {
            let t = board.poll(std::mem::take(&mut clear), std::mem::take(&mut arm))?;
            eprint!("\r{}\x1b[K", status_line(&t));
            if let Some(path) = record
                && t.capture == CaptureState::Done
                && !downloaded
            {
                // A slice at a time (about 0.1 s), so that the display and the keys stay
                // live while a long capture downloads.
                board.download_more(&mut data, t.capture_len, DOWNLOAD_SLICE_CHUNKS)?;
                eprint!(" | download {}/{}", data.samples.len(), t.capture_len);
                if data.samples.len() as u32 >= t.capture_len {
                    write_capture_trace(path, &data, &motor, CONTROL_PERIOD_S)?;
                    eprintln!(
                        "\ncapture: {} samples ({}) written to {}",
                        data.samples.len(),
                        data.format.name(),
                        path.display()
                    );
                    downloaded = true;
                    data.samples.clear();
                }
            }
            std::thread::sleep(POLL_PERIOD);
            if interrupted() {
                let t = board.disable()?;
                eprintln!("\r{}\x1b[K\ninterrupted: drive disabled", status_line(&t));
                return finish_download(board, record, &mut data, &motor, &t);
            }
            while let Ok(line) = typed.try_recv() {
                if line.trim().is_empty() {
                    continue;
                }
                match parse_typed(&line) {
                    Ok(Typed::Enable) => board.wish_mut().enable = true,
                    Ok(Typed::Disable) => board.wish_mut().enable = false,
                    Ok(Typed::Clear) => clear = true,
                    Ok(Typed::Speed(v)) => board.wish_mut().speed_m_per_s = v,
                    Ok(Typed::MoveTo(m)) => board.queue_move(m),
                    Ok(Typed::Record) => {
                        arm = true;
                        downloaded = false;
                        data.samples.clear();
                        if record.is_none() {
                            eprintln!("\n(no --record FILE: the capture will not be downloaded)");
                        }
                    }
                    Ok(Typed::Quit) => {
                        let t = board.disable()?;
                        eprintln!("\r{}\x1b[K\ndrive disabled", status_line(&t));
                        return finish_download(board, record, &mut data, &motor, &t);
                    }
                    Err(e) => eprintln!("\n{e}"),
                }
            }
        }
    })
}

/// On the way out, with the drive already disabled: a capture download under way is
/// completed and written (the samples of a finished capture do not change).
fn finish_download(
    board: &mut dyn BoardOps,
    record: Option<&Path>,
    data: &mut CaptureData,
    motor: &MotorParams,
    t: &BoardTelemetry,
) -> anyhow::Result<()> {
    let Some(path) = record else { return Ok(()) };
    if data.samples.is_empty() || t.capture != CaptureState::Done {
        return Ok(());
    }
    board.download_more(data, t.capture_len, u32::MAX)?;
    write_capture_trace(path, data, motor, CONTROL_PERIOD_S)?;
    eprintln!("capture: {} samples written to {}", data.samples.len(), path.display());
    Ok(())
}

// ---- The command.

/// What `dcfo board` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// The drive image: QEMU or a board on a serial port.
    pub target: Target,
    /// Download the capture into this trace (CSV, docs/trace-format.md) once it is over.
    pub record: Option<PathBuf>,
    /// Non-interactive: connect, arm the capture, enable at `speed_m_per_s`, wait until
    /// the drive runs and the capture is over, download it, replay it, disable.
    pub demo: bool,
    /// Speed reference of the demo, m/s.
    pub speed_m_per_s: f32,
    /// With `demo`: print one JSON object on the last line of stdout.
    pub json: bool,
    /// Queue this move (target m, dwell s) with the first command; on QEMU without
    /// `image` the image then runs the positioning drive of [`qemu_positioning_image`].
    /// With `demo`: the move demo ([`run_move_demo`]) instead of the capture demo.
    pub move_to: Option<Move>,
    /// QEMU only: the motor image the QEMU drive image runs (as a board reads its own
    /// from flash): with an axis a positioning drive, without one a speed drive.
    pub image: Option<PathBuf>,
}

/// `dcfo board`: the interactive session, or the demo (its report on stdout; an error
/// when the replay of the capture differs from the drive's estimates).
pub fn run_command(params: &Params) -> anyhow::Result<()> {
    if !params.speed_m_per_s.is_finite() {
        bail!("--speed must be a finite number of m/s");
    }
    if let Some(m) = params.move_to {
        check_move(m.target_m, m.dwell_s).map_err(|e| anyhow::anyhow!("--move-to/--dwell: {e}"))?;
    }
    let image = match (&params.image, &params.target) {
        (Some(path), Target::Qemu { .. }) => Some(crate::commands::motor_image::read_image(path)?),
        (Some(_), Target::Port { .. }) => {
            bail!("--image is for --qemu: a board reads its motor image from flash (write it with probe-rs)")
        }
        (None, _) => None,
    };
    let image = match params.target {
        Target::Qemu { .. } => qemu_image(image, params.move_to.is_some()),
        Target::Port { .. } => None,
    };
    if let Some(i) = &image {
        eprintln!("motor image: {}", crate::commands::motor_image::describe_axis(i.axis));
    }
    catch_interrupt()?;
    if !params.demo {
        return run_interactive(&params.target, image.as_ref(), params.record.as_deref(), params.move_to);
    }
    if let Some(m) = params.move_to {
        let report = run_move_demo(&params.target, image.as_ref(), m, Duration::from_secs(60))?;
        if params.json {
            println!("{}", serde_json::to_string(&report)?);
        } else {
            println!(
                "move to {:.4} m: x_hat {:.4} m (error {:+.3} mm, tolerance {:.3} mm){}; refused move reported: {}",
                report.target_m,
                report.x_hat_m,
                report.x_err_m * 1e3,
                report.tolerance_m * 1e3,
                match report.move_s {
                    Some(s) => format!(", reached {s:.2} s after the enable"),
                    None => String::new(),
                },
                report.refused_move_reported
            );
        }
        anyhow::ensure!(report.move_reached, "the move did not reach its target within the tolerance");
        anyhow::ensure!(report.refused_move_reported, "the refused move was not reported");
        return Ok(());
    }
    let report = run_demo(
        &params.target,
        image.as_ref(),
        params.speed_m_per_s,
        params.record.as_deref(),
        Duration::from_secs(60),
    )?;
    if params.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "drive reached {}; captured {} samples ({}); replay {} ({} differ{}); download {:.1} s at {:.0} round trips/s",
            report.state_reached,
            report.capture_samples,
            report.numeric,
            if report.replay_identical { "identical bit for bit" } else { "DIFFERS" },
            report.replay_differing,
            match report.replay_first_differing {
                Some(k) => format!(", the first at sample {k}"),
                None => String::new(),
            },
            report.download_s,
            report.round_trips_per_s
        );
    }
    anyhow::ensure!(report.replay_identical, "the replay of the capture differs from the drive's estimates");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use dcfo::drive::Faults;

    #[test]
    fn typed_commands_parse_and_bad_ones_are_named() {
        assert_eq!(parse_typed("e"), Ok(Typed::Enable));
        assert_eq!(parse_typed(" s -0.25 "), Ok(Typed::Speed(-0.25)));
        assert!(parse_typed("s fast").unwrap_err().contains("`fast` is not a speed"));
        assert!(parse_typed("s").unwrap_err().contains("needs a speed"));
        assert_eq!(parse_typed("m 0.02 0.5"), Ok(Typed::MoveTo(Move { target_m: 0.02, dwell_s: 0.5 })));
        assert_eq!(parse_typed("move -0.01"), Ok(Typed::MoveTo(Move { target_m: -0.01, dwell_s: 0.0 })));
        assert!(parse_typed("m").unwrap_err().contains("needs a target"));
        assert!(parse_typed("m 0.1 -2").unwrap_err().contains("dwell must be"));
        assert!(parse_typed("x").unwrap_err().contains("commands are"));
        assert!(parse_typed("e now").unwrap_err().contains("unexpected `now`"));
        assert!(parse_typed("s inf").is_err());
    }

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
