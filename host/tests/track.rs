//! `dcfo track` (module docs of `dcfo_host::track`): the recordings hold the reversals
//! their profiles command, the estimator claims no lock on a wrong angle on any of them,
//! and Q8.24 follows f32 within a degree. The issue-35 floors (re-lock within 2 periods
//! of a reversal, 8 degrees through a sharp step) are figures `dcfo track` prints; the
//! estimator does not meet them yet (`docs/estimator-design.md`).

use dcfo::motor::MotorParams;
use dcfo_host::track::{Figures, profiles, run_all, setup_for};

fn check(motor: &MotorParams, label: &str) {
    let all: Vec<Figures> = run_all(&setup_for(motor)).expect("recorded and replayed");
    for profile in profiles() {
        // A reversal is a sign change between successive speed targets.
        let mut targets = vec![profile.initial_m_per_s];
        targets.extend(profile.steps.iter().map(|s| s.1));
        let reversals = targets.windows(2).filter(|w| w[0] * w[1] < 0.0).count();
        let fig = |numeric: &str| {
            all.iter().find(|f| f.profile == profile.name && f.numeric == numeric).expect("profile run")
        };
        let (a, b) = (fig("f32"), fig("q24"));
        for f in [a, b] {
            assert_eq!(f.reversals, reversals, "{label} {}: {f:?}", profile.name);
            assert_eq!(f.false_lock_samples, 0, "{label} {}: {f:?}", profile.name);
        }
        assert!(
            (a.transient_err_max_deg - b.transient_err_max_deg).abs() < 1.0,
            "{label} {}: f32 {a:?}, Q8.24 {b:?}",
            profile.name
        );
    }
}

#[test]
fn the_paper_motor_reverses_without_a_false_lock() {
    check(&MotorParams::paper(), "paper");
}

#[test]
fn a_salient_motor_reverses_without_a_false_lock() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../motors/salient.toml");
    let motor = dcfo_host::motor_file::load_motor(path).expect("motor file").params;
    check(&motor, "salient");
}
