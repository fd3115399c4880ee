//! The speed drive reverses on command: `scenarios/reversal.toml` (+0.4 -> -0.4 -> +0.4
//! m/s) on the paper axis and on every motor file in `motors/`, through the low-speed
//! mode at each passage through zero speed and back to the sensorless loop.

use dcfo::algorithms::observer::ObserverKind;
use dcfo::drive::DriveState;
use dcfo::motor::MotorParams;
use dcfo_host::commands::sim::load_scenario;
use dcfo_host::motor_file::load_motor;
use dcfo_host::simulation::{Event, Run, Setup, run};

const ROOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/..");

/// The drive's state changes over a run: (t s, state).
fn transitions(r: &Run) -> Vec<(f64, DriveState)> {
    let mut out: Vec<(f64, DriveState)> = Vec::new();
    for s in &r.samples {
        let state = DriveState::from_code(s.state).expect("state code");
        if out.last().is_none_or(|(_, last)| *last != state) {
            out.push((s.row.t, state));
        }
    }
    out
}

fn check(name: &str, setup: &Setup) {
    let scenario = load_scenario(&format!("{ROOT}/scenarios/reversal.toml")).unwrap();
    let r = run(setup, &scenario, |_| {}).unwrap();
    let t = transitions(&r);
    let floor = dcfo::drive::back_emf_floor_m_per_s(&setup.motor, &setup.drive);
    eprintln!("{name}: low-speed band below {floor:.3} m/s; faults {:?}, states {t:?}", r.faults);
    assert!(r.faults.is_empty(), "{name}: tripped {:?}; states {t:?}", r.faults);
    assert!(r.samples.last().is_some_and(|s| s.row.t > scenario.duration_s - 0.01), "{name}: stopped early");
    // Each reversal passes through the low-speed mode and ends on the sensorless loop,
    // or, where the speed lies inside the motor's low-speed band (below its back-EMF
    // floor), stays in the low-speed mode; either way the mover runs at the new speed
    // (within 20 %, the hand-over's tolerance) by the next command.
    let in_band = 0.4 < floor;
    for (from, to, v) in [(3.0, 6.0, -0.4f64), (6.0, scenario.duration_s, 0.4)] {
        let low = in_band || t.iter().any(|(at, s)| *at > from && *at < to && *s == DriveState::LowSpeed);
        assert!(low, "{name}: no low-speed passage in ({from}, {to}) s; states {t:?}");
        let end = r.samples.iter().rev().find(|s| s.row.t < to - 0.01).unwrap();
        let expected = if in_band { DriveState::LowSpeed } else { DriveState::Running };
        assert_eq!(DriveState::from_code(end.state), Some(expected), "{name}: at {to} s; states {t:?}");
        // No overspeed on the way: the mover never runs faster than 1.5 times the
        // commanded speed (measured at most 1.31, on motors/high_inductance.toml; 3.4 on
        // motors/low_r.toml while the speed loop left the low-speed mode from the
        // vector's q current in a frame still 10-25 deg off the mover).
        let peak = r.samples.iter().filter(|s| s.row.t > from && s.row.t < to).filter_map(|s| s.row.v);
        let peak = peak.fold(0.0f64, |m, v| m.max(v.abs()));
        eprintln!("{name}: peak speed {peak:.3} m/s in ({from}, {to}) s (target {v:+})");
        assert!(peak <= 1.5 * v.abs(), "{name}: peak speed {peak:.3} m/s in ({from}, {to}) s, target {v}");
        // Mean true speed over the last 0.3 s before the next command.
        let tail: Vec<f64> = r
            .samples
            .iter()
            .filter(|s| s.row.t > to - 0.31 && s.row.t < to - 0.01)
            .filter_map(|s| s.row.v)
            .collect();
        let mean = tail.iter().sum::<f64>() / tail.len() as f64;
        eprintln!("{name}: mean speed {mean:+.3} m/s before {to} s (target {v:+})");
        assert!(
            (mean - v).abs() < 0.2 * v.abs(),
            "{name}: mean speed {mean:.3} m/s before {to} s, target {v}"
        );
    }
}

#[test]
fn the_paper_axis_reverses_twice_through_the_low_speed_mode() {
    check("paper", &Setup::paper(ObserverKind::Dcfo));
}

#[test]
fn every_motor_file_reverses_twice_through_the_low_speed_mode() {
    let scenario = load_scenario(&format!("{ROOT}/scenarios/reversal.toml")).unwrap();
    let mut files: Vec<_> = std::fs::read_dir(format!("{ROOT}/motors"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    files.sort();
    assert!(files.len() >= 4);
    for f in files {
        let motor = load_motor(f.to_str().unwrap()).unwrap();
        check(&f.display().to_string(), &Setup::for_axis(&motor.params, &scenario, ObserverKind::Dcfo));
    }
}

/// A motor the repository has no file for: ironless, high resistance, on a 48 V bus (4
/// ohm, 0.8 mH, 0.03 Wb, 30 mm pitch, 4 A rms).
fn ironless_48_v() -> MotorParams {
    MotorParams {
        rs_ohm: 4.0,
        ld_h: 8e-4,
        lq_h: 8e-4,
        psi_f_wb: 0.03,
        pole_pitch_m: 0.03,
        mass_kg: 0.5,
        viscous_n_s_per_m: 0.5,
        rated_current_a: 4.0,
        rated_voltage_v: 48.0,
    }
}

/// The ironless motor: twice its rated peak would take 45 V through the winding at
/// standstill, more than the bus drives: the drive's current limit comes from the bus
/// instead (`DriveConfig::bus_current_limit_a`), else the current loops saturate at the
/// first reversal and trip `CURRENT_CONTROL`. Its back-EMF floor lies above the
/// scenario's 0.4 m/s, so it runs in the low-speed mode.
#[test]
fn an_ironless_motor_on_a_48_v_bus_reverses_twice() {
    let scenario = load_scenario(&format!("{ROOT}/scenarios/reversal.toml")).unwrap();
    check("ironless 48 V", &Setup::for_axis(&ironless_48_v(), &scenario, ObserverKind::Dcfo));
}

/// The ironless motor in its low-speed mode at 0.4 m/s, then a load step
/// (`scenarios/load-step.toml`, 20 N, and the same at 10 N). At 0.4 m/s the vector's
/// current has fallen towards the band's edge and its spring holds about 19 N: under 20 N
/// the mover slips, pushed back pole after pole. The drive must say so (`OVERLOAD`, the
/// bridge off) within a second of the step, where the signed speed reading alone (`w
/// cos delta`, averaging out as delta turns) let it run back at 3 m/s without a trip.
/// Under 10 N it holds: no fault, and the mover keeps its speed.
#[test]
fn an_ironless_motor_slipping_under_a_load_beyond_its_thrust_trips_overload() {
    let motor = ironless_48_v();
    let mut scenario = load_scenario(&format!("{ROOT}/scenarios/load-step.toml")).unwrap();
    let setup = Setup::for_axis(&motor, &scenario, ObserverKind::Dcfo);
    let r = run(&setup, &scenario, |_| {}).unwrap();
    let t = transitions(&r);
    eprintln!("ironless 48 V under 20 N: faults {:?}; states {t:?}", r.faults);
    assert_eq!(r.faults, dcfo::drive::Faults::OVERLOAD, "states {t:?}");
    let trip = t.iter().find(|(_, s)| *s == DriveState::Fault).map(|(at, _)| *at);
    assert!(trip.is_some_and(|at| at > 3.5 && at < 4.5), "tripped at {trip:?} s, the load stepped at 3.5 s");
    // The mover did slip: pushed backwards before the trip.
    let slowest = r.samples.iter().filter(|s| s.row.t > 3.5).filter_map(|s| s.row.v).fold(f64::MAX, f64::min);
    eprintln!("slowest true speed after the step {slowest:+.3} m/s");
    assert!(slowest < 0.0, "the mover never ran backwards (slowest {slowest:+.3} m/s)");

    for (_, e) in &mut scenario.events {
        if let Event::Load(n) = e {
            *n = 10.0;
        }
    }
    let r = run(&setup, &scenario, |_| {}).unwrap();
    assert!(r.faults.is_empty(), "under 10 N: tripped {:?}; states {:?}", r.faults, transitions(&r));
    let tail: Vec<f64> = r.samples.iter().filter(|s| s.row.t > 4.5).filter_map(|s| s.row.v).collect();
    let mean = tail.iter().sum::<f64>() / tail.len() as f64;
    eprintln!("under 10 N: mean speed {mean:+.3} m/s over the last 0.5 s");
    assert!((mean - 0.4).abs() < 0.08, "under 10 N: mean speed {mean:.3} m/s, target 0.4");
}

/// Mean of `|psi_hat - psi| / |psi|` over the samples of `r` in the low-speed mode with
/// the mover faster than `above_m_per_s`: how well the back-EMF observer, seeded
/// leaving the band, knows the flux while HFI still injects.
fn low_speed_flux_error(r: &Run, above_m_per_s: f64) -> f64 {
    let errors: Vec<f64> = r
        .samples
        .iter()
        .filter(|s| DriveState::from_code(s.state) == Some(DriveState::LowSpeed))
        .filter(|s| s.row.v.is_some_and(|v| v.abs() > above_m_per_s))
        .map(|s| {
            let (e, p) = (s.psi_hat, s.psi_true);
            f64::hypot(e[0] - p[0], e[1] - p[1]) / f64::hypot(p[0], p[1])
        })
        .collect();
    assert!(
        errors.len() > 1000,
        "only {} samples in the low-speed mode above {above_m_per_s} m/s",
        errors.len()
    );
    errors.iter().sum::<f64>() / errors.len() as f64
}

/// HFI's square wave swings the salient motor's d current across zero every period, so
/// the inverter loses little of its dead time where the fundamental alone says it loses
/// all of it; the compensation models the injection's ramp at the switching edges
/// (`dcfo::algorithms::dead_time`, "Under injection"). Leaving the low-speed mode, the
/// back-EMF observer (seeded there, told the compensated command) then knows the flux
/// as well as on an ideal inverter, and the drive hands over once per reversal. Measured
/// above the exit speed: 0.10 of the flux, 0.22 on the ideal inverter (no compensation);
/// 0.55 with the signs from the fundamental alone, which handed over into a fall-back to
/// the low-speed mode.
#[test]
fn the_salient_motor_leaves_the_hfi_low_speed_mode_as_on_an_ideal_inverter() {
    let scenario = load_scenario(&format!("{ROOT}/scenarios/reversal.toml")).unwrap();
    let motor = load_motor(&format!("{ROOT}/motors/salient.toml")).unwrap();
    let setup = Setup::for_axis(&motor.params, &scenario, ObserverKind::Dcfo);
    let exit = f64::from(dcfo::drive::LOW_SPEED_EXIT_RATIO)
        * f64::from(dcfo::drive::back_emf_floor_m_per_s(&setup.motor, &setup.drive));
    let r = run(&setup, &scenario, |_| {}).unwrap();
    let t = transitions(&r);
    let realistic = low_speed_flux_error(&r, exit);
    let mut ideal = setup.clone();
    ideal.plant.inverter = dcfo_host::plant::InverterParams::ideal(setup.plant.inverter.dc_bus_v);
    ideal.drive.dead_time_compensation = None;
    let ideal = low_speed_flux_error(&run(&ideal, &scenario, |_| {}).unwrap(), exit);
    eprintln!(
        "flux error in the low-speed mode above {exit:.3} m/s: {realistic:.3} (ideal inverter {ideal:.3}); states {t:?}"
    );
    assert!(r.faults.is_empty(), "tripped {:?}; states {t:?}", r.faults);
    assert!(realistic < 1.2 * ideal, "flux error {realistic:.3} of the flux, ideal inverter {ideal:.3}");
    let handovers = t.windows(2).filter(|w| w[0].1 == DriveState::LowSpeed && w[1].1 == DriveState::Running);
    assert_eq!(handovers.count(), 2, "one hand-over per reversal; states {t:?}");
}
