//! The paper scenarios at several event phases: how much of a `dcfo paper` figure is
//! the realisation of one run.
//!
//! ```sh
//! cargo run --release -p dcfo-host --example paper_phases           # 8 phases
//! cargo run --release -p dcfo-host --example paper_phases -- 16     # 16 phases
//! ```
//!
//! Each scenario of `dcfo paper`, DCFO only, runs once per phase `k` with its event (and
//! every later event) `12.5 ms * k` later: a light-load drive whose speed loop swings
//! meets the event in another state each time. `steady` has no event: its one-second
//! window starts `0.5 s * k` later instead. A seventh case, `reset-at-speed`, resets the
//! estimator at 0.3 m/s at 3.0 s (the flying restart of `dcfo faults`' `lock-loss`) and
//! measures the last 0.5 s of the run. Printed per case: the median and the largest of
//! the runs' maximum angle error (electrical degrees) over the scenario's window, runs
//! that did not end healthy (sensorless and without a fault), and samples reported
//! locked while more than 15 degrees off. The runs go through `dcfo paper`'s runner
//! ([`dcfo_host::commands::paper::run_all`]): about 30 s for 8 phases on two cores.

use anyhow::{Context, Result, bail};
use dcfo::algorithms::observer::ObserverKind;
use dcfo_host::commands::paper::run_all;
use dcfo_host::simulation::figures::figures;
use dcfo_host::simulation::scenarios::{Event, Scenario, paper_scenarios, scenario};

/// Event shift between phases, s.
const PHASE_STEP_S: f64 = 0.0125;
/// Shift of `steady`'s window between phases, s.
const STEADY_WINDOW_STEP_S: f64 = 0.5;

fn main() -> Result<()> {
    let phases: usize = match std::env::args().nth(1) {
        Some(a) => a.parse().with_context(|| format!("phases: {a:?} is not a count"))?,
        None => 8,
    };
    if phases == 0 {
        bail!("phases: at least one");
    }
    let mut cases = paper_scenarios();
    let mut reset = scenario("steady").context("the steady scenario")?;
    reset.name = "reset-at-speed".into();
    reset.events.push((3.0, Event::ResetEstimator));
    reset.event_s = reset.duration_s - 0.5;
    reset.window_s = 0.5;
    cases.push(reset);

    let jobs: Vec<(Scenario, ObserverKind)> =
        cases.iter().flat_map(|s| (0..phases).map(move |k| (shifted(s, k), ObserverKind::Dcfo))).collect();
    let (runs, _) = run_all(&jobs)?;
    println!("DCFO max angle error over {phases} phases, electrical degrees");
    println!("{:<16} {:>8} {:>8} {:>10} {:>12}", "case", "median", "max", "unhealthy", "false-lock");
    for (s, (runs, jobs)) in cases.iter().zip(runs.chunks(phases).zip(jobs.chunks(phases))) {
        let figures: Vec<_> = runs.iter().zip(jobs).map(|(r, (sc, _))| figures(r, sc)).collect();
        let mut e: Vec<f64> = figures.iter().map(|f| f.theta_err_max_deg).collect();
        e.sort_by(f64::total_cmp);
        let n = e.len();
        let median = if n % 2 == 1 { e[n / 2] } else { 0.5 * (e[n / 2 - 1] + e[n / 2]) };
        let unhealthy = figures.iter().filter(|f| !f.healthy).count();
        let false_lock: usize = figures.iter().map(|f| f.false_lock_samples).sum();
        println!("{:<16} {:>8.2} {:>8.2} {:>10} {:>12}", s.name, median, e[n - 1], unhealthy, false_lock);
    }
    Ok(())
}

/// `s` at phase `k`: every event after the initial speed `k` phase steps later (and the
/// window with it); `steady`, which has none, with its window `k` window steps later.
fn shifted(s: &Scenario, k: usize) -> Scenario {
    let mut s = s.clone();
    let step = if s.events.len() <= 1 { STEADY_WINDOW_STEP_S } else { PHASE_STEP_S };
    let shift = step * k as f64;
    for e in s.events.iter_mut().skip(1) {
        e.0 += shift;
    }
    s.event_s += shift;
    s.duration_s += shift;
    s
}
