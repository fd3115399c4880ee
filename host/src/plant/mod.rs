//! PMSLM + two-level inverter + sensor plant model (std, `f64`, SI units).
//!
//! What it simulates:
//!
//! - **Motor** in the rotor (dq) frame, docs/method.md §1: `u_d = Rs i_d + Ld di_d/dt -
//!   omega_e Lq i_q`, `u_q = Rs i_q + Lq di_q/dt + omega_e (Ld i_d + psi_f)`,
//!   thrust `F_e = 1.5 (pi/tau) (psi_f i_q + (Ld - Lq) i_d i_q)`,
//!   `omega_e = pi v / tau`, `theta_e = pi x / tau + theta_offset`. Park and Clarke
//!   are amplitude-invariant; `psi_f_alpha = psi_f cos(theta_e)`. Saliency (`Ld != Lq`)
//!   is in the model as it stands; optionally the d axis saturates
//!   ([`PlantParams::ld_saturation_per_a`]: `L_d i_d` becomes a flux whose incremental
//!   inductance falls with `i_d > 0`; thrust `1.5 (pi/tau) (psi_d i_q - L_q i_q i_d)`),
//!   which magnet-polarity detection reads; off by default.
//! - **Mechanics**: `M dv/dt = F_e - B v - F_c sign(v) - F_load - F_em cos(2 pi x / tau)`,
//!   `dx/dt = v`. At zero speed the mover sticks while `|F_e - F_load - F_em cos(..)|`
//!   is at most the static friction; a mover that slows through zero under
//!   friction stops there (and may stick). Or the speed can be clamped to a
//!   prescribed value ([`Plant::set_speed_clamp`]).
//! - **Inverter**: two-level, three legs on a DC bus with optional ripple;
//!   centre-aligned PWM with period Ts (upper switch commanded on for `d Ts`
//!   around the carrier peak), dead time on every turn-on, device drops
//!   (threshold + slope) in IGBTs and diodes. During dead time the leg voltage
//!   follows the current sign. Isolated star point: `v_n = mean of the three leg
//!   voltages`.
//! - **Integration**: each period is split at its switching instants (known from
//!   duties, carrier and dead time, including turn-ons delayed across the period
//!   boundary) and each sub-interval is integrated with classic RK4 in equal steps
//!   no longer than `max_substep_s` (or half the electrical time constant, if
//!   shorter). Within one RK4 step the conduction path (which device each
//!   current flows through) and the friction state are frozen
//!   at their values at the step's start; a current sign change is picked up at
//!   the next step (at most 2 us later with the defaults).
//! - **Sensors**: offset, gain error, white noise, ADC quantisation and
//!   saturation for phase currents (two or three sensors) and the DC bus, with a
//!   seeded PCG64 generator.
//!
//! Timing contract: [`Plant::step`] applies duties over `[t, t + Ts)` and advances
//! `t` by Ts; [`Plant::sample`] reads the sensors at the present `t`, a carrier
//! valley. A drive that computes its duties from the sample at `t_k` and applies
//! them from `t_{k+1}` adds the one-period computation delay itself.
//!
//! Energy book-keeping ([`Plant::energy`]) integrates every power flow with the
//! same RK4 stages as the state, so that the energy balance can be checked.

mod faults;
mod inverter;
mod params;
mod sensors;
#[cfg(test)]
mod tests;

use core::f64::consts::PI;

pub use inverter::svpwm_duties;
use inverter::{Devices, LegCommand, LegMode, PeriodSchedule, leg_output};
pub use params::{
    CurrentSensing, InverterParams, PlantError, PlantParams, SensorParams, SimParams, rad_per_m,
    rated_thrust_n,
};
pub use sensors::SensorReading;
use sensors::Sensors;

const SQRT3: f64 = 1.732_050_807_568_877_2;

// Layout of the integrated state vector.
const ID: usize = 0;
const IQ: usize = 1;
const V: usize = 2;
const X: usize = 3;
const E_BUS: usize = 4;
const E_MOTOR: usize = 5;
const E_CU: usize = 6;
const E_DEV: usize = 7;
const W_THRUST: usize = 8;
const E_FRIC: usize = 9;
const E_LOAD: usize = 10;
const E_END: usize = 11;
const INT_UA: usize = 12;
const INT_UB: usize = 13;
const INT_VA: usize = 14;
const NY: usize = 17;

type Vector = [f64; NY];

/// Motor constants, precomputed.
#[derive(Debug, Clone, Copy)]
struct Model {
    rs: f64,
    ld: f64,
    lq: f64,
    psi_f: f64,
    pi_tau: f64,
    mass: f64,
    b: f64,
    fc: f64,
    fs: f64,
    fem: f64,
    theta0: f64,
    /// d saturation `c`, 1/A (0: linear).
    sat: f64,
    dev: Devices,
}

/// Mechanical state over one RK4 step.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Mech {
    /// Speed held at the given value, m/s.
    Clamped(f64),
    /// At rest, held by static friction.
    Stuck,
    /// Moving; Coulomb friction acts against the given direction (+1 or -1).
    Sliding(f64),
}

/// Everything held constant over one RK4 step.
#[derive(Debug, Clone, Copy)]
struct Frozen {
    /// Every switch off (bridge disabled): see [`Plant::step_open`].
    open: bool,
    modes: [LegMode; 3],
    signs: [i8; 3],
    upper_last: [bool; 3],
    vdc: f64,
    mech: Mech,
    load: f64,
}

fn inv_clarke(alpha: f64, beta: f64) -> [f64; 3] {
    let h = 0.5 * SQRT3;
    [alpha, -0.5 * alpha + h * beta, -0.5 * alpha - h * beta]
}

impl Model {
    fn new(p: &PlantParams, inv: &InverterParams) -> Self {
        Model {
            rs: p.rs_ohm,
            ld: p.ld_h,
            lq: p.lq_h,
            psi_f: p.psi_f_wb,
            pi_tau: PI / p.pole_pitch_m,
            mass: p.mass_kg,
            b: p.viscous_n_s_per_m,
            fc: p.coulomb_friction_n,
            fs: p.static_friction_n,
            fem: p.end_effect_ripple_n,
            theta0: p.theta_offset_rad,
            sat: p.ld_saturation_per_a,
            dev: Devices {
                igbt_v0: inv.igbt_threshold_v,
                igbt_r: inv.igbt_slope_ohm,
                diode_v0: inv.diode_threshold_v,
                diode_r: inv.diode_slope_ohm,
            },
        }
    }

    fn theta(&self, x: f64) -> f64 {
        self.pi_tau * x + self.theta0
    }

    fn thrust(&self, i_d: f64, i_q: f64) -> f64 {
        if self.sat == 0.0 {
            1.5 * self.pi_tau * (self.psi_f * i_q + (self.ld - self.lq) * i_d * i_q)
        } else {
            1.5 * self.pi_tau * (self.flux_d(i_d) * i_q - self.lq * i_q * i_d)
        }
    }

    /// d flux linkage `psi_f + L_d i_d`, or with saturation `psi_f + L_d (i_d - (1/4c)
    /// ln cosh(2 c i_d))` (see [`PlantParams::ld_saturation_per_a`]), Wb.
    fn flux_d(&self, i_d: f64) -> f64 {
        if self.sat == 0.0 {
            self.ld * i_d + self.psi_f
        } else {
            let x = (2.0 * self.sat * i_d).abs();
            // ln cosh x = x + ln(1 + e^-2x) - ln 2, exact and overflow-free.
            let ln_cosh = x + (-2.0 * x).exp().ln_1p() - core::f64::consts::LN_2;
            self.ld * (i_d - ln_cosh / (4.0 * self.sat)) + self.psi_f
        }
    }

    /// Incremental d inductance `d psi_d / d i_d`, H.
    fn ld_incremental(&self, i_d: f64) -> f64 {
        if self.sat == 0.0 { self.ld } else { self.ld * (1.0 - 0.5 * (2.0 * self.sat * i_d).tanh()) }
    }

    /// End-effect force as it enters the mechanics (subtracted), newton.
    fn end_force(&self, x: f64) -> f64 {
        if self.fem == 0.0 { 0.0 } else { self.fem * (2.0 * self.pi_tau * x).cos() }
    }

    /// Phase currents a, b, c (A) of state `y`.
    fn phase_currents(&self, y: &Vector) -> [f64; 3] {
        let (s, c) = self.theta(y[X]).sin_cos();
        inv_clarke(c * y[ID] - s * y[IQ], s * y[ID] + c * y[IQ])
    }

    /// Time derivative of the state (and of the energy and voltage integrals).
    fn deriv(&self, y: &Vector, fr: &Frozen) -> Vector {
        let (i_d, i_q, x) = (y[ID], y[IQ], y[X]);
        let (s, c) = self.theta(x).sin_cos();
        let i_abc = inv_clarke(c * i_d - s * i_q, s * i_d + c * i_q);
        let mut v_leg = [0.0; 3];
        let mut i_plus = 0.0;
        let mut loss = 0.0;
        for k in 0..3 {
            let o = leg_output(fr.modes[k], fr.signs[k], fr.upper_last[k], i_abc[k], fr.vdc, &self.dev);
            v_leg[k] = o.v;
            i_plus += o.i_plus;
            loss += o.loss_w;
        }
        let v_n = (v_leg[0] + v_leg[1] + v_leg[2]) / 3.0;
        let v_ph = v_leg.map(|v| v - v_n);
        let u_alpha = (2.0 * v_ph[0] - v_ph[1] - v_ph[2]) / 3.0;
        let u_beta = (v_ph[1] - v_ph[2]) / SQRT3;
        let u_d = c * u_alpha + s * u_beta;
        let u_q = -s * u_alpha + c * u_beta;

        let v = match fr.mech {
            Mech::Clamped(vc) => vc,
            Mech::Stuck => 0.0,
            Mech::Sliding(_) => y[V],
        };
        let w = self.pi_tau * v;
        let f_e = self.thrust(i_d, i_q);
        let (dv, dx, f_fric, f_load, f_end) = match fr.mech {
            Mech::Clamped(vc) => (0.0, vc, 0.0, 0.0, 0.0),
            Mech::Stuck => (0.0, 0.0, 0.0, 0.0, 0.0),
            Mech::Sliding(dir) => {
                let f_fric = self.b * v + self.fc * dir;
                let f_end = self.end_force(x);
                ((f_e - f_fric - fr.load - f_end) / self.mass, v, f_fric, fr.load, f_end)
            }
        };

        let mut d = [0.0; NY];
        if fr.open {
            // No current flows; the terminals show the back-EMF.
            let (e_alpha, e_beta) = (-s * w * self.psi_f, c * w * self.psi_f);
            d[V] = dv;
            d[X] = dx;
            d[E_FRIC] = f_fric * v;
            d[E_LOAD] = f_load * v;
            d[E_END] = f_end * v;
            d[INT_UA] = e_alpha;
            d[INT_UB] = e_beta;
            d[INT_VA..INT_VA + 3].copy_from_slice(&inv_clarke(e_alpha, e_beta));
            return d;
        }
        d[ID] = (u_d - self.rs * i_d + w * self.lq * i_q) / self.ld_incremental(i_d);
        d[IQ] = (u_q - self.rs * i_q - w * self.flux_d(i_d)) / self.lq;
        d[V] = dv;
        d[X] = dx;
        d[E_BUS] = fr.vdc * i_plus;
        d[E_MOTOR] = v_ph[0] * i_abc[0] + v_ph[1] * i_abc[1] + v_ph[2] * i_abc[2];
        d[E_CU] = 1.5 * self.rs * (i_d * i_d + i_q * i_q);
        d[E_DEV] = loss;
        d[W_THRUST] = f_e * v;
        d[E_FRIC] = f_fric * v;
        d[E_LOAD] = f_load * v;
        d[E_END] = f_end * v;
        d[INT_UA] = u_alpha;
        d[INT_UB] = u_beta;
        d[INT_VA..INT_VA + 3].copy_from_slice(&v_ph);
        d
    }

    fn rk4(&self, y: &mut Vector, h: f64, fr: &Frozen) {
        let axpy = |a: &Vector, s: f64, b: &Vector| -> Vector {
            let mut o = *a;
            for (oi, bi) in o.iter_mut().zip(b) {
                *oi += s * bi;
            }
            o
        };
        let k1 = self.deriv(y, fr);
        let k2 = self.deriv(&axpy(y, 0.5 * h, &k1), fr);
        let k3 = self.deriv(&axpy(y, 0.5 * h, &k2), fr);
        let k4 = self.deriv(&axpy(y, h, &k3), fr);
        for i in 0..NY {
            y[i] += h / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
        }
    }
}

/// Period averages over the last [`Plant::step`] (what an ideal, averaging
/// voltage sensor would have measured), and the inputs that were applied.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PeriodAverage {
    /// Duties applied, after clamping to `[0, 1]` (non-finite inputs become 0.5).
    pub duties: [f64; 3],
    /// Load force applied, newton (a non-finite input becomes 0).
    pub load_force_n: f64,
    /// Mean true DC-bus voltage over the period, volt.
    pub vdc_avg_v: f64,
    /// Mean applied alpha voltage (amplitude-invariant), volt.
    pub u_alpha_avg_v: f64,
    /// Mean applied beta voltage (amplitude-invariant), volt.
    pub u_beta_avg_v: f64,
    /// Mean applied phase voltages a, b, c to the motor's star point, volt.
    pub u_phase_avg_v: [f64; 3],
}

impl PeriodAverage {
    /// Phase voltages a, b, c (V) that an ideal inverter would have applied with
    /// these duties at the period's mean bus voltage: `vdc (d_k - mean(d))`.
    pub fn commanded_phase_v(&self) -> [f64; 3] {
        let m = (self.duties[0] + self.duties[1] + self.duties[2]) / 3.0;
        self.duties.map(|d| self.vdc_avg_v * (d - m))
    }

    /// Alpha and beta voltages (V) an ideal inverter would have applied (see
    /// [`Self::commanded_phase_v`]).
    pub fn commanded_alpha_beta_v(&self) -> (f64, f64) {
        let v = self.commanded_phase_v();
        ((2.0 * v[0] - v[1] - v[2]) / 3.0, (v[1] - v[2]) / SQRT3)
    }
}

/// The plant's true state at the present time (ground truth for tests and traces).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrueState {
    /// Time, second.
    pub t_s: f64,
    /// d-axis current, ampere.
    pub i_d_a: f64,
    /// q-axis current, ampere.
    pub i_q_a: f64,
    /// Alpha current, ampere.
    pub i_alpha_a: f64,
    /// Beta current, ampere.
    pub i_beta_a: f64,
    /// Phase currents a, b, c, ampere.
    pub i_abc_a: [f64; 3],
    /// Mover speed, metre per second.
    pub v_m_per_s: f64,
    /// Mover position, metre.
    pub x_m: f64,
    /// Electrical angle `pi x / tau + theta_offset`, radian, not wrapped.
    pub theta_e_rad: f64,
    /// Electrical angular speed `pi v / tau`, radian per second.
    pub omega_e_rad_per_s: f64,
    /// Mover (PM) flux, alpha component `psi_f cos(theta_e)`, weber.
    pub psi_f_alpha_wb: f64,
    /// Mover (PM) flux, beta component `psi_f sin(theta_e)`, weber.
    pub psi_f_beta_wb: f64,
    /// Stator flux linkage alpha `(Ld i_d + psi_f) cos - Lq i_q sin`, weber.
    pub psi_s_alpha_wb: f64,
    /// Stator flux linkage beta `(Ld i_d + psi_f) sin + Lq i_q cos`, weber.
    pub psi_s_beta_wb: f64,
    /// Electromagnetic thrust F_e, newton.
    pub thrust_n: f64,
    /// End-effect force `F_em cos(2 pi x / tau)` as subtracted in the mechanics, newton.
    pub end_effect_force_n: f64,
    /// True DC-bus voltage, volt.
    pub vdc_v: f64,
    /// `true` while the mover is held by static friction.
    pub stuck: bool,
    /// `true` while the speed is clamped.
    pub speed_clamped: bool,
    /// Averages over the last period.
    pub last_period: PeriodAverage,
}

/// Energy flows since the plant was built, joule (each the time integral of its
/// power), and the energies stored now.
///
/// Balances: `bus_j = motor_input_j + device_j`;
/// `motor_input_j = copper_j + delta(magnetic_j) + thrust_work_j`;
/// with free mechanics `thrust_work_j = delta(kinetic_j) + friction_j + load_j +
/// end_effect_j`. While the speed is clamped, friction, load and end-effect
/// flows are not accumulated (the clamp absorbs them).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnergyLedger {
    /// Drawn from the DC bus, `integral(vdc * i_dc)`.
    pub bus_j: f64,
    /// Delivered to the motor terminals, `integral(sum of v_kn i_k)`.
    pub motor_input_j: f64,
    /// Stator copper loss, `integral(1.5 Rs (i_d^2 + i_q^2))`.
    pub copper_j: f64,
    /// Inverter conduction loss (IGBT and diode drops).
    pub device_j: f64,
    /// Work of the electromagnetic thrust, `integral(F_e v)`.
    pub thrust_work_j: f64,
    /// Dissipated by viscous and Coulomb friction (including stopping at zero speed).
    pub friction_j: f64,
    /// Work done against the load force, `integral(F_load v)`.
    pub load_j: f64,
    /// Work done against the end-effect force, `integral(F_em cos(2 pi x / tau) v)`.
    pub end_effect_j: f64,
    /// Magnetic energy stored now, `0.75 (Ld i_d^2 + Lq i_q^2)`.
    pub magnetic_j: f64,
    /// Kinetic energy now, `0.5 M v^2`.
    pub kinetic_j: f64,
}

/// The simulated PMSLM drive power stage: motor, inverter and sensors.
#[derive(Debug, Clone)]
pub struct Plant {
    params: SimParams,
    model: Model,
    y: Vector,
    period_index: u64,
    legs: [LegCommand; 3],
    upper_last: [bool; 3],
    clamp: Option<f64>,
    stuck: bool,
    last: PeriodAverage,
    sensors: Sensors,
    /// The phase (0, 1, 2 for a, b, c) whose connection is broken, if any.
    open_phase: Option<usize>,
}

fn finite(what: &'static str, x: f64) -> Result<f64, PlantError> {
    if x.is_finite() { Ok(x) } else { Err(PlantError::NotFinite { what }) }
}

impl Plant {
    /// Builds a plant at rest (x = 0, v = 0, zero current, t = 0) after checking
    /// every parameter.
    pub fn new(params: &SimParams) -> Result<Self, PlantError> {
        params.validate()?;
        let model = Model::new(&params.plant, &params.inverter);
        let mut p = Plant {
            params: *params,
            model,
            y: [0.0; NY],
            period_index: 0,
            legs: [LegCommand::IDLE; 3],
            upper_last: [false; 3],
            clamp: None,
            stuck: false,
            last: PeriodAverage {
                duties: [0.5; 3],
                load_force_n: 0.0,
                vdc_avg_v: 0.0,
                u_alpha_avg_v: 0.0,
                u_beta_avg_v: 0.0,
                u_phase_avg_v: [0.0; 3],
            },
            sensors: Sensors::new(params.sensors, params.seed),
            open_phase: None,
        };
        p.last.vdc_avg_v = p.vdc_at(0.0);
        Ok(p)
    }

    /// The parameters the plant was built with.
    pub fn params(&self) -> &SimParams {
        &self.params
    }

    /// Present time, second (`periods stepped * Ts`).
    pub fn time_s(&self) -> f64 {
        self.period_index as f64 * self.params.inverter.pwm_period_s
    }

    /// PWM period Ts, second.
    pub fn pwm_period_s(&self) -> f64 {
        self.params.inverter.pwm_period_s
    }

    /// True DC-bus voltage at time `t_s` (second), volt.
    fn vdc_at(&self, t_s: f64) -> f64 {
        let inv = &self.params.inverter;
        if inv.bus_ripple_v == 0.0 {
            inv.dc_bus_v
        } else {
            inv.dc_bus_v + inv.bus_ripple_v * (2.0 * PI * inv.bus_ripple_hz * t_s).sin()
        }
    }

    /// Holds the mover at `Some(speed)` (m/s) from now on, or releases it (`None`)
    /// to free mechanics starting from its present speed. Refuses a non-finite speed.
    pub fn set_speed_clamp(&mut self, speed_m_per_s: Option<f64>) -> Result<(), PlantError> {
        match speed_m_per_s {
            Some(v) => {
                let v = finite("speed clamp", v)?;
                self.clamp = Some(v);
                self.y[V] = v;
                self.stuck = false;
            }
            None => self.clamp = None,
        }
        Ok(())
    }

    /// Breaks the connection of phase `Some(k)` (0, 1, 2 for a, b, c; others are
    /// ignored) from now on, or restores it (`None`): that phase's current is held at zero
    /// (after every integration step the current vector loses its component along the
    /// phase's axis), the other two carry equal and opposite currents. Exact for equal
    /// `Ld` and `Lq`; with saliency the projection is an approximation.
    pub fn set_open_phase(&mut self, phase: Option<usize>) {
        self.open_phase = phase.filter(|&k| k < 3);
        self.enforce_open_phase();
    }

    fn enforce_open_phase(&mut self) {
        let Some(k) = self.open_phase else { return };
        let axis = [0.0f64, 2.0 * PI / 3.0, -2.0 * PI / 3.0][k];
        let theta = self.model.theta(self.y[X]);
        // Phase k's current is the projection of the current vector on its axis.
        let rel = theta - axis;
        let (s, c) = rel.sin_cos();
        // Current vector in the phase's frame: along = c i_d - s i_q.
        let along = c * self.y[ID] - s * self.y[IQ];
        self.y[ID] -= along * c;
        self.y[IQ] -= along * (-s);
    }

    /// Moves the mover to `x_m` (metre); speed and currents are kept.
    pub fn set_position(&mut self, x_m: f64) -> Result<(), PlantError> {
        self.y[X] = finite("position", x_m)?;
        Ok(())
    }

    /// Sets the mover speed (m/s). If the speed is clamped, the clamp moves to it.
    pub fn set_speed(&mut self, v_m_per_s: f64) -> Result<(), PlantError> {
        let v = finite("speed", v_m_per_s)?;
        self.y[V] = v;
        if self.clamp.is_some() {
            self.clamp = Some(v);
        }
        Ok(())
    }

    /// Sets the winding currents in the rotor frame, ampere.
    pub fn set_currents_dq(&mut self, i_d_a: f64, i_q_a: f64) -> Result<(), PlantError> {
        let i_d = finite("i_d", i_d_a)?;
        let i_q = finite("i_q", i_q_a)?;
        self.y[ID] = i_d;
        self.y[IQ] = i_q;
        Ok(())
    }

    /// Mechanical state for the next RK4 step, from the state at its start.
    fn mech_mode(&self, y: &Vector, load: f64) -> Mech {
        if let Some(vc) = self.clamp {
            return Mech::Clamped(vc);
        }
        let v = y[V];
        if v > 0.0 {
            Mech::Sliding(1.0)
        } else if v < 0.0 {
            Mech::Sliding(-1.0)
        } else {
            let drive = self.model.thrust(y[ID], y[IQ]) - load - self.model.end_force(y[X]);
            if drive.abs() <= self.model.fs { Mech::Stuck } else { Mech::Sliding(drive.signum()) }
        }
    }

    /// Applies `duties` (upper-switch on-time fractions of legs a, b, c; each is
    /// clamped to `[0, 1]`, a non-finite one is replaced by 0.5) and the load force
    /// `load_force_n` (newton, opposing positive motion when positive; non-finite
    /// is taken as 0) over the period `[t, t + Ts)`, and advances to `t + Ts`.
    /// Never panics.
    pub fn step(&mut self, duties: [f64; 3], load_force_n: f64) {
        self.step_impl(duties, load_force_n, false);
    }

    /// Advances one period with every switch of the bridge off (a disabled drive): no
    /// current flows and the mover coasts under friction, end effect and `load_force_n`
    /// (as in [`Plant::step`]). Exact while the line-to-line back-EMF stays below the bus
    /// (`sqrt(3) w psi_f < V_dc`: 2.8 m/s on the paper motor at 311 V); above it the
    /// diodes would rectify into the bus, which this model does not represent (the
    /// currents are held at zero). The winding currents are set to zero on entry (the
    /// switching-off transient through the diodes is not modelled).
    pub fn step_open(&mut self, load_force_n: f64) {
        self.y[ID] = 0.0;
        self.y[IQ] = 0.0;
        self.step_impl([0.5; 3], load_force_n, true);
    }

    fn step_impl(&mut self, duties: [f64; 3], load_force_n: f64, open: bool) {
        let duties = duties.map(|d| if d.is_finite() { d.clamp(0.0, 1.0) } else { 0.5 });
        let load = if load_force_n.is_finite() { load_force_n } else { 0.0 };
        let ts = self.params.inverter.pwm_period_s;
        let max_h = self.params.effective_max_step_s();
        let t0 = self.time_s();
        let sched = PeriodSchedule::new(self.legs, duties, ts, self.params.inverter.dead_time_s);
        for i in INT_UA..NY {
            self.y[i] = 0.0;
        }
        let mut vdc_int = 0.0;
        let model = self.model;
        for w in sched.breakpoints().windows(2) {
            let (a, b) = (w[0], w[1]);
            let len = b - a;
            if len <= 0.0 {
                continue;
            }
            let mid = 0.5 * (a + b);
            let modes = [0, 1, 2].map(|k| sched.mode_at(k, mid));
            for (k, m) in modes.iter().enumerate() {
                match m {
                    LegMode::Upper => self.upper_last[k] = true,
                    LegMode::Lower => self.upper_last[k] = false,
                    LegMode::Dead => {}
                }
            }
            // Validation bounds Ts / max_h, so n stays small.
            let n = (len / max_h).ceil().max(1.0) as usize;
            let h = len / n as f64;
            for j in 0..n {
                let t_mid = t0 + a + (j as f64 + 0.5) * h;
                let vdc = self.vdc_at(t_mid);
                let i_abc = model.phase_currents(&self.y);
                let signs = i_abc.map(|i| {
                    if i > 0.0 {
                        1i8
                    } else if i < 0.0 {
                        -1
                    } else {
                        0
                    }
                });
                let mech = self.mech_mode(&self.y, load);
                self.stuck = mech == Mech::Stuck;
                let fr = Frozen { open, modes, signs, upper_last: self.upper_last, vdc, mech, load };
                model.rk4(&mut self.y, h, &fr);
                self.enforce_open_phase();
                // Coulomb friction cannot push the mover back through zero speed:
                // stop it there and book the (tiny) overshoot energy as friction.
                if let Mech::Sliding(dir) = mech
                    && model.fc > 0.0
                    && self.y[V] * dir < 0.0
                {
                    self.y[E_FRIC] += 0.5 * model.mass * self.y[V] * self.y[V];
                    self.y[V] = 0.0;
                }
                vdc_int += vdc * h;
            }
        }
        self.legs = sched.carry();
        self.period_index += 1;
        self.last = PeriodAverage {
            duties,
            load_force_n: load,
            vdc_avg_v: vdc_int / ts,
            u_alpha_avg_v: self.y[INT_UA] / ts,
            u_beta_avg_v: self.y[INT_UB] / ts,
            u_phase_avg_v: [self.y[INT_VA] / ts, self.y[INT_VA + 1] / ts, self.y[INT_VA + 2] / ts],
        };
    }

    /// Sensor readings at the present time (a carrier valley). Each call draws
    /// fresh noise, so call it once per period.
    pub fn sample(&mut self) -> SensorReading {
        let t = self.time_s();
        let i_abc = self.model.phase_currents(&self.y);
        let vdc = self.vdc_at(t);
        self.sensors.read(t, i_abc, vdc)
    }

    /// The true state now.
    pub fn state(&self) -> TrueState {
        let m = &self.model;
        let (i_d, i_q, v, x) = (self.y[ID], self.y[IQ], self.y[V], self.y[X]);
        let theta = m.theta(x);
        let (s, c) = theta.sin_cos();
        let i_alpha = c * i_d - s * i_q;
        let i_beta = s * i_d + c * i_q;
        let psi_d = m.flux_d(i_d);
        let psi_q = m.lq * i_q;
        TrueState {
            t_s: self.time_s(),
            i_d_a: i_d,
            i_q_a: i_q,
            i_alpha_a: i_alpha,
            i_beta_a: i_beta,
            i_abc_a: inv_clarke(i_alpha, i_beta),
            v_m_per_s: v,
            x_m: x,
            theta_e_rad: theta,
            omega_e_rad_per_s: m.pi_tau * v,
            psi_f_alpha_wb: m.psi_f * c,
            psi_f_beta_wb: m.psi_f * s,
            psi_s_alpha_wb: c * psi_d - s * psi_q,
            psi_s_beta_wb: s * psi_d + c * psi_q,
            thrust_n: m.thrust(i_d, i_q),
            end_effect_force_n: m.end_force(x),
            vdc_v: self.vdc_at(self.time_s()),
            stuck: self.stuck,
            speed_clamped: self.clamp.is_some(),
            last_period: self.last,
        }
    }

    /// Energy flows since the plant was built, and the energies stored now.
    pub fn energy(&self) -> EnergyLedger {
        let m = &self.model;
        let y = &self.y;
        EnergyLedger {
            bus_j: y[E_BUS],
            motor_input_j: y[E_MOTOR],
            copper_j: y[E_CU],
            device_j: y[E_DEV],
            thrust_work_j: y[W_THRUST],
            friction_j: y[E_FRIC],
            load_j: y[E_LOAD],
            end_effect_j: y[E_END],
            magnetic_j: 0.75 * (m.ld * y[ID] * y[ID] + m.lq * y[IQ] * y[IQ]),
            kinetic_j: 0.5 * m.mass * y[V] * y[V],
        }
    }
}
