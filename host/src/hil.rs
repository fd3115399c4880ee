//! Hardware-in-the-loop: the plant simulation in lock-step with a drive behind the
//! serial link of [`dcfo::link`] — the firmware on QEMU's `mps2-an386` (Cortex-M4F, f32)
//! or `mps2-an385` (Cortex-M3, Q8.24) board, UART0 on QEMU's standard I/O, or a board on
//! a serial port.
//!
//! Per PWM period the host sends one [`SensorFrame`] and waits for the
//! [`ActuationFrame`] with the same sequence number; the plant then runs the period with
//! the duties of the previous answer, exactly as in the in-process simulation
//! ([`crate::sim::run_with`]). The firmware runs the same drive code as
//! [`crate::sim::LocalDrive`] of the same numeric type, so the angle estimates equal the
//! in-process run's bit for bit: f32 is IEEE on both sides, and Q8.24 is integer
//! arithmetic (the f32 conversions at its edges are IEEE too, in software on the M3).

use crate::sim::{ControlStep, Controller, SimError};
use dcfo::link::{ActuationFrame, Receiver, SensorFrame, encode};
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// How long to wait for an answer before declaring the link dead.
pub const ANSWER_TIMEOUT: Duration = Duration::from_secs(5);

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
}

impl<W: Write> SerialController<W> {
    /// A controller writing to `writer` and reading from `reader` (moved to a thread).
    pub fn new(writer: W, mut reader: impl Read + Send + 'static) -> Self {
        let (tx, incoming) = mpsc::channel();
        std::thread::spawn(move || {
            let mut buf = [0u8; 512];
            loop {
                match reader.read(&mut buf) {
                    Ok(0) => {
                        let _ = tx
                            .send(Err(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "link closed")));
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
        SerialController {
            writer,
            incoming,
            pending: VecDeque::new(),
            receiver: Receiver::new(),
            stale_frames: 0,
            round_trips: 0,
            started: Instant::now(),
            last_sent: Vec::new(),
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
            let starting = self.round_trips == 0;
            let now = Instant::now();
            let left = deadline.saturating_duration_since(now);
            let wait = if starting { left.min(resend_at.saturating_duration_since(now)) } else { left };
            match self.incoming.recv_timeout(wait) {
                Ok(Ok(bytes)) => self.pending.extend(bytes),
                Ok(Err(e)) => return Err(SimError::Controller(format!("link read failed: {e}"))),
                Err(_) if starting && Instant::now() < deadline => {
                    self.writer
                        .write_all(&self.last_sent)
                        .and_then(|_| self.writer.flush())
                        .map_err(|e| SimError::Controller(format!("link write failed: {e}")))?;
                    resend_at = Instant::now() + START_RESEND;
                }
                Err(_) => {
                    return Err(SimError::Controller(format!(
                        "no answer to frame {sequence} within {} s (link stats: {:?})",
                        ANSWER_TIMEOUT.as_secs(),
                        self.receiver.stats()
                    )));
                }
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
        self.writer
            .write_all(&buf[..n])
            .and_then(|_| self.writer.flush())
            .map_err(|e| SimError::Controller(format!("link write failed: {e}")))?;
        let frame = self.await_answer(sensor.sequence)?;
        self.round_trips += 1;
        Ok(ControlStep { frame, detail: None })
    }
}

/// The QEMU board of a HIL run, and with it the firmware's numeric type.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum QemuCpu {
    /// Cortex-M4F on `mps2-an386`: `Drive<f32>`, SI units.
    M4f,
    /// Cortex-M3 (no FPU) on `mps2-an385`: `Drive<Q24>`, the motor's per-unit base.
    M3,
}

impl QemuCpu {
    /// Rust target triple of the firmware.
    pub fn target(self) -> &'static str {
        match self {
            QemuCpu::M4f => "thumbv7em-none-eabihf",
            QemuCpu::M3 => "thumbv7m-none-eabi",
        }
    }

    /// QEMU machine (`-M`) and CPU (`-cpu`).
    pub fn machine_and_cpu(self) -> (&'static str, &'static str) {
        match self {
            QemuCpu::M4f => ("mps2-an386", "cortex-m4"),
            QemuCpu::M3 => ("mps2-an385", "cortex-m3"),
        }
    }

    /// The in-process drive the firmware's results must equal: same code, same numeric
    /// type, same units.
    pub fn local_drive(self, setup: &crate::sim::Setup) -> Result<Box<dyn Controller>, SimError> {
        Ok(match self {
            QemuCpu::M4f => Box::new(crate::sim::LocalDrive::new(setup)?),
            QemuCpu::M3 => Box::new(crate::sim::LocalDrive::fixed_point(setup)?),
        })
    }
}

/// The HIL firmware ELF for `cpu`, in the workspace's target directory.
pub fn default_qemu_elf(workspace: &Path, cpu: QemuCpu) -> PathBuf {
    workspace.join("target").join(cpu.target()).join("release/examples/qemu_hil")
}

/// Builds the QEMU HIL firmware for `cpu` with cargo (release).
pub fn build_qemu_firmware(workspace: &Path, cpu: QemuCpu) -> Result<PathBuf, SimError> {
    let status = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .current_dir(workspace)
        .args(["build", "--release", "-p", "dcfo-firmware", "--features", "mps2", "--example", "qemu_hil"])
        .args(["--target", cpu.target()])
        .status()
        .map_err(|e| SimError::Controller(format!("cannot run cargo to build the firmware: {e}")))?;
    if !status.success() {
        return Err(SimError::Controller(format!("building the QEMU firmware failed ({status})")));
    }
    Ok(default_qemu_elf(workspace, cpu))
}

/// QEMU running the firmware, its UART0 on QEMU's standard input and output, its
/// monitor (QMP) on a socket for reading the target's memory.
pub struct QemuSession {
    child: Child,
    qmp_socket: PathBuf,
    /// Holds the socket's directory until QEMU is gone.
    _dir: tempfile::TempDir,
}

/// The pattern `dcfo_firmware::stack::paint` fills the free stack with at boot.
pub const STACK_PAINT: u32 = 0xA5C3_5A3C;
/// Start of RAM on the MPS2 boards: with flip-link, the stack's lowest address.
pub const MPS2_RAM_ORIGIN: u32 = 0x2000_0000;
/// `dcfo_firmware::stack::GUARD_BYTES`: the MPU guard at the bottom of the stack, never
/// painted and never readable by the firmware.
pub const STACK_GUARD_BYTES: u32 = 256;
/// How far below the top of the stack [`QemuSession::stack_high_water`] looks (bytes).
pub const STACK_SCAN_BYTES: u32 = 64 * 1024;

impl QemuSession {
    /// Starts `qemu-system-arm` on `cpu`'s board with `elf`; returns the session and a
    /// controller talking to its UART0.
    pub fn start(elf: &Path, cpu: QemuCpu) -> Result<(QemuSession, SerialController<ChildStdin>), SimError> {
        let (machine, core) = cpu.machine_and_cpu();
        let dir =
            tempfile::tempdir().map_err(|e| SimError::Controller(format!("temporary directory: {e}")))?;
        let qmp_socket = dir.path().join("qmp.sock");
        let mut child = Command::new("qemu-system-arm")
            .args(["-M", machine, "-cpu", core, "-display", "none", "-monitor", "none"])
            .arg("-qmp")
            .arg(format!("unix:{},server=on,wait=off", qmp_socket.display()))
            .args(["-semihosting-config", "enable=on,target=native", "-serial", "stdio", "-kernel"])
            .arg(elf)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| {
                SimError::Controller(format!(
                    "cannot start qemu-system-arm ({e}); install it with apt-get install qemu-system-arm"
                ))
            })?;
        let (Some(stdin), Some(stdout)) = (child.stdin.take(), child.stdout.take()) else {
            let _ = child.kill();
            return Err(SimError::Controller("qemu's standard I/O is not available".into()));
        };
        Ok((QemuSession { child, qmp_socket, _dir: dir }, SerialController::new(stdin, stdout)))
    }

    /// Reads `count` 32-bit words of the target's memory from `addr`, through QEMU's
    /// monitor (QMP `human-monitor-command` with `xp`). The target keeps running.
    pub fn read_words(&self, addr: u32, count: u32) -> Result<Vec<u32>, SimError> {
        use std::io::BufRead;
        let err = |what: &str| SimError::Controller(format!("QEMU monitor: {what}"));
        let socket = std::os::unix::net::UnixStream::connect(&self.qmp_socket)
            .map_err(|e| err(&format!("connecting to {}: {e}", self.qmp_socket.display())))?;
        socket.set_read_timeout(Some(ANSWER_TIMEOUT)).map_err(|e| err(&e.to_string()))?;
        let mut writer = socket.try_clone().map_err(|e| err(&e.to_string()))?;
        let mut lines = std::io::BufReader::new(socket).lines();
        // The greeting, then one answer per command (events in between are skipped).
        let mut answer = |command: serde_json::Value| -> Result<serde_json::Value, SimError> {
            writeln!(writer, "{command}").map_err(|e| err(&e.to_string()))?;
            loop {
                let line = lines.next().ok_or_else(|| err("closed"))?.map_err(|e| err(&e.to_string()))?;
                let v: serde_json::Value = serde_json::from_str(&line).map_err(|e| err(&e.to_string()))?;
                if let Some(r) = v.get("return") {
                    return Ok(r.clone());
                }
                if let Some(e) = v.get("error") {
                    return Err(err(&e.to_string()));
                }
            }
        };
        answer(serde_json::json!({ "execute": "qmp_capabilities" }))?;
        let text = answer(serde_json::json!({
            "execute": "human-monitor-command",
            "arguments": { "command-line": format!("xp /{count}wx {addr:#x}") },
        }))?;
        let text = text.as_str().ok_or_else(|| err("xp answered no text"))?;
        // Lines `<address>: 0x<word> 0x<word> ...`.
        let words: Vec<u32> = text
            .lines()
            .filter_map(|l| l.split_once(':'))
            .flat_map(|(_, w)| w.split_whitespace())
            .filter_map(|w| u32::from_str_radix(w.trim_start_matches("0x"), 16).ok())
            .collect();
        if words.len() != count as usize {
            return Err(err(&format!("xp gave {} words, not {count}", words.len())));
        }
        Ok(words)
    }

    /// The firmware's deepest stack use since boot, in bytes below the top of the stack:
    /// the image paints its free stack with [`STACK_PAINT`] at boot
    /// (`dcfo_firmware::stack::paint`), and the lowest word that no longer holds it is
    /// the high-water mark. The top is the initial stack pointer (word 0 of the vector
    /// table at address 0). `Err` when the stack was used deeper than
    /// [`STACK_SCAN_BYTES`] (or not painted).
    pub fn stack_high_water(&self) -> Result<u32, SimError> {
        let top = *self.read_words(0, 1)?.first().unwrap_or(&0);
        let lowest = (MPS2_RAM_ORIGIN + STACK_GUARD_BYTES).max(top.saturating_sub(STACK_SCAN_BYTES));
        let words = self.read_words(lowest, (top - lowest) / 4)?;
        match words.iter().position(|&w| w != STACK_PAINT) {
            Some(0) => Err(SimError::Controller(format!(
                "the stack below {lowest:#x} is not painted, or used deeper than {STACK_SCAN_BYTES} bytes"
            ))),
            Some(i) => Ok(top - (lowest + 4 * i as u32)),
            None => Ok(0),
        }
    }
}

impl Drop for QemuSession {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// What a HIL run measured.
#[derive(Debug, serde::Serialize)]
pub struct HilReport {
    /// Scenario name.
    pub scenario: String,
    /// The scenario's figures over its measurement window; `None` when the run was
    /// shortened (`--duration`) to end before the window.
    pub figures: Option<crate::sim::scenarios::Figures>,
    /// Lock-step round trips per second over the link.
    pub round_trips_per_s: f64,
    /// Simulated time, s.
    pub simulated_s: f64,
    /// The QEMU board (`None` for a board on a serial port).
    pub qemu_cpu: Option<QemuCpu>,
    /// With `--check`: samples compared, and whether every angle estimate was identical.
    pub equivalence: Option<Equivalence>,
    /// On QEMU: the firmware's deepest stack use since boot, bytes
    /// ([`QemuSession::stack_high_water`]).
    pub stack_high_water_bytes: Option<u32>,
}

/// Bit-for-bit comparison of the angle estimates of a HIL run and an in-process run.
#[derive(Debug, serde::Serialize)]
pub struct Equivalence {
    /// Samples compared.
    pub samples: usize,
    /// Samples whose f32 angle estimate differed.
    pub differing: usize,
    /// Largest difference, electrical degrees.
    pub max_diff_deg: f64,
}

/// Compares the link-reported angle estimates of two runs of the same scenario.
pub fn compare_runs(a: &crate::sim::Run, b: &crate::sim::Run) -> Equivalence {
    let mut differing = 0;
    let mut max_diff_deg = 0.0f64;
    let n = a.samples.len().min(b.samples.len());
    for (x, y) in a.samples.iter().zip(&b.samples) {
        if x.theta_hat_link.to_bits() != y.theta_hat_link.to_bits() || x.row.t != y.row.t {
            differing += 1;
            let d = crate::trace::wrap_angle(f64::from(x.theta_hat_link) - f64::from(y.theta_hat_link));
            max_diff_deg = max_diff_deg.max(d.abs().to_degrees());
        }
    }
    differing += a.samples.len().max(b.samples.len()) - n;
    Equivalence { samples: n, differing, max_diff_deg }
}

/// `dcfo hil`: see [`crate::cli::HilArgs`].
pub fn run_hil(args: &crate::cli::HilArgs) -> anyhow::Result<HilReport> {
    use crate::sim::{Setup, run_with, scenarios};
    use anyhow::Context;
    let Some(mut scenario) = scenarios::scenario(&args.scenario) else {
        anyhow::bail!("unknown scenario `{}`", args.scenario);
    };
    if let Some(d) = args.duration {
        anyhow::ensure!(d.is_finite() && d > 0.0, "--duration must be a positive number of seconds");
        scenario.duration_s = d;
        scenario.window_s = scenario.window_s.min((d - scenario.event_s).max(0.0));
    }
    // The firmware runs the DCFO drive of the paper axis.
    let setup = Setup::paper(dcfo::observer::ObserverKind::Dcfo);
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let bar = indicatif::ProgressBar::new(1000);
    let progress = |f: f64| bar.set_position((f * 1000.0) as u64);
    let mut stack = None;
    let (hil_run, rate) = if args.qemu {
        let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap_or(Path::new("."));
        let elf = match &args.elf {
            Some(e) => e.clone(),
            None => build_qemu_firmware(workspace, args.cpu)?,
        };
        let (session, mut link) = QemuSession::start(&elf, args.cpu)?;
        let run = run_with(&setup, &scenario, &mut link, progress)?;
        // A monitor that does not answer costs the figure, not the run.
        stack = match session.stack_high_water() {
            Ok(bytes) => Some(bytes),
            Err(e) => {
                eprintln!("no stack figure: {e}");
                None
            }
        };
        (run, link.round_trips_per_s())
    } else {
        let Some(port) = &args.port else { anyhow::bail!("give --qemu or --port DEVICE") };
        let dev = port.to_string_lossy().to_string();
        let serial = serialport::new(&dev, args.baud)
            .timeout(ANSWER_TIMEOUT)
            .open()
            .with_context(|| format!("opening {dev} at {} bit/s", args.baud))?;
        let reader = serial.try_clone().with_context(|| format!("{dev}: second handle"))?;
        let mut link = SerialController::new(serial, reader);
        let run = run_with(&setup, &scenario, &mut link, progress)?;
        (run, link.round_trips_per_s())
    };
    bar.finish_and_clear();
    let figures = (scenario.window_s > 0.0).then(|| scenarios::figures(&hil_run, &scenario));
    let equivalence = if args.check {
        // A board on --port runs the f32 firmware.
        let cpu = if args.qemu { args.cpu } else { QemuCpu::M4f };
        let local = run_with(&setup, &scenario, cpu.local_drive(&setup)?.as_mut(), |_| {})?;
        Some(compare_runs(&hil_run, &local))
    } else {
        None
    };
    let report = HilReport {
        scenario: scenario.name.to_string(),
        figures,
        round_trips_per_s: rate,
        qemu_cpu: args.qemu.then_some(args.cpu),
        simulated_s: hil_run.simulated_s,
        equivalence,
        stack_high_water_bytes: stack,
    };
    crate::sim::report::write_run_outputs(&hil_run, &scenario, &args.out, "hil")?;
    std::fs::write(args.out.join("summary.json"), serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}/summary.json", args.out.display()))?;
    let figures_text = match figures {
        Some(f) => {
            format!("theta_err max {:.2} deg, rms {:.2} deg", f.theta_err_max_deg, f.theta_err_rms_deg)
        }
        None => format!("no figures (the run ends before the window at {} s)", scenario.event_s),
    };
    println!(
        "{} over the HIL link: {figures_text}; {rate:.0} round trips/s; {:.2} s simulated",
        report.scenario, hil_run.simulated_s
    );
    if let Some(bytes) = stack {
        println!("deepest stack of the firmware since boot: {bytes} bytes");
    }
    if let Some(e) = &report.equivalence {
        println!(
            "equivalence with the in-process drive: {} of {} angle estimates differ (max {:.2e} deg)",
            e.differing, e.samples, e.max_diff_deg
        );
        anyhow::ensure!(e.differing == 0, "the HIL run's angle estimates differ from the in-process run's");
    }
    Ok(report)
}
