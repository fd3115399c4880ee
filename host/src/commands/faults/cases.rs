//! The campaign's cases, as data, derived from the motor they run on.
//!
//! A [`Bench`] is one motor on two simulated axes: the speed drive at
//! [`Bench::speed_m_per_s`] (the paper axis's plant and drive settings for that motor) and
//! the positioning drive of `dcfo stroke` ([`crate::commands::stroke::setup_for`]: carriage,
//! friction, R +20 %, L -5 %; HFI on a salient motor). Every level a case injects or
//! expects comes from the bench's own settings ([`Levels`]): the trip levels of its
//! drive, the thrust at its current limit, the hold's thrust, its bus limits, its ADC's
//! full scale, its pole pitch. So one list of cases serves any motor file, and the
//! expectation of each case is fixed, as data, before the case runs.

use dcfo::algorithms::motion::Move;
use dcfo::drive::{Faults, LOW_SPEED_EXIT_RATIO, back_emf_floor_m_per_s};
use dcfo::motor::MotorParams;

use super::axis::Injection;
use crate::simulation::Setup;

/// A speed case's fault comes at this time, s (the drive has handed over and settled).
pub const INJECT_S: f64 = 3.0;
/// A speed case runs this long after its fault, s: longer than a lock loss plus the
/// re-acquire timeout (0.05 + 0.5 s).
pub const AFTER_S: f64 = 1.0;
/// A positioning case's hold at the end of the stroke lasts this long, s (the first
/// move's dwell).
pub const HOLD_S: f32 = 1.0;
/// A fault at rest comes this long into the hold, s.
pub const HOLD_INJECT_S: f64 = 0.2;
/// The second (return) move's dwell, s.
pub const RETURN_DWELL_S: f32 = 0.2;
/// A positioning case runs this long after the healthy run completed its moves, s:
/// the margin for a move the fault delayed.
pub const POSITIONING_MARGIN_S: f64 = 0.5;

/// Which drive a case runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum DriveKind {
    /// The speed drive at [`Bench::speed_m_per_s`].
    Speed,
    /// The positioning drive over the stroke ([`Bench::moves`]).
    Positioning,
}

/// When a case's fault comes: a moment of the healthy run, found in it, so that the
/// same case lands in the same phase of the motion on any motor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Trigger {
    /// The speed drive at [`INJECT_S`].
    SpeedSettled,
    /// From the start of the run.
    FromStart,
    /// The first move's reference passes half the stroke (the drive running sensorless).
    MidMove,
    /// [`HOLD_INJECT_S`] into the hold at the end of the stroke.
    Holding,
    /// The reversal: the first period the return move's reference moves (the low-speed
    /// mode; HFI on a salient motor).
    Reversal,
    /// The first period running sensorless again after the reversal (the hand-over from
    /// the low-speed mode).
    RelockAfterReversal,
}

/// What the design promises for a case.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Expected {
    /// One of these faults latched, bridge off within one period.
    Trip(Faults),
    /// No fault; angle error over the last [`super::STEADY_WINDOW_S`] at most this, deg.
    RideThrough(f64),
    /// A positioning drive: no fault, every move done, and at the end both the position
    /// estimate's error and the mover's distance from the last target at most this, m.
    Completes(f64),
    /// A positioning drive: the move is refused (counted, not executed), the mover never
    /// goes further than this (m) beyond the stroke's ends, and the run then completes as
    /// [`Expected::Completes`] with this bound.
    Refused(f64),
}

/// One case of the campaign.
#[derive(Clone, Debug)]
pub struct Case {
    /// Short name (file names, the table), unique in a campaign.
    pub name: String,
    /// The drive it runs on.
    pub drive: DriveKind,
    /// When the fault comes.
    pub trigger: Trigger,
    /// The fault.
    pub injection: Injection,
    /// The reaction the design promises.
    pub expected: Expected,
    /// Why the design promises it, with the levels it was derived from.
    pub why: String,
}

/// One motor on the campaign's two axes.
#[derive(Clone, Debug)]
pub struct Bench {
    /// The motor's name (the file's `name`, or `paper`).
    pub name: String,
    /// The motor file as the drives are told it.
    pub motor: MotorParams,
    /// The speed drive's plant and settings.
    pub speed: Setup,
    /// The positioning drive's plant and settings.
    pub stroke: Setup,
}

impl Bench {
    /// `motor` (named `name`; in case names, characters other than ASCII letters, digits,
    /// `-`, `_` and `.` become `-`) on both axes. The speed axis is the paper axis's for
    /// that motor: the plant of [`crate::plant::SimParams::from_motor`] carrying the
    /// [`dcfo::drive::PAPER_AXIS_PAYLOAD_KG`] carriage, the drive of
    /// [`dcfo::drive::DriveConfig::stroke_axis`] without its motion.
    pub fn for_motor(name: &str, motor: &MotorParams) -> Self {
        let stroke = crate::commands::stroke::setup_for(motor);
        let mut plant = crate::plant::SimParams::from_motor(motor);
        plant.plant.mass_kg += f64::from(dcfo::drive::PAPER_AXIS_PAYLOAD_KG);
        let mut drive = stroke.drive;
        drive.motion = None;
        let name = name
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() || "-_.".contains(c) { c } else { '-' })
            .collect();
        Bench { name, motor: *motor, speed: Setup { motor: *motor, plant, drive }, stroke }
    }

    /// The paper motor, its speed axis exactly `dcfo paper`'s ([`Setup::paper`] with the
    /// DCFO: the drive told the bus as [`dcfo::drive::PAPER_AXIS_BUS_V`], 311.127 V, where
    /// [`Bench::for_motor`] tells it the simulated inverter's 220 V times sqrt(2)).
    pub fn paper() -> Self {
        let mut bench = Bench::for_motor("paper", &MotorParams::paper());
        bench.speed = Setup::paper(dcfo::algorithms::observer::ObserverKind::Dcfo);
        bench
    }

    /// `motors/salient.toml`, built into the binary.
    pub fn salient() -> Result<Self, String> {
        let file = "motors/salient.toml";
        let m = crate::motor_file::parse_motor_toml(include_str!("../../../../motors/salient.toml"), file)
            .map_err(|e| e.to_string())?;
        Ok(Bench::for_motor(&m.name, &m.params))
    }

    /// The speed cases' speed, m/s: 1.2 times the drive's hand-over speed (0.3 m/s on the
    /// paper axis), running sensorless, the estimator settled; where that lies inside the
    /// motor's low-speed band (below [`back_emf_floor_m_per_s`]), where the speed drive
    /// runs the low-speed mode and not the estimator, 1.2 times the band's exit (the
    /// floor times [`LOW_SPEED_EXIT_RATIO`]).
    pub fn speed_m_per_s(&self) -> f64 {
        let handover = 1.2 * f64::from(self.speed.drive.startup.handover_speed_m_per_s);
        let floor = back_emf_floor_m_per_s(&self.motor, &self.speed.drive);
        if handover >= f64::from(floor) { handover } else { 1.2 * f64::from(floor * LOW_SPEED_EXIT_RATIO) }
    }

    /// The stroke the positioning cases move over: from 0 (where the drive aligns) to
    /// this end, m.
    pub fn stroke_m(&self) -> f32 {
        crate::commands::stroke::STROKE_M
    }

    /// The positioning drive's moves: to the stroke's end, hold [`HOLD_S`] there, back
    /// to 0 and dwell [`RETURN_DWELL_S`].
    pub fn moves(&self) -> [Move; 2] {
        [Move { target_m: self.stroke_m(), dwell_s: HOLD_S }, Move { target_m: 0.0, dwell_s: RETURN_DWELL_S }]
    }

    /// The levels the cases are derived from.
    pub fn levels(&self) -> Levels {
        Levels::of(self)
    }
}

/// The levels of a bench that the cases inject and expect.
#[derive(Clone, Copy, Debug)]
pub struct Levels {
    /// Phase-current trip level, A.
    pub overcurrent_a: f64,
    /// The current ADC's full scale, A.
    pub full_scale_a: f64,
    /// Thrust at the speed drive's current limit, N (`K_f I_max`).
    pub thrust_limit_n: f64,
    /// Nominal bus, V, and the drive's limits, V.
    pub bus_v: f64,
    /// Lowest bus the drive accepts, V.
    pub bus_min_v: f64,
    /// Highest bus the drive accepts, V.
    pub bus_max_v: f64,
    /// The bus reading at the ripple's trough on a bus at `BUS_INSIDE` times the lower
    /// limit, V (divider gain error and offset included, noise not).
    pub bus_inside_trough_read_v: f64,
    /// Back-EMF at the speed cases' speed, V (peak, phase).
    pub emf_v: f64,
    /// Phase voltage the bridge gives (linear modulation, the drive's modulation limit)
    /// on a bus at `BUS_INSIDE` times the lower limit, V (peak).
    pub phase_v_inside: f64,
    /// Current-control supervision threshold, A, and its time, s.
    pub current_error_a: f64,
    /// See `current_error_a`, s.
    pub current_error_s: f64,
    /// Re-acquire timeout (`LOCK_LOST` after it), s.
    pub reacquire_timeout_s: f64,
    /// Overload supervision time, s.
    pub overload_s: f64,
    /// Pole pitch, m.
    pub pole_pitch_m: f64,
    /// The thrust the positioning drive holds a position with at rest, N: with HFI the
    /// hold's thrust at the current limit, without it the peak of the low-speed current
    /// vector's spring (`K_f I_ls`, at a load angle of 90 deg).
    pub hold_thrust_n: f64,
    /// The least thrust the positioning drive has along its moves, N: with HFI the
    /// current limit's, without it the peak force of the low-speed vector at the band's
    /// edge, where its amplitude has fallen to `I_exit` (`K_f I_exit`).
    pub moving_thrust_n: f64,
    /// The thrust the moves need besides a load, N: the moving mass at the profile's
    /// acceleration limit plus the stroke axis's break-away friction.
    pub motion_force_n: f64,
    /// The positioning drive has HFI (a salient motor).
    pub hfi: bool,
    /// The positioning drive's moves leave the low-speed band (their speed limit is above
    /// its exit speed) and run sensorless on the estimator.
    pub runs_sensorless: bool,
    /// The profile's stroke limits, m.
    pub stroke_min_m: f64,
    /// See `stroke_min_m`, m.
    pub stroke_max_m: f64,
}

/// A bus below the lower limit (or above the upper) by this factor's distance from 1:
/// a trip. 5 %: beyond the ripple (1 %) and the divider's gain error (1 %).
const BUS_BEYOND: f64 = 0.05;
/// A bus this many times the lower limit: inside it with the same margins to spare.
const BUS_INSIDE: f64 = 1.08;
/// A load this fraction of the thrust available: held.
const LOAD_HELD: f64 = 2.0 / 3.0;
/// A load this fraction of the thrust available: beyond it.
const LOAD_BEYOND: f64 = 4.0 / 3.0;
/// A positioning ride-through ends within this fraction of a pole pitch (m) of its
/// target and of its estimate: a quarter pole pitch, 45 electrical degrees, the largest
/// position error `dcfo stroke` accepts during a healthy run.
const POSITION_BOUND_POLE_PITCHES: f64 = 0.25;

impl Levels {
    fn of(b: &Bench) -> Self {
        let d = &b.speed.drive;
        let f = &d.faults;
        let inv = &b.speed.plant.inverter;
        let sensors = &b.speed.plant.sensors;
        let k_f = f64::from(b.motor.thrust_constant_n_per_a());
        let bus_inside = BUS_INSIDE * f64::from(f.bus_min_v);
        let gain = 1.0 + sensors.bus_gain_error;
        let omega = b.speed_m_per_s() * std::f64::consts::PI / f64::from(b.motor.pole_pitch_m);
        let motion = b.stroke.drive.motion;
        let hfi = motion.is_some_and(|m| m.hfi.is_some());
        let limit_a = f64::from(b.stroke.drive.current_limit_a);
        let (hold_current_a, moving_current_a) = match motion {
            Some(m) if m.hfi.is_none() => (f64::from(m.low_speed_current_a), f64::from(m.exit_current_a)),
            _ => (limit_a, limit_a),
        };
        let limits = motion.map(|m| m.limits);
        let max_accel = limits.map_or(0.0, |l| f64::from(l.max_accel_m_per_s2));
        Levels {
            overcurrent_a: f64::from(f.overcurrent_a),
            full_scale_a: sensors.current_full_scale_a,
            thrust_limit_n: k_f * f64::from(d.current_limit_a),
            bus_v: inv.dc_bus_v,
            bus_min_v: f64::from(f.bus_min_v),
            bus_max_v: f64::from(f.bus_max_v),
            bus_inside_trough_read_v: (bus_inside - inv.bus_ripple_v) * gain + sensors.bus_offset_v,
            emf_v: omega * f64::from(b.motor.psi_f_wb),
            phase_v_inside: bus_inside * f64::from(d.modulation_limit) / 3f64.sqrt(),
            current_error_a: f64::from(f.current_error_a),
            current_error_s: f64::from(f.current_error_s),
            reacquire_timeout_s: f64::from(f.reacquire_timeout_s),
            overload_s: f64::from(f.overload_s),
            pole_pitch_m: f64::from(b.motor.pole_pitch_m),
            hold_thrust_n: k_f * hold_current_a,
            moving_thrust_n: k_f * moving_current_a,
            motion_force_n: f64::from(b.stroke.drive.moving_mass_kg) * max_accel
                + b.stroke.plant.plant.static_friction_n,
            hfi,
            runs_sensorless: motion
                .is_some_and(|m| m.limits.max_speed_m_per_s > m.low_speed_m_per_s * m.low_speed_exit_ratio),
            stroke_min_m: limits.map_or(0.0, |l| f64::from(l.stroke_min_m)),
            stroke_max_m: limits.map_or(0.0, |l| f64::from(l.stroke_max_m)),
        }
    }
}

/// The speed drive's cases on `bench`.
pub fn speed_cases(bench: &Bench) -> Vec<Case> {
    use Expected::*;
    use Injection::*;
    let l = bench.levels();
    let v = bench.speed_m_per_s();
    let case = |name: &str, injection, expected, why: String| Case {
        name: name.to_string(),
        drive: DriveKind::Speed,
        trigger: if Injection::from_start(injection) { Trigger::FromStart } else { Trigger::SpeedSettled },
        injection,
        expected,
        why,
    };
    let (oc, fs) = (l.overcurrent_a, l.full_scale_a);
    let sag = (1.0 - BUS_BEYOND) * l.bus_min_v / l.bus_v;
    let inside = BUS_INSIDE * l.bus_min_v / l.bus_v;
    let over = (1.0 + BUS_BEYOND) * l.bus_max_v / l.bus_v;
    let held = LOAD_HELD * l.thrust_limit_n;
    let beyond = LOAD_BEYOND * l.thrust_limit_n;
    let pct = |x: f64| format!("{:.0}%", 100.0 * x);
    let file = |rs, l_, psi_f| MotorFile { rs, l: l_, psi_f };
    vec![
        case(
            "open-phase",
            OpenPhase,
            Trip(Faults::CURRENT_CONTROL),
            format!(
                "phase a carries no current whatever the loops apply: the phase-loss check (or the voltage on its limit with the current {:.2} A off its reference for {:.0} ms)",
                l.current_error_a,
                1e3 * l.current_error_s
            ),
        ),
        case(
            "phase-short",
            PhaseShort,
            Trip(Faults::OVER_CURRENT),
            format!("the short's current exceeds the {oc:.1} A trip level within a period"),
        ),
        case(
            "sensor-stuck",
            SensorStuck,
            Trip(Faults::CURRENT_CONTROL),
            format!(
                "the loops chase a reading that does not move: the voltage goes to its limit with the read current off its reference ({:.0} ms)",
                1e3 * l.current_error_s
            ),
        ),
        if fs > oc {
            case(
                "adc-saturated",
                AdcSaturated,
                Trip(Faults::OVER_CURRENT),
                format!("full scale ({fs} A) is above the {oc:.1} A trip level"),
            )
        } else {
            case(
                "adc-saturated",
                AdcSaturated,
                Trip(Faults::CURRENT_CONTROL),
                format!("full scale ({fs} A) is below the {oc:.1} A trip level: a reading stuck there"),
            )
        },
        case("adc-nan", AdcNan, Trip(Faults::NON_FINITE), "every reading is checked for NaN/inf before use".into()),
        case(
            &format!("bus-sag-{}", pct(sag)),
            Bus(sag),
            Trip(Faults::BUS_UNDER_VOLTAGE),
            format!("5 % below the {:.1} V limit (beyond the ripple and the divider's errors)", l.bus_min_v),
        ),
        case(
            &format!("bus-sag-{}", pct(inside)),
            Bus(inside),
            RideThrough(5.0),
            format!(
                "the reading's trough ({:.1} V: ripple, divider gain and offset) stays above the {:.1} V limit; at {v} m/s the back-EMF needs {:.0} V of the {:.0} V the bridge gives",
                l.bus_inside_trough_read_v, l.bus_min_v, l.emf_v, l.phase_v_inside
            ),
        ),
        case(
            &format!("bus-over-{}", pct(over)),
            Bus(over),
            Trip(Faults::BUS_OVER_VOLTAGE),
            format!("5 % above the {:.1} V limit", l.bus_max_v),
        ),
        case("bus-loss", Bus(0.0), Trip(Faults::BUS_UNDER_VOLTAGE), "below the lower limit".into()),
        case(
            "blocked-mover",
            Blocked,
            Trip(Faults::LOCK_LOST),
            format!(
                "no back-EMF: the estimate stops tracking, Reacquiring (no thrust), LOCK_LOST after {} s",
                l.reacquire_timeout_s
            ),
        ),
        case(
            &format!("load-{held:.0}N"),
            Load(held),
            RideThrough(10.0),
            format!(
                "two thirds of the {:.0} N at the current limit: the speed loop holds it below the limit, no OVERLOAD",
                l.thrust_limit_n
            ),
        ),
        case(
            &format!("load-{beyond:.0}N"),
            Load(beyond),
            Trip(Faults::OVERLOAD),
            format!(
                "beyond the {:.0} N at the current limit: the mover stops and is pushed back while the speed loop pushes on the limit; OVERLOAD after {} s there, not a flying restart into the same load",
                l.thrust_limit_n, l.overload_s
            ),
        ),
        case(
            "lock-loss",
            EstimatorReset,
            RideThrough(5.0),
            "flying restart: Reacquiring with zero current, Running again within 0.1 s".into(),
        ),
        case(
            "silent-link",
            LinkSilent,
            Trip(Faults::EXTERNAL),
            format!(
                "the link watchdog trips an active drive after {} periods without a frame",
                dcfo::link::SILENT_LINK_PERIODS
            ),
        ),
        case(
            "corrupted-frames",
            LinkCorrupt { every: 20 },
            RideThrough(5.0),
            "CRC-16 rejects every corrupted frame; a dropped period repeats the duties, and the next frame's sequence number tells the drive to integrate it; no 10 in a row".into(),
        ),
        case(
            "replayed-frames",
            LinkReplay { every: 7, age: 5 },
            RideThrough(5.0),
            "a duplicate is answered with the same bytes without a second step; an old frame is counted and ignored".into(),
        ),
        case(
            "R-x2",
            PlantRs(2.0),
            RideThrough(10.0),
            "the DCFO removes the DC part of the error; the paper's R = 2 Rs case reaches 7.5 deg".into(),
        ),
        case(
            "file-R+30%",
            file(1.3, 1.0, 1.0),
            RideThrough(10.0),
            "a resistance error under light load is a small back-EMF error (dR i / (w psi_f))".into(),
        ),
        case("file-R-30%", file(0.7, 1.0, 1.0), RideThrough(10.0), "as R +30 %".into()),
        case(
            "file-L+30%",
            file(1.0, 1.3, 1.0),
            RideThrough(10.0),
            "the observer subtracts L i: an error of dL i / psi_f rad".into(),
        ),
        case("file-L-30%", file(1.0, 0.7, 1.0), RideThrough(10.0), "as L +30 %".into()),
        case(
            "file-psi+30%",
            file(1.0, 1.0, 1.3),
            RideThrough(10.0),
            "the angle does not depend on psi_f; the speed loop's gain and the decoupling feed-forward do".into(),
        ),
        case("file-psi-30%", file(1.0, 1.0, 0.7), RideThrough(10.0), "as psi_f +30 %".into()),
    ]
}

/// The positioning drive's cases on `bench`, named `<motor>-stroke-<what>`.
pub fn positioning_cases(bench: &Bench) -> Vec<Case> {
    use Expected::*;
    use Injection::*;
    let l = bench.levels();
    let tau = l.pole_pitch_m;
    let bound = POSITION_BOUND_POLE_PITCHES * tau;
    let low_speed = if l.hfi { "the low-speed mode on HFI" } else { "the low-speed mode's current vector" };
    let case = |what: &str, trigger, injection, expected, why: String| Case {
        name: format!("{}-stroke-{what}", bench.name),
        drive: DriveKind::Positioning,
        trigger,
        injection,
        expected,
        why,
    };
    let carried = LOAD_HELD * (l.moving_thrust_n - l.motion_force_n).max(0.0);
    let held = LOAD_HELD * l.hold_thrust_n;
    let beyond = LOAD_BEYOND * l.hold_thrust_n;
    let (hold_how, moving_how) = if l.hfi {
        (
            format!("the thrust at the current limit ({:.0} N)", l.hold_thrust_n),
            "the thrust at the current limit",
        )
    } else {
        (
            format!("the low-speed vector's peak spring force K_f I_ls ({:.0} N)", l.hold_thrust_n),
            "the vector's force at the band's edge, K_f I_exit",
        )
    };
    vec![
        if l.runs_sensorless {
            case(
                "lock-loss-at-reversal",
                Trigger::RelockAfterReversal,
                EstimatorReset,
                Completes(bound),
                format!(
                    "the estimator lost just after the hand-over that follows the reversal: back to {low_speed} on the reference, seeded again, handed over again; the move ends within {:.1} mm",
                    1e3 * bound
                ),
            )
        } else {
            case(
                "lock-loss-at-reversal",
                Trigger::Reversal,
                EstimatorReset,
                Completes(bound),
                format!(
                    "the estimator reset as the reversal starts; the moves never leave {low_speed} (its exit speed is above their speed limit), which does not run on the estimator: the move ends within {:.1} mm",
                    1e3 * bound
                ),
            )
        },
        case(
            "sensor-stuck-low-speed",
            Trigger::Reversal,
            SensorStuck,
            Trip(Faults::CURRENT_CONTROL),
            format!(
                "phase b's reading freezes as the reversal starts in {low_speed}: the loops chase a reading that does not move, the voltage goes to its limit with the read current off its reference ({:.0} ms)",
                1e3 * l.current_error_s
            ),
        ),
        case(
            "adc-nan-low-speed",
            Trigger::Reversal,
            AdcNan,
            Trip(Faults::NON_FINITE),
            format!("phase a's reading is NaN as the reversal starts in {low_speed}: checked before use"),
        ),
        case(
            "open-phase-moving",
            Trigger::MidMove,
            OpenPhase,
            Trip(Faults::CURRENT_CONTROL),
            format!(
                "phase a opens mid-move, running sensorless: the phase-loss check (or the voltage on its limit with the current {:.2} A off its reference for {:.0} ms)",
                l.current_error_a,
                1e3 * l.current_error_s
            ),
        ),
        case(
            "link-loss-mid-move",
            Trigger::MidMove,
            LinkSilent,
            Trip(Faults::EXTERNAL),
            format!(
                "the host stops sending mid-move: the link watchdog trips the moving drive after {} periods without a frame",
                dcfo::link::SILENT_LINK_PERIODS
            ),
        ),
        case(
            &format!("load-{carried:.0}N"),
            Trigger::Holding,
            Load(carried),
            Completes(bound),
            format!(
                "a load while holding, on through the return move: two thirds of what the moves leave of {moving_how} ({:.0} N less {:.0} N of acceleration and break-away friction); held, the return move ends within {:.1} mm",
                l.moving_thrust_n,
                l.motion_force_n,
                1e3 * bound
            ),
        ),
        if held + l.motion_force_n <= l.moving_thrust_n {
            case(
                &format!("load-{held:.0}N-holding"),
                Trigger::Holding,
                Load(held),
                Completes(bound),
                format!(
                    "two thirds of {hold_how} while holding: held, and within what the moves leave of {moving_how} ({:.0} N) on the return move, which ends within {:.1} mm",
                    l.moving_thrust_n - l.motion_force_n,
                    1e3 * bound
                ),
            )
        } else {
            case(
                &format!("load-{held:.0}N-holding"),
                Trigger::Holding,
                Load(held),
                Trip(Faults::OVERLOAD),
                format!(
                    "two thirds of {hold_how} while holding: held at rest, but beyond what the return move leaves of {moving_how} ({:.0} N): OVERLOAD as the mover slips, not a runaway",
                    l.moving_thrust_n - l.motion_force_n
                ),
            )
        },
        case(
            &format!("overload-{beyond:.0}N-holding"),
            Trigger::Holding,
            Load(beyond),
            Trip(Faults::OVERLOAD),
            format!(
                "four thirds of {hold_how} while holding: the hold cannot keep the mover; OVERLOAD rather than the load pushing the mover off its position unannounced"
            ),
        ),
        case(
            "move-beyond-stroke",
            Trigger::Holding,
            MoveTo(l.stroke_max_m + tau),
            Refused(bound),
            format!(
                "a move to {:.3} m, a pole pitch beyond the stroke's end ({:.3} m), while holding: refused and counted; the mover stays, the return move ends within {:.1} mm",
                l.stroke_max_m + tau,
                l.stroke_max_m,
                1e3 * bound
            ),
        ),
        case(
            "move-nan",
            Trigger::Holding,
            MoveTo(f64::NAN),
            Refused(bound),
            "a move to a NaN target while holding: refused and counted, as a target outside the stroke"
                .into(),
        ),
    ]
}
