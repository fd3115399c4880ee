//! A position, speed and load observer on the moving mass: the speed and the thrust the
//! axis needs (load, friction) from a noisy position measurement and the thrust the drive
//! commands.
//!
//! ## Model and loop
//! The mover is a mass `M` pushed by the drive's thrust `F` (N) against a load `L` (N,
//! friction and outside forces, slowly varying):
//!
//! ```text
//! x' = v,   v' = (F - L) / M,   L' = 0
//! ```
//!
//! With the innovation `e = x_meas - x_hat`, the observer is the model plus corrections,
//!
//! ```text
//! x_hat' = v_hat + l1 e
//! v_hat' = (F - L_hat) / M + l2 e
//! L_hat' = -M l3 e
//! ```
//!
//! and its error dynamics have the characteristic polynomial `s^3 + l1 s^2 + l2 s + l3`.
//! The gains place a triple pole at `-w_o`: `l1 = 3 w_o`, `l2 = 3 w_o^2`, `l3 = w_o^3`.
//!
//! ## Why it is here: speed at standstill without differentiating noise
//! At rest the position comes from high-frequency injection, whose angle carries noise
//! (1.3 deg RMS on the salient test motor); the tracking loop's integrator, used as the
//! speed, carries that noise differentiated, and a speed loop stiff enough to hold a load
//! step turned it into ±5 A of thrust-current noise, which shook the mover by ±5 mm.
//! Here the speed is the integral of the known thrust over the mass, corrected by the
//! position at `w_o`: the measurement noise reaches `v_hat` through a band-pass of
//! bandwidth about `w_o`, not a differentiator. The load estimate is what an integrator
//! in a position loop would wind up to, and it is known at once as a force, so the
//! drive feeds it forward and a PD law on `(x_hat, v_hat)` holds the position.
//!
//! ## Response to a load step (analytic, used by the tests)
//! The transfer function from the true load to the estimate is `w_o^3 / (s + w_o)^3`:
//! unity at DC (no lasting error), a step of the load is estimated along
//! `1 - e^{-w_o t} (1 + w_o t + (w_o t)^2 / 2)`.
//!
//! ## Discretisation, working units and bounds
//! Forward Euler at the control period, in states scaled by the bandwidth so that every
//! gain of the recursion is at most one and the states stay small in fixed point: with
//! `h = w_o dt`, `z2 = v_hat / w_o` and `z3 = L_hat / (M w_o^2)` (all three in metres),
//!
//! ```text
//! x_hat += h (z2 + 3 e)
//! z2    += h (g F - z3 + 3 e)        g = 1 / (M w_o^2), per unit of thrust
//! z3    -= h e
//! ```
//!
//! which is exactly the Euler step of the model above, rescaled. Stable for `w_o dt` up to
//! about 0.5; [`LoadObserver::new`] refuses `w_o dt > 0.25`, and a configuration whose constants the
//! working type cannot hold. The thrust comes in the caller's unit
//! ([`LoadObserverConfig::thrust_unit_n`], N per unit: the drive passes its thrust current
//! in working units). The load estimate is clamped to `±load_limit_n` and the speed to
//! `±speed_limit_m_per_s`, so a wrong input cannot wind the states up; an invalid input
//! (NaN, saturated) leaves the state unchanged and returns `false`.
//!
//! ## The hold
//! [`LoadObserver::hold_thrust`] is the state feedback that holds a target on these
//! estimates, `F = M (a_ref + 2 w_c (v_ref - v_hat) + w_c^2 (x_ref - x_hat)) + L_hat` at
//! `w_c = hold_ratio w_o`, formed in the scaled states (one division by `g`).
//!
//! ## Accuracy and cost
//! `f32` and `f64` follow the recursion to their rounding; in Q8.24 a state moves in steps
//! of 2^-24 m (6e-8 m), so a position error below about `2^-25 / h` m (4 um at
//! `h = 0.008`) no longer moves the load estimate: far below any position measurement's
//! noise. The tests run the analytic load step in `f64`, `f32` and Q8.24. Per period: five
//! rounded products and two clamps; the hold adds two products and a division.

#![forbid(unsafe_code)]

use crate::num::{Scalar, positive};

/// Gains and limits of a [`LoadObserver`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoadObserverConfig {
    /// Moving mass, kg (> 0).
    pub mass_kg: f32,
    /// Observer bandwidth `w_o` (the triple pole), rad/s (> 0).
    pub bandwidth_rad_s: f32,
    /// Control period, s (> 0).
    pub dt_s: f32,
    /// Largest load estimate, N (> 0): the thrust the drive can produce.
    pub load_limit_n: f32,
    /// Largest speed estimate, m/s (> 0).
    pub speed_limit_m_per_s: f32,
    /// The thrust input's unit, N (> 0): 1 for newtons; the drive's thrust constant times
    /// its base current for a thrust current in working units.
    pub thrust_unit_n: f32,
    /// The hold's bandwidth as a share of the observer's, `w_c / w_o`, in (0, 1].
    pub hold_ratio: f32,
}

/// A configuration the observer cannot run with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoadObserverConfigError {
    /// A field is not a positive finite number, `w_o dt > 0.25`, `hold_ratio > 1`, or a
    /// constant the working type cannot hold; names the field.
    Invalid(&'static str),
}

/// `x` as a working value, or the error naming `field` when the working type cannot hold
/// it within 1 % (beyond fixed point's range, zero in it, NaN).
fn representable<T: Scalar>(x: f32, field: &'static str) -> Result<T, LoadObserverConfigError> {
    let v = T::from_f32(x);
    let back = v.to_f32();
    if v.is_valid() && back != 0.0 && libm::fabsf(back - x) <= 0.01 * libm::fabsf(x) {
        Ok(v)
    } else {
        Err(LoadObserverConfigError::Invalid(field))
    }
}

/// A target of [`LoadObserver::hold_thrust`] in the observer's scaled units: the
/// position (m), the speed over `w_o` (m) and the acceleration over `w_o^2` (m).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HoldTarget<T> {
    x_m: T,
    v_scaled_m: T,
    a_scaled_m: T,
}

/// Position, speed and load observer, generic over the working type. See the module docs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoadObserver<T> {
    /// `w_o dt`.
    h: T,
    /// `g`: metres of `z2`/`z3` per unit of thrust (`thrust_unit_n / (M w_o^2)`).
    scaled_per_thrust: T,
    /// `2 hold_ratio` and `hold_ratio^2`.
    two_ratio: T,
    ratio_sq: T,
    /// The limits of `z2` and `z3` (m) and of the hold's thrust (units of thrust).
    speed_limit: T,
    load_limit: T,
    thrust_limit: T,
    /// `1 / w_o` (s) and `1 / w_o^2` (s^2): SI to scaled, for presets and targets.
    inv_w: f32,
    inv_w_sq: f32,
    /// `w_o` (rad/s) and `M w_o^2` (N/m): scaled to SI, for telemetry.
    w: f32,
    mass_w_sq: f32,
    x_hat_m: T,
    z2: T,
    z3: T,
}

impl<T: Scalar> LoadObserver<T> {
    /// Builds an observer from `config`, at rest at position 0 with no load. Always
    /// inlined: its one caller, the drive's constructor, is where a drive without HFI
    /// drops it whole (an outlined copy costs the ESC1 image about 1 KB of flash).
    #[inline(always)]
    pub fn new(config: &LoadObserverConfig) -> Result<Self, LoadObserverConfigError> {
        let c = config;
        for (ok, field) in [
            (positive(c.mass_kg), "mass_kg"),
            (positive(c.bandwidth_rad_s), "bandwidth_rad_s"),
            (positive(c.dt_s), "dt_s"),
            (positive(c.load_limit_n), "load_limit_n"),
            (positive(c.speed_limit_m_per_s), "speed_limit_m_per_s"),
            (positive(c.thrust_unit_n), "thrust_unit_n"),
            (positive(c.hold_ratio) && c.hold_ratio <= 1.0, "hold_ratio"),
            (c.bandwidth_rad_s * c.dt_s <= 0.25, "bandwidth_rad_s"),
        ] {
            if !ok {
                return Err(LoadObserverConfigError::Invalid(field));
            }
        }
        let w = c.bandwidth_rad_s;
        let mass_w_sq = c.mass_kg * w * w;
        let r = c.hold_ratio;
        Ok(LoadObserver {
            h: representable::<T>(w * c.dt_s, "bandwidth_rad_s")?,
            scaled_per_thrust: representable::<T>(c.thrust_unit_n / mass_w_sq, "thrust_unit_n")?,
            two_ratio: representable::<T>(2.0 * r, "hold_ratio")?,
            ratio_sq: representable::<T>(r * r, "hold_ratio")?,
            speed_limit: representable::<T>(c.speed_limit_m_per_s / w, "speed_limit_m_per_s")?,
            load_limit: representable::<T>(c.load_limit_n / mass_w_sq, "load_limit_n")?,
            thrust_limit: representable::<T>(c.load_limit_n / c.thrust_unit_n, "load_limit_n")?,
            inv_w: 1.0 / w,
            inv_w_sq: 1.0 / (w * w),
            w,
            mass_w_sq,
            x_hat_m: T::ZERO,
            z2: T::ZERO,
            z3: T::ZERO,
        })
    }

    /// Starts from position `x_m` (m), speed `v_m_per_s` (m/s) and load `load_n` (N),
    /// each clamped to its limit (non-finite values read as 0).
    pub fn preset(&mut self, x_m: f32, v_m_per_s: f32, load_n: f32) {
        let finite = |x: f32| if x.is_finite() { x } else { 0.0 };
        self.x_hat_m = T::from_f32(finite(x_m));
        self.z2 = T::from_f32(finite(v_m_per_s) * self.inv_w).clamp_to(-self.speed_limit, self.speed_limit);
        self.z3 = T::from_f32(finite(load_n) / self.mass_w_sq).clamp_to(-self.load_limit, self.load_limit);
    }

    /// One control period: the measured position `x_meas_m` (m) and the thrust the drive
    /// applied during the period, `thrust` (units of [`LoadObserverConfig::thrust_unit_n`]).
    /// Returns `false` (state unchanged) if either is not valid.
    pub fn update(&mut self, x_meas_m: T, thrust: T) -> bool {
        if !(x_meas_m.is_valid() && thrust.is_valid()) {
            return false;
        }
        let e = x_meas_m - self.x_hat_m;
        let three_e = e.mul_nearest(T::TWO + T::ONE);
        // Rounded products: an Euler step's increments are a few LSB in fixed point, and
        // rounded down they would drift.
        let dx = (self.z2 + three_e).mul_nearest(self.h);
        let dz2 = (thrust.mul_nearest(self.scaled_per_thrust) - self.z3 + three_e).mul_nearest(self.h);
        let dz3 = e.mul_nearest(self.h);
        self.x_hat_m = self.x_hat_m + dx;
        self.z2 = (self.z2 + dz2).clamp_to(-self.speed_limit, self.speed_limit);
        self.z3 = (self.z3 - dz3).clamp_to(-self.load_limit, self.load_limit);
        true
    }

    /// The target position `x_m` (m), speed `v_m_per_s` (m/s) and acceleration
    /// `a_m_per_s2` (m/s^2) of [`LoadObserver::hold_thrust`], in the observer's units.
    pub fn target(&self, x_m: f32, v_m_per_s: f32, a_m_per_s2: f32) -> HoldTarget<T> {
        HoldTarget {
            x_m: T::from_f32(x_m),
            v_scaled_m: T::from_f32(v_m_per_s * self.inv_w),
            a_scaled_m: T::from_f32(a_m_per_s2 * self.inv_w_sq),
        }
    }

    /// The thrust (units of [`LoadObserverConfig::thrust_unit_n`]) that holds `target` on
    /// the estimates (module docs, "The hold"), within the load limit's thrust.
    pub fn hold_thrust(&self, target: &HoldTarget<T>) -> T {
        let scaled = target.a_scaled_m
            + self.two_ratio * (target.v_scaled_m - self.z2)
            + self.ratio_sq * (target.x_m - self.x_hat_m)
            + self.z3;
        self.thrust_of(scaled)
    }

    /// The thrust (units of [`LoadObserverConfig::thrust_unit_n`]) that balances the
    /// estimated load, within the load limit's thrust: [`LoadObserver::hold_thrust`] with
    /// no acceleration and no state error, what holds the mover where it is on average.
    pub fn load_thrust(&self) -> T {
        self.thrust_of(self.z3)
    }

    /// The thrust of a scaled force `scaled` (m: force over `M w_o^2`), within the load
    /// limit's thrust. Not inlined: one copy for the hold and its exit (flash).
    #[inline(never)]
    fn thrust_of(&self, scaled: T) -> T {
        match scaled.checked_div(self.scaled_per_thrust) {
            Some(f) => f.clamp_to(-self.thrust_limit, self.thrust_limit),
            None if scaled < T::ZERO => -self.thrust_limit,
            None => self.thrust_limit,
        }
    }

    /// Estimated position, m.
    pub fn position_m(&self) -> T {
        self.x_hat_m
    }

    /// Estimated speed over the observer's bandwidth, `v_hat / w_o` (m): the state as the
    /// recursion holds it, for a caller that scales it by a constant of its own formed
    /// once (`w_o` times its unit per m/s) instead of converting through `f32`.
    pub fn speed_over_bandwidth_m(&self) -> T {
        self.z2
    }

    /// Estimated speed, m/s (telemetry and tests: formed in `f32`).
    pub fn speed_m_per_s(&self) -> f32 {
        self.z2.to_f32() * self.w
    }

    /// Estimated load (friction and outside forces, opposing positive thrust), N
    /// (telemetry and tests: formed in `f32`).
    pub fn load_n(&self) -> f32 {
        self.z3.to_f32() * self.mass_w_sq
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::num::Q24;

    fn config(w: f32) -> LoadObserverConfig {
        LoadObserverConfig {
            mass_kg: 5.0,
            bandwidth_rad_s: w,
            dt_s: 1e-4,
            load_limit_n: 100.0,
            speed_limit_m_per_s: 5.0,
            thrust_unit_n: 1.0,
            hold_ratio: 0.5,
        }
    }

    #[test]
    fn refuses_bad_configurations_by_name() {
        let mut c = config(80.0);
        c.mass_kg = 0.0;
        assert_eq!(LoadObserver::<f32>::new(&c), Err(LoadObserverConfigError::Invalid("mass_kg")));
        let mut c = config(80.0);
        c.dt_s = f32::NAN;
        assert_eq!(LoadObserver::<f32>::new(&c), Err(LoadObserverConfigError::Invalid("dt_s")));
        assert_eq!(
            LoadObserver::<f32>::new(&config(3000.0)),
            Err(LoadObserverConfigError::Invalid("bandwidth_rad_s"))
        );
        let mut c = config(80.0);
        c.hold_ratio = 1.5;
        assert_eq!(LoadObserver::<f32>::new(&c), Err(LoadObserverConfigError::Invalid("hold_ratio")));
        // A thrust unit whose scaled gain is beyond Q8.24's range.
        let mut c = config(80.0);
        c.thrust_unit_n = 1e7;
        assert_eq!(LoadObserver::<Q24>::new(&c), Err(LoadObserverConfigError::Invalid("thrust_unit_n")));
        assert!(LoadObserver::<f32>::new(&c).is_ok());
    }

    /// A load step on a mass held still (thrust zero, the mover accelerating under the
    /// load alone) in `T`: the worst deviation of the load estimate from
    /// `1 - e^{-wt}(1 + wt + (wt)^2/2)`, the final load and speed errors.
    fn load_step<T: Scalar>() -> (f64, f64, f64) {
        let w = 80.0f32;
        let mut o = LoadObserver::<T>::new(&config(w)).unwrap();
        let (load, m, dt) = (60.0f64, 5.0f64, 1e-4f64);
        let (mut x, mut v) = (0.0f64, 0.0f64);
        let mut worst = 0.0f64;
        for k in 1..=2000 {
            // The plant over one period under the load alone (exact for constant force).
            let a = -load / m;
            x += v * dt + 0.5 * a * dt * dt;
            v += a * dt;
            assert!(o.update(T::from_f32(x as f32), T::ZERO));
            let wt = f64::from(w) * k as f64 * dt;
            let expected = load * (1.0 - (-wt).exp() * (1.0 + wt + 0.5 * wt * wt));
            worst = worst.max((f64::from(o.load_n()) - expected).abs());
        }
        (worst, (f64::from(o.load_n()) - load).abs(), (f64::from(o.speed_m_per_s()) - v).abs())
    }

    /// The analytic triple-pole response, within the Euler discretisation's error (at
    /// `w dt = 0.008` it delays the response by about a sample: within 1 % of the step),
    /// in each working type; Q8.24 within 0.1 % of the step of `f64`.
    #[test]
    fn load_step_is_estimated_along_the_analytic_triple_pole_response() {
        let reference = load_step::<f64>();
        for (name, (worst, load_err, speed_err)) in
            [("f64", reference), ("f32", load_step::<f32>()), ("Q24", load_step::<Q24>())]
        {
            assert!(worst < 0.6, "{name}: worst {worst} N");
            assert!(load_err < 0.6, "{name}: final load error {load_err} N");
            assert!(speed_err < 2.4e-3, "{name}: final speed error {speed_err} m/s");
            assert!(
                (worst - reference.0).abs() < 0.06,
                "{name}: worst {worst} N against f64's {}",
                reference.0
            );
        }
    }

    /// Measurement noise reaches the speed estimate attenuated: white position noise of
    /// `sigma` per sample gives a speed noise far below what differentiating it gives
    /// (`sqrt(2) sigma / dt`).
    #[test]
    fn position_noise_is_not_differentiated() {
        let mut o = LoadObserver::<f32>::new(&config(80.0)).unwrap();
        let sigma = 1e-4f32;
        // A deterministic pseudo-random sequence (xorshift), uniform in [-sqrt 3, sqrt 3] sigma.
        let mut s = 0x1234_5678u32;
        let mut sum_sq = 0.0f64;
        let n = 20_000;
        for k in 0..n {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            let u = (s as f32 / u32::MAX as f32) * 2.0 - 1.0;
            assert!(o.update(u * sigma * 3f32.sqrt(), 0.0));
            if k >= n / 2 {
                sum_sq += f64::from(o.speed_m_per_s()).powi(2);
            }
        }
        let rms = (sum_sq / (n / 2) as f64).sqrt();
        let differentiated = 2f64.sqrt() * f64::from(sigma) / 1e-4;
        assert!(rms < 0.05 * differentiated, "speed noise {rms} m/s against {differentiated}");
    }

    /// The hold's thrust is the PD law on the estimates plus the load, against the same
    /// law formed in SI, and it saturates at the load limit.
    #[test]
    fn hold_thrust_is_the_state_feedback_in_si() {
        let c = config(80.0);
        let mut o = LoadObserver::<f64>::new(&c).unwrap();
        o.preset(0.010, 0.02, 7.0);
        let (x_ref, v_ref, a_ref) = (0.0105f32, 0.0f32, 0.5f32);
        let wc = f64::from(c.hold_ratio * c.bandwidth_rad_s);
        let m = f64::from(c.mass_kg);
        let want = m
            * (f64::from(a_ref)
                + 2.0 * wc * (f64::from(v_ref) - 0.02)
                + wc * wc * (f64::from(x_ref) - 0.010))
            + 7.0;
        let got = o.hold_thrust(&o.target(x_ref, v_ref, a_ref));
        assert!((got - want).abs() < 1e-6 * want.abs(), "{got} N against {want} N");
        let q = {
            let mut q = LoadObserver::<Q24>::new(&c).unwrap();
            q.preset(0.010, 0.02, 7.0);
            q.hold_thrust(&q.target(x_ref, v_ref, a_ref)).to_f32()
        };
        assert!((f64::from(q) - want).abs() < 0.01 * want.abs(), "Q24 {q} N against {want} N");
        assert_eq!(o.hold_thrust(&o.target(10.0, 0.0, 0.0)), 100.0);
    }

    /// The load's thrust is the estimated load in the thrust unit, whatever the position
    /// and speed estimates (no feedback term), in f64 and Q8.24; it saturates at the load
    /// limit as the hold does.
    #[test]
    fn load_thrust_is_the_estimated_load_in_the_thrust_unit() {
        let c = LoadObserverConfig { thrust_unit_n: 12.5, ..config(80.0) };
        let unit = f64::from(c.thrust_unit_n);
        let mut o = LoadObserver::<f64>::new(&c).unwrap();
        o.preset(0.010, 0.3, -7.0);
        let want = -7.0 / unit;
        // Within the f32 the preset takes its load in.
        let got = o.load_thrust();
        assert!((got - want).abs() < 1e-6 * want.abs(), "{got} against {want}");
        let mut q = LoadObserver::<Q24>::new(&c).unwrap();
        q.preset(0.010, 0.3, -7.0);
        let got = f64::from(q.load_thrust().to_f32());
        assert!((got - want).abs() < 1e-3 * want.abs(), "Q24 {got} against {want}");
        // The limit: 100 N, at most 8 units of 12.5 N.
        o.preset(0.0, 0.0, 1e6);
        assert!((o.load_thrust() - 100.0 / unit).abs() < 1e-6 * 100.0 / unit);
    }

    /// Driven by the thrust that accelerates the mass, the speed estimate follows an
    /// acceleration with no lag beyond the discretisation's (about `a dt`): a loop on the
    /// position alone of the same bandwidth (a critically damped tracking loop) lags a
    /// ramp of the speed by `2 a / w_o` (0.075 m/s here). In each working type, read in
    /// the working units the drive scales (`speed_over_bandwidth_m`).
    #[test]
    fn speed_follows_a_commanded_acceleration_without_lag() {
        fn worst_lag<T: Scalar>() -> f64 {
            let c = config(80.0);
            let mut o = LoadObserver::<T>::new(&c).unwrap();
            let (m, load, a, dt) = (5.0f64, 10.0f64, 3.0f64, 1e-4f64);
            o.preset(0.0, 0.0, load as f32);
            let thrust = T::from_f32((m * a + load) as f32);
            let (mut x, mut v) = (0.0f64, 0.0f64);
            let mut worst = 0.0f64;
            for _ in 0..2000 {
                x += v * dt + 0.5 * a * dt * dt;
                v += a * dt;
                assert!(o.update(T::from_f32(x as f32), thrust));
                let v_hat = o.speed_over_bandwidth_m().to_f32() * c.bandwidth_rad_s;
                worst = worst.max((f64::from(v_hat) - v).abs());
            }
            worst
        }
        for (name, lag) in [("f32", worst_lag::<f32>()), ("Q24", worst_lag::<Q24>())] {
            assert!(lag < 1e-3, "{name}: speed {lag} m/s off a 3 m/s^2 ramp (a dt = 3e-4)");
        }
    }

    #[test]
    fn invalid_inputs_leave_the_state_alone() {
        let mut o = LoadObserver::<f32>::new(&config(80.0)).unwrap();
        o.preset(0.01, 0.2, 5.0);
        let before = o;
        assert!(!o.update(f32::NAN, 0.0));
        assert!(!o.update(0.0, f32::INFINITY));
        assert_eq!(o, before);
        o.preset(f32::NAN, 1e9, -1e9);
        assert_eq!(o.position_m(), 0.0);
        assert!((o.speed_m_per_s() - 5.0).abs() < 1e-5);
        assert!((o.load_n() + 100.0).abs() < 1e-3);
    }
}
