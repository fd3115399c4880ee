//! `dcfo identify`: the drive's commissioning (`dcfo::drive::Commissioning`) run on the
//! simulated plant built from a motor, identified values against the plant's truth.
//!
//! The plant is [`SimParams::from_motor`] (dead time, device drops, sensor offsets, gain
//! errors and noise, Coulomb friction, end effect, the bare mover) with the mover placed
//! off alignment (electrical angle 1 rad). The drive (`Drive<f32>`, the firmware's control
//! step) is told only the rated current and voltage, the nominal bus and the pole pitch.
//!
//! Truth for the resistance: the *terminal* resistance, the winding's plus the mean slope
//! resistance of the inverter's devices (`(r_igbt + r_diode) / 2`), which no terminal
//! test can separate (`dcfo::drive` commissioning docs); the winding resistance and its
//! error are reported alongside (`rs_winding_ohm`). Truth for the voltage error: the
//! per-phase error of a current that keeps its sign, `dead_time / Ts * V_dc + (V_igbt0 +
//! V_diode0) / 2`.

use std::f64::consts::PI;
use std::fmt::Write as _;

use dcfo::drive::{
    CommissioningConfig, CommissioningError, CommissioningResult, Drive, DriveConfig, DriveState,
};
use dcfo::motor::MotorParams;
use dcfo::observer::ObserverKind;
use dcfo::units::Base;
use serde::Serialize;

use crate::plant::{Plant, SimParams};

/// Something wrong with the simulated motor, for the tests of the refusals.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PlantFault {
    /// A healthy motor.
    #[default]
    None,
    /// A phase disconnected (0, 1, 2: a, b, c).
    OpenPhase(usize),
    /// A short across the motor terminals: the drive sees only the cable up to the short
    /// (R and L a hundredth of the motor's, no back-EMF: the motor is bypassed).
    ShortedTerminals,
    /// A motor without magnets (psi_f = 0).
    NoMagnet,
    /// The bus at half the nominal value the drive is told.
    LowBus,
}

/// One identified quantity against the truth.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Compared {
    /// What commissioning measured.
    pub identified: f64,
    /// The plant's truth.
    pub r#true: f64,
    /// `100 (identified - true) / true`, %.
    pub err_pct: f64,
}

impl Compared {
    fn new(identified: f64, truth: f64) -> Self {
        Compared { identified, r#true: truth, err_pct: 100.0 * (identified - truth) / truth }
    }
}

/// The report of one identification.
#[derive(Clone, Debug, Serialize)]
pub struct IdentifyReport {
    /// Motor name.
    pub motor: String,
    /// Noise seed of the plant.
    pub seed: u64,
    /// Terminal resistance (winding + device slope), ohm.
    pub rs_ohm: Compared,
    /// The same identified value against the winding resistance alone, ohm.
    pub rs_winding_ohm: Compared,
    /// d-axis inductance, H.
    pub ld_h: Compared,
    /// q-axis inductance, H.
    pub lq_h: Compared,
    /// Magnet flux linkage, Wb.
    pub psi_f_wb: Compared,
    /// Saturated per-phase voltage error of the inverter, V.
    pub voltage_error_v: Compared,
    /// Current band of the compensation, A.
    pub current_band_a: f64,
    /// Measured bus, V.
    pub bus_v: f64,
    /// The voltage-error curve: (alpha current A, per-phase error V).
    pub curve: Vec<(f64, f64)>,
    /// Direction convention check (+1).
    pub direction: i8,
    /// Commissioning time (simulated), s.
    pub duration_s: f64,
    /// Largest travel of the mover from its start, m.
    pub travel_max_m: f64,
    /// The raw result.
    #[serde(skip)]
    pub result: Option<CommissioningResult>,
}

/// Why identification did not produce a motor.
#[derive(Debug, thiserror::Error)]
pub enum IdentifyError {
    /// The commissioning stopped with a named error (the bridge was off from then on).
    #[error("commissioning stopped: {0} (bridge off)")]
    Commissioning(CommissioningError),
    /// The simulation could not be set up.
    #[error("{0}")]
    Setup(String),
    /// The commissioning did not end in time.
    #[error("commissioning did not end within {0} s")]
    Timeout(f64),
}

/// What commissioning is told about `motor`: ratings, its nominal bus `sqrt(2) V_rated`
/// and pole pitch.
pub fn told(motor: &MotorParams) -> CommissioningConfig {
    CommissioningConfig {
        rated_current_a: motor.rated_current_a,
        rated_voltage_v: motor.rated_voltage_v,
        bus_v: motor.rated_voltage_v * core::f32::consts::SQRT_2,
        pole_pitch_m: motor.pole_pitch_m,
    }
}

/// The simulated plant for `motor` (module docs) with `fault`, noise seed `seed`.
pub fn plant_for(motor: &MotorParams, seed: u64, fault: PlantFault) -> SimParams {
    let mut p = SimParams::from_motor(motor);
    p.seed = seed;
    match fault {
        PlantFault::ShortedTerminals => {
            p.plant.rs_ohm *= 0.01;
            p.plant.ld_h *= 0.01;
            p.plant.lq_h *= 0.01;
            p.plant.psi_f_wb = 0.0;
        }
        PlantFault::NoMagnet => p.plant.psi_f_wb = 0.0,
        PlantFault::LowBus => p.inverter.dc_bus_v *= 0.5,
        PlantFault::None | PlantFault::OpenPhase(_) => {}
    }
    p
}

/// Runs the commissioning of a `Drive<f32>` on the plant for `motor`.
pub fn identify(
    name: &str,
    motor: &MotorParams,
    seed: u64,
    fault: PlantFault,
) -> Result<IdentifyReport, IdentifyError> {
    let sim = plant_for(motor, seed, fault);
    let config = told(motor);
    let placeholder = config.placeholder_motor();
    let drive_config = DriveConfig::for_motor(&placeholder, config.bus_v, ObserverKind::Dcfo);
    let mut drive = Drive::<f32>::new(&placeholder, &drive_config, &Base::SI)
        .map_err(|e| IdentifyError::Setup(format!("drive: {e}")))?;
    let mut plant = Plant::new(&sim).map_err(|e| IdentifyError::Setup(e.to_string()))?;
    // Start off alignment: the commissioning's alignment has to pull the mover.
    let x0 = 1.0 * sim.plant.pole_pitch_m / PI;
    plant.set_position(x0).map_err(|e| IdentifyError::Setup(e.to_string()))?;
    if let PlantFault::OpenPhase(k) = fault {
        plant.set_open_phase(Some(k));
    }
    drive.start_commissioning(config).map_err(IdentifyError::Commissioning)?;
    let ts = plant.pwm_period_s();
    let limit_s = 10.0;
    let n = (limit_s / ts) as usize;
    let mut pending = [0.5f64; 3];
    let mut pending_on = false;
    let mut travel_max = 0.0f64;
    let mut started = false;
    for _ in 0..n {
        let reading = plant.sample();
        let m = reading.measurements();
        let out = drive.step(&m);
        if pending_on {
            plant.step(pending, 0.0);
        } else {
            plant.step_open(0.0);
        }
        pending_on = out.bridge_enabled;
        pending = [f64::from(out.duties.a), f64::from(out.duties.b), f64::from(out.duties.c)];
        travel_max = travel_max.max((plant.state().x_m - x0).abs());
        if out.state == DriveState::Commissioning {
            started = true;
        }
        if started && out.state != DriveState::Commissioning {
            break;
        }
    }
    let result = match drive.commissioning_result() {
        Some(Ok(r)) => r,
        Some(Err(e)) => return Err(IdentifyError::Commissioning(e)),
        None => return Err(IdentifyError::Timeout(limit_s)),
    };
    let p = &sim.plant;
    let inv = &sim.inverter;
    let slope = 0.5 * (inv.igbt_slope_ohm + inv.diode_slope_ohm);
    let e_true = inv.dead_time_error_v() + 0.5 * (inv.igbt_threshold_v + inv.diode_threshold_v);
    Ok(IdentifyReport {
        motor: name.to_string(),
        seed,
        rs_ohm: Compared::new(f64::from(result.rs_ohm), p.rs_ohm + slope),
        rs_winding_ohm: Compared::new(f64::from(result.rs_ohm), p.rs_ohm),
        ld_h: Compared::new(f64::from(result.ld_h), p.ld_h),
        lq_h: Compared::new(f64::from(result.lq_h), p.lq_h),
        psi_f_wb: Compared::new(f64::from(result.psi_f_wb), p.psi_f_wb),
        voltage_error_v: Compared::new(f64::from(result.voltage_error_v), e_true),
        current_band_a: f64::from(result.current_band_a),
        bus_v: f64::from(result.bus_v),
        curve: result.curve.iter().map(|p| (f64::from(p.current_a), f64::from(p.error_v))).collect(),
        direction: result.direction,
        duration_s: f64::from(result.duration_s),
        travel_max_m: travel_max,
        result: Some(result),
    })
}

/// The identified-against-true table.
pub fn table(r: &IdentifyReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "identify {} (seed {}): {:.2} s, travel {:.3} m",
        r.motor, r.seed, r.duration_s, r.travel_max_m
    );
    let _ = writeln!(s, "{:<34} {:>12} {:>12} {:>8}", "quantity", "identified", "true", "err %");
    let row = |s: &mut String, name: &str, c: &Compared| {
        let _ = writeln!(s, "{:<34} {:>12.6} {:>12.6} {:>+8.2}", name, c.identified, c.r#true, c.err_pct);
    };
    row(&mut s, "Rs terminal (winding + device), ohm", &r.rs_ohm);
    row(&mut s, "Rs against the winding alone, ohm", &r.rs_winding_ohm);
    row(&mut s, "Ld, H", &r.ld_h);
    row(&mut s, "Lq, H", &r.lq_h);
    row(&mut s, "psi_f, Wb", &r.psi_f_wb);
    row(&mut s, "inverter voltage error, V", &r.voltage_error_v);
    let _ = writeln!(
        s,
        "compensation band {:.4} A at bus {:.1} V; direction {:+}",
        r.current_band_a, r.bus_v, r.direction
    );
    let _ = write!(s, "voltage-error curve (A: V):");
    for (i, e) in &r.curve {
        let _ = write!(s, " {i:.3}: {e:.3};");
    }
    s.push('\n');
    s
}

/// The identified motor as a motor file (shared format), with the ratings and pole pitch
/// the drive was told; mass and friction are not identified and left out (readers default
/// them). The inverter compensation is noted in comments.
pub fn motor_toml(r: &IdentifyReport, motor: &MotorParams) -> Result<String, IdentifyError> {
    let result = r.result.ok_or_else(|| IdentifyError::Setup("no result".into()))?;
    let m = result
        .motor(&told(motor), motor.mass_kg, motor.viscous_n_s_per_m)
        .map_err(|e| IdentifyError::Setup(format!("identified motor refused: {e:?}")))?;
    let comp = result.dead_time_compensation(1e-4);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Identified by `dcfo identify` (commissioning on the simulated plant of {}, seed {}).",
        r.motor, r.seed
    );
    let _ = writeln!(s, "# rs_ohm is the terminal resistance (winding + inverter device slope).");
    let _ = writeln!(
        s,
        "# Inverter voltage error {:.4} V per phase at {:.1} V bus (dead time {:.4e} s at 10 kHz), band {:.4} A.",
        result.voltage_error_v, result.bus_v, comp.dead_time_s, comp.current_band_a
    );
    let _ = writeln!(s, "name = \"{}-identified\"", r.motor.replace(['"', '\\'], "_"));
    let _ = writeln!(s, "rs_ohm = {:?}", m.rs_ohm);
    let _ = writeln!(s, "ld_h = {:?}", m.ld_h);
    let _ = writeln!(s, "lq_h = {:?}", m.lq_h);
    let _ = writeln!(s, "psi_f_wb = {:?}", m.psi_f_wb);
    let _ = writeln!(s, "pole_pitch_m = {:?}", m.pole_pitch_m);
    let _ = writeln!(s, "rated_current_a = {:?}", m.rated_current_a);
    let _ = writeln!(s, "rated_voltage_v = {:?}", m.rated_voltage_v);
    Ok(s)
}

/// The one-line JSON object of `--json`.
pub fn json_line(r: &IdentifyReport) -> String {
    serde_json::json!({
        "motor": r.motor,
        "seed": r.seed,
        "rs_ohm": r.rs_ohm,
        "rs_ohm_true_is": "terminal: winding + mean device slope resistance",
        "rs_winding_ohm": r.rs_winding_ohm,
        "ld_h": r.ld_h,
        "lq_h": r.lq_h,
        "psi_f_wb": r.psi_f_wb,
        "voltage_error_v": r.voltage_error_v,
        "current_band_a": r.current_band_a,
        "direction": r.direction,
        "duration_s": r.duration_s,
    })
    .to_string()
}

/// The light-load steady angle error of the paper axis (`dcfo sim steady`: 0.3 m/s, no
/// load, [`crate::sim::Setup::paper`]) for one plant noise seed, under four inverter
/// compensations: none, the typed-in one of [`DriveConfig::paper_axis`], the one
/// identified by commissioning (`identified`, on the paper motor's plant with the same
/// seed), and the identified compensation together with the identified motor.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct SteadyRow {
    /// Plant noise seed.
    pub seed: u64,
    /// RMS angle error without compensation, electrical degrees (`None`: the run did not
    /// stay healthy, e.g. lost lock).
    pub none_deg: Option<f64>,
    /// With the typed-in compensation (2 us, 0.95 V, 0.01 A).
    pub typed_deg: Option<f64>,
    /// With the identified compensation.
    pub identified_comp_deg: Option<f64>,
    /// With the identified compensation and the identified motor (Rs, Ld, Lq, psi_f).
    pub identified_all_deg: Option<f64>,
}

/// Runs the four steady runs of [`SteadyRow`] for `seed`.
pub fn steady_row(seed: u64) -> Result<SteadyRow, IdentifyError> {
    use crate::sim::scenarios::{figures, scenario};
    use crate::sim::{Setup, run};
    let paper = MotorParams::paper();
    let report = identify("paper", &paper, seed, PlantFault::None)?;
    let result = report.result.ok_or_else(|| IdentifyError::Setup("no result".into()))?;
    let sc = scenario("steady").ok_or_else(|| IdentifyError::Setup("no steady scenario".into()))?;
    let base = Setup::paper(ObserverKind::Dcfo);
    let comp = result.dead_time_compensation(base.drive.control_period_s);
    let identified_motor = result
        .motor(&told(&paper), paper.mass_kg, paper.viscous_n_s_per_m)
        .map_err(|e| IdentifyError::Setup(format!("{e:?}")))?;
    let once = |motor: MotorParams, c: Option<dcfo::drive::DeadTimeCompensation>| -> Option<f64> {
        let mut setup = base.clone();
        setup.plant.seed = seed;
        setup.motor = motor;
        setup.drive.dead_time_compensation = c;
        let estimator = dcfo::estimator::EstimatorConfig::for_motor(&motor, ObserverKind::Dcfo);
        setup.drive.estimator = estimator;
        let r = run(&setup, &sc, |_| {}).ok()?;
        let f = figures(&r, &sc);
        f.healthy.then_some(f.theta_err_rms_deg)
    };
    Ok(SteadyRow {
        seed,
        none_deg: once(paper, None),
        typed_deg: once(paper, base.drive.dead_time_compensation),
        identified_comp_deg: once(paper, Some(comp)),
        identified_all_deg: once(identified_motor, Some(comp)),
    })
}

// ---- The command.

/// Where `dcfo identify` runs the commissioning.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Where {
    /// In this process, against the simulated plant of the motor.
    Sim,
    /// The firmware under QEMU (not implemented: exit status 2).
    Qemu,
    /// A board on this serial port (not implemented: exit status 2).
    Port(String),
    /// Not said (an error).
    Unsaid,
}

/// What `dcfo identify` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// Where the commissioning runs.
    pub place: Where,
    /// Motor the plant is built from: a preset name (`paper`) or a motor TOML file.
    pub motor: String,
    /// Seed of the plant's sensor noise.
    pub seed: u64,
    /// Write the identified motor (shared motor-file format) to this file.
    pub output: Option<std::path::PathBuf>,
    /// Print one JSON object on the last line of stdout.
    pub json: bool,
    /// Instead: the light-load steady angle error (electrical degrees) over this many
    /// plant seeds (1..=N), and the medians.
    pub steady_seeds: Option<u64>,
}

/// `dcfo identify`: runs the commissioning (or the steady-error comparison) and prints
/// the table; exit status 2 for a place that is not implemented.
pub fn run_command(params: &Params) -> anyhow::Result<std::process::ExitCode> {
    use anyhow::Context;
    use std::process::ExitCode;
    match params.place {
        Where::Qemu | Where::Port(_) => {
            eprintln!(
                "dcfo identify: --qemu and --port are not implemented yet (the firmware images do \
                 not run commissioning over the link); use --sim"
            );
            return Ok(ExitCode::from(2));
        }
        Where::Unsaid => {
            anyhow::bail!("identify: say where to run the commissioning: --sim (or --qemu, --port)")
        }
        Where::Sim => {}
    }
    if let Some(seeds) = params.steady_seeds {
        let median = |mut v: Vec<f64>| -> String {
            if v.is_empty() {
                return "-".into();
            }
            v.sort_by(f64::total_cmp);
            let n = v.len();
            format!("{:.3}", if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) })
        };
        let show = |x: Option<f64>| x.map_or("lost".to_string(), |d| format!("{d:.3}"));
        println!("seed  none(deg)  typed-in  identified-comp  identified-motor+comp");
        let mut rows = Vec::new();
        for seed in 1..=seeds {
            let r = steady_row(seed).map_err(|e| anyhow::anyhow!("seed {seed}: {e}"))?;
            println!(
                "{:>4}  {:>9}  {:>8}  {:>15}  {:>21}",
                seed,
                show(r.none_deg),
                show(r.typed_deg),
                show(r.identified_comp_deg),
                show(r.identified_all_deg)
            );
            rows.push(r);
        }
        let col = |f: fn(&SteadyRow) -> Option<f64>| -> (String, usize) {
            let v: Vec<f64> = rows.iter().filter_map(f).collect();
            let lost = rows.len() - v.len();
            (median(v), lost)
        };
        let cols = [
            col(|r| r.none_deg),
            col(|r| r.typed_deg),
            col(|r| r.identified_comp_deg),
            col(|r| r.identified_all_deg),
        ];
        println!(
            "median rms angle error (deg; runs lost): none {} ({}), typed-in {} ({}), identified comp {} ({}), \
             identified motor + comp {} ({})",
            cols[0].0, cols[0].1, cols[1].0, cols[1].1, cols[2].0, cols[2].1, cols[3].0, cols[3].1
        );
        if params.json {
            println!("{}", serde_json::to_string(&rows)?);
        }
        return Ok(ExitCode::SUCCESS);
    }
    let motor = crate::motor_file::load_motor(&params.motor)?;
    let report = identify(&params.motor, &motor.params, params.seed, Default::default())
        .map_err(|e| anyhow::anyhow!("identify {}: {e}", params.motor))?;
    if let Some(path) = &params.output {
        let text = motor_toml(&report, &motor.params)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    print!("{}", table(&report));
    if params.json {
        println!("{}", json_line(&report));
    }
    Ok(ExitCode::SUCCESS)
}
