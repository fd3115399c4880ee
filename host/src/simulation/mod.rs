//! Closed-loop simulation: the plant model and the library's drive (the firmware's
//! control step, `Drive<f32>` in SI units or `Drive<Q24>` per-unit: [`LocalDrive`]) in
//! lock-step, with scenario events and ground truth. Both numeric types log the same
//! detailed samples ([`StepDetail`], converted to SI through the drive's base); a drive
//! behind a link ([`Controller`] in `crate::hil_link`) logs what the link carries.
//! Every controller steps on the HIL link's frames: [`sensor_frame`] turns the plant's
//! SI readings into one, [`frame_bridge`] an answer into the bridge of the next period.
//!
//! Per PWM period `k` (time `t_k`), in the order of [`crate::closed_loop`]: the plant's
//! sensors are sampled, the drive computes its step, the plant runs the period with the
//! duties computed one step earlier (the drive's one-period computation delay), and a
//! trace row is logged. Rows start at the
//! drive's first start-up step, when its estimator is reset, so that replaying the
//! trace through the same estimator reproduces the run's estimates exactly.

pub mod figures;
pub mod scenarios;

use crate::closed_loop::{Bridge, ClosedLoop};
use crate::plant::{Plant, PlantError, SensorReading, SimParams};
use crate::trace::{TraceRow, wrap_angle};
use dcfo::algorithms::observer::ObserverKind;
use dcfo::algorithms::transforms::{Abc, AlphaBeta, clarke};
use dcfo::drive::{Drive, DriveConfig, DriveState, Faults, PAPER_AXIS_PAYLOAD_KG, StepOutput};
use dcfo::link::{ActuationFrame, LinkStats, PositionReport, SensorFrame};
use dcfo::motor::MotorParams;
use dcfo::num::units::Base;
use dcfo::num::{Q24, Scalar};

pub use scenarios::{Event, PlantChanges, Scenario};

/// One logged sample: the trace row (observer inputs and ground truth) and what the
/// drive estimated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Inputs and ground truth, in the trace format's terms.
    pub row: TraceRow,
    /// Estimated electrical angle, rad in (-pi, pi].
    pub theta_hat: f64,
    /// The angle estimate as the HIL link reports it (rad, f32): equal bit for bit
    /// between the in-process drive and the same drive on a target with IEEE f32.
    pub theta_hat_link: f32,
    /// Estimated speed, m/s.
    pub v_hat: f64,
    /// Estimated mover flux, Wb.
    pub psi_hat: [f64; 2],
    /// True mover flux, Wb.
    pub psi_true: [f64; 2],
    /// Voltage the inverter actually applied, averaged over `[t, t + Ts)`, V: compare
    /// with `row.u_alpha`, `row.u_beta` (what the observer is told) for the inverter's
    /// error.
    pub u_actual: [f64; 2],
    /// d-axis current reference and measurement in the control frame, A.
    pub i_d_ref: f64,
    /// Measured d-axis current in the control frame, A.
    pub i_d: f64,
    /// Thrust-current reference in the control frame, A.
    pub i_q_ref: f64,
    /// Measured q-axis current in the control frame, A.
    pub i_q: f64,
    /// Speed reference target while running sensorless, m/s (NaN before hand-over).
    pub v_ref: f64,
    /// Drive state code ([`DriveState::code`]).
    pub state: u8,
    /// The estimator's lock flag (`None` over a link, which does not carry it).
    pub locked: Option<bool>,
    /// The commanded electrical acceleration the drive's estimator used, rad/s^2 (NaN
    /// over a link, which does not carry it).
    pub alpha_e_ref: f64,
}

/// The result of one simulated run.
#[derive(Clone, Debug)]
pub struct Run {
    /// Scenario name.
    pub scenario: String,
    /// Observer used.
    pub observer: ObserverKind,
    /// Logged samples, from the first start-up step on.
    pub samples: Vec<Sample>,
    /// Time of the hand-over to sensorless operation, s (None if it never happened).
    pub handover_s: Option<f64>,
    /// Faults latched at the end of the run.
    pub faults: Faults,
    /// Control period, s.
    pub period_s: f64,
    /// Simulated time, s.
    pub simulated_s: f64,
    /// The motor's pole pitch, m (one electrical period is two).
    pub pole_pitch_m: f64,
}

/// Why a simulation could not run.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The plant parameters were refused.
    #[error("plant: {0}")]
    Plant(#[from] PlantError),
    /// The drive settings were refused.
    #[error("drive: {0}")]
    Drive(dcfo::drive::DriveConfigError),
    /// The controller behind the HIL link failed (I/O, timeout, bad frame) or cannot do
    /// what the scenario asks.
    #[error("controller: {0}")]
    Controller(String),
}

/// Everything a run needs besides the scenario.
#[derive(Clone, Debug)]
pub struct Setup {
    /// Motor as the drive knows it.
    pub motor: MotorParams,
    /// Plant, inverter and sensors (the plant may differ from `motor`, e.g. R = 2 Rs).
    pub plant: SimParams,
    /// Drive settings.
    pub drive: DriveConfig,
}

impl Setup {
    /// The paper motor on the simulated test axis: the plant carries the
    /// [`PAPER_AXIS_PAYLOAD_KG`] carriage on a realistic inverter and sensors, and the
    /// drive runs [`DriveConfig::paper_axis`] — the settings the HIL firmware runs too.
    pub fn paper(observer: ObserverKind) -> Self {
        let motor = MotorParams::paper();
        let mut plant = SimParams::from_motor(&motor);
        plant.plant.mass_kg += f64::from(PAPER_AXIS_PAYLOAD_KG);
        Setup { motor, plant, drive: DriveConfig::paper_axis(observer) }
    }

    /// Any motor on the realistic simulated inverter and sensors of
    /// [`SimParams::from_motor`], with the drive tuned from the motor file alone
    /// ([`DriveConfig::for_motor`] on the inverter's bus) and compensating the
    /// inverter's dead time and mean device drop ([`compensation_for`]).
    pub fn for_motor(motor: &MotorParams, observer: ObserverKind) -> Self {
        let plant = SimParams::from_motor(motor);
        let mut drive = DriveConfig::for_motor(motor, plant.inverter.dc_bus_v as f32, observer);
        drive.dead_time_compensation = Some(compensation_for(&plant));
        Setup { motor: *motor, plant, drive }
    }
}

impl Setup {
    /// `motor` on the axis `scenario` describes: [`Setup::for_motor`], the plant carrying
    /// the scenario's payload (which the drive is told, as a user configures a drive with
    /// the mass of its axis); the scenario's other plant deviations stay unknown to the
    /// drive.
    pub fn for_axis(motor: &MotorParams, scenario: &Scenario, observer: ObserverKind) -> Self {
        let mut setup = Setup::for_motor(motor, observer);
        setup.drive.moving_mass_kg += scenario.plant.payload_kg as f32;
        setup
    }
}

/// The drive's inverter compensation for the simulated inverter and sensors of `sim`:
/// its dead time, the mean of its IGBT and diode threshold drops, and a sign band of
/// one current-sensor noise sigma (at least 1 mA).
pub fn compensation_for(sim: &SimParams) -> dcfo::drive::DeadTimeCompensation {
    let inv = &sim.inverter;
    dcfo::drive::DeadTimeCompensation {
        dead_time_s: inv.dead_time_s as f32,
        device_drop_v: (0.5 * (inv.igbt_threshold_v + inv.diode_threshold_v)) as f32,
        current_band_a: sim.sensors.current_noise_rms_a.max(1e-3) as f32,
    }
}

/// One control step as the simulation sees it: the actuation frame (what a drive behind
/// a serial link reports, with its conversions) and, for the in-process drive of any
/// numeric type, the drive's full step output in SI units.
#[derive(Clone, Copy, Debug)]
pub struct ControlStep {
    /// What the drive reports, exactly as the HIL link carries it.
    pub frame: ActuationFrame,
    /// The in-process drive's full output (observer inputs, currents); `None` over a
    /// link.
    pub detail: Option<StepDetail>,
}

/// A drive step's full output ([`StepOutput`]) in SI units, converted from the drive's
/// working units (f32 SI or Q8.24 per-unit) through its [`Base`]: for the f32 drive in
/// SI the values are its own, bit for bit (the base's factors are 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepDetail {
    /// Voltage applied during the present period as the observer sees it (α, β), V.
    pub u_applied_v: [f64; 2],
    /// Currents as the observer saw them this step (α, β), A.
    pub i_observer_a: [f64; 2],
    /// Measured currents in the control frame (d, q), A.
    pub i_dq_a: [f64; 2],
    /// Current references in the control frame (d, q), A.
    pub i_dq_ref_a: [f64; 2],
    /// The control frame's angle, electrical rad in `[-pi, pi)`.
    pub theta_control_rad: f64,
    /// The commanded electrical acceleration the estimator used, rad/s^2.
    pub alpha_e_ref_rad_per_s2: f64,
    /// The estimator's output, `None` while it is not running.
    pub estimate: Option<EstimateDetail>,
}

/// The estimator's output of one step in SI units (see [`StepDetail`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimateDetail {
    /// Estimated electrical angle, rad in (-pi, pi].
    pub theta_e_rad: f64,
    /// Estimated mover flux (α, β), Wb.
    pub psi_wb: [f64; 2],
    /// The estimator's lock flag.
    pub locked: bool,
}

impl StepDetail {
    /// The step output `out` of a drive working in `base`, in SI units.
    pub fn from_step<T: Scalar>(out: &StepOutput<T>, base: &Base) -> Self {
        let volts =
            |ab: AlphaBeta<T>| [f64::from(base.to_volts(ab.alpha)), f64::from(base.to_volts(ab.beta))];
        let amperes = |x: T| f64::from(base.to_amperes(x));
        StepDetail {
            u_applied_v: volts(out.u_applied),
            i_observer_a: [amperes(out.i_observer.alpha), amperes(out.i_observer.beta)],
            i_dq_a: [amperes(out.i_dq.d), amperes(out.i_dq.q)],
            i_dq_ref_a: [amperes(out.i_dq_ref.d), amperes(out.i_dq_ref.q)],
            theta_control_rad: out.theta_control.to_radians::<f64>(),
            alpha_e_ref_rad_per_s2: f64::from(base.to_rad_per_s(out.alpha_e_ref) / base.time_s()),
            estimate: out.estimate.map(|est| EstimateDetail {
                theta_e_rad: est.theta_e.to_radians::<f64>(),
                psi_wb: [
                    f64::from(base.to_webers(est.psi_ab.alpha)),
                    f64::from(base.to_webers(est.psi_ab.beta)),
                ],
                locked: est.locked,
            }),
        }
    }
}

/// `reading` as the lock-step link's sensor frame number `sequence`: the readings in
/// f32, the drive enabled, the speed reference `speed_ref_m_per_s` (m/s) and a move to
/// queue, if any. Every [`Controller`] steps on such frames, the in-process drive as
/// the firmware's link server hands them to its drive.
pub fn sensor_frame(
    reading: &SensorReading,
    sequence: u16,
    speed_ref_m_per_s: f32,
    move_to: Option<dcfo::algorithms::motion::Move>,
) -> SensorFrame {
    let [a, b, c] = reading.i_abc_a;
    SensorFrame {
        sequence,
        i_a: a as f32,
        i_b: b as f32,
        i_c: c as f32,
        vdc: reading.vdc_v as f32,
        speed_ref: speed_ref_m_per_s,
        enable: true,
        clear_faults: false,
        move_to,
    }
}

/// `reading` as the drive takes it in this process: phase currents (A) and bus
/// voltage (V) in f32, SI.
pub fn measurements(reading: &SensorReading) -> dcfo::drive::Measurements<f32> {
    let [a, b, c] = reading.i_abc_a;
    dcfo::drive::Measurements::from_si([a as f32, b as f32, c as f32], reading.vdc_v as f32, &Base::SI)
}

/// The bridge an actuation frame asks for over the next period: its duties when it
/// enables the bridge, off otherwise.
pub fn frame_bridge(frame: &ActuationFrame) -> Bridge {
    Bridge::driven(frame.bridge_enabled, [frame.duty_a, frame.duty_b, frame.duty_c].map(f64::from))
}

/// The bridge a drive step in this process asks for over the next period (as
/// [`frame_bridge`] for its actuation frame).
pub fn output_bridge(out: &StepOutput<f32>) -> Bridge {
    Bridge::driven(out.bridge_enabled, [out.duties.a, out.duties.b, out.duties.c].map(f64::from))
}

/// A drive the simulation can close the loop with: in-process ([`LocalDrive`]) or
/// behind the HIL serial link (`crate::hil_link`).
pub trait Controller {
    /// Adds DC offsets to the observer's voltage (V) and current (A) inputs (the paper's
    /// disturbance tests); only an in-process drive can.
    fn set_observer_offsets(&mut self, u_v: [f64; 2], i_a: [f64; 2]) -> Result<(), SimError>;
    /// One control step on the sensor frame (measurements and commands) of this period.
    fn step(&mut self, sensor: &SensorFrame) -> Result<ControlStep, SimError>;
    /// Resets the drive's estimator to its zero state (fault injection: a lock loss at
    /// speed); only an in-process drive can.
    fn reset_estimator(&mut self) -> Result<(), SimError>;
}

/// The library's drive in this process: `Drive<f32>` in SI units ([`LocalDrive::new`]),
/// as the Cortex-M4F firmware runs it, or `Drive<Q24>` in the motor's per-unit base
/// ([`LocalDrive::fixed_point`]), as the Cortex-M3 firmware runs it.
#[derive(Clone, Debug)]
pub struct LocalDrive<T = f32> {
    drive: Drive<T>,
    base: Base,
    /// Moves the drive refused, counted as the firmware's link server counts them.
    moves_rejected: u16,
}

impl LocalDrive<f32> {
    /// An f32 drive (SI units) for `setup`'s motor and settings.
    pub fn new(setup: &Setup) -> Result<Self, SimError> {
        Ok(LocalDrive {
            drive: Drive::new(&setup.motor, &setup.drive, &Base::SI).map_err(SimError::Drive)?,
            base: Base::SI,
            moves_rejected: 0,
        })
    }
}

impl LocalDrive<Q24> {
    /// A Q8.24 fixed-point drive in the per-unit base of `setup`'s motor.
    pub fn fixed_point(setup: &Setup) -> Result<Self, SimError> {
        let base = Base::for_motor(&setup.motor);
        Ok(LocalDrive {
            drive: Drive::new(&setup.motor, &setup.drive, &base).map_err(SimError::Drive)?,
            base,
            moves_rejected: 0,
        })
    }
}

impl<T: Scalar> Controller for LocalDrive<T> {
    fn reset_estimator(&mut self) -> Result<(), SimError> {
        self.drive.reset_estimator();
        Ok(())
    }

    fn set_observer_offsets(&mut self, u_v: [f64; 2], i_a: [f64; 2]) -> Result<(), SimError> {
        let b = &self.base;
        self.drive.set_observer_offsets(
            AlphaBeta::new(b.voltage(u_v[0] as f32), b.voltage(u_v[1] as f32)),
            AlphaBeta::new(b.current(i_a[0] as f32), b.current(i_a[1] as f32)),
        );
        Ok(())
    }

    fn step(&mut self, sensor: &SensorFrame) -> Result<ControlStep, SimError> {
        // The same calls the firmware's link server makes on a received frame: the drive
        // gets exactly the inputs (f32 conversions, per-unit scaling, moves) the
        // firmware's gets, and the frame carries exactly what the firmware would send,
        // which keeps an in-process run bit-identical with a HIL run of the same numeric
        // type.
        if sensor.apply_commands(&mut self.drive).is_err() {
            self.moves_rejected = self.moves_rejected.wrapping_add(1);
        }
        let out = self.drive.step(&sensor.measurements(&self.base));
        let mut frame = ActuationFrame::from_step(sensor.sequence, &out, &self.base, LinkStats::default());
        frame.position = PositionReport::of(&self.drive, self.moves_rejected);
        Ok(ControlStep { frame, detail: Some(StepDetail::from_step(&out, &self.base)) })
    }
}

/// Runs `scenario` on `setup` with the in-process drive, calling `progress(fraction)`
/// now and then.
pub fn run(setup: &Setup, scenario: &Scenario, progress: impl FnMut(f64)) -> Result<Run, SimError> {
    run_with(setup, scenario, &mut LocalDrive::new(setup)?, progress)
}

/// Runs `scenario` with the plant of `setup` in closed loop with `controller`.
///
/// Trace rows log what the observer was given. Over a link the drive's intended
/// voltage is not carried: rows then hold the voltage commanded by the duties (dead-time
/// compensation included) and the Clarke transform of the measured currents, so such a
/// trace is for plots and summaries, not for bit-exact replay.
pub fn run_with(
    setup: &Setup,
    scenario: &Scenario,
    controller: &mut dyn Controller,
    mut progress: impl FnMut(f64),
) -> Result<Run, SimError> {
    let mut plant_params = setup.plant;
    scenario.plant.apply(&mut plant_params.plant);
    let mut closed_loop = ClosedLoop::new(Plant::new(&plant_params)?);
    let ts = closed_loop.plant().pwm_period_s();
    let n = (scenario.duration_s / ts).round() as usize;
    let mut load_n = 0.0;
    let mut samples = Vec::with_capacity(n);
    let mut handover_s = None;
    let mut events = scenario.events.clone();
    events.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut next_event = 0;
    let mut v_ref_target = 0.0;
    let mut faults = Faults::NONE;
    for k in 0..n {
        let t = k as f64 * ts;
        while next_event < events.len() && events[next_event].0 <= t + 0.5 * ts {
            match events[next_event].1 {
                Event::Speed(v) => v_ref_target = v,
                Event::Load(f) => load_n = f,
                Event::ObserverOffsets { u_v, i_a } => controller.set_observer_offsets(u_v, i_a)?,
                Event::ResetEstimator => controller.reset_estimator()?,
                Event::MoverSpeed(v) => closed_loop.plant_mut().set_speed(v)?,
            }
            next_event += 1;
        }
        let sensed = closed_loop.sense();
        let step = controller.step(&sensor_frame(&sensed.reading, k as u16, v_ref_target as f32, None))?;
        let f = step.frame;
        let period = closed_loop.actuate(sensed, frame_bridge(&f), load_n);
        let (reading, truth, applied) = (period.reading, period.truth, period.applied);
        faults = f.faults();
        if f.state() == DriveState::Running && handover_s.is_none() {
            handover_s = Some(t);
        }
        let Some(e) = f.estimate else { continue };
        let v_ref = if f.state() == DriveState::Running { v_ref_target } else { f64::NAN };
        let locked = step.detail.and_then(|d| d.estimate).map(|est| est.locked);
        let alpha_e_ref = step.detail.map_or(f64::NAN, |d| d.alpha_e_ref_rad_per_s2);
        let (observer_u, observer_i, i_dq, i_dq_ref, theta_hat, psi_hat) = match step.detail {
            Some(d) => match d.estimate {
                Some(est) => {
                    (d.u_applied_v, d.i_observer_a, d.i_dq_a, d.i_dq_ref_a, est.theta_e_rad, est.psi_wb)
                }
                None => continue,
            },
            None => {
                let (ua, ub) = applied.commanded_alpha_beta_v();
                let i = clarke(Abc { a: reading.i_abc_a[0], b: reading.i_abc_a[1], c: reading.i_abc_a[2] });
                let nan = [f64::NAN; 2];
                (
                    [ua, ub],
                    [i.alpha, i.beta],
                    nan,
                    nan,
                    wrap_angle(e.theta_hat as f64),
                    [e.psi_alpha as f64, e.psi_beta as f64],
                )
            }
        };
        samples.push(Sample {
            row: TraceRow {
                t,
                u_alpha: observer_u[0],
                u_beta: observer_u[1],
                i_alpha: observer_i[0],
                i_beta: observer_i[1],
                theta: Some(wrap_angle(truth.theta_e_rad)),
                v: Some(truth.v_m_per_s),
                x: Some(truth.x_m),
            },
            theta_hat,
            theta_hat_link: e.theta_hat,
            v_hat: e.speed as f64,
            psi_hat,
            psi_true: [truth.psi_f_alpha_wb, truth.psi_f_beta_wb],
            u_actual: [applied.u_alpha_avg_v, applied.u_beta_avg_v],
            i_d_ref: i_dq_ref[0],
            i_d: i_dq[0],
            i_q_ref: i_dq_ref[1],
            i_q: i_dq[1],
            v_ref,
            state: f.state().code(),
            locked,
            alpha_e_ref,
        });
        if k % 4096 == 0 {
            progress(k as f64 / n as f64);
        }
    }
    progress(1.0);
    Ok(Run {
        scenario: scenario.name.to_string(),
        observer: setup.drive.estimator.observer,
        samples,
        handover_s,
        faults,
        period_s: ts,
        simulated_s: n as f64 * ts,
        pole_pitch_m: f64::from(setup.motor.pole_pitch_m),
    })
}

/// Electrical-degree angle error `theta - theta_hat`, wrapped to (-180, 180].
pub fn theta_err_deg(s: &Sample) -> f64 {
    s.row.theta.map(|th| wrap_angle(th - s.theta_hat).to_degrees()).unwrap_or(f64::NAN)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The drive preset the firmware also runs must describe the simulated axis.
    #[test]
    fn paper_axis_preset_matches_the_plant() {
        let s = Setup::paper(ObserverKind::Dcfo);
        let inv = &s.plant.inverter;
        let comp = s.drive.dead_time_compensation.expect("compensated");
        assert_eq!(comp.dead_time_s, inv.dead_time_s as f32);
        assert_eq!(comp.device_drop_v, (0.5 * (inv.igbt_threshold_v + inv.diode_threshold_v)) as f32);
        assert!((f64::from(dcfo::drive::PAPER_AXIS_BUS_V) - inv.dc_bus_v).abs() < 1e-3);
        assert_eq!(s.drive.moving_mass_kg, s.plant.plant.mass_kg as f32);
        let noise = s.plant.sensors.current_noise_rms_a;
        assert!((0.5 * noise..=2.0 * noise).contains(&f64::from(comp.current_band_a)));
    }

    /// The Q8.24 drive logs the same detailed samples as the f32 drive (lock flag,
    /// observer inputs, control-frame currents, commanded acceleration), in SI units,
    /// and its detailed angle is the one the link reports.
    #[test]
    fn fixed_point_runs_log_the_detailed_output() {
        let setup = Setup::paper(ObserverKind::Dcfo);
        let mut sc = scenarios::scenario("steady").expect("scenario");
        // Past the hand-over from the I/f start (about 1.7 s): the flag is down while
        // the start's current lies along the flux.
        sc.duration_s = 2.5;
        let f = run(&setup, &sc, |_| {}).expect("f32 run");
        let q = run_with(&setup, &sc, &mut LocalDrive::fixed_point(&setup).expect("drive"), |_| {})
            .expect("q24 run");
        assert!(q.samples.len() > 1000, "{} samples", q.samples.len());
        for s in &q.samples {
            assert!(s.locked.is_some(), "t = {}: no lock flag", s.row.t);
            assert!(
                s.alpha_e_ref.is_finite() && s.i_d.is_finite() && s.i_q_ref.is_finite(),
                "t = {}",
                s.row.t
            );
            let d = wrap_angle(s.theta_hat - f64::from(s.theta_hat_link));
            assert!(d.abs() < 1e-6, "t = {}: detail {} vs link {}", s.row.t, s.theta_hat, s.theta_hat_link);
        }
        // Running at the same point of the same scenario, the two drives' observer
        // inputs agree to the sensor noise and the per-unit rounding (SI, not per-unit).
        let (a, b) = (f.samples.last().expect("f32 sample"), q.samples.last().expect("q24 sample"));
        assert_eq!(a.row.t, b.row.t);
        assert!(b.locked == Some(true) && a.locked == Some(true));
        let amp = |s: &Sample| s.row.i_alpha.hypot(s.row.i_beta);
        assert!((amp(a) - amp(b)).abs() < 0.2 * amp(a).max(0.1), "|i| f32 {} vs Q24 {}", amp(a), amp(b));
        let (pa, pb) = (a.psi_hat[0].hypot(a.psi_hat[1]), b.psi_hat[0].hypot(b.psi_hat[1]));
        assert!((pa - pb).abs() < 0.02 * pa, "|psi| f32 {pa} vs Q24 {pb} Wb");
    }
}
