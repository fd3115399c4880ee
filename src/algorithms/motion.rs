//! Motion on a finite stroke: a trapezoidal profile generator fed by a fixed-capacity
//! queue of moves.
//!
//! The generator turns a queue of [`Move`]s (target position, dwell) into a reference
//! trajectory, one [`Setpoint`] (position, speed, acceleration) per call of
//! [`Profile::step`]. Each move is time-optimal under a speed and an acceleration limit
//! (a trapezoid, or a triangle when the move is too short to reach the speed limit):
//!
//! ```text
//! e = target - x
//! v_des = sign(e) min(v_max, sqrt(2 a_max |e|))      (the braking curve, in its
//!                                                     exact discrete form in step)
//! v    += clamp(v_des - v, -a_max dt, +a_max dt)
//! x    += (v_old + v) dt / 2
//! ```
//!
//! The braking curve `sqrt(2 a |e|)` is the speed from which a deceleration of `a_max`
//! stops exactly at the target, so the profile never overshoots by more than one
//! step's worth (it then snaps to the target with zero speed). A move's duration is
//! `|d| / v_max + v_max / a_max` (trapezoid) or `2 sqrt(|d| / a_max)` (triangle),
//! within a few periods (tested). Moves may start while the reference is still moving
//! (a new target during a move is taken once the present one is reached and its dwell
//! has passed).
//!
//! A profile can also *follow a speed* instead of a queue ([`Profile::follow_speed`]):
//! the reference speed ramps towards a target speed at `a_max` and the position is its
//! integral, with no stroke. The speed drive uses it for its passages through the
//! low-speed mode (a reversal, a stop), so that mode has one kind of reference.
//!
//! Everything is SI. The speed, the acceleration and the braking curve are in the
//! working type `T` (on the FPU-less Cortex-M3, Q8.24, where each `f32` operation would
//! be a soft-float call; `docs/cost-budget.md` has what that costs); the positions
//! are `f32`, so that neither the stroke nor a speed drive's travel is bounded by the
//! fixed-point range, and they integrate in `f32` (rounded in Q8.24, the position would
//! gain half an LSB a step). The braking curve is formed as `sqrt(2 a) sqrt(room + a
//! dt^2 / 8)`, the same value as the form above, so that no intermediate exceeds the
//! distance or the braking speed. In Q8.24 the reference stays within 1 um and, while
//! moving, 2e-5 m/s of the `f64` profile on the same queue and period (tested). The
//! period itself is what Q8.24 holds of it ([`Period`], rounded to 2^-24 s): the
//! profile's clock runs up to 2^-25 s a step fast or slow, at most 3e-4 of the time at a
//! 100 us period (1.7e-4 for 100 us itself) and 3e-5 at 1 ms, so a move ends that share
//! of its duration early or late, on its target. The setpoint is `f32`; the drive converts its speed and acceleration into
//! working units.
//! Bounded time, no allocation, no panics: the queue is a [`heapless::Deque`] (fixed
//! capacity, `Err` when full) — a well-kept crate rather than a hand-written ring.

use crate::num::{Scalar, positive, sqrt_rounded};
use heapless::Deque;

/// Speed and acceleration limits of a profile, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ProfileLimits {
    /// Largest speed, m/s (> 0).
    pub max_speed_m_per_s: f32,
    /// Largest acceleration and deceleration, m/s^2 (> 0).
    pub max_accel_m_per_s2: f32,
    /// Lowest allowed target position, m.
    pub stroke_min_m: f32,
    /// Highest allowed target position, m (> `stroke_min_m`).
    pub stroke_max_m: f32,
}

/// A field of [`ProfileLimits`], as errors name it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ProfileField {
    /// [`ProfileLimits::max_speed_m_per_s`].
    MaxSpeed,
    /// [`ProfileLimits::max_accel_m_per_s2`].
    MaxAccel,
    /// [`ProfileLimits::stroke_min_m`].
    StrokeMin,
    /// [`ProfileLimits::stroke_max_m`].
    StrokeMax,
}

impl ProfileField {
    /// The field's name (`"max_speed_m_per_s"`, ...).
    pub fn name(self) -> &'static str {
        match self {
            ProfileField::MaxSpeed => "max_speed_m_per_s",
            ProfileField::MaxAccel => "max_accel_m_per_s2",
            ProfileField::StrokeMin => "stroke_min_m",
            ProfileField::StrokeMax => "stroke_max_m",
        }
    }

    /// The field's path in a drive's settings (`"motion.limits.max_speed_m_per_s"`,
    /// ...), as the drive's `DriveConfigError` names it.
    pub fn config_path(self) -> &'static str {
        match self {
            ProfileField::MaxSpeed => "motion.limits.max_speed_m_per_s",
            ProfileField::MaxAccel => "motion.limits.max_accel_m_per_s2",
            ProfileField::StrokeMin => "motion.limits.stroke_min_m",
            ProfileField::StrokeMax => "motion.limits.stroke_max_m",
        }
    }
}

impl ProfileLimits {
    /// Checks the limits on their own (not against a motor: that is
    /// the drive's `DriveConfig::check_profile`): the
    /// speed and the acceleration positive and finite, the stroke's ends finite with
    /// `stroke_min_m < stroke_max_m`. The first bad field is named.
    pub fn validate(&self) -> Result<(), ProfileField> {
        if !self.stroke_min_m.is_finite() {
            return Err(ProfileField::StrokeMin);
        }
        if !(self.stroke_max_m.is_finite() && self.stroke_max_m > self.stroke_min_m) {
            return Err(ProfileField::StrokeMax);
        }
        if !positive(self.max_speed_m_per_s) {
            return Err(ProfileField::MaxSpeed);
        }
        if !positive(self.max_accel_m_per_s2) {
            return Err(ProfileField::MaxAccel);
        }
        Ok(())
    }
}

/// One move: go to `target_m`, then stay there for `dwell_s`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Move {
    /// Target position, m (within the stroke).
    pub target_m: f32,
    /// Time to hold the target once reached before the next move starts, s (>= 0).
    pub dwell_s: f32,
}

/// The reference trajectory at one instant, SI.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Setpoint {
    /// Reference position, m.
    pub position_m: f32,
    /// Reference speed, m/s.
    pub speed_m_per_s: f32,
    /// Reference acceleration, m/s^2 (the speed change of this step over its period).
    pub accel_m_per_s2: f32,
}

/// Why a profile or a move was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MotionError {
    /// A limit is not a positive finite number, or the stroke is empty.
    BadLimits,
    /// The target is not finite or lies outside the stroke.
    Unreachable,
    /// The dwell is negative or not finite.
    BadDwell,
    /// The move queue is full.
    QueueFull,
}

/// The period a profile steps by, formed once: in `T` for the speed, and half of it and
/// its inverse in `f32`, for the position (which integrates in `f32`: rounded in Q8.24,
/// the product would add half an LSB of position a step, 13 um over a 0.3 m move at
/// 1 kHz) and the acceleration (Q8.24 cannot hold `1 / dt`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Period<T> {
    /// The period, s.
    dt_s: T,
    /// Half of it, s.
    half_s: f32,
    /// Its inverse, 1/s.
    inverse_per_s: f32,
}

impl<T: Scalar> Period<T> {
    /// A period of `dt_s` (s); `None` unless it is positive, finite and `T` holds it
    /// (Q8.24 to within 2^-24 s). Not inlined: a setting formed once.
    #[inline(never)]
    pub fn new(dt_s: f32) -> Option<Self> {
        // Not positive or NaN gives zero or less in every `T`; too large, an invalid one.
        let dt = T::from_f32(dt_s);
        (dt > T::ZERO && dt.is_valid()).then(|| {
            // The period as `T` holds it: the speed and the position integrate the same.
            let held = dt.to_f32();
            Period { dt_s: dt, half_s: 0.5 * held, inverse_per_s: 1.0 / held }
        })
    }
}

/// Positions closer than this count as reached (m): 1 um.
const REACHED_M: f32 = 1e-6;

/// The profile generator with a queue of up to `N` moves, its speed in the working type
/// `T`. See the module docs.
#[derive(Clone, Debug)]
pub struct Profile<T, const N: usize> {
    limits: ProfileLimits,
    /// [`ProfileLimits::max_speed_m_per_s`] and [`ProfileLimits::max_accel_m_per_s2`] in
    /// `T` (m/s, m/s^2).
    max_speed: T,
    max_accel: T,
    /// `sqrt(2 max_accel)` (sqrt(m)/s): the braking curve's factor.
    braking_gain: T,
    /// [`REACHED_M`] in `T` (m).
    reached: T,
    queue: Deque<Move, N>,
    /// The move being executed.
    active: Option<Move>,
    /// Dwell time left at the reached target, s.
    dwell_left_s: f32,
    /// The reference speed in `T` (m/s); the setpoint holds it in `f32`.
    speed: T,
    setpoint: Setpoint,
    /// Following a speed: the target speed, m/s ([`Profile::follow_speed`]); `None`
    /// runs the queue.
    speed_target_m_per_s: Option<f32>,
    /// That target in `T` (m/s).
    speed_target: T,
}

impl<T: Scalar, const N: usize> Profile<T, N> {
    /// A profile at rest at `position_m`, with `limits`. Refused (`BadLimits`) when the
    /// limits are invalid ([`ProfileLimits::validate`]) or when `T` cannot hold the top
    /// speed or twice the acceleration limit (the landing step's deceleration): Q8.24
    /// holds up to 128 m/s and 64 m/s^2.
    pub fn new(limits: ProfileLimits, position_m: f32) -> Result<Self, MotionError> {
        limits.validate().map_err(|_| MotionError::BadLimits)?;
        let max_speed = T::from_f32(limits.max_speed_m_per_s);
        let max_accel = T::from_f32(limits.max_accel_m_per_s2);
        if !(max_speed.is_valid() && T::from_f32(2.0 * limits.max_accel_m_per_s2).is_valid()) {
            return Err(MotionError::BadLimits);
        }
        let mut p = Profile {
            limits,
            max_speed,
            max_accel,
            braking_gain: T::from_f32(sqrt_rounded(2.0 * limits.max_accel_m_per_s2)),
            reached: T::from_f32(REACHED_M),
            queue: Deque::new(),
            active: None,
            dwell_left_s: 0.0,
            speed: T::ZERO,
            setpoint: Setpoint::default(),
            speed_target_m_per_s: None,
            speed_target: T::ZERO,
        };
        p.reset(position_m);
        Ok(p)
    }

    /// The limits.
    pub fn limits(&self) -> &ProfileLimits {
        &self.limits
    }

    /// Queues a move; refused (queue unchanged) if the target is outside the stroke,
    /// the dwell is invalid, or the queue is full.
    pub fn push(&mut self, m: Move) -> Result<(), MotionError> {
        if !(m.target_m.is_finite()
            && m.target_m >= self.limits.stroke_min_m
            && m.target_m <= self.limits.stroke_max_m)
        {
            return Err(MotionError::Unreachable);
        }
        if !(m.dwell_s.is_finite() && m.dwell_s >= 0.0) {
            return Err(MotionError::BadDwell);
        }
        self.queue.push_back(m).map_err(|_| MotionError::QueueFull)
    }

    /// Drops every queued move and the active one, and holds the reference at rest at
    /// `position_m` (0 if not finite).
    pub fn reset(&mut self, position_m: f32) {
        self.queue.clear();
        self.hold_at(position_m);
    }

    /// Holds the reference at rest at `position_m` (0 if not finite), abandoning the
    /// active move but keeping the queued ones (e.g. on enable, from the estimated
    /// position).
    pub fn hold_at(&mut self, position_m: f32) {
        self.active = None;
        self.dwell_left_s = 0.0;
        self.speed_target_m_per_s = None;
        let x = if position_m.is_finite() { position_m } else { 0.0 };
        self.speed = T::ZERO;
        self.setpoint = Setpoint { position_m: x, speed_m_per_s: 0.0, accel_m_per_s2: 0.0 };
    }

    /// `true` when no move is active or queued and the reference is at rest.
    pub fn is_idle(&self) -> bool {
        self.active.is_none() && self.queue.is_empty() && self.speed_target_m_per_s.is_none()
    }

    /// Follows a speed from now on: the reference starts at `position_m` (m) moving at
    /// `speed_m_per_s` (m/s) and ramps towards
    /// `target_m_per_s` (m/s, clamped to the speed limit) at the acceleration limit; the
    /// queue is dropped. Values that are not finite count as 0.
    /// [`Profile::set_speed_target`] moves the target, [`Profile::reset`] and
    /// [`Profile::hold_at`] end it.
    pub fn follow_speed(&mut self, position_m: f32, speed_m_per_s: f32, target_m_per_s: f32) {
        self.reset(position_m);
        let v = if speed_m_per_s.is_finite() { speed_m_per_s } else { 0.0 };
        self.speed = T::from_f32(v);
        self.setpoint.speed_m_per_s = v;
        self.set_speed_target(target_m_per_s);
    }

    /// The speed the reference ramps to while following a speed, m/s (clamped to the
    /// speed limit; not finite counts as 0). No effect on a profile running its queue.
    pub fn set_speed_target(&mut self, target_m_per_s: f32) {
        if self.speed_target_m_per_s.is_none() && !self.is_idle() {
            return;
        }
        let top = self.limits.max_speed_m_per_s;
        let v = if target_m_per_s.is_finite() { target_m_per_s.clamp_to(-top, top) } else { 0.0 };
        if self.speed_target_m_per_s != Some(v) {
            self.speed_target_m_per_s = Some(v);
            self.speed_target = T::from_f32(v);
        }
    }

    /// The target speed while following a speed (m/s), `None` while running the queue.
    pub fn speed_target(&self) -> Option<f32> {
        self.speed_target_m_per_s
    }

    /// Number of moves waiting (not counting the active one).
    pub fn queued(&self) -> usize {
        self.queue.len()
    }

    /// The present setpoint.
    pub fn setpoint(&self) -> Setpoint {
        self.setpoint
    }

    /// Advances the reference by one `period`.
    pub fn step(&mut self, period: &Period<T>) -> Setpoint {
        let dt_s = period.dt_s;
        let dv_max = self.max_accel * dt_s;
        let v = self.speed;
        if self.speed_target_m_per_s.is_some() {
            let v_new = v + (self.speed_target - v).clamp_to(-dv_max, dv_max);
            return self.advance(v, v_new, period, None);
        }
        if self.active.is_none() {
            self.active = self.queue.pop_front();
            self.dwell_left_s = self.active.map_or(0.0, |m| m.dwell_s);
        }
        let Some(m) = self.active else {
            self.speed = T::ZERO;
            self.setpoint.speed_m_per_s = 0.0;
            self.setpoint.accel_m_per_s2 = 0.0;
            return self.setpoint;
        };
        // The distance to go in f32 (a position is not bounded by T's range), its
        // magnitude in T (saturated where T cannot hold it: the braking speed is then
        // the top speed).
        let e_m = m.target_m - self.setpoint.position_m;
        let toward_target = e_m >= 0.0;
        let distance = T::from_f32(e_m).abs();
        if distance <= self.reached && v.abs() <= dv_max {
            // At the target: hold, count the dwell down, then take the next move.
            self.speed = T::ZERO;
            self.setpoint = Setpoint { position_m: m.target_m, speed_m_per_s: 0.0, accel_m_per_s2: 0.0 };
            self.dwell_left_s -= dt_s.to_f32();
            if self.dwell_left_s <= 0.0 {
                self.active = None;
            }
            return self.setpoint;
        }
        // The fastest speed for the end of this step from which braking at a_max still
        // stops at the target: after the step, `|e| - (|v| + v_new) dt / 2` must be at
        // least `v_new^2 / (2 a)` (exact for the trapezoidal integration of a linear
        // speed ramp). Solving for v_new, the discrete braking curve:
        // `v_new = sqrt((a dt / 2)^2 + 2 a room) - a dt / 2`, `room = |e| - v_toward dt / 2`,
        // formed as `sqrt(2 a) sqrt(room + a dt^2 / 8)` so that no intermediate exceeds
        // the distance or the braking speed (Q8.24 saturates, at worst, a speed above the
        // top speed).
        let toward = if toward_target { v } else { -v };
        let room = distance - T::HALF * toward * dt_s;
        let room = if room > T::ZERO { room } else { T::ZERO };
        let half = T::HALF * dv_max;
        let quarter_dt = T::HALF * (T::HALF * dt_s);
        let braking = self.braking_gain * Scalar::sqrt(room + half.mul_nearest(quarter_dt)) - half;
        let braking = if braking < self.max_speed { braking } else { self.max_speed };
        let v_des = if toward_target { braking } else { -braking };
        let v_new = v + (v_des - v).clamp_to(-dv_max, dv_max);
        // Reaching (or about to pass) the target at a crawl: land on it (a speed step of
        // at most 2 a dt).
        let landing = v.abs() <= T::TWO * dv_max;
        self.advance(v, v_new, period, landing.then_some(m.target_m))
    }

    /// Integrates the speed `v -> v_new` (m/s in `T`) over `period` into the position
    /// (trapezoidal, in `f32`); with `land_m`, a step that reaches or passes that target
    /// ends on it at rest.
    fn advance(&mut self, v: T, v_new: T, period: &Period<T>, land_m: Option<f32>) -> Setpoint {
        let x = self.setpoint.position_m;
        let mut x_new = x + (v + v_new).to_f32() * period.half_s;
        let mut v_out = v_new;
        if let Some(target_m) = land_m
            && (target_m - x_new) * (target_m - x) <= 0.0
        {
            x_new = target_m;
            v_out = T::ZERO;
        }
        self.speed = v_out;
        self.setpoint = Setpoint {
            position_m: x_new,
            speed_m_per_s: v_out.to_f32(),
            accel_m_per_s2: (v_out - v).to_f32() * period.inverse_per_s,
        };
        self.setpoint
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::num::Q24;

    fn limits() -> ProfileLimits {
        ProfileLimits {
            max_speed_m_per_s: 0.5,
            max_accel_m_per_s2: 3.0,
            stroke_min_m: -0.01,
            stroke_max_m: 0.31,
        }
    }

    /// The absolute resolution of `T`: 2^-24 for Q8.24; 0 for the floats, whose
    /// rounding the relative tolerances below cover.
    fn quantum<T: Scalar>() -> f64 {
        if T::from_f32(1e-9) == T::ZERO { 1.0 / 16_777_216.0 } else { 0.0 }
    }

    /// Runs one move from rest; returns (duration s, max |v|, max |a|, final setpoint).
    fn run<T: Scalar>(d: f32, dt: f32) -> (f32, f32, f32, Setpoint) {
        let mut p: Profile<T, 4> = Profile::new(limits(), 0.0).unwrap();
        p.push(Move { target_m: d, dwell_s: 0.0 }).unwrap();
        let (mut t, mut vmax, mut amax) = (0.0f32, 0.0f32, 0.0f32);
        let mut s = p.setpoint();
        for _ in 0..1_000_000 {
            s = p.step(&Period::new(dt).unwrap());
            vmax = vmax.max(s.speed_m_per_s.abs());
            amax = amax.max(s.accel_m_per_s2.abs());
            if p.is_idle() {
                break;
            }
            t += dt;
        }
        (t, vmax, amax, s)
    }

    fn moves_take_the_time_optimal_trapezoid_or_triangle_and_land_exactly_in<T: Scalar>() {
        let (v, a) = (0.5f32, 3.0f32);
        for dt in [1e-4f32, 1e-3] {
            for d in [0.3f32, 0.2, 0.05, 0.01, -0.01 + 0.0] {
                let (t, vmax, amax, s) = run::<T>(d, dt);
                // Analytic minimum time: trapezoid if the move reaches v_max, else triangle.
                let expected =
                    if d.abs() >= v * v / a { d.abs() / v + v / a } else { 2.0 * (d.abs() / a).sqrt() };
                assert!((t - expected).abs() < 0.01 * expected + 5.0 * dt, "d {d}: {t} s vs {expected} s");
                assert!(vmax <= v * (1.0 + 1e-6), "d {d}: speed {vmax}");
                // The landing step may brake a little harder than a_max (at most one
                // step's worth of speed, 2 a dt, over dt), plus a quantum of speed over dt.
                let bound = 2.0 * a * (1.0 + 1e-5) + (2.0 * quantum::<T>() / f64::from(dt)) as f32;
                assert!(amax <= bound, "d {d}: accel {amax}");
                assert_eq!(s.position_m, d);
                assert_eq!(s.speed_m_per_s, 0.0);
            }
        }
    }

    #[test]
    fn moves_take_the_time_optimal_trapezoid_or_triangle_and_land_exactly() {
        moves_take_the_time_optimal_trapezoid_or_triangle_and_land_exactly_in::<f64>();
        moves_take_the_time_optimal_trapezoid_or_triangle_and_land_exactly_in::<f32>();
        moves_take_the_time_optimal_trapezoid_or_triangle_and_land_exactly_in::<Q24>();
    }

    fn a_queue_of_moves_runs_in_order_and_position_is_the_integral_of_speed_in<T: Scalar>() {
        let dt = 1e-4;
        let mut p: Profile<T, 4> = Profile::new(limits(), 0.0).unwrap();
        for (x, d) in [(0.3, 0.1), (0.0, 0.1), (0.15, 0.0)] {
            p.push(Move { target_m: x, dwell_s: d }).unwrap();
        }
        let mut integral = 0.0f64;
        let mut prev_v = 0.0f32;
        let mut reached = [false; 3];
        let mut t = 0.0;
        while !p.is_idle() && t < 10.0 {
            let s = p.step(&Period::new(dt).unwrap());
            integral += 0.5 * f64::from(prev_v + s.speed_m_per_s) * f64::from(dt);
            prev_v = s.speed_m_per_s;
            for (i, x) in [0.3f32, 0.0, 0.15].iter().enumerate() {
                if s.position_m == *x && s.speed_m_per_s == 0.0 && (i == 0 || reached[i - 1]) {
                    reached[i] = true;
                }
            }
            t += dt;
        }
        assert!(reached.iter().all(|r| *r), "{reached:?}");
        // Two 0.3 m moves (0.6 + 0.1667 s each), a 0.15 m move (0.3 + 0.1667 s), two dwells.
        let expected = 2.0 * (0.6 + 0.5 / 3.0) + (0.3 + 0.5 / 3.0) + 0.2;
        assert!((t - expected).abs() < 0.01, "{t} vs {expected}");
        // The landing snaps absorb only sub-micrometre residuals; in Q8.24 the period
        // itself is rounded (1e-4 s to 3e-4 relative), which the position integrates
        // and the integral here does not: 3e-4 of the 0.75 m travelled.
        let period_error = f64::from(T::from_f32(dt).to_f32()) / f64::from(dt) - 1.0;
        let bound = 1e-4 + period_error.abs() * 0.75;
        assert!((integral - 0.15).abs() < bound, "{integral}");
    }

    #[test]
    fn a_queue_of_moves_with_dwells_runs_in_order_and_position_is_the_integral_of_speed() {
        a_queue_of_moves_runs_in_order_and_position_is_the_integral_of_speed_in::<f64>();
        a_queue_of_moves_runs_in_order_and_position_is_the_integral_of_speed_in::<f32>();
        a_queue_of_moves_runs_in_order_and_position_is_the_integral_of_speed_in::<Q24>();
    }

    fn following_a_speed_in<T: Scalar>() {
        let dt = 1e-4f32;
        let mut p: Profile<T, 2> = Profile::new(limits(), 0.0).unwrap();
        // From 0.4 m/s towards -0.4 at the 3 m/s^2 limit.
        p.push(Move { target_m: 0.2, dwell_s: 0.0 }).unwrap();
        p.follow_speed(0.1, 0.4, -0.4);
        assert!(!p.is_idle());
        assert_eq!(p.queued(), 0, "following a speed drops the queue");
        // The reference on the period as `T` holds it; a speed step of 3 m/s^2 dt is
        // rounded down by at most a quantum each step.
        let dt_t = Period::<T>::new(dt).unwrap();
        let h = f64::from(T::from_f32(dt).to_f32());
        let (mut x, mut v) = (0.1f64, 0.4f64);
        let mut crossed_at = None;
        for k in 1..=4000 {
            let s = p.step(&dt_t);
            let v_new = (v - 3.0 * h).max(-0.4);
            x += 0.5 * (v + v_new) * h;
            v = v_new;
            let tol = 1e-5 + quantum::<T>() * f64::from(k);
            assert!((f64::from(s.speed_m_per_s) - v).abs() < tol, "step {k}: {} vs {v}", s.speed_m_per_s);
            let bound = 3.0 * (1.0 + 1e-4) + (2.0 * quantum::<T>() / h) as f32;
            assert!(s.accel_m_per_s2.abs() <= bound);
            if crossed_at.is_none() && s.speed_m_per_s <= 0.0 {
                crossed_at = Some(k);
            }
        }
        // 0.4 m/s at 3 m/s^2: zero after 0.1333 s; -0.4 after 0.2667 s; then constant.
        assert!((crossed_at.unwrap() as f32 * dt - 0.4 / 3.0).abs() < 2.0 * dt);
        assert!(f64::from(p.setpoint().speed_m_per_s + 0.4).abs() <= quantum::<T>());
        // The speed's error, at most a quantum per step, integrated over the 4000 steps.
        let tol = 1e-5 + quantum::<T>() * h * 4000.0 * 4000.0 / 2.0;
        assert!((f64::from(p.setpoint().position_m) - x).abs() < tol, "{} vs {x}", p.setpoint().position_m);
        // Analytic: 0.1 + 0.4^2/(2*3) - 0.4^2/(2*3) - 0.4 (0.4 - 0.2667) = 0.1 - 0.05333.
        assert!((x - (0.1 - 0.4 * (0.4 - 0.8 / 3.0))).abs() < 1e-4, "{x}");
        // A target beyond the limit is clamped to it; hold_at ends the following.
        p.set_speed_target(-2.0);
        assert_eq!(p.speed_target(), Some(-0.5));
        p.hold_at(0.0);
        assert_eq!(p.speed_target(), None);
        assert_eq!(p.step(&dt_t).speed_m_per_s, 0.0);
    }

    #[test]
    fn following_a_speed_ramps_at_the_limit_through_zero_and_integrates_the_position() {
        following_a_speed_in::<f64>();
        following_a_speed_in::<f32>();
        following_a_speed_in::<Q24>();
    }

    /// Q8.24 (the Cortex-M3's profile) against the f64 reference on the same queue at the
    /// speed loop's period: the reference positions within 1 um every step (0.015 deg
    /// electrical on a 12 mm pole pitch; the drive's floor is 1 deg), the speeds within
    /// 2e-5 m/s while both move (the braking curve's root in Q8.24), and each landing,
    /// a discrete decision, within one period of the reference's.
    #[test]
    fn fixed_point_profile_follows_the_f64_reference() {
        let dt = 1e-3f32;
        let mut q: Profile<Q24, 8> = Profile::new(limits(), 0.0).unwrap();
        let mut r: Profile<f64, 8> = Profile::new(limits(), 0.0).unwrap();
        for (x, d) in [(0.3, 0.05), (0.001, 0.0), (0.2, 0.0), (0.2002, 0.0), (-0.01, 0.0)] {
            q.push(Move { target_m: x, dwell_s: d }).unwrap();
            r.push(Move { target_m: x, dwell_s: d }).unwrap();
        }
        let (mut dx, mut dv) = (0.0f64, 0.0f64);
        let mut landings = ([0usize; 5], [0usize; 5], 0usize, 0usize);
        let (mut va, mut vb) = (0.0f32, 0.0f32);
        for k in 0..5_000 {
            let a = q.step(&Period::new(dt).unwrap());
            let b = r.step(&Period::new(Q24::from_f32(dt).to_f32()).unwrap());
            dx = dx.max(f64::from((a.position_m - b.position_m).abs()));
            if a.speed_m_per_s != 0.0 && b.speed_m_per_s != 0.0 {
                dv = dv.max(f64::from((a.speed_m_per_s - b.speed_m_per_s).abs()));
            }
            if a.speed_m_per_s == 0.0 && va != 0.0 && landings.2 < 5 {
                landings.0[landings.2] = k;
                landings.2 += 1;
            }
            if b.speed_m_per_s == 0.0 && vb != 0.0 && landings.3 < 5 {
                landings.1[landings.3] = k;
                landings.3 += 1;
            }
            (va, vb) = (a.speed_m_per_s, b.speed_m_per_s);
        }
        assert!(q.is_idle() && r.is_idle());
        assert_eq!((landings.2, landings.3), (5, 5), "{landings:?}");
        assert!(landings.0.iter().zip(landings.1).all(|(a, b)| a.abs_diff(b) <= 1), "{landings:?}");
        assert!(dx < 1e-6 && dv < 2e-5, "position {dx} m, speed {dv} m/s apart");
    }

    #[test]
    fn bad_moves_and_limits_are_refused_and_a_full_queue_says_so() {
        let mut p: Profile<f32, 2> = Profile::new(limits(), 0.0).unwrap();
        assert_eq!(p.push(Move { target_m: 0.4, dwell_s: 0.0 }), Err(MotionError::Unreachable));
        assert_eq!(p.push(Move { target_m: f32::NAN, dwell_s: 0.0 }), Err(MotionError::Unreachable));
        assert_eq!(p.push(Move { target_m: 0.1, dwell_s: -1.0 }), Err(MotionError::BadDwell));
        assert!(p.push(Move { target_m: 0.1, dwell_s: 0.0 }).is_ok());
        assert!(p.push(Move { target_m: 0.2, dwell_s: 0.0 }).is_ok());
        assert_eq!(p.push(Move { target_m: 0.3, dwell_s: 0.0 }), Err(MotionError::QueueFull));
        assert_eq!(p.queued(), 2);
        let bad = ProfileLimits { max_speed_m_per_s: 0.0, ..limits() };
        assert_eq!(Profile::<f32, 2>::new(bad, 0.0).err(), Some(MotionError::BadLimits));
        let bad = ProfileLimits { stroke_max_m: -1.0, ..limits() };
        assert_eq!(Profile::<f32, 2>::new(bad, 0.0).err(), Some(MotionError::BadLimits));
        // Limits Q8.24 cannot hold (the landing's 2 a_max above 128 m/s^2) are refused
        // there, and held in f32.
        let fast = ProfileLimits { max_accel_m_per_s2: 70.0, ..limits() };
        assert_eq!(Profile::<Q24, 2>::new(fast, 0.0).err(), Some(MotionError::BadLimits));
        assert!(Profile::<f32, 2>::new(fast, 0.0).is_ok());
        // A period that is not positive and finite, or that Q8.24 rounds to zero, is
        // refused.
        for dt in [f32::NAN, f32::INFINITY, 0.0, -1e-4] {
            assert_eq!(Period::<f32>::new(dt), None, "{dt}");
        }
        assert_eq!(Period::<Q24>::new(1e-8), None);
        assert!(Period::<Q24>::new(1e-7).is_some());
    }
}
