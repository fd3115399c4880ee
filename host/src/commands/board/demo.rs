//! The non-interactive runs of `dcfo board`: [`run_demo`] (enable, capture, download,
//! replay bit for bit, disable) and [`run_move_demo`] (a move to a target and a refused
//! move outside the stroke).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use dcfo::algorithms::motion::Move;
use dcfo::algorithms::observer::ObserverKind;
use dcfo::capture::CaptureState;
use dcfo::drive::{DriveConfig, DriveState, PAPER_AXIS_BUS_V};
use dcfo::link::board::BoardTelemetry;
use dcfo::motor_image::MotorImage;

use super::capture::{replay_matches, write_capture_trace};
use super::link::{BoardOps, CONTROL_PERIOD_S, DriveClock, POLL_PERIOD, Wish};
use super::session::{interrupted, move_tolerance_m, qemu_drive_motor, status_line, with_board};
use crate::commands::sim::fault_names;
use crate::target::Target;
use crate::trace::InputTrace;

/// What `dcfo board --demo --move-to` did (its JSON line).
#[derive(Debug, serde::Serialize)]
pub struct MoveDemoReport {
    /// The most advanced state the drive reported.
    pub state_reached: String,
    /// Faults latched before the disable (`none`).
    pub faults: String,
    /// The move's target, m.
    pub target_m: f32,
    /// The drive's position estimate x̂ at the end, m.
    pub x_hat_m: f32,
    /// The profile's reference position at the end, m.
    pub x_ref_m: f32,
    /// `x_hat_m - target_m`, m.
    pub x_err_m: f32,
    /// The tolerance on `x_err_m` ([`move_tolerance_m`]), m.
    pub tolerance_m: f32,
    /// The reference came to rest at the target and x̂ is within the tolerance of it.
    pub move_reached: bool,
    /// Simulated time from the enable until the move was reached, s.
    pub move_s: Option<f64>,
    /// A move outside the stroke sent afterwards was refused and counted in the
    /// telemetry's position report.
    pub refused_move_reported: bool,
    /// Moves the drive image refused in all (its report's count).
    pub moves_rejected: u16,
    /// Control periods the image ran, as simulated time, s.
    pub simulated_s: f64,
    /// Wall-clock time from connecting to the disable, s.
    pub wall_s: f64,
}

/// `dcfo board --demo --move-to`: connect to a positioning drive image, enable at rest,
/// queue the move, poll until the reference is at rest at the target and x̂ has settled
/// within [`move_tolerance_m`] of it (or `timeout` of the drive's own time,
/// [`DriveClock`]), then send a move outside any stroke (1 km) and check the image
/// reports it refused, and disable.
///
/// # Errors
/// The link failed, the image reports no position (a speed drive), the drive tripped.
pub fn run_move_demo(
    target: &Target,
    image: Option<&MotorImage>,
    m: Move,
    timeout: Duration,
) -> anyhow::Result<MoveDemoReport> {
    let started = Instant::now();
    let motor = image.map_or_else(qemu_drive_motor, |i| i.motor);
    let tolerance_m = move_tolerance_m(&motor);
    with_board(target, image, |board| {
        let first = first_period(board)?;
        let Some(p0) = first.position else {
            let _ = board.disable();
            bail!(
                "the drive image reports no position: it runs a speed drive, which refuses every move; \
                 its motor image has no axis (a version-1 or -2 image, or written without one): write one with \
                 `dcfo motor-image ... --stroke-min-m --stroke-max-m --max-speed --max-accel --payload-kg`"
            );
        };
        *board.wish_mut() = Wish { enable: true, speed_m_per_s: 0.0 };
        board.queue_move(m);
        let mut t = board.poll(true, false)?;
        let enabled_at = t.periods;
        let mut best = t.state();
        let mut clock = DriveClock::start(&t);
        let mut reached_at = None;
        let mut settled = 0;
        loop {
            if t.state() == DriveState::Fault {
                let _ = board.disable();
                bail!("the drive tripped: {}", fault_names(t.faults()));
            }
            if interrupted() {
                let _ = board.disable();
                bail!("interrupted");
            }
            if let Some(p) = t.position
                && p.idle
                && p.x_ref_m == m.target_m
                && (p.x_hat_m - m.target_m).abs() < tolerance_m
            {
                reached_at.get_or_insert(t.periods);
                // Settled: within the tolerance for a few polls in a row.
                settled += 1;
                if settled >= 5 {
                    break;
                }
            } else {
                settled = 0;
                reached_at = None;
            }
            if clock.elapsed_s(&t)? > timeout.as_secs_f64() {
                break;
            }
            std::thread::sleep(POLL_PERIOD);
            t = board.poll(false, false)?;
            if state_rank(t.state()) > state_rank(best) {
                best = t.state();
            }
            eprint!("\r{}\x1b[K", status_line(&t));
        }
        eprintln!();
        let p = t.position.unwrap_or(p0);
        let rejected_before = p.moves_rejected;
        board.queue_move(Move { target_m: 1000.0, dwell_s: 0.0 });
        board.poll(false, false)?;
        // The refusal is counted at the image's next control period.
        std::thread::sleep(POLL_PERIOD);
        let after = board.poll(false, false)?;
        let rejected = after.position.map_or(rejected_before, |q| q.moves_rejected);
        let faults = fault_names(after.faults());
        let last = board.disable()?;
        let x_err_m = p.x_hat_m - m.target_m;
        Ok(MoveDemoReport {
            state_reached: format!("{best:?}"),
            faults,
            target_m: m.target_m,
            x_hat_m: p.x_hat_m,
            x_ref_m: p.x_ref_m,
            x_err_m,
            tolerance_m,
            move_reached: p.idle && p.x_ref_m == m.target_m && x_err_m.abs() < tolerance_m,
            move_s: reached_at.map(|k: u32| f64::from(k.wrapping_sub(enabled_at)) * CONTROL_PERIOD_S),
            refused_move_reported: rejected == rejected_before.wrapping_add(1),
            moves_rejected: rejected,
            simulated_s: f64::from(last.periods) * CONTROL_PERIOD_S,
            wall_s: started.elapsed().as_secs_f64(),
        })
    })
}

/// The first telemetry that follows a control period of the drive: the image may answer
/// before its control interrupt has run once (a host that connects at boot), and until
/// then its status is the power-on one (no position report even for a positioning drive).
///
/// # Errors
/// The link failed, or the drive's periods do not start ([`DriveClock`]).
fn first_period(board: &mut dyn BoardOps) -> anyhow::Result<BoardTelemetry> {
    let mut t = board.poll(false, false)?;
    let mut clock = DriveClock::start(&t);
    while t.periods == 0 {
        clock.elapsed_s(&t)?;
        std::thread::sleep(Duration::from_millis(10));
        t = board.poll(false, false)?;
    }
    Ok(t)
}

/// What `dcfo board --demo` did (its JSON line).
#[derive(Debug, serde::Serialize)]
pub struct DemoReport {
    /// The most advanced state the drive reported (`Running` when it ran sensorless).
    pub state_reached: String,
    /// The state when the demo disabled it.
    pub state_before_disable: String,
    /// Faults latched before the disable (`none`).
    pub faults: String,
    /// Speed estimate before the download, read once the drive has run long enough to
    /// finish its ramp to the reference and settle (`speed_settle_periods`), m/s.
    pub speed_m_per_s: Option<f32>,
    /// Samples captured and downloaded (full rate, from the estimator's start).
    pub capture_samples: usize,
    /// The drive's number type, as the capture reported it (`f32`, `q24`).
    pub numeric: &'static str,
    /// Every replayed estimate equals the drive's own, bit for bit.
    pub replay_identical: bool,
    /// Replayed samples that differ.
    pub replay_differing: usize,
    /// The first replayed sample that differs (0: the estimator's first step).
    pub replay_first_differing: Option<usize>,
    /// Time to download the capture, s.
    pub download_s: f64,
    /// Commands answered per second during the download.
    pub round_trips_per_s: f64,
    /// Control periods the image ran, as simulated time, s.
    pub simulated_s: f64,
    /// Wall-clock time from connecting to the disable, s.
    pub wall_s: f64,
    /// The trace written (`--record`).
    pub trace: Option<PathBuf>,
}

fn state_rank(s: DriveState) -> u8 {
    match s {
        DriveState::Fault => 0,
        DriveState::Disabled => 1,
        DriveState::Calibrating => 2,
        DriveState::Commissioning => 2,
        DriveState::Starting => 3,
        DriveState::Reacquiring => 4,
        DriveState::LowSpeed => 5,
        DriveState::Running => 6,
    }
}

/// Settling time after the drive first reports `Running` before [`run_demo`] reads the
/// speed estimate, s: past the speed loop's response (a few times its `1/20` s time
/// constant).
pub const SPEED_SETTLE_S: f64 = 0.25;

/// Control periods from the first `Running` telemetry to the demo's speed reading: the
/// longest ramp to `speed` m/s (from rest, at the acceleration limit of the drive the
/// image builds from `image`, the paper motor's without one) plus [`SPEED_SETTLE_S`].
fn speed_settle_periods(image: Option<&MotorImage>, speed: f32) -> u32 {
    let motor = image.map_or_else(qemu_drive_motor, |i| i.motor);
    let accel = DriveConfig::for_motor(&motor, PAPER_AXIS_BUS_V, ObserverKind::Dcfo).accel_limit_m_per_s2;
    let ramp_s = f64::from(speed.abs()) / f64::from(accel);
    ((ramp_s + SPEED_SETTLE_S) / CONTROL_PERIOD_S).ceil() as u32
}

/// `dcfo board --demo`: connect, arm the capture, enable at `speed` m/s, wait for the
/// capture to finish (the drive reaching `Running` on the way), download it, replay it,
/// disable. `record`: also write the capture as a trace there.
///
/// # Errors
/// The link failed, or the capture did not finish within `timeout` of the drive's own
/// time ([`DriveClock`]).
pub fn run_demo(
    target: &Target,
    image: Option<&MotorImage>,
    speed: f32,
    record: Option<&Path>,
    timeout: Duration,
) -> anyhow::Result<DemoReport> {
    let started = Instant::now();
    with_board(target, image, |board| {
        let first = board.poll(false, false)?;
        eprintln!(
            "connected: drive {:?}, capture capacity {} samples",
            first.state(),
            first.capture_capacity
        );
        *board.wish_mut() = Wish { enable: true, speed_m_per_s: speed };
        let mut t = board.poll(true, true)?;
        let mut best = t.state();
        let mut clock = DriveClock::start(&t);
        while !(t.capture == CaptureState::Done && t.state() == DriveState::Running) {
            if clock.elapsed_s(&t)? > timeout.as_secs_f64() {
                let _ = board.disable();
                bail!(
                    "no finished capture with the drive running within {} s of its time: drive {:?} (faults {}), capture {:?} with {} samples",
                    timeout.as_secs(),
                    t.state(),
                    fault_names(t.faults()),
                    t.capture,
                    t.capture_len
                );
            }
            if t.state() == DriveState::Fault {
                let _ = board.disable();
                bail!("the drive tripped: {}", fault_names(t.faults()));
            }
            if interrupted() {
                let t = board.disable()?;
                bail!(
                    "interrupted: drive {:?}, bridge {}",
                    t.state(),
                    if t.bridge_enabled { "on" } else { "off" }
                );
            }
            std::thread::sleep(POLL_PERIOD);
            t = board.poll(false, false)?;
            if state_rank(t.state()) > state_rank(best) {
                best = t.state();
                eprintln!(
                    "drive {:?} after {:.2} s simulated",
                    t.state(),
                    f64::from(t.periods) * CONTROL_PERIOD_S
                );
            }
        }
        // The speed is read at a defined drive time, not at the first poll: the drive
        // ramps from its hand-over speed to the reference at its acceleration limit, and
        // where the wall clock's poll falls on that ramp depends on how fast the target
        // runs against it (QEMU's M3 is slower than its M4F).
        let settle_periods = speed_settle_periods(image, speed);
        let running_seen = t.periods;
        while t.periods.wrapping_sub(running_seen) < settle_periods {
            if t.state() != DriveState::Running || clock.elapsed_s(&t)? > timeout.as_secs_f64() {
                let _ = board.disable();
                bail!(
                    "the drive left Running (or the time ran out) while settling at the speed: drive {:?} (faults {})",
                    t.state(),
                    fault_names(t.faults())
                );
            }
            std::thread::sleep(POLL_PERIOD);
            t = board.poll(false, false)?;
        }
        let (state_before, faults, speed_now) = (t.state(), t.faults(), t.estimate.map(|e| e.1));
        let trips_before = board.round_trips();
        let download_started = Instant::now();
        let data = board.download_capture(t.capture_len)?;
        let download_s = download_started.elapsed().as_secs_f64();
        let round_trips_per_s = (board.round_trips() - trips_before) as f64 / download_s.max(1e-9);
        let last = board.disable()?;
        eprintln!(
            "downloaded {} samples ({}) in {download_s:.1} s ({round_trips_per_s:.0} round trips/s); drive {:?}",
            data.samples.len(),
            data.format.name(),
            last.state()
        );
        // Through the file, as `dcfo replay` reads it.
        let dir = tempfile::tempdir().context("temporary directory")?;
        let path = match record {
            Some(p) => p.to_path_buf(),
            None => dir.path().join("capture.csv"),
        };
        let motor = image.map_or_else(qemu_drive_motor, |i| i.motor);
        write_capture_trace(&path, &data, &motor, CONTROL_PERIOD_S)?;
        let trace = InputTrace::read_path(&path)?;
        let comparison = replay_matches(&trace, &motor, &data)?;
        Ok(DemoReport {
            state_reached: format!("{best:?}"),
            state_before_disable: format!("{state_before:?}"),
            faults: fault_names(faults),
            speed_m_per_s: speed_now,
            capture_samples: data.samples.len(),
            numeric: data.format.name(),
            replay_identical: comparison.identical(data.samples.len()),
            replay_differing: comparison.differing,
            replay_first_differing: comparison.first_differing,
            download_s,
            round_trips_per_s,
            simulated_s: f64::from(last.periods) * CONTROL_PERIOD_S,
            wall_s: started.elapsed().as_secs_f64(),
            trace: record.map(Path::to_path_buf),
        })
    })
}
