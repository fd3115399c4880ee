//! Cold-start acquisition (`dcfo acquire`) on a subset of the benchmark's sweep: a
//! mover held at 0.1, 0.3 and 1.5 m/s in both directions, eight mover positions, with
//! and without +0.2 A / +2 V offsets present from the first sample, f32 and Q8.24.
//!
//! Measured on this subset (144 starts) with the back-EMF circle fit that gives the
//! DC error with the seed (`src/algorithms/arc_fit.rs`): every start within its budget
//! (at 0.1 m/s, 0.5 s at most of 0.6 s; without the fit 25 of the 48 starts there are
//! over, the +2 V ones by 2.1 budgets in the median); no false lock. Q8.24 within
//! 0.20 deg of f32 once both are locked and seeded (the floor is 1 deg): 1.37
//! when the PLL integrator's update rounded down (0.12 rad/s of
//! bias at 0.1 m/s, a notch 0.6 % off: 0.35 deg) and the seed was the first circle to
//! pass its checks (the two types passed a sample apart, 1.2 deg apart; now the mean of
//! the circles over the next eighth of the fit).

use dcfo::algorithms::observer::ObserverKind;
use dcfo_host::commands::acquire::{Offset, Options, PlantModel, sweep};
use dcfo_host::simulation::Setup;

#[test]
fn estimator_finds_a_moving_mover_from_its_zero_state() {
    let setup = Setup::paper(ObserverKind::Dcfo);
    let options = Options {
        speeds_m_per_s: vec![0.1, 0.3, 1.5],
        positions: 8,
        offsets: Offset::ALL.to_vec(),
        fixed_point: true,
    };
    let starts = sweep(&setup, &options, |_, _| {}).unwrap();
    assert_eq!(starts.len(), 3 * 2 * 8 * 3);
    for s in &starts {
        println!(
            "{:5.2} m/s p{} {:7}: lock {:?} s, flag {:?} s, Q24 dev {:?} deg",
            s.speed_m_per_s,
            s.position,
            s.offset.label(),
            s.lock_time_s,
            s.flag_time_s,
            s.q24_deviation_deg
        );
        assert!(s.within_budget(), "{s:?}");
        assert_eq!(s.false_lock_samples, 0, "{s:?}");
        assert!(s.q24_deviation_deg.unwrap_or(f64::INFINITY) < 1.0, "{s:?}");
    }
}

/// The estimator's own acquisition, without what the inputs cost: traces recorded
/// through an ideal inverter and ideal sensors (`dcfo acquire --plant ideal`). Measured:
/// every start without an offset at 0.42 and 1.0 m/s locks within a sixth
/// of its budget (0.16 at most), so what `dcfo acquire` counts over budget there on the
/// realistic plant is the inputs' error, not the estimator's pull-in.
#[test]
fn on_ideal_inputs_the_estimator_locks_well_within_budget() {
    let mut setup = Setup::paper(ObserverKind::Dcfo);
    PlantModel::Ideal.apply(&mut setup);
    let options = Options {
        speeds_m_per_s: vec![0.42, 1.0],
        positions: 8,
        offsets: vec![Offset::None],
        fixed_point: false,
    };
    let starts = sweep(&setup, &options, |_, _| {}).unwrap();
    assert_eq!(starts.len(), 2 * 2 * 8);
    for s in &starts {
        println!(
            "{:5.2} m/s p{}: lock {:?} s of {:.3} s",
            s.speed_m_per_s, s.position, s.lock_time_s, s.budget_s
        );
        assert_eq!(s.false_lock_samples, 0, "{s:?}");
        assert!(s.within_budget(), "{s:?}");
    }
}

/// The steady angle error of a cold-started estimator is the inverter's period-average
/// voltage error across the mover flux over the back-EMF, and the compensation with
/// the ripple at the switching edges (`dcfo::algorithms::dead_time`) and the reference's signs
/// removes most of it.
///
/// The DCFO passes the fundamental with unity gain and zero phase (docs/method.md §3,
/// `tests/observer_analysis.rs`), so an error `dU_d` the estimator is not told turns the
/// flux estimate by `dU_d / (w psi_f)`: [`dcfo_host::commands::acquire::Start::inverter_bias_deg`],
/// computed from the plant's period-average voltages, predicts the mean error the
/// estimator shows. Ideal sensors, so that the inverter is the only error. Measured:
/// within 0.1 deg at every start. With the measured current's signs at
/// 0.6 m/s (a duty spread of 5.6 dead times, below the ripple's fade-in) the
/// compensation leaves 2.2 deg, so the agreement is not one of two zeros; with the
/// default (the reference's signs, the ripple) 0.02 deg at most at every speed (the
/// recorder's reference is exact; 4.5 deg at 1.2 m/s with the measured signs before the
/// ripple).
#[test]
fn the_steady_angle_error_is_the_inverters_voltage_error_over_the_back_emf() {
    use dcfo::drive::CompensationSigns;
    let options = Options {
        speeds_m_per_s: vec![0.3, 0.6, 1.2],
        positions: 2,
        offsets: vec![Offset::None],
        fixed_point: false,
    };
    for signs in [CompensationSigns::Measured, CompensationSigns::ReferenceAboveNoise] {
        let mut setup = Setup::paper(ObserverKind::Dcfo);
        PlantModel::IdealSensors.apply(&mut setup);
        setup.drive.compensation_signs = signs;
        let starts = sweep(&setup, &options, |_, _| {}).unwrap();
        assert_eq!(starts.len(), 3 * 2 * 2);
        for s in &starts {
            let mean = s.steady_error_mean_deg.expect("locked by the second half of its window");
            println!(
                "{signs:?} {:5.2} m/s p{}: dU_d {:+.3} V, predicted {:+.2} deg, measured mean {:+.2} deg",
                s.speed_m_per_s, s.position, s.inverter_error_d_v, s.inverter_bias_deg, mean
            );
            assert!((mean - s.inverter_bias_deg).abs() < 0.2, "{s:?}");
            let v = s.speed_m_per_s.abs();
            if signs == CompensationSigns::Measured && (v - 0.6).abs() < 1e-9 {
                assert!(s.inverter_bias_deg.abs() > 1.0, "{s:?}");
            }
            if signs == CompensationSigns::ReferenceAboveNoise && v >= 0.6 {
                assert!(s.inverter_bias_deg.abs() < 1.0, "{s:?}");
            }
        }
    }
}

/// `dcfo acquire --motor`: another motor is swept at the benchmark's electrical
/// frequencies (its speeds scaled by its pole pitch) and recorded at the same share of its
/// rated thrust, both derived from its file alone; the paper motor gets the benchmark's
/// own speeds and load.
#[test]
fn another_motor_is_swept_at_the_benchmarks_electrical_frequencies_and_load_share() {
    use dcfo::motor::MotorParams;
    use dcfo_host::commands::acquire::{LOAD_N, electrical_hz, recording_load_n};
    let paper = MotorParams::paper();
    assert_eq!(Options::full_for(&paper).speeds_m_per_s, Options::full().speeds_m_per_s);
    assert_eq!(recording_load_n(&paper), LOAD_N);
    for file in ["motors/salient.toml", "motors/low_r.toml"] {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(file);
        let motor = dcfo_host::motor_file::read_motor_file(&path).expect("motor file").params;
        let options = Options::full_for(&motor);
        assert_eq!(options.speeds_m_per_s.len(), Options::full().speeds_m_per_s.len());
        for (v, v_paper) in options.speeds_m_per_s.iter().zip(&Options::full().speeds_m_per_s) {
            let (f, f_paper) = (electrical_hz(&motor, *v), electrical_hz(&paper, *v_paper));
            assert!((f - f_paper).abs() < 1e-9 * f_paper, "{file}: {f} Hz against {f_paper} Hz");
        }
        // The same share of rated thrust: the thrust current is the same share of rated current.
        let share = |m: &MotorParams| {
            recording_load_n(m) / f64::from(m.thrust_constant_n_per_a()) / f64::from(m.rated_current_a)
        };
        assert!((share(&motor) / share(&paper) - 1.0).abs() < 1e-6, "{file}");
    }
}

/// On a motor whose back-EMF carries as much of the current sensors' noise as signal at
/// low speed (`motors/salient_high_l.toml`: through `Ls di/dt`, 1.5 times the back-EMF
/// at 3.3 Hz), the circle fit takes the noise's variance out of its points
/// (`dcfo::algorithms::arc_fit`, "Noise") and every start at 5 and 6.7 Hz, with and without the
/// offsets, locks within its budget. Measured (f32): all 96 (the plain
/// algebraic fit, biased towards small circles by the noise: 22 over budget, up to 0.95 s
/// of 0.4).
#[test]
fn with_noisy_sensors_a_high_inductance_motor_locks_within_budget_at_low_speed() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../motors/salient_high_l.toml");
    let motor = dcfo_host::motor_file::read_motor_file(&path).expect("motor file").params;
    let setup = Setup::for_motor(&motor, ObserverKind::Dcfo);
    let speeds = Options::full_for(&motor).speeds_m_per_s[1..3].to_vec();
    let options =
        Options { speeds_m_per_s: speeds, positions: 8, offsets: Offset::ALL.to_vec(), fixed_point: false };
    let starts = sweep(&setup, &options, |_, _| {}).unwrap();
    assert_eq!(starts.len(), 2 * 2 * 8 * 3);
    for s in &starts {
        println!(
            "{:5.3} m/s ({:.1} Hz) p{} {:7}: lock {:?} s of {:.3} s",
            s.speed_m_per_s,
            s.electrical_hz,
            s.position,
            s.offset.label(),
            s.lock_time_s,
            s.budget_s
        );
        assert!(s.within_budget(), "{s:?}");
        assert_eq!(s.false_lock_samples, 0, "{s:?}");
    }
}
