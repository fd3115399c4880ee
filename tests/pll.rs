//! The PLL of docs/method.md §4 on a clean rotating flux.

mod common;

use common::*;
use dcfo::algorithms::pll::{Pll, PllConfig};
use dcfo::algorithms::transforms::AlphaBeta;
use dcfo::motor::MotorParams;
use dcfo::num::Angle;
use dcfo::num::units::Base;
use std::f64::consts::PI;

/// Time within which the PLL locks from any initial angle error, s. The loop starts
/// at zero speed, at its lowest bandwidth (2 pi 3 Hz), and its gains grow as it acquires
/// the 10 Hz speed. There, w_p = |omega| = 62.8 rad/s with zeta_p = 4 puts the slow
/// closed-loop pole at -0.127 w_p = -8 rad/s: going from about 1 rad of error to
/// 1 degree takes four of its 125 ms time constants, 0.5 s, after acquisition. The
/// stated bound is 0.8 s.
const LOCK_TIME_S: f64 = 0.8;

fn pll() -> Pll<f64> {
    let m = MotorParams::paper();
    Pll::new(&PllConfig::for_flux(m.psi_f_wb), m.pole_pitch_m, &Base::SI).unwrap()
}

#[test]
fn locks_from_any_initial_angle_within_the_stated_time() {
    let f_hz = 10.0;
    let w = 2.0 * PI * f_hz;
    let mut worst: f64 = 0.0;
    for start_deg in 0..360 {
        let theta0 = (start_deg as f64).to_radians();
        let mut p = pll();
        let mut last_unlocked_t = 0.0;
        let n = (1.5 / TS) as usize;
        for k in 0..n {
            let t = k as f64 * TS;
            let th = theta0 + w * t;
            let out = p.update(AlphaBeta::new(PSI_F * th.cos(), PSI_F * th.sin()), TS).unwrap();
            let err = angle_diff_deg(angle_of(th), out.theta_e).abs();
            if err > 1.0 {
                last_unlocked_t = t;
            }
        }
        worst = worst.max(last_unlocked_t);
        assert!(
            last_unlocked_t < LOCK_TIME_S,
            "start {start_deg} deg: error above 1 deg until {last_unlocked_t} s"
        );
    }
    println!("worst time to stay within 1 deg, over 360 initial angles: {worst:.4} s");
}

#[test]
fn steady_state_speed_error_below_0_1_percent_and_lock_flag() {
    let m = MotorParams::paper();
    for v in [0.1, 0.3, 0.45, 0.9, -0.3] {
        let w = PI * v / m.pole_pitch_m as f64;
        let mut p = pll();
        // Low speeds have proportionally lower PLL bandwidth: give them time.
        let settle_s = 1.5 * (0.3 / v.abs()).max(1.0);
        let n = ((settle_s + 0.2) / TS) as usize;
        let mut sum_v = 0.0;
        let mut count = 0;
        let mut locked_at_end = false;
        let mut max_angle_err: f64 = 0.0;
        for k in 0..n {
            let t = k as f64 * TS;
            let th = 1.0 + w * t;
            let out = p.update(AlphaBeta::new(PSI_F * th.cos(), PSI_F * th.sin()), TS).unwrap();
            if t >= settle_s {
                sum_v += out.speed_m_per_s;
                count += 1;
                max_angle_err = max_angle_err.max(angle_diff_deg(angle_of(th), out.theta_e).abs());
                locked_at_end = out.locked;
            }
        }
        let v_hat = sum_v / count as f64;
        let rel = ((v_hat - v) / v).abs();
        println!(
            "v = {v} m/s: mean v_hat {v_hat:.6} (rel err {rel:.2e}), max angle err {max_angle_err:.2e} deg"
        );
        assert!(rel < 1e-3, "{v}: {v_hat}");
        assert!(locked_at_end);
    }
}

#[test]
fn low_flux_coasts_and_bad_input_is_refused() {
    let mut p = pll();
    p.preset(Angle::ZERO, 62.8);
    let out = p.update(AlphaBeta::new(1e-4, 0.0), TS).unwrap();
    assert!(!out.tracking && !out.locked);
    assert_eq!(out.omega_e, 62.8, "coasts at the integrator's speed");
    assert!(p.update(AlphaBeta::new(f64::NAN, 0.0), TS).is_err());
    assert!(p.update(AlphaBeta::new(0.1, 0.0), 0.0).is_err());
}

/// The frequency integrator in Q8.24 settles on the flux's frequency (it tunes the
/// DCFO's notch, where 1 % is 0.6 deg of flux angle). Its update `w_p^2 dt eps` is about
/// 650 LSB times the phase error at 0.1 m/s on the paper motor's base: rounded down (the
/// `fixed` crate's `*`) it was biased by half an LSB a sample, and whatever the rounding,
/// phase errors below 0.00076 rad did not move it, so the loop held the frequency with
/// `kp eps` and left the integrator up to 0.6 % off (`kp` 168 rad/s). Measured: -1.2e-2 (as it was),
/// -6.0e-3 (rounded to nearest), 2e-5 to 6e-5 with the residue of
/// `dcfo::algorithms::pll::INTEGRAL_RESIDUE_SCALE`.
#[test]
fn the_fixed_point_frequency_integrator_settles_on_the_true_frequency() {
    use dcfo::num::Q24;
    let m = MotorParams::paper();
    let pu = Base::for_motor(&m);
    for v in [0.1, -0.1, 0.3, -0.3] {
        let w = PI * v / m.pole_pitch_m as f64;
        let mut p = Pll::<Q24>::new(&PllConfig::for_flux(m.psi_f_wb), m.pole_pitch_m, &pu).unwrap();
        let dt = pu.time::<Q24>(TS as f32);
        let settle_s = 1.5 * (0.3 / v.abs()).max(1.0);
        let n = ((settle_s + 0.5) / TS) as usize;
        let (mut sum, mut count) = (0.0, 0);
        for k in 0..n {
            let th = 1.0 + w * k as f64 * TS;
            let psi = AlphaBeta::new(
                pu.flux::<Q24>((PSI_F * th.cos()) as f32),
                pu.flux::<Q24>((PSI_F * th.sin()) as f32),
            );
            p.update(psi, dt).unwrap();
            if k as f64 * TS >= settle_s {
                sum += f64::from(pu.to_rad_per_s(p.omega_integral()));
                count += 1;
            }
        }
        let rel = (sum / count as f64 - w) / w.abs();
        println!(
            "v = {v} m/s: Q8.24 frequency integrator {:.4} rad/s of {w:.4} ({rel:.2e})",
            sum / count as f64
        );
        assert!(rel.abs() < 2e-4, "{v}: {rel}");
    }
}
