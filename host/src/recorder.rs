//! Sensored recordings: what a lab recorder logs from an axis that a load machine moves
//! along a prescribed speed profile, independent of the estimator under test.
//!
//! The simulated axis (inverter with dead time and drops, sensors with offsets, gain
//! errors, noise and quantisation; [`crate::plant`]) has its speed imposed by the load
//! machine (the plant's speed clamp, set every period from the profile) while a current
//! controller on the plant's *true* angle, as an encoder drive runs it, drives the thrust
//! current the profile needs: the recording load plus the moving mass times the profile's
//! acceleration. The drive's inverter compensation is applied, and what the controller
//! commands (less the compensation) and measures is the trace, exactly as a recording
//! that starts or reverses mid-motion holds it. `dcfo acquire` (constant speeds) and
//! `dcfo track` (reversals, speed steps) replay such recordings through the estimator
//! alone.

use dcfo::algorithms::pi::Pi;
use dcfo::algorithms::svpwm::{DcBus, svpwm_on};
use dcfo::algorithms::transforms::{AlphaBeta, CosSin, Dq, inverse_clarke, inverse_park, park};
use dcfo::drive::{COMPENSATION_REFERENCE_FROM_BANDS, CompensationSigns};
use dcfo::estimator::{Estimate, Estimator};
use dcfo::motor::MotorParams;
use dcfo::num::Scalar;
use dcfo::num::units::Base;

use crate::closed_loop::{Bridge, ClosedLoop};
use crate::plant::Plant;
use crate::simulation::Setup;

/// One recorded period: the observer's inputs as a trace row holds them, and the truth.
#[derive(Clone, Copy, Debug)]
pub struct Row {
    /// Voltage applied during `[t_k, t_k + Ts)` as the controller intended it, V.
    pub u: [f64; 2],
    /// Voltage the inverter actually applied over that period (the plant's period
    /// average), V: `u_actual - u` is the inverter's error the estimator is not told.
    pub u_actual: [f64; 2],
    /// Measured currents at `t_k`, A.
    pub i: [f64; 2],
    /// True electrical angle at `t_k`, rad.
    pub theta: f64,
    /// True speed at `t_k`, m/s.
    pub v: f64,
}

/// The load machine's trajectory: speed (m/s) and acceleration (m/s^2) at a time (s).
pub trait SpeedProfile {
    /// `(speed m/s, acceleration m/s^2)` at `t_s` seconds from the recording's start.
    fn at(&self, t_s: f64) -> (f64, f64);
}

/// A constant speed (m/s).
#[derive(Clone, Copy, Debug)]
pub struct ConstantSpeed(pub f64);

impl SpeedProfile for ConstantSpeed {
    fn at(&self, _t_s: f64) -> (f64, f64) {
        (self.0, 0.0)
    }
}

/// Speed steps through a first-order reference prefilter, as a speed drive commands
/// them: the speed starts at `initial_m_per_s` and moves towards each step's speed from
/// its time on, `v' = (target - v) / prefilter_s`; with `accel_limit_m_per_s2` the
/// prefilter's rate is also limited (a trapezoidal move's ramps).
#[derive(Clone, Debug)]
pub struct PrefilteredSteps {
    /// Speed at `t = 0`, m/s.
    pub initial_m_per_s: f64,
    /// `(time s, target speed m/s)`, in time order.
    pub steps: Vec<(f64, f64)>,
    /// Prefilter time constant, s (> 0).
    pub prefilter_s: f64,
    /// Acceleration limit, m/s^2 (`f64::INFINITY` for none).
    pub accel_limit_m_per_s2: f64,
}

impl PrefilteredSteps {
    /// The whole trajectory sampled every `dt_s` up to `duration_s`: `(v, a)` per sample.
    pub fn sampled(&self, dt_s: f64, duration_s: f64) -> Vec<(f64, f64)> {
        let n = (duration_s / dt_s).round() as usize + 1;
        let mut v = self.initial_m_per_s;
        let mut out = Vec::with_capacity(n);
        for k in 0..n {
            let t = k as f64 * dt_s;
            let target =
                self.steps.iter().rev().find(|(ts, _)| *ts <= t).map(|s| s.1).unwrap_or(self.initial_m_per_s);
            let a = ((target - v) / self.prefilter_s)
                .clamp(-self.accel_limit_m_per_s2, self.accel_limit_m_per_s2);
            out.push((v, a));
            v += a * dt_s;
        }
        out
    }
}

/// A trajectory sampled at the recording's period: `(v, a)` per period.
#[derive(Clone, Debug)]
pub struct SampledProfile {
    /// `(speed m/s, acceleration m/s^2)` per period.
    pub samples: Vec<(f64, f64)>,
    /// The period, s.
    pub dt_s: f64,
}

impl SpeedProfile for SampledProfile {
    fn at(&self, t_s: f64) -> (f64, f64) {
        let k = (t_s / self.dt_s).round().max(0.0) as usize;
        self.samples.get(k).or(self.samples.last()).copied().unwrap_or((0.0, 0.0))
    }
}

/// Records `duration_s` of the plant of `setup` moved along `profile` from mover
/// position `x0_m`, the thrust current that of `load_n` (N, opposing the motion) plus the
/// moving mass times the profile's acceleration. The first 0.1 s (current loops settling
/// on the profile's initial speed) are dropped: row 0 is the profile at `t = 0`.
pub fn record(
    setup: &Setup,
    profile: &dyn SpeedProfile,
    x0_m: f64,
    load_n: f64,
    duration_s: f64,
) -> Result<Vec<Row>, String> {
    let err = |e: &dyn std::fmt::Debug| format!("recording: {e:?}");
    let motor = &setup.motor;
    let mut plant = Plant::new(&setup.plant).map_err(|e| err(&e))?;
    plant.set_position(x0_m).map_err(|e| err(&e))?;
    let ts = plant.pwm_period_s();
    // The bridge switches from the start, at 50 % duty until the controller's first
    // duties take effect.
    let mut closed_loop = ClosedLoop::starting_with(plant, Bridge::On([0.5; 3]));
    let wc = f64::from(setup.drive.current_bandwidth_rad_s);
    let (l, r, psi) = (f64::from(motor.lq_h), f64::from(motor.rs_ohm), f64::from(motor.psi_f_wb));
    let pi = |lim: f64| Pi::new(l * wc, r * wc * ts, -lim, lim).map_err(|e| err(&e));
    let vmax = setup.plant.inverter.dc_bus_v / 3f64.sqrt();
    let (mut pi_d, mut pi_q) = (pi(vmax)?, pi(vmax)?);
    let kf = f64::from(motor.thrust_constant_n_per_a());
    let mass = setup.plant.plant.mass_kg;
    let comp = setup.drive.dead_time_compensation.map(|c| {
        (
            c,
            dcfo::algorithms::dead_time::InverterErrorModel::<f64>::for_drive(
                &c,
                ts as f32,
                motor,
                &Base::SI,
            ),
        )
    });
    let skip = (0.1 / ts).round() as usize;
    let n = skip + (duration_s / ts).round() as usize;
    let mut rows = Vec::with_capacity(n);
    // The voltage the controller intended for the period now queued, V.
    let mut u_queued = [0.0f64; 2];
    for k in 0..n {
        let t = k.saturating_sub(skip) as f64 * ts;
        let (v, a) = profile.at(t);
        closed_loop.plant_mut().set_speed_clamp(Some(v)).map_err(|e| err(&e))?;
        let omega = omega_e(motor, v);
        let sensed = closed_loop.sense();
        let reading = sensed.reading;
        let theta = sensed.truth.theta_e_rad;
        let i_ab = AlphaBeta::new(reading.i_alpha_a, reading.i_beta_a);
        let cs = CosSin { cos: theta.cos(), sin: theta.sin() };
        let i_dq = park(i_ab, &cs);
        let iq_ref = (load_n * v.signum() + mass * a) / kf;
        let u_d = pi_d.update(-i_dq.d) - omega * l * i_dq.q;
        let u_q = pi_q.update(iq_ref - i_dq.q) + omega * (l * i_dq.d + psi);
        let apply = theta + 1.5 * omega * ts;
        let cs_apply = CosSin { cos: apply.cos(), sin: apply.sin() };
        let u_ab = inverse_park(Dq::new(u_d, u_q), &cs_apply);
        // The drive's inverter compensation (`dcfo::algorithms::dead_time`), from the current carried
        // to the window: the measured current blended into the reference as the drive
        // does (`Drive::compensation_current`).
        let bus = DcBus::new(reading.vdc_v).map_err(|e| err(&e))?;
        let c = match comp {
            Some((c, model)) => {
                let band = f64::from(c.current_band_a);
                let from = f64::from(COMPENSATION_REFERENCE_FROM_BANDS);
                let w = match setup.drive.compensation_signs {
                    CompensationSigns::Measured => 0.0,
                    CompensationSigns::ReferenceAboveNoise => {
                        ((iq_ref.abs() / band - from) / from).clamp(0.0, 1.0)
                    }
                };
                let i_sign = Dq::new(i_dq.d * (1.0 - w), i_dq.q + w * (iq_ref - i_dq.q));
                model.compensation(u_ab, &bus, inverse_clarke(inverse_park(i_sign, &cs_apply)))
            }
            None => AlphaBeta::new(0.0, 0.0),
        };
        let m =
            svpwm_on(AlphaBeta::new(u_ab.alpha + c.alpha, u_ab.beta + c.beta), &bus).map_err(|e| err(&e))?;
        let applied =
            closed_loop.actuate(sensed, Bridge::On([m.duties.a, m.duties.b, m.duties.c]), 0.0).applied;
        if k >= skip {
            rows.push(Row {
                u: u_queued,
                u_actual: [applied.u_alpha_avg_v, applied.u_beta_avg_v],
                i: [i_ab.alpha, i_ab.beta],
                theta,
                v,
            });
        }
        u_queued = [m.u_applied.alpha - c.alpha, m.u_applied.beta - c.beta];
    }
    Ok(rows)
}

/// The electrical angular speed of `v` (m/s) on `motor`, rad/s.
pub fn omega_e(motor: &MotorParams, v: f64) -> f64 {
    std::f64::consts::PI * v / f64::from(motor.pole_pitch_m)
}

/// Replays `rows` (recorded at `ts` seconds) through a fresh estimator of `setup`'s
/// drive in number type `T` and working units `base`, with the DC offsets `du` (V) and
/// `di` (A, alpha-beta) added to its inputs, as `dcfo replay` feeds a trace: sample `k`
/// gets row `k - 1`'s voltage (the first sample none: a recording that starts
/// mid-motion has no earlier voltage) and row `k`'s currents. Per sample, the angle
/// estimate (rad) and the `locked` flag; and the first sample after the estimator's
/// circle fit ended ([`Estimator::fitting`]; the number of rows if it never did).
///
/// # Errors
/// The estimator refused its settings or a sample.
pub fn replay<T: Scalar>(
    setup: &Setup,
    base: &Base,
    rows: &[Row],
    ts: f64,
    du: [f64; 2],
    di: [f64; 2],
) -> Result<(Vec<(f64, bool)>, usize), String> {
    replay_observed::<T>(setup, base, rows, ts, du, di, |_, _| {})
}

/// [`replay`], with `observe` called after every sample with the estimator (after its
/// update) and the sample's estimate: what a diagnostic reads of its inner loops (the
/// notch, the FLL). `observe` only reads, so the estimates are [`replay`]'s.
///
/// # Errors
/// The estimator refused its settings or a sample.
pub fn replay_observed<T: Scalar>(
    setup: &Setup,
    base: &Base,
    rows: &[Row],
    ts: f64,
    du: [f64; 2],
    di: [f64; 2],
    mut observe: impl FnMut(&Estimator<T>, &Estimate<T>),
) -> Result<(Vec<(f64, bool)>, usize), String> {
    let mut est: Estimator<T> = Estimator::new(&setup.motor, &setup.drive.estimator, base)
        .map_err(|e| format!("estimator: {e:?}"))?;
    let dt = base.time(ts as f32);
    let mut out = Vec::with_capacity(rows.len());
    let mut u_prev = [0.0f64; 2];
    let mut fit_end = None;
    for (k, r) in rows.iter().enumerate() {
        let u = AlphaBeta::new(
            base.voltage((u_prev[0] + du[0]) as f32),
            base.voltage((u_prev[1] + du[1]) as f32),
        );
        u_prev = r.u;
        let i = AlphaBeta::new(base.current((r.i[0] + di[0]) as f32), base.current((r.i[1] + di[1]) as f32));
        let e = est.update(u, i, dt).map_err(|e| format!("estimator fault at sample {k}: {e:?}"))?;
        observe(&est, &e);
        out.push((e.theta_e.to_radians::<f64>(), e.locked));
        if fit_end.is_none() && !est.fitting() {
            fit_end = Some(k + 1);
        }
    }
    Ok((out, fit_end.unwrap_or(rows.len())))
}
