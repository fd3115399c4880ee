//! `dcfo faults`: the fault campaign. Each case injects one fault into the closed-loop
//! simulation of the paper axis running at 0.3 m/s (the drive of `dcfo paper`,
//! `Drive<f32>` as the firmware runs it, in process or behind the firmware's link
//! server) and checks the reaction the design promises, stated before measuring:
//!
//! - **trip**: a named fault latched and the bridge off within one PWM period of the
//!   first sample that shows the fault's condition (the one-period computation delay of
//!   the simulation: the duties of step `k` apply from `t_{k+1}`);
//! - **ride-through**: no fault, and the angle error over the last [`STEADY_WINDOW_S`] of
//!   the run within the stated bound.
//!
//! For every case it also looks for a *silent failure*: the estimate reported as locked
//! while more than [`SILENT_ERROR_DEG`] off the plant's true angle for more than
//! [`SILENT_TIME_S`] in a row.
//!
//! The bridge-off latency is counted from the first period whose sample meets the
//! latched fault's condition, computed here independently of the drive from the
//! readings it was given (a phase current beyond the trip level, a bus reading outside
//! its limits, a non-finite reading, the watchdog's count of periods without a frame);
//! for a fault the drive decides on its own state (`LOCK_LOST`), from the step that
//! latched it.

pub mod axis;

use crate::sim::report::fault_names;

use dcfo::drive::{Drive, DriveConfig, DriveState, Faults};
use dcfo::link::SILENT_LINK_PERIODS;
use dcfo::motor::MotorParams;
use dcfo::observer::ObserverKind;
use dcfo::units::Base;
use serde::Serialize;

pub use axis::{Axis, Injection, LinkChecks, Period};

use crate::sim::Setup;
use crate::trace::wrap_angle;

/// Speed the axis runs at when the fault comes, m/s.
pub const SPEED_M_PER_S: f64 = 0.3;
/// Injection time, s (the drive has handed over and settled by then).
pub const INJECT_S: f64 = 3.0;
/// Simulated time after the injection, s: longer than a lock loss plus the re-acquire
/// timeout (0.05 + 0.5 s).
pub const AFTER_S: f64 = 1.0;
/// A ride-through's accuracy is measured over the run's last this many seconds.
pub const STEADY_WINDOW_S: f64 = 0.5;
/// A silent failure: locked while wrong by more than this (electrical degrees)...
pub const SILENT_ERROR_DEG: f64 = 30.0;
/// ... for longer than this, s.
pub const SILENT_TIME_S: f64 = 0.05;

/// What the design promises for a case.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Expected {
    /// One of these faults latched, bridge off within one period.
    Trip(Faults),
    /// No fault; angle error over the last [`STEADY_WINDOW_S`] at most this, deg.
    RideThrough(f64),
}

/// One case of the campaign.
#[derive(Clone, Copy, Debug)]
pub struct Case {
    /// Short name (file names, the table).
    pub name: &'static str,
    /// The fault.
    pub injection: Injection,
    /// The reaction the design promises.
    pub expected: Expected,
    /// Why the design promises it.
    pub why: &'static str,
}

/// Every case, in the table's order.
pub fn cases() -> Vec<Case> {
    use Expected::*;
    use Injection::*;
    vec![
        Case {
            name: "open-phase",
            injection: OpenPhase,
            expected: Trip(Faults::CURRENT_CONTROL),
            why: "phase a carries no current whatever the loops apply: the voltage goes to its limit with the current off its reference (5 ms)",
        },
        Case {
            name: "phase-short",
            injection: PhaseShort,
            expected: Trip(Faults::OVER_CURRENT),
            why: "the short's current exceeds the 8.9 A trip level within a period",
        },
        Case {
            name: "sensor-stuck",
            injection: SensorStuck,
            expected: Trip(Faults::CURRENT_CONTROL),
            why: "the loops chase a reading that does not move: the voltage goes to its limit with the read current off its reference (5 ms)",
        },
        Case {
            name: "adc-saturated",
            injection: AdcSaturated,
            expected: Trip(Faults::OVER_CURRENT),
            why: "full scale (10 A) is above the 8.9 A trip level",
        },
        Case {
            name: "adc-nan",
            injection: AdcNan,
            expected: Trip(Faults::NON_FINITE),
            why: "every reading is checked for NaN/inf before use",
        },
        Case {
            name: "bus-sag-60%",
            injection: Bus(0.6),
            expected: Trip(Faults::BUS_UNDER_VOLTAGE),
            why: "at the 60 % limit: the 1 % (3.1 V) ripple's trough reads 185.9 V < 186.7 V (first expected a ride-through, forgetting the ripple)",
        },
        Case {
            name: "bus-sag-65%",
            injection: Bus(0.65),
            expected: RideThrough(5.0),
            why: "the reading stays above the 60 % limit; at 0.3 m/s the back-EMF needs 20 V of the 114 V left",
        },
        Case {
            name: "bus-over-140%",
            injection: Bus(1.4),
            expected: Trip(Faults::BUS_OVER_VOLTAGE),
            why: "above the 130 % limit",
        },
        Case {
            name: "bus-loss",
            injection: Bus(0.0),
            expected: Trip(Faults::BUS_UNDER_VOLTAGE),
            why: "below the 60 % limit",
        },
        Case {
            name: "blocked-mover",
            injection: Blocked,
            expected: Trip(Faults::LOCK_LOST),
            why: "no back-EMF: the estimate stops tracking, Reacquiring (no thrust), LOCK_LOST after 0.5 s",
        },
        Case {
            name: "load-200N",
            injection: Load(200.0),
            expected: RideThrough(10.0),
            why: "two thirds of the 299 N at the current limit: the speed loop holds it below the limit, no OVERLOAD",
        },
        Case {
            name: "load-400N",
            injection: Load(400.0),
            expected: Trip(Faults::OVERLOAD),
            why: "beyond the 299 N at the current limit: the mover stops and is pushed back while the speed loop pushes on the limit; OVERLOAD after 0.1 s there, not a flying restart into the same load",
        },
        Case {
            name: "lock-loss",
            injection: EstimatorReset,
            expected: RideThrough(5.0),
            why: "flying restart: Reacquiring with zero current, Running again within 0.1 s",
        },
        Case {
            name: "silent-link",
            injection: LinkSilent,
            expected: Trip(Faults::EXTERNAL),
            why: "the link watchdog trips an active drive after 10 periods without a frame",
        },
        Case {
            name: "corrupted-frames",
            injection: LinkCorrupt { every: 20 },
            expected: RideThrough(5.0),
            why: "CRC-16 rejects every corrupted frame; a dropped period repeats the duties, and the next frame's sequence number tells the drive to integrate it; no 10 in a row",
        },
        Case {
            name: "replayed-frames",
            injection: LinkReplay { every: 7, age: 5 },
            expected: RideThrough(5.0),
            why: "a duplicate is answered with the same bytes without a second step; an old frame is counted and ignored",
        },
        Case {
            name: "R-x2",
            injection: PlantRs(2.0),
            expected: RideThrough(10.0),
            why: "the DCFO removes the DC part of the error; the paper's R = 2 Rs case reaches 7.5 deg",
        },
        Case {
            name: "file-R+30%",
            injection: MotorFile { rs: 1.3, l: 1.0, psi_f: 1.0 },
            expected: RideThrough(10.0),
            why: "a resistance error under light load is a small back-EMF error (dR i / (w psi_f))",
        },
        Case {
            name: "file-R-30%",
            injection: MotorFile { rs: 0.7, l: 1.0, psi_f: 1.0 },
            expected: RideThrough(10.0),
            why: "as R +30 %",
        },
        Case {
            name: "file-L+30%",
            injection: MotorFile { rs: 1.0, l: 1.3, psi_f: 1.0 },
            expected: RideThrough(10.0),
            why: "the observer subtracts L i: an error of dL i / psi_f rad (0.3 x 8.5 mH x 1 A / 0.16 Wb: 1 deg)",
        },
        Case {
            name: "file-L-30%",
            injection: MotorFile { rs: 1.0, l: 0.7, psi_f: 1.0 },
            expected: RideThrough(10.0),
            why: "as L +30 %",
        },
        Case {
            name: "file-psi+30%",
            injection: MotorFile { rs: 1.0, l: 1.0, psi_f: 1.3 },
            expected: RideThrough(10.0),
            why: "the angle does not depend on psi_f; the speed loop's gain and the decoupling feed-forward do",
        },
        Case {
            name: "file-psi-30%",
            injection: MotorFile { rs: 1.0, l: 1.0, psi_f: 0.7 },
            expected: RideThrough(10.0),
            why: "as psi_f +30 %",
        },
    ]
}

/// What one case did.
#[derive(Clone, Debug, Serialize)]
pub struct CaseResult {
    /// The case's name.
    pub name: String,
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
    /// Largest angle error over the last [`STEADY_WINDOW_S`] (ride-throughs), deg.
    pub steady_err_deg: Option<f64>,
    /// Largest angle error while reported locked after the injection, deg.
    pub locked_err_max_deg: f64,
    /// Longest time reported locked while off by more than [`SILENT_ERROR_DEG`], s.
    pub locked_wrong_s: f64,
    /// A silent failure happened.
    pub silent_failure: bool,
    /// Largest true phase current after the injection, A.
    pub i_peak_a: f64,
    /// Link-fault counts (link cases only).
    pub link: Option<LinkChecks>,
    /// The case met its expectation (and the floors).
    pub met: bool,
}

/// The campaign's result.
#[derive(Clone, Debug, Serialize)]
pub struct Campaign {
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

/// The paper axis the cases run on.
pub fn setup() -> Setup {
    Setup::paper(ObserverKind::Dcfo)
}

fn describe(e: Expected) -> String {
    match e {
        Expected::Trip(f) => format!("trip {} <= 1 period", fault_names(f)),
        Expected::RideThrough(deg) => format!("ride through, <= {deg} deg"),
    }
}

/// The drive's motor file for `injection` (the plant keeps the true motor).
fn drive_motor(setup: &Setup, injection: Injection) -> MotorParams {
    let mut m = setup.motor;
    if let Injection::MotorFile { rs, l, psi_f } = injection {
        m.rs_ohm *= rs as f32;
        m.ld_h *= l as f32;
        m.lq_h *= l as f32;
        m.psi_f_wb *= psi_f as f32;
    }
    m
}

/// A fresh axis for `injection` (its from-the-start part applied).
fn fresh_axis(setup: &Setup, injection: Option<Injection>) -> Result<Axis, String> {
    let mut sim = setup.plant;
    if let Some(Injection::PlantRs(k)) = injection {
        sim.plant.rs_ohm *= k;
    }
    let motor = injection.map_or(setup.motor, |i| drive_motor(setup, i));
    let config: DriveConfig = setup.drive;
    let drive = Drive::<f32>::new(&motor, &config, &Base::SI).map_err(|e| format!("drive: {e}"))?;
    Axis::new(&sim, drive, SPEED_M_PER_S, false).map_err(|e| e.to_string())
}

/// Runs `axis` for `periods`, appending to `log`.
fn run_for(axis: &mut Axis, periods: usize, log: &mut Vec<Period>) {
    for _ in 0..periods {
        log.push(axis.period());
    }
}

/// The healthy axis up to the injection time and its log (shared by the cases that
/// inject later).
pub fn healthy_prefix(setup: &Setup) -> Result<(Axis, Vec<Period>), String> {
    let mut axis = fresh_axis(setup, None)?;
    let n = (INJECT_S / axis.plant().pwm_period_s()).round() as usize;
    let mut log = Vec::with_capacity(n);
    run_for(&mut axis, n, &mut log);
    Ok((axis, log))
}

/// Runs `case`: from `prefix` (a clone of the healthy axis at the injection time) or,
/// for a fault present from the start, from scratch. Returns the result and the log
/// from 0.5 s before the injection on.
pub fn run_case(
    setup: &Setup,
    case: &Case,
    prefix: &(Axis, Vec<Period>),
) -> Result<(CaseResult, Vec<Period>), String> {
    let ts = prefix.0.plant().pwm_period_s();
    let n_inject = (INJECT_S / ts).round() as usize;
    let (mut axis, mut log) = if case.injection.from_start() {
        let mut axis = fresh_axis(setup, Some(case.injection))?;
        let mut log = Vec::with_capacity(n_inject);
        run_for(&mut axis, n_inject, &mut log);
        (axis, log)
    } else {
        let (axis, log) = prefix;
        let mut axis = axis.clone();
        axis.inject(case.injection).map_err(|e| e.to_string())?;
        (axis, log.clone())
    };
    run_for(&mut axis, (AFTER_S / ts).round() as usize, &mut log);
    let result = analyse(setup, case, &log, n_inject, &axis);
    let keep = n_inject.saturating_sub((0.5 / ts) as usize);
    Ok((result, log.split_off(keep)))
}

/// The angle error of a period, deg (NaN without an estimate).
pub fn err_deg(p: &Period) -> f64 {
    wrap_angle(p.theta_rad - p.theta_hat_rad).to_degrees()
}

/// The figures of one case from its log (`k0`: the injection's period).
fn analyse(setup: &Setup, case: &Case, log: &[Period], k0: usize, axis: &Axis) -> CaseResult {
    let ts = axis.plant().pwm_period_s();
    let limits = &setup.drive.faults;
    // Silent failure: over the whole run (start-up included).
    let (mut run, mut longest) = (0usize, 0usize);
    let mut locked_err_max = 0.0f64;
    for (k, p) in log.iter().enumerate() {
        let e = err_deg(p).abs();
        if p.locked && e > SILENT_ERROR_DEG {
            run += 1;
            longest = longest.max(run);
        } else {
            run = 0;
        }
        if k >= k0 && p.locked && e.is_finite() {
            locked_err_max = locked_err_max.max(e);
        }
    }
    let locked_wrong_s = longest as f64 * ts;
    let silent = locked_wrong_s > SILENT_TIME_S;
    let after = &log[k0.min(log.len())..];
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
    let steady = if final_faults.is_empty() {
        // Periods without an answer (a dropped link frame) have no estimate.
        Some(tail.iter().filter(|p| p.answered).map(|p| err_deg(p).abs()).fold(0.0, f64::max))
    } else {
        None
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
        };
    let last_state = log.last().map_or(DriveState::Disabled, |p| p.state);
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
        (None, None) => format!("{last_state:?}"),
    };
    CaseResult {
        name: case.name.into(),
        expected: describe(case.expected),
        why: case.why.into(),
        happened,
        faults: fault_names(final_faults),
        detect_s,
        bridge_off_periods,
        steady_err_deg: steady,
        locked_err_max_deg: locked_err_max,
        locked_wrong_s,
        silent_failure: silent,
        i_peak_a: i_peak,
        link,
        met,
    }
}

/// A case's result and its log, or why it could not run.
type CaseRun = Result<(CaseResult, Vec<Period>), String>;

/// Runs every case (on `threads` threads), calling `progress(name)` as each ends.
/// Returns the campaign and each case's log.
pub fn run_all(
    threads: usize,
    progress: impl Fn(&str) + Sync,
) -> Result<(Campaign, Vec<Vec<Period>>), String> {
    let setup = setup();
    let prefix = healthy_prefix(&setup)?;
    let cases = cases();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut slots: Vec<Option<CaseRun>> = vec![None; cases.len()];
    let results = std::sync::Mutex::new(&mut slots);
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(case) = cases.get(i) else { break };
                    let r = run_case(&setup, case, &prefix);
                    progress(case.name);
                    if let Ok(mut slots) = results.lock() {
                        slots[i] = Some(r);
                    }
                }
            });
        }
    });
    let mut out = Vec::new();
    let mut logs = Vec::new();
    for (slot, case) in slots.into_iter().zip(&cases) {
        let (r, log) = slot.ok_or_else(|| format!("{}: not run", case.name))??;
        out.push(r);
        logs.push(log);
    }
    let campaign = Campaign {
        cases: out.len(),
        silent_failures: out.iter().filter(|r| r.silent_failure).count(),
        max_bridge_off_periods: out.iter().filter_map(|r| r.bridge_off_periods).max().unwrap_or(0),
        unmet: out.iter().filter(|r| !r.met).count(),
        results: out,
    };
    Ok((campaign, logs))
}

/// The campaign as a table.
pub fn table(c: &Campaign) -> String {
    let mut s = format!(
        "fault campaign: paper axis at {SPEED_M_PER_S} m/s, fault at {INJECT_S} s, {AFTER_S} s after\n{:<17} {:<36} {:<62} {:>8} {:>9} {:>7}  {}\n",
        "case", "expected", "happened", "off (T)", "lock err", "silent", "met"
    );
    for r in &c.results {
        s += &format!(
            "{:<17} {:<36} {:<62} {:>8} {:>8.1}° {:>7}  {}\n",
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
        "{} cases, {} silent failures, bridge off within {} period(s) at most, {} unmet\n",
        c.cases, c.silent_failures, c.max_bridge_off_periods, c.unmet
    );
    s
}

/// Angle, speed, current and state around the injection.
pub fn figure(result: &CaseResult, log: &[Period]) -> crate::plot::Figure {
    use crate::plot::{Panel, Series, time_series_figure};
    let t: Vec<f64> = log.iter().map(|p| p.t_s).collect();
    let col = |f: &dyn Fn(&Period) -> f64| log.iter().map(f).collect::<Vec<f64>>();
    time_series_figure(
        format!("fault `{}`: {}", result.name, result.happened),
        vec![
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
            Panel::new("speed (m/s)", vec![Series::from_xy("v (true)", &t, &col(&|p| p.v_m_per_s))]),
            Panel::new(
                "current (A)",
                vec![
                    Series::from_xy("max |i| (true)", &t, &col(&|p| p.i_true_max_a)),
                    Series::from_xy("i_a read", &t, &col(&|p| p.i_meas_a[0])),
                    Series::from_xy("i_b read", &t, &col(&|p| p.i_meas_a[1])),
                ],
            ),
            Panel::new(
                "state (3 running, 4 fault, 5 reacquiring); bridge on",
                vec![
                    Series::from_xy("state", &t, &col(&|p| f64::from(p.state.code()))),
                    Series::from_xy("bridge on", &t, &col(&|p| if p.bridge_on { 1.0 } else { 0.0 })),
                ],
            ),
        ],
    )
}

// ---- The command.

/// What `dcfo faults` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// Print exactly one JSON object (the campaign) on stdout, on its last line.
    pub json: bool,
    /// Directory for `faults.json` and one figure per case (`CASE.png` / `CASE.svg`).
    pub out: std::path::PathBuf,
}

/// `dcfo faults`: the fault campaign on every core, its results in `params.out` and the
/// table (or JSON) on stdout. Exit status 1 when a floor is missed (a silent failure, a
/// bridge switched off later than one period after its fault's condition); cases that
/// miss their stated expectation are counted as `unmet`.
pub fn run_command(params: &Params) -> anyhow::Result<std::process::ExitCode> {
    use anyhow::Context;
    let started = std::time::Instant::now();
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    let (campaign, logs) =
        run_all(threads, |name| eprintln!("faults: {name} done")).map_err(|e| anyhow::anyhow!(e))?;
    let out = &params.out;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(out.join("faults.json"), serde_json::to_string_pretty(&campaign)?)
        .with_context(|| format!("writing {}", out.join("faults.json").display()))?;
    for (r, log) in campaign.results.iter().zip(&logs) {
        crate::plot::write_figure(&figure(r, log), &out.join(&r.name))?;
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
