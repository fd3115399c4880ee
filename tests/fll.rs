//! The FLL's frequency discriminator against the band-pass analysis: exact frequency
//! whatever the notch error, in either direction, from the flux a mistuned DCFO passes.

use dcfo::algorithms::fll::{Fll, FllConfig};
use dcfo::algorithms::transforms::AlphaBeta;
use dcfo::num::units::Base;

/// The steady output of the DCFO's band-pass `D(jw) = 1 / (1 + j X)`,
/// `X = (w / w_n - w_n / w) / (2 zeta)` (SOGI gain `2 zeta`), for a flux vector
/// `psi_f e^{j theta}` rotating at `w` (negative: backwards; the real filter acts on the
/// conjugate frequency alike).
fn band_pass_output(psi_f: f64, theta: f64, w: f64, w_n: f64, zeta: f64) -> (f64, f64) {
    let x = (w.abs() / w_n - w_n / w.abs()) / (2.0 * zeta);
    let gain = 1.0 / (1.0 + x * x).sqrt();
    let phase = -x.atan() * w.signum();
    (psi_f * gain * (theta + phase).cos(), psi_f * gain * (theta + phase).sin())
}

#[test]
fn discriminator_reads_the_true_frequency_through_a_mistuned_band_pass() {
    let psi_f = 0.16;
    let dt = 1e-4;
    for w in [-400.0, -63.0, -21.0, 21.0, 63.0, 400.0] {
        for detune in [0.5, 0.8, 1.0, 1.25, 2.0] {
            let w_n: f64 = f64::abs(w) * detune;
            let config = FllConfig {
                gain_per_omega: 4.0,
                start_omega_rad_s: 2000.0,
                floor_rad_s: 10.0,
                ref_flux_wb: 0.01,
                settle_tolerance: 0.1,
                settle_guard_rad: 15.0,
            };
            let mut fll = Fll::<f64>::new(&config, &Base::SI).unwrap();
            let mut theta = 0.4;
            let mut out = None;
            for _ in 0..20_000 {
                let next = theta + w * dt;
                // As in the DCFO: the output at a sample and the integrator's increment
                // over the period that ends there (in steady state the true flux's).
                let x1 = band_pass_output(psi_f, next, w, w_n, 1.0);
                let inc = (psi_f * (next.cos() - theta.cos()), psi_f * (next.sin() - theta.sin()));
                out = Some(fll.update(AlphaBeta::new(x1.0, x1.1), AlphaBeta::new(inc.0, inc.1), dt));
                theta = next;
            }
            let o = out.unwrap();
            // Continuous time: exactly w (Re D = |D|^2). Sampled: the increment is a chord
            // centred half a sample before the output, so the band-pass phase phi is
            // read as phi + w dt / 2: relative error up to (|w| dt / 2) |tan phi|, plus the
            // chord's (w dt)^2 / 6.
            let x = (detune - 1.0 / detune) / 2.0;
            let bound = (w.abs() * dt / 2.0) * x.abs() + (w * dt).powi(2) / 6.0 + 1e-9;
            let rel = (o.omega_e - w).abs() / w.abs();
            assert!(rel <= bound, "w {w}, notch x{detune}: {} (rel {rel:.2e}, bound {bound:.2e})", o.omega_e);
            assert!((o.notch_omega - o.omega_e.abs()).abs() < 1e-6 * w.abs(), "notch {}", o.notch_omega);
            assert!(o.settled, "w {w}, notch x{detune}: not settled");
        }
    }
}

#[test]
fn without_a_flux_the_notch_sweeps_down_to_its_floor_and_never_settles() {
    let config = FllConfig {
        gain_per_omega: 4.0,
        start_omega_rad_s: 1000.0,
        floor_rad_s: 10.0,
        ref_flux_wb: 0.08,
        settle_tolerance: 0.1,
        settle_guard_rad: 15.0,
    };
    let mut fll = Fll::<f32>::new(&config, &Base::SI).unwrap();
    assert_eq!(fll.notch_omega(), 1000.0);
    let zero = AlphaBeta::new(0.0, 0.0);
    // d w_n / dt = -gain w_n^2: w_n(t) = 1 / (1 / w0 + gain t); at t = 0.02 s, 11.1 rad/s.
    let mut o = fll.update(zero, zero, 1e-4);
    for _ in 1..200 {
        o = fll.update(zero, zero, 1e-4);
    }
    let expected = 1.0 / (1.0 / 1000.0 + 4.0 * 0.02);
    assert!((o.notch_omega - expected).abs() < 0.05 * expected, "{} vs {expected}", o.notch_omega);
    for _ in 0..10_000 {
        o = fll.update(zero, zero, 1e-4);
    }
    assert_eq!(o.notch_omega, 10.0);
    assert!(!o.settled);
}

#[test]
fn bad_settings_are_refused_by_name() {
    use dcfo::algorithms::fll::FllConfigError;
    let ok = FllConfig::for_motor(0.16, 179.6, 12.6);
    assert!(Fll::<f32>::new(&ok, &Base::SI).is_ok());
    let bad = |c: FllConfig| Fll::<f32>::new(&c, &Base::SI).err();
    assert_eq!(bad(FllConfig { gain_per_omega: 0.0, ..ok }), Some(FllConfigError::BadGain));
    assert_eq!(bad(FllConfig { floor_rad_s: f32::NAN, ..ok }), Some(FllConfigError::BadRange));
    assert_eq!(bad(FllConfig { start_omega_rad_s: 1.0, ..ok }), Some(FllConfigError::BadRange));
    assert_eq!(bad(FllConfig { ref_flux_wb: -1.0, ..ok }), Some(FllConfigError::BadFlux));
    assert_eq!(bad(FllConfig { settle_tolerance: 1.0, ..ok }), Some(FllConfigError::BadTolerance));
}

/// The notch follows the frequency without the bias that noise puts on a magnitude. At
/// low speed the per-sample rotation is comparable to the noise on the increment (3.3
/// Hz on the salient example motor: 2e-3 rad a sample), and the mean of `|x + n|` for
/// `n ~ N(0, s)` exceeds `|x|`: by 17 % at `s = |x|` (`E|X| = s sqrt(2/pi)
/// e^{-x^2/2s^2} + x (1 - 2 Phi(-x/s))`). A notch that tracked `|dtheta|` sat that far
/// above the mover and the DCFO's angle lagged by `dw / (zeta w)`, 10 deg; the notch
/// now tracks the reading along the signed frequency's direction, linear in the noise.
/// At five and ten times the rotation (`rho` about 4 and 8 in the `crate::fll` docs,
/// "Noise") the notch tracking the reading along the direction only once the signed
/// frequency had reached the notch itself (`DIRECTION_SHARE_GAIN` 1) sat at 3 and 7 times
/// the mover's frequency, the high equilibrium those docs derive.
#[test]
fn noise_on_the_increment_does_not_bias_the_notch() {
    let psi_f = 0.12;
    let dt = 1e-4;
    let config = FllConfig {
        gain_per_omega: 4.0,
        start_omega_rad_s: 2000.0,
        floor_rad_s: 4.0 * std::f32::consts::PI,
        ref_flux_wb: 0.01,
        settle_tolerance: 0.1,
        settle_guard_rad: 15.0,
    };
    for (w, noise_ratio, notch_tolerance) in
        [(21.0f64, 1.0, 0.02), (-21.0, 1.0, 0.02), (21.0, 5.0, 0.06), (-21.0, 5.0, 0.06), (21.0, 10.0, 0.25)]
    {
        let mut fll = Fll::<f64>::new(&config, &Base::SI).unwrap();
        let mut theta = 0.4;
        let mut seed = 7u64;
        let mut gauss = || {
            // Box-Muller on a 64-bit LCG: deterministic.
            let mut u = || {
                seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                ((seed >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (a, b) = (u(), u());
            (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
        };
        // Noise on each component of the increment, `noise_ratio` times the per-sample
        // rotation's size.
        let sigma = noise_ratio * psi_f * w.abs() * dt;
        let mut notch_sum = 0.0;
        let mut omega_sum = 0.0;
        let n = 200_000;
        for k in 0..n {
            let next = theta + w * dt;
            let x1 = (psi_f * next.cos(), psi_f * next.sin());
            let inc = (
                psi_f * (next.cos() - theta.cos()) + sigma * gauss(),
                psi_f * (next.sin() - theta.sin()) + sigma * gauss(),
            );
            let o = fll.update(AlphaBeta::new(x1.0, x1.1), AlphaBeta::new(inc.0, inc.1), dt);
            theta = next;
            if k >= n / 2 {
                notch_sum += o.notch_omega;
                omega_sum += o.omega_e;
            }
        }
        let (notch, omega) = (notch_sum / (n / 2) as f64, omega_sum / (n / 2) as f64);
        // The signed frequency is unbiased (linear in the noise); the notch within 2 % of
        // the mover (measured: equal to |omega|, 0.7 % below w at +21 rad/s). Tracking
        // |dtheta| instead it sat 16.4 % above (24.45 rad/s), as the formula says.
        // At five and ten times the rotation (measured, notch: 20.09 and 20.48 rad/s at
        // noise 5, 24.7 at noise 10; 62.5, 62.2 and 127.9 with DIRECTION_SHARE_GAIN 1, the
        // high root (rho - 1) |w| at rho 4.0 and 7.1) two second-order effects remain:
        // the trackers' rate is scaled with the notch, which moves with the same noise
        // as the estimate it scales, so the signed frequency settles low by about its
        // variance over |w| (19.0 and 16.5 rad/s); and at ten times the signed
        // frequency's own noise crosses a quarter of the notch now and then, letting some
        // of |dtheta| back in. Neither is the fault asserted here.
        println!("w {w}, noise {noise_ratio} x the rotation: omega {omega:.3}, notch {notch:.3}");
        // The high equilibrium of the crate::fll docs ("Noise") would be at (rho - 1) |w|.
        assert!(
            (notch - w.abs()).abs() < notch_tolerance * w.abs(),
            "w {w}, noise {noise_ratio}: notch {notch}"
        );
        if noise_ratio == 1.0 {
            assert!((omega - w).abs() < 0.01 * w.abs(), "w {w}: omega {omega}");
        }
    }
}
