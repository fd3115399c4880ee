//! The Q8.24 fixed-point drive (what the Cortex-M3 firmware runs, in the motor's
//! per-unit base) closes the loop on the simulated axis as the f32 drive does: the same
//! scenario figures within a stated margin. An independent expectation: the f32 drive
//! of the same code is the reference, and the paper's figure for the steady scenario.
//! The estimator's own numerics are compared open-loop, on identical inputs, so that the
//! closed loop's amplification of rounding does not hide or fake a difference.

use dcfo::estimator::Estimator;
use dcfo::num::Q24;
use dcfo::observer::ObserverKind;
use dcfo::transforms::AlphaBeta;
use dcfo::units::Base;
use dcfo_host::sim::{LocalDrive, Setup, run, run_with, scenarios};
use dcfo_host::trace::wrap_angle;

#[test]
fn q24_estimator_follows_the_f32_estimator_within_one_degree_on_the_same_inputs() {
    let setup = Setup::paper(ObserverKind::Dcfo);
    let pu = Base::for_motor(&setup.motor);
    for name in ["steady", "speed-step", "dc-u", "dc-i", "resistance", "load-step"] {
        let sc = scenarios::scenario(name).expect("scenario");
        let r = run(&setup, &sc, |_| {}).expect("f32 run");
        let mut f: Estimator<f32> = Estimator::new(&setup.motor, &setup.drive.estimator, &Base::SI).unwrap();
        let mut q: Estimator<Q24> = Estimator::new(&setup.motor, &setup.drive.estimator, &pu).unwrap();
        let mut worst = 0.0f64;
        // As the drive and `dcfo replay` do: sample k gets row k - 1's voltage.
        let mut u = [0.0f32; 2];
        for s in &r.samples {
            let i = [s.row.i_alpha as f32, s.row.i_beta as f32];
            let ef = f.update(AlphaBeta::new(u[0], u[1]), AlphaBeta::new(i[0], i[1]), 1e-4).unwrap();
            let eq = q
                .update(
                    AlphaBeta::new(pu.voltage(u[0]), pu.voltage(u[1])),
                    AlphaBeta::new(pu.current(i[0]), pu.current(i[1])),
                    pu.time(1e-4),
                )
                .unwrap();
            u = [s.row.u_alpha as f32, s.row.u_beta as f32];
            // From the drive's hand-over on (before it the estimator is acquiring).
            if r.handover_s.is_some_and(|h| s.row.t >= h) {
                let d = wrap_angle(ef.theta_e.to_radians::<f64>() - eq.theta_e.to_radians::<f64>());
                worst = worst.max(d.to_degrees().abs());
            }
        }
        println!("{name}: largest |theta_q24 - theta_f32| {worst:.3} deg");
        assert!(worst < 1.0, "{name}: {worst} deg");
    }
}

#[test]
fn q24_drive_runs_the_paper_scenarios_like_the_f32_drive() {
    let setup = Setup::paper(ObserverKind::Dcfo);
    for name in ["steady", "speed-step", "load-step"] {
        let sc = scenarios::scenario(name).expect("scenario");
        let f32_run = run(&setup, &sc, |_| {}).expect("f32 run");
        let q24_run = run_with(&setup, &sc, &mut LocalDrive::fixed_point(&setup).expect("drive"), |_| {})
            .expect("q24 run");
        let (a, b) = (scenarios::figures(&f32_run, &sc), scenarios::figures(&q24_run, &sc));
        println!(
            "{name}: theta_err max/rms f32 {:.2}/{:.2} deg, Q24 {:.2}/{:.2} deg",
            a.theta_err_max_deg, a.theta_err_rms_deg, b.theta_err_max_deg, b.theta_err_rms_deg
        );
        assert!(b.healthy, "{name}: the Q24 drive faulted ({:?})", q24_run.faults);
        // Q24's resolution (6e-8 pu) is not the limit (see the open-loop test above); the
        // difference is the closed loop amplifying rounding differently, and the
        // estimator's FLL/PLL hand-overs are threshold decisions that the two runs can
        // take a few samples apart (load step: f32 13.8, Q24 11.6 deg). The Q24 drive
        // must be no worse than 1 degree of max error, and within 0.5 degree rms.
        assert!(b.theta_err_max_deg <= a.theta_err_max_deg + 1.0, "{name}: max");
        assert!((b.theta_err_rms_deg - a.theta_err_rms_deg).abs() <= 0.5, "{name}: rms");
    }
}

#[test]
fn q24_steady_scenario_meets_the_papers_figure() {
    let setup = Setup::paper(ObserverKind::Dcfo);
    let sc = scenarios::scenario("steady").expect("scenario");
    let r = run_with(&setup, &sc, &mut LocalDrive::fixed_point(&setup).expect("drive"), |_| {}).expect("run");
    let f = scenarios::figures(&r, &sc);
    assert!(f.healthy && f.theta_err_max_deg <= 5.0 && f.theta_err_rms_deg <= 2.5, "{f:?}");
}
