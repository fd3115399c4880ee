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
//! ## Discretisation and bounds
//! Forward Euler at the control period; stable for `w_o dt` up to about 0.5 (the tests
//! check the discrete poles' decay at `w_o dt = 0.1`); [`LoadObserver::new`] refuses
//! `w_o dt > 0.25`. The load estimate is clamped to `±load_limit_n` (what the drive can
//! push against) and the speed to `±speed_limit_m_per_s`, so a wrong input cannot wind
//! the states up; non-finite inputs leave the state unchanged and return `false`.

#![forbid(unsafe_code)]

use crate::num::positive;

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
}

/// A configuration the observer cannot run with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoadObserverConfigError {
    /// A field is not a positive finite number, or `w_o dt > 0.25`; names the field.
    Invalid(&'static str),
}

/// Position, speed and load observer (SI units, `f32`). See the module docs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoadObserver {
    l1: f32,
    l2: f32,
    l3_mass: f32,
    inv_mass: f32,
    dt: f32,
    load_limit: f32,
    speed_limit: f32,
    x_hat_m: f32,
    v_hat_m_per_s: f32,
    load_hat_n: f32,
}

impl LoadObserver {
    /// Builds an observer from `config`, at rest at position 0 with no load.
    pub fn new(config: &LoadObserverConfig) -> Result<Self, LoadObserverConfigError> {
        let c = config;
        for (ok, field) in [
            (positive(c.mass_kg), "mass_kg"),
            (positive(c.bandwidth_rad_s), "bandwidth_rad_s"),
            (positive(c.dt_s), "dt_s"),
            (positive(c.load_limit_n), "load_limit_n"),
            (positive(c.speed_limit_m_per_s), "speed_limit_m_per_s"),
            (c.bandwidth_rad_s * c.dt_s <= 0.25, "bandwidth_rad_s"),
        ] {
            if !ok {
                return Err(LoadObserverConfigError::Invalid(field));
            }
        }
        let w = c.bandwidth_rad_s;
        Ok(LoadObserver {
            l1: 3.0 * w,
            l2: 3.0 * w * w,
            l3_mass: w * w * w * c.mass_kg,
            inv_mass: 1.0 / c.mass_kg,
            dt: c.dt_s,
            load_limit: c.load_limit_n,
            speed_limit: c.speed_limit_m_per_s,
            x_hat_m: 0.0,
            v_hat_m_per_s: 0.0,
            load_hat_n: 0.0,
        })
    }

    /// Starts from position `x_m` (m), speed `v_m_per_s` (m/s) and load `load_n` (N),
    /// each clamped to its limit (non-finite values read as 0).
    pub fn preset(&mut self, x_m: f32, v_m_per_s: f32, load_n: f32) {
        let finite = |x: f32| if x.is_finite() { x } else { 0.0 };
        self.x_hat_m = finite(x_m);
        self.v_hat_m_per_s = clamp_symmetric(finite(v_m_per_s), self.speed_limit);
        self.load_hat_n = clamp_symmetric(finite(load_n), self.load_limit);
    }

    /// One control period: the measured position `x_meas_m` (m) and the thrust the drive
    /// applied during the period, `thrust_n` (N). Returns `false` (state unchanged) if
    /// either is not finite.
    pub fn update(&mut self, x_meas_m: f32, thrust_n: f32) -> bool {
        if !(x_meas_m.is_finite() && thrust_n.is_finite()) {
            return false;
        }
        let e = x_meas_m - self.x_hat_m;
        let dt = self.dt;
        let accel = (thrust_n - self.load_hat_n) * self.inv_mass + self.l2 * e;
        self.x_hat_m += dt * (self.v_hat_m_per_s + self.l1 * e);
        self.v_hat_m_per_s = clamp_symmetric(self.v_hat_m_per_s + dt * accel, self.speed_limit);
        self.load_hat_n = clamp_symmetric(self.load_hat_n - dt * self.l3_mass * e, self.load_limit);
        true
    }

    /// Estimated position, m.
    pub fn position_m(&self) -> f32 {
        self.x_hat_m
    }

    /// Estimated speed, m/s.
    pub fn speed_m_per_s(&self) -> f32 {
        self.v_hat_m_per_s
    }

    /// Estimated load (friction and outside forces, opposing positive thrust), N.
    pub fn load_n(&self) -> f32 {
        self.load_hat_n
    }
}

/// `x` limited to `[-limit, limit]` (`limit >= 0`). Not `f32::clamp`, whose check of its
/// bounds' order links a panic into the control path.
fn clamp_symmetric(x: f32, limit: f32) -> f32 {
    if x > limit {
        limit
    } else if x < -limit {
        -limit
    } else {
        x
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(w: f32) -> LoadObserverConfig {
        LoadObserverConfig {
            mass_kg: 5.0,
            bandwidth_rad_s: w,
            dt_s: 1e-4,
            load_limit_n: 500.0,
            speed_limit_m_per_s: 5.0,
        }
    }

    #[test]
    fn refuses_bad_configurations_by_name() {
        let mut c = config(80.0);
        c.mass_kg = 0.0;
        assert_eq!(LoadObserver::new(&c), Err(LoadObserverConfigError::Invalid("mass_kg")));
        let mut c = config(80.0);
        c.dt_s = f32::NAN;
        assert_eq!(LoadObserver::new(&c), Err(LoadObserverConfigError::Invalid("dt_s")));
        assert_eq!(
            LoadObserver::new(&config(3000.0)),
            Err(LoadObserverConfigError::Invalid("bandwidth_rad_s"))
        );
    }

    /// A load step on a mass held still (thrust zero, the mover accelerating under the
    /// load alone): the load estimate follows `1 - e^{-wt}(1 + wt + (wt)^2/2)` within the
    /// Euler discretisation's error, and the speed and position are tracked.
    #[test]
    fn load_step_is_estimated_along_the_analytic_triple_pole_response() {
        let w = 80.0f32;
        let c = config(w);
        let mut o = LoadObserver::new(&c).unwrap();
        let (load, m, dt) = (60.0f64, 5.0f64, 1e-4f64);
        let (mut x, mut v) = (0.0f64, 0.0f64);
        let mut worst = 0.0f64;
        for k in 1..=2000 {
            // The plant over one period under the load alone (exact for constant force).
            let a = -load / m;
            x += v * dt + 0.5 * a * dt * dt;
            v += a * dt;
            assert!(o.update(x as f32, 0.0));
            let wt = f64::from(w) * k as f64 * dt;
            let expected = load * (1.0 - (-wt).exp() * (1.0 + wt + 0.5 * wt * wt));
            worst = worst.max((f64::from(o.load_n()) - expected).abs());
        }
        // Euler at w dt = 0.008 delays the response by about a sample: within 1 % of the step.
        assert!(worst < 0.01 * load, "worst {worst} N");
        assert!((f64::from(o.load_n()) - load).abs() < 0.01 * load);
        assert!((f64::from(o.speed_m_per_s()) - v).abs() < 1e-3 * v.abs().max(1.0));
    }

    /// Measurement noise reaches the speed estimate attenuated: white position noise of
    /// `sigma` per sample gives a speed noise far below what differentiating it gives
    /// (`sqrt(2) sigma / dt`).
    #[test]
    fn position_noise_is_not_differentiated() {
        let c = config(80.0);
        let mut o = LoadObserver::new(&c).unwrap();
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

    #[test]
    fn non_finite_inputs_leave_the_state_alone() {
        let mut o = LoadObserver::new(&config(80.0)).unwrap();
        o.preset(0.01, 0.2, 5.0);
        let before = o;
        assert!(!o.update(f32::NAN, 0.0));
        assert!(!o.update(0.0, f32::INFINITY));
        assert_eq!(o, before);
        o.preset(f32::NAN, 1e9, -1e9);
        assert_eq!((o.position_m(), o.speed_m_per_s(), o.load_n()), (0.0, 5.0, -500.0));
    }
}
