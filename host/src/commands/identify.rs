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

use dcfo::algorithms::observer::ObserverKind;
use dcfo::drive::{CommissioningConfig, CommissioningError, CommissioningResult, Drive, DriveState};
use dcfo::link::{ActuationFrame, CommissioningStatus, LinkStats, SensorFrame};
use dcfo::motor::MotorParams;
use dcfo::motor_image::{MotorAxis, MotorImage};
use dcfo::num::units::Base;
use dcfo::num::{Q24, Scalar};
use serde::Serialize;

use crate::closed_loop::ClosedLoop;
use crate::plant::{Plant, SimParams};
use crate::simulation::{frame_bridge, sensor_frame};

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
    /// The link to the drive failed (QEMU or a serial port).
    #[error("link: {0}")]
    Link(String),
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

/// A drive that runs commissioning: in this process ([`InProcess`]) or behind the HIL
/// link (the firmware on QEMU or a board: [`crate::hil_link::SerialController`]).
pub trait Commissioner {
    /// Requests commissioning of a drive told only `config`.
    ///
    /// # Errors
    /// [`IdentifyError::Commissioning`] when the drive refuses; a link failure.
    fn start(&mut self, config: CommissioningConfig) -> Result<(), IdentifyError>;
    /// One control period on `sensor` (measurements and commands): the drive's answer.
    ///
    /// # Errors
    /// A link failure.
    fn step(&mut self, sensor: &SensorFrame) -> Result<ActuationFrame, IdentifyError>;
    /// The last commissioning's outcome, `None` while none has ended.
    ///
    /// # Errors
    /// A link failure.
    fn outcome(&mut self) -> Result<Option<Result<CommissioningResult, CommissioningError>>, IdentifyError>;
}

/// The library's drive in this process, built as the HIL link builds it on a start
/// request ([`Drive::for_commissioning`]): `Drive<f32>` in SI ([`InProcess::f32`], as
/// the Cortex-M4F firmware) or `Drive<Q24>` in the told ratings' per-unit base
/// ([`InProcess::q24`], as the Cortex-M3 firmware).
#[derive(Debug, Clone)]
pub struct InProcess<T> {
    drive: Option<Drive<T>>,
    like: Base,
}

impl InProcess<f32> {
    /// An f32 drive in SI units (built at [`Commissioner::start`]).
    pub fn f32() -> Self {
        InProcess { drive: None, like: Base::SI }
    }
}

impl InProcess<Q24> {
    /// A Q8.24 drive in the per-unit base of the told ratings (built at
    /// [`Commissioner::start`]).
    pub fn q24() -> Self {
        InProcess { drive: None, like: Base::for_motor(&MotorParams::paper()) }
    }
}

impl<T: Scalar> Commissioner for InProcess<T> {
    fn start(&mut self, config: CommissioningConfig) -> Result<(), IdentifyError> {
        self.drive =
            Some(Drive::for_commissioning(config, &self.like).map_err(IdentifyError::Commissioning)?);
        Ok(())
    }

    fn step(&mut self, sensor: &SensorFrame) -> Result<ActuationFrame, IdentifyError> {
        let drive = self.drive.as_mut().ok_or_else(|| IdentifyError::Setup("not started".into()))?;
        // The calls `LinkServer::on_byte` makes on a received frame.
        let base = *drive.base();
        sensor
            .apply_commands(drive)
            .map_err(|e| IdentifyError::Setup(format!("the drive refused the frame's move: {e:?}")))?;
        let out = drive.step(&sensor.measurements(&base));
        Ok(ActuationFrame::from_step(sensor.sequence, &out, &base, LinkStats::default()))
    }

    fn outcome(&mut self) -> Result<Option<Result<CommissioningResult, CommissioningError>>, IdentifyError> {
        Ok(self.drive.as_ref().and_then(Drive::commissioning_result))
    }
}

impl<W: std::io::Write> Commissioner for crate::hil_link::SerialController<W> {
    fn start(&mut self, config: CommissioningConfig) -> Result<(), IdentifyError> {
        let report = self.commissioning(Some(config)).map_err(|e| IdentifyError::Link(e.to_string()))?;
        match (report.status, report.error()) {
            (CommissioningStatus::Running, _) => Ok(()),
            (_, Some(e)) => Err(IdentifyError::Commissioning(e)),
            (status, None) => Err(IdentifyError::Link(format!("start answered with status {status:?}"))),
        }
    }

    fn step(&mut self, sensor: &SensorFrame) -> Result<ActuationFrame, IdentifyError> {
        use crate::simulation::Controller;
        Controller::step(self, sensor).map(|s| s.frame).map_err(|e| IdentifyError::Link(e.to_string()))
    }

    fn outcome(&mut self) -> Result<Option<Result<CommissioningResult, CommissioningError>>, IdentifyError> {
        let report = self.commissioning(None).map_err(|e| IdentifyError::Link(e.to_string()))?;
        Ok(match report.status {
            CommissioningStatus::Done => report.result.map(Ok),
            CommissioningStatus::Failed | CommissioningStatus::Refused => report.error().map(Err),
            CommissioningStatus::Idle | CommissioningStatus::Running => None,
        })
    }
}

/// Runs the commissioning of a `Drive<f32>` in this process on the plant for `motor`.
pub fn identify(
    name: &str,
    motor: &MotorParams,
    seed: u64,
    fault: PlantFault,
) -> Result<IdentifyReport, IdentifyError> {
    identify_with(name, motor, seed, fault, &mut InProcess::f32())
}

/// Runs the commissioning of `drive` on the plant for `motor` in lock-step: per PWM
/// period one sensor frame (the plant's readings, enable, speed reference 0) and the
/// drive's answer, whose duties the plant applies over the next period, until the drive
/// leaves commissioning; then asks for the outcome.
pub fn identify_with(
    name: &str,
    motor: &MotorParams,
    seed: u64,
    fault: PlantFault,
    drive: &mut dyn Commissioner,
) -> Result<IdentifyReport, IdentifyError> {
    let sim = plant_for(motor, seed, fault);
    let config = told(motor);
    let mut plant = Plant::new(&sim).map_err(|e| IdentifyError::Setup(e.to_string()))?;
    // Start off alignment: the commissioning's alignment has to pull the mover.
    let x0 = 1.0 * sim.plant.pole_pitch_m / PI;
    plant.set_position(x0).map_err(|e| IdentifyError::Setup(e.to_string()))?;
    if let PlantFault::OpenPhase(k) = fault {
        plant.set_open_phase(Some(k));
    }
    drive.start(config)?;
    let ts = plant.pwm_period_s();
    let mut closed_loop = ClosedLoop::new(plant);
    let limit_s = 10.0;
    let n = (limit_s / ts) as usize;
    let mut travel_max = 0.0f64;
    let mut started = false;
    for k in 0..n {
        let sensed = closed_loop.sense();
        let out = drive.step(&sensor_frame(&sensed.reading, k as u16, 0.0, None))?;
        closed_loop.actuate(sensed, frame_bridge(&out), 0.0);
        travel_max = travel_max.max((closed_loop.plant().state().x_m - x0).abs());
        let state = out.state();
        if state == DriveState::Commissioning {
            started = true;
        }
        if (started && state != DriveState::Commissioning) || state == DriveState::Fault {
            break;
        }
    }
    let result = match drive.outcome()? {
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

/// The identified motor as a motor file (docs/motor-format.md), with the ratings and pole pitch
/// the drive was told; mass and friction are not identified and left out (readers default
/// them). The inverter compensation is noted in comments.
pub fn motor_toml(r: &IdentifyReport, motor: &MotorParams) -> Result<String, IdentifyError> {
    let result = r.result.ok_or_else(|| IdentifyError::Setup("no result".into()))?;
    let m = result
        .motor(&told(motor), motor.mass_kg, motor.viscous_n_s_per_m)
        .map_err(|e| IdentifyError::Setup(format!("identified motor refused: {e:?}")))?;
    let comp = result.dead_time_compensation(COMMISSIONING_PERIOD_S);
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

/// The identified motor as the board's flash record (`dcfo::motor_image`, version 3):
/// the motor of [`motor_toml`] (mass and friction of `motor`, not identified), the
/// nominal bus the drive was told, the identified inverter compensation as a dead
/// time at the commissioning's 100 us period, and `axis` (commissioning does not
/// identify one: `dcfo identify --image` keeps the axis of the image it overwrites);
/// checked by decoding it as the firmware does.
///
/// # Errors
/// No result, or a result or an axis the image refuses (named).
pub fn motor_image(
    r: &IdentifyReport,
    motor: &MotorParams,
    axis: Option<MotorAxis>,
) -> Result<[u8; MotorImage::LEN], IdentifyError> {
    let result = r.result.ok_or_else(|| IdentifyError::Setup("no result".into()))?;
    let mut image = result
        .motor_image(&told(motor), motor.mass_kg, motor.viscous_n_s_per_m, COMMISSIONING_PERIOD_S)
        .map_err(|e| IdentifyError::Setup(format!("identified motor refused for the image: {e}")))?;
    if let Some(axis) = axis {
        image = image
            .with_axis(axis)
            .map_err(|e| e.to_string())
            .and_then(|image| {
                dcfo::drive::DriveConfig::check_image_axis(&image)
                    .map(|()| image)
                    .map_err(|f| format!("axis `{}` is more than the motor can do", f.name()))
            })
            .map_err(|e| {
                IdentifyError::Setup(format!(
                    "the existing image's axis does not fit the identified motor: {e}"
                ))
            })?;
    }
    let bytes = image.encode();
    MotorImage::decode(&bytes).map_err(|e| IdentifyError::Setup(format!("encoded image: {e}")))?;
    Ok(bytes)
}

/// The PWM period the commissioning runs at (`DriveConfig::for_motor`'s), s.
pub const COMMISSIONING_PERIOD_S: f32 = 1e-4;

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
/// load, [`crate::simulation::Setup::paper`]) for one plant noise seed, under four inverter
/// compensations: none, the typed-in one of [`dcfo::drive::DriveConfig::paper_axis`], the one
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
    use crate::simulation::figures::figures;
    use crate::simulation::scenarios::scenario;
    use crate::simulation::{Setup, run};
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
#[derive(Debug, Clone)]
pub enum Where {
    /// In this process (`Drive<f32>`), against the simulated plant of the motor.
    Sim,
    /// On the firmware behind the lock-step HIL link, against the same simulated plant:
    /// the HIL image on QEMU ([`crate::target::Target::Qemu`]: f32 on the M4F, Q8.24 on
    /// the M3) or a board running it on a serial port.
    Link(crate::target::Target),
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
    /// Write the identified motor (a motor file, docs/motor-format.md) to this file.
    pub output: Option<std::path::PathBuf>,
    /// Write the identified motor, the nominal bus and the identified inverter
    /// compensation as a motor image (the board's flash record) to this file.
    pub image: Option<std::path::PathBuf>,
    /// Over the link: also run the commissioning in this process with the firmware's
    /// numeric type and require the results to be identical bit for bit.
    pub check: bool,
    /// Print one JSON object on the last line of stdout.
    pub json: bool,
    /// Instead: the light-load steady angle error (electrical degrees) over this many
    /// plant seeds (1..=N), and the medians.
    pub steady_seeds: Option<u64>,
}

/// A commissioning on the firmware behind the link ([`identify_over_link`]).
#[derive(Debug)]
pub struct OverLink {
    /// What it identified, against the plant's truth.
    pub report: IdentifyReport,
    /// Wall time from the link's start (QEMU's boot included) to the result, s.
    pub wall_s: f64,
    /// On QEMU: the firmware's deepest stack since boot, bytes (the drive it builds on
    /// the start request is built in the receive interrupt).
    pub stack_high_water_bytes: Option<u32>,
}

/// The commissioning on the firmware behind the link at `target`.
///
/// # Errors
/// QEMU or the port cannot be started or opened, the link fails, or the commissioning
/// stops with a named error.
pub fn identify_over_link(
    name: &str,
    motor: &MotorParams,
    seed: u64,
    target: &crate::target::Target,
) -> anyhow::Result<OverLink> {
    use crate::target::Target;
    let started = std::time::Instant::now();
    let report = match target {
        Target::Qemu { cpu, elf } => {
            let workspace = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .parent()
                .unwrap_or(std::path::Path::new("."));
            let elf = match elf {
                Some(e) => e.clone(),
                None => crate::hil_link::build_qemu_firmware(workspace, *cpu)?,
            };
            let started_qemu = std::time::Instant::now();
            let (session, mut link) = crate::qemu::QemuSession::start(&elf, *cpu)?;
            let report = identify_with(name, motor, seed, PlantFault::None, &mut link)?;
            let wall_s = started_qemu.elapsed().as_secs_f64();
            let stack_high_water_bytes = session.stack_high_water().ok();
            return Ok(OverLink { report, wall_s, stack_high_water_bytes });
        }
        Target::Port { device, baud } => {
            let (serial, reader) = crate::target::open_serial(device, *baud)?;
            let mut link = crate::hil_link::SerialController::new(serial, reader);
            identify_with(name, motor, seed, PlantFault::None, &mut link)?
        }
    };
    Ok(OverLink { report, wall_s: started.elapsed().as_secs_f64(), stack_high_water_bytes: None })
}

/// `true` when two results are the same bit for bit (every `f32`, the curve, the
/// direction).
pub fn identical(a: &CommissioningResult, b: &CommissioningResult) -> bool {
    let bits = |r: &CommissioningResult| {
        let mut v = vec![
            r.rs_ohm,
            r.ld_h,
            r.lq_h,
            r.psi_f_wb,
            r.voltage_error_v,
            r.current_band_a,
            r.bus_v,
            r.duration_s,
        ];
        v.extend(r.curve.iter().flat_map(|p| [p.current_a, p.error_v]));
        (v.into_iter().map(f32::to_bits).collect::<Vec<_>>(), r.direction)
    };
    bits(a) == bits(b)
}

/// `dcfo identify`: runs the commissioning (or the steady-error comparison) and prints
/// the table; writes the motor file and the motor image only from a finished
/// commissioning.
pub fn run_command(params: &Params) -> anyhow::Result<std::process::ExitCode> {
    use anyhow::Context;
    use std::process::ExitCode;
    match (&params.place, params.steady_seeds) {
        (Where::Unsaid, _) => {
            anyhow::bail!("identify: say where to run the commissioning: --sim, --qemu or --port DEVICE")
        }
        (Where::Link(_), Some(_)) => anyhow::bail!("identify: --steady runs in process only (--sim)"),
        _ => {}
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
    let report = match &params.place {
        Where::Link(target) => {
            let OverLink { report, wall_s, stack_high_water_bytes } =
                identify_over_link(&params.motor, &motor.params, params.seed, target)
                    .map_err(|e| anyhow::anyhow!("identify {}: {e}", params.motor))?;
            println!("commissioning over the HIL link took {wall_s:.1} s of wall time");
            if let Some(bytes) = stack_high_water_bytes {
                println!("deepest stack of the firmware since boot: {bytes} bytes");
            }
            if params.check {
                let local = match target.qemu_cpu() {
                    Some(crate::qemu::QemuCpu::M3) => identify_with(
                        &params.motor,
                        &motor.params,
                        params.seed,
                        PlantFault::None,
                        &mut InProcess::q24(),
                    ),
                    // A board on a serial port runs the f32 firmware.
                    _ => identify(&params.motor, &motor.params, params.seed, PlantFault::None),
                }
                .map_err(|e| anyhow::anyhow!("identify {} in process: {e}", params.motor))?;
                let same = match (&report.result, &local.result) {
                    (Some(a), Some(b)) => identical(a, b),
                    _ => false,
                };
                anyhow::ensure!(same, "the firmware's results differ from the in-process run's");
                println!("identical bit for bit to the in-process run of the same numeric type");
            }
            report
        }
        _ => identify(&params.motor, &motor.params, params.seed, Default::default())
            .map_err(|e| anyhow::anyhow!("identify {}: {e}", params.motor))?,
    };
    // Both files come from a finished commissioning only (an error returned above).
    if let Some(path) = &params.output {
        let text = motor_toml(&report, &motor.params)?;
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &params.image {
        // An axis in the image being overwritten is kept: commissioning identifies
        // the motor and the inverter, not the axis.
        let axis = crate::commands::motor_image::existing_axis(path);
        let bytes = motor_image(&report, &motor.params, axis)?;
        std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))?;
        println!(
            "motor image (version {}): {} bytes in {}, {}{}",
            MotorImage::VERSION,
            bytes.len(),
            path.display(),
            crate::commands::motor_image::describe_axis(axis),
            if axis.is_some() { " kept from the image it replaces" } else { "" }
        );
    }
    print!("{}", table(&report));
    if params.json {
        println!("{}", json_line(&report));
    }
    Ok(ExitCode::SUCCESS)
}
