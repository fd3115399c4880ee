//! The paper's experiments (`docs/method.md` §6) as named scenarios: what a run
//! simulates (speed references, loads, disturbances, plant deviations).

use crate::plant::rated_thrust_n;
use dcfo::motor::MotorParams;

/// Something that happens at a given time in a scenario.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    /// Speed reference, m/s.
    Speed(f64),
    /// Load force opposing motion, N.
    Load(f64),
    /// DC offsets on the observer's inputs only: voltage (V) and current (A), alpha-beta.
    ObserverOffsets {
        /// Voltage offset, V.
        u_v: [f64; 2],
        /// Current offset, A.
        i_a: [f64; 2],
    },
    /// The drive's estimator is reset to its zero state (a lock loss at speed).
    ResetEstimator,
    /// The mover is set moving at this speed, m/s, at that instant (an external push).
    MoverSpeed(f64),
}

/// A named experiment.
#[derive(Clone, Debug)]
pub struct Scenario {
    /// Short name used on the command line.
    pub name: String,
    /// What it reproduces.
    pub description: String,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Timed events (time s, event).
    pub events: Vec<(f64, Event)>,
    /// How the simulated plant differs from the motor file the drive was tuned on.
    pub plant: PlantChanges,
    /// Time of the disturbance the scenario is about, s; figures are measured from it.
    pub event_s: f64,
    /// Length of the window after `event_s` over which figures are measured, s.
    pub window_s: f64,
    /// What the paper reports, for the table (empty for other scenarios).
    pub paper: String,
}

/// How a scenario's plant differs from the motor file (the drive keeps the file's
/// values): multiples of the file's electrical parameters, and mechanics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlantChanges {
    /// Plant resistance over the file's, dimensionless (> 0).
    pub rs_factor: f64,
    /// Plant d-axis inductance over the file's, dimensionless (> 0).
    pub ld_factor: f64,
    /// Plant q-axis inductance over the file's, dimensionless (> 0).
    pub lq_factor: f64,
    /// Plant magnet flux over the file's, dimensionless (> 0).
    pub psi_f_factor: f64,
    /// Mass carried besides the mover, kg (>= 0).
    pub payload_kg: f64,
    /// Coulomb (sliding) friction, N (>= 0), with a break-away 1.3 times it; `None`: the
    /// plant's default.
    pub coulomb_friction_n: Option<f64>,
    /// Viscous friction, N s/m (>= 0); `None`: the motor file's.
    pub viscous_n_s_per_m: Option<f64>,
}

impl Default for PlantChanges {
    /// The motor file as it is.
    fn default() -> Self {
        PlantChanges {
            rs_factor: 1.0,
            ld_factor: 1.0,
            lq_factor: 1.0,
            psi_f_factor: 1.0,
            payload_kg: 0.0,
            coulomb_friction_n: None,
            viscous_n_s_per_m: None,
        }
    }
}

impl PlantChanges {
    /// A plant whose resistance is `k` times the file's.
    pub fn resistance(k: f64) -> Self {
        PlantChanges { rs_factor: k, ..PlantChanges::default() }
    }

    /// Applies the changes to `plant` (built from the motor file).
    pub fn apply(&self, plant: &mut crate::plant::PlantParams) {
        plant.rs_ohm *= self.rs_factor;
        plant.ld_h *= self.ld_factor;
        plant.lq_h *= self.lq_factor;
        plant.psi_f_wb *= self.psi_f_factor;
        plant.mass_kg += self.payload_kg;
        if let Some(f) = self.coulomb_friction_n {
            // Break-away 30 % above sliding, as the plant's default friction has it.
            plant.coulomb_friction_n = f;
            plant.static_friction_n = 1.3 * f;
        }
        if let Some(b) = self.viscous_n_s_per_m {
            plant.viscous_n_s_per_m = b;
        }
    }
}

/// Hand-over happens about 0.95 s after enable (0.1 s calibration, 0.3 s I/f ramp to
/// 0.15 m/s, 0.5 s dwell); the speed reference then ramps at 1 m/s^2, so every
/// scenario is settled by 2.5 s.
const SETTLED_S: f64 = 3.0;

/// All paper scenarios, in the order of the paper's figures.
pub fn paper_scenarios() -> Vec<Scenario> {
    let base = |v: f64| vec![(0.0, Event::Speed(v))];
    vec![
        Scenario {
            name: "steady".into(),
            description: "steady 0.3 m/s (10 Hz)".into(),
            duration_s: SETTLED_S + 1.0,
            events: base(0.3),
            plant: PlantChanges::default(),
            event_s: SETTLED_S,
            window_s: 1.0,
            paper: "Fig 11-12, 17: CFO max ~14 deg with lag; DCFO max < 10 deg".into(),
        },
        Scenario {
            name: "speed-step".into(),
            description: "speed step 0.24 -> 0.45 m/s (8 -> 15 Hz)".into(),
            duration_s: SETTLED_S + 1.0,
            events: {
                let mut e = base(0.24);
                e.push((SETTLED_S, Event::Speed(0.45)));
                e
            },
            plant: PlantChanges::default(),
            event_s: SETTLED_S,
            window_s: 1.0,
            paper: "Fig 13: speed estimate tracks".into(),
        },
        Scenario {
            name: "dc-u".into(),
            description: "+2 V DC on the observer's u_alpha at 0.3 m/s".into(),
            duration_s: SETTLED_S + 1.0,
            events: {
                let mut e = base(0.3);
                e.push((SETTLED_S, Event::ObserverOffsets { u_v: [2.0, 0.0], i_a: [0.0, 0.0] }));
                e
            },
            plant: PlantChanges::default(),
            event_s: SETTLED_S,
            window_s: 1.0,
            paper: "Fig 14: CFO flux drifts ~0.03 Wb; DCFO unaffected".into(),
        },
        Scenario {
            name: "dc-i".into(),
            description: "+0.2 A DC on the observer's i_beta at 0.3 m/s".into(),
            duration_s: SETTLED_S + 1.0,
            events: {
                let mut e = base(0.3);
                e.push((SETTLED_S, Event::ObserverOffsets { u_v: [0.0, 0.0], i_a: [0.0, 0.2] }));
                e
            },
            plant: PlantChanges::default(),
            event_s: SETTLED_S,
            window_s: 1.0,
            paper: "Fig 15: CFO ~0.02 Wb; DCFO brief blip only".into(),
        },
        Scenario {
            name: "resistance".into(),
            description: "R = 2 Rs in the motor (observer keeps Rs), +0.2 A on i_beta at 0.3 m/s".into(),
            duration_s: SETTLED_S + 1.0,
            events: {
                let mut e = base(0.3);
                e.push((SETTLED_S, Event::ObserverOffsets { u_v: [0.0, 0.0], i_a: [0.0, 0.2] }));
                e
            },
            plant: PlantChanges::resistance(2.0),
            event_s: SETTLED_S,
            window_s: 1.0,
            paper: "Fig 16: CFO ~0.04 Wb; DCFO brief blip".into(),
        },
        Scenario {
            name: "load-step".into(),
            description: "40 N load step at 0.42 m/s".into(),
            duration_s: SETTLED_S + 1.0,
            events: {
                let mut e = base(0.42);
                e.push((SETTLED_S, Event::Load(40.0)));
                e
            },
            plant: PlantChanges::default(),
            event_s: SETTLED_S,
            window_s: 1.0,
            paper: "Fig 18-19: speed err CFO 0.039 / DCFO 0.034 m/s; position err CFO ~23 / DCFO ~21 deg"
                .into(),
        },
    ]
}

/// How the paper's experiments carry over to another motor ([`Scenario::scaled`]): the
/// same experiment in every ratio the estimator and the drive see, so that on the paper
/// motor every factor is exactly 1 and the axis is the paper's.
///
/// - speeds by the pole pitch: the same electrical frequencies, which is what the
///   estimator's dynamics depend on (`dcfo acquire --motor` sweeps the same way);
/// - the axis: the paper axis's mass per rated thrust (10.7 kg for the paper motor's
///   105 N), as a payload on the mover, so that thrust, friction and end-effect force
///   (shares of the rated thrust) move it as they move the paper's axis. On a bare mover
///   the plant's friction and end-effect force (3 % of rated thrust each) are tens of
///   m/s^2, more than a 20 rad/s speed loop on a back-EMF estimate holds at 0.25 m/s:
///   another experiment (`scenarios/bare-mover.toml` is that one);
/// - loads by the rated thrust and the pole pitch: on that axis the same electrical
///   deceleration (the paper's 40 N slows its axis by 785 rad/s^2 electrical, 30 % of
///   the speed in 90 ms). The paper's 40 N on a bare 1.5 kg mover drove it backwards
///   through zero speed, and so did the same share of rated thrust on a motor of a
///   shorter pole pitch (the same linear deceleration at a lower linear speed);
/// - voltage offsets by the rated voltage (an inverter's or a sensor's voltage error is a
///   share of the bus) and current offsets by the rated current (a sensor's offset is a
///   share of its full scale), as `dcfo acquire --motor` scales its offsets. The paper's
///   2 V was half the 48 V low-resistance motor's back-EMF at 0.24 m/s.
///
/// Plant deviations given as multiples (`R = 2 Rs`) need no scaling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PaperScale {
    /// Speeds, dimensionless (m/s per m/s of the paper's).
    pub speed: f64,
    /// Rated thrust over the paper motor's, dimensionless: a steady load of the same
    /// share of it (`dcfo acquire --motor` records at one). Load steps scale by
    /// `thrust * speed`: the same electrical deceleration on the scaled axis.
    pub thrust: f64,
    /// Voltage offsets, dimensionless (V per V of the paper's).
    pub voltage: f64,
    /// Current offsets, dimensionless (A per A of the paper's).
    pub current: f64,
    /// Payload the mover carries, kg (>= 0): the paper axis's mass per rated thrust
    /// less the mover's own mass.
    pub payload_kg: f64,
}

impl PaperScale {
    /// The paper's experiments on `motor`, against the paper motor on its test axis.
    pub fn for_motor(motor: &MotorParams) -> Self {
        let paper = MotorParams::paper();
        let thrust = rated_thrust_n(motor) / rated_thrust_n(&paper);
        let speed = f64::from(motor.pole_pitch_m) / f64::from(paper.pole_pitch_m);
        let paper_axis_kg = f64::from(paper.mass_kg) + f64::from(dcfo::drive::PAPER_AXIS_PAYLOAD_KG);
        PaperScale {
            speed,
            thrust,
            voltage: f64::from(motor.rated_voltage_v) / f64::from(paper.rated_voltage_v),
            current: f64::from(motor.rated_current_a) / f64::from(paper.rated_current_a),
            payload_kg: (paper_axis_kg * thrust - f64::from(motor.mass_kg)).max(0.0),
        }
    }
}

impl Scenario {
    /// The same experiment with its speeds, loads and offsets scaled by `scale` and the
    /// payload added; the description says so, with the factors. Times, plant multiples
    /// and the estimator reset are unchanged.
    pub fn scaled(&self, scale: &PaperScale) -> Scenario {
        let event = |e: Event| match e {
            Event::Speed(v) => Event::Speed(v * scale.speed),
            Event::Load(f) => Event::Load(f * scale.thrust * scale.speed),
            Event::ObserverOffsets { u_v, i_a } => Event::ObserverOffsets {
                u_v: u_v.map(|u| u * scale.voltage),
                i_a: i_a.map(|i| i * scale.current),
            },
            Event::ResetEstimator => Event::ResetEstimator,
            Event::MoverSpeed(v) => Event::MoverSpeed(v * scale.speed),
        };
        Scenario {
            description: format!(
                "{}; scaled to this motor: speeds x{:.3}, loads x{:.3}, voltage offsets x{:.3}, current \
                 offsets x{:.3}, {:.1} kg payload",
                self.description,
                scale.speed,
                scale.thrust * scale.speed,
                scale.voltage,
                scale.current,
                scale.payload_kg
            ),
            events: self.events.iter().map(|&(t, e)| (t, event(e))).collect(),
            plant: PlantChanges { payload_kg: self.plant.payload_kg + scale.payload_kg, ..self.plant },
            ..self.clone()
        }
    }
}

/// Looks up a paper scenario by name.
pub fn scenario(name: &str) -> Option<Scenario> {
    paper_scenarios().into_iter().find(|s| s.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// On the paper motor the experiments are the paper's, to the bit, on its axis.
    #[test]
    fn the_paper_motor_keeps_every_experiment_and_its_axis() {
        let scale = PaperScale::for_motor(&MotorParams::paper());
        assert_eq!((scale.speed, scale.thrust, scale.voltage, scale.current), (1.0, 1.0, 1.0, 1.0));
        assert!((scale.payload_kg - f64::from(dcfo::drive::PAPER_AXIS_PAYLOAD_KG)).abs() < 1e-6, "{scale:?}");
        for sc in paper_scenarios() {
            assert_eq!(sc.scaled(&scale).events, sc.events, "{}", sc.name);
        }
    }

    /// On another motor the estimator sees the same electrical frequencies and, under the
    /// load step, the same electrical deceleration; the axis has the paper axis's mass
    /// per rated thrust; the offsets are the same share of its rated voltage and current.
    #[test]
    fn another_motor_gets_the_same_experiment_on_the_same_axis() {
        let motor = MotorParams {
            rs_ohm: 0.3,
            ld_h: 0.0012,
            lq_h: 0.0012,
            psi_f_wb: 0.05,
            pole_pitch_m: 0.012,
            mass_kg: 1.5,
            viscous_n_s_per_m: 0.5,
            rated_current_a: 10.0,
            rated_voltage_v: 48.0,
        };
        let paper = MotorParams::paper();
        // Rated thrust, N: 1.5 pi / tau psi_f I_rated.
        let thrust = |m: &MotorParams| {
            1.5 * PI / f64::from(m.pole_pitch_m) * f64::from(m.psi_f_wb) * f64::from(m.rated_current_a)
        };
        let omega_per_speed = crate::plant::rad_per_m;
        let paper_axis_kg = f64::from(paper.mass_kg) + f64::from(dcfo::drive::PAPER_AXIS_PAYLOAD_KG);
        let scale = PaperScale::for_motor(&motor);
        // The motor's values are f32: equal to their precision.
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * b.abs().max(1e-3);
        let axis_kg = f64::from(motor.mass_kg) + scale.payload_kg;
        assert!(close(axis_kg / thrust(&motor), paper_axis_kg / thrust(&paper)), "{scale:?}");
        for sc in paper_scenarios() {
            let scaled = sc.scaled(&scale);
            assert_eq!(scaled.plant.payload_kg, scale.payload_kg, "{}", sc.name);
            for (&(_, p), &(_, e)) in sc.events.iter().zip(&scaled.events) {
                let name = &sc.name;
                match (p, e) {
                    (Event::Speed(v0), Event::Speed(v)) => {
                        assert!(close(v * omega_per_speed(&motor), v0 * omega_per_speed(&paper)), "{name}")
                    }
                    (Event::Load(f0), Event::Load(f)) => assert!(
                        close(
                            f / axis_kg * omega_per_speed(&motor),
                            f0 / paper_axis_kg * omega_per_speed(&paper)
                        ),
                        "{name}: the same electrical deceleration"
                    ),
                    (Event::ObserverOffsets { u_v: u0, i_a: i0 }, Event::ObserverOffsets { u_v, i_a }) => {
                        for k in 0..2 {
                            assert!(close(u_v[k] / 48.0, u0[k] / 220.0), "{name}");
                            assert!(close(i_a[k] / 10.0, i0[k] / 2.1), "{name}");
                        }
                    }
                    (p, e) => panic!("{name}: {p:?} became {e:?}"),
                }
            }
        }
    }
}
