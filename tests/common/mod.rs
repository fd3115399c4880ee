//! Shared test support: a synthetic PMSLM whose voltages are generated so that the
//! observers' timing contract holds exactly (held voltage per period, currents sampled
//! at period ends), plus measurement helpers.
#![allow(dead_code)]

use dcfo::algorithms::observer::ObserverInput;
use dcfo::algorithms::transforms::AlphaBeta;
use dcfo::num::units::Base;
use dcfo::num::{Angle, Scalar};
use std::f64::consts::PI;

/// Paper motor constants (docs/method.md §1).
pub const RS: f64 = 5.0;
pub const LS: f64 = 0.0085;
pub const PSI_F: f64 = 0.16;
pub const TS: f64 = 1e-4;

/// A synthetic motor at constant electrical speed with a q-axis current, optional
/// DC offsets and voltage harmonics. All quantities SI, f64.
#[derive(Clone, Copy, Debug)]
pub struct Synthetic {
    pub omega: f64,
    pub theta0: f64,
    pub psi_f: f64,
    pub i_q: f64,
    /// Added to the observer's voltage input (V), from `offset_from_s` on.
    pub u_offset: [f64; 2],
    /// Added to the observer's current input (A), from `offset_from_s` on.
    pub i_offset: [f64; 2],
    pub offset_from_s: f64,
    /// Voltage harmonics fed to the observer: (order n, amplitude V); n > 0 positive
    /// sequence, n < 0 negative sequence.
    pub harmonics: [(f64, f64); 2],
    /// Optional linear speed ramp: from `omega` at `t_start` to `omega_end` at `t_end`.
    pub ramp: Option<Ramp>,
    /// Optional angle wobble `(amplitude rad, angular frequency rad/s)` added to theta:
    /// a speed modulation, for measuring how estimates follow speed changes.
    pub wobble: Option<(f64, f64)>,
}

/// A linear change of electrical speed.
#[derive(Clone, Copy, Debug)]
pub struct Ramp {
    pub t_start: f64,
    pub t_end: f64,
    pub omega_end: f64,
}

impl Synthetic {
    pub fn at_hz(f_hz: f64) -> Self {
        Synthetic {
            omega: 2.0 * PI * f_hz,
            theta0: 0.3,
            psi_f: PSI_F,
            i_q: 1.0,
            u_offset: [0.0; 2],
            i_offset: [0.0; 2],
            offset_from_s: 0.0,
            harmonics: [(0.0, 0.0); 2],
            ramp: None,
            wobble: None,
        }
    }

    /// Electrical speed at time t (rad/s).
    pub fn omega_at(&self, t: f64) -> f64 {
        match self.ramp {
            Some(r) if t > r.t_start => {
                let x = ((t - r.t_start) / (r.t_end - r.t_start)).min(1.0);
                self.omega + x * (r.omega_end - self.omega)
            }
            _ => self.omega,
        }
    }

    /// Electrical angle at time t (rad), the integral of `omega_at`, plus any wobble.
    pub fn theta(&self, t: f64) -> f64 {
        let wobble = self.wobble.map_or(0.0, |(a, w)| a * (w * t).sin());
        wobble + self.theta_ramped(t)
    }

    fn theta_ramped(&self, t: f64) -> f64 {
        match self.ramp {
            Some(r) if t > r.t_start => {
                let dt_ramp = (t.min(r.t_end) - r.t_start).max(0.0);
                let slope = (r.omega_end - self.omega) / (r.t_end - r.t_start);
                let after = (t - r.t_end).max(0.0);
                self.theta0
                    + self.omega * r.t_start
                    + self.omega * dt_ramp
                    + 0.5 * slope * dt_ramp * dt_ramp
                    + r.omega_end * after
            }
            _ => self.theta0 + self.omega * t,
        }
    }
    /// True mover flux at time t (Wb).
    pub fn psi_f_ab(&self, t: f64) -> [f64; 2] {
        let th = self.theta(t);
        [self.psi_f * th.cos(), self.psi_f * th.sin()]
    }
    /// True current at time t (A): q-axis, i.e. 90 degrees ahead of the flux.
    pub fn current(&self, t: f64) -> [f64; 2] {
        let th = self.theta(t);
        [-self.i_q * th.sin(), self.i_q * th.cos()]
    }
    /// Stator flux from the harmonic voltages: integral of A cos(n w t) etc.
    fn harmonic_flux(&self, t: f64) -> [f64; 2] {
        let mut f = [0.0; 2];
        for &(n, a) in &self.harmonics {
            if n == 0.0 || a == 0.0 {
                continue;
            }
            // A harmonic of the fundamental's phase: voltage a [cos(n theta), sin(n theta)]
            // gives flux a/(n w) [sin(n theta), -cos(n theta)] at constant speed.
            let wn = n * self.omega;
            let th = n * (self.theta_ramped(t) - self.theta0);
            f[0] += a / wn * th.sin();
            f[1] += -a / wn * th.cos();
        }
        f
    }
    /// Stator flux `psi_f + Ls i + harmonics` (Wb).
    pub fn psi_s(&self, t: f64) -> [f64; 2] {
        let pf = self.psi_f_ab(t);
        let i = self.current(t);
        let h = self.harmonic_flux(t);
        [pf[0] + LS * i[0] + h[0], pf[1] + LS * i[1] + h[1]]
    }

    /// The observer input for the sample at the end of period k (time (k+1) Ts): the
    /// voltage held over [k Ts, (k+1) Ts) and the current sampled at (k+1) Ts.
    pub fn sample(&self, k: usize, dt: f64) -> ([f64; 2], [f64; 2], f64) {
        let t0 = k as f64 * dt;
        let t1 = t0 + dt;
        let s0 = self.psi_s(t0);
        let s1 = self.psi_s(t1);
        let i0 = self.current(t0);
        let i1 = self.current(t1);
        let mut u = [0.0; 2];
        for ax in 0..2 {
            // Exact for the observer's integration rule: held u, trapezoidal Rs i.
            u[ax] = (s1[ax] - s0[ax]) / dt + RS * 0.5 * (i0[ax] + i1[ax]);
        }
        let mut i = i1;
        if t0 >= self.offset_from_s {
            u.iter_mut().zip(self.u_offset).for_each(|(x, o)| *x += o);
        }
        if t1 >= self.offset_from_s {
            i.iter_mut().zip(self.i_offset).for_each(|(x, o)| *x += o);
        }
        (u, i, t1)
    }

    /// The sample as an observer input in type T and working units `base`.
    pub fn input<T: Scalar>(
        &self,
        k: usize,
        dt: f64,
        omega_est: f64,
        base: &Base,
    ) -> (ObserverInput<T>, f64) {
        let (u, i, t) = self.sample(k, dt);
        (
            ObserverInput {
                u_ab: AlphaBeta::new(base.voltage(u[0] as f32), base.voltage(u[1] as f32)),
                i_ab: AlphaBeta::new(base.current(i[0] as f32), base.current(i[1] as f32)),
                omega_e: base.omega(omega_est as f32),
                dt: base.time(dt as f32),
            },
            t,
        )
    }
}

/// f64 input in SI directly (no f32 rounding of the inputs) for the f64 observers.
pub fn input_f64(u: [f64; 2], i: [f64; 2], omega: f64, dt: f64) -> ObserverInput<f64> {
    ObserverInput { u_ab: AlphaBeta::new(u[0], u[1]), i_ab: AlphaBeta::new(i[0], i[1]), omega_e: omega, dt }
}

/// Complex ratio estimate (gain, phase rad) of `out` relative to `reference`, both
/// sequences of alpha-beta vectors treated as complex numbers.
pub fn complex_ratio(out: &[[f64; 2]], reference: &[[f64; 2]]) -> (f64, f64) {
    let (mut re, mut im, mut den) = (0.0, 0.0, 0.0);
    for (o, r) in out.iter().zip(reference) {
        // o * conj(r)
        re += o[0] * r[0] + o[1] * r[1];
        im += o[1] * r[0] - o[0] * r[1];
        den += r[0] * r[0] + r[1] * r[1];
    }
    ((re * re + im * im).sqrt() / den, im.atan2(re))
}

/// Wrapped angle difference a - b in degrees.
pub fn angle_diff_deg(a: Angle, b: Angle) -> f64 {
    (a - b).to_degrees_f64()
}

/// Angle of a real number of radians.
pub fn angle_of(rad: f64) -> Angle {
    rad.radians_to_angle()
}
