//! Flying restart: the drive's estimator is reset to zero while the mover runs; the drive
//! must not trip, must stop pushing on an untrusted angle (`Reacquiring`: zero current
//! references), find the mover again and resume closed-loop control.

use dcfo::algorithms::observer::ObserverKind;
use dcfo::drive::DriveState;
use dcfo_host::simulation::{self, Event, Scenario, Setup, theta_err_deg};

/// (time to resume Running, peak current, lowest speed, max error over the last 0.1 s,
/// max error over the 0.5 s before the reset).
fn run_reset_at(v: f64) -> (Option<f64>, f64, f64, f64, f64) {
    let setup = Setup::paper(ObserverKind::Dcfo);
    let accel = f64::from(setup.drive.accel_limit_m_per_s2);
    let t_reset = 1.0 + v / accel + 1.0;
    let scenario = Scenario {
        name: "flying-restart".into(),
        description: "estimator reset at speed".into(),
        duration_s: t_reset + 1.0,
        events: vec![(0.0, Event::Speed(v)), (t_reset, Event::ResetEstimator)],
        plant: simulation::PlantChanges::default(),
        event_s: t_reset,
        window_s: 1.0,
        paper: String::new(),
    };
    let run = simulation::run(&setup, &scenario, |_| {}).unwrap();
    assert!(run.faults.is_empty(), "{v} m/s: tripped {:?}", run.faults);
    let after: Vec<&simulation::Sample> = run.samples.iter().filter(|s| s.row.t >= t_reset).collect();
    let left = after.iter().position(|s| s.state == DriveState::Reacquiring.code());
    // Back in Running after having been in Reacquiring.
    let resumed = left.and_then(|j| {
        after[j..].iter().find(|s| s.state == DriveState::Running.code()).map(|s| s.row.t - t_reset)
    });
    let i_peak = after.iter().map(|s| s.i_q.abs().max(s.i_d.abs())).fold(0.0, f64::max);
    let v_min = after.iter().map(|s| s.row.v.unwrap_or(0.0)).fold(f64::INFINITY, f64::min);
    let err_end = after.iter().rev().take(1000).map(|s| theta_err_deg(s).abs()).fold(0.0, f64::max);
    // The steady error's maximum before the reset, over several periods of the
    // electrical angle and of the end-effect ripple.
    let err_before = run
        .samples
        .iter()
        .filter(|s| s.row.t >= t_reset - 0.5 && s.row.t < t_reset)
        .map(|s| theta_err_deg(s).abs())
        .fold(0.0, f64::max);
    (resumed, i_peak, v_min, err_end, err_before)
}

#[test]
fn drive_reacquires_a_moving_mover_instead_of_tripping() {
    let limit = f64::from(Setup::paper(ObserverKind::Dcfo).drive.current_limit_a);
    for v in [0.3, 0.6, 1.0] {
        let (resumed, i_peak, v_min, err_end, err_before) = run_reset_at(v);
        println!(
            "{v} m/s: resumed after {:?} s, peak current {i_peak:.2} A, lowest speed {v_min:.3} m/s, \
             max error over the last 0.1 s {err_end:.2} deg (before the reset {err_before:.2})",
            resumed
        );
        let resumed = resumed.expect("never resumed Running");
        // Issue floor: closed loop again within 100 ms (measured 40-92 ms).
        assert!(resumed < 0.1, "{v} m/s: {resumed} s");
        assert!(i_peak <= limit, "{v} m/s: {i_peak} A over the {limit} A limit");
        // Back to the accuracy it had before the reset (the steady ripple at that speed).
        assert!(err_end < err_before + 1.0, "{v} m/s: {err_end} deg, {err_before} before");
    }
}

/// Enabling the drive while the mover coasts at `v` (m/s; friction slows it at about
/// 0.4 m/s^2): (states the drive went through, time from the end of calibration to
/// `Running`, peak current, max angle error over the last 0.2 s).
fn enable_while_moving(v: f64) -> (Vec<u8>, Option<f64>, f64, f64) {
    let setup = Setup::paper(ObserverKind::Dcfo);
    let scenario = Scenario {
        name: "catch-on-enable".into(),
        description: "drive enabled with the mover already moving".into(),
        duration_s: 1.5,
        events: vec![(0.0, Event::Speed(v)), (0.0, Event::MoverSpeed(v))],
        plant: simulation::PlantChanges::default(),
        event_s: 0.0,
        window_s: 1.5,
        paper: String::new(),
    };
    let run = simulation::run(&setup, &scenario, |_| {}).unwrap();
    assert!(run.faults.is_empty(), "{v} m/s: tripped {:?}", run.faults);
    let mut states: Vec<u8> = run.samples.iter().map(|s| s.state).collect();
    states.dedup();
    let calibrated = run.samples.iter().find(|s| s.state != DriveState::Calibrating.code()).map(|s| s.row.t);
    let running = run.samples.iter().find(|s| s.state == DriveState::Running.code()).map(|s| s.row.t);
    let caught = calibrated.zip(running).map(|(a, b)| b - a);
    let i_peak = run.samples.iter().map(|s| s.i_q.abs().max(s.i_d.abs())).fold(0.0, f64::max);
    let err_end =
        run.samples.iter().filter(|s| s.row.t > 1.3).map(|s| theta_err_deg(s).abs()).fold(0.0, f64::max);
    (states, caught, i_peak, err_end)
}

/// The largest angle error (deg) over the last 0.5 s of a drive started by I/f from rest
/// and run at `v` (m/s) for 1.5 s after its speed ramp.
fn steady_error_after_if_start(v: f64) -> f64 {
    let setup = Setup::paper(ObserverKind::Dcfo);
    let accel = f64::from(setup.drive.accel_limit_m_per_s2);
    let duration = 2.0 + v.abs() / accel + 1.5;
    let scenario = Scenario {
        name: "steady".into(),
        description: "started by I/f".into(),
        duration_s: duration,
        events: vec![(0.0, Event::Speed(v))],
        plant: simulation::PlantChanges::default(),
        event_s: 0.0,
        window_s: duration,
        paper: String::new(),
    };
    let run = simulation::run(&setup, &scenario, |_| {}).unwrap();
    assert!(run.faults.is_empty(), "{v} m/s: tripped {:?}", run.faults);
    run.samples
        .iter()
        .filter(|s| s.row.t > duration - 0.5)
        .map(|s| theta_err_deg(s).abs())
        .fold(0.0, f64::max)
}

#[test]
fn enabling_a_drive_on_a_moving_mover_catches_it_without_a_current_spike() {
    let limit = f64::from(Setup::paper(ObserverKind::Dcfo).drive.current_limit_a);
    for v in [0.3, -0.6, 1.0] {
        let (states, caught, i_peak, err_end) = enable_while_moving(v);
        println!(
            "{v} m/s: states {states:?}, Running {caught:?} s after calibration, peak {i_peak:.2} A, end error {err_end:.2} deg"
        );
        // Straight from the catch (Reacquiring) to Running: no I/f start on a moving mover.
        assert!(!states.contains(&DriveState::Starting.code()), "{v} m/s: {states:?}");
        let caught = caught.expect("never reached Running");
        // The issue sets no time for this case (the flying restart's 100 ms is for a lock
        // loss); measured 131 ms at 0.3 m/s (the estimate tracks, drops once, tracks
        // again), 42-45 ms at 0.6-1.0 m/s.
        assert!(caught < 0.2, "{v} m/s: {caught} s");
        assert!(i_peak <= limit, "{v} m/s: {i_peak} A over the {limit} A limit");
        // Then as accurate as a drive started by I/f from rest and run at the same speed
        // (its steady ripple at that speed: 1.2 deg at 0.3 m/s, about 6 deg at
        // 0.6-1.0 m/s), within a degree.
        let steady = steady_error_after_if_start(v);
        println!("{v} m/s: steady error of a drive started by I/f {steady:.2} deg");
        assert!(err_end < steady + 1.0, "{v} m/s: {err_end} deg, {steady} deg started by I/f");
    }
}
