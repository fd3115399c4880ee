//! f32 and fixed point (Q8.24, per-unit) against the f64 reference: the same DCFO + PLL
//! source run three times on one synthetic trace.

mod common;

use common::*;
use dcfo::algorithms::observer::{Dcfo, DcfoConfig, FluxObserver, ObserverMotor};
use dcfo::algorithms::pll::{Pll, PllConfig};
use dcfo::motor::MotorParams;
use dcfo::num::units::Base;
use dcfo::num::{Angle, Q24, Scalar};

/// DCFO + PLL in type T, the PLL's frequency integrator tuning the notch (as in the drive).
struct Chain<T> {
    base: Base,
    obs: Dcfo<T>,
    pll: Pll<T>,
    max_abs_state: f64,
}

impl<T: Scalar> Chain<T> {
    /// `omega0`: the speed the PLL starts from (rad/s), as a drive hands over from
    /// open-loop start-up at a known speed; the angle starts at zero either way.
    fn new(base: Base, omega0: f32) -> Self {
        let m = MotorParams::paper();
        let mut pll = Pll::new(&PllConfig::for_flux(m.psi_f_wb), m.pole_pitch_m, &base).unwrap();
        pll.preset(Angle::ZERO, base.omega(omega0));
        Chain {
            base,
            obs: Dcfo::new(ObserverMotor::new(&m, &base), &DcfoConfig::default(), &base).unwrap(),
            pll,
            max_abs_state: 0.0,
        }
    }

    /// One sample; returns the angle estimate. Panics on any fault (none is expected).
    fn step(&mut self, syn: &Synthetic, k: usize) -> Angle {
        let notch = self.base.to_rad_per_s(self.pll.omega_integral()) as f64;
        let (input, _) = syn.input::<T>(k, TS, notch, &self.base);
        let est = self.obs.update(&input).expect("observer fault");
        let out = self.pll.update(est.psi_ab, input.dt).expect("pll fault");
        let psi_i = self.obs.integrator_state();
        for x in [psi_i.alpha, psi_i.beta, est.psi_ab.alpha, est.psi_ab.beta, out.omega_e] {
            assert!(x.is_valid(), "saturated or non-finite state");
            self.max_abs_state = self.max_abs_state.max(x.to_f32().abs() as f64);
        }
        out.theta_e
    }
}

/// Runs the three chains; returns (max |f32 - f64|, max |Q24 - f64|) in degrees over
/// the samples after `compare_from_s`, and the largest |working value| seen in Q24.
fn compare(syn: &Synthetic, duration_s: f64, compare_from_s: f64, omega0: f32) -> (f64, f64, f64) {
    let pu = Base::for_motor(&MotorParams::paper());
    let mut reference = Chain::<f64>::new(Base::SI, omega0);
    let mut single = Chain::<f32>::new(Base::SI, omega0);
    let mut fixed = Chain::<Q24>::new(pu, omega0);
    let (mut d32, mut dq) = (0.0f64, 0.0f64);
    for k in 0..(duration_s / TS) as usize {
        let a64 = reference.step(syn, k);
        let a32 = single.step(syn, k);
        let aq = fixed.step(syn, k);
        if k as f64 * TS >= compare_from_s {
            d32 = d32.max(angle_diff_deg(a32, a64).abs());
            dq = dq.max(angle_diff_deg(aq, a64).abs());
            // and the reference itself is locked on the truth
            let truth = angle_of(syn.theta((k + 1) as f64 * TS));
            assert!(angle_diff_deg(a64, truth).abs() < 5.0, "reference not locked at {} s", k as f64 * TS);
        }
    }
    (d32, dq, fixed.max_abs_state)
}

fn realistic(f_hz: f64, i_q: f64) -> Synthetic {
    let mut syn = Synthetic::at_hz(f_hz);
    syn.i_q = i_q;
    // Dead-time-like 5th and 7th voltage harmonics and a small offset.
    syn.harmonics = [(-5.0, 3.0), (7.0, 2.0)];
    syn.u_offset = [0.4, -0.3];
    syn
}

#[test]
fn f32_and_fixed_point_track_the_f64_reference_at_10_hz() {
    let m = MotorParams::paper();
    let rated_peak = m.rated_current_a as f64 * 2f64.sqrt();
    // From a cold start (speed and angle unknown).
    let (d32, dq, _) = compare(&realistic(10.0, rated_peak), 3.0, 1.5, 0.0);
    println!(
        "10 Hz, rated current: max |theta_f32 - theta_f64| = {d32:.2e} deg, max |theta_Q24 - theta_f64| = {dq:.2e} deg"
    );
    assert!(d32 <= 0.05, "f32 deviates {d32} deg");
    assert!(dq <= 0.2, "Q24 deviates {dq} deg");
}

#[test]
fn no_saturation_at_twice_rated_current_and_twice_top_speed() {
    let m = MotorParams::paper();
    let two_rated_peak = 2.0 * m.rated_current_a as f64 * 2f64.sqrt();
    // 2x the paper's top speed, 0.45 m/s -> 0.9 m/s = 30 Hz.
    let f_hz = m.omega_e_from_speed(0.9) as f64 / (2.0 * std::f64::consts::PI);
    // Started at the speed (as after an open-loop start-up), angle unknown.
    let omega0 = m.omega_e_from_speed(0.9);
    let (d32, dq, max_pu) = compare(&realistic(f_hz, two_rated_peak), 2.0, 1.0, omega0);
    println!(
        "{f_hz:.1} Hz, 2x rated current: f32 {d32:.2e} deg, Q24 {dq:.2e} deg; largest Q24 working value {max_pu:.3} (range 128)"
    );
    assert!(d32 <= 0.05);
    assert!(dq <= 0.2);
    assert!(max_pu < 8.0, "margin to the Q8.24 range is below 16x");
}
