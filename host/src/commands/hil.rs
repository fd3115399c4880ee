//! `dcfo hil` ([`run_command`]): a scenario of the closed-loop simulation with the drive
//! behind the lock-step HIL link ([`crate::hil_link`]), the firmware on QEMU or on a
//! board at a serial port; its figures, and with `--check` the bit-for-bit comparison of
//! its angle estimates with the in-process drive of the same numeric type
//! ([`compare_runs`]).

use std::path::{Path, PathBuf};

use crate::hil_link::{SerialController, build_qemu_firmware};
use crate::qemu::{QemuCpu, QemuSession};
use crate::target::Target;

/// What a HIL run measured.
#[derive(Debug, serde::Serialize)]
pub struct HilReport {
    /// Scenario name.
    pub scenario: String,
    /// The scenario's figures over its measurement window; `None` when the run was
    /// shortened (`--duration`) to end before the window.
    pub figures: Option<crate::simulation::figures::Figures>,
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
pub fn compare_runs(a: &crate::simulation::Run, b: &crate::simulation::Run) -> Equivalence {
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

/// What `dcfo hil` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// Where the drive runs: the HIL image on QEMU (built with cargo,
    /// [`build_qemu_firmware`], when no image is given) or a board on a serial port
    /// running the HIL firmware (f32).
    pub target: Target,
    /// Scenario by name (steady, speed-step or load-step: the link carries no observer
    /// offsets).
    pub scenario: String,
    /// Simulated time, s (`None`: the scenario's full duration).
    pub duration_s: Option<f64>,
    /// Also run the scenario in this process (same numeric type as the firmware) and
    /// require the link-reported angle estimates to be identical bit for bit.
    pub check: bool,
    /// Directory for the trace, summary and figures.
    pub out: PathBuf,
}

/// `dcfo hil`: runs the scenario over the link, writes the outputs into `params.out`,
/// prints the figures; an error when `check` finds a difference.
pub fn run_command(params: &Params) -> anyhow::Result<HilReport> {
    use crate::simulation::{Setup, run_with, scenarios};
    use anyhow::Context;
    let Some(mut scenario) = scenarios::scenario(&params.scenario) else {
        anyhow::bail!("unknown scenario `{}`", params.scenario);
    };
    if let Some(d) = params.duration_s {
        anyhow::ensure!(d.is_finite() && d > 0.0, "--duration must be a positive number of seconds");
        scenario.duration_s = d;
        scenario.window_s = scenario.window_s.min((d - scenario.event_s).max(0.0));
    }
    // The firmware runs the DCFO drive of the paper axis.
    let setup = Setup::paper(dcfo::algorithms::observer::ObserverKind::Dcfo);
    std::fs::create_dir_all(&params.out).with_context(|| format!("creating {}", params.out.display()))?;
    let bar = indicatif::ProgressBar::new(1000);
    let progress = |f: f64| bar.set_position((f * 1000.0) as u64);
    let mut stack = None;
    let (hil_run, rate) = match &params.target {
        Target::Qemu { cpu, elf } => {
            let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap_or(Path::new("."));
            let elf = match elf {
                Some(e) => e.clone(),
                None => build_qemu_firmware(workspace, *cpu)?,
            };
            let (session, mut link) = QemuSession::start(&elf, *cpu)?;
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
        }
        Target::Port { device, baud } => {
            let (serial, reader) = crate::target::open_serial(device, *baud)?;
            let mut link = SerialController::new(serial, reader);
            let run = run_with(&setup, &scenario, &mut link, progress)?;
            (run, link.round_trips_per_s())
        }
    };
    bar.finish_and_clear();
    let qemu_cpu = params.target.qemu_cpu();
    let figures = (scenario.window_s > 0.0).then(|| crate::simulation::figures::figures(&hil_run, &scenario));
    let equivalence = if params.check {
        // A board on a serial port runs the f32 firmware.
        let cpu = qemu_cpu.unwrap_or(QemuCpu::M4f);
        let local = run_with(&setup, &scenario, cpu.local_drive(&setup)?.as_mut(), |_| {})?;
        Some(compare_runs(&hil_run, &local))
    } else {
        None
    };
    let report = HilReport {
        scenario: scenario.name.to_string(),
        figures,
        round_trips_per_s: rate,
        qemu_cpu,
        simulated_s: hil_run.simulated_s,
        equivalence,
        stack_high_water_bytes: stack,
    };
    crate::commands::sim::write_run_outputs(&hil_run, &scenario, &params.out, "hil")?;
    std::fs::write(params.out.join("summary.json"), serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}/summary.json", params.out.display()))?;
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
