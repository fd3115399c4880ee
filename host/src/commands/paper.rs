//! `dcfo paper`: every experiment of the paper (Figs. 11-19) in simulation with the CFO
//! and the DCFO, the table beside the paper's figures, a figure per scenario, the Bode
//! figure and `summary.json`.

use crate::commands::sim::series;
use crate::observer::observer_name;
use crate::plot::bode::{BodeSetup, bode_figure};
use crate::plot::{PALETTE, Panel, Rgb, Series, time_series_figure, write_figure};
use crate::simulation::figures::{Figures, figures};
use crate::simulation::scenarios::{Scenario, paper_scenarios};
use crate::simulation::{Run, Setup, run, theta_err_deg};
use anyhow::{Context, Result, bail};
use dcfo::algorithms::observer::ObserverKind;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

/// What `dcfo paper` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// Directory for the figures (PNG and SVG) and `summary.json`; created if absent.
    pub out: PathBuf,
}

/// `dcfo paper`: [`run_paper`] into `params.out`.
pub fn run_command(params: &Params) -> Result<()> {
    run_paper(&params.out)?;
    Ok(())
}

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

/// Runs `jobs` (scenario, observer), each on the paper axis ([`Setup::paper`]), on all
/// cores with a progress bar on stderr; the runs in the order of `jobs` and the wall time
/// (s). Also used by `host/examples/paper_phases.rs`.
pub fn run_all(jobs: &[(Scenario, ObserverKind)]) -> Result<(Vec<Run>, f64)> {
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
