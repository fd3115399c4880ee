//! Numbers and units: one [`Scalar`] trait, three implementations, the binary [`Angle`], and
//! the working [`units`].
//!
//! The control algorithms are written once, generic over `T: Scalar`:
//! - `f32` for Cortex-M4F (single-precision FPU);
//! - [`Q24`], a saturating fixed-point number with 24 fractional bits, for FPU-less
//!   Cortex-M3/M0+ (used with the per-unit system of [`crate::num::units`]);
//! - `f64` on the host, as the reference the other two are tested against.
//!
//! Why a trait and generics rather than macros or a type alias chosen by a feature:
//! one source text is type-checked for all three types in every build, the host tests
//! instantiate all three side by side in one binary, and monomorphisation leaves no
//! run-time cost. The trait is deliberately small: ring operations, a guarded
//! division, a square root, validity, and the angle functions. Constants needed in
//! per-sample code are associated constants or fields formed by the constructors: a
//! conversion from `f32` (a routine in fixed point) runs in the control step only for a
//! value the step forms in `f32` (the positioning drive's profile, at the speed loop's
//! divided rate).
//!
//! Angles are not `Scalar`s: an [`Angle`] is a 32-bit binary angle (a full turn is
//! 2^32), so wrapping is exact and free, and phase accumulation never loses
//! resolution however long the drive runs.
//!
//! # Layer
//! The ground floor, beside [`crate::motor`]: [`units`] imports the motor's parameters
//! (for [`units::Base::for_motor`]) and nothing else of the crate; the rest imports
//! nothing of the crate at all; [`checksum`] is the bytes' CRC of the link and the records.

pub mod checksum;
pub mod units;

use core::ops::{Add, Mul, Neg, Sub};
use fixed::types::I8F24;

/// A real number type the control algorithms run on. See the module docs.
///
/// Arithmetic operators never panic: for [`Q24`] they saturate, for floats they follow
/// IEEE 754. [`Scalar::is_valid`] tells a usable value from NaN/inf (floats) or a
/// saturated one (fixed point), so the algorithms can turn overflow into a fault.
pub trait Scalar:
    Copy
    + PartialEq
    + PartialOrd
    + Default
    + core::fmt::Debug
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Neg<Output = Self>
{
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// 2.
    const TWO: Self;
    /// 1/2.
    const HALF: Self;
    /// 1/3.
    const ONE_THIRD: Self;
    /// 1/√3.
    const INV_SQRT3: Self;
    /// √3/2.
    const SQRT3_HALF: Self;

    /// Converts from `f32`, saturating at the type's range; NaN gives 0. For
    /// configuration and I/O only: on an FPU-less core it is a software conversion.
    fn from_f32(x: f32) -> Self;
    /// Converts to `f32` (telemetry, tests).
    fn to_f32(self) -> f32;
    /// Absolute value (saturating for fixed point).
    fn abs(self) -> Self;
    /// The smaller of two values, by comparison (no library call on FPv4).
    fn min(self, other: Self) -> Self {
        if other < self { other } else { self }
    }
    /// The larger of two values, by comparison (no library call on FPv4).
    fn max(self, other: Self) -> Self {
        if other > self { other } else { self }
    }
    /// `self * rhs` rounded to the nearest representable value (ties up), saturating:
    /// the floats' product itself; for [`Q24`] the 64-bit product rounded, where `*`
    /// rounds down (the `fixed` crate's product). Rounding down is a bias of half an LSB
    /// per product, which a running mean over thousands of samples accumulates to
    /// thousands of LSB; rounded to nearest, the errors average out. One 32 x 32 -> 64
    /// multiplication (`SMULL` on Cortex-M3 and M4), an add and a shift.
    fn mul_nearest(self, rhs: Self) -> Self {
        self * rhs
    }
    /// `self * k` for a factor of magnitude at most one (`|k| <= 1`: a cosine, a sine, a
    /// constant below one), where the product cannot leave the range (`|self k| <=
    /// |self|`): the same value as `self * k`, and for [`Q24`] one `SMULL` and a shift
    /// with no saturation check. The caller proves `|k| <= 1`; a larger `k` gives a
    /// wrong (wrapped) fixed-point result, never a panic (host builds with debug
    /// assertions check the bound).
    fn mul_unit(self, k: Self) -> Self {
        self * k
    }
    /// `(turns + fraction / 2^32) * per_turn`: a whole number of turns and a fraction of
    /// one (in `2^-32` of a turn, a binary angle's steps) scaled by `per_turn` (a
    /// position from an unwrapped angle). Accuracy: floats as the `f32` expression
    /// (`turns` and `fraction` each rounded to 24 bits, then two roundings); [`Q24`]
    /// exact to within 1 LSB, saturated at the type's range, in integers (one `SMULL`
    /// and one `UMULL`, where the `f32` expression is two conversions and two products
    /// in software on Cortex-M3).
    fn from_turns(turns: i32, fraction: u32, per_turn: Self) -> Self {
        let turns_f32 = turns as f32 + fraction as f32 * (1.0 / 4_294_967_296.0);
        Self::from_f32(turns_f32 * per_turn.to_f32())
    }
    /// `(reference_turns - counts / 2^32) * per_turn`: the lead of a position given in
    /// turns over one counted in `2^-32` of a turn (an unwrapped binary angle), scaled by
    /// `per_turn` (a position loop's command from its reference and its estimate).
    /// Accuracy: floats as the `f32` expression (the count rounded to 24 bits, as
    /// [`Scalar::from_turns`]); [`Q24`] the reference rounded towards zero to `2^-16` of
    /// a turn and limited to `2^15` turns, the difference in integers and
    /// [`Scalar::from_turns`] of it: within 1 LSB of the lead of the rounded reference,
    /// saturated at the type's range, with one soft-float product and one conversion on
    /// Cortex-M3 where the `f32` expression takes three conversions, two products and two
    /// sums.
    fn lead_turns(reference_turns: f32, counts: i64, per_turn: Self) -> Self {
        let counts_f32 = (counts >> 32) as i32 as f32 + (counts as u32) as f32 * (1.0 / 4_294_967_296.0);
        Self::from_f32((reference_turns - counts_f32) * per_turn.to_f32())
    }
    /// `self` limited to `[lo, hi]`; returns `lo` if `lo > hi` would otherwise apply.
    fn clamp_to(self, lo: Self, hi: Self) -> Self {
        self.min(hi).max(lo)
    }
    /// Square root of `max(self, 0)`. Accuracy: `f64` correctly rounded; `f32` within
    /// 4e-7 relative; [`Q24`] within 1 LSB (2^-24).
    fn sqrt(self) -> Self;
    /// `self / rhs`, or `None` when `rhs` is zero or the quotient is not representable
    /// (infinite, NaN, or outside the fixed-point range). [`Q24`] rounds towards zero;
    /// on Cortex-M3 two hardware divisions and a few corrections.
    fn checked_div(self, rhs: Self) -> Option<Self>;
    /// `self / rhs` and `other / rhs` ([`Scalar::checked_div`] each): two quotients by one
    /// divisor. Floats: two correctly rounded divisions (a division is one instruction on
    /// an FPU). [`Q24`]: one reciprocal of `rhs` and two products, each within `(1 + |x|)`
    /// LSB of the quotient of `x` (the reciprocal within 1 LSB, the product rounded
    /// down), where two exact quotients take four hardware divisions and their
    /// corrections; the exact quotients where `1 / rhs` is out of range.
    fn checked_div_pair(self, other: Self, rhs: Self) -> (Option<Self>, Option<Self>) {
        (self.checked_div(rhs), other.checked_div(rhs))
    }
    /// `self / rhs` limited to `[-1, 1]`, for `rhs > 0` (0 otherwise): the share of a
    /// span, a linear blend's weight. Accuracy: floats correctly rounded (one division);
    /// [`Q24`] within 1e-4 absolute, by one 32-bit hardware division of the operands
    /// normalised to the divisor's leading bit (a 16-bit quotient), where
    /// [`Scalar::checked_div`]'s exact quotient takes two and their corrections.
    fn unit_ratio(self, rhs: Self) -> Self {
        // A NaN divisor passes, and its quotient is not representable: 0 too.
        if rhs <= Self::ZERO {
            return Self::ZERO;
        }
        self.checked_div(rhs).map_or(Self::ZERO, |x| x.clamp_to(-Self::ONE, Self::ONE))
    }
    /// `1 / self`, or `None` when `self` is zero or the result is not representable.
    /// Accuracy: floats correctly rounded (one division); [`Q24`] within 1 LSB
    /// (the quotient rounded towards zero: [`Scalar::checked_div`] of one by `self`).
    fn recip(self) -> Option<Self>;
    /// `1 / n` for a count `n >= 1`: a running mean's weight. Accuracy: floats correctly
    /// rounded (one division); [`Q24`] rounded to nearest (within half an LSB), by one
    /// 32-bit integer division (`UDIV` on Cortex-M3, where `1.0 / n as f32` is two
    /// soft-float calls). `n = 0` gives the largest value (`1 / 0` saturated; the floats'
    /// infinity).
    fn recip_count(n: u32) -> Self;
    /// `1 / sqrt(self)` for `self > 0`; `None` for `self <= 0`, NaN, or a result out of
    /// range. Accuracy: `f64` correctly rounded sqrt then division; `f32` within 4e-7
    /// relative (micromath seed, three Newton steps); [`Q24`] within 1 LSB plus 2e-9
    /// relative (the square root's normalised mantissa, then one 64-by-32-bit division
    /// in two hardware divisions; no bit-serial square root).
    fn inv_sqrt(self) -> Option<Self>;
    /// `true` for a usable number: finite (floats), not saturated (fixed point).
    fn is_valid(self) -> bool;
    /// Cosine and sine of a binary angle. Accuracy: `f64` correctly rounded (libm);
    /// `f32` and [`Q24`] within 2e-5 absolute (idsp 0.23's table cossin: measured max
    /// 1.87e-5, which includes a deliberate amplitude bias of 1.35e-5 at the axes).
    fn cos_sin(angle: Angle) -> (Self, Self);
    /// Four-quadrant arctangent of `y / x` as a binary angle; `(0, 0)` gives 0.
    /// Accuracy: `f64` correctly rounded; `f32` and [`Q24`] within 1.3e-5 rad (idsp).
    fn atan2(y: Self, x: Self) -> Angle;
    /// An angle of `self` radians, wrapped to one turn. Exact to the binary angle's
    /// resolution for `f64`; to `f32` rounding (6e-8 relative) for `f32`; to 1 LSB of
    /// [`Q24`] for fixed point.
    fn radians_to_angle(self) -> Angle;
    /// The angle in radians, in `[-π, π)`.
    fn angle_to_radians(angle: Angle) -> Self;
}

/// A binary angle: `bits / 2^31 * π` radians, wrapping modulo one turn.
///
/// `i32::MIN` is `-π`; a full turn is 2^32 counts, so one count is 1.46e-9 rad.
/// Addition and subtraction wrap, which is exactly angle arithmetic.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Angle(i32);

impl Angle {
    /// Zero radians.
    pub const ZERO: Angle = Angle(0);
    /// `π/2` radians.
    pub const QUARTER_TURN: Angle = Angle(1 << 30);
    /// `-π` radians (the same angle as `+π`).
    pub const HALF_TURN: Angle = Angle(i32::MIN);

    /// The angle whose binary representation is `bits` (`2^31` counts = π rad).
    pub const fn from_bits(bits: i32) -> Self {
        Angle(bits)
    }
    /// The binary representation (`2^31` counts = π rad).
    pub const fn bits(self) -> i32 {
        self.0
    }
    /// An angle of `radians` rad, wrapped (convenience for [`Scalar::radians_to_angle`]).
    pub fn from_radians<T: Scalar>(radians: T) -> Self {
        radians.radians_to_angle()
    }
    /// The angle in radians, in `[-π, π)`.
    pub fn to_radians<T: Scalar>(self) -> T {
        T::angle_to_radians(self)
    }
    /// The angle in degrees, in `[-180, 180)`, as `f32` (for reports).
    pub fn to_degrees_f32(self) -> f32 {
        self.0 as f32 * (180.0 / 2_147_483_648.0)
    }
    /// The angle in degrees, in `[-180, 180)`, as `f64` (for host reports).
    pub fn to_degrees_f64(self) -> f64 {
        f64::from(self.0) * (180.0 / 2_147_483_648.0)
    }
}

impl Add for Angle {
    type Output = Angle;
    fn add(self, rhs: Angle) -> Angle {
        Angle(self.0.wrapping_add(rhs.0))
    }
}

impl Sub for Angle {
    type Output = Angle;
    /// The wrapped difference, in `[-π, π)`.
    fn sub(self, rhs: Angle) -> Angle {
        Angle(self.0.wrapping_sub(rhs.0))
    }
}

impl Neg for Angle {
    type Output = Angle;
    fn neg(self) -> Angle {
        Angle(self.0.wrapping_neg())
    }
}

/// Sine and cosine of `x` radians in `f32` for code outside the control step's hot path
/// that takes radians (commissioning's test signals, the low-speed mode's dither):
/// the binary angle ([`Scalar::radians_to_angle`], exact to `f32` rounding of
/// `x / 2π`) and [`Scalar::cos_sin`]'s table, within 2e-5 absolute for `|x|` up to a
/// few hundred radians. libm's `sinf`/`cosf` are correctly rounded but reduce the
/// argument in `f64` (software on Cortex-M), about 10 KB of flash with their
/// `f64` routines. NaN and infinite `x` give `(0, 1)`.
pub fn sin_cos(x: f32) -> (f32, f32) {
    let (c, s) = <f32 as Scalar>::cos_sin(x.radians_to_angle());
    (s, c)
}

/// Arcsine of `x` (clamped to `[-1, 1]`) in radians, `f32`: the angle of the vector
/// `(sqrt((1 - x)(1 + x)), x)` ([`Scalar::atan2`]), within 2e-5 rad; see [`sin_cos`] for
/// why not libm's `asinf`. NaN gives 0.
pub fn asin(x: f32) -> f32 {
    let x = x.clamp_to(-1.0, 1.0);
    let adjacent = Scalar::sqrt((1.0 - x) * (1.0 + x));
    <f32 as Scalar>::atan2(x, adjacent).to_radians::<f32>()
}

/// `e^-x` in `f32` for `x >= 0`: the envelope of a first-order decay after `x` time
/// constants. `2^-y` with `y = x log2(e)` split as `n + f` (`n` whole, `f` in `[0, 1)`):
/// `2^-n` is the exponent field and `2^-f` a degree-4 polynomial (least-squares fit in
/// relative error, `1` at `f = 0` and `1/2` at `f = 1`, so it is continuous). Within 5e-6
/// relative for `x` up to 16 and 1e-5 up to 87, the excess being the `f32` rounding of
/// `y`. libm's `expf` is correctly rounded and about 460 bytes of flash; this is five
/// multiplications. `x <= 0` and NaN give 1; beyond 87 (under `f32`'s smallest normal
/// number) it gives 0.
pub fn decay(x: f32) -> f32 {
    // Coefficients of 2^-f = 1 + f (c1 + f (c2 + f (c3 + f c4))).
    const C: [f32; 4] = [-0.693_060_1, 0.239_438_74, -0.053_195_57, 0.006_818_329];
    let y = x * core::f32::consts::LOG2_E;
    if y.is_nan() || y <= 0.0 {
        return 1.0;
    }
    if y >= 126.0 {
        return 0.0;
    }
    // y is in (0, 126): the truncation is the floor, and 127 - n a normal exponent.
    let n = y as u32;
    let f = y - n as f32;
    let fraction = 1.0 + f * (C[0] + f * (C[1] + f * (C[2] + f * C[3])));
    fraction * f32::from_bits((127 - n) << 23)
}

/// Binary-angle counts per radian, `2^31 / π`.
const COUNTS_PER_RAD: f64 = 2_147_483_648.0 / core::f64::consts::PI;
/// `1 / 2^31`: converts idsp's full-scale `i32` sine/cosine to 1.0.
const INV_2POW31: f32 = 1.0 / 2_147_483_648.0;

impl Scalar for f32 {
    const ZERO: f32 = 0.0;
    const ONE: f32 = 1.0;
    const TWO: f32 = 2.0;
    const HALF: f32 = 0.5;
    const ONE_THIRD: f32 = 1.0 / 3.0;
    const INV_SQRT3: f32 = 0.577_350_26;
    const SQRT3_HALF: f32 = 0.866_025_4;

    fn from_f32(x: f32) -> f32 {
        x
    }
    fn to_f32(self) -> f32 {
        self
    }
    /// One `vabs.f32` on FPv4 (core's `f32::abs`, no library call): `-0.0` gives `+0.0`.
    fn abs(self) -> f32 {
        f32::abs(self)
    }
    fn sqrt(self) -> f32 {
        if self.is_nan() {
            return self;
        }
        if self <= 0.0 {
            return 0.0;
        }
        if self == f32::INFINITY {
            return self;
        }
        self * f32_inv_sqrt(self)
    }
    fn checked_div(self, rhs: f32) -> Option<f32> {
        if rhs == 0.0 {
            return None;
        }
        let q = self / rhs;
        if q.is_finite() { Some(q) } else { None }
    }
    fn recip(self) -> Option<f32> {
        Scalar::checked_div(1.0, self)
    }
    fn recip_count(n: u32) -> f32 {
        1.0 / n as f32
    }
    fn inv_sqrt(self) -> Option<f32> {
        if !(self > 0.0 && self.is_finite()) {
            return None;
        }
        let r = f32_inv_sqrt(self);
        if r.is_finite() { Some(r) } else { None }
    }
    fn is_valid(self) -> bool {
        self.is_finite()
    }
    fn cos_sin(angle: Angle) -> (f32, f32) {
        let (c, s) = idsp::cossin(angle.0);
        (c as f32 * INV_2POW31, s as f32 * INV_2POW31)
    }
    fn atan2(y: f32, x: f32) -> Angle {
        // idsp's atan2 takes integers: scale the larger component to 2^30 so that
        // both fit an i32 with full resolution. NaN/inf give 0 (callers check validity).
        // Scalar::max, not f32::max: a library call (fmaxf) on FPv4.
        let m = Scalar::max(Scalar::abs(x), Scalar::abs(y));
        if !(m > 0.0 && m.is_finite()) {
            return Angle::ZERO;
        }
        let k = 1_073_741_824.0 / m;
        Angle(idsp::atan2((y * k) as i32, (x * k) as i32))
    }
    fn radians_to_angle(self) -> Angle {
        // Reduce to turns in [-1/2, 1/2] before scaling so no cast saturates.
        let turns = self * (1.0 / core::f32::consts::TAU);
        let frac = turns - (turns as i32) as f32;
        let frac = if frac > 0.5 {
            frac - 1.0
        } else if frac < -0.5 {
            frac + 1.0
        } else {
            frac
        };
        // Saturating cast: exactly +1/2 turn gives i32::MAX, one count (1.5e-9 rad)
        // short of +π. A direct i32 cast avoids a 64-bit library call on Cortex-M4F.
        Angle((frac * 4_294_967_296.0) as i32)
    }
    fn angle_to_radians(angle: Angle) -> f32 {
        angle.0 as f32 * (core::f32::consts::PI * INV_2POW31)
    }
}

impl Scalar for f64 {
    const ZERO: f64 = 0.0;
    const ONE: f64 = 1.0;
    const TWO: f64 = 2.0;
    const HALF: f64 = 0.5;
    const ONE_THIRD: f64 = 1.0 / 3.0;
    const INV_SQRT3: f64 = 0.577_350_269_189_625_8;
    const SQRT3_HALF: f64 = 0.866_025_403_784_438_6;

    fn from_f32(x: f32) -> f64 {
        f64::from(x)
    }
    fn to_f32(self) -> f32 {
        self as f32
    }
    fn abs(self) -> f64 {
        libm::fabs(self)
    }
    fn sqrt(self) -> f64 {
        if self.is_nan() { self } else { libm::sqrt(self.max(0.0)) }
    }
    fn checked_div(self, rhs: f64) -> Option<f64> {
        if rhs == 0.0 {
            return None;
        }
        let q = self / rhs;
        if q.is_finite() { Some(q) } else { None }
    }
    fn recip(self) -> Option<f64> {
        Scalar::checked_div(1.0, self)
    }
    fn recip_count(n: u32) -> f64 {
        1.0 / f64::from(n)
    }
    fn inv_sqrt(self) -> Option<f64> {
        if !(self > 0.0 && self.is_finite()) {
            return None;
        }
        Scalar::checked_div(1.0, libm::sqrt(self))
    }
    fn is_valid(self) -> bool {
        self.is_finite()
    }
    fn cos_sin(angle: Angle) -> (f64, f64) {
        let (s, c) = libm::sincos(Self::angle_to_radians(angle));
        (c, s)
    }
    fn atan2(y: f64, x: f64) -> Angle {
        if !(x.is_finite() && y.is_finite()) {
            return Angle::ZERO;
        }
        libm::atan2(y, x).radians_to_angle()
    }
    fn radians_to_angle(self) -> Angle {
        let turns = self * (1.0 / core::f64::consts::TAU);
        let frac = turns - libm::round(turns);
        Angle((frac * 4_294_967_296.0) as i64 as i32)
    }
    fn angle_to_radians(angle: Angle) -> f64 {
        f64::from(angle.0) / COUNTS_PER_RAD
    }
}

/// Saturating fixed-point number, Q8.24: `i32` with 24 fractional bits.
///
/// Range `[-128, 128)`, resolution 2^-24 ≈ 6.0e-8. Every operator saturates at the
/// range limits instead of wrapping or panicking; [`Scalar::is_valid`] reports a value
/// at either limit as invalid, so an overflow anywhere in a chain surfaces as a fault.
/// Meant to carry per-unit quantities (see [`crate::num::units::Base::for_motor`]), where
/// the paper motor at twice rated current and twice its top speed stays within +-2.5 (currents reach 2 pu, the bus 1.7 pu).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord)]
pub struct Q24(pub I8F24);

impl Q24 {
    /// Builds from the raw representation (`bits / 2^24`).
    pub const fn from_bits(bits: i32) -> Self {
        Q24(I8F24::from_bits(bits))
    }
    /// The raw representation (`value * 2^24`).
    pub const fn to_bits(self) -> i32 {
        self.0.to_bits()
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Q24 {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "{=i32}/2^24", self.to_bits())
    }
}

impl Add for Q24 {
    type Output = Q24;
    fn add(self, rhs: Q24) -> Q24 {
        Q24(self.0.saturating_add(rhs.0))
    }
}
impl Sub for Q24 {
    type Output = Q24;
    fn sub(self, rhs: Q24) -> Q24 {
        Q24(self.0.saturating_sub(rhs.0))
    }
}
impl Mul for Q24 {
    type Output = Q24;
    /// The product rounded down (towards -inf), saturated: the same result as the `fixed`
    /// crate's `saturating_mul` for every pair of operands (tested), which forms a wider
    /// product and spends four multiplications on it; this is one `SMULL`, the shift and
    /// a range check on the high word.
    #[inline]
    fn mul(self, rhs: Q24) -> Q24 {
        Q24::from_bits(q24_mul_saturating(self.to_bits(), rhs.to_bits()))
    }
}
impl Neg for Q24 {
    type Output = Q24;
    fn neg(self) -> Q24 {
        Q24(self.0.saturating_neg())
    }
}

/// `round(2^7 / π * 2^24)`: Q24 radians to binary-angle counts, with a 24-bit shift.
const Q24_RAD_TO_COUNTS: i64 = 683_565_276;
/// `round(π * 2^25)`: binary-angle counts to Q24 radians, with a 32-bit shift.
const Q24_COUNTS_TO_RAD: i64 = 105_414_357;

/// 1/sqrt(x) for finite `x > 0`: micromath's bit-trick seed (within 3.5 %) refined by
/// three Newton steps; the error squares each step (3.5e-2, 1.8e-3, 5e-6, f32
/// rounding), nine multiplications in all. Bounded time, no division, no libm.
fn f32_inv_sqrt(x: f32) -> f32 {
    let mut r = micromath::F32Ext::invsqrt(x);
    let half_x = 0.5 * x;
    for _ in 0..3 {
        r = r * (1.5 - half_x * r * r);
    }
    r
}

/// `(a * b) >> 24` of two Q24 bit patterns, rounded down and saturated to `i32`: one
/// `SMULL` (32 x 32 -> 64 bits) and a check that the high word lies in `[-2^23, 2^23)`
/// (bits 55 to 63 of the product, those the shift leaves above bit 31, all copies of its
/// sign), then the shift. The saturated value is formed on a cold path
/// (`core::hint::cold_path`): on the Cortex-M3 an in-range product is six instructions
/// (`SMULL`, the check's add, compare and branch, the shift's two), where forming both
/// results and selecting one takes nine. The same value for every pair of operands.
#[inline(always)]
fn q24_mul_saturating(a: i32, b: i32) -> i32 {
    let product = i64::from(a) * i64::from(b);
    let high = (product >> 32) as i32;
    if (high.wrapping_add(1 << 23) as u32) < 1 << 24 {
        (product >> 24) as i32
    } else {
        core::hint::cold_path();
        // The product's sign: i32::MAX when positive, i32::MIN when negative.
        (high >> 31) ^ i32::MAX
    }
}

/// `(a * b) >> 24` of two Q24 bit patterns whose product is in range (`|b| <= 2^24`,
/// i.e. a factor of magnitude at most one): one `SMULL` and the shift, no check.
#[inline(always)]
fn q24_mul_in_range(a: i32, b: i32) -> i32 {
    ((i64::from(a) * i64::from(b)) >> 24) as i32
}

/// `(a << 24) / b` of two Q24 bit patterns, rounded towards zero; `None` for `b = 0` or
/// a quotient outside `i32`: the same result as the `fixed` crate's `checked_div` for
/// every pair of operands (tested), which divides 64 by 64 bits in a software library
/// routine on Cortex-M3 (`__aeabi_ldivmod`). Here the magnitudes divide 56 by
/// 32 bits with two of the core's 32-bit hardware divisions ([`div_u64_by_u32`]).
#[inline]
fn q24_div(a: i32, b: i32) -> Option<i32> {
    if b == 0 {
        return None;
    }
    let n = u64::from(a.unsigned_abs()) << 24;
    let d = b.unsigned_abs();
    // A quotient of 2^32 or more: (n >> 32) >= d.
    let (high, low) = ((n >> 32) as u32, n as u32);
    if high >= d {
        return None;
    }
    let q = div_u64_by_u32(high, low, d);
    if (a < 0) != (b < 0) {
        // -q down to i32::MIN (q = 2^31).
        (q <= 1 << 31).then(|| (q as i32).wrapping_neg())
    } else {
        i32::try_from(q).ok()
    }
}

/// `(high * 2^32 + low) / d` for `high < d` (so the quotient fits 32 bits), rounded down:
/// long division in two 16-bit digits on the normalised divisor, each digit from one
/// 32-bit hardware division and corrected at most twice (H. S. Warren, *Hacker's
/// Delight*, 2nd ed., section 9-4, `divlu`). Bounded: no loop runs more than twice.
#[inline]
fn div_u64_by_u32(high: u32, low: u32, d: u32) -> u32 {
    const BASE: u32 = 1 << 16;
    const MASK: u32 = BASE - 1;
    // Normalise: the divisor's top bit set (d > high >= 0, so d > 0).
    let shift = d.leading_zeros();
    let v = d << shift;
    let v0 = v & MASK;
    // v's top bit is set, so its high digit is at least 2^15: never zero (the type says
    // so to the compiler, which then links no division-by-zero panic).
    let Some(v1) = core::num::NonZeroU32::new(v >> 16) else { return u32::MAX };
    let n32 = if shift == 0 { high } else { (high << shift) | (low >> (32 - shift)) };
    let n10 = low << shift;
    let (n1, n0) = (n10 >> 16, n10 & MASK);
    // The first digit: n32 / v1 is at most two too large.
    let mut q1 = n32 / v1;
    let mut rhat = n32 - q1 * v1.get();
    while q1 >= BASE || q1 * v0 > (rhat << 16) + n1 {
        q1 -= 1;
        rhat += v1.get();
        if rhat >= BASE {
            break;
        }
    }
    let n21 = (n32 << 16).wrapping_add(n1).wrapping_sub(q1.wrapping_mul(v));
    // The second digit, likewise.
    let mut q0 = n21 / v1;
    let mut rhat = n21 - q0 * v1.get();
    while q0 >= BASE || q0 * v0 > (rhat << 16) + n0 {
        q0 -= 1;
        rhat += v1.get();
        if rhat >= BASE {
            break;
        }
    }
    (q1 << 16) | q0
}

/// `sqrt(m) 2^16` for `m` in `[2^30, 2^32)`: in `[2^31, 2^32)`, at most one above its
/// exact value's floor.
///
/// `r = floor(sqrt(m))` by three Newton steps `(r + m / r) / 2` from a chord seed
/// (relative error 5.6 %, then 1.5e-3, 1.1e-6, 6e-13, each step truncating by less than
/// one) and a correction of at most one each way; the 16 bits below `r` from the
/// remainder, `(m - r^2) / 2r` (one more Newton step, over by less than 2^-16). Four of the
/// core's 32-bit hardware divisions, no loop over the bits (the `fixed` crate's square
/// root iterates once per result bit).
#[inline]
fn sqrt_q16_normalised(m: u32) -> u32 {
    // The chord through (2^30, 2^15) and (2^32, 2^16), below sqrt: 2^15 + (m - 2^30) / 3 2^15.
    let mut r = (1u32 << 15) + (m.saturating_sub(1 << 30) >> 15) / 3;
    for _ in 0..3 {
        // r >= 2^15 throughout (Newton's iterates stay above the root after the first).
        let Some(d) = core::num::NonZeroU32::new(r) else { return 0 };
        r = (r + m / d) >> 1;
    }
    // floor(sqrt(m)) <= 65535: within one of r after the steps.
    r = r.min(u32::from(u16::MAX));
    if r * r > m {
        r -= 1;
    }
    if r < u32::from(u16::MAX) && (r + 1) * (r + 1) <= m {
        r += 1;
    }
    // sqrt(m) 2^16 = r 2^16 + 2^16 (m - r^2) / (sqrt(m) + r), the last term at most
    // (m - r^2) 2^15 / r: m - r^2 <= 2r, so the product fits 32 bits.
    let Some(d) = core::num::NonZeroU32::new(r) else { return 0 };
    let fraction = (m.saturating_sub(r * r) << 15) / d;
    (r << 16).saturating_add(fraction)
}

/// The square root of a Q24 bit pattern `x > 0`, normalised: `x = m 4^-j` with `m` in
/// `[2^30, 2^32)` (`shift = 2j`, the even count of `x`'s leading zeros), and `root =
/// sqrt(m) 2^16` ([`sqrt_q16_normalised`]).
#[inline]
fn q24_sqrt_normalised(x: i32) -> (u32, u32) {
    // x < 2^31 has at least one leading zero: an even shift to [2^30, 2^32).
    let shift = x.leading_zeros() & !1;
    (sqrt_q16_normalised((x as u32) << shift), shift)
}

/// The square root of `x` in `f32`, correctly rounded (to nearest, as IEEE 754 and
/// libm's `sqrtf`: the same bits, every positive `f32` checked once against the host's
/// `sqrt`; `tests/numerics.rs` checks a sweep), for settings formed once: libm's
/// `sqrtf` is about 480 bytes of flash with its table, this a digit-by-digit integer
/// root of the mantissa (25 steps; not inlined, one copy for its callers). NaN and
/// negative `x` give NaN, `-0.0` gives `-0.0`, infinity itself.
#[inline(never)]
pub fn sqrt_rounded(x: f32) -> f32 {
    if x.is_nan() || x < 0.0 {
        return f32::NAN;
    }
    if x == 0.0 || x == f32::INFINITY {
        return x;
    }
    // x = m 2^e with m a 24-bit integer whose top bit is set (subnormals normalised).
    let bits = x.to_bits();
    let field = (bits >> 23) as i32;
    let (m, e) = if field == 0 {
        let shift = (bits.leading_zeros() - 8) as i32;
        (bits << shift, -149 - shift)
    } else {
        ((bits & 0x7f_ffff) | 0x80_0000, field - 150)
    };
    // n = m 2^s in [2^48, 2^50) with e - s even: r = floor(sqrt(n)) has 25 bits, one per
    // step of the digit-by-digit root (25 steps: bounded, and small in flash).
    let s = if e & 1 != 0 { 25 } else { 26 };
    let mut rest = u64::from(m) << s;
    let mut r = 0u64;
    // The highest power of four in n, 2^48 (from n's bits: a loop of unknown count is not
    // unrolled into 25 copies).
    let mut bit = 1u64 << ((63 - rest.leading_zeros()) & !1);
    while bit != 0 {
        if rest >= r + bit {
            rest -= r + bit;
            r = (r >> 1) + bit;
        } else {
            r >>= 1;
        }
        bit >>= 2;
    }
    // Round the 25-bit root to 24: up when the bit below is set (a square root of an
    // integer is never exactly halfway). 2^24 after rounding carries into the exponent.
    let q = ((r >> 1) + (r & 1)) as u32;
    let exponent = (e - s) / 2 + 1;
    f32::from_bits((((exponent + 150) as u32) << 23).wrapping_add(q - (1 << 23)))
}

/// `sqrt(x 2^24)` for Q24 bits `x` (the square root's Q24 bits; 0 for `x <= 0`): the
/// exact root's floor, or one LSB above it (1.2 % of inputs; every positive `x` was checked
/// against an exact integer root, `tests/numerics.rs` checks a sweep).
#[inline]
fn q24_sqrt_non_negative(x: i32) -> i32 {
    if x <= 0 {
        return 0;
    }
    let (root, shift) = q24_sqrt_normalised(x);
    // sqrt(x 2^24) = sqrt(m) 2^(12 - shift/2) = root 2^-(4 + shift/2).
    (root >> (4 + shift / 2)) as i32
}

/// 1 / x for Q24 bits `x != 0`: the exact quotient `2^48 / x` rounded towards zero
/// ([`q24_div`], two hardware divisions). `None` for `x = 0` or a result at or beyond
/// the Q24 range.
#[inline]
fn q24_recip(x: i32) -> Option<i32> {
    q24_div(1 << 24, x).filter(|r| r.unsigned_abs() < i32::MAX as u32)
}

/// 1 / sqrt(x) for Q24 bits `x > 0`: `2^(52 + j) / root` from [`q24_sqrt_normalised`]
/// (`x = m 4^-j`, `root = sqrt(m) 2^16`), as `floor(2^62 / root)` ([`div_u64_by_u32`], 31
/// significant bits) shifted by `j - 10`. Within one LSB plus 2e-9 relative. `None` for
/// `x <= 0` or a result at or beyond the Q24 range.
#[inline]
fn q24_inv_sqrt_positive(x: i32) -> Option<i32> {
    if x <= 0 {
        return None;
    }
    let (root, shift) = q24_sqrt_normalised(x);
    // root >= 2^31 > 2^30: the quotient fits 32 bits, in (2^30, 2^31].
    let q = div_u64_by_u32(1 << 30, 0, root);
    let j = shift / 2;
    let r = if j <= 10 { q >> (10 - j) } else { q.checked_shl(j - 10).filter(|&r| r >> (j - 10) == q)? };
    i32::try_from(r).ok().filter(|&r| r < i32::MAX)
}

/// `x` finite and `> 0`: the settings' check of the constructors and validations. Not
/// inlined: settings are checked once, at construction, and inlined at each of some sixty
/// call sites (the finiteness test is integer bit work on Cortex-M4F and M3) it cost about
/// 40 bytes of flash apiece.
#[inline(never)]
pub(crate) fn positive(x: f32) -> bool {
    x.is_finite() && x > 0.0
}

/// `x` finite and `>= 0` (a setting's check; not inlined, as [`positive`]).
#[inline(never)]
pub(crate) fn non_negative(x: f32) -> bool {
    x.is_finite() && x >= 0.0
}

/// The Q24 bits of `x`: rounded to nearest, ties to even, saturated to the Q8.24 range,
/// NaN to 0. The same result as `I8F24::saturating_from_num` for every non-NaN `f32`
/// (tested), read from the float's bits: `fixed` panics on NaN inside that conversion,
/// and that path stayed in the firmware images although NaN never reaches it. Not
/// inlined: a conversion is configuration or I/O, and inlined at each of its many call
/// sites (the drive's, the estimator's and the observers' constructors) it cost about
/// 100 bytes of flash apiece on Cortex-M3.
#[inline(never)]
fn q24_bits_from_f32(x: f32) -> i32 {
    let bits = x.to_bits();
    let negative = bits >> 31 != 0;
    let exponent = ((bits >> 23) & 0xFF) as i32;
    let fraction = bits & 0x7F_FFFF;
    let saturated = if negative { i32::MIN } else { i32::MAX };
    if exponent == 0xFF {
        // Infinity saturates; NaN has no sign worth keeping.
        return if fraction == 0 { saturated } else { 0 };
    }
    // |x| = m 2^(e - 150) (subnormals: e = 1 without the implicit one), so
    // |x| 2^24 = m 2^(e - 126).
    let (m, e) = if exponent == 0 { (fraction, 1) } else { (fraction | 0x80_0000, exponent) };
    let shift = e - 126;
    // In 32 bits (a shift of a 64-bit value is several instructions on Cortex-M3):
    // m < 2^24 and a shift below 8 keep |x| 2^24 below 2^31.
    let magnitude: u32 = if shift >= 0 {
        // A normal m >= 2^23: from a shift of 8 on, |x| 2^24 >= 2^31.
        if shift >= 8 {
            return saturated;
        } else {
            m << shift
        }
    } else {
        let r = -shift;
        if r > 25 {
            // Below half an LSB (m < 2^24 <= 2^(r - 1) / 2): rounds to 0.
            0
        } else {
            let kept = m >> r;
            let rest = m & ((1 << r) - 1);
            let half = 1u32 << (r - 1);
            if rest > half || (rest == half && kept & 1 == 1) { kept + 1 } else { kept }
        }
    };
    // Below 2^31: the cast keeps the value.
    let magnitude = magnitude as i32;
    if negative { -magnitude } else { magnitude }
}

impl Scalar for Q24 {
    const ZERO: Q24 = Q24(I8F24::ZERO);
    const ONE: Q24 = Q24(I8F24::ONE);
    const TWO: Q24 = Q24(I8F24::lit("2"));
    const HALF: Q24 = Q24(I8F24::lit("0.5"));
    const ONE_THIRD: Q24 = Q24(I8F24::lit("0.333333333333333333"));
    const INV_SQRT3: Q24 = Q24(I8F24::lit("0.577350269189625765"));
    const SQRT3_HALF: Q24 = Q24(I8F24::lit("0.866025403784438647"));

    fn from_f32(x: f32) -> Q24 {
        Q24(I8F24::from_bits(q24_bits_from_f32(x)))
    }
    fn to_f32(self) -> f32 {
        self.0.to_num::<f32>()
    }
    fn abs(self) -> Q24 {
        Q24(self.0.saturating_abs())
    }
    #[inline]
    fn mul_unit(self, k: Q24) -> Q24 {
        debug_assert!(k.to_bits().unsigned_abs() <= 1 << 24, "mul_unit: |k| > 1");
        Q24::from_bits(q24_mul_in_range(self.to_bits(), k.to_bits()))
    }
    fn mul_nearest(self, rhs: Q24) -> Q24 {
        let product = i64::from(self.0.to_bits()) * i64::from(rhs.0.to_bits());
        let rounded = (product + (1 << 23)) >> 24;
        Q24(I8F24::from_bits(rounded.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32))
    }
    fn sqrt(self) -> Q24 {
        Q24::from_bits(q24_sqrt_non_negative(self.to_bits()))
    }
    fn checked_div(self, rhs: Q24) -> Option<Q24> {
        q24_div(self.to_bits(), rhs.to_bits()).map(Q24::from_bits)
    }
    fn checked_div_pair(self, other: Q24, rhs: Q24) -> (Option<Q24>, Option<Q24>) {
        match rhs.recip() {
            Some(inverse) => (Some(self * inverse), Some(other * inverse)),
            None => (self.checked_div(rhs), other.checked_div(rhs)),
        }
    }
    fn unit_ratio(self, rhs: Q24) -> Q24 {
        let (n, d) = (self.to_bits(), rhs.to_bits());
        if d <= 0 {
            return Q24::ZERO;
        }
        if n.unsigned_abs() >= d.unsigned_abs() {
            return if n < 0 { -Q24::ONE } else { Q24::ONE };
        }
        // d << shift in [2^30, 2^31), n << shift below it in magnitude (no overflow); the
        // divisor's top 16 bits (>= 2^14: a relative error below 2^-14) give a quotient
        // of 2^16 (n / d), truncated (2^-16 absolute), at most 2^16 (1 + 2^-14).
        let shift = d.leading_zeros() - 1;
        let divisor = (d << shift) >> 16;
        let quotient = (n << shift).checked_div(divisor).unwrap_or(0);
        Q24::from_bits(quotient.clamp(-(1 << 16), 1 << 16) << 8)
    }
    fn from_turns(turns: i32, fraction: u32, per_turn: Q24) -> Q24 {
        let per_turn = per_turn.to_bits();
        // In 64 bits (|turns per_turn| < 2^62), saturated once at the end: a whole part
        // saturated first would be pulled back inside the range by the fraction's part.
        let whole = i64::from(turns) * i64::from(per_turn);
        // fraction / 2^32 < 1 of |per_turn| < 2^31: the high word fits an i32.
        let part = ((u64::from(fraction) * u64::from(per_turn.unsigned_abs())) >> 32) as i64;
        let sum = whole + if per_turn < 0 { -part } else { part };
        Q24::from_bits(sum.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32)
    }
    fn lead_turns(reference_turns: f32, counts: i64, per_turn: Q24) -> Q24 {
        // The reference in 2^-16 of a turn (a 32-bit conversion: a 64-bit one is a
        // library routine of its own), saturating at 2^15 turns either way (NaN to 0).
        let reference = i64::from((reference_turns * 65_536.0) as i32) << 16;
        let lead = reference.saturating_sub(counts);
        let turns = (lead >> 32).clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
        Q24::from_turns(turns, lead as u32, per_turn)
    }
    fn recip(self) -> Option<Q24> {
        q24_recip(self.to_bits()).map(Q24::from_bits)
    }
    fn recip_count(n: u32) -> Q24 {
        const ONE_BITS: u32 = 1 << 24;
        match n {
            0 => Q24::from_bits(i32::MAX),
            // (2^24 + n / 2) / n: 1 / n rounded to nearest; below 2^25 for every n >= 1.
            _ => Q24::from_bits(((ONE_BITS + n / 2) / n) as i32),
        }
    }
    fn inv_sqrt(self) -> Option<Q24> {
        q24_inv_sqrt_positive(self.to_bits()).map(Q24::from_bits)
    }
    fn is_valid(self) -> bool {
        // Strictly inside (-MAX, MAX): a saturated value, or the negation of one
        // (-MAX = MIN + 1), is reported.
        self.0 < I8F24::MAX && self.0 > -I8F24::MAX
    }
    fn cos_sin(angle: Angle) -> (Q24, Q24) {
        let (c, s) = idsp::cossin(angle.0);
        // Full scale 2^31 -> 2^24: an arithmetic shift by 7, rounding to nearest.
        (Q24::from_bits((c >> 7) + ((c >> 6) & 1)), Q24::from_bits((s >> 7) + ((s >> 6) & 1)))
    }
    fn atan2(y: Q24, x: Q24) -> Angle {
        // The ratio is scale-free: idsp works on the raw bits directly.
        Angle(idsp::atan2(y.to_bits(), x.to_bits()))
    }
    fn radians_to_angle(self) -> Angle {
        // Wrapping cast to i32 reduces modulo one turn.
        Angle(((i64::from(self.to_bits()) * Q24_RAD_TO_COUNTS) >> 24) as i32)
    }
    fn angle_to_radians(angle: Angle) -> Q24 {
        Q24::from_bits(((i64::from(angle.0) * Q24_COUNTS_TO_RAD) >> 32) as i32)
    }
}
