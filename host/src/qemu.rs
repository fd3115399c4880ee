//! QEMU's MPS2 boards for the firmware images: which board and numeric type
//! ([`QemuCpu`]), building an image, and a running QEMU ([`QemuSession`]) with UART0 on
//! its standard I/O and its monitor on a socket. Shared by `dcfo hil` (the lock-step
//! HIL image), `dcfo board` (the drive image with the virtual motor), the `bench_qemu`
//! benchmark (the same command line with the exec log, [`qemu_command`] and
//! [`qmp_human_command`]) and the tests: the one table of which image, board, machine
//! and target belong together.
//!
//! QEMU 7.2+: `-display none -monitor none -serial stdio` (a display or a monitor on
//! stdio would take the UART's place); the CMSDK UART model moves about 500 to 1,400
//! lock-step round trips a second.
//!
//! **Time.** No image's behaviour may follow the host's clock, which on a loaded machine
//! is not the image's to count on. Each session says what the guest's clock follows
//! ([`GuestClock`]):
//!
//! - The drive image (`qemu_drive`), whose SysTick paces its control periods, runs with
//!   [`ICOUNT`], `-icount shift=0,sleep=off`: the guest's clock is its count of executed
//!   instructions, one nanosecond each, and an idle core (`WFI`) jumps straight to its next
//!   timer deadline. Without it QEMU's virtual clock follows the host's: on a loaded machine
//!   the 10 kHz control interrupt keeps the wall clock's pace while QEMU gets less CPU, the
//!   thread between interrupts starves, and a command can take longer to cross than the
//!   command watchdog allows (the drive is then disabled and restarted mid-move). With it,
//!   what the guest does per period is fixed by its instructions: a loaded host makes it
//!   slower, never different. `shift=0` gives a period of 100,000 instructions, several
//!   times the heaviest control step (the Cortex-M3's soft-float virtual motor); `sleep=off`
//!   makes idle time free, so the image runs as fast as QEMU executes it.
//! - The lock-step HIL image (`qemu_hil`) and the stack-guard image have no timer: the HIL
//!   image steps once per frame from the host, and its link watchdog counts the periods the
//!   host's sequence numbers skip. Nothing in them reads a clock, and they run on QEMU's
//!   default. Under `-icount` every device access ends a translation block, and the
//!   lock-step exchange is nearly all UART accesses: it would cost QEMU about half again
//!   the CPU for nothing.
//!
//! The watchdogs so measure a silent host in what the host paces: the lock-step image in
//! the host's simulated periods, the drive image in its own periods *and* the host's
//! milliseconds (read through semihosting, `dcfo_firmware::board::mps2::HostClock`), so
//! that neither a host slower than QEMU nor a machine that stalls both looks like a
//! silence. The host side waits for the drive's own time where it waits for the drive
//! (`crate::commands::board`: deadlines in control periods of the telemetry, wall-clock limits only
//! against a hang). The instruction counts of `bench_qemu` come from QEMU's exec log, not
//! from its clock: its command line ([`qemu_command`]) has no `-icount`.

use crate::simulation::{Controller, SimError};
use std::io::Write;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::Duration;

/// How long a reply of QEMU's monitor may take.
pub const MONITOR_TIMEOUT: Duration = Duration::from_secs(5);

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

    /// The real core this one stands for: its clock (Hz) and the cycles per instruction
    /// assumed for it (dimensionless), from which `bench_qemu`'s instruction counts give a
    /// PWM rate ([`QemuCpu::pwm_max_hz`]).
    /// - Cortex-M4F (STM32G4 at 170 MHz): single-cycle ALU, FPU and MAC, but loads take
    ///   two cycles, taken branches refill the 3-stage pipeline (1 to 3 cycles) and the
    ///   flash has 4 wait states behind the ART cache, whose misses cost more: 1.5.
    /// - Cortex-M3 (72 MHz, e.g. STM32F103): as the M4 for the ALU, branches and loads,
    ///   but a 32 x 32 -> 64 multiply (`SMULL`, the Q8.24 product) takes 3 to 5 cycles,
    ///   the flash has 2 wait states behind a small prefetch buffer and there is no
    ///   cache: 2.0 (issue 36's 3,600 instructions in a 10 kHz period of 7,200 cycles).
    pub fn clock_and_cpi(self) -> (f64, f64) {
        match self {
            QemuCpu::M4f => (170e6, 1.5),
            QemuCpu::M3 => (72e6, 2.0),
        }
    }

    /// The highest PWM rate (Hz, rounded down) at which a control step of `instructions`
    /// fits one period on the real core ([`QemuCpu::clock_and_cpi`]).
    pub fn pwm_max_hz(self, instructions: u64) -> f64 {
        let (clock, cpi) = self.clock_and_cpi();
        (clock / (cpi * instructions.max(1) as f64)).floor()
    }

    /// The in-process drive the firmware's results must equal: same code, same numeric
    /// type, same units.
    pub fn local_drive(self, setup: &crate::simulation::Setup) -> Result<Box<dyn Controller>, SimError> {
        Ok(match self {
            QemuCpu::M4f => Box::new(crate::simulation::LocalDrive::new(setup)?),
            QemuCpu::M3 => Box::new(crate::simulation::LocalDrive::fixed_point(setup)?),
        })
    }
}

/// Why an image for `cpu` cannot run on QEMU here, if it cannot: no `qemu-system-arm`,
/// or the toolchain (`$RUSTC`, else `rustc`) lacks the target's `core`. For tests that
/// skip rather than fail where the tools are missing.
pub fn missing_tools(cpu: QemuCpu) -> Option<String> {
    if Command::new("qemu-system-arm").arg("--version").output().is_err() {
        return Some("qemu-system-arm is not installed (apt-get install qemu-system-arm)".into());
    }
    let rustc = std::env::var_os("RUSTC").unwrap_or_else(|| "rustc".into());
    let libdir = Command::new(rustc).args(["--print", "target-libdir", "--target", cpu.target()]).output();
    let installed = libdir.is_ok_and(|o| {
        o.status.success()
            && std::fs::read_dir(String::from_utf8_lossy(&o.stdout).trim())
                .is_ok_and(|d| d.flatten().any(|e| e.file_name().to_string_lossy().starts_with("libcore-")))
    });
    (!installed).then(|| format!("the {} target is not installed", cpu.target()))
}

/// Cargo's target directory for the workspace at `workspace`: `$CARGO_TARGET_DIR`
/// (relative to `workspace` when relative) if set, else `workspace/target`, where a
/// `cargo build` run in `workspace` puts its output.
pub fn target_dir(workspace: &Path) -> PathBuf {
    match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) if !dir.is_empty() => workspace.join(dir),
        _ => workspace.join("target"),
    }
}

/// The ELF of firmware image `example` (`qemu_hil`, `qemu_drive`, `bench`, ...) for
/// `cpu`, in the workspace's target directory ([`target_dir`]).
pub fn qemu_example_elf(workspace: &Path, cpu: QemuCpu, example: &str) -> PathBuf {
    target_dir(workspace).join(cpu.target()).join("release/examples").join(example)
}

/// The command line that runs `elf` on `cpu`'s board: `-display none -monitor none
/// -serial stdio` (UART0 on QEMU's standard I/O), semihosting on (the images exit
/// through it), the monitor (QMP) on the Unix socket `qmp_socket`. Standard I/O is not
/// set; callers add their own options (the benchmark: the exec log).
pub fn qemu_command(elf: &Path, cpu: QemuCpu, qmp_socket: &Path) -> Command {
    let (machine, core) = cpu.machine_and_cpu();
    let mut command = Command::new("qemu-system-arm");
    command
        .args(["-M", machine, "-cpu", core, "-display", "none", "-monitor", "none"])
        .arg("-qmp")
        .arg(format!("unix:{},server=on,wait=off", qmp_socket.display()))
        .args(["-semihosting-config", "enable=on,target=native", "-serial", "stdio", "-kernel"])
        .arg(elf);
    command
}

/// Runs one human-monitor command (`xp /4wx 0x0`, `log exec,nochain`) through QEMU's
/// monitor (QMP) on the Unix socket `qmp_socket` and returns its text output; each read
/// waits at most `timeout`. An error names the socket or QMP's refusal.
pub fn qmp_human_command(
    qmp_socket: &Path,
    command_line: &str,
    timeout: Duration,
) -> Result<String, SimError> {
    use std::io::BufRead;
    let err = |what: &str| SimError::Controller(format!("QEMU monitor at {}: {what}", qmp_socket.display()));
    let socket =
        std::os::unix::net::UnixStream::connect(qmp_socket).map_err(|e| err(&format!("connecting: {e}")))?;
    socket.set_read_timeout(Some(timeout)).map_err(|e| err(&e.to_string()))?;
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
                return Err(err(&format!("`{command_line}` refused: {e}")));
            }
        }
    };
    answer(serde_json::json!({ "execute": "qmp_capabilities" }))?;
    let text = answer(serde_json::json!({
        "execute": "human-monitor-command",
        "arguments": { "command-line": command_line },
    }))?;
    text.as_str().map(str::to_owned).ok_or_else(|| err(&format!("`{command_line}` answered no text")))
}

/// Builds the MPS2 firmware image `example` for `cpu` with cargo (release).
pub fn build_qemu_example(workspace: &Path, cpu: QemuCpu, example: &str) -> Result<PathBuf, SimError> {
    let status = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .current_dir(workspace)
        .args(["build", "--release", "-p", "dcfo-firmware", "--features", "mps2", "--example", example])
        .args(["--target", cpu.target()])
        .status()
        .map_err(|e| SimError::Controller(format!("cannot run cargo to build the firmware: {e}")))?;
    if !status.success() {
        return Err(SimError::Controller(format!(
            "building the QEMU firmware `{example}` failed ({status})"
        )));
    }
    Ok(qemu_example_elf(workspace, cpu, example))
}

/// QEMU's options that make the guest's clock count its instructions (see the module
/// docs): one instruction per nanosecond, idle time skipped.
pub const ICOUNT: [&str; 2] = ["-icount", "shift=0,sleep=off"];

/// What the guest's clock follows in a session (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GuestClock {
    /// The instructions the guest executes ([`ICOUNT`]): for an image whose timers pace
    /// its work (the drive image's control periods).
    Instructions,
    /// QEMU's default, which follows the host's clock: only for an image that has no timer
    /// and reads no clock (the lock-step HIL image, the stack-guard image).
    Untimed,
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
    /// Starts `qemu-system-arm` on `cpu`'s board with `elf` (`-display none -monitor none
    /// -serial stdio`: UART0 on the returned pipes), the guest's clock following `clock`;
    /// returns the session and the pipes.
    pub fn spawn(
        elf: &Path,
        cpu: QemuCpu,
        clock: GuestClock,
    ) -> Result<(QemuSession, ChildStdin, ChildStdout), SimError> {
        Self::spawn_with_cmdline(elf, cpu, clock, None)
    }

    /// [`QemuSession::spawn`], passing `cmdline` to the image (QEMU's `-append`: the
    /// image reads `<elf> <cmdline>` through semihosting `SYS_GET_CMDLINE`).
    pub fn spawn_with_cmdline(
        elf: &Path,
        cpu: QemuCpu,
        clock: GuestClock,
        cmdline: Option<&str>,
    ) -> Result<(QemuSession, ChildStdin, ChildStdout), SimError> {
        let dir =
            tempfile::tempdir().map_err(|e| SimError::Controller(format!("temporary directory: {e}")))?;
        let qmp_socket = dir.path().join("qmp.sock");
        let mut command = qemu_command(elf, cpu, &qmp_socket);
        if clock == GuestClock::Instructions {
            command.args(ICOUNT);
        }
        if let Some(line) = cmdline {
            command.arg("-append").arg(line);
        }
        let mut child = command
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            // Its own process group: a Ctrl-C at the terminal goes to the host tool, which
            // disables the drive through QEMU before it stops it (`dcfo board`).
            .process_group(0)
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
        Ok((QemuSession { child, qmp_socket, _dir: dir }, stdin, stdout))
    }

    /// Reads `count` 32-bit words of the target's memory from `addr`, through QEMU's
    /// monitor (QMP `human-monitor-command` with `xp`). The target keeps running.
    pub fn read_words(&self, addr: u32, count: u32) -> Result<Vec<u32>, SimError> {
        let text = qmp_human_command(&self.qmp_socket, &format!("xp /{count}wx {addr:#x}"), MONITOR_TIMEOUT)?;
        let err = |what: &str| SimError::Controller(format!("QEMU monitor: {what}"));
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
