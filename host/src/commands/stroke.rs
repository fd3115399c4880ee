//! `dcfo stroke`: the closed-loop positioning drive moving back and forth over a finite
//! stroke, through zero speed at every reversal, on a plant that differs from the motor
//! file.
//!
//! The axis: the motor (file or preset) with a carriage of [`PAYLOAD_KG`], 10 N Coulomb
//! friction (13 N break-away), the plant's end-effect ripple, R +20 % and L -5 % against
//! the motor file, the realistic inverter (dead time, drops) and sensors (offsets, gain
//! errors, noise) of [`SimParams::from_motor`]. The drive (`Drive<f32>`, the firmware's
//! control step) is built from the motor file alone: [`DriveConfig::for_motor`] with the
//! inverter compensation the paper axis uses, and [`dcfo::drive::MotionConfig::for_drive`].
//! It aligns on enable (the zero of its position estimate is that pole position; the
//! mover starts there), then runs [`MOVES`] moves between the stroke's ends with
//! [`DWELL_S`] dwells.
//!
//! Figures per run: position error `|x_hat - x|` (max over the run after alignment, and
//! at the end), re-lock time after each low-speed segment (from the reference speed
//! crossing the exit threshold to `Running`), the largest step of the current reference
//! vector between two periods (bumpless transitions), faults.

use std::f64::consts::PI;

use dcfo::algorithms::motion::Move;
use dcfo::drive::{DriveConfig, DriveState};
use dcfo::motor::MotorParams;
use serde::Serialize;

use crate::closed_loop::ClosedLoop;
use crate::plant::{InverterParams, Plant, PlantParams, SimParams};
use crate::simulation::{Controller, LocalDrive, Setup, frame_bridge, sensor_frame};

/// Carriage and load moved besides the mover, kg.
pub const PAYLOAD_KG: f64 = dcfo::drive::PAPER_AXIS_PAYLOAD_KG as f64;
/// Stroke, m.
pub const STROKE_M: f32 = dcfo::drive::STROKE_AXIS_STROKE_M;
/// Speed limit of the moves, m/s.
pub const MAX_SPEED_M_PER_S: f32 = dcfo::drive::STROKE_AXIS_LIMITS.max_speed_m_per_s;
/// Acceleration limit of the moves, m/s^2.
pub const MAX_ACCEL_M_PER_S2: f32 = dcfo::drive::STROKE_AXIS_LIMITS.max_accel_m_per_s2;
/// Number of moves (end to end); each after the first reverses.
pub const MOVES: usize = 12;
/// Dwell at each end, s.
pub const DWELL_S: f32 = 0.2;
/// Coulomb friction of the axis, N (break-away 1.3 times).
pub const COULOMB_N: f64 = 10.0;

/// One logged period.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Row {
    /// Time, s.
    pub t_s: f64,
    /// True position, m (from the alignment position).
    pub x_m: f64,
    /// Estimated position, m.
    pub x_hat_m: f64,
    /// Reference position, m.
    pub x_ref_m: f64,
    /// True speed, m/s.
    pub v_m_per_s: f64,
    /// Reference speed, m/s.
    pub v_ref_m_per_s: f64,
    /// Drive state code.
    pub state: u8,
    /// True minus control angle, electrical degrees (in the low-speed mode: how far the
    /// mover trails the current vector's reference position); NaN over a link.
    pub angle_err_deg: f64,
    /// Measured d current in the control frame, A; NaN over a link.
    pub i_d_a: f64,
    /// Measured q current in the control frame, A; NaN over a link.
    pub i_q_a: f64,
}

/// The speed overshoot a move may have at the end of its acceleration, % of the
/// profile's top speed (issue 35).
pub const SPEED_OVERSHOOT_FLOOR_PCT: f64 = 10.0;

/// The final `|x_hat - x|` a stroke may end with, electrical degrees, where the position
/// at rest comes from the current vector: 3 deg (`tau / 60`).
pub const FINAL_ERROR_FLOOR_DEG: f64 = 3.0;

/// The same where the position at rest comes from HFI (salient motors): HFI's standstill
/// angle budget, 10 deg (`tau / 18`: the sensors' noise through its loop, 4.5 deg at 3.5
/// sigma; the dead time's tilt of the injected vector, up to 2 deg; the phases' unequal
/// gains read as saliency, up to 2 deg; `host/tests/hfi.rs`). `tau / 60` is no bound there:
/// where the last move stops decides whether one sample of HFI's bias at rest meets it.
pub const FINAL_ERROR_FLOOR_HFI_DEG: f64 = 10.0;

/// The figures of one stroke run.
#[derive(Clone, Debug, Serialize)]
pub struct StrokeSummary {
    /// Motor name.
    pub motor: String,
    /// Pole pitch, m.
    pub pole_pitch_m: f64,
    /// Direction reversals of the reference.
    pub reversals: usize,
    /// Latched faults at the end (0 or the number of fault kinds latched).
    pub faults: u32,
    /// Latched faults, named.
    pub fault_names: String,
    /// Largest |x_hat - x| after alignment, m.
    pub x_err_max_m: f64,
    /// |x_hat - x| at the end, m.
    pub x_err_final_m: f64,
    /// Its floor, m: [`FINAL_ERROR_FLOOR_DEG`] of the pole pitch's 180 deg, or
    /// [`FINAL_ERROR_FLOOR_HFI_DEG`] for a drive whose low-speed mode runs on HFI.
    pub x_err_final_floor_m: f64,
    /// Longest time from the reference speed leaving the low-speed band to `Running`, s
    /// (`None` if the drive never left the low-speed mode).
    pub relock_time_max_s: Option<f64>,
    /// Number of low-speed exits measured.
    pub relocks: usize,
    /// Exits the drive missed: the reference speed left the low-speed band (above its
    /// exit speed) and came back into it, or the run ended, with the drive still in the
    /// low-speed mode. With no exit measured, 0 means that the moves never asked for
    /// one (the profile's speed below the band's exit: the low-speed mode throughout).
    pub exits_missed: usize,
    /// Largest change of the current reference vector between two periods, A, over the
    /// whole run (beyond its rotation at the reference speed); `None` over a link, which
    /// does not carry the current references.
    pub current_ref_step_max_a: Option<f64>,
    /// The same within five periods of a change of the drive's state: the mode
    /// transitions (the bumpless floor), A; `None` over a link.
    pub current_ref_step_transition_max_a: Option<f64>,
    /// When the largest current reference step happened, s; `None` over a link.
    pub current_ref_step_max_t_s: Option<f64>,
    /// When the largest position error happened, s.
    pub x_err_max_t_s: f64,
    /// 5 % of the rated peak current, A (the bumpless floor).
    pub current_step_limit_a: f64,
    /// Low-speed threshold and low-speed current vector amplitude, m/s and A.
    pub low_speed_m_per_s: f64,
    /// Low-speed current amplitude, A.
    pub low_speed_current_a: f64,
    /// Largest |true - control angle| while running sensorless, electrical degrees;
    /// `None` over a link, which does not carry the control angle.
    pub angle_err_running_max_deg: Option<f64>,
    /// Largest speed overshoot while the reference cruises at the profile's top speed
    /// (after each acceleration), as a share of that speed: `max(|v| - |v_ref|) / v_top`
    /// with `v` along the reference, %.
    pub speed_overshoot_max_pct: f64,
    /// Moves completed.
    pub moves_done: usize,
    /// Moves sent to the drive (all of the run's, unless it ended early).
    pub moves_sent: usize,
}

/// The plant for `motor`: carriage, friction, R +20 %, L -5 %; for a salient motor
/// (`L_q / L_d >= 1.15`, an interior-magnet design, whose iron saturates along the
/// magnet) a d axis whose incremental inductance is 10 % lower at the rated peak
/// current ([`PlantParams::d_saturation_for`]), which its HFI polarity test reads. The
/// surface-magnet motors' plants stay linear.
pub fn plant_for(motor: &MotorParams) -> SimParams {
    let mut p = SimParams::from_motor(motor);
    if motor.lq_h >= dcfo::algorithms::hfi::MIN_SALIENCY * motor.ld_h {
        let rated_peak = f64::from(motor.rated_current_a) * 2f64.sqrt();
        p.plant.ld_saturation_per_a = PlantParams::d_saturation_for(0.1, rated_peak);
    }
    p.plant.mass_kg += PAYLOAD_KG;
    p.plant.coulomb_friction_n = COULOMB_N;
    p.plant.static_friction_n = 1.3 * COULOMB_N;
    p.plant.rs_ohm *= 1.2;
    p.plant.ld_h *= 0.95;
    p.plant.lq_h *= 0.95;
    p
}

/// The nominal bus of the simulated inverter for `motor`, V ([`InverterParams::from_motor`]).
pub fn bus_for(motor: &MotorParams) -> f32 {
    InverterParams::from_motor(motor).dc_bus_v as f32
}

/// The drive for `motor` from the motor file alone, positioning over the stroke:
/// [`DriveConfig::stroke_axis`] on the simulated inverter's bus ([`bus_for`]), the
/// function the HIL firmware builds its drive with.
pub fn drive_for(motor: &MotorParams) -> DriveConfig {
    DriveConfig::stroke_axis(motor, bus_for(motor))
}

/// The plant, the motor and the drive of a stroke run on `motor` ([`plant_for`],
/// [`drive_for`]).
pub fn setup_for(motor: &MotorParams) -> Setup {
    Setup { motor: *motor, plant: plant_for(motor), drive: drive_for(motor) }
}

/// What the link carried in one period, for the bit-for-bit comparison of two runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkEstimate {
    /// The angle estimate θ̂ (electrical rad) as sent, `None` without an estimate.
    pub theta_hat: Option<f32>,
    /// The position estimate x̂ (m) as sent.
    pub x_hat_m: f32,
}

/// One stroke run: the figures, the logged rows and every period's estimates.
#[derive(Clone, Debug)]
pub struct StrokeRun {
    /// The figures.
    pub summary: StrokeSummary,
    /// Every `log_every`-th period.
    pub rows: Vec<Row>,
    /// Every period's θ̂ and x̂ as the link carried them.
    pub estimates: Vec<LinkEstimate>,
}

/// Bit-for-bit comparison of the estimates of two stroke runs.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StrokeEquivalence {
    /// Periods compared (the shorter run's).
    pub periods: usize,
    /// Periods whose θ̂ or x̂ differ in any bit (or whose estimate is present in one
    /// run only), plus the longer run's extra periods.
    pub differing: usize,
    /// Largest |x̂ difference|, m.
    pub max_x_diff_m: f64,
    /// The first period that differs (`None`: none), where to start looking.
    pub first_differing: Option<usize>,
}

/// Compares the per-period estimates of two runs bit for bit.
pub fn compare(a: &[LinkEstimate], b: &[LinkEstimate]) -> StrokeEquivalence {
    let bits = |e: &LinkEstimate| (e.theta_hat.map(f32::to_bits), e.x_hat_m.to_bits());
    let mut differing = a.len().abs_diff(b.len());
    let mut max_x_diff_m = 0.0f64;
    let mut first_differing = (a.len() != b.len()).then_some(a.len().min(b.len()));
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        if bits(x) != bits(y) {
            first_differing = Some(first_differing.map_or(k, |f| f.min(k)));
            differing += 1;
            max_x_diff_m = max_x_diff_m.max((f64::from(x.x_hat_m) - f64::from(y.x_hat_m)).abs());
        }
    }
    StrokeEquivalence { periods: a.len().min(b.len()), differing, max_x_diff_m, first_differing }
}

/// The moves of a stroke run: `count` moves between the stroke's ends, the first to
/// [`STROKE_M`], each with a [`DWELL_S`] dwell.
pub fn moves(count: usize) -> Vec<Move> {
    (0..count).map(|i| Move { target_m: if i % 2 == 0 { STROKE_M } else { 0.0 }, dwell_s: DWELL_S }).collect()
}

/// Simulated time of a run of `moves` moves, s: the alignment (0.3 s), then each move
/// takes `d / v + v / a` plus its dwell; margin 1 s.
pub fn duration_s(moves: usize) -> f64 {
    let per_move = f64::from(STROKE_M / MAX_SPEED_M_PER_S + MAX_SPEED_M_PER_S / MAX_ACCEL_M_PER_S2 + DWELL_S);
    0.3 + moves as f64 * per_move + 1.0
}

/// Runs the stroke on `motor` (named `name`) with the in-process `Drive<f32>` and all
/// [`MOVES`] moves, logging every `log_every` periods.
pub fn run(name: &str, motor: &MotorParams, log_every: usize) -> Result<(StrokeSummary, Vec<Row>), String> {
    let setup = setup_for(motor);
    let mut drive = LocalDrive::new(&setup).map_err(|e| e.to_string())?;
    let r = run_with(name, &setup, &mut drive, MOVES, log_every, |_| {})?;
    Ok((r.summary, r.rows))
}

/// Runs `moves` moves of the stroke on `setup`'s plant in closed loop with `controller`
/// (the in-process drive of either numeric type, or the firmware behind the HIL link:
/// the same loop, the same frames), logging every `log_every` periods and calling
/// `progress(fraction)` now and then.
///
/// Moves reach the drive as the link carries them: one per sensor frame
/// ([`dcfo::link::SensorFrame::move_to`]), while the last answer shows room in the drive's
/// fixed-capacity queue. Position, reference and queue come back in the answer's
/// [`dcfo::link::PositionReport`]. The figures that need the drive's internals (control
/// angle, current references) are `None` over a link.
pub fn run_with(
    name: &str,
    setup: &Setup,
    controller: &mut dyn Controller,
    moves_count: usize,
    log_every: usize,
    mut progress: impl FnMut(f64),
) -> Result<StrokeRun, String> {
    let motor = &setup.motor;
    let motion = setup.drive.motion.ok_or("no motion config")?;
    let mut closed_loop = ClosedLoop::new(Plant::new(&setup.plant).map_err(|e| e.to_string())?);
    let mut moves: std::collections::VecDeque<Move> = moves(moves_count).into();
    let ts = closed_loop.plant().pwm_period_s();
    let tau = f64::from(motor.pole_pitch_m);
    let rated_peak = f64::from(motor.rated_current_a) * 2f64.sqrt();
    let n = (duration_s(moves_count) / ts).round() as usize;
    let log_every = log_every.max(1);
    let mut rows = Vec::new();
    let mut estimates = Vec::with_capacity(n);
    let (mut x_err_max, mut x_err_final) = (0.0f64, 0.0f64);
    let mut aligned = false;
    let mut prev_ref_ab: Option<(f64, f64)> = None;
    let mut step_max: Option<f64> = None;
    let mut step_max_t: Option<f64> = None;
    let mut transition_step_max: Option<f64> = None;
    let mut last_change = 0usize;
    let mut last_state = DriveState::Disabled;
    let mut x_err_max_t = 0.0f64;
    let mut exit_since: Option<f64> = None;
    let mut relocks = Vec::new();
    let mut exits_missed = 0usize;
    let mut angle_err_running: Option<f64> = None;
    let mut prev_v_ref = 0.0f64;
    let mut reversals = 0usize;
    let mut last_dir = 0.0f64;
    let exit_speed = f64::from(motion.low_speed_m_per_s * motion.low_speed_exit_ratio);
    let mut moves_done = 0usize;
    let top_speed = f64::from(motion.limits.max_speed_m_per_s);
    let mut overshoot_max = 0.0f64;
    // Room in the drive's queue as the last answer reported it (before the first
    // answer: the queue is empty).
    let mut queue_room = dcfo::drive::MOVE_QUEUE;
    let mut rejected = 0u16;
    let mut faults = dcfo::drive::Faults::NONE;
    for k in 0..n {
        let t = k as f64 * ts;
        let move_to = if queue_room > 0 { moves.pop_front() } else { None };
        let sensed = closed_loop.sense();
        let truth = sensed.truth;
        let step = controller
            .step(&sensor_frame(&sensed.reading, k as u16, 0.0, move_to))
            .map_err(|e| e.to_string())?;
        let f = step.frame;
        let Some(pos) = f.position else {
            return Err(format!(
                "period {k}: the drive reports no position (not a positioning drive: a HIL image \
                 must be started with the stroke axis)"
            ));
        };
        if pos.moves_rejected != rejected {
            return Err(format!(
                "period {k}: the drive refused a move ({} refused in all){}",
                pos.moves_rejected,
                move_to.map_or(String::new(), |m| format!(", the last sent to {} m", m.target_m))
            ));
        }
        rejected = pos.moves_rejected;
        queue_room = dcfo::drive::MOVE_QUEUE.saturating_sub(usize::from(pos.moves_queued));
        closed_loop.actuate(sensed, frame_bridge(&f), 0.0);
        let state = f.state();
        faults = f.faults();
        estimates.push(LinkEstimate { theta_hat: f.estimate.map(|e| e.theta_hat), x_hat_m: pos.x_hat_m });
        if state != last_state {
            last_change = k;
            last_state = state;
        }
        let v_ref = f64::from(pos.v_ref_m_per_s);
        let dir = if v_ref > 1e-9 {
            1.0
        } else if v_ref < -1e-9 {
            -1.0
        } else {
            0.0
        };
        if dir != 0.0 {
            if last_dir != 0.0 && dir != last_dir {
                reversals += 1;
            }
            last_dir = dir;
        }
        if prev_v_ref != 0.0 && v_ref == 0.0 {
            moves_done += 1;
        }
        prev_v_ref = v_ref;
        // Cruising: the reference within 0.5 % of the top speed.
        if v_ref.abs() >= 0.995 * top_speed {
            overshoot_max = overshoot_max.max(truth.v_m_per_s * v_ref.signum() - v_ref.abs());
        }
        let x_hat = f64::from(pos.x_hat_m);
        let x = truth.x_m;
        let angle_err = step
            .detail
            .map(|d| crate::trace::wrap_angle(truth.theta_e_rad - d.theta_control_rad).to_degrees());
        if state == DriveState::LowSpeed && !aligned && pos.x_ref_m == 0.0 && t > 0.2 {
            aligned = true;
        }
        if state != DriveState::LowSpeed && state != DriveState::Disabled && state != DriveState::Calibrating
        {
            aligned = true;
        }
        if aligned {
            if (x_hat - x).abs() > x_err_max {
                x_err_max = (x_hat - x).abs();
                x_err_max_t = t;
            }
            x_err_final = (x_hat - x).abs();
        }
        if state == DriveState::Running
            && let Some(a) = angle_err
        {
            angle_err_running = Some(angle_err_running.unwrap_or(0.0).max(a.abs()));
        }
        // Bumpless: the reference current vector in alpha-beta, step by step (the
        // in-process drive's detail only).
        match step.detail {
            Some(d)
                if matches!(state, DriveState::Running | DriveState::LowSpeed | DriveState::Reacquiring) =>
            {
                let (s, c) = d.theta_control_rad.sin_cos();
                let [i_d, i_q] = d.i_dq_ref_a;
                let r = (i_d * c - i_q * s, i_d * s + i_q * c);
                if let Some(p) = prev_ref_ab {
                    // Discount the rotation of a constant vector at the reference speed.
                    let turn = (v_ref * PI / tau * ts).abs();
                    let mag = (r.0 * r.0 + r.1 * r.1).sqrt();
                    let step = ((r.0 - p.0).powi(2) + (r.1 - p.1).powi(2)).sqrt() - mag * turn;
                    if step_max.is_none_or(|m| step > m) {
                        step_max = Some(step);
                        step_max_t = Some(t);
                    }
                    if k < last_change + 5 && transition_step_max.is_none_or(|m| step > m) {
                        transition_step_max = Some(step);
                    }
                }
                prev_ref_ab = Some(r);
            }
            _ => prev_ref_ab = None,
        }
        // Re-lock: from the reference speed leaving the low-speed band to Running.
        if state == DriveState::LowSpeed && v_ref.abs() > exit_speed {
            exit_since.get_or_insert(t);
        } else if state == DriveState::Running {
            if let Some(t0) = exit_since.take() {
                relocks.push(t - t0);
            }
        } else {
            if state == DriveState::LowSpeed && exit_since.is_some() {
                exits_missed += 1;
            }
            exit_since = None;
        }
        if k % log_every == 0 {
            rows.push(Row {
                t_s: t,
                x_m: x,
                x_hat_m: x_hat,
                x_ref_m: f64::from(pos.x_ref_m),
                v_m_per_s: truth.v_m_per_s,
                v_ref_m_per_s: v_ref,
                state: state.code(),
                angle_err_deg: angle_err.unwrap_or(f64::NAN),
                i_d_a: step.detail.map_or(f64::NAN, |d| d.i_dq_a[0]),
                i_q_a: step.detail.map_or(f64::NAN, |d| d.i_dq_a[1]),
            });
        }
        if k % 4096 == 0 {
            progress(k as f64 / n as f64);
        }
        if state == DriveState::Fault {
            break;
        }
    }
    progress(1.0);
    let summary = StrokeSummary {
        motor: name.to_string(),
        pole_pitch_m: tau,
        reversals,
        faults: faults.bits().count_ones(),
        fault_names: format!("{faults:?}"),
        x_err_max_m: x_err_max,
        x_err_final_m: x_err_final,
        x_err_final_floor_m: tau
            * if motion.hfi.is_some() { FINAL_ERROR_FLOOR_HFI_DEG } else { FINAL_ERROR_FLOOR_DEG }
            / 180.0,
        relock_time_max_s: relocks.iter().copied().reduce(f64::max),
        relocks: relocks.len(),
        // A run ending while the drive waits to leave the band missed that exit too.
        exits_missed: exits_missed + usize::from(exit_since.is_some()),
        current_ref_step_max_a: step_max,
        current_ref_step_transition_max_a: transition_step_max,
        current_ref_step_max_t_s: step_max_t,
        x_err_max_t_s: x_err_max_t,
        current_step_limit_a: 0.05 * rated_peak,
        low_speed_m_per_s: f64::from(motion.low_speed_m_per_s),
        low_speed_current_a: f64::from(motion.low_speed_current_a),
        angle_err_running_max_deg: angle_err_running,
        speed_overshoot_max_pct: 100.0 * overshoot_max / top_speed,
        moves_done,
        moves_sent: moves_count - moves.len(),
    };
    Ok(StrokeRun { summary, rows, estimates })
}

/// The summary as a table.
pub fn table(s: &StrokeSummary) -> String {
    let mm = |x: f64| format!("{:.2} mm", 1e3 * x);
    let ms = |x: Option<f64>| x.map_or("never".to_string(), |t| format!("{:.1} ms", 1e3 * t));
    let ok = |b: bool| if b { "yes" } else { "NO" };
    let tau = s.pole_pitch_m;
    let mut out = format!("stroke on `{}` (pole pitch {} mm)\n", s.motor, 1e3 * tau);
    out += &format!("{:<34} {:>14} {:>14}  {}\n", "figure", "measured", "floor", "met");
    let mut row = |name: &str, v: String, f: String, met: bool| {
        out += &format!("{name:<34} {v:>14} {f:>14}  {}\n", ok(met));
    };
    // Every move after the first reverses; the last may end in its dwell.
    let reversals_floor = s.moves_sent.saturating_sub(2);
    row(
        "moves / reversals",
        format!("{} / {}", s.moves_done, s.reversals),
        format!(">= {reversals_floor} rev"),
        s.reversals >= reversals_floor,
    );
    row(
        "faults",
        format!("{} {}", s.faults, if s.faults > 0 { &s.fault_names } else { "" }),
        "0".into(),
        s.faults == 0,
    );
    row("max |x_hat - x|", mm(s.x_err_max_m), mm(tau / 4.0), s.x_err_max_m <= tau / 4.0);
    row(
        "final |x_hat - x|",
        mm(s.x_err_final_m),
        mm(s.x_err_final_floor_m),
        s.x_err_final_m <= s.x_err_final_floor_m,
    );
    row(
        "speed overshoot, cruising",
        format!("{:.1} %", s.speed_overshoot_max_pct),
        format!("{SPEED_OVERSHOOT_FLOOR_PCT} %"),
        s.speed_overshoot_max_pct <= SPEED_OVERSHOOT_FLOOR_PCT,
    );
    let relock = match (s.relock_time_max_s, s.exits_missed) {
        (_, missed) if missed > 0 => format!("{missed} missed"),
        (None, _) => "none asked".into(),
        (longest, _) => ms(longest),
    };
    row(
        &format!("re-lock after low speed ({} exits)", s.relocks),
        relock,
        "100 ms".into(),
        s.exits_missed == 0 && s.relock_time_max_s.is_none_or(|t| t <= 0.1),
    );
    match (s.current_ref_step_transition_max_a, s.current_ref_step_max_a) {
        (Some(transition), Some(anywhere)) => {
            row(
                "current step at mode transitions",
                format!("{transition:.3} A"),
                format!("{:.3} A", s.current_step_limit_a),
                transition <= s.current_step_limit_a,
            );
            out += &format!(
                "largest current reference step anywhere {anywhere:.3} A (the speed loop's steps included)\n"
            );
        }
        _ => out += "current reference steps: not measured (the link does not carry the references)\n",
    }
    out += &format!(
        "low-speed mode below {:.3} m/s with {:.2} A; max angle error running sensorless {}\n",
        s.low_speed_m_per_s,
        s.low_speed_current_a,
        s.angle_err_running_max_deg
            .map_or("not measured (the link does not carry the control angle)".into(), |a| format!(
                "{a:.1} deg"
            ))
    );
    out
}

/// Position, speed, mode, angle error and currents against time.
pub fn figure(s: &StrokeSummary, rows: &[Row]) -> crate::plot::Figure {
    use crate::plot::{Panel, Series, time_series_figure};
    let t: Vec<f64> = rows.iter().map(|r| r.t_s).collect();
    let col = |f: fn(&Row) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
    time_series_figure(
        format!("stroke on `{}`: position estimate through every reversal", s.motor),
        vec![
            Panel::new(
                "position (m)",
                vec![
                    Series::from_xy("x (true)", &t, &col(|r| r.x_m)),
                    Series::from_xy("x_hat", &t, &col(|r| r.x_hat_m)),
                    Series::from_xy("x_ref", &t, &col(|r| r.x_ref_m)),
                ],
            ),
            Panel::new(
                "x_hat - x (mm)",
                vec![Series::from_xy("x_hat - x", &t, &col(|r| 1e3 * (r.x_hat_m - r.x_m)))],
            ),
            Panel::new(
                "speed (m/s)",
                vec![
                    Series::from_xy("v (true)", &t, &col(|r| r.v_m_per_s)),
                    Series::from_xy("v_ref", &t, &col(|r| r.v_ref_m_per_s)),
                ],
            ),
            Panel::new(
                "state (3 running, 6 low speed)",
                vec![Series::from_xy("state", &t, &col(|r| f64::from(r.state)))],
            ),
            Panel::new(
                "true - control angle (deg el)",
                vec![Series::from_xy("angle", &t, &col(|r| r.angle_err_deg))],
            ),
            Panel::new(
                "current (A)",
                vec![
                    Series::from_xy("i_d", &t, &col(|r| r.i_d_a)),
                    Series::from_xy("i_q", &t, &col(|r| r.i_q_a)),
                ],
            ),
        ],
    )
}

// ---- The command.

/// The semihosting command line that makes the HIL image (`qemu_hil`) run the stroke
/// axis: `stroke` and the motor image ([`dcfo::motor_image::MotorImage`] of `motor` on
/// a `bus_v` bus) in hexadecimal. The image builds its drive from it with
/// [`DriveConfig::stroke_axis`], as [`drive_for`] does here.
pub fn qemu_cmdline(motor: &MotorParams, bus_v: f32) -> Result<String, String> {
    let image = dcfo::motor_image::MotorImage::new(*motor, bus_v).map_err(|e| format!("motor image: {e}"))?;
    let hex: String = image.encode().iter().map(|b| format!("{b:02x}")).collect();
    Ok(format!("stroke {hex}"))
}

/// What `dcfo stroke` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// Motor: a preset name (`paper`) or a motor TOML file (it must give `mass_kg`).
    pub motor: String,
    /// Print exactly one JSON object (the summary) on stdout.
    pub json: bool,
    /// Directory for `stroke.json`, `stroke.csv` (every 10th period) and the figure
    /// `stroke.png` / `stroke.svg`.
    pub out: std::path::PathBuf,
    /// Number of moves (at least 1; [`MOVES`] by default).
    pub moves: usize,
    /// Run the drive on QEMU through the lock-step HIL link (the board, and the image,
    /// built with cargo when `None`) instead of in this process.
    pub qemu: Option<(crate::qemu::QemuCpu, Option<std::path::PathBuf>)>,
    /// With `qemu`: also run the in-process drive of the firmware's numeric type and
    /// require every period's θ̂ and x̂ to be identical bit for bit.
    pub check: bool,
}

/// The JSON summary of `dcfo stroke`: the figures, and for a run on QEMU the link's
/// rate, the wall time and the comparison with the in-process drive.
#[derive(Debug, Serialize)]
pub struct Report {
    /// The figures.
    #[serde(flatten)]
    pub summary: StrokeSummary,
    /// The QEMU board, `None` in process.
    pub qemu_cpu: Option<crate::qemu::QemuCpu>,
    /// Lock-step round trips per second over the link (QEMU only).
    pub round_trips_per_s: Option<f64>,
    /// Wall time of the run, s.
    pub wall_s: f64,
    /// With `--check`: the comparison with the in-process drive.
    pub equivalence: Option<StrokeEquivalence>,
}

/// Runs the stroke as `params` asks: in process, or on QEMU (with the comparison when
/// `check`). For the command and the tests.
pub fn run_params(params: &Params, motor: &MotorParams) -> anyhow::Result<(Report, Vec<Row>)> {
    anyhow::ensure!(params.moves >= 1, "--moves must be at least 1");
    let setup = setup_for(motor);
    let started = std::time::Instant::now();
    let name = params.motor.as_str();
    let Some((cpu, elf)) = &params.qemu else {
        anyhow::ensure!(!params.check, "--check compares a QEMU run with the in-process drive: give --qemu");
        let mut drive = LocalDrive::new(&setup)?;
        let r = run_with(name, &setup, &mut drive, params.moves, 10, |_| {})
            .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        let report = Report {
            summary: r.summary,
            qemu_cpu: None,
            round_trips_per_s: None,
            wall_s: started.elapsed().as_secs_f64(),
            equivalence: None,
        };
        return Ok((report, r.rows));
    };
    let workspace =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap_or(std::path::Path::new("."));
    let elf = match elf {
        Some(e) => e.clone(),
        None => crate::hil_link::build_qemu_firmware(workspace, *cpu)?,
    };
    let cmdline = qemu_cmdline(motor, bus_for(motor)).map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
    let started = std::time::Instant::now();
    let (session, mut link) = crate::qemu::QemuSession::start_with_cmdline(&elf, *cpu, &cmdline)?;
    let bar = indicatif::ProgressBar::new(1000);
    let r = run_with(name, &setup, &mut link, params.moves, 10, |f| bar.set_position((f * 1000.0) as u64))
        .map_err(|e| anyhow::anyhow!("{name} on QEMU {cpu:?}: {e}"))?;
    bar.finish_and_clear();
    let rate = link.round_trips_per_s();
    let wall_s = started.elapsed().as_secs_f64();
    drop(session);
    let equivalence = if params.check {
        let mut local = cpu.local_drive(&setup)?;
        let l = run_with(name, &setup, local.as_mut(), params.moves, 10, |_| {})
            .map_err(|e| anyhow::anyhow!("{name} in process: {e}"))?;
        Some(compare(&r.estimates, &l.estimates))
    } else {
        None
    };
    let report = Report {
        summary: r.summary,
        qemu_cpu: Some(*cpu),
        round_trips_per_s: Some(rate),
        wall_s,
        equivalence,
    };
    Ok((report, r.rows))
}

/// `dcfo stroke`: the positioning drive over the stroke, its results in `params.out`
/// and the table (or JSON) on stdout; an error when `check` finds a difference.
pub fn run_command(params: &Params) -> anyhow::Result<()> {
    use anyhow::Context;
    let motor = crate::motor_file::load_motor(&params.motor)?;
    // The positioning drive's speed loop, feed-forward and low-speed damping are tuned
    // on the mover's mass: a placeholder would tune them silently wrong.
    if motor.defaulted.contains(&"mass_kg") {
        anyhow::bail!(
            "motor file {}: key `mass_kg` is required by the positioning drive (its speed loop, \
             acceleration feed-forward and low-speed damping are tuned on the moving mass)",
            params.motor
        );
    }
    let (report, rows) = run_params(params, &motor.params)?;
    let summary = &report.summary;
    let out = &params.out;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(out.join("stroke.json"), serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}", out.join("stroke.json").display()))?;
    let mut csv =
        String::from("t_s,x_m,x_hat_m,x_ref_m,v_m_per_s,v_ref_m_per_s,state,angle_err_deg,i_d_a,i_q_a\n");
    for r in &rows {
        csv += &format!(
            "{},{},{},{},{},{},{},{},{},{}\n",
            r.t_s,
            r.x_m,
            r.x_hat_m,
            r.x_ref_m,
            r.v_m_per_s,
            r.v_ref_m_per_s,
            r.state,
            r.angle_err_deg,
            r.i_d_a,
            r.i_q_a
        );
    }
    std::fs::write(out.join("stroke.csv"), csv)
        .with_context(|| format!("writing {}", out.join("stroke.csv").display()))?;
    crate::plot::write_figure(&figure(summary, &rows), &out.join("stroke"))?;
    let place = match (report.qemu_cpu, report.round_trips_per_s) {
        (Some(cpu), Some(rate)) => format!(" on QEMU {cpu:?} ({rate:.0} round trips/s)"),
        _ => String::new(),
    };
    eprintln!("stroke{place}: {:.1} s; results in {}", report.wall_s, out.display());
    if params.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print!("{}", table(summary));
        if let Some(e) = &report.equivalence {
            println!(
                "equivalence with the in-process drive: {} of {} periods differ in θ̂ or x̂ (max |Δx̂| {:.2e} m){}",
                e.differing,
                e.periods,
                e.max_x_diff_m,
                e.first_differing.map(|k| format!(", first at period {k}")).unwrap_or_default()
            );
        }
    }
    if let Some(e) = &report.equivalence {
        anyhow::ensure!(e.differing == 0, "the QEMU run's estimates differ from the in-process run's");
    }
    Ok(())
}
