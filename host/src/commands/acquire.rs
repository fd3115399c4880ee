//! `dcfo acquire`: how fast the estimator finds a mover that is already moving.
//!
//! For each speed and direction the simulated axis (inverter with dead time and drops,
//! sensors with offsets, gain errors, noise and quantisation) is held at that speed by
//! the load machine (the plant's speed clamp) while a *sensored* current controller on
//! the plant's true angle drives the thrust current of a 10 N load, with the drive's
//! dead-time compensation; what it commands (less the compensation) and measures is the
//! trace, as a recording that starts mid-motion would hold it ([`crate::recorder`] at a
//! [`ConstantSpeed`]). The recorder does not depend on the estimator under test, and the
//! speed is exact. A fresh estimator
//! (zero state, not told the speed) is then started on that trace at eight instants a
//! pole pitch apart in eighths (eight initial mover angles), with and without a
//! constant +0.2 A on `i_beta` or +2 V on `u_alpha` present from its first sample, in
//! f32 and in Q8.24 per-unit.
//!
//! Per start: the **lock time** is the time after which `|theta - theta_hat| < 5 deg`
//! holds to the end of the window (issue floor: within `max(60 ms, 2 electrical
//! periods)`), and a **false lock** is any sample where the estimator's `locked` flag is
//! set while the true error exceeds 15 deg.

use dcfo::motor::MotorParams;
use dcfo::num::units::Base;
use dcfo::num::{Q24, Scalar};
use serde::Serialize;

use crate::recorder::{ConstantSpeed, Row, omega_e, record, replay};
use crate::simulation::Setup;
use crate::simulation::scenarios::PaperScale;
use crate::trace::wrap_angle;

/// Lock criterion: the error stays below this from the lock time on, electrical degrees.
pub const LOCK_DEG: f64 = 5.0;
/// A `locked` flag with a true error above this is a false lock, electrical degrees.
pub const FALSE_LOCK_DEG: f64 = 15.0;
/// Load on the paper axis while the trace is recorded, opposing the motion, N: a light
/// load, 6.7 % of the paper motor's rated thrust (0.2 A of thrust current).
pub const LOAD_N: f64 = 10.0;

/// Load while the trace is recorded on `motor`, N: the same share of its rated thrust
/// as [`LOAD_N`] is of the paper motor's ([`LOAD_N`] itself on the paper motor).
pub fn recording_load_n(motor: &MotorParams) -> f64 {
    LOAD_N * PaperScale::for_motor(motor).thrust
}

/// Disturbance present in the estimator's inputs from its first sample. The issue's
/// values are for the paper motor; on another motor they scale with its rated values
/// ([`Offset::values_for`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Offset {
    /// None beyond the sensors' own.
    None,
    /// +0.2 A on `i_beta` (paper motor): 6.7 % of its rated peak current.
    CurrentBeta,
    /// +2 V on `u_alpha` (paper motor): 0.64 % of its 311 V bus (`sqrt(2)` times its
    /// rated voltage).
    VoltageAlpha,
}

impl Offset {
    /// All variants.
    pub const ALL: [Offset; 3] = [Offset::None, Offset::CurrentBeta, Offset::VoltageAlpha];

    /// (u offset V, i offset A), alpha-beta, on the paper motor.
    fn values(self) -> ([f64; 2], [f64; 2]) {
        match self {
            Offset::None => ([0.0; 2], [0.0; 2]),
            Offset::CurrentBeta => ([0.0; 2], [0.0, 0.2]),
            Offset::VoltageAlpha => ([2.0, 0.0], [0.0; 2]),
        }
    }

    /// (u offset V, i offset A), alpha-beta, on `motor`: the paper motor's values scaled
    /// by its rated voltage and rated current over the paper motor's (a voltage error
    /// scales with the bus it is a share of, a current sensor's offset with its full
    /// scale); on the paper motor exactly the values. A 48 V motor thus gets
    /// 0.44 V, not the 2 V that would be 4 % of its bus.
    pub fn values_for(self, motor: &MotorParams) -> ([f64; 2], [f64; 2]) {
        let scale = PaperScale::for_motor(motor);
        let (u, i) = self.values();
        (u.map(|x| x * scale.voltage), i.map(|x| x * scale.current))
    }

    /// Short label.
    pub fn label(self) -> &'static str {
        match self {
            Offset::None => "none",
            Offset::CurrentBeta => "+0.2 A",
            Offset::VoltageAlpha => "+2 V",
        }
    }
}

/// What to sweep.
#[derive(Clone, Debug)]
pub struct Options {
    /// Speeds, m/s (positive; each is run in both directions).
    pub speeds_m_per_s: Vec<f64>,
    /// Start instants per speed, spread over one electrical period.
    pub positions: usize,
    /// Offsets to run.
    pub offsets: Vec<Offset>,
    /// Also run the Q8.24 estimator and compare it with f32.
    pub fixed_point: bool,
}

impl Options {
    /// The benchmark's speeds on the paper motor, m/s: 0.1 to 2.0 m/s, 3.3 to 67 Hz.
    pub const PAPER_SPEEDS_M_PER_S: [f64; 12] =
        [0.1, 0.15, 0.2, 0.3, 0.42, 0.6, 0.8, 1.0, 1.2, 1.5, 1.75, 2.0];

    /// The benchmark's sweep: 12 speeds from 0.1 to 2.0 m/s, 8 positions, all offsets,
    /// fixed point included.
    pub fn full() -> Self {
        Options {
            speeds_m_per_s: Self::PAPER_SPEEDS_M_PER_S.to_vec(),
            positions: 8,
            offsets: Offset::ALL.to_vec(),
            fixed_point: true,
        }
    }

    /// The same sweep on `motor`: the benchmark's electrical frequencies (3.3 to 67 Hz),
    /// so speeds scaled by its pole pitch over the paper motor's.
    pub fn full_for(motor: &MotorParams) -> Self {
        let scale = PaperScale::for_motor(motor).speed;
        Options {
            speeds_m_per_s: Self::PAPER_SPEEDS_M_PER_S.iter().map(|v| v * scale).collect(),
            ..Self::full()
        }
    }
}

/// One cold start.
#[derive(Clone, Debug, Serialize)]
pub struct Start {
    /// Signed speed, m/s.
    pub speed_m_per_s: f64,
    /// Electrical frequency, Hz.
    pub electrical_hz: f64,
    /// Position index (0..positions).
    pub position: usize,
    /// Offset present from the start.
    pub offset: Offset,
    /// Time to lock, s (`None`: not locked by the end of the window).
    pub lock_time_s: Option<f64>,
    /// The budget, `max(60 ms, 2 electrical periods)`, s.
    pub budget_s: f64,
    /// Samples with the lock flag set and the true error above 15 degrees.
    pub false_lock_samples: usize,
    /// When the lock flag was first set, s (`None`: never).
    pub flag_time_s: Option<f64>,
    /// Largest |theta_q24 - theta_f32| after the later of the f32 and Q8.24 lock times
    /// (the f32 one if Q8.24 never locks), degrees (`None` if not run or f32 never
    /// locks).
    pub q24_deviation_deg: Option<f64>,
    /// Lock time of the Q8.24 estimator, s.
    pub q24_lock_time_s: Option<f64>,
    /// The inverter's voltage error along the mover flux (d axis, true angle), mean over
    /// the recording, V: what the drive's dead-time compensation leaves (0 on an ideal
    /// inverter).
    pub inverter_error_d_v: f64,
    /// The steady angle error that error alone gives the estimator, `-dU_d / (w_e
    /// psi_f)`, degrees (as `theta - theta_hat`): the DCFO passes the fundamental with
    /// unity gain and zero phase, so a voltage error turns the flux by `dU / (j w)`.
    pub inverter_bias_deg: f64,
    /// Mean of `theta - theta_hat` over the second half of the window, degrees (`None`
    /// unless locked by then).
    pub steady_error_mean_deg: Option<f64>,
}

impl Start {
    /// Locked within its budget.
    pub fn within_budget(&self) -> bool {
        self.lock_time_s.is_some_and(|t| t <= self.budget_s)
    }
}

/// Electrical frequency of `v` (m/s) on `motor`, Hz.
pub fn electrical_hz(motor: &MotorParams, v: f64) -> f64 {
    v.abs() / (2.0 * f64::from(motor.pole_pitch_m))
}

/// The lock budget at `v`: `max(60 ms, 2 electrical periods)`, s.
pub fn budget_s(motor: &MotorParams, v: f64) -> f64 {
    (2.0 / electrical_hz(motor, v)).max(0.06)
}

/// Runs a fresh estimator over `rows` with `offset` added ([`replay`]); returns the
/// angle estimates (rad) and lock flags, and the first sample after its circle fit
/// ended.
fn cold_run<T: Scalar>(
    setup: &Setup,
    base: &Base,
    rows: &[Row],
    ts: f64,
    offset: Offset,
) -> Result<(Vec<(f64, bool)>, usize), String> {
    let (du, di) = offset.values_for(&setup.motor);
    replay::<T>(setup, base, rows, ts, du, di)
}

/// Lock time (s) of `estimates` against the truth of `samples`: the time after which
/// the error stays below [`LOCK_DEG`]; `None` if the last sample is still outside.
fn lock_time(rows: &[Row], estimates: &[(f64, bool)], dt: f64) -> Option<f64> {
    let mut last_bad = None;
    for (j, (r, e)) in rows.iter().zip(estimates).enumerate() {
        let err = wrap_angle(r.theta - e.0).to_degrees();
        if err.abs().is_nan() || err.abs() >= LOCK_DEG {
            last_bad = Some(j);
        }
    }
    match last_bad {
        None => Some(0.0),
        Some(j) if j + 1 < rows.len() => Some((j + 1) as f64 * dt),
        Some(_) => None,
    }
}

/// All cold starts at one signed speed.
fn starts_at(setup: &Setup, v: f64, options: &Options) -> Result<Vec<Start>, String> {
    let motor = &setup.motor;
    let budget = budget_s(motor, v);
    // The window shows that the lock holds: at least 0.3 s and three budgets.
    let window = (3.0 * budget).max(budget + 0.3);
    let dt = setup.plant.inverter.pwm_period_s;
    let pu = Base::for_motor(motor);
    let mut starts = Vec::new();
    for position in 0..options.positions {
        // Eight mover positions spread over a pole pair (one electrical period).
        let x0 = 2.0 * f64::from(motor.pole_pitch_m) * position as f64 / options.positions as f64;
        let rows = record(setup, &ConstantSpeed(v), x0, recording_load_n(motor), window)
            .map_err(|e| format!("{v} m/s: {e}"))?;
        let inverter_error_d_v = rows
            .iter()
            .map(|r| {
                let e = [r.u_actual[0] - r.u[0], r.u_actual[1] - r.u[1]];
                e[0] * r.theta.cos() + e[1] * r.theta.sin()
            })
            .sum::<f64>()
            / rows.len().max(1) as f64;
        let inverter_bias_deg =
            (-inverter_error_d_v / (omega_e(motor, v) * f64::from(motor.psi_f_wb))).to_degrees();
        for &offset in &options.offsets {
            let (f, f_fit_end) = cold_run::<f32>(setup, &Base::SI, &rows, dt, offset)?;
            let lock = lock_time(&rows, &f, dt);
            let false_lock_samples = rows
                .iter()
                .zip(&f)
                .filter(|(r, e)| e.1 && wrap_angle(r.theta - e.0).to_degrees().abs() > FALSE_LOCK_DEG)
                .count();
            let flag_time_s = f.iter().position(|e| e.1).map(|j| j as f64 * dt);
            let half = rows.len() / 2;
            let steady_error_mean_deg = lock.filter(|&t| t <= half as f64 * dt).map(|_| {
                rows[half..]
                    .iter()
                    .zip(&f[half..])
                    .map(|(r, e)| wrap_angle(r.theta - e.0).to_degrees())
                    .sum::<f64>()
                    / (rows.len() - half).max(1) as f64
            });
            let (q24_deviation_deg, q24_lock_time_s) = if options.fixed_point {
                let (q, q_fit_end) = cold_run::<Q24>(setup, &pu, &rows, dt, offset)?;
                let q_lock = lock_time(&rows, &q, dt);
                // From the later of the two lock times and the two ends of the circle
                // fit: the two arithmetics may seed a sample apart (the circle fit's
                // test crosses its threshold a sample later in one), and before its own
                // lock and its seed an estimator's angle is its acquisition, not its
                // numerics (an unseeded estimate may pass within 5 deg on its way); the
                // lock times are reported apart. A Q8.24 run that never locks is
                // measured from the f32 lock.
                let fit_end = f_fit_end.max(q_fit_end);
                let from = lock.map(|t| ((t.max(q_lock.unwrap_or(t)) / dt).round() as usize).max(fit_end));
                let dev = from.map(|j0| {
                    f[j0.min(f.len())..]
                        .iter()
                        .zip(&q[j0.min(q.len())..])
                        .map(|(a, b)| wrap_angle(a.0 - b.0).to_degrees().abs())
                        .fold(0.0, f64::max)
                });
                (dev, q_lock)
            } else {
                (None, None)
            };
            starts.push(Start {
                speed_m_per_s: v,
                electrical_hz: electrical_hz(motor, v),
                position,
                offset,
                lock_time_s: lock,
                budget_s: budget,
                false_lock_samples,
                flag_time_s,
                q24_deviation_deg,
                q24_lock_time_s,
                inverter_error_d_v,
                inverter_bias_deg,
                steady_error_mean_deg,
            });
        }
    }
    Ok(starts)
}

/// Runs the sweep on `setup` (both directions of every speed), two speeds at a time,
/// calling `progress(done, total)` after each.
pub fn sweep(
    setup: &Setup,
    options: &Options,
    progress: impl Fn(usize, usize) + Sync,
) -> Result<Vec<Start>, String> {
    let speeds: Vec<f64> = options.speeds_m_per_s.iter().flat_map(|&v| [v, -v]).collect();
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1).min(speeds.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let done = std::sync::atomic::AtomicUsize::new(0);
    let results = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| {
                loop {
                    let j = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some(&v) = speeds.get(j) else { break };
                    let r = starts_at(setup, v, options);
                    results.lock().map(|mut g| g.push((j, r))).ok();
                    let d = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                    progress(d, speeds.len());
                }
            });
        }
    });
    let mut results = results.into_inner().map_err(|_| "a sweep thread panicked".to_string())?;
    results.sort_by_key(|(j, _)| *j);
    let mut all = Vec::new();
    for (_, r) in results {
        all.extend(r?);
    }
    Ok(all)
}

/// One row of the table: one signed speed, over its positions and offsets.
#[derive(Clone, Debug, Serialize)]
pub struct SpeedRow {
    /// Signed speed, m/s.
    pub speed_m_per_s: f64,
    /// Electrical frequency, Hz.
    pub electrical_hz: f64,
    /// Budget, s.
    pub budget_s: f64,
    /// Median lock time over the starts that locked, s.
    pub lock_time_median_s: Option<f64>,
    /// Largest lock time, s (`None` if a start never locked).
    pub lock_time_max_s: Option<f64>,
    /// Starts over the budget (or never locked).
    pub budget_violations: usize,
    /// Starts with a false lock.
    pub false_locks: usize,
    /// Largest Q8.24 deviation from f32 after lock, degrees.
    pub q24_deviation_max_deg: Option<f64>,
    /// Median over the recordings of the inverter's d-axis voltage error, V
    /// ([`Start::inverter_error_d_v`]; `None` for a row without starts).
    pub inverter_error_d_v: Option<f64>,
    /// Median of the steady angle error that error predicts, degrees
    /// ([`Start::inverter_bias_deg`]).
    pub inverter_bias_deg: Option<f64>,
    /// Median of the measured steady mean angle error of the starts that locked, degrees
    /// ([`Start::steady_error_mean_deg`]).
    pub steady_error_mean_deg: Option<f64>,
    /// Starts.
    pub runs: usize,
}

/// The sweep's totals, as `dcfo acquire --json` prints them.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// Cold starts run.
    pub runs: usize,
    /// Largest lock time over every start, s (`None` if any start never locked).
    pub lock_time_max_s: Option<f64>,
    /// Starts that did not lock within `max(60 ms, 2 electrical periods)`.
    pub lock_time_budget_violations: usize,
    /// Starts that never locked within their window.
    pub never_locked: usize,
    /// Starts in which `locked` was claimed with a true error above 15 degrees.
    pub false_locks: usize,
    /// Largest Q8.24 deviation from f32 after lock, degrees.
    pub q24_deviation_max_deg: Option<f64>,
    /// Per signed speed.
    pub speeds: Vec<SpeedRow>,
}

/// The median of `xs` (the upper one of an even count), `None` for none.
fn median(xs: impl Iterator<Item = f64>) -> Option<f64> {
    let mut v: Vec<f64> = xs.collect();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

fn max_opt(mut xs: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    xs.try_fold(0.0f64, |m, x| Some(m.max(x?)))
}

/// Totals and the per-speed table of `starts`.
pub fn summarise(starts: &[Start]) -> Summary {
    let mut speeds: Vec<f64> = Vec::new();
    for s in starts {
        if !speeds.contains(&s.speed_m_per_s) {
            speeds.push(s.speed_m_per_s);
        }
    }
    let rows = speeds
        .iter()
        .map(|&v| {
            let of: Vec<&Start> = starts.iter().filter(|s| s.speed_m_per_s == v).collect();
            let mut locked: Vec<f64> = of.iter().filter_map(|s| s.lock_time_s).collect();
            locked.sort_by(f64::total_cmp);
            SpeedRow {
                speed_m_per_s: v,
                electrical_hz: of.first().map(|s| s.electrical_hz).unwrap_or(0.0),
                budget_s: of.first().map(|s| s.budget_s).unwrap_or(0.0),
                lock_time_median_s: locked.get(locked.len() / 2).copied(),
                lock_time_max_s: max_opt(of.iter().map(|s| s.lock_time_s)),
                budget_violations: of.iter().filter(|s| !s.within_budget()).count(),
                false_locks: of.iter().filter(|s| s.false_lock_samples > 0).count(),
                q24_deviation_max_deg: of.iter().filter_map(|s| s.q24_deviation_deg).reduce(f64::max),
                inverter_error_d_v: median(of.iter().map(|s| s.inverter_error_d_v)),
                inverter_bias_deg: median(of.iter().map(|s| s.inverter_bias_deg)),
                steady_error_mean_deg: median(of.iter().filter_map(|s| s.steady_error_mean_deg)),
                runs: of.len(),
            }
        })
        .collect();
    Summary {
        runs: starts.len(),
        lock_time_max_s: max_opt(starts.iter().map(|s| s.lock_time_s)),
        lock_time_budget_violations: starts.iter().filter(|s| !s.within_budget()).count(),
        never_locked: starts.iter().filter(|s| s.lock_time_s.is_none()).count(),
        false_locks: starts.iter().filter(|s| s.false_lock_samples > 0).count(),
        q24_deviation_max_deg: starts.iter().filter_map(|s| s.q24_deviation_deg).reduce(f64::max),
        speeds: rows,
    }
}

/// The table as text: times in ms; the inverter's d-axis voltage error (V), the steady
/// angle error it predicts and the measured mean error (degrees).
pub fn table(summary: &Summary) -> String {
    let two_places = |x: Option<f64>| x.map(|d| format!("{d:.2}")).unwrap_or_else(|| "-".into());
    let ms = |x: Option<f64>| x.map(|t| format!("{:.0}", t * 1e3)).unwrap_or_else(|| "never".into());
    let mut out = String::from(
        "speed m/s   f_e Hz  budget ms  lock median ms  lock max ms  over budget  false locks  Q24-f32 max deg  inverter dU_d V  bias deg  mean err deg\n",
    );
    for r in &summary.speeds {
        out += &format!(
            "{:>9.2}  {:>7.1}  {:>9.0}  {:>14}  {:>11}  {:>8} /{:>2}  {:>11}  {:>15}  {:>15}  {:>8}  {:>12}\n",
            r.speed_m_per_s,
            r.electrical_hz,
            r.budget_s * 1e3,
            ms(r.lock_time_median_s),
            ms(r.lock_time_max_s),
            r.budget_violations,
            r.runs,
            r.false_locks,
            r.q24_deviation_max_deg.map(|d| format!("{d:.3}")).unwrap_or_else(|| "-".into()),
            two_places(r.inverter_error_d_v),
            two_places(r.inverter_bias_deg),
            two_places(r.steady_error_mean_deg),
        );
    }
    out += &format!(
        "{} cold starts: {} over budget, {} never locked, {} false locks; largest lock time {}\n",
        summary.runs,
        summary.lock_time_budget_violations,
        summary.never_locked,
        summary.false_locks,
        ms(summary.lock_time_max_s)
    );
    out
}

/// The figure of `dcfo acquire`: median and largest lock time against |speed| for each
/// direction, with the budget, in ms (log x axis). A start that never locked is drawn at
/// its window's end.
pub fn figure(starts: &[Start]) -> crate::plot::Figure {
    use crate::plot::{Figure, Panel, Series};
    let summary = summarise(starts);
    let window_end = |v: f64| {
        starts
            .iter()
            .filter(|s| s.speed_m_per_s == v)
            .map(|s| (3.0 * s.budget_s).max(s.budget_s + 0.3))
            .fold(0.0, f64::max)
    };
    let mut series = Vec::new();
    for (dir, sign) in [("+", 1.0), ("-", -1.0)] {
        let rows: Vec<&SpeedRow> = summary.speeds.iter().filter(|r| r.speed_m_per_s * sign > 0.0).collect();
        let point = |r: &&SpeedRow, t: Option<f64>| {
            (r.speed_m_per_s.abs(), 1e3 * t.unwrap_or(window_end(r.speed_m_per_s)))
        };
        series.push(Series::line(
            format!("max, {dir}"),
            rows.iter().map(|r| point(r, r.lock_time_max_s)).collect(),
        ));
        series.push(Series::markers(
            format!("median, {dir}"),
            rows.iter().map(|r| point(r, r.lock_time_median_s)).collect(),
        ));
    }
    let mut budget: Vec<(f64, f64)> =
        summary.speeds.iter().map(|r| (r.speed_m_per_s.abs(), 1e3 * r.budget_s)).collect();
    budget.sort_by(|a, b| a.0.total_cmp(&b.0));
    budget.dedup_by(|a, b| a.0 == b.0);
    series.push(Series::dashed("budget max(60 ms, 2 periods)", budget));
    Figure {
        title: "cold-start acquisition: time to lock (< 5 deg from then on)".into(),
        x_label: "speed (m/s)".into(),
        x_log: true,
        x_range: None,
        panels: vec![Panel::new("lock time (ms)", series)],
        size: None,
    }
}

// ---- The command.

/// Which simulated inverter and sensors record the traces: the realistic ones, or
/// either made ideal, to tell what the estimator loses from what its inputs lose.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum PlantModel {
    /// The realistic inverter (dead time, device drops, bus ripple; the drive's
    /// compensation) and sensors (offsets, gain errors, noise, quantisation).
    Realistic,
    /// An ideal inverter (no dead time, drops or ripple; nothing to compensate), the
    /// realistic sensors.
    IdealInverter,
    /// The realistic inverter, ideal sensors.
    IdealSensors,
    /// Both ideal: what is left is the estimator's own error.
    Ideal,
}

impl PlantModel {
    /// `setup` with this model's inverter and sensors.
    pub fn apply(self, setup: &mut Setup) {
        if matches!(self, PlantModel::IdealInverter | PlantModel::Ideal) {
            let bus_v = setup.plant.inverter.dc_bus_v;
            setup.plant.inverter = crate::plant::InverterParams::ideal(bus_v);
            setup.drive.dead_time_compensation = None;
        }
        if matches!(self, PlantModel::IdealSensors | PlantModel::Ideal) {
            setup.plant.sensors = crate::plant::SensorParams::ideal();
        }
    }
}

/// What `dcfo acquire` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// Print exactly one JSON object (the totals and the per-speed table) on stdout.
    pub json: bool,
    /// What tunes the DCFO's notch, in the recording drive and in the cold-started
    /// estimators.
    pub notch: dcfo::estimator::NotchTuning,
    /// The simulated inverter and sensors that record the traces.
    pub plant: PlantModel,
    /// Which current the drive's (and the recorder's) inverter compensation takes its
    /// signs from.
    pub compensation_signs: dcfo::drive::CompensationSigns,
    /// The motor (`--motor`: a preset name or a motor file) on the simulated realistic
    /// inverter and sensors with the drive tuned from its file ([`Setup::for_motor`]),
    /// swept over the benchmark's electrical frequencies ([`Options::full_for`]); `None`:
    /// the benchmark, the paper motor on its test axis ([`Setup::paper`]).
    pub motor: Option<String>,
    /// Directory for `acquire.json` (every cold start), `acquire.csv` (the table) and
    /// `acquire.png` / `acquire.svg` (lock time against speed).
    pub out: std::path::PathBuf,
}

/// `dcfo acquire`: the acquisition sweep on the simulated paper axis (or `params.motor`),
/// its results in `params.out` and the table (or JSON) on stdout.
///
/// # Errors
/// The motor could not be loaded, a run failed, or the results could not be written.
pub fn run_command(params: &Params) -> anyhow::Result<()> {
    use anyhow::Context;
    let observer = dcfo::algorithms::observer::ObserverKind::Dcfo;
    let (mut setup, options, motor_name) = match &params.motor {
        None => (Setup::paper(observer), Options::full(), "paper (test axis)".to_string()),
        Some(arg) => {
            let file = crate::motor_file::load_motor(arg)?;
            (Setup::for_motor(&file.params, observer), Options::full_for(&file.params), file.name)
        }
    };
    setup.drive.estimator.notch_tuning = params.notch;
    setup.drive.compensation_signs = params.compensation_signs;
    params.plant.apply(&mut setup);
    let started = std::time::Instant::now();
    let starts = sweep(&setup, &options, |done, total| eprintln!("acquire: {done}/{total} speeds"))
        .map_err(|e| anyhow::anyhow!(e))?;
    let summary = summarise(&starts);
    let out = &params.out;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let all = serde_json::json!({ "motor": motor_name, "plant": params.plant, "summary": &summary, "starts": &starts });
    std::fs::write(out.join("acquire.json"), serde_json::to_string_pretty(&all)?)
        .with_context(|| format!("writing {}", out.join("acquire.json").display()))?;
    let mut csv = String::from(
        "speed_m_per_s,budget_s,lock_time_median_s,lock_time_max_s,budget_violations,runs,false_locks,inverter_error_d_v,inverter_bias_deg,steady_error_mean_deg\n",
    );
    let opt = |x: Option<f64>| x.map(|v| format!("{v:.6}")).unwrap_or_default();
    for r in &summary.speeds {
        csv += &format!(
            "{},{:.6},{},{},{},{},{},{},{},{}\n",
            r.speed_m_per_s,
            r.budget_s,
            opt(r.lock_time_median_s),
            opt(r.lock_time_max_s),
            r.budget_violations,
            r.runs,
            r.false_locks,
            opt(r.inverter_error_d_v),
            opt(r.inverter_bias_deg),
            opt(r.steady_error_mean_deg)
        );
    }
    std::fs::write(out.join("acquire.csv"), csv)
        .with_context(|| format!("writing {}", out.join("acquire.csv").display()))?;
    crate::plot::write_figure(&figure(&starts), &out.join("acquire"))?;
    eprintln!("acquire: {:.1} s; results in {}", started.elapsed().as_secs_f64(), out.display());
    if params.json {
        println!("{}", serde_json::to_string(&summary)?);
    } else {
        print!("{}", table(&summary));
    }
    Ok(())
}
