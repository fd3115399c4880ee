//! `dcfo faults`: the fault campaign. Each case injects one fault into a closed-loop
//! simulation (`Drive<f32>` as the firmware runs it, in process or behind the firmware's
//! link server) and checks the reaction the design promises, stated as data before
//! measuring ([`cases`]), derived from the motor the case runs on. A campaign is a list
//! of parts, each one drive on one motor ([`Plan`]):
//!
//! - the **speed drive** at 1.2 times its hand-over speed, the fault at [`INJECT_S`]
//!   (the paper axis's plant and settings for the motor);
//! - the **positioning drive** of `dcfo stroke` moving to the end of the stroke, holding
//!   there, and moving back through a reversal (HFI in the low-speed mode on a salient
//!   motor), the fault at a moment of the motion found in a healthy run of the same
//!   axis ([`Trigger`]): mid-move, while holding, at the reversal, at the hand-over after
//!   it.
//!
//! `dcfo faults` runs the speed drive on the paper motor and the positioning drive on
//! the paper motor and on `motors/salient.toml`; `dcfo faults --motor FILE` runs both
//! drives on any motor file.
//!
//! The reactions:
//!
//! - **trip**: a named fault latched and the bridge off within one PWM period of the
//!   first sample that shows the fault's condition (the one-period computation delay of
//!   the simulation: the duties of step `k` apply from `t_{k+1}`);
//! - **ride-through** (speed drive): no fault, and the angle error over the last
//!   [`STEADY_WINDOW_S`] of the run within the stated bound;
//! - **completes** (positioning drive): no fault, every move done, and at the end the
//!   position estimate and the mover within the stated bound of each other and of the
//!   last target;
//! - **refused** (positioning drive): the move command refused and counted, the mover
//!   never beyond the stroke's ends by more than the bound, and the moves then complete.
//!
//! For every case it also looks for a *silent failure*: the estimate reported as locked
//! (and, on the positioning drive, in use: `Running`) while more than
//! [`SILENT_ERROR_DEG`] off the plant's true angle, or a positioning drive driving the
//! bridge without a fault while its position estimate is more than
//! [`SILENT_POSITION_POLE_PITCHES`] of a pole pitch off the mover, for more than
//! [`SILENT_TIME_S`] in a row.
//!
//! The bridge-off latency is counted from the first period whose sample meets the
//! latched fault's condition, computed here independently of the drive from the
//! readings it was given (a phase current beyond the trip level, a bus reading outside
//! its limits, a non-finite reading, the watchdog's count of periods without a frame);
//! for a fault the drive decides on its own state (`LOCK_LOST`, `CURRENT_CONTROL`,
//! `OVERLOAD`), from the step that latched it.
//!
//! Cost: each part runs its healthy axis once and starts every case from a copy of it
//! at the case's moment (a fault present from the start runs from scratch); a run stops
//! [`AFTER_TRIP_S`] after a fault latched. The cases run on as many threads as asked.

pub mod axis;
pub mod cases;

use crate::commands::sim::fault_names;

use dcfo::drive::{Drive, DriveState, Faults};
use dcfo::link::SILENT_LINK_PERIODS;
use dcfo::motor::MotorParams;
use dcfo::num::units::Base;
use serde::Serialize;

pub use axis::{Axis, Injection, LinkChecks, Period};
pub use cases::{AFTER_S, Bench, Case, DriveKind, Expected, INJECT_S, Levels, Trigger};

use crate::simulation::Setup;
use crate::trace::wrap_angle;

/// A ride-through's accuracy is measured over the run's last this many seconds.
pub const STEADY_WINDOW_S: f64 = 0.5;
/// A silent failure: locked while wrong by more than this (electrical degrees)...
pub const SILENT_ERROR_DEG: f64 = 30.0;
/// ... or a positioning drive's estimate off the mover by more than this many pole
/// pitches (0.5: 90 electrical degrees, twice what `dcfo stroke` accepts)...
pub const SILENT_POSITION_POLE_PITCHES: f64 = 0.5;
/// ... for longer than this, s.
pub const SILENT_TIME_S: f64 = 0.05;
/// A run stops this long after a fault latched, s (the bridge is off; the rest would
/// only lengthen the figure).
pub const AFTER_TRIP_S: f64 = 0.2;

/// One part of a campaign: one drive on one motor, and its cases.
#[derive(Clone, Debug)]
pub struct Part {
    /// The motor and its axes.
    pub bench: Bench,
    /// The drive the cases run on.
    pub drive: DriveKind,
    /// The cases, in the table's order.
    pub cases: Vec<Case>,
}

impl Part {
    /// The speed drive's cases on `bench`.
    pub fn speed(bench: &Bench) -> Self {
        Part { bench: bench.clone(), drive: DriveKind::Speed, cases: cases::speed_cases(bench) }
    }

    /// The positioning drive's cases on `bench`.
    pub fn positioning(bench: &Bench) -> Self {
        Part { bench: bench.clone(), drive: DriveKind::Positioning, cases: cases::positioning_cases(bench) }
    }

    /// The part in words, for the table.
    pub fn describe(&self) -> String {
        let b = &self.bench;
        match self.drive {
            DriveKind::Speed => format!(
                "speed drive on `{}` at {} m/s, fault at {INJECT_S} s, {AFTER_S} s after",
                b.name,
                b.speed_m_per_s()
            ),
            DriveKind::Positioning => format!(
                "positioning drive on `{}`{}: 0 -> {} m, hold {} s, back to 0",
                b.name,
                if b.levels().hfi { " (HFI)" } else { "" },
                b.stroke_m(),
                cases::HOLD_S
            ),
        }
    }

    fn setup(&self) -> &Setup {
        match self.drive {
            DriveKind::Speed => &self.bench.speed,
            DriveKind::Positioning => &self.bench.stroke,
        }
    }
}

/// What a campaign runs.
#[derive(Clone, Debug)]
pub struct Plan {
    /// The parts, in the table's order.
    pub parts: Vec<Part>,
}

impl Plan {
    /// `dcfo faults`: the speed drive on the paper motor, the positioning drive on the
    /// paper motor (no saliency: the low-speed mode's current vector) and on
    /// `motors/salient.toml` (HFI).
    pub fn standard() -> Result<Self, String> {
        let paper = Bench::paper();
        let salient = Bench::salient()?;
        Ok(Plan { parts: vec![Part::speed(&paper), Part::positioning(&paper), Part::positioning(&salient)] })
    }

    /// `dcfo faults --motor FILE`: both drives on `bench`.
    pub fn for_motor(bench: &Bench) -> Self {
        Plan { parts: vec![Part::speed(bench), Part::positioning(bench)] }
    }

    /// Every case, in the table's order, with its part.
    pub fn cases(&self) -> impl Iterator<Item = (&Part, &Case)> {
        self.parts.iter().flat_map(|p| p.cases.iter().map(move |c| (p, c)))
    }
}

/// What one case did.
#[derive(Clone, Debug, Serialize)]
pub struct CaseResult {
    /// The case's name.
    pub name: String,
    /// The motor's name.
    pub motor: String,
    /// The drive it ran on.
    pub drive: DriveKind,
    /// When the fault came.
    pub trigger: Trigger,
    /// The expected reaction, in words.
    pub expected: String,
    /// Why the design promises it.
    pub why: String,
    /// What happened, in words.
    pub happened: String,
    /// Latched faults at the end, named.
    pub faults: String,
    /// Time from the injection to the fault latched, s.
    pub detect_s: Option<f64>,
    /// Periods from the first sample meeting the fault's condition to the first period
    /// with the bridge off.
    pub bridge_off_periods: Option<u64>,
    /// Largest angle error over the last [`STEADY_WINDOW_S`] (speed ride-throughs), deg.
    pub steady_err_deg: Option<f64>,
    /// Largest angle error while reported locked after the injection, deg.
    pub locked_err_max_deg: f64,
    /// Longest time a silent-failure condition held, s.
    pub locked_wrong_s: f64,
    /// A silent failure happened.
    pub silent_failure: bool,
    /// Largest true phase current after the injection, A.
    pub i_peak_a: f64,
    /// Positioning: largest |x_hat - x| after the injection while the drive reported a
    /// position, m.
    pub x_err_max_m: Option<f64>,
    /// Positioning: |x_hat - x| at the end, m.
    pub x_err_final_m: Option<f64>,
    /// Positioning: the mover's distance from the last move's target at the end, m.
    pub x_off_target_m: Option<f64>,
    /// Positioning: the mover's lowest and highest position after the injection, m.
    pub x_range_m: Option<[f64; 2]>,
    /// Positioning: every move done at the end.
    pub moves_done: Option<bool>,
    /// Positioning: moves the drive refused after the injection.
    pub moves_rejected: Option<u16>,
    /// Link-fault counts (link cases only).
    pub link: Option<LinkChecks>,
    /// The case met its expectation (and the floors).
    pub met: bool,
}

/// The campaign's result.
#[derive(Clone, Debug, Serialize)]
pub struct Campaign {
    /// The parts, in words.
    pub parts: Vec<String>,
    /// Number of cases.
    pub cases: usize,
    /// Cases with a silent failure.
    pub silent_failures: usize,
    /// Largest bridge-off latency over the tripping cases, periods.
    pub max_bridge_off_periods: u64,
    /// Cases that did not meet their expectation.
    pub unmet: usize,
    /// Per case.
    pub results: Vec<CaseResult>,
}

fn describe(e: Expected) -> String {
    match e {
        Expected::Trip(f) => format!("trip {} <= 1 period", fault_names(f)),
        Expected::RideThrough(deg) => format!("ride through, <= {deg} deg"),
        Expected::Completes(m) => format!("complete, <= {:.2} mm", 1e3 * m),
        Expected::Refused(m) => format!("refuse, complete, <= {:.2} mm", 1e3 * m),
    }
}

/// The drive's motor file for `injection` (the plant keeps the true motor).
fn drive_motor(motor: &MotorParams, injection: Injection) -> MotorParams {
    let mut m = *motor;
    if let Injection::MotorFile { rs, l, psi_f } = injection {
        m.rs_ohm *= rs as f32;
        m.ld_h *= l as f32;
        m.lq_h *= l as f32;
        m.psi_f_wb *= psi_f as f32;
    }
    m
}

/// A fresh axis of `part` for `injection` (its from-the-start part applied).
fn fresh_axis(part: &Part, injection: Option<Injection>) -> Result<Axis, String> {
    let setup = part.setup();
    let mut sim = setup.plant;
    if let Some(Injection::PlantRs(k)) = injection {
        sim.plant.rs_ohm *= k;
    }
    let motor = injection.map_or(setup.motor, |i| drive_motor(&setup.motor, i));
    let drive = Drive::<f32>::new(&motor, &setup.drive, &Base::SI).map_err(|e| format!("drive: {e}"))?;
    match part.drive {
        DriveKind::Speed => Axis::new(&sim, drive, part.bench.speed_m_per_s(), false),
        DriveKind::Positioning => Axis::positioning(&sim, drive, &part.bench.moves()),
    }
    .map_err(|e| e.to_string())
}

/// An axis at a case's moment and its log up to then.
type Snapshot = (Axis, Vec<Period>);

/// A part's healthy run: a copy of its axis at every trigger's moment, and the number
/// of periods a case runs in all.
#[derive(Clone, Debug)]
pub struct Prefix {
    /// The snapshots, one per trigger the healthy run reached.
    snapshots: Vec<(Trigger, Snapshot)>,
    /// Periods a case runs in all (its prefix included).
    pub periods: usize,
    /// Why the healthy run is no base for the cases (it faulted, or never reached a
    /// trigger), if so.
    pub unhealthy: Option<String>,
}

impl Prefix {
    fn at(&self, trigger: Trigger) -> Option<&Snapshot> {
        self.snapshots.iter().find(|(t, _)| *t == trigger).map(|(_, s)| s)
    }
}

/// Runs `part`'s healthy axis and takes its snapshots.
pub fn healthy_prefix(part: &Part) -> Result<Prefix, String> {
    let mut axis = fresh_axis(part, None)?;
    let ts = axis.plant().pwm_period_s();
    let periods = |s: f64| (s / ts).round() as usize;
    let mut log = Vec::new();
    match part.drive {
        DriveKind::Speed => {
            for _ in 0..periods(INJECT_S) {
                log.push(axis.period());
            }
            let unhealthy = log.last().and_then(|p| {
                (!p.faults.is_empty() || p.state != DriveState::Running).then(|| {
                    format!("the healthy run is {:?} ({}) at the injection", p.state, fault_names(p.faults))
                })
            });
            Ok(Prefix {
                snapshots: vec![(Trigger::SpeedSettled, (axis, log))],
                periods: periods(INJECT_S + AFTER_S),
                unhealthy,
            })
        }
        DriveKind::Positioning => positioning_prefix(part, axis),
    }
}

/// The positioning drive's healthy run: the moves of [`Bench::moves`], snapshots at
/// each [`Trigger`] in their order of the motion (no [`Trigger::RelockAfterReversal`] on
/// a motor whose moves never leave the low-speed band).
fn positioning_prefix(part: &Part, mut axis: Axis) -> Result<Prefix, String> {
    let ts = axis.plant().pwm_period_s();
    let stroke = f64::from(part.bench.stroke_m());
    // The healthy run's moves take about 3 s; stop it at ten.
    let limit = (10.0 / ts) as usize;
    let hold_periods = (cases::HOLD_INJECT_S / ts).round() as usize;
    let mut log: Vec<Period> = Vec::new();
    let mut snapshots: Vec<(Trigger, Snapshot)> = Vec::new();
    let mut hold_start: Option<usize> = None;
    let mut unhealthy = None;
    let mut done = None;
    for k in 0..limit {
        let p = axis.period();
        log.push(p);
        if !p.faults.is_empty() {
            unhealthy = Some(format!("the healthy run tripped {} at {:.3} s", fault_names(p.faults), p.t_s));
            break;
        }
        let reached = |snapshots: &[(Trigger, Snapshot)], t: Trigger| snapshots.iter().any(|(s, _)| *s == t);
        let reached = |t: Trigger| reached(&snapshots, t);
        let next = if !reached(Trigger::MidMove) {
            (p.x_ref_m >= 0.5 * stroke).then_some(Trigger::MidMove)
        } else if !reached(Trigger::Holding) {
            let at_end = p.v_ref_m_per_s == 0.0 && p.x_ref_m >= stroke - 1e-6;
            let since = if at_end { *hold_start.get_or_insert(k) } else { k };
            (at_end && k - since >= hold_periods).then_some(Trigger::Holding)
        } else if !reached(Trigger::Reversal) {
            (p.v_ref_m_per_s < 0.0).then_some(Trigger::Reversal)
        } else if !reached(Trigger::RelockAfterReversal) {
            (p.state == DriveState::Running).then_some(Trigger::RelockAfterReversal)
        } else {
            None
        };
        let reversed = reached(Trigger::Reversal);
        if let Some(t) = next {
            snapshots.push((t, (axis.clone(), log.clone())));
        }
        if p.motion_done && reversed {
            done = Some(k);
            break;
        }
    }
    let periods = match done {
        Some(k) => k + 1 + (cases::POSITIONING_MARGIN_S / ts).round() as usize,
        None => {
            unhealthy.get_or_insert_with(|| "the healthy run did not complete its moves".to_string());
            log.len()
        }
    };
    Ok(Prefix { snapshots, periods, unhealthy })
}

/// Runs `case` of `part` from its moment in `prefix` (or, for a fault present from the
/// start, from scratch). Returns the result and the log from 0.5 s before the injection
/// on.
pub fn run_case(part: &Part, case: &Case, prefix: &Prefix) -> Result<(CaseResult, Vec<Period>), String> {
    let (mut axis, mut log) = if case.trigger == Trigger::FromStart {
        let mut axis = fresh_axis(part, Some(case.injection))?;
        let n = prefix.at(Trigger::SpeedSettled).map_or(0, |(_, log)| log.len());
        let mut log = Vec::with_capacity(prefix.periods);
        for _ in 0..n {
            log.push(axis.period());
        }
        (axis, log)
    } else {
        let Some((axis, log)) = prefix.at(case.trigger) else {
            return Err(format!(
                "{}: the healthy run never reached {:?}{}",
                case.name,
                case.trigger,
                prefix.unhealthy.as_ref().map(|u| format!(" ({u})")).unwrap_or_default()
            ));
        };
        let mut axis = axis.clone();
        axis.inject(case.injection).map_err(|e| e.to_string())?;
        (axis, log.clone())
    };
    let k0 = log.len();
    let ts = axis.plant().pwm_period_s();
    let after_trip = (AFTER_TRIP_S / ts).round() as usize;
    let mut tripped_at: Option<usize> = None;
    while log.len() < prefix.periods.max(k0 + 1) {
        let p = axis.period();
        log.push(p);
        if !p.faults.is_empty() {
            let at = *tripped_at.get_or_insert(log.len());
            if log.len() >= at + after_trip {
                break;
            }
        }
    }
    let result = analyse(part, case, &log, k0, &axis);
    let keep = k0.saturating_sub((0.5 / ts) as usize);
    Ok((result, log.split_off(keep)))
}

/// The angle error of a period, deg (NaN without an estimate).
pub fn err_deg(p: &Period) -> f64 {
    wrap_angle(p.theta_rad - p.theta_hat_rad).to_degrees()
}

/// The longest run of consecutive `true`s.
fn longest_run(flags: impl Iterator<Item = bool>) -> usize {
    let (mut run, mut longest) = (0usize, 0usize);
    for f in flags {
        run = if f { run + 1 } else { 0 };
        longest = longest.max(run);
    }
    longest
}

/// The figures of one case from its log (`k0`: the injection's period).
fn analyse(part: &Part, case: &Case, log: &[Period], k0: usize, axis: &Axis) -> CaseResult {
    let ts = axis.plant().pwm_period_s();
    let setup = part.setup();
    let limits = &setup.drive.faults;
    let positioning = part.drive == DriveKind::Positioning;
    let tau = f64::from(setup.motor.pole_pitch_m);
    // Silent failure: over the whole run (start-up included).
    let wrong_angle = |p: &Period| {
        p.locked && (!positioning || p.state == DriveState::Running) && err_deg(p).abs() > SILENT_ERROR_DEG
    };
    let wrong_position = |p: &Period| {
        positioning
            && p.bridge_on
            && p.faults.is_empty()
            && (p.x_hat_m - p.x_m).abs() > SILENT_POSITION_POLE_PITCHES * tau
    };
    let longest = longest_run(log.iter().map(|p| wrong_angle(p) || wrong_position(p)));
    let locked_wrong_s = longest as f64 * ts;
    let silent = locked_wrong_s > SILENT_TIME_S;
    let after = &log[k0.min(log.len())..];
    let locked_err_max = after
        .iter()
        .filter(|p| p.locked)
        .map(|p| err_deg(p).abs())
        .filter(|e| e.is_finite())
        .fold(0.0f64, f64::max);
    let latched = after.iter().position(|p| !p.faults.is_empty());
    let final_faults = log.last().map_or(Faults::NONE, |p| p.faults);
    let detect_s = latched.map(|j| j as f64 * ts);
    // The first period at or after the injection whose readings meet the latched
    // fault's condition, computed from the readings.
    let condition = |p: &Period, j: usize| -> bool {
        let f = final_faults;
        let i_trip = f64::from(limits.overcurrent_a);
        (f.contains(Faults::OVER_CURRENT) && p.i_meas_a.iter().any(|i| i.abs() > i_trip))
            || (f.contains(Faults::NON_FINITE)
                && p.i_meas_a.iter().chain([&p.vdc_meas_v]).any(|x| !x.is_finite()))
            || (f.contains(Faults::BUS_UNDER_VOLTAGE) && p.vdc_meas_v < f64::from(limits.bus_min_v))
            || (f.contains(Faults::BUS_OVER_VOLTAGE) && p.vdc_meas_v > f64::from(limits.bus_max_v))
            || (f.contains(Faults::EXTERNAL)
                && j + 1 >= usize::from(SILENT_LINK_PERIODS)
                && after[j + 1 - usize::from(SILENT_LINK_PERIODS)..=j].iter().all(|q| !q.answered))
    };
    let k_condition = after.iter().enumerate().position(|(j, p)| condition(p, j)).or(latched);
    let k_off = k_condition.and_then(|c| after[c..].iter().position(|p| !p.bridge_on).map(|d| c + d));
    let bridge_off_periods = match (latched, k_condition, k_off) {
        (Some(_), Some(c), Some(off)) => Some((off - c) as u64),
        _ => None,
    };
    let i_peak = after.iter().map(|p| p.i_true_max_a).fold(0.0, f64::max);
    let n_window = (STEADY_WINDOW_S / ts) as usize;
    let tail = &log[log.len().saturating_sub(n_window)..];
    let steady = if final_faults.is_empty() && !positioning {
        // Periods without an answer (a dropped link frame) have no estimate.
        Some(tail.iter().filter(|p| p.answered).map(|p| err_deg(p).abs()).fold(0.0, f64::max))
    } else {
        None
    };
    // The positioning figures.
    let last = log.last();
    let target = part.bench.moves().last().map_or(0.0, |m| f64::from(m.target_m));
    let x_err_max = positioning.then(|| {
        after.iter().map(|p| (p.x_hat_m - p.x_m).abs()).filter(|e| e.is_finite()).fold(0.0, f64::max)
    });
    let x_err_final = last.filter(|_| positioning).map(|p| (p.x_hat_m - p.x_m).abs());
    let x_off_target = last.filter(|_| positioning).map(|p| (p.x_m - target).abs());
    let x_range = positioning.then(|| {
        after.iter().fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], p| [lo.min(p.x_m), hi.max(p.x_m)])
    });
    let moves_done = last.filter(|_| positioning).map(|p| p.motion_done);
    let rejected_before = log.get(k0.wrapping_sub(1)).map_or(0, |p| p.moves_rejected);
    let moves_rejected = last.filter(|_| positioning).map(|p| p.moves_rejected.wrapping_sub(rejected_before));
    let completes = |bound: f64| {
        final_faults.is_empty()
            && moves_done == Some(true)
            && x_err_final.is_some_and(|e| e <= bound)
            && x_off_target.is_some_and(|e| e <= bound)
    };
    let link = case.injection.over_link().then_some(axis.link);
    let link_ok = link
        .is_none_or(|l| l.corrupted_answered == 0 && l.duplicate_mismatches == 0 && l.replays_answered == 0);
    let met = !silent
        && link_ok
        && match case.expected {
            Expected::Trip(f) => {
                final_faults.bits() & f.bits() != 0 && bridge_off_periods.is_some_and(|p| p <= 1)
            }
            Expected::RideThrough(deg) => final_faults.is_empty() && steady.is_some_and(|e| e <= deg),
            Expected::Completes(bound) => completes(bound),
            Expected::Refused(bound) => {
                let levels = part.bench.levels();
                moves_rejected.is_some_and(|n| n >= 1)
                    && x_range.is_some_and(|[lo, hi]| {
                        lo >= levels.stroke_min_m - bound && hi <= levels.stroke_max_m + bound
                    })
                    && completes(bound)
            }
        };
    let last_state = last.map_or(DriveState::Disabled, |p| p.state);
    let mm = |x: Option<f64>| x.map_or("-".to_string(), |x| format!("{:.2} mm", 1e3 * x));
    let happened = match (latched, steady) {
        (Some(j), _) => format!(
            "{} after {:.1} ms, bridge off {} period(s) after its condition",
            fault_names(final_faults),
            j as f64 * ts * 1e3,
            bridge_off_periods.map_or("never".into(), |p| p.to_string())
        ),
        (None, Some(e)) => {
            format!("rode through ({last_state:?}), {e:.1} deg over the last {STEADY_WINDOW_S} s")
        }
        (None, None) if positioning => format!(
            "{}{}, x_hat - x {}, {} off the target",
            moves_rejected.filter(|&n| n > 0).map(|n| format!("refused {n}, ")).unwrap_or_default(),
            if moves_done == Some(true) { "moves done" } else { "moves NOT done" },
            mm(x_err_final),
            mm(x_off_target)
        ),
        (None, None) => format!("{last_state:?}"),
    };
    CaseResult {
        faults: fault_names(final_faults),
        detect_s,
        bridge_off_periods,
        steady_err_deg: steady,
        locked_err_max_deg: locked_err_max,
        locked_wrong_s,
        silent_failure: silent,
        i_peak_a: i_peak,
        x_err_max_m: x_err_max,
        x_err_final_m: x_err_final,
        x_off_target_m: x_off_target,
        x_range_m: x_range,
        moves_done,
        moves_rejected,
        link,
        met,
        ..CaseResult::unmet(part, case, happened)
    }
}

impl CaseResult {
    /// The result of `case` on `part` with nothing measured: unmet, `happened` saying
    /// why (a case that could not run: its part's healthy run is no base for it); the
    /// base every result is built on.
    fn unmet(part: &Part, case: &Case, happened: String) -> Self {
        CaseResult {
            name: case.name.clone(),
            motor: part.bench.name.clone(),
            drive: part.drive,
            trigger: case.trigger,
            expected: describe(case.expected),
            why: case.why.clone(),
            happened,
            faults: "-".into(),
            detect_s: None,
            bridge_off_periods: None,
            steady_err_deg: None,
            locked_err_max_deg: 0.0,
            locked_wrong_s: 0.0,
            silent_failure: false,
            i_peak_a: 0.0,
            x_err_max_m: None,
            x_err_final_m: None,
            x_off_target_m: None,
            x_range_m: None,
            moves_done: None,
            moves_rejected: None,
            link: None,
            met: false,
        }
    }
}

/// Runs `tasks` on `threads` threads (each task once, results in order).
fn parallel<T: Sync, R: Send>(threads: usize, tasks: &[T], run: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let next = std::sync::atomic::AtomicUsize::new(0);
    let slots: std::sync::Mutex<Vec<Option<R>>> =
        std::sync::Mutex::new(std::iter::repeat_with(|| None).take(tasks.len()).collect());
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(task) = tasks.get(i) else { break };
                    let r = run(task);
                    if let Ok(mut slots) = slots.lock() {
                        slots[i] = Some(r);
                    }
                }
            });
        }
    });
    slots.into_inner().map(|s| s.into_iter().flatten().collect()).unwrap_or_default()
}

/// Runs every case of `plan` (on `threads` threads), calling `progress(name)` as each
/// ends. Returns the campaign and each case's log (empty for a case that could not run).
pub fn run_all(
    plan: &Plan,
    threads: usize,
    progress: impl Fn(&str) + Sync,
) -> Result<(Campaign, Vec<Vec<Period>>), String> {
    let prefixes = parallel(threads, &plan.parts, healthy_prefix);
    let prefixes: Vec<Prefix> = prefixes.into_iter().collect::<Result<_, _>>()?;
    if prefixes.len() != plan.parts.len() {
        return Err("a healthy run did not finish".into());
    }
    let tasks: Vec<(usize, &Case)> =
        plan.parts.iter().enumerate().flat_map(|(i, p)| p.cases.iter().map(move |c| (i, c))).collect();
    let runs = parallel(threads, &tasks, |&(i, case)| {
        let part = &plan.parts[i];
        let r = match run_case(part, case, &prefixes[i]) {
            Ok(r) => r,
            Err(e) => (CaseResult::unmet(part, case, format!("not run: {e}")), Vec::new()),
        };
        progress(&case.name);
        r
    });
    if runs.len() != tasks.len() {
        return Err("a case did not finish".into());
    }
    let (out, logs): (Vec<CaseResult>, Vec<Vec<Period>>) = runs.into_iter().unzip();
    let campaign = Campaign {
        parts: plan.parts.iter().map(Part::describe).collect(),
        cases: out.len(),
        silent_failures: out.iter().filter(|r| r.silent_failure).count(),
        max_bridge_off_periods: out.iter().filter_map(|r| r.bridge_off_periods).max().unwrap_or(0),
        unmet: out.iter().filter(|r| !r.met).count(),
        results: out,
    };
    Ok((campaign, logs))
}

/// The campaign as a table, one section per part.
pub fn table(c: &Campaign) -> String {
    let width = c.results.iter().map(|r| r.name.len()).max().unwrap_or(4).max(4);
    let mut s = String::from("fault campaign\n");
    let mut part: Option<(&str, DriveKind)> = None;
    let mut part_index = 0;
    for r in &c.results {
        let this = (r.motor.as_str(), r.drive);
        if part != Some(this) {
            if part.is_some() {
                part_index += 1;
            }
            part = Some(this);
            s += &format!(
                "\n{}\n{:<width$} {:<36} {:<66} {:>8} {:>9} {:>7}  {}\n",
                c.parts.get(part_index).map_or("", String::as_str),
                "case",
                "expected",
                "happened",
                "off (T)",
                "lock err",
                "silent",
                "met"
            );
        }
        s += &format!(
            "{:<width$} {:<36} {:<66} {:>8} {:>8.1}° {:>7}  {}\n",
            r.name,
            r.expected,
            r.happened,
            r.bridge_off_periods.map_or("-".into(), |p| p.to_string()),
            r.locked_err_max_deg,
            if r.silent_failure { "YES" } else { "no" },
            if r.met { "yes" } else { "NO" }
        );
    }
    s += &format!(
        "\n{} cases, {} silent failures, bridge off within {} period(s) at most, {} unmet\n",
        c.cases, c.silent_failures, c.max_bridge_off_periods, c.unmet
    );
    s
}

/// Angle, speed, position (positioning), current and state around the injection.
pub fn figure(result: &CaseResult, log: &[Period]) -> crate::plot::Figure {
    use crate::plot::{Panel, Series, time_series_figure};
    let t: Vec<f64> = log.iter().map(|p| p.t_s).collect();
    let col = |f: &dyn Fn(&Period) -> f64| log.iter().map(f).collect::<Vec<f64>>();
    let mut panels = vec![
        Panel::new(
            "angle (deg el)",
            vec![
                Series::from_xy("theta (true)", &t, &col(&|p| wrap_angle(p.theta_rad).to_degrees())),
                Series::from_xy("theta_hat", &t, &col(&|p| p.theta_hat_rad.to_degrees())),
            ],
        ),
        Panel::new(
            "theta - theta_hat (deg el)",
            vec![
                Series::from_xy("error", &t, &col(&|p| err_deg(p))),
                Series::from_xy(
                    "error while locked",
                    &t,
                    &col(&|p| if p.locked { err_deg(p) } else { f64::NAN }),
                ),
            ],
        ),
        Panel::new(
            "speed (m/s)",
            vec![
                Series::from_xy("v (true)", &t, &col(&|p| p.v_m_per_s)),
                Series::from_xy("v_hat", &t, &col(&|p| p.v_hat_m_per_s)),
            ],
        ),
    ];
    if result.drive == DriveKind::Positioning {
        panels.push(Panel::new(
            "position (m)",
            vec![
                Series::from_xy("x (true)", &t, &col(&|p| p.x_m)),
                Series::from_xy("x_hat", &t, &col(&|p| p.x_hat_m)),
                Series::from_xy("x_ref", &t, &col(&|p| p.x_ref_m)),
            ],
        ));
    }
    panels.push(Panel::new(
        "current (A)",
        vec![
            Series::from_xy("max |i| (true)", &t, &col(&|p| p.i_true_max_a)),
            Series::from_xy("i_a read", &t, &col(&|p| p.i_meas_a[0])),
            Series::from_xy("i_b read", &t, &col(&|p| p.i_meas_a[1])),
        ],
    ));
    panels.push(Panel::new(
        "state (3 running, 4 fault, 5 reacquiring, 6 low speed); bridge on",
        vec![
            Series::from_xy("state", &t, &col(&|p| f64::from(p.state.code()))),
            Series::from_xy("bridge on", &t, &col(&|p| if p.bridge_on { 1.0 } else { 0.0 })),
        ],
    ));
    time_series_figure(format!("fault `{}`: {}", result.name, result.happened), panels)
}

// ---- The command.

/// What `dcfo faults` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// Print exactly one JSON object (the campaign) on stdout, on its last line.
    pub json: bool,
    /// Directory for `faults.json` and one figure per case (`CASE.png` / `CASE.svg`).
    pub out: std::path::PathBuf,
    /// A motor (file or preset) to run both drives' cases on, instead of the standard
    /// campaign ([`Plan::standard`]).
    pub motor: Option<String>,
}

/// The plan `params` asks for: [`Plan::standard`], or [`Plan::for_motor`] on the motor
/// file, which must give `mass_kg` (the positioning drive is tuned on it).
pub fn plan_for(params: &Params) -> anyhow::Result<Plan> {
    let Some(arg) = &params.motor else {
        return Plan::standard().map_err(|e| anyhow::anyhow!(e));
    };
    let motor = crate::motor_file::load_motor(arg)?;
    if motor.defaulted.contains(&"mass_kg") {
        anyhow::bail!(
            "motor file {arg}: key `mass_kg` is required by the positioning drive's cases (its speed \
             loop, acceleration feed-forward and low-speed damping are tuned on the moving mass)"
        );
    }
    Ok(Plan::for_motor(&Bench::for_motor(&motor.name, &motor.params)))
}

/// `dcfo faults`: the fault campaign on every core, its results in `params.out` and the
/// table (or JSON) on stdout. Exit status 1 when a floor is missed (a silent failure, a
/// bridge switched off later than one period after its fault's condition); cases that
/// miss their stated expectation are counted as `unmet`.
pub fn run_command(params: &Params) -> anyhow::Result<std::process::ExitCode> {
    use anyhow::Context;
    let plan = plan_for(params)?;
    let started = std::time::Instant::now();
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    let (campaign, logs) =
        run_all(&plan, threads, |name| eprintln!("faults: {name} done")).map_err(|e| anyhow::anyhow!(e))?;
    let out = &params.out;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(out.join("faults.json"), serde_json::to_string_pretty(&campaign)?)
        .with_context(|| format!("writing {}", out.join("faults.json").display()))?;
    for (r, log) in campaign.results.iter().zip(&logs) {
        if !log.is_empty() {
            crate::plot::write_figure(&figure(r, log), &out.join(&r.name))?;
        }
    }
    eprintln!("faults: {:.1} s; results in {}", started.elapsed().as_secs_f64(), out.display());
    if params.json {
        println!("{}", serde_json::to_string(&campaign)?);
    } else {
        print!("{}", table(&campaign));
    }
    // The floors: no silent failure, the bridge off within one period on every trip.
    let floors = campaign.silent_failures == 0 && campaign.max_bridge_off_periods <= 1;
    Ok(if floors { std::process::ExitCode::SUCCESS } else { std::process::ExitCode::FAILURE })
}

#[cfg(test)]
mod tests {
    use super::*;
    use dcfo::algorithms::observer::ObserverKind;

    /// The speed drive's axis of any motor file is the paper axis's for that motor: for
    /// the paper motor it is `dcfo paper`'s plant and drive (the firmware's settings) but
    /// for the bus the drive is told, the simulated inverter's 220 V times sqrt(2) instead
    /// of `PAPER_AXIS_BUS_V` rounded to 311.127 V.
    #[test]
    fn a_motor_files_speed_axis_is_the_paper_axis_for_the_paper_motor() {
        let generic = Bench::for_motor("paper", &MotorParams::paper()).speed;
        let paper = Setup::paper(ObserverKind::Dcfo);
        assert_eq!(generic.plant, paper.plant);
        assert_eq!(generic.motor, paper.motor);
        let bus_ratio = f64::from(dcfo::drive::PAPER_AXIS_BUS_V) / paper.plant.inverter.dc_bus_v;
        assert!((bus_ratio - 1.0).abs() < 1e-6, "{bus_ratio}");
        let mut drive = generic.drive;
        drive.faults.bus_min_v = paper.drive.faults.bus_min_v;
        drive.faults.bus_max_v = paper.drive.faults.bus_max_v;
        assert_eq!(drive, paper.drive);
        assert_eq!(Bench::paper().speed.drive, paper.drive);
        assert_eq!(Bench::paper().speed_m_per_s(), 0.3);
    }

    /// The standard campaign's case names are unique (they name the figures' files), and
    /// it has at least 32 cases, positioning ones on a salient and a non-salient motor.
    #[test]
    fn the_standard_plan_has_unique_names_and_both_kinds_of_motor() {
        let plan = Plan::standard().expect("plan");
        let names: std::collections::BTreeSet<&str> = plan.cases().map(|(_, c)| c.name.as_str()).collect();
        assert_eq!(names.len(), plan.cases().count());
        assert!(names.len() >= 32, "{} cases", names.len());
        let hfi: Vec<bool> = plan
            .parts
            .iter()
            .filter(|p| p.drive == DriveKind::Positioning)
            .map(|p| p.bench.levels().hfi)
            .collect();
        assert_eq!(hfi, [false, true]);
    }
}
