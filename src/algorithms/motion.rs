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
//!                                                     exact discrete form below)
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
//! Everything is SI `f32`: the profile is a planner that runs beside the control step;
//! the drive converts its speed and acceleration into working units.
//! Bounded time, no allocation, no panics: the queue is a [`heapless::Deque`] (fixed
//! capacity, `Err` when full) — a well-kept crate rather than a hand-written ring.

use crate::num::{Scalar, positive};
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

/// Positions closer than this count as reached (m): 1 um.
const REACHED_M: f32 = 1e-6;

/// The profile generator with a queue of up to `N` moves. See the module docs.
#[derive(Clone, Debug)]
pub struct Profile<const N: usize> {
    limits: ProfileLimits,
    queue: Deque<Move, N>,
    /// The move being executed.
    active: Option<Move>,
    /// Dwell time left at the reached target, s.
    dwell_left_s: f32,
    setpoint: Setpoint,
    /// Following a speed: the target speed, m/s ([`Profile::follow_speed`]); `None`
    /// runs the queue.
    speed_target_m_per_s: Option<f32>,
}

impl<const N: usize> Profile<N> {
    /// A profile at rest at `position_m`, with `limits`.
    pub fn new(limits: ProfileLimits, position_m: f32) -> Result<Self, MotionError> {
        limits.validate().map_err(|_| MotionError::BadLimits)?;
        let mut p = Profile {
            limits,
            queue: Deque::new(),
            active: None,
            dwell_left_s: 0.0,
            setpoint: Setpoint::default(),
            speed_target_m_per_s: None,
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
    /// `position_m` (clamped into the stroke; 0 if not finite).
    pub fn reset(&mut self, position_m: f32) {
        self.queue.clear();
        self.active = None;
        self.dwell_left_s = 0.0;
        self.speed_target_m_per_s = None;
        let x = if position_m.is_finite() { position_m } else { 0.0 };
        self.setpoint = Setpoint { position_m: x, speed_m_per_s: 0.0, accel_m_per_s2: 0.0 };
    }

    /// Holds the reference at rest at `position_m` (0 if not finite), abandoning the
    /// active move but keeping the queued ones (e.g. on enable, from the estimated
    /// position).
    pub fn hold_at(&mut self, position_m: f32) {
        self.active = None;
        self.dwell_left_s = 0.0;
        self.speed_target_m_per_s = None;
        let x = if position_m.is_finite() { position_m } else { 0.0 };
        self.setpoint = Setpoint { position_m: x, speed_m_per_s: 0.0, accel_m_per_s2: 0.0 };
    }

    /// `true` when no move is active or queued and the reference is at rest.
    pub fn is_idle(&self) -> bool {
        self.active.is_none() && self.queue.is_empty() && self.speed_target_m_per_s.is_none()
    }

    /// Follows a speed from now on: the reference starts at `position_m` (m) moving at
    /// `speed_m_per_s` (m/s) and ramps towards `target_m_per_s` (m/s, clamped to the
    /// speed limit) at the acceleration limit; the queue is dropped. Values that are not
    /// finite count as 0. [`Profile::set_speed_target`] moves the target,
    /// [`Profile::reset`] and [`Profile::hold_at`] end it.
    pub fn follow_speed(&mut self, position_m: f32, speed_m_per_s: f32, target_m_per_s: f32) {
        self.reset(position_m);
        self.setpoint.speed_m_per_s = if speed_m_per_s.is_finite() { speed_m_per_s } else { 0.0 };
        self.set_speed_target(target_m_per_s);
    }

    /// The speed the reference ramps to while following a speed, m/s (clamped to the
    /// speed limit; not finite counts as 0). No effect on a profile running its queue.
    pub fn set_speed_target(&mut self, target_m_per_s: f32) {
        if self.speed_target_m_per_s.is_none() && !self.is_idle() {
            return;
        }
        let top = self.limits.max_speed_m_per_s;
        let v = if target_m_per_s.is_finite() { target_m_per_s } else { 0.0 };
        self.speed_target_m_per_s = Some(v.clamp_to(-top, top));
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

    /// Advances the reference by `dt_s` (s, > 0; anything else leaves it unchanged).
    pub fn step(&mut self, dt_s: f32) -> Setpoint {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return self.setpoint;
        }
        if let Some(target) = self.speed_target_m_per_s {
            let dv_max = self.limits.max_accel_m_per_s2 * dt_s;
            let v = self.setpoint.speed_m_per_s;
            let v_new = v + (target - v).clamp_to(-dv_max, dv_max);
            self.setpoint = Setpoint {
                position_m: self.setpoint.position_m + 0.5 * (v + v_new) * dt_s,
                speed_m_per_s: v_new,
                accel_m_per_s2: (v_new - v) / dt_s,
            };
            return self.setpoint;
        }
        if self.active.is_none() {
            self.active = self.queue.pop_front();
            self.dwell_left_s = self.active.map_or(0.0, |m| m.dwell_s);
        }
        let Some(m) = self.active else {
            self.setpoint.speed_m_per_s = 0.0;
            self.setpoint.accel_m_per_s2 = 0.0;
            return self.setpoint;
        };
        let a_max = self.limits.max_accel_m_per_s2;
        let x = self.setpoint.position_m;
        let v = self.setpoint.speed_m_per_s;
        let e = m.target_m - x;
        if e.abs() <= REACHED_M && v.abs() <= a_max * dt_s {
            // At the target: hold, count the dwell down, then take the next move.
            self.setpoint = Setpoint { position_m: m.target_m, speed_m_per_s: 0.0, accel_m_per_s2: 0.0 };
            self.dwell_left_s -= dt_s;
            if self.dwell_left_s <= 0.0 {
                self.active = None;
            }
            return self.setpoint;
        }
        // The fastest speed for the end of this step from which braking at a_max still
        // stops at the target: after the step, `|e| - (|v| + v_new) dt / 2` must be at
        // least `v_new^2 / (2 a)` (exact for the trapezoidal integration of a linear
        // speed ramp). Solving for v_new: the discrete braking curve.
        let dv_max = a_max * dt_s;
        let toward = if e >= 0.0 { v } else { -v };
        // Comparisons, not f32::max / f32::min (library calls on FPv4); NaN gives 0 and
        // the top speed, as those calls would.
        let room = e.abs() - 0.5 * toward * dt_s;
        let room = if room > 0.0 { room } else { 0.0 };
        let half = 0.5 * dv_max;
        let braking = Scalar::sqrt(half * half + 2.0 * a_max * room) - half;
        let top = self.limits.max_speed_m_per_s;
        let braking = if braking < top { braking } else { top };
        let v_des = if e >= 0.0 { braking } else { -braking };
        let v_new = v + (v_des - v).clamp_to(-dv_max, dv_max);
        let mut x_new = x + 0.5 * (v + v_new) * dt_s;
        let mut v_out = v_new;
        if (m.target_m - x_new) * e <= 0.0 && v.abs() <= 2.0 * dv_max {
            // Reached (or would pass) the target at a crawl: land on it (a speed step of
            // at most 2 a dt).
            x_new = m.target_m;
            v_out = 0.0;
        }
        self.setpoint =
            Setpoint { position_m: x_new, speed_m_per_s: v_out, accel_m_per_s2: (v_out - v) / dt_s };
        self.setpoint
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> ProfileLimits {
        ProfileLimits {
            max_speed_m_per_s: 0.5,
            max_accel_m_per_s2: 3.0,
            stroke_min_m: -0.01,
            stroke_max_m: 0.31,
        }
    }

    /// Runs one move from rest; returns (duration s, max |v|, max |a|, final setpoint).
    fn run(d: f32, dt: f32) -> (f32, f32, f32, Setpoint) {
        let mut p: Profile<4> = Profile::new(limits(), 0.0).unwrap();
        p.push(Move { target_m: d, dwell_s: 0.0 }).unwrap();
        let (mut t, mut vmax, mut amax) = (0.0f32, 0.0f32, 0.0f32);
        let mut s = p.setpoint();
        for _ in 0..1_000_000 {
            s = p.step(dt);
            vmax = vmax.max(s.speed_m_per_s.abs());
            amax = amax.max(s.accel_m_per_s2.abs());
            if p.is_idle() {
                break;
            }
            t += dt;
        }
        (t, vmax, amax, s)
    }

    #[test]
    fn moves_take_the_time_optimal_trapezoid_or_triangle_and_land_exactly() {
        let dt = 1e-4;
        let (v, a) = (0.5f32, 3.0f32);
        for d in [0.3f32, 0.2, 0.05, 0.01, -0.01 + 0.0] {
            let (t, vmax, amax, s) = run(d, dt);
            // Analytic minimum time: trapezoid if the move reaches v_max, else triangle.
            let expected =
                if d.abs() >= v * v / a { d.abs() / v + v / a } else { 2.0 * (d.abs() / a).sqrt() };
            assert!((t - expected).abs() < 0.01 * expected + 5.0 * dt, "d {d}: {t} s vs {expected} s");
            assert!(vmax <= v * (1.0 + 1e-6), "d {d}: speed {vmax}");
            // The landing step may brake a little harder than a_max (at most one step's
            // worth of speed, 2 a dt, over dt).
            assert!(amax <= 2.0 * a * (1.0 + 1e-5), "d {d}: accel {amax}");
            assert_eq!(s.position_m, d);
            assert_eq!(s.speed_m_per_s, 0.0);
        }
    }

    #[test]
    fn a_queue_of_moves_with_dwells_runs_in_order_and_position_is_the_integral_of_speed() {
        let dt = 1e-4;
        let mut p: Profile<4> = Profile::new(limits(), 0.0).unwrap();
        for (x, d) in [(0.3, 0.1), (0.0, 0.1), (0.15, 0.0)] {
            p.push(Move { target_m: x, dwell_s: d }).unwrap();
        }
        let mut integral = 0.0f64;
        let mut prev_v = 0.0f32;
        let mut reached = [false; 3];
        let mut t = 0.0;
        while !p.is_idle() && t < 10.0 {
            let s = p.step(dt);
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
        // The landing snaps absorb only sub-micrometre residuals.
        assert!((integral - 0.15).abs() < 1e-4, "{integral}");
    }

    #[test]
    fn following_a_speed_ramps_at_the_limit_through_zero_and_integrates_the_position() {
        let dt = 1e-4f32;
        let mut p: Profile<2> = Profile::new(limits(), 0.0).unwrap();
        // From 0.4 m/s towards -0.4 at the 3 m/s^2 limit.
        p.push(Move { target_m: 0.2, dwell_s: 0.0 }).unwrap();
        p.follow_speed(0.1, 0.4, -0.4);
        assert!(!p.is_idle());
        assert_eq!(p.queued(), 0, "following a speed drops the queue");
        let (mut x, mut v) = (0.1f64, 0.4f64);
        let mut crossed_at = None;
        for k in 1..=4000 {
            let s = p.step(dt);
            let v_new = (v - 3.0 * f64::from(dt)).max(-0.4);
            x += 0.5 * (v + v_new) * f64::from(dt);
            v = v_new;
            assert!((f64::from(s.speed_m_per_s) - v).abs() < 1e-5, "step {k}");
            assert!(s.accel_m_per_s2.abs() <= 3.0 * (1.0 + 1e-4));
            if crossed_at.is_none() && s.speed_m_per_s <= 0.0 {
                crossed_at = Some(k);
            }
        }
        // 0.4 m/s at 3 m/s^2: zero after 0.1333 s; -0.4 after 0.2667 s; then constant.
        assert!((crossed_at.unwrap() as f32 * dt - 0.4 / 3.0).abs() < 2.0 * dt);
        assert_eq!(p.setpoint().speed_m_per_s, -0.4);
        assert!((f64::from(p.setpoint().position_m) - x).abs() < 1e-5, "{} vs {x}", p.setpoint().position_m);
        // Analytic: 0.1 + 0.4^2/(2*3) - 0.4^2/(2*3) - 0.4 (0.4 - 0.2667) = 0.1 - 0.05333.
        assert!((x - (0.1 - 0.4 * (0.4 - 0.8 / 3.0))).abs() < 1e-4, "{x}");
        // A target beyond the limit is clamped to it; hold_at ends the following.
        p.set_speed_target(-2.0);
        assert_eq!(p.speed_target(), Some(-0.5));
        p.hold_at(0.0);
        assert_eq!(p.speed_target(), None);
        assert_eq!(p.step(dt).speed_m_per_s, 0.0);
    }

    #[test]
    fn bad_moves_and_limits_are_refused_and_a_full_queue_says_so() {
        let mut p: Profile<2> = Profile::new(limits(), 0.0).unwrap();
        assert_eq!(p.push(Move { target_m: 0.4, dwell_s: 0.0 }), Err(MotionError::Unreachable));
        assert_eq!(p.push(Move { target_m: f32::NAN, dwell_s: 0.0 }), Err(MotionError::Unreachable));
        assert_eq!(p.push(Move { target_m: 0.1, dwell_s: -1.0 }), Err(MotionError::BadDwell));
        assert!(p.push(Move { target_m: 0.1, dwell_s: 0.0 }).is_ok());
        assert!(p.push(Move { target_m: 0.2, dwell_s: 0.0 }).is_ok());
        assert_eq!(p.push(Move { target_m: 0.3, dwell_s: 0.0 }), Err(MotionError::QueueFull));
        assert_eq!(p.queued(), 2);
        let bad = ProfileLimits { max_speed_m_per_s: 0.0, ..limits() };
        assert_eq!(Profile::<2>::new(bad, 0.0).err(), Some(MotionError::BadLimits));
        let bad = ProfileLimits { stroke_max_m: -1.0, ..limits() };
        assert_eq!(Profile::<2>::new(bad, 0.0).err(), Some(MotionError::BadLimits));
        // A bad period leaves the reference where it is.
        let before = p.setpoint();
        assert_eq!(p.step(f32::NAN), before);
        assert_eq!(p.step(0.0), before);
    }
}
