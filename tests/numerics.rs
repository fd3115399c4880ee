//! Each numeric function of `dcfo::num` against the accuracy its documentation states,
//! with f64/std as the independent expectation.

use dcfo::num::{Angle, Q24, Scalar, sqrt_rounded};
use std::f64::consts::PI;

/// Dense sweep of binary angles: 2^20 points plus the octant boundaries.
fn angles() -> impl Iterator<Item = Angle> {
    let step = 1i64 << 12;
    (0..(1i64 << 20))
        .map(move |k| Angle::from_bits((i32::MIN as i64 + k * step) as i32))
        .chain((0..8).map(|k| Angle::from_bits((k as u32).wrapping_mul(1 << 29) as i32)))
}

fn exact_rad(a: Angle) -> f64 {
    a.bits() as f64 * PI / 2f64.powi(31)
}

#[test]
fn cos_sin_within_2e_5_for_f32_and_q24() {
    let (mut e32, mut eq) = (0.0f64, 0.0f64);
    for a in angles() {
        let (c, s) = (exact_rad(a).cos(), exact_rad(a).sin());
        let (c32, s32) = f32::cos_sin(a);
        let (cq, sq) = Q24::cos_sin(a);
        e32 = e32.max((c32 as f64 - c).abs()).max((s32 as f64 - s).abs());
        eq = eq.max((cq.to_f32() as f64 - c).abs()).max((sq.to_f32() as f64 - s).abs());
    }
    println!("cos_sin max error: f32 {e32:.2e}, Q24 {eq:.2e}");
    assert!(e32 < 2e-5 && eq < 2e-5);
    let (c64, s64) = f64::cos_sin(Angle::from_bits(123_456_789));
    assert!((c64 - exact_rad(Angle::from_bits(123_456_789)).cos()).abs() < 1e-15);
    assert!((s64 - exact_rad(Angle::from_bits(123_456_789)).sin()).abs() < 1e-15);
}

#[test]
fn atan2_within_1_3e_5_rad_for_f32_and_q24() {
    let (mut e32, mut eq) = (0.0f64, 0.0f64);
    for a in angles().step_by(7) {
        let r = exact_rad(a);
        for mag in [1e-3, 0.16, 1.0, 50.0] {
            let (x, y) = (mag * r.cos(), mag * r.sin());
            let d32 = (<f32 as Scalar>::atan2(y as f32, x as f32) - a).to_radians::<f64>().abs();
            e32 = e32.max(d32);
            if mag < 100.0 {
                let dq = (Q24::atan2(Q24::from_f32(y as f32), Q24::from_f32(x as f32)) - a)
                    .to_radians::<f64>()
                    .abs();
                // Q24 quantises x, y to 6e-8: allow that on top of the function's error.
                eq = eq.max(dq - 6e-8 / mag);
            }
        }
    }
    println!("atan2 max error: f32 {e32:.2e} rad, Q24 {eq:.2e} rad (beyond input quantisation)");
    assert!(e32 < 1.3e-5 && eq < 1.3e-5);
    assert_eq!(<f32 as Scalar>::atan2(0.0, 0.0), Angle::ZERO);
    assert_eq!(<f32 as Scalar>::atan2(f32::NAN, 1.0), Angle::ZERO);
}

#[test]
fn sqrt_accuracy_f32_relative_4e_7_q24_one_lsb() {
    let mut worst = 0.0f64;
    let mut x = 1e-30f32;
    while x < 1e30 {
        let r = x.sqrt() as f64; // std's correctly rounded sqrt as reference
        let got = Scalar::sqrt(x) as f64;
        worst = worst.max(((got - r) / r).abs());
        x *= 1.013;
    }
    println!("f32 sqrt worst relative error {worst:.2e}");
    assert!(worst < 4e-7);
    assert_eq!(Scalar::sqrt(-1.0f32), 0.0);
    assert!(Scalar::sqrt(f32::NAN).is_nan());
    // Every pattern of the sweep, and around every even power of two (where the
    // normalisation's shift changes) and every perfect square up to 2^12 LSB: within
    // one LSB above the exact root's floor, on the raw bits (25 significant bits do not
    // survive a trip through f32).
    let around_powers = (0..31).flat_map(|k| [-2i64, -1, 0, 1, 2].map(|d| (1i64 << k) + d));
    let around_squares = (1..4096i64).flat_map(|r| [-1, 0, 1].map(|d| r * r + d));
    let patterns = q24_sweep()
        .chain(around_powers.chain(around_squares).filter_map(|b| i32::try_from(b).ok().filter(|&b| b > 0)));
    for bits in patterns {
        let got = i64::from(Scalar::sqrt(Q24::from_bits(bits)).to_bits());
        let floor = (bits as f64 * 2f64.powi(24)).sqrt().floor() as i64;
        assert!(got == floor || got == floor + 1, "{bits}: {got} LSB against the floor {floor}");
    }
    assert_eq!(Scalar::sqrt(Q24::ZERO), Q24::ZERO);
    assert_eq!(Scalar::sqrt(Q24::from_f32(-2.0)), Q24::ZERO);
}

/// `sqrt_rounded` is IEEE 754's square root (std's, correctly rounded) bit for bit: a
/// stride through every positive `f32` (subnormals, every exponent's parity), the
/// extremes, and the special values. (Every positive `f32` was checked once.)
#[test]
fn sqrt_rounded_is_the_correctly_rounded_root_bit_for_bit() {
    let patterns = (1..0x7f80_0000u32)
        .step_by(4_099)
        .chain((0..64).flat_map(|k| [k, 0x7f_ffff - k, 0x80_0000 + k, 0x7f7f_ffff - k, 0x3f80_0000 + k]));
    for bits in patterns {
        let x = f32::from_bits(bits);
        assert_eq!(sqrt_rounded(x).to_bits(), x.sqrt().to_bits(), "sqrt({x:e})");
    }
    for x in [0.0f32, -0.0, f32::INFINITY] {
        assert_eq!(sqrt_rounded(x).to_bits(), x.sqrt().to_bits(), "sqrt({x})");
    }
    for x in [-1.0f32, -f32::MIN_POSITIVE, f32::NEG_INFINITY, f32::NAN] {
        assert!(sqrt_rounded(x).is_nan(), "sqrt({x})");
    }
}

#[test]
fn radians_to_angle_wraps_and_round_trips() {
    for k in -2000..2000 {
        let r = k as f64 * 0.0123;
        let expected = r.rem_euclid(2.0 * PI);
        let expected = if expected >= PI { expected - 2.0 * PI } else { expected };
        let a64 = r.radians_to_angle();
        assert!((exact_rad(a64) - expected).abs() < 1e-8, "f64 {r}");
        let a32 = (r as f32).radians_to_angle();
        let d = (a32 - a64).to_radians::<f64>().abs();
        assert!(d < 2e-6 * (1.0 + r.abs()), "f32 {r}: {d}");
        if r.abs() < 100.0 {
            let aq = Q24::from_f32(r as f32).radians_to_angle();
            let d = (aq - a64).to_radians::<f64>().abs();
            assert!(d < 1e-6, "Q24 {r}: {d}");
        }
    }
    // Round trip through radians.
    for bits in (i32::MIN..i32::MAX).step_by(33_554_467) {
        let a = Angle::from_bits(bits);
        assert!((f64::angle_to_radians(a).radians_to_angle() - a).bits().abs() <= 1);
        assert!(
            (Q24::angle_to_radians(a).radians_to_angle() - a).bits().abs() < 200,
            "Q24 LSB is 6e-8 rad = 41 counts"
        );
    }
}

#[test]
fn angle_arithmetic_wraps_exactly() {
    let a = Angle::from_bits(i32::MAX - 10);
    let b = Angle::from_bits(20);
    assert_eq!((a + b).bits(), i32::MIN + 9);
    assert_eq!((Angle::HALF_TURN - Angle::ZERO).to_degrees_f64(), -180.0);
    assert_eq!((-Angle::QUARTER_TURN).to_degrees_f64(), -90.0);
}

#[test]
fn q24_saturates_and_reports_it() {
    let big = Q24::from_f32(100.0);
    assert!(big.is_valid());
    let sum = big + big;
    assert!(!sum.is_valid(), "saturated sum must be reported");
    assert_eq!(sum.to_f32(), 128.0 - 2f32.powi(-24));
    assert!(!(big * big).is_valid());
    assert!(!(-(big + big)).is_valid());
    assert_eq!(Q24::from_f32(f32::NAN), Q24::ZERO);
    assert_eq!(Q24::ONE.checked_div(Q24::ZERO), None);
    assert_eq!(Q24::from_f32(100.0).checked_div(Q24::from_f32(0.5)), None, "200 is out of range");
    assert_eq!(Q24::from_f32(3.0).checked_div(Q24::from_f32(2.0)), Some(Q24::from_f32(1.5)));
    for (c, x) in [
        (Q24::HALF, 0.5),
        (Q24::ONE_THIRD, 1.0 / 3.0),
        (Q24::INV_SQRT3, 1.0 / 3f64.sqrt()),
        (Q24::SQRT3_HALF, 3f64.sqrt() / 2.0),
    ] {
        assert!((c.to_f32() as f64 - x).abs() <= 2f64.powi(-24));
    }
}

/// Every Q24 bit pattern in a dense sweep (plus the extremes), against f64.
fn q24_sweep() -> impl Iterator<Item = i32> {
    (1..i32::MAX).step_by(65_537).chain([
        1,
        2,
        3,
        0x7f,
        1 << 23,
        1 << 24,
        (1 << 24) + 1,
        i32::MAX - 1,
        i32::MAX,
    ])
}

#[test]
fn recip_accuracy_floats_rounded_q24_one_lsb() {
    let lsb = 2f64.powi(-24);
    let mut worst_lsb = 0.0f64;
    for bits in q24_sweep() {
        let x = bits as f64 * lsb;
        let exact = 1.0 / x;
        for sign in [1, -1] {
            let got = Scalar::recip(Q24::from_bits(sign * bits));
            if exact >= 128.0 - 4.0 * lsb {
                // Beyond (or at the edge of) the range: refused, never a wrong number.
                if let Some(g) = got {
                    assert!((g.to_bits() as f64 * lsb).abs() >= 127.9, "{bits}");
                }
                continue;
            }
            let Some(got) = got else { panic!("1/{x} refused") };
            let err = (got.to_bits() as f64 * lsb - sign as f64 * exact).abs();
            // The quotient rounded towards zero: less than one LSB off, never beyond.
            assert!(err < lsb, "1/{x}: error {err:e} of an LSB {lsb:e}");
            worst_lsb = worst_lsb.max(err / lsb);
        }
    }
    println!("Q24 recip worst error {worst_lsb:.2} LSB");
    assert_eq!(Scalar::recip(Q24::ZERO), None);
    assert_eq!(Scalar::recip(0.0f32), None);
    assert_eq!(Scalar::recip(4.0f32), Some(0.25));
    assert_eq!(Scalar::recip(-8.0f64), Some(-0.125));
}

#[test]
fn recip_count_floats_rounded_q24_within_half_an_lsb() {
    let lsb = 2f64.powi(-24);
    let counts = (1..100_000u32).chain((0..32).map(|k| 1u32 << k)).chain([3 << 24, u32::MAX - 1, u32::MAX]);
    let mut worst_lsb = 0.0f64;
    for n in counts {
        let exact = 1.0 / f64::from(n);
        let got = Q24::recip_count(n).to_bits() as f64 * lsb;
        // Rounded to nearest: at most half an LSB off (a tie rounds up).
        assert!((got - exact).abs() <= 0.5 * lsb, "1/{n}: {got} for {exact}");
        worst_lsb = worst_lsb.max((got - exact).abs() / lsb);
        assert_eq!(f32::recip_count(n), 1.0 / n as f32, "{n}");
        assert_eq!(f64::recip_count(n), exact, "{n}");
    }
    println!("Q24 recip_count worst error {worst_lsb:.3} LSB");
    assert_eq!(Q24::recip_count(0).to_bits(), i32::MAX);
    assert_eq!(f32::recip_count(0), f32::INFINITY);
}

#[test]
fn inv_sqrt_accuracy_f32_4e_7_q24_one_lsb_plus_2e_9_relative() {
    let lsb = 2f64.powi(-24);
    let mut worst_rel = 0.0f64;
    for bits in q24_sweep() {
        let x = bits as f64 * lsb;
        let exact = 1.0 / x.sqrt();
        let got = Scalar::inv_sqrt(Q24::from_bits(bits));
        if exact >= 128.0 - 4.0 * lsb {
            assert!(got.is_none_or(|g| g.to_bits() as f64 * lsb >= 127.9), "{bits}");
            continue;
        }
        let Some(got) = got else { panic!("1/sqrt({x}) refused") };
        let err = (got.to_bits() as f64 * lsb - exact).abs();
        assert!(err <= lsb + exact * 2e-9, "1/sqrt({x}): error {err:e}");
        worst_rel = worst_rel.max(err / exact);
    }
    println!("Q24 inv_sqrt worst relative error {worst_rel:.2e}");
    let mut worst = 0.0f64;
    let mut x = 1e-30f32;
    while x < 1e30 {
        let exact = 1.0 / (x as f64).sqrt();
        let got = Scalar::inv_sqrt(x).expect("positive") as f64;
        worst = worst.max(((got - exact) / exact).abs());
        x *= 1.013;
    }
    println!("f32 inv_sqrt worst relative error {worst:.2e}");
    assert!(worst < 4e-7);
    for bad in [0.0f32, -1.0, f32::NAN, f32::INFINITY] {
        assert_eq!(Scalar::inv_sqrt(bad), None, "{bad}");
    }
    assert_eq!(Scalar::inv_sqrt(Q24::ZERO), None);
    assert_eq!(Scalar::inv_sqrt(Q24::from_f32(-1.0)), None);
}

/// `Q24::from_f32` reads the float's bits itself (no panicking path in the images): it
/// must round and saturate exactly as `fixed`'s `saturating_from_num` (to nearest, ties
/// to even), with NaN as 0. Every exponent, with the fractions that decide a rounding
/// (the rounding bit and its neighbours, ties, all ones) and a stride through the rest.
#[test]
fn q24_from_f32_is_fixed_saturating_from_num_bit_for_bit() {
    use fixed::types::I8F24;
    let mut checked = 0u64;
    let mut check = |bits: u32| {
        let x = f32::from_bits(bits);
        let got = Q24::from_f32(x).to_bits();
        if x.is_nan() {
            assert_eq!(got, 0, "{bits:#x}");
        } else {
            assert_eq!(got, I8F24::saturating_from_num(x).to_bits(), "{x:e} ({bits:#x})");
        }
        checked += 1;
    };
    for sign in [0u32, 1 << 31] {
        for exponent in 0u32..=0xFF {
            let head = sign | exponent << 23;
            for k in 0..23 {
                for fraction in [1u32 << k, (1 << k) - 1, (1 << k) + 1, (1 << k) | 1 << 22, 3 << k >> 1] {
                    check(head | (fraction & 0x7F_FFFF));
                }
            }
            for fraction in (0..0x80_0000u32).step_by(997) {
                check(head | fraction);
            }
            check(head | 0x7F_FFFF);
        }
    }
    for x in
        [0.5f32 / 16_777_216.0, 1.5 / 16_777_216.0, 2.5 / 16_777_216.0, 127.99999, -128.0, 128.0, -128.00002]
    {
        check(x.to_bits());
    }
    assert!(checked > 4_000_000);
}

#[test]
fn q24_mul_nearest_is_within_half_an_lsb_and_unbiased() {
    // Against the exact product (f64 holds a 48-bit product exactly): never more than
    // half an LSB off (ties up), saturating outside the range; and, unlike `*` (which
    // rounds down), no bias over many products: the mean error of `*` is -1/2 LSB.
    let lsb = 2f64.powi(-24);
    let mut n = 0u64;
    let (mut sum_nearest, mut sum_floor) = (0.0f64, 0.0f64);
    let mut seed = 0x2545_f491u32;
    let (max, min) = (f64::from(i32::MAX) * lsb, -128.0);
    for a in q24_sweep().flat_map(|a| [a, -a]) {
        for _ in 0..4 {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            // Second factors spread over [-2, 2): products within the range mostly.
            let b = Q24::from_bits((seed as i32) >> 5);
            let x = Q24::from_bits(a);
            let exact = f64::from(a) * lsb * (f64::from(b.to_bits()) * lsb);
            let got = f64::from(x.mul_nearest(b).to_bits()) * lsb;
            if exact > max {
                assert_eq!(got, max, "{a} x {}", b.to_bits());
            } else if exact < min {
                assert_eq!(got, min, "{a} x {}", b.to_bits());
            } else {
                assert!((got - exact).abs() <= 0.5 * lsb, "{a} x {}: {got} vs {exact}", b.to_bits());
                sum_nearest += (got - exact) / lsb;
                sum_floor += (f64::from((x * b).to_bits()) * lsb - exact) / lsb;
                n += 1;
            }
        }
    }
    assert!(n > 10_000, "{n} products");
    let (mean_nearest, mean_floor) = (sum_nearest / n as f64, sum_floor / n as f64);
    assert!(mean_nearest.abs() < 0.01, "mean error {mean_nearest} LSB");
    assert!((mean_floor + 0.5).abs() < 0.01, "`*` mean error {mean_floor} LSB");
}

#[test]
fn q24_product_is_fixed_saturating_mul_bit_for_bit() {
    // `*` on Q24 is one SMULL and a range check; it must equal the `fixed` crate's
    // saturating product (floor of the exact product, saturated) for every operand pair:
    // the sweep against itself and against pseudo-random factors of every magnitude,
    // including both extremes and the products that just reach or just leave the range.
    use fixed::types::I8F24;
    let mut seed = 0x9e37_79b9u32;
    let mut n = 0u64;
    let mut saturated = 0u64;
    let mut check = |a: i32, b: i32| {
        let want = I8F24::from_bits(a).saturating_mul(I8F24::from_bits(b)).to_bits();
        let got = (Q24::from_bits(a) * Q24::from_bits(b)).to_bits();
        assert_eq!(got, want, "{a} x {b}");
        n += 1;
        if want == i32::MAX || want == i32::MIN {
            saturated += 1;
        }
    };
    let operands: Vec<i32> = q24_sweep().flat_map(|a| [a, -a]).chain([0, i32::MIN, i32::MIN + 1]).collect();
    for &a in &operands {
        for shift in 0..32 {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let b = (seed as i32) >> shift;
            check(a, b);
            check(b, a);
        }
        // Factors around the product's edge of range: 2^31 / |a| (in Q24) and its neighbours.
        if a != 0 && a != i32::MIN {
            let edge = (1i64 << 55) / i64::from(a.unsigned_abs());
            for d in -2..=2 {
                if let Ok(b) = i32::try_from(edge + d) {
                    check(a, b);
                    check(a, -b);
                }
            }
        }
    }
    assert!(n > 2_000_000, "{n} products");
    assert!(saturated > 100_000, "{saturated} saturated products");
}

#[test]
fn q24_mul_unit_equals_the_saturating_product_for_factors_up_to_one() {
    // `mul_unit` skips the range check: with |k| <= 1 the product cannot leave the range,
    // so it must equal `*` there, for every value including the extremes.
    let mut seed = 0x1234_5678u32;
    let mut n = 0u64;
    let one = 1i32 << 24;
    for a in q24_sweep().flat_map(|a| [a, -a]).chain([0, i32::MIN + 1]) {
        for k in [one, -one, 0, 1, -1, one - 1, -(one - 1)] {
            let (x, k) = (Q24::from_bits(a), Q24::from_bits(k));
            assert_eq!(x.mul_unit(k), x * k, "{a} x {}", k.to_bits());
            n += 1;
        }
        for _ in 0..16 {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let k = Q24::from_bits(((seed as i32) >> 7).clamp(-one, one));
            let x = Q24::from_bits(a);
            assert_eq!(x.mul_unit(k), x * k, "{a} x {}", k.to_bits());
            n += 1;
        }
    }
    assert!(n > 500_000, "{n} products");
    // The floats: the product itself.
    assert_eq!(3.0f32.mul_unit(-0.5), -1.5);
    assert_eq!(3.0f64.mul_unit(0.25), 0.75);
}

#[test]
fn q24_division_is_fixed_checked_div_bit_for_bit() {
    // Q24's checked_div divides 56 by 32 bits with two hardware divisions; it must equal
    // the `fixed` crate's checked division (64-bit, rounded towards zero, None on zero or
    // overflow) for every operand pair: the sweep against pseudo-random divisors of every
    // magnitude, both signs, the extremes, and divisors at the edge of overflow.
    use fixed::types::I8F24;
    let mut seed = 0x0bad_5eedu32;
    let (mut n, mut none) = (0u64, 0u64);
    let mut check = |a: i32, b: i32| {
        let want = I8F24::from_bits(a).checked_div(I8F24::from_bits(b)).map(I8F24::to_bits);
        let got = Q24::from_bits(a).checked_div(Q24::from_bits(b)).map(Q24::to_bits);
        assert_eq!(got, want, "{a} / {b}");
        n += 1;
        none += u64::from(want.is_none());
    };
    let operands: Vec<i32> =
        q24_sweep().flat_map(|a| [a, -a]).chain([0, i32::MIN, i32::MIN + 1, -1]).collect();
    for &a in &operands {
        for shift in 0..32 {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let b = (seed as i32) >> shift;
            check(a, b);
            check(b, a);
        }
        for b in [0, 1, -1, 2, 1 << 24, -(1 << 24), i32::MAX, i32::MIN, i32::MIN + 1] {
            check(a, b);
        }
        // Divisors around |a| 2^24 / 2^31, where the quotient leaves the range.
        let edge = (i64::from(a.unsigned_abs()) << 24) >> 31;
        for d in -2..=2 {
            if let Ok(b) = i32::try_from(edge + d) {
                check(a, b);
                check(a, b.wrapping_neg());
            }
        }
    }
    assert!(n > 2_000_000, "{n} divisions");
    assert!(none > 50_000, "{none} refused divisions");
}

#[test]
fn decay_within_5e_6_relative_to_16_and_1e_5_to_87() {
    for (top, bound) in [(16.0f32, 5e-6), (87.0, 1e-5)] {
        let mut worst = 0.0f64;
        for i in 0..=1_000_000 {
            let x = top * i as f32 * 1e-6;
            let exact = (-f64::from(x)).exp();
            let got = f64::from(dcfo::num::decay(x));
            worst = worst.max((got / exact - 1.0).abs());
        }
        eprintln!("decay: worst relative error {worst:.2e} over [0, {top}]");
        assert!(worst < bound, "worst relative error {worst:e} over [0, {top}]");
    }
    // Outside the domain: 1 at and below zero and for NaN, 0 far out, never negative.
    assert_eq!(dcfo::num::decay(0.0), 1.0);
    assert_eq!(dcfo::num::decay(-3.0), 1.0);
    assert_eq!(dcfo::num::decay(f32::NAN), 1.0);
    assert_eq!(dcfo::num::decay(90.0), 0.0);
    assert_eq!(dcfo::num::decay(f32::INFINITY), 0.0);
}

/// `unit_ratio` against the exact quotient limited to [-1, 1]: floats correctly rounded,
/// Q24 within the 1e-4 its documentation states, over divisors across Q24's range and
/// numerators across each (both signs, and beyond the divisor: limited), with 0 for a
/// divisor that is not positive.
#[test]
fn unit_ratio_floats_rounded_q24_within_1e_4() {
    let mut worst = 0.0f64;
    for d in q24_sweep().step_by(7) {
        for k in 0..=64 {
            // Numerators from -1.25 d to 1.25 d.
            let n = i64::from(d) * (k - 32) * 5 / 128;
            let Ok(n) = i32::try_from(n) else { continue };
            let exact = (f64::from(n) / f64::from(d)).clamp(-1.0, 1.0);
            let q = Q24::from_bits(n).unit_ratio(Q24::from_bits(d)).to_f32() as f64;
            worst = worst.max((q - exact).abs());
            let (nf, df) = (n as f32 * 2f32.powi(-24), d as f32 * 2f32.powi(-24));
            let expected = ((nf / df) as f64).clamp(-1.0, 1.0) as f32;
            assert_eq!(nf.unit_ratio(df), expected, "f32 {nf} / {df}");
        }
    }
    println!("unit_ratio: Q24 worst error {worst:.2e}");
    assert!(worst <= 1e-4, "Q24 unit_ratio off by {worst:.2e}");
    for d in [0, -1, i32::MIN] {
        assert_eq!(Q24::ONE.unit_ratio(Q24::from_bits(d)), Q24::ZERO, "divisor {d}");
    }
    assert_eq!(1.0f32.unit_ratio(0.0), 0.0);
    assert_eq!(1.0f32.unit_ratio(f32::NAN), 0.0);
    assert_eq!(Q24::from_bits(i32::MIN).unit_ratio(Q24::from_bits(1)), -Q24::ONE);
    assert_eq!(Q24::from_bits(i32::MAX).unit_ratio(Q24::from_bits(i32::MAX)), Q24::ONE);
}

/// `from_turns` against `(turns + fraction / 2^32) * per_turn` in f64: Q24 within 1 LSB
/// of the exact product of its operands and saturated beyond the range; f32 the f32
/// expression bit for bit.
#[test]
fn from_turns_q24_within_one_lsb_and_saturating() {
    let lsb = 2f64.powi(-24);
    for per_turn in [0.002f32, 0.04, 0.1, -0.04, 3.0] {
        let p = Q24::from_f32(per_turn);
        let p_exact = f64::from(p.to_bits()) * lsb;
        for turns in [-40, -3, -1, 0, 1, 7, 39] {
            for fraction in [0u32, 1, 1 << 31, 0x1234_5678, u32::MAX] {
                let exact = (f64::from(turns) + f64::from(fraction) / 4_294_967_296.0) * p_exact;
                let q = f64::from(Q24::from_turns(turns, fraction, p).to_bits()) * lsb;
                assert!(
                    (q - exact).abs() <= lsb,
                    "{turns} + {fraction}/2^32 turns of {per_turn}: {q} vs {exact}"
                );
                let f = (turns as f32 + fraction as f32 * (1.0 / 4_294_967_296.0)) * per_turn;
                assert_eq!(f32::from_turns(turns, fraction, per_turn).to_bits(), f.to_bits());
            }
        }
    }
    let p = Q24::from_f32(1.0);
    assert_eq!(Q24::from_turns(200, 0, p), Q24::from_bits(i32::MAX), "saturated up");
    assert_eq!(Q24::from_turns(-200, 0, p), Q24::from_bits(i32::MIN), "saturated down");
    assert_eq!(Q24::from_turns(-200, u32::MAX, p), Q24::from_bits(i32::MIN), "saturated down, a fraction on");
}

/// `lead_turns` against `(reference - counts / 2^32) * per_turn` in f64: Q24 within 1 LSB
/// of the exact lead of the reference rounded towards zero to 2^-16 of a turn, and
/// saturated beyond the range; f32 the f32 expression bit for bit.
#[test]
fn lead_turns_q24_within_one_lsb_of_the_rounded_reference_and_saturating() {
    let lsb = 2f64.powi(-24);
    let count = |turns: f64| (turns * 4_294_967_296.0).floor() as i64;
    for per_turn in [0.002f32, 0.14, 3.0, -0.5] {
        let p = Q24::from_f32(per_turn);
        let p_exact = f64::from(p.to_bits()) * lsb;
        for reference in [-37.3f32, -1.0, -0.2, 0.0, 1e-4, 0.75, 12.5, 300.1] {
            for estimate in [-36.9f64, -0.21, 0.0, 0.7512, 12.0, 299.9] {
                let counts = count(estimate);
                let rounded = (f64::from(reference) * 65_536.0).trunc() / 65_536.0;
                let exact = (rounded - counts as f64 / 4_294_967_296.0) * p_exact;
                let q = f64::from(Q24::lead_turns(reference, counts, p).to_bits()) * lsb;
                let expected = exact.clamp(-128.0, 128.0 - lsb);
                assert!(
                    (q - expected).abs() <= lsb,
                    "{reference} turns over {estimate} at {per_turn}: {q} vs {expected}"
                );
                let c = (counts >> 32) as i32 as f32 + (counts as u32) as f32 * (1.0 / 4_294_967_296.0);
                let f = (reference - c) * per_turn;
                assert_eq!(f32::lead_turns(reference, counts, per_turn).to_bits(), f.to_bits());
            }
        }
    }
    let p = Q24::from_f32(1.0);
    assert_eq!(Q24::lead_turns(1e9, 0, p), Q24::from_bits(i32::MAX), "saturated up");
    assert_eq!(Q24::lead_turns(0.0, i64::MAX, p), Q24::from_bits(i32::MIN), "saturated down");
    assert_eq!(Q24::lead_turns(f32::NAN, count(2.0), p), Q24::from_f32(-2.0), "NaN reads as 0");
}

/// `checked_div_pair`: floats are `checked_div` of each, bit for bit; Q24 within
/// `(1 + |x|)` LSB of the exact quotient of each numerator `x` where `1 / rhs` is
/// representable, and `checked_div` of each where it is not (a divisor under 1/128).
#[test]
fn checked_div_pair_floats_exact_q24_within_one_plus_x_lsb() {
    let lsb = 2f64.powi(-24);
    for d in q24_sweep().step_by(5) {
        let rhs = Q24::from_bits(d);
        for (a, b) in [(1, -1), (1 << 24, -(3 << 22)), (123_456_789, -987_654), (i32::MAX, i32::MIN + 1)] {
            let (x, y) = (Q24::from_bits(a), Q24::from_bits(b));
            let (qx, qy) = x.checked_div_pair(y, rhs);
            if rhs.recip().is_none() {
                assert_eq!((qx, qy), (x.checked_div(rhs), y.checked_div(rhs)), "divisor {d}");
                continue;
            }
            for (n, q) in [(a, qx), (b, qy)] {
                let exact = f64::from(n) / f64::from(d);
                if exact.abs() >= 127.0 {
                    continue;
                }
                let q = q.expect("a representable quotient");
                let bound = (1.0 + (f64::from(n) * lsb).abs()) * lsb;
                let err = (f64::from(q.to_bits()) * lsb - exact).abs();
                assert!(err <= bound, "{n} / {d}: error {err:.3e} over {bound:.3e}");
            }
        }
    }
    for (a, b, d) in [(1.0f32, -3.0f32, 7.0f32), (0.25, 1e6, 1e-3), (1.0, 1.0, 0.0)] {
        assert_eq!(a.checked_div_pair(b, d), (a.checked_div(d), b.checked_div(d)));
    }
}
