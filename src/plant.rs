//! The plant, at the library's edge: a virtual motor, a PMSLM and an averaged two-level
//! inverter, in `f32`, small enough to run inside a drive image in place of the power
//! stage (as VESC's "virtual motor" does), so that a drive image runs closed loop with no
//! plant outside it: on QEMU's `mps2-an386`, or on a board with its bridge held off.
//!
//! # Where it lives, and why
//! The model is physics, not a board: it touches no register and knows nothing of how
//! a board samples or switches. So it lives in the library (`#![forbid(unsafe_code)]`,
//! `no_std`, no allocation, no panic, bounded time), where host tests can check it
//! against analysis and run it in closed loop with the very `Drive` the image runs. It
//! imports only the motor's parameters, the numbers and the transforms, and nothing in
//! the library imports it. The firmware's board layer wraps it as a *virtual board*
//! (`dcfo_firmware::board::virtual_motor::VirtualBoard`) implementing the same
//! `PhaseSensors` and `PowerStage` traits as the real boards, so the control loop cannot
//! tell it from a power stage.
//!
//! # Model (the trace format's conventions, docs/trace-format.md)
//! Rotor (dq) frame at the electrical angle `θ = π x / τ`, amplitude-invariant:
//!
//! ```text
//! Ld di_d/dt = u_d − Rs i_d + ω Lq i_q
//! Lq di_q/dt = u_q − Rs i_q − ω (Ld i_d + ψf)          ω = π v / τ
//! M dv/dt    = F − B v − F_load,   F = 3/2 · π/τ · (ψf i_q + (Ld − Lq) i_d i_q)
//! ```
//!
//! Every coefficient comes from the [`MotorParams`] (`rs_ohm`, `ld_h`, `lq_h`,
//! `psi_f_wb`, `pole_pitch_m`, `mass_kg`, `viscous_n_s_per_m`); the axis adds a payload
//! mass and a constant load force ([`VirtualAxis`]). No per-motor constant is in code.
//!
//! **Inverter, averaged over a PWM period**: leg `x` at duty `d_x` puts `d_x · Vdc` on
//! its phase on average; the amplitude-invariant Clarke transform removes the common
//! mode, so `u_α = Vdc (2 d_a − d_b − d_c) / 3` and `u_β = Vdc (d_b − d_c) / √3`. No dead
//! time, no device drop: the drive should run without inverter compensation on it. With
//! the bridge off the phases are open: the currents are zero (exact while the back-EMF
//! stays below the bus, as in the host's plant; faster, the diodes would conduct).
//!
//! **Integration**: [`SUBSTEPS`] sub-steps a period. The electrical equations take the
//! resistive term implicitly (backward Euler: stable for any `Rs dt / L`) and the
//! rotational and back-EMF terms explicitly; then the speed and the position follow
//! from the new currents (semi-implicit Euler). The angle is a binary [`Angle`] advanced
//! by `ω dt` each sub-step, so it wraps exactly and keeps its resolution however far the
//! mover travels; cos/sin come from the library's bounded-time table.
//!
//! **Timing**, as a board with preloaded PWM registers: [`VirtualMotor::step`] runs one
//! period with the duties given; the firmware's virtual board applies the duties
//! computed at sample `k` during `[t_{k+1}, t_{k+2})`, like the host's simulation.

use crate::algorithms::transforms::{AlphaBeta, CosSin, Dq};
use crate::motor::{MotorParams, ParamError};
use crate::num::{Angle, Scalar};

/// Sub-steps of the integration per PWM period: at the 100 µs default period, 12.5 µs,
/// a fiftieth of the paper motor's 1.7 ms electrical time constant and a 1/12,000 of an
/// electrical period at 1 m/s.
pub const SUBSTEPS: u32 = 8;

/// What the motor moves besides its own mover, and what pushes back.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VirtualAxis {
    /// Mass moved besides the mover (carriage, payload), kg (≥ 0).
    pub payload_kg: f32,
    /// Constant load force against positive motion, N (finite; positive brakes a mover
    /// moving forward).
    pub load_n: f32,
    /// DC-bus voltage, V (> 0).
    pub bus_v: f32,
    /// PWM (control) period, s (> 0).
    pub period_s: f32,
}

/// Why a virtual motor could not be built: the field that was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum VirtualMotorError {
    /// A motor parameter (see [`MotorParams::new`]).
    Motor(ParamError),
    /// An axis setting, by field name (`payload_kg`, `load_n`, `bus_v`, `period_s`).
    Axis(&'static str),
}

/// The mover's true state, SI units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VirtualState {
    /// Position, m (from where the model started).
    pub x_m: f32,
    /// Speed, m/s.
    pub v_m_per_s: f32,
    /// Electrical angle of the magnet flux from the α axis.
    pub theta_e: Angle,
    /// Stator current in the rotor frame, A.
    pub i_dq_a: Dq<f32>,
    /// Stator current in the stationary frame, A.
    pub i_ab_a: AlphaBeta<f32>,
    /// Average stator voltage of the last period in the stationary frame, V (zero with the
    /// bridge off).
    pub u_ab_v: AlphaBeta<f32>,
    /// Thrust at the end of the last period, N.
    pub thrust_n: f32,
}

/// The virtual motor. See the module documentation.
#[derive(Clone, Debug)]
pub struct VirtualMotor {
    rs: f32,
    ld: f32,
    lq: f32,
    psi_f: f32,
    /// `π / τ`, rad per metre (electrical).
    pi_per_tau: f32,
    inv_mass: f32,
    viscous: f32,
    /// `3/2 · π/τ`, N per (Wb·A).
    thrust_per_flux_current: f32,
    load_n: f32,
    bus_v: f32,
    /// Sub-step, s.
    h: f32,
    x_m: f32,
    v: f32,
    theta: Angle,
    i_dq: Dq<f32>,
    u_ab: AlphaBeta<f32>,
}

const INV_SQRT3: f32 = 0.577_350_26;

impl VirtualMotor {
    /// A motor at rest at `x = 0`, `θ = 0`, no current.
    ///
    /// # Errors
    /// A motor parameter that [`MotorParams::new`] refuses, or an axis setting out
    /// of its range (named).
    pub fn new(motor: &MotorParams, axis: &VirtualAxis) -> Result<Self, VirtualMotorError> {
        MotorParams::new(*motor).map_err(VirtualMotorError::Motor)?;
        if !(axis.payload_kg.is_finite() && axis.payload_kg >= 0.0) {
            return Err(VirtualMotorError::Axis("payload_kg"));
        }
        if !axis.load_n.is_finite() {
            return Err(VirtualMotorError::Axis("load_n"));
        }
        if !(axis.bus_v.is_finite() && axis.bus_v > 0.0) {
            return Err(VirtualMotorError::Axis("bus_v"));
        }
        if !(axis.period_s.is_finite() && axis.period_s > 0.0) {
            return Err(VirtualMotorError::Axis("period_s"));
        }
        let pi_per_tau = motor.rad_per_m();
        Ok(VirtualMotor {
            rs: motor.rs_ohm,
            ld: motor.ld_h,
            lq: motor.lq_h,
            psi_f: motor.psi_f_wb,
            pi_per_tau,
            inv_mass: 1.0 / (motor.mass_kg + axis.payload_kg),
            viscous: motor.viscous_n_s_per_m,
            thrust_per_flux_current: 1.5 * pi_per_tau,
            load_n: axis.load_n,
            bus_v: axis.bus_v,
            h: axis.period_s / SUBSTEPS as f32,
            x_m: 0.0,
            v: 0.0,
            theta: Angle::ZERO,
            i_dq: Dq::default(),
            u_ab: AlphaBeta::default(),
        })
    }

    /// Runs one PWM period with the bridge switching at `duties` (each clamped to
    /// `[0, 1]`; NaN counts as 1/2), or with every switch off when `bridge_on` is false.
    pub fn step(&mut self, duties: [f32; 3], bridge_on: bool) {
        let u_ab = if bridge_on {
            let d = duties.map(|d| if d.is_nan() { 0.5 } else { d.clamp(0.0, 1.0) });
            AlphaBeta::new(
                self.bus_v * (2.0 * d[0] - d[1] - d[2]) * (1.0 / 3.0),
                self.bus_v * (d[1] - d[2]) * INV_SQRT3,
            )
        } else {
            AlphaBeta::default()
        };
        self.u_ab = u_ab;
        for _ in 0..SUBSTEPS {
            self.substep(u_ab, bridge_on);
        }
    }

    fn substep(&mut self, u_ab: AlphaBeta<f32>, bridge_on: bool) {
        let h = self.h;
        let omega = self.pi_per_tau * self.v;
        if bridge_on {
            let cs = CosSin::<f32>::new(self.theta);
            // Park of the applied voltage at the sub-step's angle.
            let u_d = u_ab.alpha * cs.cos + u_ab.beta * cs.sin;
            let u_q = -u_ab.alpha * cs.sin + u_ab.beta * cs.cos;
            let Dq { d: i_d, q: i_q } = self.i_dq;
            let drive_d = u_d + omega * self.lq * i_q;
            let drive_q = u_q - omega * (self.ld * i_d + self.psi_f);
            // Backward Euler on the resistive term: L (i' - i)/h = drive - R i'.
            let d_new = (self.ld * i_d + h * drive_d) / (self.ld + h * self.rs);
            let q_new = (self.lq * i_q + h * drive_q) / (self.lq + h * self.rs);
            self.i_dq = Dq::new(d_new, q_new);
        } else {
            self.i_dq = Dq::default();
        }
        let thrust = self.thrust();
        let accel = (thrust - self.viscous * self.v - self.load_n) * self.inv_mass;
        let v_new = self.v + h * accel;
        // Position and angle with the mean speed of the sub-step.
        let v_mean = 0.5 * (self.v + v_new);
        self.v = v_new;
        self.x_m += h * v_mean;
        self.theta = self.theta + (self.pi_per_tau * v_mean * h).radians_to_angle();
    }

    fn thrust(&self) -> f32 {
        let Dq { d, q } = self.i_dq;
        self.thrust_per_flux_current * (self.psi_f * q + (self.ld - self.lq) * d * q)
    }

    /// The phase currents a, b, c (A, positive into the motor) now: the inverse
    /// amplitude-invariant Clarke transform of the stator current.
    pub fn phase_currents_a(&self) -> [f32; 3] {
        let i = self.i_ab();
        const HALF_SQRT3: f32 = 0.866_025_4;
        [i.alpha, -0.5 * i.alpha + HALF_SQRT3 * i.beta, -0.5 * i.alpha - HALF_SQRT3 * i.beta]
    }

    fn i_ab(&self) -> AlphaBeta<f32> {
        let cs = CosSin::<f32>::new(self.theta);
        let Dq { d, q } = self.i_dq;
        AlphaBeta::new(d * cs.cos - q * cs.sin, d * cs.sin + q * cs.cos)
    }

    /// The DC-bus voltage, V (a stiff bus).
    pub fn bus_v(&self) -> f32 {
        self.bus_v
    }

    /// Sets the constant load force, N (a non-finite value is ignored).
    pub fn set_load_n(&mut self, load_n: f32) {
        if load_n.is_finite() {
            self.load_n = load_n;
        }
    }

    /// Sets the mover's speed, m/s (a push by hand; a non-finite value is ignored).
    pub fn set_speed_m_per_s(&mut self, v_m_per_s: f32) {
        if v_m_per_s.is_finite() {
            self.v = v_m_per_s;
        }
    }

    /// The true state.
    pub fn state(&self) -> VirtualState {
        VirtualState {
            x_m: self.x_m,
            v_m_per_s: self.v,
            theta_e: self.theta,
            i_dq_a: self.i_dq,
            i_ab_a: self.i_ab(),
            u_ab_v: self.u_ab,
            thrust_n: self.thrust(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::algorithms::svpwm::svpwm;
    use crate::algorithms::transforms::inverse_park;

    fn axis(payload_kg: f32) -> VirtualAxis {
        VirtualAxis { payload_kg, load_n: 0.0, bus_v: 311.0, period_s: 1e-4 }
    }

    /// The duties that make `u_dq` (V) in the frame at `theta`, by the library's SVPWM.
    fn duties_for(u_dq: Dq<f32>, theta: Angle, bus_v: f32) -> [f32; 3] {
        let u_ab = inverse_park(u_dq, &CosSin::<f32>::new(theta));
        let m = svpwm(u_ab, bus_v).unwrap();
        assert!(!m.limited);
        [m.duties.a, m.duties.b, m.duties.c]
    }

    /// The averaged inverter produces the SVPWM's own voltage (any zero-sequence).
    #[test]
    fn averaged_inverter_applies_the_modulated_voltage() {
        let motor = MotorParams::paper();
        let mut m = VirtualMotor::new(&motor, &axis(0.0)).unwrap();
        for (a, b) in [(100.0f32, 0.0f32), (-30.0, 120.0), (0.0, -170.0), (12.5, 3.25)] {
            let sv = svpwm(AlphaBeta::new(a, b), 311.0).unwrap();
            m.step([sv.duties.a, sv.duties.b, sv.duties.c], true);
            let u = m.state().u_ab_v;
            assert!((u.alpha - sv.u_applied.alpha).abs() < 1e-3 * 311.0, "{u:?} vs {sv:?}");
            assert!((u.beta - sv.u_applied.beta).abs() < 1e-3 * 311.0, "{u:?} vs {sv:?}");
        }
    }

    /// Held at a constant speed (a payload too heavy to move), with a constant dq
    /// voltage applied in the rotor frame, the currents settle where the steady-state
    /// voltage equations put them: `u_d = R i_d − ω Lq i_q`, `u_q = R i_q + ω (Ld i_d + ψf)`.
    #[test]
    fn steady_state_currents_solve_the_dq_voltage_equations() {
        let mut motor = MotorParams::paper();
        motor.lq_h = 1.5 * motor.ld_h; // salient, so that Ld and Lq are told apart
        let v = 0.3f32;
        let mut m = VirtualMotor::new(&motor, &axis(1e9)).unwrap();
        m.set_speed_m_per_s(v);
        let omega = core::f32::consts::PI * v / motor.pole_pitch_m;
        let (r, ld, lq, psi) = (motor.rs_ohm, motor.ld_h, motor.lq_h, motor.psi_f_wb);
        let u = Dq::new(-3.0f32, 12.0f32);
        // 1 s: hundreds of electrical time constants. The duties are computed at the
        // period's start angle and held, as a drive does; take the voltage the period
        // applies on average in the rotor frame: rotated by half a period's travel.
        let half_period = (omega * 0.5e-4).radians_to_angle();
        for _ in 0..10_000 {
            let theta = m.state().theta_e + half_period;
            m.step(duties_for(u, theta, 311.0), true);
        }
        // Solve the 2x2 steady-state system for (i_d, i_q).
        let (a11, a12, a21, a22) = (r, -omega * lq, omega * ld, r);
        let (b1, b2) = (u.d, u.q - omega * psi);
        let det = a11 * a22 - a12 * a21;
        let i_d = (b1 * a22 - a12 * b2) / det;
        let i_q = (a11 * b2 - a21 * b1) / det;
        let got = m.state().i_dq_a;
        // The held voltage's ripple over a period is ω Ts / 2 = 0.3 % of its phase.
        let tol = 0.01 * (i_d.abs() + i_q.abs());
        assert!((got.d - i_d).abs() < tol && (got.q - i_q).abs() < tol, "{got:?} vs ({i_d}, {i_q})");
        // And the back-EMF alone: at zero voltage (all legs 1/2) the short-circuit current.
        for _ in 0..10_000 {
            m.step([0.5; 3], true);
        }
        let (b1, b2) = (0.0, -omega * psi);
        let i_d = (b1 * a22 - a12 * b2) / det;
        let i_q = (a11 * b2 - a21 * b1) / det;
        let got = m.state().i_dq_a;
        let tol = 0.01 * (i_d.abs() + i_q.abs());
        assert!((got.d - i_d).abs() < tol && (got.q - i_q).abs() < tol, "{got:?} vs ({i_d}, {i_q})");
    }

    /// Energy balance over a run from rest: the electrical energy put in equals the
    /// copper losses, the viscous losses, the kinetic energy gained and the magnetic
    /// energy stored, within the integration's error.
    #[test]
    fn energy_is_balanced() {
        let motor = MotorParams::paper();
        let mut m = VirtualMotor::new(&motor, &axis(10.0)).unwrap();
        let mass = motor.mass_kg + 10.0;
        let ts = 1e-4f32;
        let (mut e_in, mut e_cu, mut e_visc) = (0.0f64, 0.0f64, 0.0f64);
        // A q voltage at the rotor angle for 0.5 s: the mover accelerates.
        let u = Dq::new(0.0f32, 20.0f32);
        for _ in 0..5000 {
            let before = m.state();
            m.step(duties_for(u, before.theta_e, 311.0), true);
            let after = m.state();
            let i = |s: &VirtualState| s.i_ab_a;
            let (i0, i1) = (i(&before), i(&after));
            let mean = AlphaBeta::new(0.5 * (i0.alpha + i1.alpha), 0.5 * (i0.beta + i1.beta));
            let ua = after.u_ab_v;
            e_in += f64::from(1.5 * (ua.alpha * mean.alpha + ua.beta * mean.beta) * ts);
            let sq = |x: AlphaBeta<f32>| x.alpha * x.alpha + x.beta * x.beta;
            e_cu += f64::from(1.5 * motor.rs_ohm * 0.5 * (sq(i0) + sq(i1)) * ts);
            let v_mean = 0.5 * (before.v_m_per_s + after.v_m_per_s);
            e_visc += f64::from(motor.viscous_n_s_per_m * v_mean * v_mean * ts);
        }
        let s = m.state();
        let e_kin = 0.5 * f64::from(mass * s.v_m_per_s * s.v_m_per_s);
        let e_mag =
            0.75 * f64::from(motor.ld_h * s.i_dq_a.d * s.i_dq_a.d + motor.lq_h * s.i_dq_a.q * s.i_dq_a.q);
        let out = e_cu + e_visc + e_kin + e_mag;
        assert!(s.v_m_per_s > 0.1, "the mover moved: {s:?}");
        assert!((e_in - out).abs() < 0.01 * e_in, "in {e_in} J, out {out} J (cu {e_cu}, kin {e_kin})");
    }

    /// Force and motion: a constant q current of I against no load accelerates the mass
    /// at `3/2 π/τ ψf I / M` (the viscous term is small over 0.1 s), and the angle follows
    /// the position as `π x / τ`.
    #[test]
    fn thrust_accelerates_the_mass_and_the_angle_follows_the_position() {
        let mut motor = MotorParams::paper();
        motor.viscous_n_s_per_m = 0.0;
        let mut m = VirtualMotor::new(&motor, &axis(10.0)).unwrap();
        // Current regulated by a simple loop on the true current (not the drive's).
        let i_ref = 2.0f32;
        for _ in 0..1000 {
            let s = m.state();
            let back_emf = core::f32::consts::PI * s.v_m_per_s / motor.pole_pitch_m * motor.psi_f_wb;
            let u = Dq::new(-20.0 * s.i_dq_a.d, 20.0 * (i_ref - s.i_dq_a.q) + back_emf);
            m.step(duties_for(u, s.theta_e, 311.0), true);
        }
        let s = m.state();
        let mass = motor.mass_kg + 10.0;
        let thrust = motor.thrust_constant_n_per_a() * s.i_dq_a.q;
        assert!((s.thrust_n - thrust).abs() < 1e-3 * thrust);
        // v = ∫F/M dt with the current settled in about 5 ms of the 100 ms.
        let expected_v = thrust / mass * 0.1;
        assert!((s.v_m_per_s - expected_v).abs() < 0.05 * expected_v, "{} vs {expected_v}", s.v_m_per_s);
        let theta = core::f32::consts::PI * s.x_m / motor.pole_pitch_m;
        let wrapped = Angle::from_radians(theta);
        let diff = (s.theta_e - wrapped).to_radians::<f32>().abs();
        assert!(diff < 1e-3, "angle {:?} vs pi x / tau {theta}", s.theta_e);
    }

    #[test]
    fn open_bridge_carries_no_current_and_bad_settings_are_named() {
        let motor = MotorParams::paper();
        let mut m = VirtualMotor::new(&motor, &axis(0.0)).unwrap();
        m.step([1.0, 0.0, 0.0], true);
        assert!(m.state().i_ab_a.alpha > 0.0);
        m.step([1.0, 0.0, 0.0], false);
        assert_eq!(m.phase_currents_a(), [0.0; 3]);
        let bad = VirtualAxis { bus_v: -1.0, ..axis(0.0) };
        assert_eq!(VirtualMotor::new(&motor, &bad).unwrap_err(), VirtualMotorError::Axis("bus_v"));
        let bad = VirtualAxis { period_s: f32::NAN, ..axis(0.0) };
        assert_eq!(VirtualMotor::new(&motor, &bad).unwrap_err(), VirtualMotorError::Axis("period_s"));
        let mut bad_motor = motor;
        bad_motor.ld_h = 0.0;
        assert!(matches!(VirtualMotor::new(&bad_motor, &axis(0.0)), Err(VirtualMotorError::Motor(_))));
    }
}
