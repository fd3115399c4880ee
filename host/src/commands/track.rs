//! `dcfo track`: the estimator alone on recordings of motion it must follow: reversals
//! through zero speed and sharp speed steps.
//!
//! Each profile is recorded once per motor by the sensored recorder of
//! [`crate::recorder`] (a load machine imposes the speed, an encoder drive pushes the
//! thrust current the profile needs, on the realistic inverter and sensors), then
//! replayed through a fresh estimator (zero state, not told the speed or the
//! acceleration), in f32 and in Q8.24 per-unit. The profiles are the paper motor's,
//! scaled to the motor by its pole pitch (the same electrical frequencies) and limited
//! to the acceleration its rated thrust gives the axis:
//!
//! | profile | speeds (paper motor, m/s) | what it asks |
//! |---|---|---|
//! | `reversal` | 0.3 -> 1.0 -> -0.6, 20 ms prefilter | a fast reversal |
//! | `stroke` | +-0.4 back and forth at 3 m/s^2 | slow reversals, long near zero |
//! | `step` | 0.24 -> 0.45 -> 0.3, 20 ms prefilter | the paper's step, sharp |
//! | `step-wide` | 0.4 -> 1.0 -> 0.4, 20 ms prefilter | a wide, sharp step |
//!
//! Figures, per profile and number type:
//! - **re-lock after a reversal**: after each passage through zero speed, the electrical
//!   travel (in periods) from the instant `|v|` reaches the back-EMF floor until the angle
//!   is within [`RELOCK_DEG`] and stays there while `|v|` stays above the floor (issue
//!   floor: 2 periods). The floor is the motor's, [`dcfo::drive::back_emf_floor_m_per_s`].
//! - **transient error**: the largest angle error while the speed changes by more than
//!   a tenth of a period's worth per period, and for 50 ms after, above the floor, once
//!   the estimator has locked the first time (issue floor: 8 deg).
//! - **false-lock samples**: the `locked` flag set with the angle more than
//!   [`crate::commands::acquire::FALSE_LOCK_DEG`] off (floor: 0).
//!
//! `dcfo track --dump PROFILE` prints, instead of the figures, that profile's f32 replay
//! sample by sample ([`dump`]): the truth beside the estimator's frequency, its notch's
//! tuning, its FLL's reading, the angle error and the flags, which is where a figure is
//! traced to its cause (`docs/estimator-design.md` reads such replays).

use serde::Serialize;

use dcfo::motor::MotorParams;
use dcfo::num::Q24;
use dcfo::num::units::Base;

use crate::commands::acquire::{FALSE_LOCK_DEG, recording_load_n};
use crate::recorder::{PrefilteredSteps, Row, SampledProfile, record, replay, replay_observed};
use crate::simulation::Setup;
use crate::simulation::scenarios::PaperScale;
use crate::trace::wrap_angle;

/// After a reversal the angle must be within this of the truth, electrical degrees.
pub const RELOCK_DEG: f64 = 10.0;
/// Prefilter of the speed steps, s.
pub const PREFILTER_S: f64 = 0.02;

/// One profile: a name and its steps on the paper motor.
#[derive(Clone, Debug)]
pub struct Profile {
    /// Name.
    pub name: &'static str,
    /// Speed at the start, m/s (paper motor).
    pub initial_m_per_s: f64,
    /// `(time s, speed m/s)` (paper motor).
    pub steps: Vec<(f64, f64)>,
    /// Acceleration limit on the paper axis, m/s^2 (`None`: the motor's rated thrust on
    /// the axis).
    pub accel_m_per_s2: Option<f64>,
    /// Length, s.
    pub duration_s: f64,
}

/// The profiles of the module docs.
pub fn profiles() -> Vec<Profile> {
    vec![
        Profile {
            name: "reversal",
            initial_m_per_s: 0.3,
            steps: vec![(0.6, 1.0), (1.4, -0.6)],
            accel_m_per_s2: None,
            duration_s: 2.6,
        },
        Profile {
            name: "stroke",
            initial_m_per_s: 0.4,
            steps: vec![(0.6, -0.4), (1.4, 0.4), (2.2, -0.4)],
            accel_m_per_s2: Some(3.0),
            duration_s: 3.0,
        },
        Profile {
            name: "step",
            initial_m_per_s: 0.24,
            steps: vec![(0.8, 0.45), (1.4, 0.3)],
            accel_m_per_s2: None,
            duration_s: 2.0,
        },
        Profile {
            name: "step-wide",
            initial_m_per_s: 0.4,
            steps: vec![(0.6, 1.0), (1.2, 0.4)],
            accel_m_per_s2: None,
            duration_s: 1.8,
        },
    ]
}

/// The figures of one profile in one number type.
#[derive(Clone, Debug, Serialize)]
pub struct Figures {
    /// Profile name.
    pub profile: String,
    /// `f32` or `q24`.
    pub numeric: &'static str,
    /// Reversals in the recording.
    pub reversals: usize,
    /// Largest re-lock travel after a reversal, electrical periods (`None`: some reversal
    /// never re-locked within its segment).
    pub relock_periods_max: Option<f64>,
    /// Largest angle error while the speed changes (and 50 ms after), degrees.
    pub transient_err_max_deg: f64,
    /// Largest angle error above the floor outside transients and re-locks, degrees.
    pub steady_err_max_deg: f64,
    /// When the estimator first locked, s (`None`: never).
    pub first_lock_s: Option<f64>,
    /// Samples with `locked` set and the angle more than 15 deg off.
    pub false_lock_samples: usize,
    /// The back-EMF floor used, m/s.
    pub floor_m_per_s: f64,
}

/// Scores one replay against its recording (module docs).
fn score(
    motor: &MotorParams,
    rows: &[Row],
    accel: &[(f64, f64)],
    est: &[(f64, bool)],
    ts: f64,
    floor: f64,
) -> (usize, Option<f64>, f64, f64, Option<f64>, usize) {
    let err: Vec<f64> = rows.iter().zip(est).map(|(r, e)| wrap_angle(r.theta - e.0).to_degrees()).collect();
    let false_locks =
        rows.iter().zip(est).zip(&err).filter(|((_, e), x)| e.1 && x.abs() > FALSE_LOCK_DEG).count();
    let first_lock = est.iter().position(|e| e.1);
    let w_per_v = crate::plant::rad_per_m(motor);
    // Segments above the floor, between passages below it.
    let mut segments: Vec<(usize, usize)> = Vec::new();
    let mut start = None;
    for (k, r) in rows.iter().enumerate() {
        match (r.v.abs() >= floor, start) {
            (true, None) => start = Some(k),
            (false, Some(s)) => {
                segments.push((s, k));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        segments.push((s, rows.len()));
    }
    // Re-lock after each reversal: segments that follow a sign change.
    let mut reversals = 0;
    let mut relock_max: Option<f64> = Some(0.0);
    for w in segments.windows(2) {
        let (prev, seg) = (w[0], w[1]);
        if rows[prev.0].v.signum() == rows[seg.0].v.signum() {
            continue;
        }
        reversals += 1;
        let last_bad = (seg.0..seg.1).rev().find(|&k| err[k].abs() > RELOCK_DEG);
        let periods = match last_bad {
            None => Some(0.0),
            Some(k) if k + 1 < seg.1 => {
                let travel: f64 = rows[seg.0..=k].iter().map(|r| r.v.abs() * w_per_v * ts).sum();
                Some(travel / (2.0 * std::f64::consts::PI))
            }
            Some(_) => None,
        };
        relock_max = match (relock_max, periods) {
            (Some(a), Some(b)) => Some(a.max(b)),
            _ => None,
        };
    }
    // Transients: the speed changing by more than a tenth of a period's worth of
    // frequency per period, and 50 ms after.
    let settle = (0.05 / ts).round() as usize;
    let mut in_transient = vec![false; rows.len()];
    let mut last_accel = None;
    for (k, &(v, a)) in accel.iter().enumerate().take(rows.len()) {
        let w = v.abs() * w_per_v;
        if a.abs() * w_per_v > 0.1 * w * w / (2.0 * std::f64::consts::PI) {
            last_accel = Some(k);
        }
        in_transient[k] = last_accel.is_some_and(|j| k <= j + settle);
    }
    let from = first_lock.unwrap_or(rows.len());
    // Samples after a reversal's re-lock window are not transients of the step kind.
    let mut in_relock = vec![false; rows.len()];
    for w in segments.windows(2) {
        if rows[w[0].0].v.signum() != rows[w[1].0].v.signum() {
            let seg = w[1];
            let end = (seg.0..seg.1).rev().find(|&k| err[k].abs() > RELOCK_DEG).map_or(seg.0, |k| k + 1);
            for f in in_relock.iter_mut().take(end).skip(seg.0) {
                *f = true;
            }
        }
    }
    let above = |k: usize| rows[k].v.abs() >= floor && k >= from && !in_relock[k];
    let transient_max =
        (0..rows.len()).filter(|&k| above(k) && in_transient[k]).map(|k| err[k].abs()).fold(0.0, f64::max);
    let steady_max =
        (0..rows.len()).filter(|&k| above(k) && !in_transient[k]).map(|k| err[k].abs()).fold(0.0, f64::max);
    (reversals, relock_max, transient_max, steady_max, first_lock.map(|k| k as f64 * ts), false_locks)
}

/// One profile recorded on `setup`'s axis: the rows, the load machine's `(speed m/s,
/// acceleration m/s^2)` per sample, and the motor's back-EMF floor (m/s).
struct Recording {
    rows: Vec<Row>,
    accel: Vec<(f64, f64)>,
    floor: f64,
}

/// Records `profile` on `setup`'s axis (module docs: scaled to the motor).
fn record_profile(setup: &Setup, profile: &Profile) -> Result<Recording, String> {
    let motor = &setup.motor;
    let scale = PaperScale::for_motor(motor);
    let ts = setup.plant.inverter.pwm_period_s;
    let mass = setup.plant.plant.mass_kg;
    let rated = crate::plant::rated_thrust_n(motor);
    let accel = profile.accel_m_per_s2.map_or(rated / mass, |a| a * scale.speed);
    let steps = PrefilteredSteps {
        initial_m_per_s: profile.initial_m_per_s * scale.speed,
        steps: profile.steps.iter().map(|&(t, v)| (t, v * scale.speed)).collect(),
        prefilter_s: PREFILTER_S,
        accel_limit_m_per_s2: accel,
    };
    let sampled = SampledProfile { samples: steps.sampled(ts, profile.duration_s), dt_s: ts };
    let rows = record(setup, &sampled, 0.0, recording_load_n(motor), profile.duration_s)?;
    let floor = f64::from(dcfo::drive::back_emf_floor_m_per_s(motor, &setup.drive));
    Ok(Recording { rows, accel: sampled.samples, floor })
}

/// Records `profile` on `setup`'s axis and scores the estimator on it, f32 and Q8.24.
pub fn run_profile(setup: &Setup, profile: &Profile) -> Result<Vec<Figures>, String> {
    let motor = &setup.motor;
    let ts = setup.plant.inverter.pwm_period_s;
    let Recording { rows, accel, floor } = record_profile(setup, profile)?;
    let mut out = Vec::new();
    for (numeric, est) in [
        ("f32", replay::<f32>(setup, &Base::SI, &rows, ts, [0.0; 2], [0.0; 2])?.0),
        ("q24", replay::<Q24>(setup, &Base::for_motor(motor), &rows, ts, [0.0; 2], [0.0; 2])?.0),
    ] {
        let (reversals, relock, transient, steady, first_lock, false_locks) =
            score(motor, &rows, &accel, &est, ts, floor);
        out.push(Figures {
            profile: profile.name.to_string(),
            numeric,
            reversals,
            relock_periods_max: relock,
            transient_err_max_deg: transient,
            steady_err_max_deg: steady,
            first_lock_s: first_lock,
            false_lock_samples: false_locks,
            floor_m_per_s: floor,
        });
    }
    Ok(out)
}

/// The header of [`dump`]'s CSV.
pub const DUMP_HEADER: &str =
    "t_s,v_m_per_s,omega_e_rad_s,omega_hat_rad_s,notch_rad_s,fll_rad_s,err_deg,locked,tracking";

/// The profile named `name` recorded on `setup`'s axis and replayed in f32, sample by
/// sample, as CSV ([`DUMP_HEADER`]): time (s), the mover's speed (m/s) and electrical
/// frequency (rad/s), the estimator's frequency, its notch's tuning and its FLL's reading
/// (rad/s; empty for an estimator without an FLL), the angle error (electrical degrees,
/// truth less estimate) and the two flags (0 or 1). The same replay as [`run_profile`]'s
/// f32 figures: what they summarise, for finding where an error comes from.
///
/// # Errors
/// No profile has that name (the error lists the names), or the recording or the
/// replay failed.
pub fn dump(setup: &Setup, name: &str) -> Result<String, String> {
    let all = profiles();
    let Some(profile) = all.iter().find(|p| p.name == name) else {
        let names: Vec<&str> = all.iter().map(|p| p.name).collect();
        return Err(format!("no track profile named {name:?}; the profiles are {}", names.join(", ")));
    };
    let ts = setup.plant.inverter.pwm_period_s;
    let Recording { rows, .. } = record_profile(setup, profile)?;
    let w_per_v = crate::plant::rad_per_m(&setup.motor);
    let mut csv = String::from(DUMP_HEADER);
    csv.push('\n');
    let mut k = 0;
    replay_observed::<f32>(setup, &Base::SI, &rows, ts, [0.0; 2], [0.0; 2], |est, e| {
        let r = &rows[k];
        let err = wrap_angle(r.theta - e.theta_e.to_radians::<f64>()).to_degrees();
        let fll = est.fll_omega().map_or(String::new(), |w| format!("{w:.3}"));
        csv += &format!(
            "{:.6},{:.5},{:.3},{:.3},{:.3},{fll},{err:.3},{},{}\n",
            k as f64 * ts,
            r.v,
            r.v * w_per_v,
            e.omega_e,
            est.notch_omega(),
            u8::from(e.locked),
            u8::from(e.tracking)
        );
        k += 1;
    })?;
    Ok(csv)
}

/// The axis a profile is recorded on: `motor` on the realistic inverter and sensors
/// ([`Setup::for_motor`]) carrying the paper axis's mass per rated thrust.
pub fn setup_for(motor: &MotorParams) -> Setup {
    let observer = dcfo::algorithms::observer::ObserverKind::Dcfo;
    let mut setup = Setup::for_motor(motor, observer);
    let payload = PaperScale::for_motor(motor).payload_kg;
    setup.plant.plant.mass_kg += payload;
    setup.drive.moving_mass_kg += payload as f32;
    setup
}

/// Every profile on `setup`, in parallel.
pub fn run_all(setup: &Setup) -> Result<Vec<Figures>, String> {
    let profiles = profiles();
    let results: Vec<Result<Vec<Figures>, String>> = std::thread::scope(|scope| {
        let handles: Vec<_> = profiles.iter().map(|p| scope.spawn(|| run_profile(setup, p))).collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|_| Err("a profile thread panicked".into())))
            .collect()
    });
    let mut all = Vec::new();
    for r in results {
        all.extend(r?);
    }
    Ok(all)
}

/// The figures as a table.
pub fn table(figures: &[Figures]) -> String {
    let mut s = String::from(
        "profile    type  reversals  re-lock max [periods]  transient max [deg]  steady max [deg]  first lock [s]  false locks\n",
    );
    let opt = |x: Option<f64>, p: usize| x.map_or("never".to_string(), |v| format!("{v:.p$}"));
    for f in figures {
        s += &format!(
            "{:<10} {:<5} {:>9}  {:>21}  {:>19.1}  {:>16.1}  {:>14}  {:>11}\n",
            f.profile,
            f.numeric,
            f.reversals,
            if f.reversals == 0 { "-".to_string() } else { opt(f.relock_periods_max, 2) },
            f.transient_err_max_deg,
            f.steady_err_max_deg,
            opt(f.first_lock_s, 3),
            f.false_lock_samples
        );
    }
    s
}

/// What `dcfo track` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// The motor: a preset or a motor file (`None`: the paper motor).
    pub motor: Option<String>,
    /// Print one JSON object instead of the table.
    pub json: bool,
    /// Print this profile's f32 replay sample by sample ([`dump`]) instead.
    pub dump: Option<String>,
}

/// `dcfo track`: every profile on the motor, the table (or one JSON object) on stdout.
///
/// # Errors
/// The motor could not be loaded, or a recording or a replay failed.
pub fn run_command(p: &Params) -> anyhow::Result<()> {
    let (params, name) = match p.motor.as_deref() {
        None => (MotorParams::paper(), "paper".to_string()),
        Some(arg) => {
            let file = crate::motor_file::load_motor(arg)?;
            (file.params, file.name)
        }
    };
    let setup = setup_for(&params);
    if let Some(profile) = p.dump.as_deref() {
        print!("{}", dump(&setup, profile).map_err(|e| anyhow::anyhow!(e))?);
        return Ok(());
    }
    let figures = run_all(&setup).map_err(|e| anyhow::anyhow!(e))?;
    if p.json {
        println!("{}", serde_json::json!({ "motor": name, "profiles": figures }));
    } else {
        println!("motor: {name}");
        print!("{}", table(&figures));
    }
    Ok(())
}
