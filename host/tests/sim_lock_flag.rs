//! The estimator's `locked` flag is honest: on every `dcfo sim` scenario (the paper's
//! experiments and every file in `scenarios/`) and every motor (the paper axis and every
//! file in `motors/`), I/f start included, no sample is flagged locked while the angle is
//! more than 15 deg off (`false_lock_samples`, docs/trace-format.md), with the DCFO and
//! with the CFO. The closed loop is the command's own ([`setup_for`]), so what this
//! counts is what `dcfo sim` reports.

use dcfo::algorithms::observer::ObserverKind;
use dcfo::drive::DriveState;
use dcfo_host::commands::sim::setup_for;
use dcfo_host::simulation::scenarios::paper_scenarios;
use dcfo_host::simulation::{Sample, run, theta_err_deg};
use std::path::PathBuf;

mod common;

/// The false-lock criterion of the trace format, electrical degrees.
const FALSE_LOCK_DEG: f64 = 15.0;

fn files(dir: &str) -> Vec<String> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(common::workspace().join(dir))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    out.sort();
    out.into_iter().map(|p| p.display().to_string()).collect()
}

/// (false-lock samples, samples of the sensorless loop within 5 deg, those of them
/// flagged locked) of one run.
fn count(scenario: &str, motor: Option<&str>, observer: ObserverKind) -> (usize, usize, usize) {
    let (setup, sc) = setup_for(scenario, motor, observer).unwrap();
    let r = run(&setup, &sc, |_| {}).unwrap();
    let locked = |s: &&Sample| s.locked == Some(true);
    let false_locks =
        r.samples.iter().filter(locked).filter(|s| theta_err_deg(s).abs() > FALSE_LOCK_DEG).count();
    let running: Vec<&Sample> = r
        .samples
        .iter()
        .filter(|s| {
            DriveState::from_code(s.state) == Some(DriveState::Running) && theta_err_deg(s).abs() < 5.0
        })
        .collect();
    let running_locked = running.iter().filter(|s| s.locked == Some(true)).count();
    (false_locks, running.len(), running_locked)
}

/// Every scenario on every motor with `observer`; the runs failing the false-lock
/// criterion are printed and failed. Returns, over all runs, the samples of the
/// sensorless loop within 5 deg and those of them flagged locked.
fn every_run(observer: ObserverKind) -> (usize, usize) {
    let mut scenarios: Vec<String> = paper_scenarios().into_iter().map(|s| s.name).collect();
    scenarios.extend(files("scenarios"));
    let mut motors: Vec<Option<String>> = vec![None];
    motors.extend(files("motors").into_iter().map(Some));
    assert!(scenarios.len() >= 10 && motors.len() >= 5);
    let cases: Vec<(String, Option<String>)> =
        scenarios.iter().flat_map(|s| motors.iter().map(move |m| (s.clone(), m.clone()))).collect();
    // The runs are independent.
    let results: Vec<(String, Option<String>, usize, usize, usize)> =
        common::map_on_every_core(&cases, |(s, m)| {
            let (f, n, l) = count(s, m.as_deref(), observer);
            (s.clone(), m.clone(), f, n, l)
        });
    let mut failures = Vec::new();
    for (s, m, false_locks, running, running_locked) in &results {
        let motor = m.as_deref().unwrap_or("paper axis");
        eprintln!(
            "{observer:?}: {s} on {motor}: {false_locks} false-lock samples; {running_locked} of \
             {running} sensorless samples within 5 deg flagged locked"
        );
        if *false_locks > 0 {
            failures.push(format!("{s} on {motor}: {false_locks}"));
        }
    }
    assert!(failures.is_empty(), "{observer:?}: false-lock samples: {failures:?}");
    let running: usize = results.iter().map(|r| r.3).sum();
    let running_locked: usize = results.iter().map(|r| r.4).sum();
    eprintln!(
        "{observer:?}, all runs: {running_locked} of {running} sensorless samples within 5 deg flagged locked"
    );
    (running, running_locked)
}

#[test]
fn no_sample_is_locked_more_than_15_deg_off_on_any_scenario_or_motor() {
    let (running, running_locked) = every_run(ObserverKind::Dcfo);
    // The flag is not simply off: over the runs, while the drive runs its sensorless loop
    // with the estimate within 5 deg, the flag is set for most of it (the rest: the
    // hand-over's first samples and the resistance allowance at the motors' low-speed
    // edge; measured 89 % over these runs).
    assert!(running > 0 && running_locked * 100 >= running * 85, "{running_locked} of {running}");
}

/// The CFO, whose flag has only the PLL's lock, the resistance check and the errors
/// bounded together (`Estimator::flux_steady`: its phase lead `atan(w_c / w)`, an offset
/// read from the magnitude's swing, the PLL's error, the resistance's), is as honest. Its lead is 14 deg at
/// the paper's 10 Hz, so it vouches for its angle mostly at the scenarios' higher speeds;
/// the flag is not simply off (measured: 13,314 of the 51,809 samples of its sensorless
/// loop within 5 deg over these runs).
#[test]
fn the_cfo_is_never_locked_more_than_15_deg_off_either() {
    let (_, running_locked) = every_run(ObserverKind::Cfo);
    assert!(running_locked > 0);
}
