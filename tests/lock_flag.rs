//! `Estimate::locked` is honest through DC steps in the observer's inputs: on an ideal
//! flux turning at 0.3 m/s (the paper's Figs. 14-15), a +2 V step on `u_alpha` or a
//! +0.2 A step on `i_beta` moves the angle estimate by tens of degrees while the
//! observer removes it; the flag must never be set while the true error exceeds 15 deg
//! (issue floor), must drop while the observer is disturbed, and must come back once
//! the estimate has recovered.

use dcfo::algorithms::observer::ObserverKind;
use dcfo::algorithms::transforms::AlphaBeta;
use dcfo::estimator::{Estimator, EstimatorConfig};
use dcfo::motor::MotorParams;
use dcfo::num::Angle;
use dcfo::num::units::Base;

const DT: f64 = 1e-4;
const STEP_S: f64 = 1.0;

fn wrap_deg(x: f64) -> f64 {
    (x + 3.0 * std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI).to_degrees() - 180.0
}

/// What one run saw after the step.
#[derive(Debug)]
struct AfterStep {
    /// Largest true angle error, deg.
    max_err_deg: f64,
    /// Samples with the flag set and the true error above 15 deg.
    false_locks: usize,
    /// Samples with the flag cleared.
    unlocked: usize,
    /// The flag is set again at the end (after 2 s of recovery).
    locked_at_end: bool,
}

/// The estimator seeded on an ideal flux at `w` rad/s; at [`STEP_S`] a DC step of
/// `du` V (u_alpha) and `di` A (i_beta) enters its inputs.
fn run(w: f64, du: f32, di: f32) -> AfterStep {
    let m = MotorParams::paper();
    let psi = f64::from(m.psi_f_wb);
    let cfg = EstimatorConfig::for_motor(&m, ObserverKind::Dcfo);
    let mut est = Estimator::<f32>::new(&m, &cfg, &Base::SI).unwrap();
    let mut th = 0.3f64;
    est.seed(Angle::from_radians(th as f32), w as f32, AlphaBeta::new(0.0, 0.0));
    let mut locked_before = false;
    let mut after = AfterStep { max_err_deg: 0.0, false_locks: 0, unlocked: 0, locked_at_end: false };
    for k in 0..((STEP_S + 2.0) / DT) as usize {
        let t = k as f64 * DT;
        let th_next = th + w * DT;
        let on = t >= STEP_S;
        let u = AlphaBeta::new(
            (psi * (th_next.cos() - th.cos()) / DT) as f32 + if on { du } else { 0.0 },
            (psi * (th_next.sin() - th.sin()) / DT) as f32,
        );
        th = th_next;
        let i = AlphaBeta::new(0.0, if on { di } else { 0.0 });
        let e = est.update(u, i, DT as f32).unwrap();
        let err = wrap_deg(th - f64::from(e.theta_e.to_radians::<f32>())).abs();
        if !on {
            locked_before = e.locked;
            continue;
        }
        after.max_err_deg = after.max_err_deg.max(err);
        after.false_locks += usize::from(e.locked && err > 15.0);
        after.unlocked += usize::from(!e.locked);
        after.locked_at_end = e.locked;
    }
    assert!(locked_before, "a clean flux must be reported locked");
    after
}

#[test]
fn a_4_volt_step_never_leaves_the_flag_set_on_a_wrong_angle() {
    let w = std::f64::consts::PI * 0.3 / 0.015; // 0.3 m/s, 10 Hz
    let a = run(w, 4.0, 0.0);
    println!("+4 V: {a:?}");
    // The step is a real disturbance (the observer's own transient, module docs of
    // `observer::dcfo`, about 1.5 dU / w of flux, less what the DC offset's angle
    // correction takes back, `estimator`; the paper's +2 V now stays within 10.5 deg
    // here, below the 15 deg line, so twice that) ...
    assert!(a.max_err_deg > 15.0, "{a:?}");
    // ... which the flag reports, and recovers from.
    assert_eq!(a.false_locks, 0, "{a:?}");
    assert!(a.unlocked > 0 && a.locked_at_end, "{a:?}");
}

#[test]
fn dc_steps_at_other_speeds_never_leave_the_flag_set_on_a_wrong_angle() {
    for w in [62.8, -62.8, 125.6, 251.2] {
        let a = run(w, 0.0, 0.2);
        println!("+0.2 A at {w} rad/s: {a:?}");
        assert_eq!(a.false_locks, 0, "{a:?}");
        assert!(a.locked_at_end, "{a:?}");
    }
    // At 5 Hz the 2 V are 40 % of the back-EMF: the estimate is lost for a while
    // (180 deg), and must say so.
    for w in [31.4, 125.6, -125.6, 251.2] {
        let a = run(w, 2.0, 0.0);
        println!("+2 V at {w} rad/s: {a:?}");
        assert_eq!(a.false_locks, 0, "{a:?}");
        assert!(a.locked_at_end, "{a:?}");
    }
}

/// The last sample's (flag, |angle error| deg) of the estimator seeded on a consistent
/// plant turning at `w` rad/s with a current `i_d` A held along the flux (the voltage
/// `R i + d/dt((psi_f + L i_d) e^{j theta})`): the estimate itself is right.
fn along_flux(w: f64, i_d: f64) -> (bool, f64) {
    let m = MotorParams::paper();
    let (psi, r, l) = (f64::from(m.psi_f_wb), f64::from(m.rs_ohm), f64::from(m.ld_h));
    let cfg = EstimatorConfig::for_motor(&m, ObserverKind::Dcfo);
    let mut est = Estimator::<f32>::new(&m, &cfg, &Base::SI).unwrap();
    let mut th = 0.3f64;
    est.seed(
        Angle::from_radians(th as f32),
        w as f32,
        AlphaBeta::new((i_d * th.cos()) as f32, (i_d * th.sin()) as f32),
    );
    let total = psi + l * i_d;
    let mut last = (false, 0.0);
    for _ in 0..(1.5 / DT) as usize {
        let th_next = th + w * DT;
        let u = AlphaBeta::new(
            (r * i_d * th.cos() + total * (th_next.cos() - th.cos()) / DT) as f32,
            (r * i_d * th.sin() + total * (th_next.sin() - th.sin()) / DT) as f32,
        );
        th = th_next;
        let i = AlphaBeta::new((i_d * th.cos()) as f32, (i_d * th.sin()) as f32);
        let e = est.update(u, i, DT as f32).unwrap();
        last = (e.locked, wrap_deg(th - f64::from(e.theta_e.to_radians::<f32>())).abs());
    }
    last
}

/// The resistance allowance (`estimator::LOCK_ANGLE_RAD`): a resistance error up to the
/// file's own would turn the angle by `atan(dR i_d / (w psi_f))`; with the current along
/// the flux the flag holds below `I* = tan(15 deg) w psi_f / (dR (1 + sin(15 deg)))` and
/// drops above it, whatever the estimate's own accuracy. The bound's norms are
/// approximate (within 12 %), so the test brackets `I*` at 0.7 and 1.5 times it.
#[test]
fn a_current_along_the_flux_drops_the_flag_where_a_resistance_error_could_turn_the_angle() {
    use dcfo::estimator::{LOCK_ANGLE_RAD, RESISTANCE_UNCERTAINTY_SHARE};
    let m = MotorParams::paper();
    let dr = f64::from(RESISTANCE_UNCERTAINTY_SHARE * m.rs_ohm);
    let a = f64::from(LOCK_ANGLE_RAD);
    for w in [62.8f64, -125.6, 251.2] {
        let i_star = a.tan() * w.abs() * f64::from(m.psi_f_wb) / (dr * (1.0 + a.sin()));
        let below = along_flux(w, 0.7 * i_star);
        let above = along_flux(w, 1.5 * i_star);
        println!("w {w} rad/s, I* {i_star:.3} A: 0.7 I* {below:?}, 1.5 I* {above:?}");
        assert!(below.0 && below.1 < 5.0, "{below:?}");
        // The estimate is right on this consistent plant; the flag says it cannot vouch.
        assert!(!above.0 && above.1 < 5.0, "{above:?}");
    }
}
