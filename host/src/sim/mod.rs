//! Closed-loop simulation: the plant model and the library's drive (`Drive<f32>`, the
//! firmware's control step) in lock-step, with scenario events and ground truth.
//!
//! Per PWM period `k` (time `t_k`): the plant's sensors are sampled, the drive computes
//! its step, the plant runs the period with the duties computed one step earlier (the
//! drive's one-period computation delay), and a trace row is logged. Rows start at the
//! drive's first start-up step, when its estimator is reset, so that replaying the
//! trace through the same estimator reproduces the run's estimates exactly.

pub mod report;
pub mod scenarios;

use crate::plant::{Plant, PlantError, SimParams, TrueState};
use crate::trace::{TraceRow, wrap_angle};
use dcfo::drive::{Drive, DriveConfig, DriveState, Faults, Measurements};
use dcfo::motor::MotorParams;
use dcfo::observer::ObserverKind;
use dcfo::transforms::{Abc, AlphaBeta};
use dcfo::units::Base;

pub use scenarios::{Event, Scenario};

/// One logged sample: the trace row (observer inputs and ground truth) and what the
/// drive estimated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Inputs and ground truth, in the trace format's terms.
    pub row: TraceRow,
    /// Estimated electrical angle, rad in (-pi, pi].
    pub theta_hat: f64,
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
}

/// Carriage and load moved by the paper motor in the simulated experiments, kg.
///
/// The paper states only the mover's 0.66 kg. Alone, it would accelerate at 60 m/s^2
/// under the 40 N load step, so any back-EMF estimator (whose angle lags transients by
/// 15-30 ms at 8-15 Hz) would see speed dips of several tenths of a m/s, not the
/// 0.034-0.039 m/s the paper reports: its test axis moved far more mass. 10 kg is a
/// typical carriage plus load for a 150 N-class linear motor; it was not fitted to any
/// figure.
pub const PAPER_PAYLOAD_KG: f64 = 10.0;

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
    /// The paper motor carrying a [`PAPER_PAYLOAD_KG`] carriage and load, on a realistic
    /// inverter and sensors; drive defaults with the given observer, the total moving
    /// mass, and inverter compensation matched to the plant's dead time and drops.
    pub fn paper(observer: ObserverKind) -> Self {
        let motor = MotorParams::paper();
        let mut plant = SimParams::from_motor(&motor);
        plant.plant.mass_kg += PAPER_PAYLOAD_KG;
        let mut drive = DriveConfig::for_motor(&motor, plant.inverter.dc_bus_v as f32, observer);
        drive.moving_mass_kg = plant.plant.mass_kg as f32;
        drive.dead_time_compensation = Some(dcfo::drive::DeadTimeCompensation {
            dead_time_s: plant.inverter.dead_time_s as f32,
            device_drop_v: (0.5 * (plant.inverter.igbt_threshold_v + plant.inverter.diode_threshold_v))
                as f32,
            current_band_a: 0.01,
        });
        Setup { motor, plant, drive }
    }
}

/// Runs `scenario` on `setup`, calling `progress(fraction)` now and then.
pub fn run(setup: &Setup, scenario: &Scenario, mut progress: impl FnMut(f64)) -> Result<Run, SimError> {
    let mut plant_params = setup.plant;
    if let Some(k) = scenario.plant_rs_factor {
        plant_params.plant.rs_ohm *= k;
    }
    let mut plant = Plant::new(&plant_params)?;
    let mut drive: Drive<f32> = Drive::new(&setup.motor, &setup.drive, &Base::SI).map_err(SimError::Drive)?;
    let ts = plant.pwm_period_s();
    let n = (scenario.duration_s / ts).round() as usize;
    let mut pending = [0.5f64; 3];
    let mut load_n = 0.0;
    let mut samples = Vec::with_capacity(n);
    let mut handover_s = None;
    let mut events = scenario.events.clone();
    events.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut next_event = 0;
    let mut v_ref_target = 0.0;
    drive.enable();
    for k in 0..n {
        let t = k as f64 * ts;
        while next_event < events.len() && events[next_event].0 <= t + 0.5 * ts {
            match events[next_event].1 {
                Event::Speed(v) => {
                    v_ref_target = v;
                    drive.set_speed_reference(drive.omega_from_speed(v as f32));
                }
                Event::Load(f) => load_n = f,
                Event::ObserverOffsets { u_v, i_a } => drive.set_observer_offsets(
                    AlphaBeta::new(u_v[0] as f32, u_v[1] as f32),
                    AlphaBeta::new(i_a[0] as f32, i_a[1] as f32),
                ),
            }
            next_event += 1;
        }
        let reading = plant.sample();
        let truth: TrueState = plant.state();
        let m = Measurements {
            i_abc: Abc {
                a: reading.i_abc_a[0] as f32,
                b: reading.i_abc_a[1] as f32,
                c: reading.i_abc_a[2] as f32,
            },
            vdc: reading.vdc_v as f32,
        };
        let out = drive.step(&m);
        plant.step(pending, load_n);
        let applied = plant.state().last_period;
        pending = if out.bridge_enabled {
            [out.duties.a as f64, out.duties.b as f64, out.duties.c as f64]
        } else {
            // The plant has no open-bridge mode: centred duties apply zero line voltage.
            [0.5; 3]
        };
        if out.state == DriveState::Running && handover_s.is_none() {
            handover_s = Some(t);
        }
        if let Some(e) = out.estimate {
            let v_ref = if out.state == DriveState::Running { v_ref_target } else { f64::NAN };
            samples.push(Sample {
                row: TraceRow {
                    t,
                    u_alpha: out.u_applied.alpha as f64,
                    u_beta: out.u_applied.beta as f64,
                    i_alpha: out.i_observer.alpha as f64,
                    i_beta: out.i_observer.beta as f64,
                    theta: Some(wrap_angle(truth.theta_e_rad)),
                    v: Some(truth.v_m_per_s),
                    x: Some(truth.x_m),
                },
                theta_hat: e.theta_e.to_radians::<f64>(),
                v_hat: e.speed_m_per_s as f64,
                psi_hat: [e.psi_ab.alpha as f64, e.psi_ab.beta as f64],
                psi_true: [truth.psi_f_alpha_wb, truth.psi_f_beta_wb],
                u_actual: [applied.u_alpha_avg_v, applied.u_beta_avg_v],
                i_d_ref: out.i_dq_ref.d as f64,
                i_d: out.i_dq.d as f64,
                i_q_ref: out.i_dq_ref.q as f64,
                i_q: out.i_dq.q as f64,
                v_ref,
                state: out.state.code(),
            });
        }
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
        faults: drive.faults(),
        period_s: ts,
        simulated_s: n as f64 * ts,
    })
}

/// Electrical-degree angle error `theta - theta_hat`, wrapped to (-180, 180].
pub fn theta_err_deg(s: &Sample) -> f64 {
    s.row.theta.map(|th| wrap_angle(th - s.theta_hat).to_degrees()).unwrap_or(f64::NAN)
}
