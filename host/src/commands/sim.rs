//! The `dcfo sim` command ([`run_command`]): one scenario with one observer, its trace,
//! estimates, summary and figure; and what other commands write of a run
//! ([`write_run_outputs`], [`trace_of`], [`fault_names`]).

use crate::motor_file::load_motor;
use crate::observer::observer_name;
use crate::plot::{Panel, Series, time_series_figure, write_figure};
use crate::simulation::figures::{Figures, figures};
use crate::simulation::scenarios::{PaperScale, Scenario, paper_scenarios, scenario};
use crate::simulation::{Run, Setup, run, theta_err_deg};
use crate::trace::{
    COMMANDED_ACCEL_COLUMN, Estimate, GroundTruth, InputTrace, InputTraceWriter, write_output_trace,
};
use anyhow::{Context, Result, bail};
use dcfo::algorithms::observer::ObserverKind;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What `dcfo sim` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// Scenario: a paper experiment by name or a scenario file ([`load_scenario`]).
    pub scenario: String,
    /// The motor (preset or motor file; it must give `mass_kg`); `None`: the paper motor
    /// on the paper's simulated test axis ([`Setup::paper`]).
    pub motor: Option<String>,
    /// Flux observer of the sensorless drive.
    pub observer: ObserverKind,
    /// Which current the drive's inverter compensation takes its signs from.
    pub compensation_signs: dcfo::drive::CompensationSigns,
    /// Directory for the trace, its summary and figures.
    pub out: PathBuf,
}

/// `dcfo sim`: loads the scenario and the motor ([`setup_for`]), then [`run_sim`].
pub fn run_command(params: &Params) -> Result<()> {
    let (mut setup, scenario) = setup_for(&params.scenario, params.motor.as_deref(), params.observer)?;
    setup.drive.compensation_signs = params.compensation_signs;
    run_sim(&setup, &scenario, &params.out)?;
    Ok(())
}

/// The drive and the scenario `dcfo sim` runs for `scenario` (a paper experiment by name
/// or a scenario file) on `motor` (a preset or motor file; `None`: the paper axis): a
/// paper experiment on another motor is scaled to it, a scenario file is taken in its
/// own units.
pub fn setup_for(scenario: &str, motor: Option<&str>, observer: ObserverKind) -> Result<(Setup, Scenario)> {
    let mut loaded = load_scenario(scenario)?;
    let paper_experiment = crate::simulation::scenarios::scenario(scenario).is_some();
    let setup = match motor {
        None => Setup::paper(observer),
        Some(m) => {
            let motor = load_motor(m)?;
            // The speed loop is tuned on the moving mass: a placeholder would tune it
            // silently wrong.
            if motor.defaulted.contains(&"mass_kg") {
                bail!(
                    "motor file {m}: key `mass_kg` is required to simulate the drive (its speed loop \
                     is tuned on the moving mass)"
                );
            }
            if paper_experiment {
                loaded = loaded.scaled(&PaperScale::for_motor(&motor.params));
            }
            Setup::for_axis(&motor.params, &loaded, observer)
        }
    };
    Ok((setup, loaded))
}

/// Every fifth sample in the display window of `sc` as (t, value).
pub fn series(
    run: &Run,
    sc: &Scenario,
    value: impl Fn(&crate::simulation::Sample) -> f64,
) -> Vec<(f64, f64)> {
    // From half a second before the event; a run shortened before it, or whose drive
    // stopped reporting before it (a trip), shows everything.
    let last_t = run.samples.last().map_or(0.0, |s| s.row.t);
    let t0 = if sc.event_s < run.simulated_s && sc.event_s <= last_t { sc.event_s - 0.5 } else { 0.0 };
    run.samples.iter().filter(|s| s.row.t >= t0).step_by(5).map(|s| (s.row.t, value(s))).collect()
}

/// The trace rows of a run (observer inputs and ground truth) and its estimates, in
/// the trace format (docs/trace-format.md).
pub fn trace_of(run: &Run) -> Result<(InputTrace, Vec<Estimate>)> {
    let rows = run.samples.iter().map(|s| s.row).collect();
    let mut trace = InputTrace::from_rows(rows, &run.scenario).context("simulated trace")?;
    // The in-process drive reports what it commanded its estimator; over a link it is
    // not known and the trace goes without it.
    if run.samples.iter().all(|s| s.alpha_e_ref.is_finite()) {
        let accel = run.samples.iter().map(|s| s.alpha_e_ref).collect();
        trace = trace.with_commanded_acceleration(accel, &run.scenario).context("simulated trace")?;
    }
    let estimates = run
        .samples
        .iter()
        .map(|s| Estimate {
            theta_hat: s.theta_hat,
            v_hat: s.v_hat,
            psi_alpha_hat: s.psi_hat[0],
            psi_beta_hat: s.psi_hat[1],
            locked: s.locked.unwrap_or(false),
        })
        .collect();
    Ok((trace, estimates))
}

/// The names of the fault bits set in `faults` (`OVER_CURRENT+LOCK_LOST`,
/// [`dcfo::drive::Faults::NAMES`]), `none` for none; bits without a name as hex.
pub fn fault_names(faults: dcfo::drive::Faults) -> String {
    use dcfo::drive::Faults;
    let mut known = 0u16;
    let mut names: Vec<String> = Vec::new();
    for (bit, name) in Faults::NAMES {
        known |= bit.bits();
        if faults.contains(bit) {
            names.push(name.to_string());
        }
    }
    let unknown = faults.bits() & !known;
    if unknown != 0 {
        names.push(format!("{unknown:#06x}"));
    }
    if names.is_empty() { "none".to_string() } else { names.join("+") }
}

/// A scenario argument: a paper experiment by name, else a scenario file
/// ([`crate::scenario_file`]); an error naming both possibilities otherwise.
pub fn load_scenario(arg: &str) -> Result<Scenario> {
    if let Some(sc) = scenario(arg) {
        return Ok(sc);
    }
    if Path::new(arg).is_file() {
        return Ok(crate::scenario_file::read_scenario_file(arg)?);
    }
    let names: Vec<_> = paper_scenarios().iter().map(|s| s.name.clone()).collect();
    bail!("scenario `{arg}` is neither a paper experiment ({}) nor a readable file", names.join(", "))
}

/// `dcfo sim`: one scenario with one observer; writes `trace.csv` (input format with
/// ground truth, replayable), `estimates.csv` (output format), `summary.json` and a
/// figure into `out`.
pub fn run_sim(setup: &Setup, sc: &Scenario, out: &Path) -> Result<Figures> {
    let observer = setup.drive.estimator.observer;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let bar = ProgressBar::new(1000);
    bar.set_style(
        ProgressStyle::with_template("simulating [{bar:30}] {percent}%, {elapsed}")
            .map_err(|e| anyhow::anyhow!("progress bar template: {e}"))?,
    );
    let start = Instant::now();
    let run = run(setup, sc, |f| bar.set_position((f * 1000.0) as u64))?;
    bar.finish_and_clear();
    let wall = start.elapsed().as_secs_f64();
    let f = figures(&run, sc);
    write_run_outputs(&run, sc, out, observer_name(observer))?;
    let summary = serde_json::json!({
        "scenario": sc.name,
        "motor_pole_pitch_m": setup.motor.pole_pitch_m,
        "handover_s": run.handover_s,
        "faults": fault_names(run.faults),
        "observer": observer_name(observer),
        "figures": f,
        "real_time_factor": run.simulated_s / wall.max(1e-9),
    });
    std::fs::write(out.join("summary.json"), serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("writing {}/summary.json", out.display()))?;
    println!(
        "{} with the {}: theta_err max {:.2} deg, rms {:.2} deg; v_err max {:.4} m/s; flux drift {:.4} Wb; real-time factor {:.1}",
        sc.name,
        observer_name(observer),
        f.theta_err_max_deg,
        f.theta_err_rms_deg,
        f.v_err_max,
        f.flux_drift_wb,
        run.simulated_s / wall.max(1e-9)
    );
    if !run.faults.is_empty() {
        let last_t = run.samples.last().map_or(0.0, |s| s.row.t);
        println!(
            "the drive tripped ({}); its last estimate was at t = {last_t:.3} s, the figures cover what it reported",
            fault_names(run.faults)
        );
    } else if run.handover_s.is_none() {
        println!("the drive never reached sensorless operation (Running)");
    }
    eprintln!("trace.csv, estimates.csv, summary.json and figures in {}", out.display());
    Ok(f)
}

/// Writes a run's `trace.csv` (input format with ground truth), `estimates.csv` (output
/// format) and its figure into `out`; `label` names the drive in the figure's title.
pub fn write_run_outputs(run: &Run, sc: &Scenario, out: &Path, label: &str) -> Result<()> {
    let (trace, estimates) = trace_of(run)?;
    match trace.commanded_acceleration() {
        Some(accel) => {
            let mut w =
                InputTraceWriter::create(out.join("trace.csv"), GroundTruth::ALL, &[COMMANDED_ACCEL_COLUMN])?;
            for (row, a) in trace.rows().iter().zip(accel) {
                w.write(row, &[*a])?;
            }
            w.finish()?;
        }
        None => {
            let mut w = InputTraceWriter::create(out.join("trace.csv"), GroundTruth::ALL, &[])?;
            for row in trace.rows() {
                w.write(row, &[])?;
            }
            w.finish()?;
        }
    }
    write_output_trace(out.join("estimates.csv"), &trace, &estimates)?;
    let panels = vec![
        Panel::new(
            "psi [Wb]",
            vec![
                Series::line("psi_alpha true", series(run, sc, |s| s.psi_true[0])),
                Series::line("psi_alpha estimate", series(run, sc, |s| s.psi_hat[0])),
                Series::line("psi_beta estimate", series(run, sc, |s| s.psi_hat[1])),
            ],
        ),
        Panel::new(
            "speed [m/s]",
            vec![
                Series::line("true", series(run, sc, |s| s.row.v.unwrap_or(f64::NAN))),
                Series::line("estimate", series(run, sc, |s| s.v_hat)),
            ],
        ),
        Panel::new("position error [deg el]", vec![Series::line("error", series(run, sc, theta_err_deg))]),
    ];
    let title = format!("{} ({label}): {}", sc.name, sc.description);
    write_figure(&time_series_figure(title, panels), &out.join(&sc.name))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulation::{LocalDrive, run_with};

    /// The trace of a fixed-point run carries the commanded acceleration its estimator
    /// used (the column a replay needs to reproduce the run's estimates).
    #[test]
    fn a_fixed_point_runs_trace_carries_the_commanded_acceleration() {
        let setup = Setup::paper(ObserverKind::Dcfo);
        let mut sc = scenario("steady").expect("scenario");
        sc.duration_s = 1.5;
        let q = run_with(&setup, &sc, &mut LocalDrive::fixed_point(&setup).expect("drive"), |_| {})
            .expect("q24 run");
        assert!(trace_of(&q).expect("trace").0.commanded_acceleration().is_some());
    }
}
