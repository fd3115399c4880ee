//! The `dcfo` command line: argument definitions (clap derive) and the subcommands'
//! entry points. `src/main.rs` parses [`Cli`] and calls [`run`].
//!
//! Output discipline: results go to stdout (a human summary, or with `--json` exactly
//! one JSON object and nothing else); progress and information go to stderr; errors go
//! to stderr with a non-zero exit status (1 for a refused input or failed run, 2 for a
//! usage error or a subcommand that is not available yet).
//!
//! The doc comments of the argument structs are the `--help` text; units are written
//! in brackets (`[V]`), which rustdoc would otherwise take for links.
#![allow(rustdoc::broken_intra_doc_links)]

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::{Args, Parser, Subcommand, ValueEnum};
use dcfo::observer::ObserverKind;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use crate::motor_file::load_motor;
use crate::replay::{observer_name, replay_trace_with_progress};
use crate::summary::{DEFAULT_SETTLE_S, Summary};
use crate::trace::{InputTrace, write_output_trace};

/// `dcfo`: host tools for the sensorless PMSLM drive with the disturbance compensated
/// flux observer (DCFO).
#[derive(Debug, Parser)]
#[command(
    name = "dcfo",
    version,
    about = "Host tools for the sensorless PMSLM drive with the disturbance compensated flux observer (DCFO)",
    long_about = "Host tools for the sensorless PMSLM drive with the disturbance compensated flux \
observer (DCFO): simulate the closed-loop drive and reproduce the paper's experiments (dcfo paper, \
dcfo sim), and replay recorded or simulated traces through the drive's estimator (dcfo replay).\n\n\
All quantities are SI: seconds, volts, amperes, webers, metres, m/s; angles are electrical \
radians in files and electrical degrees in summaries. File formats: shared/trace-format.md."
)]
pub struct Cli {
    /// The subcommand to run.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Replay a trace (CSV) through a flux observer + PLL, write the estimates (CSV) and
    /// print error statistics against the trace's ground truth.
    Replay(ReplayArgs),
    /// Reproduce the paper's experiments (Figs. 11-19) in simulation, with figures.
    Paper(PaperArgs),
    /// Simulate one scenario of the closed-loop sensorless drive.
    Sim(SimArgs),
    /// Hardware-in-the-loop: run a scenario with the drive on a target (QEMU or a board
    /// on a serial port) in lock-step with the simulated plant.
    Hil(HilArgs),
    /// Operate a drive image: a board on a serial port, or the virtual-motor image on QEMU.
    /// Live state, commands (enable, disable, clear faults, speed), capture download to a
    /// trace (`--record`); `--demo` runs the whole path once, non-interactively.
    Board(BoardArgs),
    /// Acquisition benchmark: cold starts of the estimator on a mover already moving,
    /// 12 speeds x 2 directions x 8 positions x 3 input offsets, f32 and Q8.24.
    Acquire(AcquireArgs),
    /// Positioning over a 0.3 m stroke: back-and-forth moves through zero speed with
    /// the low-speed mode at every reversal, position estimate against the truth.
    Stroke(StrokeArgs),
    /// Fault campaign: inject each fault a real axis meets (open phase, short, sensor,
    /// ADC, bus, blocked mover, overload, lock loss, link faults, parameter errors) into
    /// the closed-loop simulation and check the drive's reaction.
    Faults(FaultsArgs),
    /// Write a motor image: the motor (file or preset) and the bus voltage as the binary
    /// record a drive board reads from its reserved flash page (dcfo::motor_image).
    MotorImage(MotorImageArgs),
    /// Commissioning: the drive identifies Rs, Ld, Lq, psi_f and the inverter's voltage
    /// error on the simulated plant of a motor (`--sim`), prints identified against true
    /// values and writes the identified motor file (`-o`).
    Identify(IdentifyArgs),
}

/// Arguments of `dcfo board`.
#[derive(Debug, Clone, Args)]
pub struct BoardArgs {
    /// Run the drive image with the virtual motor (`examples/qemu_drive`) on QEMU (board:
    /// --cpu); it is built with cargo unless --elf is given. Needs qemu-system-arm.
    #[arg(long, conflicts_with = "port", required_unless_present = "port")]
    pub qemu: bool,
    /// A drive image on this serial port (e.g. /dev/ttyACM0).
    #[arg(long, value_name = "DEVICE")]
    pub port: Option<String>,
    /// Serial bit rate [bit/s] (--port).
    #[arg(long, value_name = "N", default_value_t = 921_600)]
    pub baud: u32,
    /// QEMU board: m4f (mps2-an386, f32) or m3 (mps2-an385, Q8.24).
    #[arg(long, value_enum, default_value = "m4f")]
    pub cpu: crate::qemu::QemuCpu,
    /// The QEMU image to run instead of building examples/qemu_drive.
    #[arg(long, value_name = "FILE")]
    pub elf: Option<PathBuf>,
    /// Download the capture into this trace (CSV, shared trace format: t [s], u_alpha and
    /// u_beta [V], i_alpha and i_beta [A], alpha_e_ref [rad/s^2]) once it is over; the
    /// capture is armed on connect and starts at the drive's next start.
    #[arg(long, value_name = "FILE.csv")]
    pub record: Option<PathBuf>,
    /// Non-interactive: connect, arm the capture, enable at --speed, wait until the drive
    /// runs and the capture is over, download it, replay it, disable.
    #[arg(long)]
    pub demo: bool,
    /// Speed reference of --demo [m/s].
    #[arg(long, value_name = "M/S", default_value_t = 0.3, allow_negative_numbers = true)]
    pub speed: f32,
    /// With --demo: print one JSON object on the last line of stdout (keys state_reached,
    /// capture_samples, replay_identical, ...).
    #[arg(long, requires = "demo")]
    pub json: bool,
}

/// Arguments of `dcfo identify`.
#[derive(Debug, Clone, Args)]
pub struct IdentifyArgs {
    /// Run the drive's commissioning in-process against the simulated plant of `--motor`.
    #[arg(long)]
    pub sim: bool,
    /// Run the firmware's commissioning under QEMU (not implemented: exits with status 2).
    #[arg(long)]
    pub qemu: bool,
    /// Run the commissioning of a board on this serial port (not implemented: exits with
    /// status 2).
    #[arg(long, value_name = "DEVICE")]
    pub port: Option<String>,
    /// Motor the plant is built from: a preset name (`paper`) or a motor TOML file. The
    /// drive is told only its rated current and voltage, the bus and the pole pitch.
    #[arg(long, default_value = "paper")]
    pub motor: String,
    /// Seed of the plant's sensor noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write the identified motor (shared motor-file format) to this file.
    #[arg(short = 'o', long = "output", value_name = "FILE")]
    pub output: Option<PathBuf>,
    /// Print one JSON object on the last line of stdout.
    #[arg(long)]
    pub json: bool,
    /// Instead: the light-load steady angle error of the paper axis (`dcfo sim steady`)
    /// without, with the typed-in and with the identified inverter compensation, over
    /// this many plant seeds (1..=N), and the medians.
    #[arg(long, value_name = "SEEDS")]
    pub steady: Option<u64>,
}

/// What tunes the DCFO's notch (`dcfo::estimator::NotchTuning`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum NotchArg {
    /// The FLL while acquiring, then the PLL's frequency integrator.
    Acquire,
    /// The FLL always.
    Fll,
    /// The PLL's frequency integrator always (the paper's method).
    Pll,
}

impl NotchArg {
    /// The library's setting.
    pub fn tuning(self) -> dcfo::estimator::NotchTuning {
        use dcfo::estimator::NotchTuning;
        match self {
            NotchArg::Acquire => NotchTuning::AcquireWithFll,
            NotchArg::Fll => NotchTuning::Fll,
            NotchArg::Pll => NotchTuning::Pll,
        }
    }
}

/// Arguments of `dcfo stroke`.
#[derive(Debug, Clone, Args)]
pub struct StrokeArgs {
    /// Motor: a preset name (`paper`) or a motor TOML file in the shared format. The
    /// drive's tuning derives from it; the plant deviates from it (R +20 %, L -5 %).
    #[arg(long, default_value = "paper")]
    pub motor: String,
    /// Print exactly one JSON object (the summary) on stdout.
    #[arg(long)]
    pub json: bool,
    /// Directory for `stroke.json`, `stroke.csv` (every 10th period) and the figure
    /// `stroke.png` / `stroke.svg`.
    #[arg(long, value_name = "DIR", default_value = "out/stroke")]
    pub out: PathBuf,
}

/// Arguments of `dcfo faults`.
#[derive(Debug, Clone, Args)]
pub struct FaultsArgs {
    /// Print exactly one JSON object (cases, silent_failures, max_bridge_off_periods and
    /// every case's figures) on stdout, on its last line.
    #[arg(long)]
    pub json: bool,
    /// Directory for `faults.json` and one figure per case (`CASE.png` / `CASE.svg`):
    /// angle, error, speed, currents and state around the injection.
    #[arg(long, value_name = "DIR", default_value = "out/faults")]
    pub out: PathBuf,
}

/// Arguments of `dcfo acquire`.
#[derive(Debug, Clone, Args)]
pub struct AcquireArgs {
    /// Print exactly one JSON object (the totals and the per-speed table) on stdout.
    #[arg(long)]
    pub json: bool,
    /// What tunes the DCFO's notch, in the recording drive and in the cold-started
    /// estimators: `acquire` (the FLL while acquiring, then the PLL; the default), `fll`
    /// (the FLL always), `pll` (the PLL's integrator always: the paper's method).
    #[arg(long, value_enum, default_value = "acquire")]
    pub notch: NotchArg,
    /// Directory for `acquire.json` (every cold start), `acquire.csv` (the table) and
    /// `acquire.png` / `acquire.svg` (lock time against speed).
    #[arg(long, value_name = "DIR", default_value = "out/acquire")]
    pub out: PathBuf,
}

/// Arguments of `dcfo motor-image`.
#[derive(Debug, Clone, Args)]
pub struct MotorImageArgs {
    /// Motor: a preset name (`paper`) or a TOML motor file (shared/trace-format.md).
    #[arg(long, value_name = "FILE|PRESET")]
    pub motor: String,
    /// Nominal DC-bus voltage of the board, V (e.g. 24 on the B-G431B-ESC1).
    #[arg(long, value_name = "V")]
    pub bus_v: f32,
    /// Output file (56 bytes). Flash it on the B-G431B-ESC1 with
    /// `probe-rs download --chip STM32G431CBUx --binary-format bin --base-address 0x0801F800 FILE`.
    #[arg(short, long, value_name = "FILE")]
    pub out: PathBuf,
}

/// Arguments of `dcfo hil`.
#[derive(Debug, Clone, Args)]
pub struct HilArgs {
    /// Run the firmware on QEMU (board: --cpu); it is built with cargo unless --elf is
    /// given. Needs qemu-system-arm.
    #[arg(long, conflicts_with = "port", required_unless_present = "port")]
    pub qemu: bool,
    /// Serial device of a drive board running the HIL firmware (e.g. /dev/ttyACM0).
    #[arg(long, value_name = "DEVICE")]
    pub port: Option<PathBuf>,
    /// Baud rate of --port, bit/s (8N1).
    #[arg(long, value_name = "N", default_value_t = 921_600)]
    pub baud: u32,
    /// Scenario by name; the link carries no observer offsets, so: steady, speed-step or
    /// load-step.
    #[arg(long, value_name = "NAME", default_value = "steady")]
    pub scenario: String,
    /// Simulated time, s (default: the scenario's full duration).
    #[arg(long, value_name = "S")]
    pub duration: Option<f64>,
    /// QEMU board for --qemu: m4f (mps2-an386, f32 firmware) or m3 (mps2-an385, Q8.24
    /// fixed-point firmware).
    #[arg(long, value_enum, default_value = "m4f")]
    pub cpu: crate::hil::QemuCpu,
    /// Firmware ELF for --qemu (default: build and use
    /// target/<target>/release/examples/qemu_hil).
    #[arg(long, value_name = "FILE")]
    pub elf: Option<PathBuf>,
    /// Also run the scenario with the drive in this process (same numeric type as the
    /// firmware) and require the angle estimates, as the link reports them, to be
    /// identical bit for bit.
    #[arg(long)]
    pub check: bool,
    /// Directory for the trace (CSV, SI units), summary (JSON) and figures (PNG, SVG).
    #[arg(long, value_name = "DIR", default_value = "out/hil")]
    pub out: PathBuf,
}

/// Observers the replay can run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ObserverArg {
    /// Pure integrator of u - Rs i (drifts without bound on any DC offset).
    Pi,
    /// The paper's conventional flux observer: LPF 1/(s + wc), wc = 2 pi * 2.5 Hz = 15.7 rad/s.
    Cfo,
    /// Disturbance compensated flux observer: notch at the PLL's frequency estimate, zeta = 1.0, h = -0.2 Ls w.
    Dcfo,
}

impl ObserverArg {
    /// The library's observer kind.
    pub fn kind(self) -> ObserverKind {
        match self {
            ObserverArg::Pi => ObserverKind::PureIntegrator,
            ObserverArg::Cfo => ObserverKind::Cfo,
            ObserverArg::Dcfo => ObserverKind::Dcfo,
        }
    }
}

/// Observers the closed-loop drive can run (the paper compares these two).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DriveObserverArg {
    /// The paper's conventional flux observer: LPF 1/(s + wc), wc = 2 pi * 2.5 Hz = 15.7 rad/s.
    Cfo,
    /// Disturbance compensated flux observer: notch at the PLL's frequency estimate, zeta = 1.0, h = -0.2 Ls w.
    Dcfo,
}

impl DriveObserverArg {
    /// The library's observer kind.
    pub fn kind(self) -> ObserverKind {
        match self {
            DriveObserverArg::Cfo => ObserverKind::Cfo,
            DriveObserverArg::Dcfo => ObserverKind::Dcfo,
        }
    }
}

/// Arguments of `dcfo replay`.
#[derive(Debug, Clone, Args)]
#[command(after_long_help = REPLAY_AFTER_HELP)]
pub struct ReplayArgs {
    /// Motor: a preset name (`paper`) or a TOML motor file with the keys rs_ohm [ohm],
    /// ld_h and lq_h [H], psi_f_wb [Wb], pole_pitch_m [m], rated_current_a [A RMS] and
    /// rated_voltage_v [V RMS]; mass_kg [kg] and viscous_n_s_per_m [N s/m] are optional.
    #[arg(long, value_name = "FILE|PRESET")]
    pub motor: String,

    /// Flux observer feeding the PLL.
    #[arg(long, value_enum, value_name = "OBSERVER")]
    pub observer: ObserverArg,

    /// Input trace (CSV): columns t [s], u_alpha and u_beta [V] (the voltage applied during
    /// [t, t + Ts)), i_alpha and i_beta [A] (sampled at t); optional ground truth theta
    /// [rad, electrical], v [m/s], x [m]. t must have a uniform step (the control period Ts).
    #[arg(value_name = "TRACE.csv")]
    pub trace: PathBuf,

    /// Output trace (CSV), written atomically: t [s], theta_hat [rad, electrical, in
    /// [-pi, pi)], v_hat [m/s], psi_alpha_hat and psi_beta_hat [Wb]; with ground truth also
    /// theta_err [rad] and v_err [m/s].
    #[arg(short = 'o', long = "output", value_name = "OUT.csv")]
    pub output: PathBuf,

    /// Print the summary as exactly one JSON object on stdout (keys samples, settle_s [s],
    /// theta_err_rms_deg and theta_err_max_deg [electrical degrees], v_err_rms and v_err_max
    /// [m/s], psi_amp_err_rms_wb [Wb]; null without the ground truth they need).
    #[arg(long)]
    pub json: bool,

    /// Settle time [s]: the summary covers the samples from t_first + S on.
    #[arg(long, value_name = "S", default_value_t = DEFAULT_SETTLE_S, value_parser = parse_settle)]
    pub settle: f64,
}

const REPLAY_AFTER_HELP: &str = "\
Timing: the estimator (observer + PLL in f32, SI units, as the drive runs it) is given, for row k, \
the voltage of row k-1 (the one applied during the period that ends at t_k; zero for row 0) and \
the currents of row k; the period is the trace's mean step. Output row k is the estimate at t_k.

Errors (bad trace, bad motor, a value beyond f32, an estimator fault) are reported on stderr with \
the file, line or data row and column; the exit status is then 1 and no output file is written.

Example:
  dcfo replay --motor paper --observer dcfo trace.csv -o estimates.csv --json";

/// Arguments of `dcfo paper`.
#[derive(Debug, Clone, Args)]
pub struct PaperArgs {
    /// Directory for the results: figures (PNG and SVG), traces (CSV, SI units) and
    /// summaries (JSON; angles in electrical degrees, speeds in m/s, flux in Wb). Created
    /// if absent.
    #[arg(long, value_name = "DIR", default_value = "out/paper")]
    pub out: PathBuf,
}

/// Arguments of `dcfo sim`.
#[derive(Debug, Clone, Args)]
pub struct SimArgs {
    /// Scenario to simulate: one of the paper's experiments by name (steady, speed-step,
    /// dc-u, dc-i, resistance, load-step), or a scenario file (TOML: speed references,
    /// loads, disturbances, plant deviations; docs/scenario-format.md).
    #[arg(long, value_name = "NAME|FILE")]
    pub scenario: String,

    /// The motor: a preset (`paper`) or a motor file (TOML, shared trace-format.md). The
    /// drive tunes itself from it. Without it, the paper motor on the paper's simulated
    /// test axis (10 kg carriage, the settings the HIL firmware runs).
    #[arg(long, value_name = "PRESET|FILE")]
    pub motor: Option<String>,

    /// Flux observer of the sensorless drive.
    #[arg(long, value_enum, value_name = "OBSERVER")]
    pub observer: DriveObserverArg,

    /// Directory for the results: the trace (CSV, SI units), its summary (JSON) and figures
    /// (PNG and SVG). Created if absent.
    #[arg(long, value_name = "DIR", default_value = "out/sim")]
    pub out: PathBuf,
}

fn parse_settle(text: &str) -> Result<f64, String> {
    let s: f64 = text.trim().parse().map_err(|_| format!("`{text}` is not a number of seconds"))?;
    if s.is_finite() && s >= 0.0 {
        Ok(s)
    } else {
        Err(format!("{text} s: the settle time must be a finite number of seconds >= 0"))
    }
}

/// Runs the parsed command; the exit status on success (errors are returned).
pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Board(args) => {
            run_board(&args)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Replay(args) => {
            run_replay(&args)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Paper(args) => Ok(run_paper(&args)),
        Command::Sim(args) => Ok(run_sim(&args)),
        Command::Hil(args) => {
            crate::hil::run_hil(&args)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::MotorImage(args) => {
            run_motor_image(&args)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Acquire(args) => {
            run_acquire(&args)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Stroke(args) => {
            run_stroke(&args)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Identify(args) => run_identify(&args),
        Command::Faults(args) => run_faults(&args),
    }
}

/// `dcfo identify` (see `crate::identify`).
pub fn run_identify(args: &IdentifyArgs) -> anyhow::Result<ExitCode> {
    if args.qemu || args.port.is_some() {
        eprintln!(
            "dcfo identify: --qemu and --port are not implemented yet (the firmware images do \
             not run commissioning over the link); use --sim"
        );
        return Ok(ExitCode::from(2));
    }
    if !args.sim {
        anyhow::bail!("identify: say where to run the commissioning: --sim (or --qemu, --port)");
    }
    if let Some(seeds) = args.steady {
        let median = |mut v: Vec<f64>| -> String {
            if v.is_empty() {
                return "-".into();
            }
            v.sort_by(f64::total_cmp);
            let n = v.len();
            format!("{:.3}", if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) })
        };
        let show = |x: Option<f64>| x.map_or("lost".to_string(), |d| format!("{d:.3}"));
        println!("seed  none(deg)  typed-in  identified-comp  identified-motor+comp");
        let mut rows = Vec::new();
        for seed in 1..=seeds {
            let r = crate::identify::steady_row(seed).map_err(|e| anyhow::anyhow!("seed {seed}: {e}"))?;
            println!(
                "{:>4}  {:>9}  {:>8}  {:>15}  {:>21}",
                seed,
                show(r.none_deg),
                show(r.typed_deg),
                show(r.identified_comp_deg),
                show(r.identified_all_deg)
            );
            rows.push(r);
        }
        let col = |f: fn(&crate::identify::SteadyRow) -> Option<f64>| -> (String, usize) {
            let v: Vec<f64> = rows.iter().filter_map(f).collect();
            let lost = rows.len() - v.len();
            (median(v), lost)
        };
        let cols = [
            col(|r| r.none_deg),
            col(|r| r.typed_deg),
            col(|r| r.identified_comp_deg),
            col(|r| r.identified_all_deg),
        ];
        println!(
            "median rms angle error (deg; runs lost): none {} ({}), typed-in {} ({}), identified comp {} ({}), \
             identified motor + comp {} ({})",
            cols[0].0, cols[0].1, cols[1].0, cols[1].1, cols[2].0, cols[2].1, cols[3].0, cols[3].1
        );
        if args.json {
            println!("{}", serde_json::to_string(&rows)?);
        }
        return Ok(ExitCode::SUCCESS);
    }
    let motor = load_motor(&args.motor)?;
    let report = crate::identify::identify(&args.motor, &motor.params, args.seed, Default::default())
        .map_err(|e| anyhow::anyhow!("identify {}: {e}", args.motor))?;
    if let Some(path) = &args.output {
        let text = crate::identify::motor_toml(&report, &motor.params)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    print!("{}", crate::identify::table(&report));
    if args.json {
        println!("{}", crate::identify::json_line(&report));
    }
    Ok(ExitCode::SUCCESS)
}

/// `dcfo faults`: the fault campaign (see `crate::faults`). Exit status 1 when a floor
/// is missed (a silent failure, a bridge switched off later than one period after its
/// fault's condition); cases that miss their stated expectation are counted as `unmet`.
pub fn run_faults(args: &FaultsArgs) -> anyhow::Result<ExitCode> {
    let started = Instant::now();
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    let (campaign, logs) = crate::faults::run_all(threads, |name| eprintln!("faults: {name} done"))
        .map_err(|e| anyhow::anyhow!(e))?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    std::fs::write(args.out.join("faults.json"), serde_json::to_string_pretty(&campaign)?)
        .with_context(|| format!("writing {}", args.out.join("faults.json").display()))?;
    for (r, log) in campaign.results.iter().zip(&logs) {
        crate::plot::write_figure(&crate::faults::figure(r, log), &args.out.join(&r.name))?;
    }
    eprintln!("faults: {:.1} s; results in {}", started.elapsed().as_secs_f64(), args.out.display());
    if args.json {
        println!("{}", serde_json::to_string(&campaign)?);
    } else {
        print!("{}", crate::faults::table(&campaign));
    }
    // The floors: no silent failure, the bridge off within one period on every trip.
    let floors = campaign.silent_failures == 0 && campaign.max_bridge_off_periods <= 1;
    Ok(if floors { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

/// `dcfo stroke`: the positioning drive over the stroke (see `crate::stroke`).
pub fn run_stroke(args: &StrokeArgs) -> anyhow::Result<()> {
    let motor = load_motor(&args.motor)?;
    // The positioning drive's speed loop, feed-forward and low-speed damping are tuned
    // on the mover's mass: a placeholder would tune them silently wrong.
    if motor.defaulted.contains(&"mass_kg") {
        anyhow::bail!(
            "motor file {}: key `mass_kg` is required by the positioning drive (its speed loop, \
             acceleration feed-forward and low-speed damping are tuned on the moving mass)",
            args.motor
        );
    }
    let started = Instant::now();
    let (summary, rows) = crate::stroke::run(&args.motor, &motor.params, 10)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.motor))?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    std::fs::write(args.out.join("stroke.json"), serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("writing {}", args.out.join("stroke.json").display()))?;
    let mut csv =
        String::from("t_s,x_m,x_hat_m,x_ref_m,v_m_per_s,v_ref_m_per_s,state,angle_err_deg,i_d_a,i_q_a\n");
    for r in &rows {
        csv += &format!(
            "{},{},{},{},{},{},{},{},{},{}\n",
            r.t_s,
            r.x_m,
            r.x_hat_m,
            r.x_ref_m,
            r.v_m_per_s,
            r.v_ref_m_per_s,
            r.state,
            r.angle_err_deg,
            r.i_d_a,
            r.i_q_a
        );
    }
    std::fs::write(args.out.join("stroke.csv"), csv)
        .with_context(|| format!("writing {}", args.out.join("stroke.csv").display()))?;
    crate::plot::write_figure(&crate::stroke::figure(&summary, &rows), &args.out.join("stroke"))?;
    eprintln!("stroke: {:.1} s; results in {}", started.elapsed().as_secs_f64(), args.out.display());
    if args.json {
        println!("{}", serde_json::to_string(&summary)?);
    } else {
        print!("{}", crate::stroke::table(&summary));
    }
    Ok(())
}

/// `dcfo acquire`: the acquisition sweep on the simulated paper axis.
pub fn run_acquire(args: &AcquireArgs) -> anyhow::Result<()> {
    use crate::acquire::{Options, summarise, sweep, table};
    let mut setup = crate::sim::Setup::paper(ObserverKind::Dcfo);
    setup.drive.estimator.notch_tuning = args.notch.tuning();
    let started = Instant::now();
    let starts = sweep(&setup, &Options::full(), |done, total| eprintln!("acquire: {done}/{total} speeds"))
        .map_err(|e| anyhow::anyhow!(e))?;
    let summary = summarise(&starts);
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let all = serde_json::json!({ "summary": &summary, "starts": &starts });
    std::fs::write(args.out.join("acquire.json"), serde_json::to_string_pretty(&all)?)
        .with_context(|| format!("writing {}", args.out.join("acquire.json").display()))?;
    let mut csv = String::from(
        "speed_m_per_s,budget_s,lock_time_median_s,lock_time_max_s,budget_violations,runs,false_locks\n",
    );
    let opt = |x: Option<f64>| x.map(|v| format!("{v:.6}")).unwrap_or_default();
    for r in &summary.speeds {
        csv += &format!(
            "{},{:.6},{},{},{},{},{}\n",
            r.speed_m_per_s,
            r.budget_s,
            opt(r.lock_time_median_s),
            opt(r.lock_time_max_s),
            r.budget_violations,
            r.runs,
            r.false_locks
        );
    }
    std::fs::write(args.out.join("acquire.csv"), csv)
        .with_context(|| format!("writing {}", args.out.join("acquire.csv").display()))?;
    crate::plot::write_figure(&crate::acquire::figure(&starts), &args.out.join("acquire"))?;
    eprintln!("acquire: {:.1} s; results in {}", started.elapsed().as_secs_f64(), args.out.display());
    if args.json {
        println!("{}", serde_json::to_string(&summary)?);
    } else {
        print!("{}", table(&summary));
    }
    Ok(())
}

/// `dcfo motor-image`: validates the motor and the bus voltage exactly as the firmware
/// will, then writes the record (nothing is written on an error).
pub fn run_motor_image(args: &MotorImageArgs) -> anyhow::Result<()> {
    use anyhow::Context;
    let motor = load_motor(&args.motor)?;
    let image = dcfo::motor_image::MotorImage::new(motor.params, args.bus_v)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.motor))?;
    let bytes = image.encode();
    // The firmware's own check, on the bytes as written.
    dcfo::motor_image::MotorImage::decode(&bytes).map_err(|e| anyhow::anyhow!("encoded image: {e}"))?;
    std::fs::write(&args.out, bytes).with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "motor image of {} at {} V bus: {} bytes in {}",
        motor.name,
        args.bus_v,
        bytes.len(),
        args.out.display()
    );
    Ok(())
}

/// `dcfo paper`: every paper scenario with the CFO and the DCFO.
pub fn run_paper(args: &PaperArgs) -> ExitCode {
    match crate::sim::report::run_paper(&args.out) {
        Ok(_) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("dcfo paper: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// `dcfo sim`: one scenario with one observer.
pub fn run_sim(args: &SimArgs) -> ExitCode {
    let run = || -> anyhow::Result<()> {
        let scenario = crate::sim::report::load_scenario(&args.scenario)?;
        let setup = match &args.motor {
            None => crate::sim::Setup::paper(args.observer.kind()),
            Some(m) => {
                let motor = load_motor(m)?;
                // The speed loop is tuned on the moving mass: a placeholder would tune it
                // silently wrong.
                if motor.defaulted.contains(&"mass_kg") {
                    anyhow::bail!(
                        "motor file {m}: key `mass_kg` is required to simulate the drive (its speed loop \
                         is tuned on the moving mass)"
                    );
                }
                crate::sim::Setup::for_axis(&motor.params, &scenario, args.observer.kind())
            }
        };
        crate::sim::report::run_sim(&setup, &scenario, &args.out)?;
        Ok(())
    };
    match run() {
        Ok(_) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("dcfo sim: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// `dcfo board`: see [`BoardArgs`] and [`crate::board`].
pub fn run_board(args: &BoardArgs) -> anyhow::Result<()> {
    use crate::board::{Target, run_demo, run_interactive};
    let target = match &args.port {
        Some(device) => Target::Port { device: device.clone(), baud: args.baud },
        None => Target::Qemu { cpu: args.cpu, elf: args.elf.clone() },
    };
    if !args.speed.is_finite() {
        bail!("--speed must be a finite number of m/s");
    }
    crate::board::catch_interrupt()?;
    if !args.demo {
        return run_interactive(&target, args.record.as_deref());
    }
    let report = run_demo(&target, args.speed, args.record.as_deref(), Duration::from_secs(60))?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "drive reached {}; captured {} samples; replay {} ({} differ); download {:.1} s at {:.0} round trips/s",
            report.state_reached,
            report.capture_samples,
            if report.replay_identical { "identical bit for bit" } else { "DIFFERS" },
            report.replay_differing,
            report.download_s,
            report.round_trips_per_s
        );
    }
    anyhow::ensure!(report.replay_identical, "the replay of the capture differs from the drive's estimates");
    Ok(())
}

/// `dcfo replay`: read, replay, summarise, then write the output trace and print the
/// summary. Nothing is written unless every step succeeds.
pub fn run_replay(args: &ReplayArgs) -> anyhow::Result<()> {
    let motor = load_motor(&args.motor)?;
    if same_file(&args.trace, &args.output) {
        bail!("output {} is the input trace; choose another output file", args.output.display());
    }
    let trace =
        with_spinner(format!("reading {}", args.trace.display()), || InputTrace::read_path(&args.trace))?;
    let kind = args.observer.kind();
    let rows = trace.rows().len();
    let mut progress = Progress::new(rows);
    let estimates = replay_trace_with_progress(&trace, &motor.params, kind, |n| progress.update(n))
        .with_context(|| {
            format!("{}: replay with the {} observer stopped", args.trace.display(), observer_name(kind))
        });
    progress.finish();
    let estimates = estimates?;
    let summary = Summary::compute(&trace, &estimates, &motor.params, args.settle).with_context(|| {
        format!("{}: cannot summarise (adjust --settle; no output was written)", args.trace.display())
    })?;
    with_spinner(format!("writing {}", args.output.display()), || {
        write_output_trace(&args.output, &trace, &estimates)
    })?;
    if args.json {
        println!("{}", summary.to_json());
    } else {
        let ts = trace.sample_period_s();
        let span = match (trace.rows().first(), trace.rows().last()) {
            (Some(a), Some(b)) => b.t - a.t,
            _ => 0.0,
        };
        println!(
            "replay of {} ({rows} rows, Ts = {:.4} ms, {span:.4} s) with the {} observer, motor {}",
            args.trace.display(),
            ts * 1e3,
            observer_name(kind),
            motor.name
        );
        println!("wrote {}", args.output.display());
        println!("{summary}");
    }
    Ok(())
}

/// `true` when both paths name the same existing file.
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

/// How long a step runs before its progress is shown.
const PROGRESS_DELAY: Duration = Duration::from_secs(1);

/// Runs `work`, showing a spinner with `message` on stderr if it takes longer than
/// [`PROGRESS_DELAY`] (only when stderr is a terminal).
fn with_spinner<T>(message: String, work: impl FnOnce() -> T) -> T {
    // The spinner thread waits on a channel that is closed when `work` returns (or
    // panics): the sender is dropped then.
    let (done, finished) = mpsc::channel::<()>();
    std::thread::scope(|scope| {
        scope.spawn(move || {
            if finished.recv_timeout(PROGRESS_DELAY) != Err(RecvTimeoutError::Timeout) {
                return;
            }
            let spinner = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
            let style = ProgressStyle::with_template("{spinner} {msg} ({elapsed})")
                .unwrap_or_else(|_| ProgressStyle::default_spinner());
            spinner.set_style(style);
            spinner.set_message(message);
            while finished.recv_timeout(Duration::from_millis(100)) == Err(RecvTimeoutError::Timeout) {
                spinner.tick();
            }
            spinner.finish_and_clear();
        });
        let _done = done;
        work()
    })
}

/// A progress bar on stderr that appears only once a run has taken a second (and only
/// when stderr is a terminal).
struct Progress {
    total: usize,
    start: Instant,
    bar: Option<ProgressBar>,
}

impl Progress {
    fn new(total: usize) -> Self {
        Progress { total, start: Instant::now(), bar: None }
    }

    fn update(&mut self, done: usize) {
        if self.bar.is_none() && self.start.elapsed() >= PROGRESS_DELAY {
            let bar = ProgressBar::with_draw_target(Some(self.total as u64), ProgressDrawTarget::stderr());
            let style = ProgressStyle::with_template("replay [{bar:40}] {pos}/{len} rows, {eta} left")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> ");
            bar.set_style(style);
            self.bar = Some(bar);
        }
        if let Some(bar) = &self.bar {
            bar.set_position(done as u64);
        }
    }

    fn finish(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn the_command_line_is_well_formed() {
        Cli::command().debug_assert();
    }

    #[test]
    fn replay_arguments_parse() {
        let cli = Cli::try_parse_from([
            "dcfo",
            "replay",
            "--motor",
            "paper",
            "--observer",
            "dcfo",
            "in.csv",
            "-o",
            "out.csv",
            "--json",
        ])
        .unwrap();
        let Command::Replay(a) = cli.command else { panic!("not replay") };
        assert_eq!((a.motor.as_str(), a.observer, a.json, a.settle), ("paper", ObserverArg::Dcfo, true, 0.5));
        assert_eq!((a.trace, a.output), (PathBuf::from("in.csv"), PathBuf::from("out.csv")));
        for bad in ["-1", "nan", "inf", "x"] {
            let r = Cli::try_parse_from([
                "dcfo",
                "replay",
                "--motor",
                "paper",
                "--observer",
                "pi",
                "in.csv",
                "-o",
                "o.csv",
                "--settle",
                bad,
            ]);
            assert!(r.is_err(), "{bad}");
        }
    }

    #[test]
    fn faults_arguments_parse() {
        let cli = Cli::try_parse_from(["dcfo", "faults", "--json", "--out", "x"]).unwrap();
        let Command::Faults(a) = cli.command else { panic!("not faults") };
        assert!(a.json);
        assert_eq!(a.out, PathBuf::from("x"));
        let Command::Faults(d) = Cli::try_parse_from(["dcfo", "faults"]).unwrap().command else {
            panic!("not faults")
        };
        assert_eq!((d.json, d.out), (false, PathBuf::from("out/faults")));
        assert!(Cli::try_parse_from(["dcfo", "faults", "--bogus"]).is_err());
    }

    #[test]
    fn every_option_has_help_with_units() {
        let mut cmd = Cli::command();
        for sub in ["replay", "paper", "sim"] {
            let sc = cmd.find_subcommand_mut(sub).unwrap();
            for arg in sc.get_arguments() {
                let help = arg.get_long_help().or(arg.get_help()).map(|h| h.to_string()).unwrap_or_default();
                assert!(!help.is_empty(), "{sub} --{}", arg.get_id());
            }
        }
        let help = Cli::command().find_subcommand_mut("replay").unwrap().render_long_help().to_string();
        for unit in ["[s]", "[V]", "[A]", "[Wb]", "[m/s]", "[ohm]", "[H]", "electrical degrees"] {
            assert!(help.contains(unit), "replay --help lacks {unit}:\n{help}");
        }
    }
}
