//! `bench_qemu`: instructions executed per control step and per stage, counted on QEMU.
//!
//! Builds the benchmark firmware (`firmware/examples/bench.rs`) for Cortex-M4F
//! (`thumbv7em-none-eabihf`, QEMU `mps2-an386`: f32 and Q24) and Cortex-M3
//! (`thumbv7m-none-eabi`, QEMU `mps2-an385`: Q24), and the HIL image `qemu_hil` for
//! both (for its size). Each
//! benchmark runs under `qemu-system-arm -singlestep -d nochain`; once the firmware has
//! warmed its drives up it prints `READY` and waits for a byte on UART0, and this
//! program switches QEMU's exec log on over QMP (`log exec,nochain`) and sends the
//! byte. With one instruction per translation block and no chaining, every executed
//! instruction is one `Trace` line; the count of a region is the number of lines from
//! an entry of the firmware's `bench_begin` to the next entry of its `bench_end`, less
//! that of the `empty` region (the markers and the call overhead).
//!
//! Prints the table of counts, the images' flash and static RAM (from
//! `arm-none-eabi-size -A`) and the deepest stack of one `Drive::step` (measured by the
//! firmware on a painted stack).
//!
//! ```sh
//! cargo run --release -p dcfo-host --bin bench_qemu
//! ```
//!
//! `BENCH_QEMU_TRACE_DIR=<dir>` keeps the exec traces (from the gate on) in `<dir>`.
//!
//! Needs `qemu-system-arm` (7.2), `arm-none-eabi-nm` and `arm-none-eabi-size`
//! (binutils-arm-none-eabi) and the two thumb targets.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use dcfo_host::qemu::{
    QemuCpu, build_qemu_example, qemu_command, qemu_example_elf, qmp_human_command, target_dir,
};

/// The baseline region.
const EMPTY_REGION: &str = "empty";

/// One benchmark image and the QEMU board it runs on: target, machine, CPU, the
/// image's path, how it is built and run all come from `dcfo_host::qemu`, shared with
/// `dcfo hil` and `dcfo board`.
struct Board {
    label: &'static str,
    qemu: QemuCpu,
}

impl Board {
    fn target(&self) -> &'static str {
        self.qemu.target()
    }
    fn machine(&self) -> &'static str {
        self.qemu.machine_and_cpu().0
    }
}

const BOARDS: [Board; 2] =
    [Board { label: "Cortex-M4F", qemu: QemuCpu::M4f }, Board { label: "Cortex-M3", qemu: QemuCpu::M3 }];

/// What one run measured: per numeric type, the regions' instruction counts (in
/// order), and the stack depth.
#[derive(Default)]
struct Run {
    /// type name -> [(region, instructions)], the `empty` baseline not yet subtracted.
    regions: BTreeMap<String, Vec<(String, u64)>>,
    /// type name -> bytes.
    stack: BTreeMap<String, u64>,
    /// type name -> bytes of the HIL receive path (a frame's last byte).
    stack_hil: BTreeMap<String, u64>,
    /// type name -> drive state after the measured steps.
    state: BTreeMap<String, String>,
    /// type name -> the acquiring estimator's step at which its circle fit ended (or
    /// `none`).
    fit_end: BTreeMap<String, String>,
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("bench_qemu: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<()> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .context("host crate has no parent directory")?
        .to_path_buf();
    for board in &BOARDS {
        build_qemu_example(&root, board.qemu, "bench")?;
        build_qemu_example(&root, board.qemu, "qemu_hil")?;
    }

    let mut runs = Vec::new();
    for board in &BOARDS {
        let elf = qemu_example_elf(&root, board.qemu, "bench");
        let started = Instant::now();
        let run = run_traced(board, &elf)?;
        eprintln!(
            "bench_qemu: {} ({}) traced in {:.1} s",
            board.label,
            board.machine(),
            started.elapsed().as_secs_f64()
        );
        runs.push((board, run));
    }

    // Columns: (board, type) in run order.
    let mut columns = Vec::new();
    for (board, run) in &runs {
        for (ty, regions) in &run.regions {
            columns.push((board.label, ty.as_str(), regions, run));
        }
    }
    // f32 first, then by board.
    columns.sort_by_key(|(label, ty, _, _)| (*ty != "f32", *label != "Cortex-M4F"));

    println!();
    println!("Instructions executed (QEMU exec trace, one line per instruction), less the call overhead");
    println!("of an empty stage (`empty` row, raw). `step`: one whole `Drive::step` in Running, mean");
    println!("[min..max] of 10 consecutive steps (the speed loop runs in one of them). `acquire`: one");
    println!("estimator step from a re-acquisition on, mean [min..max] of 800 consecutive steps");
    println!("(the circle fit's, its seed and the hand-over among them).");
    println!();
    let headers: Vec<String> = columns.iter().map(|(label, ty, _, _)| format!("{label} {ty}")).collect();
    print!("| {:<14} |", "stage");
    for h in &headers {
        print!(" {h:>22} |");
    }
    println!();
    print!("|{}|", "-".repeat(16));
    for _ in &headers {
        print!("{}:|", "-".repeat(23));
    }
    println!();
    let stage_names = columns.first().map(|(_, _, regions, _)| unique_names(regions)).unwrap_or_default();
    for name in &stage_names {
        print!("| {name:<14} |");
        for (_, _, regions, _) in &columns {
            print!(" {:>22} |", cell(regions, name));
        }
        println!();
    }
    println!();
    for (label, ty, _, run) in &columns {
        let stack = run.stack.get(*ty).map_or_else(|| "?".to_owned(), |s| s.to_string());
        let state = run.state.get(*ty).map_or("?", String::as_str);
        let hil = run.stack_hil.get(*ty).map_or_else(|| "?".to_owned(), |s| s.to_string());
        let fit_end = run.fit_end.get(*ty).map_or("?", String::as_str);
        println!(
            "{label} {ty}: drive state {state}; deepest stack of one Drive::step {stack} bytes, of the HIL \
             receive path (decode, step, encode) {hil} bytes; acquiring estimator's circle fit ended at \
             step {fit_end}"
        );
    }

    println!();
    println!("Image sizes (arm-none-eabi-size -A; flash = .vector_table + .text + .rodata + .data,");
    println!("static RAM = .data + .bss + .uninit; the stack is not included):");
    build_esc1(&root)?;
    let mut images = Vec::new();
    for example in ["b_g431b_esc1", "b_g431b_esc1_hil"] {
        images.push((
            format!("{example} (STM32G431CB, thumbv7em-none-eabihf)"),
            target_dir(&root).join("thumbv7em-none-eabihf/release/examples").join(example),
        ));
    }
    for board in &BOARDS {
        for example in ["qemu_hil", "bench"] {
            images.push((
                format!("{example} ({}, {})", board.label, board.target()),
                qemu_example_elf(&root, board.qemu, example),
            ));
        }
    }
    println!("| {:<54} | {:>12} | {:>16} |", "image", "flash (B)", "static RAM (B)");
    println!("|{}|{}:|{}:|", "-".repeat(56), "-".repeat(13), "-".repeat(17));
    for (name, path) in &images {
        let (flash, ram) = sizes(path)?;
        println!("| {name:<54} | {flash:>12} | {ram:>16} |");
    }
    Ok(())
}

/// Region names in order, each once.
fn unique_names(regions: &[(String, u64)]) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    for (name, _) in regions {
        if !names.contains(name) {
            names.push(name.clone());
        }
    }
    names
}

/// One table cell: the region's count less the baseline (`empty`: raw; a region measured
/// more than once, such as `step` and `acquire`: mean [min..max]).
fn cell(regions: &[(String, u64)], name: &str) -> String {
    let baseline = regions.iter().find(|(n, _)| n == EMPTY_REGION).map_or(0, |(_, c)| *c);
    let counts: Vec<u64> = regions
        .iter()
        .filter(|(n, _)| n == name)
        .map(|(_, c)| if name == EMPTY_REGION { *c } else { c.saturating_sub(baseline) })
        .collect();
    match counts.as_slice() {
        [] => "-".to_owned(),
        [one] => one.to_string(),
        many => {
            let sum: u64 = many.iter().sum();
            let (min, max) =
                (many.iter().min().copied().unwrap_or(0), many.iter().max().copied().unwrap_or(0));
            let mean = sum as f64 / many.len() as f64;
            format!("{mean:.0} [{min}..{max}]")
        }
    }
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

/// Address of `symbol` in `elf` (Thumb bit cleared), from `arm-none-eabi-nm`.
fn symbol_address(elf: &Path, symbol: &str) -> Result<u64> {
    let out = Command::new("arm-none-eabi-nm")
        .arg(elf)
        .output()
        .context("running arm-none-eabi-nm (apt install binutils-arm-none-eabi)")?;
    if !out.status.success() {
        bail!("arm-none-eabi-nm {} failed", elf.display());
    }
    let text = String::from_utf8_lossy(&out.stdout);
    for line in text.lines() {
        let mut fields = line.split_whitespace();
        if let (Some(addr), Some(_kind), Some(name)) = (fields.next(), fields.next(), fields.next())
            && name == symbol
        {
            return Ok(u64::from_str_radix(addr, 16)? & !1);
        }
    }
    bail!("{symbol} not found in {}", elf.display())
}

/// Runs the benchmark `elf` on `board` with the exec log switched on at the gate, and
/// counts the instructions in each region.
fn run_traced(board: &Board, elf: &Path) -> Result<Run> {
    let begin = symbol_address(elf, "bench_begin")?;
    let end = symbol_address(elf, "bench_end")?;
    let dir = tempfile::tempdir().context("creating a temporary directory")?;
    // `BENCH_QEMU_TRACE_DIR=<dir>` keeps the traces (`<dir>/<target>.log`) for a look
    // at where the instructions go (each line names its function).
    let trace = match std::env::var_os("BENCH_QEMU_TRACE_DIR") {
        Some(keep) => {
            std::fs::create_dir_all(&keep)?;
            PathBuf::from(keep).join(format!("{}.log", board.target()))
        }
        None => dir.path().join("trace.log"),
    };
    let qmp = dir.path().join("qmp.sock");
    let mut child = qemu_command(elf, board.qemu, &qmp)
        .args(["-singlestep", "-d", "nochain", "-D"])
        .arg(&trace)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .context("starting qemu-system-arm")?;
    let (Some(mut stdin), Some(stdout)) = (child.stdin.take(), child.stdout.take()) else {
        bail!("qemu-system-arm has no stdin/stdout pipe");
    };
    let mut lines = Vec::new();
    let mut gate_opened = false;
    for line in BufReader::new(stdout).lines() {
        let line = line.context("reading QEMU's output")?;
        let line = line.trim().to_owned();
        if line == "READY" && !gate_opened {
            switch_exec_log_on(&qmp)?;
            stdin.write_all(b"g").context("opening the gate (UART0)")?;
            stdin.flush()?;
            gate_opened = true;
        }
        if line.starts_with("PANIC") || line.starts_with("ERROR") {
            eprintln!("bench_qemu: firmware: {line}");
        }
        lines.push(line);
    }
    let status = child.wait()?;
    if !status.success() {
        bail!("{} exited with {status}; output:\n{}", board.machine(), lines.join("\n"));
    }
    if !gate_opened {
        bail!("the firmware never reached READY; output:\n{}", lines.join("\n"));
    }

    let spans = region_spans(&trace, begin, end)?;
    let mut run = Run::default();
    let mut next = 0usize;
    for line in &lines {
        let mut words = line.split_whitespace();
        match (words.next(), words.next(), words.next()) {
            (Some("BENCH"), Some(ty), Some(names)) => {
                // `name*n` is n regions of that name.
                let mut expanded = Vec::new();
                for entry in names.split(',') {
                    let (name, n) = match entry.split_once('*') {
                        Some((name, n)) => {
                            (name, n.parse::<usize>().with_context(|| format!("BENCH line: {entry:?}"))?)
                        }
                        None => (entry, 1),
                    };
                    expanded.extend(std::iter::repeat_n(name, n));
                }
                let names = expanded;
                let Some(counts) = spans.get(next..next + names.len()) else {
                    bail!("{} regions in the trace, too few for those of {ty}", spans.len());
                };
                let regions = names.iter().zip(counts).map(|(n, c)| ((*n).to_owned(), *c)).collect();
                run.regions.insert(ty.to_owned(), regions);
                next += names.len();
            }
            (Some("STACK_HIL"), Some(ty), Some(bytes)) => {
                run.stack_hil.insert(ty.to_owned(), bytes.parse().context("STACK_HIL line")?);
            }
            (Some("STACK"), Some(ty), Some(bytes)) => {
                run.stack.insert(ty.to_owned(), bytes.parse().context("STACK line")?);
            }
            (Some("ACQUIRE"), Some(ty), Some(step)) => {
                run.fit_end.insert(ty.to_owned(), step.to_owned());
            }
            (Some("END"), Some(ty), Some(state)) => {
                run.state.insert(ty.to_owned(), state.to_owned());
            }
            _ => {}
        }
    }
    if next != spans.len() {
        bail!("{} regions in the trace, {next} expected", spans.len());
    }
    Ok(run)
}

/// `log exec,nochain` over QMP.
fn switch_exec_log_on(socket: &Path) -> Result<()> {
    qmp_human_command(socket, "log exec,nochain", Duration::from_secs(30))?;
    Ok(())
}

/// Instructions (trace lines) from each entry of `begin` to the next entry of `end`.
fn region_spans(trace: &Path, begin: u64, end: u64) -> Result<Vec<u64>> {
    let file = File::open(trace).with_context(|| format!("opening {}", trace.display()))?;
    let mut reader = BufReader::with_capacity(1 << 20, file);
    let mut line = Vec::new();
    let mut index = 0u64;
    let mut started = None;
    let mut spans = Vec::new();
    loop {
        line.clear();
        if reader.read_until(b'\n', &mut line)? == 0 {
            break;
        }
        // `Trace 0: 0x7f.. [00800408/00009c56/00000110/ff000201] bench_begin`
        if !line.starts_with(b"Trace ") {
            continue;
        }
        let Some(pc) = trace_pc(&line) else { continue };
        if pc == begin {
            if started.is_some() {
                bail!("{}: bench_begin entered twice without bench_end", trace.display());
            }
            started = Some(index);
        } else if pc == end {
            let Some(start) = started.take() else {
                bail!("{}: bench_end entered without bench_begin", trace.display());
            };
            spans.push(index - start);
        }
        index += 1;
    }
    Ok(spans)
}

/// The guest PC of one exec-trace line: the second field between the brackets.
fn trace_pc(line: &[u8]) -> Option<u64> {
    let open = line.iter().position(|&b| b == b'[')?;
    let rest = &line[open + 1..];
    let first = rest.iter().position(|&b| b == b'/')?;
    let rest = &rest[first + 1..];
    let end = rest.iter().position(|&b| b == b'/' || b == b']')?;
    u64::from_str_radix(std::str::from_utf8(&rest[..end]).ok()?, 16).ok()
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
