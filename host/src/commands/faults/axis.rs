//! The simulated axis with faults injected: the plant behind a wrapper that can open a
//! phase, short two phase terminals, falsify the current sensors and change the bus,
//! and a drive either in process or behind the link server (`dcfo::link::LinkServer`,
//! the firmware's receive path) whose byte stream can go silent, be corrupted or carry
//! replayed frames. One period at a time on [`crate::closed_loop::ClosedLoop`]: sample,
//! control step, the plant runs the period with the duties of the step before.
//!
//! A positioning drive is fed its moves as `dcfo stroke` feeds them
//! (`crate::commands::stroke::run_with`): one per sensor frame while the drive's last report shows
//! room in its queue; a move it refuses is counted, not retried.

use std::collections::VecDeque;

use dcfo::algorithms::motion::Move;
use dcfo::drive::{Drive, DriveState, Faults, MOVE_QUEUE, StepOutput};
use dcfo::link::{self, ActuationFrame, LinkServer, SensorFrame};
use dcfo::num::units::Base;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use crate::closed_loop::{Bridge, ClosedLoop};
use crate::plant::{Plant, PlantError, SensorReading, SimParams};
use crate::simulation::{frame_bridge, output_bridge, sensor_frame};

/// The fault a case injects (at the injection time unless said otherwise).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Injection {
    /// Phase a's connection opens: its current is zero from then on, the b-c loop
    /// carries the current alone (the plant's open phase, `Plant::set_open_phase`: exact
    /// for `Ld = Lq`, an approximation with saliency).
    OpenPhase,
    /// Phase terminals a and b short together through `SHORT_OHM` and `SHORT_H`: the
    /// current through the short flows in the sensors of legs a and b (the motor's
    /// own currents continue as before).
    PhaseShort,
    /// The phase-b current sensor freezes at its last reading.
    SensorStuck,
    /// The phase-a current ADC reads its top code (full scale).
    AdcSaturated,
    /// The phase-a current reading is NaN (a broken conversion chain).
    AdcNan,
    /// The true bus voltage becomes this multiple of nominal (0: the bus is lost).
    Bus(f64),
    /// The mover is blocked (held at zero speed: a mechanical jam).
    Blocked,
    /// A load force of this many newtons opposes the motion.
    Load(f64),
    /// The drive's estimator is reset at speed (a lock loss).
    EstimatorReset,
    /// The host stops sending (the link goes silent).
    LinkSilent,
    /// One frame in `every` (on average, seeded) has 1 to 3 bits flipped on the wire.
    LinkCorrupt {
        /// Mean interval between corrupted frames, frames.
        every: u32,
    },
    /// Every `every`-th period the frame is sent twice, followed by the frame of
    /// `age` periods earlier (a replay).
    LinkReplay {
        /// Interval between replays, periods.
        every: u32,
        /// Age of the replayed old frame, periods.
        age: u32,
    },
    /// From the start: the plant's resistance is this multiple of the motor file's.
    PlantRs(f64),
    /// From the start: the drive's motor file is off the plant by these factors on
    /// `Rs`, `Ld` and `Lq` together, and `psi_f`.
    MotorFile {
        /// Factor on the resistance.
        rs: f64,
        /// Factor on both inductances.
        l: f64,
        /// Factor on the magnet flux.
        psi_f: f64,
    },
    /// A positioning drive is sent a move to this target (m), ahead of the moves still
    /// to send, with no dwell.
    MoveTo(f64),
}

impl Injection {
    /// `true` when the drive must sit behind the link server.
    pub fn over_link(self) -> bool {
        matches!(self, Injection::LinkSilent | Injection::LinkCorrupt { .. } | Injection::LinkReplay { .. })
    }

    /// `true` when the fault is there from the start (the run cannot share the healthy
    /// run's first seconds).
    pub fn from_start(self) -> bool {
        matches!(self, Injection::PlantRs(_) | Injection::MotorFile { .. })
    }
}

/// A positioning axis's moves: those still to send, the room in the drive's queue as
/// its last report gave it, and the moves it refused.
#[derive(Clone, Debug)]
struct MoveFeed {
    to_send: VecDeque<Move>,
    queue_room: usize,
    rejected: u16,
}

/// Resistance of the phase-to-phase short, ohm.
pub const SHORT_OHM: f64 = 0.05;
/// Inductance of the phase-to-phase short (its wiring), H.
pub const SHORT_H: f64 = 2e-6;

/// One logged period.
#[derive(Clone, Copy, Debug)]
pub struct Period {
    /// Time of the sample, s.
    pub t_s: f64,
    /// True electrical angle, rad.
    pub theta_rad: f64,
    /// The drive's angle estimate, rad (NaN when it reported none this period).
    pub theta_hat_rad: f64,
    /// The estimate was reported as locked (over the link, which does not carry the
    /// flag: the drive running sensorless on it, `Running`).
    pub locked: bool,
    /// True speed, m/s.
    pub v_m_per_s: f64,
    /// The drive's speed estimate, m/s (NaN when it reported none this period).
    pub v_hat_m_per_s: f64,
    /// Largest true phase current magnitude, A.
    pub i_true_max_a: f64,
    /// The three current readings the drive got, A.
    pub i_meas_a: [f64; 3],
    /// The bus reading the drive got, V.
    pub vdc_meas_v: f64,
    /// The drive's state after this period's step.
    pub state: DriveState,
    /// Latched faults after this period's step.
    pub faults: Faults,
    /// The bridge was driven during the period that starts at `t_s`.
    pub bridge_on: bool,
    /// A sensor frame was delivered to the drive and answered this period (always for
    /// an in-process drive).
    pub answered: bool,
    /// True mover position, m (from where it started).
    pub x_m: f64,
    /// A positioning drive's position estimate, m (NaN for a speed drive, or without an
    /// answer).
    pub x_hat_m: f64,
    /// A positioning drive's reference position, m (NaN as `x_hat_m`).
    pub x_ref_m: f64,
    /// A positioning drive's reference speed, m/s (NaN as `x_hat_m`).
    pub v_ref_m_per_s: f64,
    /// A positioning drive: no move active, queued or still to send.
    pub motion_done: bool,
    /// Moves the drive refused so far.
    pub moves_rejected: u16,
}

/// What the link-fault checks counted.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct LinkChecks {
    /// Frames the host corrupted.
    pub corrupted: u32,
    /// Corrupted frames the drive answered as if they were good (must be 0).
    pub corrupted_answered: u32,
    /// Duplicates sent.
    pub duplicates: u32,
    /// Duplicates whose answer differed from the original answer (must be 0).
    pub duplicate_mismatches: u32,
    /// Old frames replayed.
    pub replays: u32,
    /// Replayed old frames that were answered (acted on; must be 0).
    pub replays_answered: u32,
    /// The drive's counts of rejected frames: malformed, bad CRC, out of order.
    pub drive_malformed: u16,
    /// Bad CRC.
    pub drive_bad_crc: u16,
    /// Out of order (duplicates and replays).
    pub drive_out_of_order: u16,
}

/// The drive, in process or behind the link server.
#[derive(Clone, Debug)]
enum Controller {
    Local(Drive<f32>),
    Linked { drive: Drive<f32>, server: LinkServer, sent: Vec<[u8; SensorFrame::WIRE_LEN]> },
}

/// What the controller answered in one period.
struct Answer {
    out: Option<StepOutput<f32>>,
    frame: Option<ActuationFrame>,
    /// Moves the in-process drive refused so far (over the link: the answer's count).
    rejected: u16,
}

/// The axis: plant, drive and the fault state.
#[derive(Clone, Debug)]
pub struct Axis {
    closed_loop: ClosedLoop,
    controller: Controller,
    k: u64,
    speed_ref: f64,
    load_n: f64,
    injection: Option<Injection>,
    moves: Option<MoveFeed>,
    stuck_b: Option<f64>,
    short_a: f64,
    full_scale_a: f64,
    lsb_a: f64,
    rng: Pcg64,
    /// Link-fault counts.
    pub link: LinkChecks,
}

impl Axis {
    /// A plant from `sim` and a drive from `drive`, the drive enabled with the speed
    /// reference `speed_ref` (m/s); behind the link server when `linked`.
    pub fn new(sim: &SimParams, drive: Drive<f32>, speed_ref: f64, linked: bool) -> Result<Self, PlantError> {
        let plant = Plant::new(sim)?;
        let controller = if linked {
            Controller::Linked { drive, server: LinkServer::new(), sent: Vec::new() }
        } else {
            Controller::Local(drive)
        };
        let codes = sim.sensors.current_adc_bits.map_or(f64::INFINITY, |b| f64::from(1u32 << b));
        Ok(Axis {
            closed_loop: ClosedLoop::new(plant),
            controller,
            k: 0,
            speed_ref,
            load_n: 0.0,
            injection: None,
            moves: None,
            stuck_b: None,
            short_a: 0.0,
            full_scale_a: sim.sensors.current_full_scale_a,
            lsb_a: 2.0 * sim.sensors.current_full_scale_a / codes,
            rng: Pcg64::seed_from_u64(11),
            link: LinkChecks::default(),
        })
    }

    /// A positioning axis: a plant from `sim` and the positioning `drive` in process,
    /// enabled, to be sent `moves` in order.
    pub fn positioning(sim: &SimParams, drive: Drive<f32>, moves: &[Move]) -> Result<Self, PlantError> {
        let mut axis = Axis::new(sim, drive, 0.0, false)?;
        axis.moves =
            Some(MoveFeed { to_send: moves.iter().copied().collect(), queue_room: MOVE_QUEUE, rejected: 0 });
        Ok(axis)
    }

    /// Moves an in-process drive behind the link server, as it is (for link faults
    /// injected into a run that started in process).
    pub fn put_behind_link(&mut self) {
        if let Controller::Local(drive) = &self.controller {
            self.controller =
                Controller::Linked { drive: drive.clone(), server: LinkServer::new(), sent: Vec::new() };
        }
    }

    /// The drive.
    pub fn drive(&self) -> &Drive<f32> {
        match &self.controller {
            Controller::Local(d) | Controller::Linked { drive: d, .. } => d,
        }
    }

    fn drive_mut(&mut self) -> &mut Drive<f32> {
        match &mut self.controller {
            Controller::Local(d) | Controller::Linked { drive: d, .. } => d,
        }
    }

    /// The plant.
    pub fn plant(&self) -> &Plant {
        self.closed_loop.plant()
    }

    /// Injects `fault` now.
    pub fn inject(&mut self, fault: Injection) -> Result<(), PlantError> {
        self.injection = Some(fault);
        match fault {
            Injection::Bus(f) => {
                let plant = self.closed_loop.plant_mut();
                plant.set_dc_bus_v(f * plant.params().inverter.dc_bus_v)?
            }
            Injection::Blocked => self.closed_loop.plant_mut().set_speed_clamp(Some(0.0))?,
            Injection::Load(f) => self.load_n = f,
            Injection::EstimatorReset => self.drive_mut().reset_estimator(),
            Injection::OpenPhase => self.closed_loop.plant_mut().set_open_phase(Some(0)),
            Injection::LinkSilent | Injection::LinkCorrupt { .. } | Injection::LinkReplay { .. } => {
                self.put_behind_link()
            }
            Injection::MoveTo(target_m) => {
                if let Some(feed) = &mut self.moves {
                    feed.to_send.push_front(Move { target_m: target_m as f32, dwell_s: 0.0 });
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// A current as the ADC returns it (clipped to its codes).
    fn adc(&self, i: f64) -> f64 {
        if !self.lsb_a.is_finite() {
            return i;
        }
        let half = self.full_scale_a / self.lsb_a;
        ((i / self.lsb_a).round().clamp(-half, half - 1.0)) * self.lsb_a
    }

    /// One period: returns what was logged.
    pub fn period(&mut self) -> Period {
        let ts = self.closed_loop.plant().pwm_period_s();
        let t = self.k as f64 * ts;
        let sensed = self.closed_loop.sense();
        let (reading, truth) = (sensed.reading, sensed.truth);
        let [mut a, mut b, _] = reading.i_abc_a;
        match self.injection {
            Some(Injection::SensorStuck) => b = *self.stuck_b.get_or_insert(b),
            Some(Injection::AdcSaturated) => a = self.adc(self.full_scale_a),
            Some(Injection::AdcNan) => a = f64::NAN,
            Some(Injection::PhaseShort) => {
                a = self.adc(a + self.short_a);
                b = self.adc(b - self.short_a);
            }
            _ => {}
        }
        // Two sensors: the third current is computed from the two readings.
        let c = -(a + b);
        let move_to =
            self.moves.as_mut().and_then(|f| if f.queue_room > 0 { f.to_send.pop_front() } else { None });
        // The readings the drive gets: the two falsified currents and the third computed
        // from them.
        let falsified = SensorReading { i_abc_a: [a, b, c], ..reading };
        let sensor = sensor_frame(&falsified, self.k as u16, self.speed_ref as f32, move_to);
        let answer = self.control(&sensor);
        let drive_state = self.drive().state();
        let next = match (answer.out.as_ref(), answer.frame.as_ref()) {
            (Some(out), _) => output_bridge(out),
            (None, Some(f)) => frame_bridge(f),
            // No answer: the PWM repeats the last duties unless the drive (its watchdog)
            // switched the bridge off.
            (None, None) => {
                if matches!(
                    drive_state,
                    DriveState::Starting
                        | DriveState::Running
                        | DriveState::Reacquiring
                        | DriveState::LowSpeed
                ) {
                    self.closed_loop.queued()
                } else {
                    Bridge::Off
                }
            }
        };
        let stepped = self.closed_loop.actuate(sensed, next, self.load_n);
        let bridge_on = stepped.bridge.is_on();
        if self.injection == Some(Injection::PhaseShort) {
            // di/dt = (v_ab - R i) / L over the period, v_ab the period's mean line
            // voltage (0 with the bridge off: the short's current then decays in its own
            // resistance and the diodes, modelled as its R/L).
            let v_ab = match stepped.bridge {
                Bridge::On(duties) => stepped.applied.vdc_avg_v * (duties[0] - duties[1]),
                Bridge::Off => 0.0,
            };
            let tau = SHORT_H / SHORT_OHM;
            let i_inf = v_ab / SHORT_OHM;
            self.short_a = i_inf + (self.short_a - i_inf) * (-ts / tau).exp();
        }
        let (theta_hat, v_hat, locked) = match (&answer.out, &answer.frame) {
            (Some(out), _) => match out.estimate {
                Some(e) => (e.theta_e.to_radians::<f64>(), f64::from(e.speed_m_per_s), e.locked),
                None => (f64::NAN, f64::NAN, false),
            },
            (None, Some(f)) => match f.estimate {
                Some(e) => (f64::from(e.theta_hat), f64::from(e.speed), f.state() == DriveState::Running),
                None => (f64::NAN, f64::NAN, false),
            },
            (None, None) => (f64::NAN, f64::NAN, false),
        };
        // The position report: the drive's own for an in-process drive, the answer's over
        // the link.
        let position = match (&answer.out, &answer.frame) {
            (Some(_), _) => dcfo::link::PositionReport::of(self.drive(), answer.rejected),
            (None, Some(f)) => f.position,
            (None, None) => None,
        };
        if let (Some(feed), Some(p)) = (&mut self.moves, position) {
            feed.queue_room = MOVE_QUEUE.saturating_sub(usize::from(p.moves_queued));
            feed.rejected = p.moves_rejected;
        }
        let nan = f64::NAN;
        self.k += 1;
        Period {
            t_s: t,
            theta_rad: truth.theta_e_rad,
            theta_hat_rad: theta_hat,
            v_hat_m_per_s: v_hat,
            locked,
            v_m_per_s: truth.v_m_per_s,
            i_true_max_a: truth.i_abc_a.iter().fold(0.0f64, |m, i| m.max(i.abs())),
            i_meas_a: [a, b, c],
            vdc_meas_v: reading.vdc_v,
            state: drive_state,
            faults: self.drive().faults(),
            bridge_on,
            answered: answer.out.is_some() || answer.frame.is_some(),
            x_m: truth.x_m,
            x_hat_m: position.map_or(nan, |p| f64::from(p.x_hat_m)),
            x_ref_m: position.map_or(nan, |p| f64::from(p.x_ref_m)),
            v_ref_m_per_s: position.map_or(nan, |p| f64::from(p.v_ref_m_per_s)),
            motion_done: self.moves.as_ref().is_some_and(|f| f.to_send.is_empty())
                && position.is_some_and(|p| p.idle),
            moves_rejected: self.moves.as_ref().map_or(0, |f| f.rejected),
        }
    }

    /// The drive's step on this period's sensor frame, directly or over the link.
    fn control(&mut self, sensor: &SensorFrame) -> Answer {
        let injection = self.injection;
        let rejected = self.moves.as_ref().map_or(0, |f| f.rejected);
        match &mut self.controller {
            Controller::Local(drive) => {
                // The calls the firmware makes on a received frame, counting a refused
                // move as the link server does.
                let rejected =
                    if sensor.apply_commands(drive).is_err() { rejected.wrapping_add(1) } else { rejected };
                let out = drive.step(&sensor.measurements(&Base::SI));
                Answer { out: Some(out), frame: None, rejected }
            }
            Controller::Linked { drive, server, sent } => {
                let mut wire = [0u8; SensorFrame::WIRE_LEN];
                let mut answer = Answer { out: None, frame: None, rejected };
                let Ok(n) = link::encode(sensor, &mut wire) else {
                    // A frame the host cannot encode (a non-finite value) is not sent.
                    server.silent_period(drive);
                    return answer;
                };
                sent.push(wire);
                let deliver = |bytes: &[u8], drive: &mut Drive<f32>, server: &mut LinkServer| {
                    let mut out = [0u8; LinkServer::REPLY_LEN];
                    let mut reply = None;
                    for &byte in bytes {
                        if let Some(len) = server.on_byte(byte, drive, &Base::SI, &mut out) {
                            reply = Some(out[..len].to_vec());
                        }
                    }
                    reply
                };
                match injection {
                    Some(Injection::LinkSilent) => {}
                    Some(Injection::LinkCorrupt { every }) if self.rng.random_range(0..every) == 0 => {
                        self.link.corrupted += 1;
                        let flips = self.rng.random_range(1..=3);
                        for _ in 0..flips {
                            let byte = self.rng.random_range(0..n);
                            wire[byte] ^= 1 << self.rng.random_range(0..8);
                        }
                        // A receiver resynchronises on the next delimiter: the host
                        // sends one before each frame, as the link's docs allow.
                        let mut bytes = vec![0u8];
                        bytes.extend_from_slice(&wire[..n]);
                        if deliver(&bytes, drive, server).is_some() {
                            self.link.corrupted_answered += 1;
                        }
                    }
                    Some(Injection::LinkReplay { every, age })
                        if u32::from(sensor.sequence).is_multiple_of(every) =>
                    {
                        let first = deliver(&wire[..n], drive, server);
                        self.link.duplicates += 1;
                        let again = deliver(&wire[..n], drive, server);
                        if again != first {
                            self.link.duplicate_mismatches += 1;
                        }
                        self.link.replays += 1;
                        let old = sent.len().checked_sub(1 + age as usize).map(|i| sent[i]);
                        if let Some(old) = old
                            && deliver(&old, drive, server).is_some()
                        {
                            self.link.replays_answered += 1;
                        }
                        answer.frame = first.and_then(|r| {
                            link::decode_in_place::<ActuationFrame>(&mut r.clone()[..r.len() - 1]).ok()
                        });
                    }
                    _ => {
                        let mut bytes = vec![0u8];
                        bytes.extend_from_slice(&wire[..n]);
                        answer.frame = deliver(&bytes, drive, server).and_then(|r| {
                            link::decode_in_place::<ActuationFrame>(&mut r.clone()[..r.len() - 1]).ok()
                        });
                    }
                }
                // The watchdog's periodic tick.
                server.silent_period(drive);
                let stats = server.stats();
                self.link.drive_malformed = stats.malformed;
                self.link.drive_bad_crc = stats.bad_crc;
                self.link.drive_out_of_order = stats.out_of_order;
                answer
            }
        }
    }
}
