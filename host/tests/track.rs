//! `dcfo track`'s figures asserted (module docs of `dcfo_host::track`): the estimator
//! alone, from zero state, on recordings of reversals and sharp speed steps, in f32 and
//! Q8.24. Floors of issue 35: the angle within 10 degrees within 2 electrical periods
//! after every reversal, once the speed is above the motor's back-EMF floor; no false
//! lock on a reversal; Q8.24 within a degree of f32.

use dcfo::motor::MotorParams;
use dcfo_host::track::{Figures, run_all, setup_for};

fn figures(motor: &MotorParams) -> Vec<Figures> {
    run_all(&setup_for(motor)).expect("recorded and replayed")
}

fn find<'a>(all: &'a [Figures], profile: &str, numeric: &str) -> &'a Figures {
    all.iter().find(|f| f.profile == profile && f.numeric == numeric).expect("profile run")
}

#[test]
fn the_paper_motor_is_found_again_after_every_reversal() {
    let all = figures(&MotorParams::paper());
    for profile in ["reversal", "stroke"] {
        for numeric in ["f32", "q24"] {
            let f = find(&all, profile, numeric);
            assert!(f.reversals >= 1, "{profile} {numeric}: no reversal recorded");
            let periods = f.relock_periods_max.expect("found again after each reversal");
            assert!(periods <= 2.0, "{profile} {numeric}: {periods} periods");
            assert_eq!(f.false_lock_samples, 0, "{profile} {numeric}");
        }
        let (a, b) = (find(&all, profile, "f32"), find(&all, profile, "q24"));
        assert!((a.transient_err_max_deg - b.transient_err_max_deg).abs() < 1.0, "{profile}: {a:?} {b:?}");
    }
}

#[test]
fn a_salient_motor_is_found_again_on_a_stroke() {
    let motor = dcfo_host::motor_file::load_motor(concat!(env!("CARGO_MANIFEST_DIR"), "/../motors/salient.toml"))
        .expect("motor file")
        .params;
    let all = figures(&motor);
    for numeric in ["f32", "q24"] {
        let f = find(&all, "stroke", numeric);
        let periods = f.relock_periods_max.expect("found again after each reversal");
        assert!(periods <= 2.0, "stroke {numeric}: {periods} periods");
        assert_eq!(f.false_lock_samples, 0, "stroke {numeric}");
    }
}
