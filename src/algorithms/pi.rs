//! PI controller with output limits, anti-windup, reset and bumpless start.
//!
//! Discrete form, per sample: `u = kp * e + I`, with `I += ki_dt * e` (`ki_dt` is the
//! integral gain times the sample period). Anti-windup is *conditional integration with
//! a clamped integrator*: the integrator does not move further in the direction that
//! would push a saturated output deeper into its limit, and is itself held inside the
//! output range. So after any time in saturation, an error of the opposite sign moves
//! the output off the limit at once: there is no wound-up integral to unwind.
//!
//! Units: `e` in the measured quantity's unit (A, m/s or per-unit), `u` in the actuator's
//! (V, A or per-unit); `kp` in u per e, `ki_dt` in u per e per sample.

use crate::num::Scalar;

/// A PI controller. See the module documentation for the law and its anti-windup.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pi<T> {
    kp: T,
    ki_dt: T,
    out_min: T,
    out_max: T,
    integral: T,
}

/// Why a PI controller could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PiError {
    /// A gain is negative or not a valid number.
    BadGain,
    /// `out_min > out_max`, or a limit is not a valid number.
    BadLimits,
}

impl<T: Scalar> Pi<T> {
    /// A controller with proportional gain `kp` (output per error unit), integral gain
    /// per sample `ki_dt` (= ki * Ts; output per error unit per sample) and output range
    /// `[out_min, out_max]`. The integrator starts at zero.
    pub fn new(kp: T, ki_dt: T, out_min: T, out_max: T) -> Result<Self, PiError> {
        if !(kp.is_valid() && ki_dt.is_valid()) || kp < T::ZERO || ki_dt < T::ZERO {
            return Err(PiError::BadGain);
        }
        if !(out_min.is_valid() && out_max.is_valid()) || out_min > out_max {
            return Err(PiError::BadLimits);
        }
        Ok(Pi { kp, ki_dt, out_min, out_max, integral: T::ZERO })
    }

    /// One sample with the stored limits: returns the output, within
    /// `[out_min, out_max]`, for `error` = setpoint − measurement.
    pub fn update(&mut self, error: T) -> T {
        self.update_within(error, self.out_min, self.out_max)
    }

    /// One sample with limits for this sample only (e.g. a voltage limit that follows
    /// the DC bus). The limits are ordered if given reversed. The integrator is held
    /// inside `[lo, hi]` too.
    pub fn update_within(&mut self, error: T, lo: T, hi: T) -> T {
        let (lo, hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
        let p = self.kp * error;
        let candidate = (self.integral + self.ki_dt * error).clamp_to(lo, hi);
        let unclamped = p + candidate;
        let pushes_up = error > T::ZERO;
        let pushes_down = error < T::ZERO;
        // Integrate unless the output is saturated and the error would drive it further.
        if !((unclamped > hi && pushes_up) || (unclamped < lo && pushes_down)) {
            self.integral = candidate;
        } else {
            self.integral = self.integral.clamp_to(lo, hi);
        }
        (p + self.integral).clamp_to(lo, hi)
    }

    /// Clears the integrator (output zero for zero error).
    pub fn reset(&mut self) {
        self.integral = T::ZERO;
    }

    /// Bumpless start: sets the integrator so that the next [`Pi::update`] with
    /// `error` gives `output` (clamped to the limits). Use when handing over from
    /// another controller that was producing `output`.
    pub fn preset(&mut self, output: T, error: T) {
        self.integral = (output - self.kp * error).clamp_to(self.out_min, self.out_max);
    }

    /// The integrator state, in output units.
    pub fn integral(&self) -> T {
        self.integral
    }

    /// The output limits `(out_min, out_max)`, in output units.
    pub fn limits(&self) -> (T, T) {
        (self.out_min, self.out_max)
    }
}
