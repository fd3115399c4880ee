//! Property tests: transforms, SVPWM and the PI controller, in f64, f32 and Q24.

use dcfo::algorithms::pi::Pi;
use dcfo::algorithms::svpwm::svpwm;
use dcfo::algorithms::transforms::*;
use dcfo::num::{Angle, Q24, Scalar};
use proptest::prelude::*;

/// Relative tolerances of the checks, per type. Results are read back through f32, so
/// even f64 gets 2e-7; f32 and Q24 carry the 2e-5 cos/sin error (twice for a Park round
/// trip) and, for Q24, a few 6e-8 LSBs.
const REL_F64: f64 = 2e-7;
const REL_F32: f64 = 5e-5;
const REL_Q24: f64 = 5e-5;

fn round_trips<T: Scalar>(a: f64, b: f64, c: f64, theta_bits: i32, rel: f64) -> Result<(), TestCaseError> {
    let conv = |x: f64| T::from_f32(x as f32);
    let back = |x: T| x.to_f32() as f64;
    let mag = a.abs().max(b.abs()).max(c.abs()).max(1e-3);
    let tol = |_: ()| rel * mag + 2e-7;
    // Balanced set: remove the common mode so inverse Clarke can restore it.
    let m = (a + b + c) / 3.0;
    let abc = Abc { a: conv(a - m), b: conv(b - m), c: conv(c - m) };
    let restored = inverse_clarke(clarke(abc));
    for (x, y) in [(abc.a, restored.a), (abc.b, restored.b), (abc.c, restored.c)] {
        prop_assert!((back(x) - back(y)).abs() <= tol(()), "clarke {} vs {}", back(x), back(y));
    }
    let two = clarke_two_phase(abc.a, abc.b);
    let full = clarke(abc);
    prop_assert!((back(two.beta) - back(full.beta)).abs() <= 2.0 * tol(()));
    let cs = CosSin::<T>::new(Angle::from_bits(theta_bits));
    let ab = AlphaBeta::new(conv(a), conv(b));
    let ab2 = inverse_park(park(ab, &cs), &cs);
    prop_assert!((back(ab.alpha) - back(ab2.alpha)).abs() <= 2.0 * tol(()));
    prop_assert!((back(ab.beta) - back(ab2.beta)).abs() <= 2.0 * tol(()));
    // Park preserves length.
    let dq = park(ab, &cs);
    let l1 = back(ab.alpha).hypot(back(ab.beta));
    let l2 = back(dq.d).hypot(back(dq.q));
    prop_assert!((l1 - l2).abs() <= 2.0 * tol(()));
    Ok(())
}

fn svpwm_props<T: Scalar>(ua: f64, ub: f64, vdc: f64, rel: f64) -> Result<(), TestCaseError> {
    let conv = |x: f64| T::from_f32(x as f32);
    let back = |x: T| x.to_f32() as f64;
    let m = svpwm(AlphaBeta::new(conv(ua), conv(ub)), conv(vdc)).unwrap();
    let d = [back(m.duties.a), back(m.duties.b), back(m.duties.c)];
    for x in d {
        prop_assert!((0.0..=1.0).contains(&x), "duty {x}");
    }
    let vmax = vdc / 3f64.sqrt();
    let mag = ua.hypot(ub);
    let t = 4.0 * rel * vdc;
    if mag <= vmax * (1.0 - 1e-4) {
        prop_assert!(!m.limited);
        // Line voltages from the duties equal those of the command.
        let p = inverse_clarke(AlphaBeta::new(ua, ub));
        prop_assert!(((d[0] - d[1]) * vdc - (p.a - p.b)).abs() <= t);
        prop_assert!(((d[1] - d[2]) * vdc - (p.b - p.c)).abs() <= t);
    } else if mag > vmax * (1.0 + 1e-4) {
        prop_assert!(m.limited);
        // Magnitude limited to Vdc/sqrt(3), angle kept.
        let (a, b) = (back(m.u_applied.alpha), back(m.u_applied.beta));
        prop_assert!((a.hypot(b) - vmax).abs() <= t);
        let dth = (b.atan2(a) - ub.atan2(ua) + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI)
            - std::f64::consts::PI;
        prop_assert!(dth.abs() < 1e-4);
        let p = inverse_clarke(AlphaBeta::new(a, b));
        prop_assert!(((d[0] - d[1]) * vdc - (p.a - p.b)).abs() <= t);
    }
    Ok(())
}

fn pi_props<T: Scalar>(kp: f64, ki_dt: f64, lim: f64, errors: &[f64]) -> Result<(), TestCaseError> {
    let conv = |x: f64| T::from_f32(x as f32);
    let back = |x: T| x.to_f32() as f64;
    let mut pi = Pi::new(conv(kp), conv(ki_dt), conv(-lim), conv(lim)).unwrap();
    for &e in errors {
        let u = back(pi.update(conv(e)));
        // 1e-6 relative for float rounding, 1e-7 absolute for Q24's 6e-8 LSB.
        prop_assert!(u.abs() <= lim * (1.0 + 1e-6) + 1e-7, "output {u} outside +-{lim}");
    }
    // Saturate hard for a long time, then reverse the error: no windup means the output
    // leaves the limit on the very first reversed sample.
    // Large enough that the proportional term alone saturates, whatever ki is.
    let e_sat = 10.0 * lim / kp;
    for _ in 0..1000 {
        pi.update(conv(e_sat));
    }
    let u_sat = back(pi.update(conv(e_sat)));
    prop_assert!((u_sat - lim).abs() <= lim * 1e-6 + 1e-7, "not saturated: {u_sat}");
    let small = lim * 1e-2;
    let u = back(pi.update(conv(-small)));
    prop_assert!(u < lim - kp * small * 0.5, "still saturated after reversal: {u}");
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn transforms_round_trip(a in -50.0..50.0f64, b in -50.0..50.0f64, c in -50.0..50.0f64, th in any::<i32>()) {
        round_trips::<f64>(a, b, c, th, REL_F64)?;
        round_trips::<f32>(a, b, c, th, REL_F32)?;
        round_trips::<Q24>(a / 50.0, b / 50.0, c / 50.0, th, REL_Q24)?;
    }

    #[test]
    fn svpwm_duties_and_line_voltages(ua in -400.0..400.0f64, ub in -400.0..400.0f64, vdc in 24.0..600.0f64) {
        svpwm_props::<f64>(ua, ub, vdc, REL_F64)?;
        svpwm_props::<f32>(ua, ub, vdc, REL_F32)?;
        // per-unit for fixed point: bus up to 3.3 pu
        svpwm_props::<Q24>(ua / 180.0, ub / 180.0, vdc / 180.0, REL_Q24)?;
    }

    #[test]
    fn pi_stays_in_limits_and_recovers_without_windup(
        kp in 0.01..10.0f64, ki_dt in 0.0..0.5f64, lim in 0.1..10.0f64,
        errors in proptest::collection::vec(-100.0..100.0f64, 1..200),
    ) {
        pi_props::<f64>(kp, ki_dt, lim, &errors)?;
        pi_props::<f32>(kp, ki_dt, lim, &errors)?;
        // Fixed point works in per-unit: limits up to 1, saturating errors below 128.
        let scaled: Vec<f64> = errors.iter().map(|e| e / 20.0).collect();
        pi_props::<Q24>(kp.max(0.1), ki_dt, lim / 10.0, &scaled)?;
    }
}

#[test]
fn svpwm_refuses_bad_bus_and_command() {
    assert!(svpwm(AlphaBeta::new(1.0f32, 0.0), 0.0).is_err());
    assert!(svpwm(AlphaBeta::new(1.0f32, 0.0), f32::NAN).is_err());
    assert!(svpwm(AlphaBeta::new(f32::INFINITY, 0.0), 300.0).is_err());
}

#[test]
fn pi_preset_is_bumpless() {
    let mut pi = Pi::new(2.0f64, 0.1, -10.0, 10.0).unwrap();
    pi.preset(3.5, 0.25);
    assert!((pi.update(0.25) - (3.5 + 0.1 * 0.25)).abs() < 1e-12);
    assert!(Pi::new(-1.0f64, 0.1, -1.0, 1.0).is_err());
    assert!(Pi::new(1.0f64, 0.1, 1.0, -1.0).is_err());
}
