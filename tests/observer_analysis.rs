//! The flux observers measured against the analysis of docs/method.md §2-3, in f64.
//!
//! Each test drives the discrete observer with synthetic inputs whose true mover flux is
//! known exactly, and compares what it measures with a closed-form expectation.

mod common;

use common::*;
use dcfo::algorithms::observer::{
    Dcfo, DcfoConfig, FluxObserver, LpfObserver, ObserverMotor, PureIntegrator,
};
use dcfo::motor::MotorParams;
use dcfo::num::units::Base;
use std::f64::consts::PI;

/// The default notch damping under test (the analysis holds for any zeta > 0, h < 0).
fn zeta() -> f64 {
    DcfoConfig::default().zeta as f64
}

/// The default h / (Ls w) under test.
fn eta_h() -> f64 {
    DcfoConfig::default().h_per_ls_omega as f64
}

fn motor() -> ObserverMotor<f64> {
    ObserverMotor::new(&MotorParams::paper(), &Base::SI)
}

fn dcfo() -> Dcfo<f64> {
    let cfg = DcfoConfig::default();
    Dcfo::new(motor(), &cfg, &Base::SI).unwrap()
}

/// The DCFO's H(s) = psi_hat / x (docs/method.md §3) at s = j w_eval, notch at w,
/// h = eta Ls w.
fn h_analytic(w_eval: f64, w: f64) -> (f64, f64) {
    let h = eta_h() * LS * w;
    // s = j we: s^2 = -we^2, s^3 = -j we^3
    let we = w_eval;
    let num = (-(2.0 * zeta() * w * LS) * we * we, 0.0);
    let den = (-(2.0 * zeta() * w * LS - h) * we * we - h * w * w, -LS * we * we * we + w * w * LS * we);
    let mag = (num.0.hypot(num.1)) / den.0.hypot(den.1);
    let ph = num.1.atan2(num.0) - den.1.atan2(den.0);
    (mag, ph)
}

/// Runs `obs` over `synthetic` with the notch at `w`; returns (estimates, true flux,
/// harmonic flux) over whole fundamental periods after `settle_s`.
fn run(
    obs: &mut impl FluxObserver<f64>,
    syn: &Synthetic,
    w: f64,
    settle_s: f64,
    periods: usize,
) -> Vec<([f64; 2], [f64; 2], f64)> {
    let n_settle = (settle_s / TS).round() as usize;
    let n_period = 2.0 * PI / syn.omega / TS;
    let n_total = n_settle + (periods as f64 * n_period).round() as usize;
    let mut out = Vec::new();
    for k in 0..n_total {
        let (u, i, t) = syn.sample(k, TS);
        let est = obs.update(&input_f64(u, i, w, TS)).unwrap();
        if k >= n_settle {
            out.push(([est.psi_ab.alpha, est.psi_ab.beta], syn.psi_f_ab(t), t));
        }
    }
    out
}

/// Settling time that leaves the slowest observer pole (0.26 w for the defaults) at e^-30.
fn settle_for(w: f64) -> f64 {
    30.0 / (0.26 * w)
}

#[test]
fn dcfo_unity_gain_and_zero_phase_at_the_fundamental_from_2_to_50_hz() {
    println!("f_Hz   gain_err_%     phase_err_deg");
    for f in [2.0, 3.0, 5.0, 10.0, 15.0, 20.0, 30.0, 50.0] {
        let mut syn = Synthetic::at_hz(f);
        syn.i_q = 0.0;
        let w = syn.omega;
        let mut obs = dcfo();
        let rows = run(&mut obs, &syn, w, settle_for(w), 10);
        let out: Vec<_> = rows.iter().map(|r| r.0).collect();
        let truth: Vec<_> = rows.iter().map(|r| r.1).collect();
        let (g, ph) = complex_ratio(&out, &truth);
        println!("{f:5.1}  {:+.3e}  {:+.3e}", (g - 1.0) * 100.0, ph.to_degrees());
        assert!((g - 1.0).abs() < 1e-3, "{f} Hz: gain {g}");
        assert!(ph.to_degrees().abs() < 0.1, "{f} Hz: phase {} deg", ph.to_degrees());
    }
}

#[test]
fn dcfo_dc_flux_offset_is_attenuated_by_more_than_60_db() {
    for f in [2.0, 10.0, 50.0] {
        let mut syn = Synthetic::at_hz(f);
        syn.i_q = 0.0;
        let w = syn.omega;
        let x0 = [0.1, -0.05]; // Wb, a step of DC flux at t = 0 (an impulse of voltage)
        let mut obs = dcfo();
        let n_settle = (settle_for(w) / TS) as usize;
        let n_period = (2.0 * PI / w / TS).round() as usize;
        let mut sum = [0.0; 2];
        let mut count = 0;
        for k in 0..n_settle + 10 * n_period {
            let (mut u, i, t) = syn.sample(k, TS);
            if k == 0 {
                u[0] += x0[0] / TS;
                u[1] += x0[1] / TS;
            }
            let est = obs.update(&input_f64(u, i, w, TS)).unwrap();
            if k >= n_settle {
                let truth = syn.psi_f_ab(t);
                sum[0] += est.psi_ab.alpha - truth[0];
                sum[1] += est.psi_ab.beta - truth[1];
                count += 1;
            }
        }
        let mean = [sum[0] / count as f64, sum[1] / count as f64];
        let ratio = mean[0].hypot(mean[1]) / x0[0].hypot(x0[1]);
        let db = 20.0 * ratio.log10();
        println!("{f} Hz: DC gain {db:.1} dB");
        assert!(db < -60.0, "{f} Hz: DC attenuation only {db:.1} dB");
    }
}

#[test]
fn dcfo_harmonic_gain_at_5w_and_7w_matches_the_transfer_function() {
    for f in [5.0, 10.0, 20.0] {
        for &n in &[-5.0, 7.0, -11.0, 13.0] {
            let mut syn = Synthetic::at_hz(f);
            syn.i_q = 0.0;
            syn.psi_f = 0.0; // linear: measure the harmonic alone
            syn.harmonics = [(n, 5.0), (0.0, 0.0)];
            let w = syn.omega;
            let mut obs = dcfo();
            let n_settle = (settle_for(w) / TS) as usize;
            let n_period = (2.0 * PI / w / TS).round() as usize;
            let mut out = Vec::new();
            let mut reference = Vec::new();
            for k in 0..n_settle + 10 * n_period {
                let (u, i, t) = syn.sample(k, TS);
                let est = obs.update(&input_f64(u, i, w, TS)).unwrap();
                if k >= n_settle {
                    out.push([est.psi_ab.alpha, est.psi_ab.beta]);
                    // the harmonic's flux: amplitude a/(|n| w), rotating at n w
                    let wn = n * w;
                    reference.push([5.0 / wn * (wn * t).sin(), -5.0 / wn * (wn * t).cos()]);
                }
            }
            let (g, _) = complex_ratio(&out, &reference);
            let (g_expected, _) = h_analytic(n.abs() * w, w);
            println!("{f} Hz, n = {n}: |H| measured {g:.4}, analytic {g_expected:.4}");
            assert!((g / g_expected - 1.0).abs() < 0.10, "{f} Hz n={n}: {g} vs {g_expected}");
        }
    }
}

/// The drift tests of the issue: +2 V on u_alpha and +0.2 A on i_beta at 10 Hz.
fn dc_step_case(u_offset: [f64; 2], i_offset: [f64; 2]) {
    let mut syn = Synthetic::at_hz(10.0);
    syn.u_offset = u_offset;
    syn.i_offset = i_offset;
    syn.offset_from_s = 1.0;
    let w = syn.omega;
    let mut pi = PureIntegrator::new(motor());
    pi.set_stator_flux(dcfo::algorithms::transforms::AlphaBeta::new(syn.psi_s(0.0)[0], syn.psi_s(0.0)[1]));
    let mut obs = dcfo();
    let n = (4.0 / TS) as usize;
    let mut pi_err_at = Vec::new();
    let mut dcfo_err_last_period: f64 = 0.0;
    let mut psi_i_max: f64 = 0.0;
    let mut psi_i_max_last_s: f64 = 0.0;
    let mut psi_i_offset_sum = [0.0; 2];
    let mut count = 0;
    let n_period = (0.1 / TS) as usize;
    for k in 0..n {
        let (u, i, t) = syn.sample(k, TS);
        let inp = input_f64(u, i, w, TS);
        let truth = syn.psi_f_ab(t);
        let e_pi = pi.update(&inp).unwrap().psi_ab;
        let e_d = obs.update(&inp).unwrap().psi_ab;
        let psi_i = obs.integrator_state();
        if (k + 1) % (5000) == 0 {
            pi_err_at.push((e_pi.alpha - truth[0]).hypot(e_pi.beta - truth[1]));
        }
        if k >= n - n_period {
            dcfo_err_last_period =
                dcfo_err_last_period.max((e_d.alpha - truth[0]).hypot(e_d.beta - truth[1]));
            psi_i_offset_sum[0] += psi_i.alpha - truth[0];
            psi_i_offset_sum[1] += psi_i.beta - truth[1];
            count += 1;
        }
        psi_i_max = psi_i_max.max(psi_i.alpha.hypot(psi_i.beta));
        if t > 3.0 {
            psi_i_max_last_s = psi_i_max_last_s.max(psi_i.alpha.hypot(psi_i.beta));
        }
    }
    // Pure integrator: the error grows at every checkpoint after the step, without bound.
    println!("pure integrator |error| every 0.5 s: {pi_err_at:?}");
    for pair in pi_err_at[2..].windows(2) {
        assert!(pair[1] > pair[0] * 1.1, "pure integrator should keep drifting: {pi_err_at:?}");
    }
    // Equivalent DC voltage on the integrator input: the voltage offset less Rs times
    // the current offset. In equilibrium the feedback cancels it, (h/Ls) d = -dc, and
    // psi_hat has no DC, so psi_i carries the whole of d = dc Ls / |h| (the -Ls i step
    // of a current offset is absorbed by the integrator).
    let dc = [u_offset[0] - RS * i_offset[0], u_offset[1] - RS * i_offset[1]];
    let h_over_ls = eta_h() * w;
    let expected_offset = [-dc[0] / h_over_ls, -dc[1] / h_over_ls];
    let measured_offset = [psi_i_offset_sum[0] / count as f64, psi_i_offset_sum[1] / count as f64];
    println!(
        "DCFO: max |error| over the last 0.1 s {:.3e} Wb; integrator offset {:?} (analysis {:?}); max |psi_i| {psi_i_max:.4} Wb (last second {psi_i_max_last_s:.4})",
        dcfo_err_last_period, measured_offset, expected_offset
    );
    assert!(dcfo_err_last_period < 1e-3, "DCFO error {dcfo_err_last_period}");
    for ax in 0..2 {
        assert!(
            (measured_offset[ax] - expected_offset[ax]).abs() < 1e-3,
            "{measured_offset:?} vs {expected_offset:?}"
        );
    }
    // Bounded: in steady state |psi_i| <= psi_f + |dc Ls / h| (the flux plus the offset).
    let bound = PSI_F + expected_offset[0].hypot(expected_offset[1]) + 1e-3;
    assert!(psi_i_max_last_s < bound, "integrator state {psi_i_max_last_s} above {bound}");
}

#[test]
fn dc_step_of_2_volts_on_u_alpha_pure_integrator_drifts_dcfo_recovers() {
    dc_step_case([2.0, 0.0], [0.0, 0.0]);
}

#[test]
fn dc_step_of_0_2_amperes_on_i_beta_pure_integrator_drifts_dcfo_recovers() {
    dc_step_case([0.0, 0.0], [0.0, 0.2]);
}

/// The DCFO's flux error after a DC step, in closed form (`dcfo::algorithms::observer::dcfo`, "DC
/// steps: the transient"): an equivalent DC voltage `du` (V) and a flux step `dpsi` (Wb)
/// on one axis from t = 0 give, on that axis,
/// `e(s) = 2 zeta w (du + s dpsi) / (s^3 + (2 zeta - eta) w s^2 + w^2 s - eta w^3)`.
/// Returns `e(t)` at `times` (s): the impulse response of that transfer function, in
/// controllable canonical form, integrated by RK4 at 1 us (the slowest pole is tens of
/// ms), independent of the discrete observer.
fn dc_step_error_analytic(z: f64, eta: f64, du: f64, dpsi: f64, w: f64, times: &[f64]) -> Vec<f64> {
    let a = [-eta * w * w * w, w * w, (2.0 * z - eta) * w]; // a0, a1, a2
    let c = [2.0 * z * w * du, 2.0 * z * w * dpsi, 0.0];
    let f = |x: [f64; 3]| [x[1], x[2], -a[0] * x[0] - a[1] * x[1] - a[2] * x[2]];
    let h = 1e-6;
    let mut x = [0.0, 0.0, 1.0];
    let mut t = 0.0;
    let mut out = Vec::with_capacity(times.len());
    for &target in times {
        while t + 0.5 * h < target {
            let k1 = f(x);
            let k2 = f(std::array::from_fn(|i| x[i] + 0.5 * h * k1[i]));
            let k3 = f(std::array::from_fn(|i| x[i] + 0.5 * h * k2[i]));
            let k4 = f(std::array::from_fn(|i| x[i] + h * k3[i]));
            x = std::array::from_fn(|i| x[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]));
            t += h;
        }
        out.push(c[0] * x[0] + c[1] * x[1] + c[2] * x[2]);
    }
    out
}

/// The paper's DC steps at 10 Hz (+2 V on u_alpha; +0.2 A on i_beta, which the
/// observer sees as `-Rs 0.2` V and a `-Ls 0.2` Wb flux step): the discrete observer's
/// flux error follows the closed form over the first half second, within 1 % of its
/// peak. The peak over `psi_f` is the largest angle error the step can cause (the flux at
/// right angles to the disturbed axis): what no loop after the observer can take back.
/// For the default tuning and for the narrower band-pass the module docs compare it with.
#[test]
fn dcfo_dc_step_transient_follows_its_closed_form() {
    for (z, eta, label, u_offset, i_offset, axis, du, dpsi, peak_deg) in [
        (zeta(), eta_h(), "+2 V on u_alpha", [2.0, 0.0], [0.0, 0.0], 0, 2.0, 0.0, 17.0),
        (zeta(), eta_h(), "+0.2 A on i_beta", [0.0, 0.0], [0.0, 0.2], 1, -RS * 0.2, -LS * 0.2, 8.4),
        (0.5, -0.3, "+2 V on u_alpha", [2.0, 0.0], [0.0, 0.0], 0, 2.0, 0.0, 9.9),
        (0.5, -0.3, "+0.2 A on i_beta", [0.0, 0.0], [0.0, 0.2], 1, -RS * 0.2, -LS * 0.2, 4.9),
    ] {
        let label = format!("zeta {z:.1}, eta_h {eta:.1}, {label}");
        let mut syn = Synthetic::at_hz(10.0);
        syn.u_offset = u_offset;
        syn.i_offset = i_offset;
        let t_step = settle_for(syn.omega);
        syn.offset_from_s = t_step;
        let w = syn.omega;
        let config = DcfoConfig { zeta: z as f32, h_per_ls_omega: eta as f32, ..DcfoConfig::default() };
        let mut obs = Dcfo::new(motor(), &config, &Base::SI).unwrap();
        let n_step = (t_step / TS).round() as usize;
        let n = n_step + (0.5 / TS) as usize;
        let (mut times, mut measured) = (Vec::new(), Vec::new());
        for k in 0..n {
            let (u, i, t) = syn.sample(k, TS);
            let est = obs.update(&input_f64(u, i, w, TS)).unwrap().psi_ab;
            if k >= n_step {
                let e = [est.alpha - syn.psi_f_ab(t)[0], est.beta - syn.psi_f_ab(t)[1]];
                times.push(t - t_step);
                measured.push(e[axis]);
            }
        }
        let analytic = dc_step_error_analytic(z, eta, du, dpsi, w, &times);
        let peak = analytic.iter().fold(0.0f64, |m, e| m.max(e.abs()));
        let deviation = measured.iter().zip(&analytic).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        let peak_measured = measured.iter().fold(0.0f64, |m, e| m.max(e.abs()));
        // The largest angle a vector of length `peak` added to the flux can turn it by.
        let angle_deg = (peak / PSI_F).asin().to_degrees();
        println!(
            "{label}: peak flux error {peak:.5} Wb analytic, {peak_measured:.5} measured (largest deviation {deviation:.2e} Wb); worst-phase angle {angle_deg:.1} deg"
        );
        assert!(deviation < 0.01 * peak, "{label}: {deviation} Wb off a {peak} Wb peak");
        assert!((angle_deg - peak_deg).abs() < 0.1, "{label}: {angle_deg} deg, documented {peak_deg}");
    }
}

#[test]
fn lpf_observer_lead_and_gain_match_atan_wc_over_w() {
    for (f, wc) in [(2.0, 5.0), (10.0, 15.7), (10.0, 62.8), (50.0, 31.4)] {
        let mut syn = Synthetic::at_hz(f);
        syn.i_q = 0.0;
        let w = syn.omega;
        let mut obs = LpfObserver::new(motor(), wc).unwrap();
        let rows = run(&mut obs, &syn, w, 30.0 / wc, 10);
        let out: Vec<_> = rows.iter().map(|r| r.0).collect();
        let truth: Vec<_> = rows.iter().map(|r| r.1).collect();
        let (g, ph) = complex_ratio(&out, &truth);
        let g_expected = w / (w * w + wc * wc).sqrt();
        let lead_expected = (wc / w).atan();
        println!(
            "{f} Hz, wc {wc}: gain {g:.5} (expected {g_expected:.5}), lead {:.4} deg (expected {:.4})",
            ph.to_degrees(),
            lead_expected.to_degrees()
        );
        assert!((g / g_expected - 1.0).abs() < 1e-3);
        assert!((ph - lead_expected).to_degrees().abs() < 0.05);
    }
}

/// The DCFO with its radial feedback armed (`Dcfo::set_magnitude_feedback`).
fn armed_dcfo() -> Dcfo<f64> {
    let mut o = dcfo();
    o.set_magnitude_feedback(1.0);
    o
}

/// The radial feedback acts on the flux magnitude's deviation from its mean, which a
/// mover turning at a steady speed does not have, with the notch on the mover or 10 %
/// off it (the band-pass then scales and turns the flux, at a constant magnitude): the
/// armed observer's estimate is the paper's. What is left (1.4e-5 rad at most) is the
/// mean's own settling from the cold start's first flux, at a tenth of `w`.
#[test]
fn dcfo_radial_feedback_leaves_the_steady_state_untouched() {
    for (f_hz, notch_share) in [(10.0, 1.0), (10.0, 0.9), (10.0, 1.1), (3.3, 1.0), (40.0, 1.0)] {
        let syn = Synthetic::at_hz(f_hz);
        let w = syn.omega * notch_share;
        let settle = settle_for(w);
        let plain = run(&mut dcfo(), &syn, w, settle, 3);
        let armed = run(&mut armed_dcfo(), &syn, w, settle, 3);
        let worst = plain.iter().zip(&armed).fold(0.0f64, |m, (p, a)| {
            let turn = (a.0[1] * p.0[0] - a.0[0] * p.0[1]).atan2(a.0[0] * p.0[0] + a.0[1] * p.0[1]);
            m.max(turn.abs())
        });
        println!("{f_hz} Hz, notch at {notch_share}: {worst:.2e} rad apart");
        assert!(worst < 1e-4, "{f_hz} Hz, notch at {notch_share} of it: {worst} rad apart");
    }
}

/// The paper's DC steps at 10 Hz, at 16 phases of the flux: the largest angle error of
/// the armed observer is the linear model's (`docs/dc_step_analysis.py`, section 5, the
/// continuous-time observer with the same feedback: 11.65 deg for +2 V and 5.73 for
/// +0.2 A, against 17.1 and 8.5 without it) within 0.2 deg (0.05 measured): the discrete observer and
/// the model agree, and the feedback takes a third off the step's transient.
#[test]
fn dcfo_radial_feedback_shortens_the_dc_step_transient_as_the_linear_model_says() {
    for (label, u_offset, i_offset, model_deg) in [
        ("+2 V on u_alpha", [2.0, 0.0], [0.0, 0.0], 11.65),
        ("+0.2 A on i_beta", [0.0, 0.0], [0.0, 0.2], 5.73),
    ] {
        let mut worst = 0.0f64;
        for k in 0..16 {
            let mut syn = Synthetic::at_hz(10.0);
            syn.u_offset = u_offset;
            syn.i_offset = i_offset;
            let period = 2.0 * PI / syn.omega;
            let t_step = settle_for(syn.omega) + period * k as f64 / 16.0;
            syn.offset_from_s = t_step;
            let mut obs = armed_dcfo();
            let n = ((t_step + 0.5) / TS).round() as usize;
            for j in 0..n {
                let (u, i, t) = syn.sample(j, TS);
                let est = obs.update(&input_f64(u, i, syn.omega, TS)).unwrap().psi_ab;
                if t >= t_step {
                    let truth = syn.psi_f_ab(t);
                    let turn = (est.beta * truth[0] - est.alpha * truth[1])
                        .atan2(est.alpha * truth[0] + est.beta * truth[1]);
                    worst = worst.max(turn.abs().to_degrees());
                }
            }
        }
        println!("{label}: {worst:.2} deg at the worst of 16 phases (linear model {model_deg})");
        assert!((worst - model_deg).abs() < 0.2, "{label}: {worst} deg, the model says {model_deg}");
    }
}
