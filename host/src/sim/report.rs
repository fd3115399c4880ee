//! The `dcfo paper` and `dcfo sim` commands: run scenarios, print the table beside the
//! paper's figures, write traces, summaries and figures.

use super::scenarios::{Figures, Scenario, figures, paper_scenarios, scenario};
use super::{Run, Setup, run, theta_err_deg};
use crate::plot::bode::{BodeSetup, bode_figure};
use crate::plot::{PALETTE, Panel, Rgb, Series, time_series_figure, write_figure};
use crate::trace::{
    COMMANDED_ACCEL_COLUMN, Estimate, GroundTruth, InputTrace, InputTraceWriter, write_output_trace,
};
use anyhow::{Context, Result, bail};
use dcfo::observer::ObserverKind;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::Path;
use std::sync::Mutex;
use std::time::Instant;

/// One scenario run with both observers.
#[derive(Debug, serde::Serialize)]
pub struct ScenarioResult {
    /// Scenario name.
    pub scenario: String,
    /// What it reproduces.
    pub description: String,
    /// What the paper reports.
    pub paper: String,
    /// Figures with the CFO.
    pub cfo: Figures,
    /// Figures with the DCFO.
    pub dcfo: Figures,
}

/// Everything `dcfo paper` measured.
#[derive(Debug, serde::Serialize)]
pub struct PaperReport {
    /// Per-scenario figures.
    pub scenarios: Vec<ScenarioResult>,
    /// Simulated seconds per wall-clock second, over all runs.
    pub real_time_factor: f64,
    /// Wall-clock time of the simulations, s.
    pub wall_s: f64,
}

fn observer_name(kind: ObserverKind) -> &'static str {
    match kind {
        ObserverKind::PureIntegrator => "pi",
        ObserverKind::Cfo => "cfo",
        ObserverKind::Dcfo => "dcfo",
    }
}

/// Runs `jobs` (scenario, observer) on all cores with a progress bar on stderr.
fn run_all(jobs: &[(Scenario, ObserverKind)]) -> Result<(Vec<Run>, f64)> {
    let bar = ProgressBar::new(jobs.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} runs, {elapsed}")
            .map_err(|e| anyhow::anyhow!("progress bar template: {e}"))?
            .progress_chars("=> "),
    );
    bar.set_message("simulating");
    let next = Mutex::new(0usize);
    let results: Mutex<Vec<Option<Result<Run>>>> = Mutex::new((0..jobs.len()).map(|_| None).collect());
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1).min(jobs.len().max(1));
    let start = Instant::now();
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| {
                loop {
                    let j = {
                        let Ok(mut n) = next.lock() else { return };
                        let j = *n;
                        *n += 1;
                        j
                    };
                    let Some((sc, obs)) = jobs.get(j) else { return };
                    let r = run(&Setup::paper(*obs), sc, |_| {})
                        .with_context(|| format!("scenario {} with the {}", sc.name, observer_name(*obs)));
                    if let Ok(mut all) = results.lock() {
                        all[j] = Some(r);
                    }
                    bar.inc(1);
                }
            });
        }
    });
    bar.finish_and_clear();
    let wall = start.elapsed().as_secs_f64();
    let runs = results
        .into_inner()
        .map_err(|_| anyhow::anyhow!("a simulation thread panicked"))?
        .into_iter()
        .map(|r| r.unwrap_or_else(|| bail!("a simulation did not run")))
        .collect::<Result<Vec<_>>>()?;
    Ok((runs, wall))
}

/// The two runs of one scenario.
#[derive(Debug)]
pub struct ScenarioRuns {
    /// The scenario.
    pub scenario: Scenario,
    /// Its run with the CFO.
    pub cfo: Run,
    /// Its run with the DCFO.
    pub dcfo: Run,
}

/// Runs every paper scenario with the CFO and the DCFO.
pub fn paper_report() -> Result<(PaperReport, Vec<ScenarioRuns>)> {
    let scenarios = paper_scenarios();
    let jobs: Vec<(Scenario, ObserverKind)> = scenarios
        .iter()
        .flat_map(|s| [(s.clone(), ObserverKind::Cfo), (s.clone(), ObserverKind::Dcfo)])
        .collect();
    let (runs, wall_s) = run_all(&jobs)?;
    let simulated: f64 = runs.iter().map(|r| r.simulated_s).sum();
    let mut runs = runs.into_iter();
    let mut results = Vec::new();
    let mut pairs = Vec::new();
    for sc in scenarios {
        let (Some(cfo), Some(dcfo)) = (runs.next(), runs.next()) else {
            bail!("missing run for {}", sc.name)
        };
        results.push(ScenarioResult {
            scenario: sc.name.to_string(),
            description: sc.description.to_string(),
            paper: sc.paper.to_string(),
            cfo: figures(&cfo, &sc),
            dcfo: figures(&dcfo, &sc),
        });
        pairs.push(ScenarioRuns { scenario: sc, cfo, dcfo });
    }
    Ok((PaperReport { scenarios: results, real_time_factor: simulated / wall_s.max(1e-9), wall_s }, pairs))
}

fn fmt_recovery(r: Option<f64>) -> String {
    r.map_or_else(|| "  >1 s".to_string(), |s| format!("{s:6.2}"))
}

/// The table of `dcfo paper`, one line per scenario and observer.
pub fn table(report: &PaperReport) -> String {
    let mut s = String::new();
    s.push_str("scenario     observer  theta_err max/rms [deg el]  v_err max [m/s]  flux DC max/end [Wb]  |psi| recovery [s]  ok   false locks\n");
    for r in &report.scenarios {
        for (name, f) in [("CFO", &r.cfo), ("DCFO", &r.dcfo)] {
            s.push_str(&format!(
                "{:<12} {:<8}  {:>9.2} / {:>6.2}            {:>8.3}         {:>7.4} / {:>7.4}      {}          {:<3}  {}\n",
                r.scenario,
                name,
                f.theta_err_max_deg,
                f.theta_err_rms_deg,
                f.v_err_max,
                f.flux_drift_wb,
                f.flux_offset_end_wb,
                fmt_recovery(f.flux_recovery_s),
                if f.healthy { "yes" } else { "NO" },
                f.false_lock_samples
            ));
        }
        s.push_str(&format!("{:<12} paper:    {}\n", "", r.paper));
    }
    s.push_str(&format!(
        "simulated {:.1} s of drive time in {:.1} s: real-time factor {:.1}\n",
        report.real_time_factor * report.wall_s,
        report.wall_s,
        report.real_time_factor
    ));
    s
}

/// Every fifth sample in the display window of `sc` as (t, value).
fn series(run: &Run, sc: &Scenario, value: impl Fn(&super::Sample) -> f64) -> Vec<(f64, f64)> {
    // From half a second before the event; a run shortened before it, or whose drive
    // stopped reporting before it (a trip), shows everything.
    let last_t = run.samples.last().map_or(0.0, |s| s.row.t);
    let t0 = if sc.event_s < run.simulated_s && sc.event_s <= last_t { sc.event_s - 0.5 } else { 0.0 };
    run.samples.iter().filter(|s| s.row.t >= t0).step_by(5).map(|s| (s.row.t, value(s))).collect()
}

/// One colour per quantity in every panel: truth, CFO, DCFO.
const TRUE_COLOR: Rgb = PALETTE[0];
const CFO_COLOR: Rgb = PALETTE[1];
const DCFO_COLOR: Rgb = PALETTE[2];

/// Writes the figure of one scenario (flux, speed, errors) with both observers.
fn scenario_figure(dir: &Path, sc: &Scenario, cfo: &Run, dcfo: &Run) -> Result<()> {
    let panels = vec![
        Panel::new(
            "psi_alpha [Wb]",
            vec![
                Series::line("true", series(dcfo, sc, |s| s.psi_true[0])).with_color(TRUE_COLOR),
                Series::line("CFO", series(cfo, sc, |s| s.psi_hat[0])).with_color(CFO_COLOR),
                Series::line("DCFO", series(dcfo, sc, |s| s.psi_hat[0])).with_color(DCFO_COLOR),
            ],
        ),
        Panel::new(
            "speed [m/s]",
            vec![
                Series::line("true (DCFO run)", series(dcfo, sc, |s| s.row.v.unwrap_or(f64::NAN)))
                    .with_color(TRUE_COLOR),
                Series::line("CFO estimate", series(cfo, sc, |s| s.v_hat)).with_color(CFO_COLOR),
                Series::line("DCFO estimate", series(dcfo, sc, |s| s.v_hat)).with_color(DCFO_COLOR),
            ],
        ),
        Panel::new(
            "speed error [m/s]",
            vec![
                Series::line("CFO", series(cfo, sc, |s| s.row.v.unwrap_or(f64::NAN) - s.v_hat))
                    .with_color(CFO_COLOR),
                Series::line("DCFO", series(dcfo, sc, |s| s.row.v.unwrap_or(f64::NAN) - s.v_hat))
                    .with_color(DCFO_COLOR),
            ],
        ),
        Panel::new(
            "position error [deg el]",
            vec![
                Series::line("CFO", series(cfo, sc, theta_err_deg)).with_color(CFO_COLOR),
                Series::line("DCFO", series(dcfo, sc, theta_err_deg)).with_color(DCFO_COLOR),
            ],
        ),
    ];
    let fig = time_series_figure(format!("{}: {}", sc.name, sc.description), panels);
    write_figure(&fig, &dir.join(&sc.name)).with_context(|| format!("figure for {}", sc.name))?;
    Ok(())
}

/// `dcfo paper`: runs everything, prints the table, writes figures and `summary.json`
/// into `out`.
pub fn run_paper(out: &Path) -> Result<PaperReport> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let (report, pairs) = paper_report()?;
    print!("{}", table(&report));
    for r in &pairs {
        scenario_figure(out, &r.scenario, &r.cfo, &r.dcfo)?;
    }
    bode_figure(&out.join("bode"), &BodeSetup::paper()).context("Bode figure")?;
    let json = serde_json::to_string_pretty(&report).context("summary")?;
    std::fs::write(out.join("summary.json"), json)
        .with_context(|| format!("writing {}/summary.json", out.display()))?;
    eprintln!("figures (PNG, SVG) and summary.json in {}", out.display());
    Ok(report)
}

/// The trace rows of a run (observer inputs and ground truth) and its estimates, in
/// the shared trace format.
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
