//! A trace written by the closed-loop simulation and replayed through `dcfo replay`
//! reproduces the run's estimates exactly: same code, same arithmetic, same inputs.

use dcfo::algorithms::observer::ObserverKind;
use dcfo_host::commands::replay::replay_trace;
use dcfo_host::commands::sim::trace_of;
use dcfo_host::simulation::{Setup, run, scenarios};
use dcfo_host::trace::InputTrace;
use std::process::Command;

#[test]
fn replayed_trace_reproduces_the_closed_loop_estimates_bit_for_bit() {
    for kind in [ObserverKind::Cfo, ObserverKind::Dcfo] {
        // The DC-step scenario exercises the observer offsets too.
        let sc = scenarios::scenario("dc-u").expect("scenario");
        let r = run(&Setup::paper(kind), &sc, |_| {}).expect("simulation");
        let (trace, closed_loop) = trace_of(&r).expect("trace");
        let replayed = replay_trace(&trace, &Setup::paper(kind).motor, kind).expect("replay");
        assert_eq!(replayed.len(), closed_loop.len());
        for (k, (a, b)) in replayed.iter().zip(&closed_loop).enumerate() {
            assert_eq!(a.theta_hat.to_bits(), b.theta_hat.to_bits(), "{kind:?} row {k}: theta");
            assert_eq!(a.v_hat.to_bits(), b.v_hat.to_bits(), "{kind:?} row {k}: v");
            assert_eq!(a.psi_alpha_hat.to_bits(), b.psi_alpha_hat.to_bits(), "{kind:?} row {k}: psi");
        }
        println!("{kind:?}: {} rows identical", replayed.len());
    }
}

#[test]
fn dcfo_sim_files_replay_through_the_command_line_identically() {
    let dir = tempfile::tempdir().expect("temp dir");
    let exe = env!("CARGO_BIN_EXE_dcfo");
    let status = Command::new(exe)
        .args(["sim", "--scenario", "steady", "--observer", "dcfo", "--out"])
        .arg(dir.path())
        .status()
        .expect("dcfo sim runs");
    assert!(status.success());
    let replayed = dir.path().join("replayed.csv");
    let status = Command::new(exe)
        .args(["replay", "--motor", "paper", "--observer", "dcfo"])
        .arg(dir.path().join("trace.csv"))
        .arg("-o")
        .arg(&replayed)
        .status()
        .expect("dcfo replay runs");
    assert!(status.success());
    let a = std::fs::read_to_string(dir.path().join("estimates.csv")).expect("estimates");
    let b = std::fs::read_to_string(&replayed).expect("replayed");
    assert!(a.lines().count() > 30_000);
    assert_eq!(a, b, "replay output differs from the simulation's estimates");
    // And the trace itself is a valid input trace with ground truth.
    let t = InputTrace::read_path(dir.path().join("trace.csv")).expect("trace reads back");
    assert!(t.ground_truth().theta && t.ground_truth().v);
}
