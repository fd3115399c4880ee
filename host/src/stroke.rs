//! `dcfo stroke`: the closed-loop positioning drive moving back and forth over a finite
//! stroke, through zero speed at every reversal, on a plant that differs from the motor
//! file.
//!
//! The axis: the motor (file or preset) with a carriage of [`PAYLOAD_KG`], 10 N Coulomb
//! friction (13 N break-away), the plant's end-effect ripple, R +20 % and L -5 % against
//! the motor file, the realistic inverter (dead time, drops) and sensors (offsets, gain
//! errors, noise) of [`SimParams::from_motor`]. The drive (`Drive<f32>`, the firmware's
//! control step) is built from the motor file alone: [`DriveConfig::for_motor`] with the
//! inverter compensation the paper axis uses, and [`MotionConfig::for_drive`].
//! It aligns on enable (the zero of its position estimate is that pole position; the
//! mover starts there), then runs [`MOVES`] moves between the stroke's ends with
//! [`DWELL_S`] dwells.
//!
//! Figures per run: position error `|x_hat - x|` (max over the run after alignment, and
//! at the end), re-lock time after each low-speed segment (from the reference speed
//! crossing the exit threshold to `Running`), the largest step of the current reference
//! vector between two periods (bumpless transitions), faults.

use std::f64::consts::PI;

use dcfo::drive::{DeadTimeCompensation, Drive, DriveConfig, DriveState, MotionConfig};
use dcfo::motion::{Move, ProfileLimits};
use dcfo::motor::MotorParams;
use dcfo::observer::ObserverKind;
use dcfo::transforms::{Dq, inverse_park};
use dcfo::units::Base;
use serde::Serialize;

use crate::plant::{InverterParams, Plant, PlantParams, SimParams};

/// Carriage and load moved besides the mover, kg.
pub const PAYLOAD_KG: f64 = dcfo::drive::PAPER_AXIS_PAYLOAD_KG as f64;
/// Stroke, m.
pub const STROKE_M: f32 = 0.3;
/// Speed limit of the moves, m/s.
pub const MAX_SPEED_M_PER_S: f32 = 0.5;
/// Acceleration limit of the moves, m/s^2.
pub const MAX_ACCEL_M_PER_S2: f32 = 3.0;
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
    /// mover trails the current vector's reference position).
    pub angle_err_deg: f64,
    /// Measured d and q current in the control frame, A.
    pub i_d_a: f64,
    /// Measured q current in the control frame, A.
    pub i_q_a: f64,
}

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
    /// Longest time from the reference speed leaving the low-speed band to `Running`, s
    /// (`None` if the drive never left the low-speed mode).
    pub relock_time_max_s: Option<f64>,
    /// Number of low-speed exits measured.
    pub relocks: usize,
    /// Largest change of the current reference vector between two periods, A, over the
    /// whole run (beyond its rotation at the reference speed).
    pub current_ref_step_max_a: f64,
    /// The same within five periods of a change of the drive's state: the mode
    /// transitions (the bumpless floor), A.
    pub current_ref_step_transition_max_a: f64,
    /// When the largest current reference step happened, s.
    pub current_ref_step_max_t_s: f64,
    /// When the largest position error happened, s.
    pub x_err_max_t_s: f64,
    /// 5 % of the rated peak current, A (the bumpless floor).
    pub current_step_limit_a: f64,
    /// Low-speed threshold and low-speed current vector amplitude, m/s and A.
    pub low_speed_m_per_s: f64,
    /// Low-speed current amplitude, A.
    pub low_speed_current_a: f64,
    /// Largest |true - control angle| while running sensorless, electrical degrees.
    pub angle_err_running_max_deg: f64,
    /// Moves completed.
    pub moves_done: usize,
}

/// The plant for `motor`: carriage, friction, R +20 %, L -5 %; for a salient motor
/// (`L_q / L_d >= 1.15`, an interior-magnet design, whose iron saturates along the
/// magnet) a d axis whose incremental inductance is 10 % lower at the rated peak
/// current ([`PlantParams::d_saturation_for`]), which its HFI polarity test reads. The
/// surface-magnet motors' plants stay linear (their figures are those of before).
pub fn plant_for(motor: &MotorParams) -> SimParams {
    let mut p = SimParams::from_motor(motor);
    if motor.lq_h >= dcfo::hfi::MIN_SALIENCY * motor.ld_h {
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

/// The drive for `motor` from the motor file alone, positioning over the stroke.
pub fn drive_for(motor: &MotorParams) -> DriveConfig {
    let bus = InverterParams::from_motor(motor).dc_bus_v as f32;
    let mut d = DriveConfig::for_motor(motor, bus, ObserverKind::Dcfo);
    d.moving_mass_kg = motor.mass_kg + PAYLOAD_KG as f32;
    d.dead_time_compensation =
        Some(DeadTimeCompensation { dead_time_s: 2e-6, device_drop_v: 0.95, current_band_a: 0.01 });
    let limits = ProfileLimits {
        max_speed_m_per_s: MAX_SPEED_M_PER_S,
        max_accel_m_per_s2: MAX_ACCEL_M_PER_S2,
        stroke_min_m: -0.01,
        stroke_max_m: STROKE_M + 0.01,
    };
    d.motion = Some(MotionConfig::for_drive(motor, &d, limits));
    d
}

/// Runs the stroke on `motor` (named `name`), logging every `log_every` periods.
pub fn run(name: &str, motor: &MotorParams, log_every: usize) -> Result<(StrokeSummary, Vec<Row>), String> {
    let sim = plant_for(motor);
    let config = drive_for(motor);
    let motion = config.motion.ok_or("no motion config")?;
    let mut drive =
        Drive::<f32>::new(motor, &config, &Base::SI).map_err(|e| format!("drive config: {e:?}"))?;
    let mut plant = Plant::new(&sim).map_err(|e| e.to_string())?;
    // The host feeds the drive's fixed-capacity queue as it drains, as a host over a
    // link would.
    let mut moves: std::collections::VecDeque<Move> = (0..MOVES)
        .map(|i| Move { target_m: if i % 2 == 0 { STROKE_M } else { 0.0 }, dwell_s: DWELL_S })
        .collect();
    let ts = plant.pwm_period_s();
    let tau = f64::from(motor.pole_pitch_m);
    let rated_peak = f64::from(motor.rated_current_a) * 2f64.sqrt();
    // Long enough for every move: each takes d / v + v / a plus the dwell; margin 1 s.
    let per_move = f64::from(STROKE_M / MAX_SPEED_M_PER_S + MAX_SPEED_M_PER_S / MAX_ACCEL_M_PER_S2 + DWELL_S);
    let duration = 0.3 + MOVES as f64 * per_move + 1.0;
    let n = (duration / ts).round() as usize;
    let mut pending = [0.5f64; 3];
    let mut pending_on = false;
    let mut rows = Vec::new();
    let (mut x_err_max, mut x_err_final) = (0.0f64, 0.0f64);
    let mut aligned = false;
    let mut prev_ref_ab: Option<(f64, f64)> = None;
    let mut step_max = 0.0f64;
    let mut step_max_t = 0.0f64;
    let mut transition_step_max = 0.0f64;
    let mut last_change = 0usize;
    let mut last_state = DriveState::Disabled;
    let mut x_err_max_t = 0.0f64;
    let mut exit_since: Option<f64> = None;
    let mut relocks = Vec::new();
    let mut angle_err_running = 0.0f64;
    let mut prev_v_ref = 0.0f64;
    let mut reversals = 0usize;
    let mut last_dir = 0.0f64;
    let exit_speed = f64::from(motion.low_speed_m_per_s * motion.low_speed_exit_ratio);
    let mut moves_done = 0usize;
    for k in 0..n {
        let t = k as f64 * ts;
        while let Some(&m) = moves.front() {
            match drive.push_move(m) {
                Ok(()) => {
                    moves.pop_front();
                }
                Err(dcfo::motion::MotionError::QueueFull) => break,
                Err(e) => return Err(format!("move to {} m: {e:?}", m.target_m)),
            }
        }
        let reading = plant.sample();
        let truth = plant.state();
        drive.enable();
        let m = reading.measurements();
        let out = drive.step(&m);
        if pending_on {
            plant.step(pending, 0.0);
        } else {
            plant.step_open(0.0);
        }
        pending_on = out.bridge_enabled;
        pending = [f64::from(out.duties.a), f64::from(out.duties.b), f64::from(out.duties.c)];
        if out.state != last_state {
            last_change = k;
            last_state = out.state;
        }
        let sp = drive.setpoint().unwrap_or_default();
        let v_ref = f64::from(sp.speed_m_per_s);
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
        let x_hat = f64::from(drive.position_m());
        let x = truth.x_m;
        let angle_err =
            crate::trace::wrap_angle(truth.theta_e_rad - out.theta_control.to_radians::<f64>()).to_degrees();
        if out.state == DriveState::LowSpeed && !aligned && sp.position_m == 0.0 && t > 0.2 {
            aligned = true;
        }
        if out.state != DriveState::LowSpeed
            && out.state != DriveState::Disabled
            && out.state != DriveState::Calibrating
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
        if out.state == DriveState::Running {
            angle_err_running = angle_err_running.max(angle_err.abs());
        }
        // Bumpless: the reference current vector in alpha-beta, step by step.
        if matches!(out.state, DriveState::Running | DriveState::LowSpeed | DriveState::Reacquiring) {
            let cs = dcfo::transforms::CosSin::<f32>::new(out.theta_control);
            let r = inverse_park(Dq::new(out.i_dq_ref.d, out.i_dq_ref.q), &cs);
            let r = (f64::from(r.alpha), f64::from(r.beta));
            if let Some(p) = prev_ref_ab {
                // Discount the rotation of a constant vector at the reference speed.
                let turn = (v_ref * PI / tau * ts).abs();
                let mag = (r.0 * r.0 + r.1 * r.1).sqrt();
                let step = ((r.0 - p.0).powi(2) + (r.1 - p.1).powi(2)).sqrt() - mag * turn;
                if step > step_max {
                    step_max = step;
                    step_max_t = t;
                }
                if k < last_change + 5 && step > transition_step_max {
                    transition_step_max = step;
                }
            }
            prev_ref_ab = Some(r);
        } else {
            prev_ref_ab = None;
        }
        // Re-lock: from the reference speed leaving the low-speed band to Running.
        if out.state == DriveState::LowSpeed && v_ref.abs() > exit_speed {
            exit_since.get_or_insert(t);
        } else if out.state == DriveState::Running {
            if let Some(t0) = exit_since.take() {
                relocks.push(t - t0);
            }
        } else {
            exit_since = None;
        }
        if k % log_every == 0 {
            rows.push(Row {
                t_s: t,
                x_m: x,
                x_hat_m: x_hat,
                x_ref_m: f64::from(sp.position_m),
                v_m_per_s: truth.v_m_per_s,
                v_ref_m_per_s: v_ref,
                state: out.state.code(),
                angle_err_deg: angle_err,
                i_d_a: f64::from(out.i_dq.d),
                i_q_a: f64::from(out.i_dq.q),
            });
        }
        if out.state == DriveState::Fault {
            break;
        }
    }
    let faults = drive.faults();
    let summary = StrokeSummary {
        motor: name.to_string(),
        pole_pitch_m: tau,
        reversals,
        faults: faults.bits().count_ones(),
        fault_names: format!("{faults:?}"),
        x_err_max_m: x_err_max,
        x_err_final_m: x_err_final,
        relock_time_max_s: relocks.iter().copied().reduce(f64::max),
        relocks: relocks.len(),
        current_ref_step_max_a: step_max,
        current_ref_step_transition_max_a: transition_step_max,
        current_ref_step_max_t_s: step_max_t,
        x_err_max_t_s: x_err_max_t,
        current_step_limit_a: 0.05 * rated_peak,
        low_speed_m_per_s: f64::from(motion.low_speed_m_per_s),
        low_speed_current_a: f64::from(motion.low_speed_current_a),
        angle_err_running_max_deg: angle_err_running,
        moves_done,
    };
    Ok((summary, rows))
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
    row(
        "moves / reversals",
        format!("{} / {}", s.moves_done, s.reversals),
        ">= 10 rev".into(),
        s.reversals >= 10,
    );
    row(
        "faults",
        format!("{} {}", s.faults, if s.faults > 0 { &s.fault_names } else { "" }),
        "0".into(),
        s.faults == 0,
    );
    row("max |x_hat - x|", mm(s.x_err_max_m), mm(tau / 4.0), s.x_err_max_m <= tau / 4.0);
    row("final |x_hat - x|", mm(s.x_err_final_m), mm(tau / 60.0), s.x_err_final_m <= tau / 60.0);
    row(
        &format!("re-lock after low speed ({} exits)", s.relocks),
        ms(s.relock_time_max_s),
        "100 ms".into(),
        s.relock_time_max_s.is_some_and(|t| t <= 0.1),
    );
    row(
        "current step at mode transitions",
        format!("{:.3} A", s.current_ref_step_transition_max_a),
        format!("{:.3} A", s.current_step_limit_a),
        s.current_ref_step_transition_max_a <= s.current_step_limit_a,
    );
    out += &format!(
        "largest current reference step anywhere {:.3} A (the speed loop's steps included)\n",
        s.current_ref_step_max_a
    );
    out += &format!(
        "low-speed mode below {:.3} m/s with {:.2} A; max angle error running sensorless {:.1} deg\n",
        s.low_speed_m_per_s, s.low_speed_current_a, s.angle_err_running_max_deg
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
}

/// `dcfo stroke`: the positioning drive over the stroke, its results in `params.out`
/// and the table (or JSON) on stdout.
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
    let started = std::time::Instant::now();
    let (summary, rows) =
        run(&params.motor, &motor.params, 10).map_err(|e| anyhow::anyhow!("{}: {e}", params.motor))?;
    let out = &params.out;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    std::fs::write(out.join("stroke.json"), serde_json::to_string_pretty(&summary)?)
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
    crate::plot::write_figure(&figure(&summary, &rows), &out.join("stroke"))?;
    eprintln!("stroke: {:.1} s; results in {}", started.elapsed().as_secs_f64(), out.display());
    if params.json {
        println!("{}", serde_json::to_string(&summary)?);
    } else {
        print!("{}", table(&summary));
    }
    Ok(())
}
