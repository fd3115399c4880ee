//! `bench_qemu`: the cost of the control step on QEMU (instructions), the firmware
//! images' flash and static RAM, and the budget they are held to.
//!
//! # What is measured
//! The benchmark firmware (`firmware/examples/bench.rs`) runs a scripted run on its
//! virtual motor and times *every* `Drive::step` of it: the speed drive's start-up (I/f),
//! cold acquisition, a lock loss and the re-acquisition; then the stroke axis's
//! positioning drive with HFI (alignment, a move out and one back through zero speed, a
//! hold). The motor is `motors/salient.toml`, passed to the image as a motor image on
//! its command line. Cortex-M4F (`mps2-an386`) runs `Drive<f32>`, Cortex-M3
//! (`mps2-an385`) `Drive<Q24>`. From the counts:
//! - `step_*`: the mean step of the positioning drive in `Running` (sensorless);
//! - `worst_step_*`: the most expensive single step of the whole run, which decides the
//!   PWM rate a core sustains; `worst_by_state` has it per segment and drive state;
//! - `estimator_*`: the mean of the estimator alone on the same steps (a copy of the
//!   drive's, stepped on the drive's inputs), `worst_estimator_*` its maximum;
//! - `stages`: each block of the step once (Clarke, cos/sin, Park, PI, SVPWM, ...);
//! - `stack_step_*_b`: the deepest stack of one step (painted stack);
//! - the images' flash (`.vector_table + .text + .rodata + .data`) and static RAM
//!   (`.data + .bss + .uninit`), from `arm-none-eabi-size -A`.
//!
//! # How: QEMU's instruction counter as a clock
//! QEMU runs with `-icount shift=8`: its virtual clock advances exactly `2^8` ns per
//! executed guest instruction, whatever the host does. SysTick on the 25 MHz core
//! clock (40 ns a tick) then counts 6.4 ticks per instruction, and the firmware reads it
//! around each step; `round(ticks / 6.4)` is the instruction count, exact (a tick's
//! quantisation is 0.16 instruction). The firmware sends sums and maxima per drive
//! state, not per-step figures, so a run of tens of thousands of steps costs a few
//! seconds and prints a few lines. Each run checks the conversion: a function of 64
//! `nop`s must measure 64 instructions more than an empty one, else the tool fails.
//! The `empty` region (a call of an empty function and the two timer reads) is
//! subtracted from every region. QEMU's single-stepped exec log would count the same
//! instructions line by line, but a log of the whole run would be billions of lines.
//! Instructions are not cycles: the PWM rates below assume the cycles per instruction
//! of [`QemuCpu::clock_and_cpi`].
//!
//! # The budget
//! `--check` compares against the figures recorded in [`RECORDED`]
//! (`bench/recorded.json`): it fails when a running or worst step (either core) is more
//! than [`GROWTH_ALLOWED`] over its recorded figure, when an image is over its hard limit
//! ([`FLASH_ESC1_LIMIT_B`], [`RAM_ESC1_LIMIT_B`], [`FLASH_QEMU_HIL_M3_LIMIT_B`]) and
//! either grew over its recorded size or its recorded size met the limit (a limit not
//! met yet is reported `OVER` and may only be approached: [`size_verdict`]), or when
//! the ESC1 image puts an initialised object of more than [`DATA_OBJECT_LIMIT_B`] bytes in
//! `.data` (a buffer that starts empty belongs in `.bss`). `--record` writes the
//! measured figures into that file (a deliberate update, committed with the reason:
//! `docs/cost-budget.md`). `--json` prints the figures as one JSON object on the last
//! line.
//!
//! ```sh
//! cargo run --release -p dcfo-host --bin bench_qemu              # table
//! cargo run --release -p dcfo-host --bin bench_qemu -- --json    # + JSON, last line
//! cargo run --release -p dcfo-host --bin bench_qemu -- --check   # the budget (CI)
//! cargo run --release -p dcfo-host --bin bench_qemu -- --record  # re-record, deliberately
//! cargo run --release -p dcfo-host --bin bench_qemu -- --profile m3  # where the worst step goes
//! ```
//!
//! `--profile m3|m4f` runs only that core's benchmark, under QEMU's translation and
//! execution log, and prints per function the instructions of the costliest step and the
//! mean step, and the soft-float routines by their callers
//! (`dcfo_host::exec_profile`). It takes several minutes (seven for the M3) and checks no
//! figure.
//!
//! Needs `qemu-system-arm` (7.2), `arm-none-eabi-size` and `arm-none-eabi-nm`
//! (binutils-arm-none-eabi) and the two thumb targets.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Parser;
use dcfo::motor_image::MotorImage;
use dcfo_host::commands::board::session::qemu_image_cmdline;
use dcfo_host::exec_profile::{ExecProfile, Symbols};
use dcfo_host::motor_file::load_motor;
use dcfo_host::qemu::{QemuCpu, build_qemu_example, qemu_example_elf, target_dir};
use serde_json::{Map, Value, json};

/// QEMU's `-icount` shift: `2^ICOUNT_SHIFT` ns of virtual time per instruction.
const ICOUNT_SHIFT: u32 = 8;
/// SysTick's period on QEMU's MPS2 boards (25 MHz core clock), ns.
const SYSTICK_NS: f64 = 40.0;
/// Timer ticks per instruction.
const TICKS_PER_INSTRUCTION: f64 = (1u64 << ICOUNT_SHIFT) as f64 / SYSTICK_NS;

/// The motor of the run (workspace-relative): salient, so that the positioning drive
/// runs HFI at low speed.
const MOTOR_FILE: &str = "motors/salient.toml";
/// The recorded figures (workspace-relative).
const RECORDED: &str = "bench/recorded.json";
/// How much a running or worst step may grow over its recorded figure before `--check`
/// fails: 10 %.
const GROWTH_ALLOWED: f64 = 0.10;
/// The figures `--check` holds to [`GROWTH_ALLOWED`].
const BUDGETED: [&str; 4] = ["step_m4f_f32", "worst_step_m4f_f32", "step_m3_q24", "worst_step_m3_q24"];
/// Hard limits: the ESC1 drive image's flash and static RAM (capture included), the
/// Cortex-M3 HIL image's flash, bytes.
const FLASH_ESC1_LIMIT_B: u64 = 64 * 1024;
const RAM_ESC1_LIMIT_B: u64 = 8 * 1024;
const FLASH_QEMU_HIL_M3_LIMIT_B: u64 = 96 * 1024;
/// The size figures and their hard limits.
const SIZE_LIMITS: [(&str, u64); 3] = [
    ("flash_esc1_drive_b", FLASH_ESC1_LIMIT_B),
    ("ram_esc1_drive_b", RAM_ESC1_LIMIT_B),
    ("flash_qemu_hil_m3_b", FLASH_QEMU_HIL_M3_LIMIT_B),
];

/// What `--check` makes of an image size.
#[derive(Debug, PartialEq, Eq)]
enum SizeVerdict {
    /// Within its hard limit.
    Within,
    /// Over its limit, but the recorded figure is over it too and it has not grown: the
    /// limit is not met yet (reported, not failed); once a figure within the limit is
    /// recorded, the limit binds.
    OverNotGrown,
    /// Over its limit, and grown over the recorded figure (or that one met the limit).
    Fail,
}

/// `now` bytes against the hard `limit` and the `recorded` figure (see [`SizeVerdict`]).
fn size_verdict(now: u64, limit: u64, recorded: Option<u64>) -> SizeVerdict {
    match recorded {
        _ if now <= limit => SizeVerdict::Within,
        Some(r) if r > limit && now <= r => SizeVerdict::OverNotGrown,
        _ => SizeVerdict::Fail,
    }
}

/// The largest initialised object the ESC1 drive image may keep in `.data`, bytes.
const DATA_OBJECT_LIMIT_B: u64 = 256;

/// `bench_qemu`: the cost of the control step on QEMU, the images' sizes, the budget.
#[derive(Parser, Debug)]
#[command(about)]
struct Args {
    /// Print the figures as one JSON object on the last line.
    #[arg(long)]
    json: bool,
    /// Fail when a running or worst step grew more than 10 % over bench/recorded.json,
    /// or an image is over its hard size limit.
    #[arg(long)]
    check: bool,
    /// Write the measured figures into bench/recorded.json (a deliberate update).
    #[arg(long, conflicts_with = "check")]
    record: bool,
    /// Only profile the benchmark on one core (`m3` or `m4f`): per function, the
    /// instructions of the costliest step and of the mean one (module docs).
    #[arg(long, value_parser = ["m3", "m4f"], conflicts_with_all = ["check", "record", "json"])]
    profile: Option<String>,
}

/// One benchmark image and the QEMU board it runs on.
struct Board {
    /// Key suffix in the figures: `m4f_f32`, `m3_q24`.
    key: &'static str,
    label: &'static str,
    qemu: QemuCpu,
}

const BOARDS: [Board; 2] = [
    Board { key: "m4f_f32", label: "Cortex-M4F f32", qemu: QemuCpu::M4f },
    Board { key: "m3_q24", label: "Cortex-M3 Q8.24", qemu: QemuCpu::M3 },
];

/// A tally the firmware sent: count, sum and maximum of a region's ticks.
#[derive(Clone, Copy, Debug)]
struct Tally {
    count: u64,
    sum: u64,
    max: u64,
}

/// What one image's run printed.
#[derive(Default, Debug)]
struct Run {
    /// Ticks of the empty function, the sled, and the sled's length.
    cal: Option<(u64, u64, u64)>,
    /// Ticks of the `empty` region (call overhead).
    empty: Option<u64>,
    /// (segment, state) -> steps.
    steps: BTreeMap<(String, String), Tally>,
    /// (segment, state) -> estimator alone.
    estimator: BTreeMap<(String, String), Tally>,
    /// segment -> states in the order entered.
    visited: BTreeMap<String, Vec<String>>,
    /// stage -> ticks.
    stages: Vec<(String, u64)>,
    stack: Option<u64>,
    stack_hil: Option<u64>,
    ended: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::FAILURE,
        Err(e) => {
            eprintln!("bench_qemu: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Runs everything; `Ok(false)` when `--check` found the budget broken.
fn run(args: &Args) -> Result<bool> {
    let started = Instant::now();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .context("host crate has no parent directory")?
        .to_path_buf();
    let motor_path = root.join(MOTOR_FILE);
    let motor = load_motor(&motor_path.to_string_lossy())
        .with_context(|| format!("loading {}", motor_path.display()))?
        .params;
    let image = MotorImage::new(motor, dcfo_host::commands::stroke::bus_for(&motor))
        .map_err(|e| anyhow::anyhow!("{MOTOR_FILE}: no motor image: {e:?}"))?;
    let cmdline = qemu_image_cmdline(&image);
    if let Some(core) = &args.profile {
        let board =
            BOARDS.iter().find(|b| b.key.starts_with(core.as_str())).context("--profile: no such core")?;
        build_qemu_example(&root, board.qemu, "bench")?;
        profile(&qemu_example_elf(&root, board.qemu, "bench"), board, &cmdline)?;
        return Ok(true);
    }

    for board in &BOARDS {
        build_qemu_example(&root, board.qemu, "bench")?;
        build_qemu_example(&root, board.qemu, "qemu_hil")?;
    }
    build_esc1(&root)?;

    let mut figures = Map::new();
    let mut stages: BTreeMap<String, Map<String, Value>> = BTreeMap::new();
    let mut by_state = Map::new();
    println!("Instructions per region (QEMU -icount shift={ICOUNT_SHIFT}, SysTick around each call), less");
    println!("the empty region's (a call and the two timer reads). Motor {MOTOR_FILE}.");
    for board in &BOARDS {
        let elf = qemu_example_elf(&root, board.qemu, "bench");
        let t = Instant::now();
        let out = run_qemu(&elf, board.qemu, &cmdline)?;
        let run = parse(&out).with_context(|| format!("{}: the benchmark's output:\n{out}", board.label))?;
        eprintln!("bench_qemu: {} ran in {:.1} s", board.label, t.elapsed().as_secs_f64());
        let results =
            figures_of(&run).with_context(|| format!("{}: the benchmark's output:\n{out}", board.label))?;
        print_run(board, &run, &results);
        let k = board.key;
        figures.insert(format!("step_{k}"), json!(results.step));
        figures.insert(format!("worst_step_{k}"), json!(results.worst_step));
        figures.insert(format!("estimator_{k}"), json!(results.estimator));
        figures.insert(format!("worst_estimator_{k}"), json!(results.worst_estimator));
        figures.insert(format!("stack_step_{}_b", k.split('_').next().unwrap_or(k)), json!(run.stack));
        figures.insert(format!("stack_hil_{}_b", k.split('_').next().unwrap_or(k)), json!(run.stack_hil));
        let pwm = board.qemu.pwm_max_hz(results.worst_step);
        figures.insert(format!("pwm_max_hz_{k}"), json!(pwm));
        by_state.insert(k.to_owned(), Value::Object(results.by_state));
        for (name, n) in &results.stages {
            stages.entry(name.clone()).or_default().insert(k.to_owned(), json!(n));
        }
    }

    println!();
    println!("Image sizes (arm-none-eabi-size -A; flash = .vector_table + .text + .rodata + .data,");
    println!("static RAM = .data + .bss + .uninit; the stack is not included):");
    let esc1 = target_dir(&root).join("thumbv7em-none-eabihf/release/examples");
    let images: Vec<(&str, String, PathBuf)> = vec![
        ("esc1_drive", "b_g431b_esc1 (STM32G431CB, thumbv7em-none-eabihf)".into(), esc1.join("b_g431b_esc1")),
        (
            "esc1_hil",
            "b_g431b_esc1_hil (STM32G431CB, thumbv7em-none-eabihf)".into(),
            esc1.join("b_g431b_esc1_hil"),
        ),
        (
            "qemu_hil_m4f",
            "qemu_hil (Cortex-M4F, thumbv7em-none-eabihf)".into(),
            qemu_example_elf(&root, QemuCpu::M4f, "qemu_hil"),
        ),
        (
            "qemu_hil_m3",
            "qemu_hil (Cortex-M3, thumbv7m-none-eabi)".into(),
            qemu_example_elf(&root, QemuCpu::M3, "qemu_hil"),
        ),
    ];
    println!("| {:<54} | {:>10} | {:>14} |", "image", "flash (B)", "static RAM (B)");
    println!("|{}|{}:|{}:|", "-".repeat(56), "-".repeat(11), "-".repeat(15));
    for (key, name, path) in &images {
        let (flash, ram) = sizes(path)?;
        println!("| {name:<54} | {flash:>10} | {ram:>14} |");
        figures.insert(format!("flash_{key}_b"), json!(flash));
        figures.insert(format!("ram_{key}_b"), json!(ram));
    }
    let big_data = data_objects(&esc1.join("b_g431b_esc1"), DATA_OBJECT_LIMIT_B)?;

    let mut all = figures.clone();
    all.insert("by_state".into(), Value::Object(by_state));
    all.insert(
        "stages".into(),
        Value::Object(stages.into_iter().map(|(k, v)| (k, Value::Object(v))).collect()),
    );
    let ((clock_m4f, cpi_m4f), (clock_m3, cpi_m3)) =
        (QemuCpu::M4f.clock_and_cpi(), QemuCpu::M3.clock_and_cpi());
    all.insert("cpi".into(), json!({ "m4f": cpi_m4f, "m3": cpi_m3 }));
    all.insert("clock_hz".into(), json!({ "m4f": clock_m4f, "m3": clock_m3 }));

    println!();
    for board in &BOARDS {
        let k = board.key;
        let (clock, cpi) = board.qemu.clock_and_cpi();
        println!(
            "{}: worst step {} instructions = {:.0} cycles at {cpi} CPI: {:.1} kHz PWM at {:.0} MHz",
            board.label,
            figures.get(&format!("worst_step_{k}")).and_then(Value::as_u64).unwrap_or(0),
            cpi * figures.get(&format!("worst_step_{k}")).and_then(Value::as_f64).unwrap_or(0.0),
            figures.get(&format!("pwm_max_hz_{k}")).and_then(Value::as_f64).unwrap_or(0.0) / 1e3,
            clock / 1e6
        );
    }

    let recorded_path = root.join(RECORDED);
    let mut ok = true;
    if args.record {
        let mut recorded = Map::new();
        let sizes = SIZE_LIMITS.map(|(key, _)| key);
        for key in BUDGETED.iter().chain(&["estimator_m4f_f32", "estimator_m3_q24"]).chain(&sizes) {
            if let Some(v) = figures.get(*key) {
                recorded.insert((*key).to_owned(), v.clone());
            }
        }
        let text = serde_json::to_string_pretty(&Value::Object(recorded))? + "\n";
        std::fs::write(&recorded_path, text)
            .with_context(|| format!("writing {}", recorded_path.display()))?;
        eprintln!("bench_qemu: recorded the figures in {RECORDED}");
    }
    if args.check {
        ok = check(&recorded_path, &figures, &big_data)?;
    }
    eprintln!("bench_qemu: {:.0} s in all", started.elapsed().as_secs_f64());
    if args.json {
        println!("{}", Value::Object(all));
    }
    Ok(ok)
}

/// The budget: the budgeted figures against the recorded ones, the hard size limits, and
/// no large initialised object in the ESC1 image's `.data`. Prints each verdict.
fn check(recorded_path: &Path, figures: &Map<String, Value>, big_data: &[(String, u64)]) -> Result<bool> {
    let text = std::fs::read_to_string(recorded_path)
        .with_context(|| format!("reading the recorded figures {}", recorded_path.display()))?;
    let recorded: Map<String, Value> = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a JSON object of figures", recorded_path.display()))?;
    let mut ok = true;
    println!();
    println!(
        "Budget (--check): steps within {:.0} % of {RECORDED}, sizes within their limits",
        GROWTH_ALLOWED * 100.0
    );
    for key in BUDGETED {
        let Some(limit) = recorded.get(key).and_then(Value::as_f64) else {
            bail!("{}: no figure `{key}`", recorded_path.display());
        };
        let now = figures
            .get(key)
            .and_then(Value::as_f64)
            .with_context(|| format!("no figure `{key}` measured"))?;
        let allowed = (limit * (1.0 + GROWTH_ALLOWED)).floor();
        let pass = now <= allowed;
        ok &= pass;
        println!(
            "{} {key}: {now} instructions, recorded {limit}, allowed {allowed} ({:+.1} %)",
            if pass { "ok  " } else { "FAIL" },
            (now / limit - 1.0) * 100.0
        );
    }
    for (key, limit) in SIZE_LIMITS {
        let now = figures
            .get(key)
            .and_then(Value::as_u64)
            .with_context(|| format!("no figure `{key}` measured"))?;
        let recorded = recorded.get(key).and_then(Value::as_u64);
        match size_verdict(now, limit, recorded) {
            SizeVerdict::Within => println!("ok   {key}: {now} B, limit {limit} B"),
            SizeVerdict::OverNotGrown => println!(
                "OVER {key}: {now} B, over the limit of {limit} B by {} B; not grown over the recorded {} B \
                 (the limit binds once it is met: issue 36 item 2)",
                now - limit,
                recorded.unwrap_or(now)
            ),
            SizeVerdict::Fail => {
                ok = false;
                println!(
                    "FAIL {key}: {now} B, limit {limit} B{}",
                    recorded.map_or(String::new(), |r| format!(", recorded {r} B"))
                );
            }
        }
    }
    if big_data.is_empty() {
        println!("ok   b_g431b_esc1: no initialised object over {DATA_OBJECT_LIMIT_B} B in .data");
    }
    for (name, size) in big_data {
        ok = false;
        println!(
            "FAIL b_g431b_esc1: {name} ({size} B) is initialised in .data (flash and RAM); an object that \
             starts empty belongs in .bss"
        );
    }
    if !ok {
        println!(
            "The budget is broken. Make it cheaper, or record the new figures deliberately \
             (docs/cost-budget.md)."
        );
    }
    Ok(ok)
}

/// QEMU on `cpu`'s board running `elf` with the instruction counter as the clock, the
/// motor image `cmdline` on its command line and UART0 on its stdout.
fn qemu_command(elf: &Path, cpu: QemuCpu, cmdline: &str) -> Command {
    let (machine, core) = cpu.machine_and_cpu();
    let mut c = Command::new("qemu-system-arm");
    c.args(["-M", machine, "-cpu", core, "-display", "none", "-monitor", "none"])
        .args(["-icount", &format!("shift={ICOUNT_SHIFT},align=off,sleep=off")])
        .args(["-semihosting-config", "enable=on,target=native", "-serial", "stdio"])
        .arg("-kernel")
        .arg(elf)
        .args(["-append", cmdline]);
    c
}

/// Runs `elf` on `cpu`'s board with the instruction counter as the clock and the motor
/// image on its command line; returns UART0's output.
fn run_qemu(elf: &Path, cpu: QemuCpu, cmdline: &str) -> Result<String> {
    let (machine, _) = cpu.machine_and_cpu();
    let out = qemu_command(elf, cpu, cmdline)
        .stdin(Stdio::null())
        .stderr(Stdio::inherit())
        .output()
        .context("running qemu-system-arm (apt-get install qemu-system-arm)")?;
    let text = String::from_utf8_lossy(&out.stdout).replace('\r', "");
    if !out.status.success() {
        bail!("{} on {machine} exited with {}; output:\n{text}", elf.display(), out.status);
    }
    Ok(text)
}

/// How many functions `--profile` lists.
const PROFILE_LINES: usize = 30;

/// `--profile`: runs `elf` on `board` under QEMU's `in_asm,exec,nochain` log (on its
/// stderr) and prints where the steps' instructions go (`dcfo_host::exec_profile`).
fn profile(elf: &Path, board: &Board, cmdline: &str) -> Result<()> {
    use std::io::{BufRead, BufReader, Read};
    let nm = Command::new("arm-none-eabi-nm")
        .args(["-n", "-C", "--defined-only"])
        .arg(elf)
        .output()
        .context("running arm-none-eabi-nm (apt install binutils-arm-none-eabi)")?;
    if !nm.status.success() {
        bail!("arm-none-eabi-nm {} failed", elf.display());
    }
    let symbols = Symbols::from_nm(&String::from_utf8_lossy(&nm.stdout));
    let marker =
        symbols.find(PROFILE_MARKER).with_context(|| format!("{}: no {PROFILE_MARKER}", elf.display()))?;
    let (machine, _) = board.qemu.machine_and_cpu();
    let t = Instant::now();
    let mut child = qemu_command(elf, board.qemu, cmdline)
        .args(["-d", "in_asm,exec,nochain"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .context("running qemu-system-arm (apt-get install qemu-system-arm)")?;
    let mut stdout = child.stdout.take().context("qemu's stdout")?;
    let uart = std::thread::spawn(move || {
        let mut s = String::new();
        stdout.read_to_string(&mut s).map(|_| s)
    });
    let mut log = BufReader::with_capacity(1 << 20, child.stderr.take().context("qemu's stderr")?);
    let mut p = ExecProfile::new(symbols, marker);
    let mut line = String::new();
    while log.read_line(&mut line).context("reading qemu's log")? > 0 {
        p.line(line.trim_end());
        line.clear();
    }
    let status = child.wait().context("waiting for qemu")?;
    let out = uart.join().map_err(|_| anyhow::anyhow!("the UART reader panicked"))?.context("qemu's UART")?;
    if !status.success() || !out.contains("END") {
        bail!("{} on {machine} exited with {status}; output:\n{out}", elf.display());
    }
    let r = p.finish().context("no step was profiled")?;
    println!(
        "{}: {} steps ({PROFILE_MARKER} calls) in {:.0} s; mean {:.0} instructions, costliest {} (step {})",
        board.label,
        r.windows,
        t.elapsed().as_secs_f64(),
        r.mean,
        r.worst,
        r.worst_window
    );
    println!("| {:>9} | {:>9} | function |", "costliest", "mean");
    println!("|----------:|----------:|----------|");
    for s in r.functions.iter().take(PROFILE_LINES) {
        let mean = s.mean.map_or_else(|| "-".to_owned(), |m| format!("{m:.0}"));
        println!("| {:>9} | {mean:>9} | {} |", s.worst, s.name);
    }
    println!();
    println!("Soft-float routines and conversions in the costliest step, by caller:");
    println!("| {:>9} | caller |", "costliest");
    println!("|----------:|--------|");
    for s in r.float_by_caller.iter().take(PROFILE_LINES) {
        println!("| {:>9} | {} |", s.worst, s.name);
    }
    Ok(())
}

/// The bench's timed call of one `Drive::step`: a profile window per call.
const PROFILE_MARKER: &str = "stage_step_brief";

/// Reads the firmware's lines (`firmware/examples/bench.rs` lists them).
fn parse(out: &str) -> Result<Run> {
    let mut run = Run::default();
    let num = |w: Option<&str>, what: &str| -> Result<u64> {
        w.with_context(|| format!("{what}: missing"))?
            .parse::<u64>()
            .with_context(|| format!("{what}: not a count"))
    };
    for line in out.lines() {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["CAL", _, nothing, sled, n, empty] => {
                run.cal = Some((num(Some(nothing), "CAL")?, num(Some(sled), "CAL")?, num(Some(n), "CAL")?));
                run.empty = Some(num(Some(empty), "CAL")?);
            }
            ["STAGE", _, name, ticks] => run.stages.push(((*name).to_owned(), num(Some(ticks), "STAGE")?)),
            [kind @ ("STEPS" | "ESTIMATOR"), _, segment, state, count, sum, max] => {
                let tally = Tally {
                    count: num(Some(count), kind)?,
                    sum: num(Some(sum), kind)?,
                    max: num(Some(max), kind)?,
                };
                let map = if *kind == "STEPS" { &mut run.steps } else { &mut run.estimator };
                map.insert(((*segment).to_owned(), (*state).to_owned()), tally);
            }
            ["VISITED", _, segment, states] => {
                run.visited.insert((*segment).to_owned(), states.split(',').map(str::to_owned).collect());
            }
            ["STACK", _, bytes] => run.stack = Some(num(Some(bytes), "STACK")?),
            ["STACK_HIL", _, bytes] => run.stack_hil = Some(num(Some(bytes), "STACK_HIL")?),
            ["END", _] => run.ended = true,
            [first, ..] if first.starts_with("PANIC") || first.starts_with("ERROR") => {
                bail!("firmware: {line}")
            }
            _ => {}
        }
    }
    if !run.ended {
        bail!("the benchmark did not finish (no END line)");
    }
    Ok(run)
}

/// The figures of one run, in instructions.
struct Results {
    step: u64,
    worst_step: u64,
    estimator: u64,
    worst_estimator: u64,
    by_state: Map<String, Value>,
    stages: Vec<(String, u64)>,
}

/// The states each segment must have gone through, in this order (others may lie
/// between): what the run is to cover.
const REQUIRED: [(&str, &[&str]); 2] = [
    ("speed", &["calibrating", "starting", "running", "reacquiring", "running"]),
    ("positioning", &["calibrating", "low_speed", "running", "low_speed", "running", "low_speed"]),
];

/// Instructions from ticks, less the empty region's.
fn figures_of(run: &Run) -> Result<Results> {
    let (nothing, sled, n) = run.cal.context("no CAL line")?;
    let insns = |ticks: f64| (ticks / TICKS_PER_INSTRUCTION).round() as i64;
    let measured = insns(sled as f64) - insns(nothing as f64);
    if measured != n as i64 {
        bail!(
            "the clock does not count instructions as assumed (-icount shift={ICOUNT_SHIFT}, SysTick at \
             {SYSTICK_NS} ns): a sled of {n} instructions measured {measured}"
        );
    }
    let empty = insns(run.empty.context("no empty region")? as f64);
    let net = |ticks: f64| (insns(ticks) - empty).max(0) as u64;
    for (segment, states) in REQUIRED {
        let visited = run.visited.get(segment).with_context(|| format!("no VISITED line for {segment}"))?;
        let mut rest = visited.iter();
        for want in states {
            if !rest.any(|s| s == want) {
                bail!(
                    "the {segment} segment did not go through {} in that order (it went {}): the run no \
                     longer covers what the budget is measured on",
                    states.join(" -> "),
                    visited.join(" -> ")
                );
            }
        }
    }
    let running = run
        .steps
        .get(&("positioning".to_owned(), "running".to_owned()))
        .context("no step of the positioning drive in Running")?;
    let est = run
        .estimator
        .get(&("positioning".to_owned(), "running".to_owned()))
        .context("no estimator step of the positioning drive in Running")?;
    let mean = |t: &Tally| net(t.sum as f64 / t.count as f64);
    let mut by_state = Map::new();
    for ((segment, state), t) in &run.steps {
        let e = run.estimator.get(&(segment.clone(), state.clone()));
        by_state.insert(
            format!("{segment}.{state}"),
            json!({
                "steps": t.count,
                "step_mean": mean(t),
                "step_worst": net(t.max as f64),
                "estimator_mean": e.map(mean),
                "estimator_worst": e.map(|e| net(e.max as f64)),
            }),
        );
    }
    Ok(Results {
        step: mean(running),
        worst_step: run.steps.values().map(|t| net(t.max as f64)).max().unwrap_or(0),
        estimator: mean(est),
        worst_estimator: run.estimator.values().map(|t| net(t.max as f64)).max().unwrap_or(0),
        by_state,
        stages: run.stages.iter().map(|(name, t)| (name.clone(), net(*t as f64))).collect(),
    })
}

/// The run's table on stdout.
fn print_run(board: &Board, run: &Run, r: &Results) {
    println!();
    println!("{} ({} steps in all):", board.label, run.steps.values().map(|t| t.count).sum::<u64>());
    println!(
        "| {:<26} | {:>6} | {:>10} | {:>10} | {:>15} | {:>15} |",
        "segment.state", "steps", "step mean", "step worst", "estimator mean", "estimator worst"
    );
    println!(
        "|{}|{}:|{}:|{}:|{}:|{}:|",
        "-".repeat(28),
        "-".repeat(7),
        "-".repeat(11),
        "-".repeat(11),
        "-".repeat(16),
        "-".repeat(16)
    );
    for (name, v) in &r.by_state {
        let field =
            |k: &str| v.get(k).and_then(Value::as_u64).map_or_else(|| "-".to_owned(), |n| n.to_string());
        println!(
            "| {name:<26} | {:>6} | {:>10} | {:>10} | {:>15} | {:>15} |",
            field("steps"),
            field("step_mean"),
            field("step_worst"),
            field("estimator_mean"),
            field("estimator_worst")
        );
    }
    println!(
        "step (positioning, running, mean) {}, worst step {}, estimator {} (worst {}); stages: {}",
        r.step,
        r.worst_step,
        r.estimator,
        r.worst_estimator,
        r.stages.iter().map(|(n, c)| format!("{n} {c}")).collect::<Vec<_>>().join(", ")
    );
    println!(
        "deepest stack of one Drive::step {} B, of the HIL receive path {} B",
        run.stack.map_or_else(|| "?".into(), |s| s.to_string()),
        run.stack_hil.map_or_else(|| "?".into(), |s| s.to_string())
    );
}

/// Builds the B-G431B-ESC1 images (feature `esc1`), for their sizes.
fn build_esc1(root: &Path) -> Result<()> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let status = Command::new(cargo)
        .current_dir(root)
        .args(["build", "-p", "dcfo-firmware", "--release", "--features", "esc1", "--examples"])
        .args(["--target", "thumbv7em-none-eabihf"])
        .status()
        .context("running cargo")?;
    if !status.success() {
        bail!("building the B-G431B-ESC1 images failed ({status})");
    }
    Ok(())
}

/// Flash and static RAM of an image (bytes), from `arm-none-eabi-size -A`.
fn sizes(elf: &Path) -> Result<(u64, u64)> {
    let out = Command::new("arm-none-eabi-size")
        .arg("-A")
        .arg(elf)
        .output()
        .context("running arm-none-eabi-size (apt install binutils-arm-none-eabi)")?;
    if !out.status.success() {
        bail!("arm-none-eabi-size {} failed", elf.display());
    }
    let (mut flash, mut ram) = (0, 0);
    for line in String::from_utf8_lossy(&out.stdout).lines() {
        let mut fields = line.split_whitespace();
        let (Some(section), Some(size)) = (fields.next(), fields.next()) else { continue };
        let Ok(size) = size.parse::<u64>() else { continue };
        match section {
            ".vector_table" | ".text" | ".rodata" => flash += size,
            ".data" => {
                flash += size;
                ram += size;
            }
            ".bss" | ".uninit" => ram += size,
            _ => {}
        }
    }
    Ok((flash, ram))
}

/// The objects in `elf`'s `.data` larger than `limit` bytes (name, size), from
/// `arm-none-eabi-nm -S -C`.
fn data_objects(elf: &Path, limit: u64) -> Result<Vec<(String, u64)>> {
    let out = Command::new("arm-none-eabi-nm")
        .args(["-S", "-C"])
        .arg(elf)
        .output()
        .context("running arm-none-eabi-nm (apt install binutils-arm-none-eabi)")?;
    if !out.status.success() {
        bail!("arm-none-eabi-nm {} failed", elf.display());
    }
    let mut found = Vec::new();
    for line in String::from_utf8_lossy(&out.stdout).lines() {
        // `<address> <size> <kind> <name>`
        let mut fields = line.splitn(4, ' ');
        let (Some(_), Some(size), Some(kind), Some(name)) =
            (fields.next(), fields.next(), fields.next(), fields.next())
        else {
            continue;
        };
        let Ok(size) = u64::from_str_radix(size, 16) else { continue };
        if matches!(kind, "d" | "D") && size > limit {
            found.push((name.to_owned(), size));
        }
    }
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::{SizeVerdict, size_verdict};

    #[test]
    fn a_size_over_its_limit_fails_once_the_limit_was_met_or_when_it_grows() {
        // Within the limit: fine whatever was recorded.
        assert_eq!(size_verdict(60_000, 65_536, Some(70_000)), SizeVerdict::Within);
        assert_eq!(size_verdict(65_536, 65_536, None), SizeVerdict::Within);
        // Over it, recorded over it too, not grown: reported, not failed.
        assert_eq!(size_verdict(75_000, 65_536, Some(75_260)), SizeVerdict::OverNotGrown);
        assert_eq!(size_verdict(75_260, 65_536, Some(75_260)), SizeVerdict::OverNotGrown);
        // Grown over the recorded figure, or the recorded figure met the limit: failed.
        assert_eq!(size_verdict(75_261, 65_536, Some(75_260)), SizeVerdict::Fail);
        assert_eq!(size_verdict(65_537, 65_536, Some(65_000)), SizeVerdict::Fail);
        assert_eq!(size_verdict(65_537, 65_536, None), SizeVerdict::Fail);
    }
}
