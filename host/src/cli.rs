//! The `dcfo` command line: argument definitions (clap derive) and the dispatch
//! ([`run`]), which turns each subcommand's arguments into the plain parameters of the
//! module that implements it and calls that module's entry point: `dcfo X` is
//! `crate::commands::X::run_command` (`dcfo motor-image`:
//! `crate::commands::motor_image::run_command`). No command module depends on this one.
//! `src/main.rs` parses [`Cli`] and calls [`run`].
//!
//! Output discipline: results go to stdout (a human summary, or with `--json` exactly
//! one JSON object and nothing else); progress and information go to stderr; errors go
//! to stderr with a non-zero exit status (1 for a refused input or failed run, 2 for a
//! usage error or a subcommand that is not available yet).
//!
//! The doc comments of the argument structs are the `--help` text; units are written
//! in brackets (`[V]`), which rustdoc would otherwise take for links.
#![allow(rustdoc::broken_intra_doc_links)]

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::bail;
use clap::{Args, Parser, Subcommand, ValueEnum};
use dcfo::algorithms::observer::ObserverKind;

use crate::summary::DEFAULT_SETTLE_S;

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
radians in files and electrical degrees in summaries. File formats: docs/trace-format.md and \
docs/motor-format.md."
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
    /// Tracking benchmark: the estimator alone on recordings of reversals through zero
    /// speed and sharp speed steps, f32 and Q8.24: re-lock after each reversal, error
    /// through the steps, false locks.
    Track(TrackArgs),
    /// Positioning over a 0.3 m stroke: back-and-forth moves through zero speed with
    /// the low-speed mode at every reversal, position estimate against the truth.
    Stroke(StrokeArgs),
    /// Fault campaign: inject each fault a real axis meets (open phase, short, sensor,
    /// ADC, bus, blocked mover, overload, lock loss, link faults, parameter errors, moves
    /// outside the stroke) into the closed-loop simulation of the speed and the
    /// positioning drive and check the drive's reaction.
    Faults(FaultsArgs),
    /// Write a motor image: the motor (file or preset) and the bus voltage as the binary
    /// record a drive board reads from its reserved flash page (dcfo::motor_image).
    MotorImage(MotorImageArgs),
    /// Commissioning: the drive identifies Rs, Ld, Lq, psi_f and the inverter's voltage
    /// error on the simulated plant of a motor (`--sim`), prints identified against true
    /// values and writes the identified motor file (`-o`).
    Identify(IdentifyArgs),
    /// The README's tables: render one from the tools' output into `results/NAME.md`,
    /// or copy every `results/NAME.md` into its README block (`--check`: compare only).
    Results(ResultsArgs),
}

/// Arguments of `dcfo results` (`dcfo_host::commands::results`).
#[derive(Debug, Clone, Args)]
pub struct ResultsArgs {
    /// What to do.
    #[command(subcommand)]
    pub action: ResultsAction,
    /// The workspace root, where `README.md` and `results/` are.
    #[arg(long, value_name = "DIR", default_value = ".", global = true)]
    pub root: PathBuf,
    /// Compare with the committed files and fail on a difference; write nothing.
    #[arg(long, global = true)]
    pub check: bool,
}

/// What `dcfo results` does.
#[derive(Debug, Clone, Subcommand)]
pub enum ResultsAction {
    /// Render the table NAME (paper, acquire, sim, replay, stroke, identify, faults, hil,
    /// board, cost) from tool outputs into `results/NAME.md`.
    Render {
        /// The table's name.
        #[arg(value_name = "NAME")]
        table: String,
        /// The tool outputs it is rendered from (JSON, or text whose last line is JSON),
        /// as FILE or LABEL=FILE (sim: the motor; replay: the observer).
        #[arg(value_name = "INPUT", required = true)]
        inputs: Vec<String>,
    },
    /// Copy every `results/NAME.md` into the README's block `<!-- generated:NAME -->`.
    Readme,
}

/// Where a command that talks to a firmware image runs it: on QEMU (`--qemu`, `--cpu`,
/// `--elf`) or on a board at a serial port (`--port`, `--baud`). Shared by `dcfo board`
/// (the drive image, `examples/qemu_drive`), `dcfo hil` and `dcfo identify` (the HIL
/// image, `examples/qemu_hil`).
#[derive(Debug, Clone, Args)]
pub struct TargetArgs {
    /// Run the command's firmware image on QEMU (board: --cpu); it is built with cargo
    /// unless --elf is given. Needs qemu-system-arm.
    #[arg(long, conflicts_with = "port")]
    pub qemu: bool,
    /// Serial device of a board running the command's firmware image (e.g.
    /// /dev/ttyACM0).
    #[arg(long, value_name = "DEVICE")]
    pub port: Option<PathBuf>,
    /// Bit rate of --port [bit/s] (8N1).
    #[arg(long, value_name = "N", default_value_t = 921_600)]
    pub baud: u32,
    /// QEMU board for --qemu: m4f (mps2-an386, f32 firmware) or m3 (mps2-an385, Q8.24
    /// fixed-point firmware).
    #[arg(long, value_enum, default_value = "m4f")]
    pub cpu: crate::qemu::QemuCpu,
    /// Firmware ELF for --qemu (default: the command's image built with cargo,
    /// `target/<target>/release/examples/IMAGE`: qemu_drive for `dcfo board`, qemu_hil
    /// for `dcfo hil` and `dcfo identify`).
    #[arg(long, value_name = "FILE")]
    pub elf: Option<PathBuf>,
}

impl TargetArgs {
    /// The target the arguments name: QEMU with --qemu, the board at --port, `None`
    /// when neither is given.
    pub fn target(self) -> Option<crate::target::Target> {
        match (self.qemu, self.port) {
            (true, _) => Some(crate::target::Target::Qemu { cpu: self.cpu, elf: self.elf }),
            (false, Some(device)) => Some(crate::target::Target::Port { device, baud: self.baud }),
            (false, None) => None,
        }
    }
}

/// Arguments of `dcfo board`: the drive image (with the virtual motor on QEMU,
/// `examples/qemu_drive`).
#[derive(Debug, Clone, Args)]
#[command(group(clap::ArgGroup::new("where").args(["qemu", "port"]).required(true)))]
pub struct BoardArgs {
    /// QEMU or a serial port.
    #[command(flatten)]
    pub target: TargetArgs,
    /// Download the capture into this trace (CSV, docs/trace-format.md: t [s], u_alpha and
    /// u_beta [V], i_alpha and i_beta [A], alpha_e_ref [rad/s^2]; comment lines name the
    /// drive's number type, f32 or q24: replay with `dcfo replay --numeric` of it) once it
    /// is over; the capture is armed on connect and starts at the drive's next start.
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
    /// Queue a move to this position [m] with the first command (on QEMU without --image
    /// the image then runs a positioning drive: the paper motor with the stroke axis of
    /// `dcfo stroke` in its motor image; the interactive `m <m> [s]` queues more). With
    /// --demo: enable, run the move, report move_reached and x_err_m (tolerance: pole
    /// pitch / 20) and check that a move outside the stroke is reported refused. A drive
    /// whose motor image has no axis runs a speed drive and refuses every move.
    #[arg(long, value_name = "X_M", allow_negative_numbers = true)]
    pub move_to: Option<f32>,
    /// Dwell at the --move-to target [s].
    #[arg(
        long,
        value_name = "S",
        default_value_t = 0.0,
        requires = "move_to",
        allow_negative_numbers = true
    )]
    pub dwell: f32,
    /// The motor image (`dcfo motor-image`, `dcfo identify --image`) the QEMU drive image
    /// runs, as a board reads its own from flash: with an axis a positioning drive that
    /// takes moves, without one (or a version-1 or -2 image) a speed drive. Without it:
    /// the paper motor (with the stroke axis for --move-to).
    #[arg(long, value_name = "FILE", conflicts_with = "port")]
    pub image: Option<PathBuf>,
}

/// Arguments of `dcfo identify`.
#[derive(Debug, Clone, Args)]
pub struct IdentifyArgs {
    /// Run the drive's commissioning in-process against the simulated plant of `--motor`.
    #[arg(long)]
    pub sim: bool,
    /// Or the firmware's commissioning through the lock-step HIL link (the HIL image,
    /// `examples/qemu_hil`) against the simulated plant of `--motor`: on QEMU or on a
    /// board at a serial port.
    #[command(flatten)]
    pub target: TargetArgs,
    /// With --qemu or --port: also run the commissioning in this process with the
    /// firmware's numeric type and require identical results, bit for bit.
    #[arg(long)]
    pub check: bool,
    /// Motor the plant is built from: a preset name (`paper`) or a motor TOML file. The
    /// drive is told only its rated current and voltage, the bus and the pole pitch.
    #[arg(long, default_value = "paper")]
    pub motor: String,
    /// Seed of the plant's sensor noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write the identified motor (a motor file, docs/motor-format.md) to this file.
    #[arg(short = 'o', long = "output", value_name = "FILE")]
    pub output: Option<PathBuf>,
    /// Write the identified motor, the nominal bus and the identified inverter
    /// compensation as a motor image (the board's flash record, `dcfo motor-image`'s
    /// format) to this file. An axis in the image this overwrites is kept (checked
    /// against the identified motor).
    #[arg(long, value_name = "FILE")]
    pub image: Option<PathBuf>,
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

/// Which current the drive's inverter compensation takes its signs from
/// (`dcfo::drive::CompensationSigns`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum CompensationSignsArg {
    /// The measured current (docs/inverter-compensation.md).
    Measured,
    /// The current reference where it is clear of the sensors' noise, the measured
    /// current near zero (the drive's default).
    Reference,
}

impl CompensationSignsArg {
    /// The library's setting.
    pub fn signs(self) -> dcfo::drive::CompensationSigns {
        match self {
            CompensationSignsArg::Measured => dcfo::drive::CompensationSigns::Measured,
            CompensationSignsArg::Reference => dcfo::drive::CompensationSigns::ReferenceAboveNoise,
        }
    }
}

/// Arguments of `dcfo stroke`.
#[derive(Debug, Clone, Args)]
pub struct StrokeArgs {
    /// Motor: a preset name (`paper`) or a motor TOML file (docs/motor-format.md). The
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
    /// Number of moves between the stroke's ends (each after the first reverses).
    #[arg(long, value_name = "N", default_value_t = crate::commands::stroke::MOVES as u16,
          value_parser = clap::value_parser!(u16).range(1..))]
    pub moves: u16,
    /// Run the drive on QEMU through the lock-step HIL link (board: --cpu; the
    /// `qemu_hil` image, built with cargo unless --elf is given, started with the stroke
    /// axis of the motor). Needs qemu-system-arm.
    #[arg(long)]
    pub qemu: bool,
    /// QEMU board for --qemu: m4f (mps2-an386, f32 firmware) or m3 (mps2-an385, Q8.24
    /// fixed-point firmware).
    #[arg(long, value_enum, default_value = "m4f", requires = "qemu")]
    pub cpu: crate::qemu::QemuCpu,
    /// Firmware ELF for --qemu (default: build and use
    /// `target/<target>/release/examples/qemu_hil`).
    #[arg(long, value_name = "FILE", requires = "qemu")]
    pub elf: Option<PathBuf>,
    /// With --qemu: also run the in-process drive of the firmware's numeric type and
    /// fail unless every period's angle and position estimates are identical bit for bit.
    #[arg(long, requires = "qemu")]
    pub check: bool,
}

/// Arguments of `dcfo faults`.
#[derive(Debug, Clone, Args)]
pub struct FaultsArgs {
    /// Print exactly one JSON object (cases, silent_failures, max_bridge_off_periods and
    /// every case's figures) on stdout, on its last line.
    #[arg(long)]
    pub json: bool,
    /// Directory for `faults.json` and one figure per case (`CASE.png` / `CASE.svg`):
    /// angle, error, speed, position, currents and state around the injection.
    #[arg(long, value_name = "DIR", default_value = "out/faults")]
    pub out: PathBuf,
    /// Run the campaign on this motor (a motor TOML file, which must give `mass_kg`, or
    /// a preset name): the speed drive's and the positioning drive's cases, their levels
    /// and expectations derived from the motor. Without it: the speed drive on the paper
    /// motor and the positioning drive on the paper motor and on motors/salient.toml.
    #[arg(long, value_name = "FILE")]
    pub motor: Option<String>,
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
    /// The simulated inverter and sensors that record the traces: `realistic` (the
    /// benchmark), or `ideal-inverter`, `ideal-sensors`, `ideal` to tell the estimator's
    /// own error from what the inverter's and the sensors' errors cost it.
    #[arg(long, value_enum, default_value = "realistic")]
    pub plant: crate::commands::acquire::PlantModel,
    /// Which current the drive's inverter compensation (and the recorder's) takes its
    /// signs from.
    #[arg(long, value_enum, default_value = "reference")]
    pub compensation_signs: CompensationSignsArg,
    /// Another motor (a preset name or a motor file): the same sweep at the benchmark's
    /// electrical frequencies (speeds scaled by its pole pitch), the same share of its
    /// rated thrust while recording, the drive tuned from its file. Without it: the
    /// benchmark, the paper motor on its test axis.
    #[arg(long, value_name = "FILE|PRESET")]
    pub motor: Option<String>,
    /// Directory for `acquire.json` (every cold start), `acquire.csv` (the table) and
    /// `acquire.png` / `acquire.svg` (lock time against speed).
    #[arg(long, value_name = "DIR", default_value = "out/acquire")]
    pub out: PathBuf,
}

/// Arguments of `dcfo track`.
#[derive(Debug, Clone, Args)]
pub struct TrackArgs {
    /// Print exactly one JSON object (every profile's figures) on stdout.
    #[arg(long)]
    pub json: bool,
    /// The motor (a preset name or a motor file); default: the paper motor. The profiles
    /// are scaled to it (speeds by its pole pitch, accelerations by its rated thrust on
    /// the axis).
    #[arg(long, value_name = "FILE|PRESET")]
    pub motor: Option<String>,
    /// Instead of the figures, print one profile's f32 replay sample by sample as CSV
    /// (time, speed, true and estimated frequencies, the notch's tuning, the FLL's
    /// reading, the angle error, the flags).
    #[arg(long, value_name = "PROFILE", conflicts_with = "json")]
    pub dump: Option<String>,
}

/// Arguments of `dcfo motor-image`.
#[derive(Debug, Clone, Args)]
pub struct MotorImageArgs {
    /// Motor: a preset name (`paper`) or a TOML motor file (docs/motor-format.md).
    #[arg(long, value_name = "FILE|PRESET")]
    pub motor: String,
    /// Nominal DC-bus voltage of the board, V (e.g. 24 on the B-G431B-ESC1).
    #[arg(long, value_name = "V")]
    pub bus_v: f32,
    /// Output file (88 bytes, version 3). Flash it on the B-G431B-ESC1 with
    /// `probe-rs download --chip STM32G431CBUx --binary-format bin --base-address 0x0801F800 FILE`.
    #[arg(short, long, value_name = "FILE")]
    pub out: PathBuf,
    /// Positioning axis: the lowest target position [m]. With the four other axis
    /// options (all or none) the board's drive is a positioning drive that takes moves
    /// over its command link; without them a speed drive.
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub stroke_min_m: Option<f32>,
    /// Positioning axis: the highest target position [m] (above --stroke-min-m).
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub stroke_max_m: Option<f32>,
    /// Positioning axis: the move profile's top speed [m/s] (> 0, within what the
    /// motor's back-EMF leaves of the bus).
    #[arg(long, value_name = "M/S", allow_negative_numbers = true)]
    pub max_speed: Option<f32>,
    /// Positioning axis: the move profile's acceleration [m/s^2] (> 0, within the
    /// drive's current limit for the moving mass).
    #[arg(long, value_name = "M/S2", allow_negative_numbers = true)]
    pub max_accel: Option<f32>,
    /// Positioning axis: carriage and payload moved besides the mover [kg] (>= 0).
    #[arg(long, value_name = "KG", allow_negative_numbers = true)]
    pub payload_kg: Option<f32>,
}

/// Arguments of `dcfo hil`: the HIL image (`examples/qemu_hil`) against the simulated
/// plant.
#[derive(Debug, Clone, Args)]
#[command(group(clap::ArgGroup::new("where").args(["qemu", "port"]).required(true)))]
pub struct HilArgs {
    /// QEMU or a serial port.
    #[command(flatten)]
    pub target: TargetArgs,
    /// Scenario by name; the link carries no observer offsets, so: steady, speed-step or
    /// load-step.
    #[arg(long, value_name = "NAME", default_value = "steady")]
    pub scenario: String,
    /// Simulated time, s (default: the scenario's full duration).
    #[arg(long, value_name = "S")]
    pub duration: Option<f64>,
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

    /// The estimator's number type: f32 (SI units, as the M4F drives) or q24 (Q8.24 in the
    /// motor's per-unit base, as the M3 image's fixed-point drive; replays its
    /// `dcfo board --cpu m3 --record` capture bit for bit).
    #[arg(long, value_enum, value_name = "TYPE", default_value = "f32")]
    pub numeric: NumericArg,
}

/// Number types the replay can run the estimator in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum NumericArg {
    /// f32 in SI units.
    F32,
    /// Q8.24 fixed point in the motor's per-unit base (dcfo::num::units::Base::for_motor).
    Q24,
}

impl NumericArg {
    /// The library's name for it.
    pub fn format(self) -> dcfo::capture::CaptureFormat {
        match self {
            NumericArg::F32 => dcfo::capture::CaptureFormat::F32,
            NumericArg::Q24 => dcfo::capture::CaptureFormat::Q24,
        }
    }
}

const REPLAY_AFTER_HELP: &str = "\
Timing: the estimator (observer + PLL in f32, SI units, as the drive runs it; with --numeric q24 in \
Q8.24 in the motor's per-unit base) is given, for row k, \
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

    /// The motor: a preset (`paper`) or a motor file (TOML, docs/motor-format.md). The
    /// drive tunes itself from it, and a paper experiment is scaled to it: speeds to the
    /// same electrical frequencies, the axis to the paper axis's mass per rated thrust
    /// (a payload), load steps to the same electrical deceleration, offsets by its rated
    /// voltage and current (`--motor paper` is `dcfo paper`'s axis). Without it, the paper
    /// motor on the paper's simulated test axis (10 kg carriage, the settings the HIL
    /// firmware runs).
    #[arg(long, value_name = "PRESET|FILE")]
    pub motor: Option<String>,

    /// Flux observer of the sensorless drive.
    #[arg(long, value_enum, value_name = "OBSERVER")]
    pub observer: DriveObserverArg,

    /// Which current the drive's inverter compensation takes its signs from.
    #[arg(long, value_enum, default_value = "reference")]
    pub compensation_signs: CompensationSignsArg,

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

/// Runs the parsed command: converts its arguments into the plain parameters of the
/// command's module and calls its entry point; the exit status on success (errors are
/// returned).
pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Board(a) => {
            let Some(target) = a.target.target() else { bail!("give --qemu or --port DEVICE") };
            crate::commands::board::run_command(&crate::commands::board::Params {
                target,
                record: a.record,
                demo: a.demo,
                speed_m_per_s: a.speed,
                json: a.json,
                move_to: a
                    .move_to
                    .map(|target_m| dcfo::algorithms::motion::Move { target_m, dwell_s: a.dwell }),
                image: a.image,
            })?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Replay(a) => {
            crate::commands::replay::run_command(&crate::commands::replay::Params {
                motor: a.motor,
                observer: a.observer.kind(),
                trace: a.trace,
                output: a.output,
                json: a.json,
                settle_s: a.settle,
                numeric: a.numeric.format(),
            })?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Paper(a) => Ok(reported(
            "paper",
            crate::commands::paper::run_command(&crate::commands::paper::Params { out: a.out }),
        )),
        Command::Sim(a) => Ok(reported(
            "sim",
            crate::commands::sim::run_command(&crate::commands::sim::Params {
                scenario: a.scenario,
                motor: a.motor,
                observer: a.observer.kind(),
                compensation_signs: a.compensation_signs.signs(),
                out: a.out,
            }),
        )),
        Command::Hil(a) => {
            let Some(target) = a.target.target() else { bail!("give --qemu or --port DEVICE") };
            crate::commands::hil::run_command(&crate::commands::hil::Params {
                target,
                scenario: a.scenario,
                duration_s: a.duration,
                check: a.check,
                out: a.out,
            })?;
            Ok(ExitCode::SUCCESS)
        }
        Command::MotorImage(a) => {
            crate::commands::motor_image::run_command(&crate::commands::motor_image::Params {
                motor: a.motor,
                bus_v: a.bus_v,
                axis: crate::commands::motor_image::AxisArgs {
                    stroke_min_m: a.stroke_min_m,
                    stroke_max_m: a.stroke_max_m,
                    max_speed_m_per_s: a.max_speed,
                    max_accel_m_per_s2: a.max_accel,
                    payload_kg: a.payload_kg,
                },
                out: a.out,
            })?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Acquire(a) => {
            crate::commands::acquire::run_command(&crate::commands::acquire::Params {
                json: a.json,
                notch: a.notch.tuning(),
                plant: a.plant,
                compensation_signs: a.compensation_signs.signs(),
                motor: a.motor,
                out: a.out,
            })?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Track(a) => {
            crate::commands::track::run_command(&crate::commands::track::Params {
                motor: a.motor,
                json: a.json,
                dump: a.dump,
            })?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Stroke(a) => {
            crate::commands::stroke::run_command(&crate::commands::stroke::Params {
                motor: a.motor,
                json: a.json,
                out: a.out,
                moves: usize::from(a.moves),
                qemu: a.qemu.then_some((a.cpu, a.elf)),
                check: a.check,
            })?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Results(a) => {
            let params = match a.action {
                ResultsAction::Render { table, inputs } => {
                    let Some(table) = crate::commands::results::Table::from_name(&table) else {
                        let names =
                            crate::commands::results::Table::ALL.map(crate::commands::results::Table::name);
                        bail!("no table `{table}` (tables: {})", names.join(", "))
                    };
                    crate::commands::results::Params::Render { root: a.root, table, inputs, check: a.check }
                }
                ResultsAction::Readme => {
                    crate::commands::results::Params::Readme { root: a.root, check: a.check }
                }
            };
            Ok(if crate::commands::results::run_command(&params)? {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            })
        }
        Command::Identify(a) => {
            use crate::commands::identify::Where;
            let place = match (a.target.target(), a.sim) {
                (Some(target), _) => Where::Link(target),
                (None, true) => Where::Sim,
                (None, false) => Where::Unsaid,
            };
            crate::commands::identify::run_command(&crate::commands::identify::Params {
                place,
                motor: a.motor,
                seed: a.seed,
                output: a.output,
                image: a.image,
                check: a.check,
                json: a.json,
                steady_seeds: a.steady,
            })
        }
        Command::Faults(a) => crate::commands::faults::run_command(&crate::commands::faults::Params {
            json: a.json,
            out: a.out,
            motor: a.motor,
        }),
    }
}

/// The exit status of a command that reports its own error on stderr, prefixed
/// `dcfo NAME:` (`dcfo paper`, `dcfo sim`).
fn reported(name: &str, result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("dcfo {name}: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::observer::observer_name;
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

    /// The observer arguments are spelled as the host names the observers everywhere
    /// else (file names, summaries, messages).
    #[test]
    fn observer_arguments_are_the_observers_names() {
        for arg in ObserverArg::value_variants() {
            let name = arg.to_possible_value().expect("listed").get_name().to_string();
            assert_eq!(name, observer_name(arg.kind()));
        }
        for arg in DriveObserverArg::value_variants() {
            let name = arg.to_possible_value().expect("listed").get_name().to_string();
            assert_eq!(name, observer_name(arg.kind()));
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
        assert_eq!((d.json, d.out, d.motor), (false, PathBuf::from("out/faults"), None));
        let Command::Faults(m) =
            Cli::try_parse_from(["dcfo", "faults", "--motor", "motors/low_r.toml"]).unwrap().command
        else {
            panic!("not faults")
        };
        assert_eq!(m.motor.as_deref(), Some("motors/low_r.toml"));
        assert!(Cli::try_parse_from(["dcfo", "faults", "--motor"]).is_err());
        assert!(Cli::try_parse_from(["dcfo", "faults", "--bogus"]).is_err());
    }

    /// `dcfo board`, `hil` and `identify` share the target options: each names the
    /// same target from the same words, board and hil need exactly one of --qemu and
    /// --port, identify neither (it also runs in process with --sim).
    #[test]
    fn the_target_options_parse_alike_in_board_hil_and_identify() {
        use crate::qemu::QemuCpu;
        use crate::target::Target;
        let target = |words: &[&str]| -> Option<Target> {
            let cli = Cli::try_parse_from(words).unwrap();
            match cli.command {
                Command::Board(a) => a.target.target(),
                Command::Hil(a) => a.target.target(),
                Command::Identify(a) => a.target.target(),
                _ => panic!("{words:?}"),
            }
        };
        for sub in ["board", "hil", "identify"] {
            let port = target(&["dcfo", sub, "--port", "/dev/ttyACM0", "--baud", "115200"]);
            assert!(
                matches!(&port, Some(Target::Port { device, baud: 115_200 }) if device == &PathBuf::from("/dev/ttyACM0")),
                "{sub}: {port:?}"
            );
            let qemu = target(&["dcfo", sub, "--qemu", "--cpu", "m3", "--elf", "x.elf"]);
            assert!(
                matches!(&qemu, Some(Target::Qemu { cpu: QemuCpu::M3, elf: Some(e) }) if e == &PathBuf::from("x.elf")),
                "{sub}: {qemu:?}"
            );
            let default = target(&["dcfo", sub, "--qemu"]);
            assert!(
                matches!(default, Some(Target::Qemu { cpu: QemuCpu::M4f, elf: None })),
                "{sub}: {default:?}"
            );
            assert!(Cli::try_parse_from(["dcfo", sub, "--qemu", "--port", "/dev/x"]).is_err(), "{sub}");
        }
        for sub in ["board", "hil"] {
            assert!(Cli::try_parse_from(["dcfo", sub]).is_err(), "{sub} without a target");
        }
        assert!(target(&["dcfo", "identify", "--sim"]).is_none());
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
