//! Runs the DCFO and the PLL (f32, as on Cortex-M4F) on a synthetic 10 Hz trace of the
//! paper motor with dead-time-like harmonics and a DC offset switched on half-way, and
//! prints how the angle estimate follows the truth.
//!
//! `cargo run --release --example synthetic_trace`

use dcfo::algorithms::observer::ObserverKind;
use dcfo::algorithms::transforms::AlphaBeta;
use dcfo::estimator::{Estimator, EstimatorConfig};
use dcfo::motor::MotorParams;
use dcfo::num::Scalar;
use dcfo::num::units::Base;

const TS: f64 = 1e-4;

/// Paper motor at 0.3 m/s with 1 A of thrust current: stator flux, current and the
/// exact held voltage of each period, plus 5th/7th voltage harmonics.
fn sample(m: &MotorParams, k: usize, dc_on: bool) -> (AlphaBeta<f32>, AlphaBeta<f32>, f64) {
    let w = m.omega_e_from_speed(0.3) as f64;
    let (rs, ls, psi) = (m.rs_ohm as f64, m.lq_h as f64, m.psi_f_wb as f64);
    let current = |t: f64| [-(w * t).sin(), (w * t).cos()];
    let stator = |t: f64| {
        let i = current(t);
        let (h5, h7) = (-5.0 * w * t, 7.0 * w * t);
        [
            psi * (w * t).cos() + ls * i[0] + 3.0 / (-5.0 * w) * h5.sin() + 2.0 / (7.0 * w) * h7.sin(),
            psi * (w * t).sin() + ls * i[1] - 3.0 / (-5.0 * w) * h5.cos() - 2.0 / (7.0 * w) * h7.cos(),
        ]
    };
    let (t0, t1) = (k as f64 * TS, (k + 1) as f64 * TS);
    let (s0, s1, i0, i1) = (stator(t0), stator(t1), current(t0), current(t1));
    let dc = if dc_on { 2.0 } else { 0.0 };
    let u = [
        (s1[0] - s0[0]) / TS + rs * 0.5 * (i0[0] + i1[0]) + dc,
        (s1[1] - s0[1]) / TS + rs * 0.5 * (i0[1] + i1[1]),
    ];
    (AlphaBeta::new(u[0] as f32, u[1] as f32), AlphaBeta::new(i1[0] as f32, i1[1] as f32), w * t1)
}

fn main() {
    let motor = MotorParams::paper();
    println!("paper motor at 0.3 m/s (10 Hz), Ts = 100 us; +2 V on u_alpha from t = 1.5 s");
    println!("{:>6}  {:>13}  {:>13}", "t [s]", "CFO err [deg]", "DCFO err [deg]");
    let mut estimators = [ObserverKind::Cfo, ObserverKind::Dcfo].map(|kind| {
        Estimator::<f32>::new(&motor, &EstimatorConfig::for_motor(&motor, kind), &Base::SI)
            .expect("valid defaults")
    });
    let mut worst = [0.0f64; 2];
    for k in 0..30_000 {
        let (u, i, theta) = sample(&motor, k, k as f64 * TS >= 1.5);
        let mut errs = [0.0; 2];
        for (j, est) in estimators.iter_mut().enumerate() {
            let e = est.update(u, i, TS as f32).expect("finite synthetic data");
            let err = (e.theta_e - theta.radians_to_angle()).to_degrees_f64();
            errs[j] = -err;
            if k as f64 * TS > 1.0 {
                worst[j] = worst[j].max(err.abs());
            }
        }
        if k % 2500 == 2499 {
            println!("{:6.2}  {:13.3}  {:13.3}", (k + 1) as f64 * TS, errs[0], errs[1]);
        }
    }
    println!("max |angle error| after 1 s: CFO {:.2} deg, DCFO {:.2} deg", worst[0], worst[1]);
}
