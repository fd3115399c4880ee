//! Reference-frame transforms: Clarke (amplitude-invariant) and Park, with inverses.
//!
//! Conventions (`docs/trace-format.md`): a balanced set of phase quantities of peak
//! `X` gives `|x_alphabeta| = X`; the rotor (dq) frame has d along the magnet flux, at
//! electrical angle `theta` from the alpha axis. Units are whatever the inputs carry
//! (V, A, Wb, or per-unit): the transforms are linear and dimensionless.
//!
//! Cost: every product has a factor of magnitude at most one (a constant below one, a
//! cosine or a sine of [`CosSin`], which [`Scalar::cos_sin`] keeps within `[-1, 1]`), so
//! it cannot leave the number's range and is taken with [`Scalar::mul_unit`]: in fixed
//! point one `SMULL` and a shift; the sums saturate.

use crate::num::{Angle, Scalar};

/// Three phase quantities (V, A or per-unit).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Abc<T> {
    /// Phase a.
    pub a: T,
    /// Phase b.
    pub b: T,
    /// Phase c.
    pub c: T,
}

/// A stationary-frame vector (V, A, Wb or per-unit).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AlphaBeta<T> {
    /// Alpha component (aligned with phase a).
    pub alpha: T,
    /// Beta component (90 degrees ahead of alpha).
    pub beta: T,
}

/// A rotor-frame vector (V, A, Wb or per-unit).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Dq<T> {
    /// Direct axis (along the magnet flux).
    pub d: T,
    /// Quadrature axis (90 degrees ahead of d; carries thrust).
    pub q: T,
}

impl<T: Scalar> AlphaBeta<T> {
    /// Builds a vector from its components.
    pub fn new(alpha: T, beta: T) -> Self {
        AlphaBeta { alpha, beta }
    }
    /// Squared magnitude, in the square of the components' unit.
    pub fn norm_squared(&self) -> T {
        self.alpha * self.alpha + self.beta * self.beta
    }
    /// Magnitude, in the components' unit.
    pub fn norm(&self) -> T {
        self.norm_squared().sqrt()
    }
    /// `true` when both components are valid numbers ([`Scalar::is_valid`]).
    pub fn is_valid(&self) -> bool {
        self.alpha.is_valid() && self.beta.is_valid()
    }
    /// Each component multiplied by `k`.
    pub fn scale(&self, k: T) -> Self {
        AlphaBeta { alpha: self.alpha * k, beta: self.beta * k }
    }
    /// The vector's angle from the alpha axis.
    pub fn angle(&self) -> Angle {
        T::atan2(self.beta, self.alpha)
    }
}

impl<T: Scalar> Dq<T> {
    /// Builds a vector from its components.
    pub fn new(d: T, q: T) -> Self {
        Dq { d, q }
    }
    /// `true` when both components are valid numbers ([`Scalar::is_valid`]).
    pub fn is_valid(&self) -> bool {
        self.d.is_valid() && self.q.is_valid()
    }
}

/// Cosine and sine of one angle, computed once and shared by the transforms that use
/// it in a control step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CosSin<T> {
    /// cos(theta), dimensionless, within `[-1, 1]` (the transforms rely on it).
    pub cos: T,
    /// sin(theta), dimensionless, within `[-1, 1]`.
    pub sin: T,
}

impl<T: Scalar> CosSin<T> {
    /// Evaluates cos and sin of `theta` (accuracy: [`Scalar::cos_sin`]). Not inlined:
    /// one copy of the table look-up for every path that does not run every period of
    /// the sensorless `Running` state (hand-overs, seeds, the low-speed modes' frames);
    /// [`CosSin::inline`] is for those that do.
    #[inline(never)]
    pub fn new(theta: Angle) -> Self {
        Self::inline(theta)
    }

    /// [`CosSin::new`], inlined: for the control step's every-period path (the PLL, the
    /// modulator's frame, the estimator's corrected angle), where a call would cost
    /// instructions every period.
    #[inline(always)]
    pub fn inline(theta: Angle) -> Self {
        let (cos, sin) = T::cos_sin(theta);
        CosSin { cos, sin }
    }
}

/// Clarke transform, amplitude-invariant: `alpha = (2a - b - c) / 3`,
/// `beta = (b - c) / sqrt(3)`. Any common-mode part of `abc` is discarded.
pub fn clarke<T: Scalar>(abc: Abc<T>) -> AlphaBeta<T> {
    AlphaBeta {
        alpha: (abc.a + abc.a - abc.b - abc.c).mul_unit(T::ONE_THIRD),
        beta: (abc.b - abc.c).mul_unit(T::INV_SQRT3),
    }
}

/// Clarke transform from two phases of a three-wire system (`a + b + c = 0`):
/// `alpha = a`, `beta = (a + 2b) / sqrt(3)`.
pub fn clarke_two_phase<T: Scalar>(a: T, b: T) -> AlphaBeta<T> {
    AlphaBeta { alpha: a, beta: (a + b + b).mul_unit(T::INV_SQRT3) }
}

/// Inverse Clarke transform (zero common mode): `a = alpha`,
/// `b = -alpha/2 + (sqrt(3)/2) beta`, `c = -alpha/2 - (sqrt(3)/2) beta`.
pub fn inverse_clarke<T: Scalar>(ab: AlphaBeta<T>) -> Abc<T> {
    let half_alpha = ab.alpha.mul_unit(T::HALF);
    let k_beta = ab.beta.mul_unit(T::SQRT3_HALF);
    Abc { a: ab.alpha, b: k_beta - half_alpha, c: -half_alpha - k_beta }
}

/// Park transform into the frame at angle `theta` (given as its [`CosSin`]):
/// `d = alpha cos + beta sin`, `q = -alpha sin + beta cos`.
pub fn park<T: Scalar>(ab: AlphaBeta<T>, theta: &CosSin<T>) -> Dq<T> {
    Dq {
        d: ab.alpha.mul_unit(theta.cos) + ab.beta.mul_unit(theta.sin),
        q: ab.beta.mul_unit(theta.cos) - ab.alpha.mul_unit(theta.sin),
    }
}

/// Inverse Park transform from the frame at angle `theta`:
/// `alpha = d cos - q sin`, `beta = d sin + q cos`.
pub fn inverse_park<T: Scalar>(dq: Dq<T>, theta: &CosSin<T>) -> AlphaBeta<T> {
    AlphaBeta {
        alpha: dq.d.mul_unit(theta.cos) - dq.q.mul_unit(theta.sin),
        beta: dq.d.mul_unit(theta.sin) + dq.q.mul_unit(theta.cos),
    }
}
