//! Reaching a drive image for `dcfo board` (`with_board`): the QEMU drive image with
//! the motor image it runs, or a board on a serial port; Ctrl-C ([`catch_interrupt`]);
//! the checks of a move the host sends; the live status line ([`status_line`]).

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use dcfo::drive::{PAPER_AXIS_BUS_V, PAPER_AXIS_PAYLOAD_KG, STROKE_AXIS_LIMITS};
use dcfo::link::board::BoardTelemetry;
use dcfo::motor::MotorParams;
use dcfo::motor_image::{MotorAxis, MotorImage};

use super::link::{Board, BoardLink, BoardOps};
use crate::commands::sim::fault_names;
use crate::qemu::{GuestClock, QemuSession, build_qemu_example};
use crate::target::Target;

/// Set by Ctrl-C (SIGINT, SIGTERM) once [`catch_interrupt`] has installed the handler.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// Makes Ctrl-C end `dcfo board` cleanly: the interactive mode and the demo see it at
/// their next poll, disable the drive and exit. Without it the process would die at
/// once and the image's watchdog would switch the bridge off 0.5 s later.
///
/// # Errors
/// The handler could not be installed (e.g. one was already).
pub fn catch_interrupt() -> anyhow::Result<()> {
    ctrlc::set_handler(|| INTERRUPTED.store(true, Ordering::SeqCst)).context("installing the Ctrl-C handler")
}

pub(super) fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::SeqCst)
}

/// The motor the QEMU drive image runs without a motor image (`examples/qemu_drive.rs`):
/// the paper motor, its drive tuned by `DriveConfig::for_motor` for the paper axis's bus;
/// the replay needs only the motor (its estimator is `EstimatorConfig::for_motor`, as
/// the drive's; the M3 image's Q8.24 drive runs in `Base::for_motor` of it, see
/// [`crate::commands::replay::working_base`]).
pub fn qemu_drive_motor() -> MotorParams {
    MotorParams::paper()
}

/// The motor image `dcfo board --qemu --move-to` gives the QEMU image when no `--image`
/// is: the paper motor at the paper axis's bus with the stroke axis of `dcfo stroke`
/// ([`STROKE_AXIS_LIMITS`], the [`PAPER_AXIS_PAYLOAD_KG`] carriage), so that the image
/// builds a positioning drive (`image_drive::drive_config`, as the ESC1 does from
/// flash).
pub fn qemu_positioning_image() -> MotorImage {
    let image = MotorImage::new(MotorParams::paper(), PAPER_AXIS_BUS_V).expect("the paper motor is valid");
    image
        .with_axis(MotorAxis { limits: STROKE_AXIS_LIMITS, payload_kg: PAPER_AXIS_PAYLOAD_KG })
        .expect("the stroke axis fits the paper motor")
}

/// The QEMU drive image's command line for `image`: `image <hex>` (the image reads it
/// through semihosting, `image_drive::motor_image_from_hex`).
pub fn qemu_image_cmdline(image: &MotorImage) -> String {
    let hex: String = image.encode().iter().map(|b| format!("{b:02x}")).collect();
    format!("image {hex}")
}

/// The motor image the QEMU drive image runs: `image` (`--image FILE`), else for a move
/// ([`qemu_positioning_image`]), else none (the image's paper speed drive).
pub fn qemu_image(image: Option<MotorImage>, move_to: bool) -> Option<MotorImage> {
    image.or_else(|| move_to.then(qemu_positioning_image))
}

/// A move the host sends: a finite target (m) and a finite, non-negative dwell (s).
/// The drive image checks the stroke itself (a target outside it is refused and
/// counted in the telemetry).
///
/// # Errors
/// What is wrong with the values, naming them.
pub fn check_move(target_m: f32, dwell_s: f32) -> Result<(), String> {
    if !target_m.is_finite() {
        return Err(format!("the move's target must be a finite number of m, not {target_m}"));
    }
    if !(dwell_s.is_finite() && dwell_s >= 0.0) {
        return Err(format!("the move's dwell must be a finite number of s, at least 0, not {dwell_s}"));
    }
    Ok(())
}

/// Tolerance on the final position of `dcfo board --demo --move-to`, m: a twentieth of
/// the motor's pole pitch (0.75 mm on the paper motor, 9 electrical degrees).
pub fn move_tolerance_m(motor: &MotorParams) -> f32 {
    motor.pole_pitch_m / 20.0
}

/// Connects to `target`, then runs `f` with the board; QEMU is stopped afterwards. On
/// QEMU the image runs the drive of `image` (its command line, [`qemu_image_cmdline`]),
/// without one the paper motor's speed drive; a board reads its own from flash.
pub(super) fn with_board<T>(
    target: &Target,
    image: Option<&MotorImage>,
    f: impl FnOnce(&mut dyn BoardOps) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    match target {
        Target::Qemu { cpu, elf } => {
            let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap_or(Path::new("."));
            let elf = match elf {
                Some(e) => e.clone(),
                None => build_qemu_example(workspace, *cpu, "qemu_drive")?,
            };
            let cmdline = image.map(qemu_image_cmdline);
            // The drive image's SysTick paces its control periods: its clock counts
            // instructions.
            let (_session, stdin, stdout) =
                QemuSession::spawn_with_cmdline(&elf, *cpu, GuestClock::Instructions, cmdline.as_deref())?;
            let mut board = Board::new(BoardLink::new(stdin, stdout));
            f(&mut board)
        }
        Target::Port { device, baud } => {
            let (serial, reader) = crate::target::open_serial(device, *baud)?;
            let mut board = Board::new(BoardLink::new(serial, reader));
            f(&mut board)
        }
    }
}

/// One line of live state: drive state, faults, speed, currents, bus, angle, capture;
/// and for a positioning drive x̂ and the reference position (mm), the queue and the
/// refused moves.
pub fn status_line(t: &BoardTelemetry) -> String {
    let (theta, v) = match t.estimate {
        Some((theta, v)) => (format!("{:+7.1} deg", theta.to_degrees()), format!("{v:+.3} m/s")),
        None => ("    --".into(), "--".into()),
    };
    let position = match t.position {
        Some(p) => format!(
            "  x {:+8.3} mm ref {:+8.3} mm{} queued {} refused {}",
            p.x_hat_m * 1e3,
            p.x_ref_m * 1e3,
            if p.idle { " idle" } else { "" },
            p.moves_queued,
            p.moves_rejected
        ),
        None => String::new(),
    };
    format!(
        "{:<12} faults {:<10} v {v:<11} ref {:+.3} m/s  i_ab [{:+6.2} {:+6.2}] A  bus {:6.1} V  theta {theta}  bridge {}  capture {:?} {}/{}{position}",
        format!("{:?}", t.state()),
        fault_names(t.faults()),
        t.speed_ref,
        t.i_ab_a[0],
        t.i_ab_a[1],
        t.vdc_v,
        if t.bridge_enabled { "on " } else { "off" },
        t.capture,
        t.capture_len,
        t.capture_capacity
    )
}
