//! `dcfo board` ([`run_command`]): operate a drive image from the host over the board
//! link ([`dcfo::link::board`]): a board on a serial port, or the virtual-motor image
//! (`firmware/examples/qemu_drive.rs`) on QEMU. By concern:
//!
//! - [`link`]: the serial transport (one command, one answer) and the drive's own clock.
//! - [`capture`]: a downloaded capture as a trace, and its bit-for-bit replay check.
//! - [`session`]: reaching the image (QEMU with its motor image, or a serial port),
//!   Ctrl-C, the moves the host sends, the live status line.
//! - [`demo`]: the non-interactive runs (`--demo`, `--demo --move-to`).
//! - [`shell`]: the interactive mode.

pub mod capture;
pub mod demo;
pub mod link;
pub mod session;
pub mod shell;

use std::path::PathBuf;
use std::time::Duration;

use anyhow::bail;
use dcfo::algorithms::motion::Move;

use crate::target::Target;
use demo::{run_demo, run_move_demo};
use session::{catch_interrupt, check_move, qemu_image};
use shell::run_interactive;

/// What `dcfo board` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// The drive image: QEMU or a board on a serial port.
    pub target: Target,
    /// Download the capture into this trace (CSV, docs/trace-format.md) once it is over.
    pub record: Option<PathBuf>,
    /// Non-interactive: connect, arm the capture, enable at `speed_m_per_s`, wait until
    /// the drive runs and the capture is over, download it, replay it, disable.
    pub demo: bool,
    /// Speed reference of the demo, m/s.
    pub speed_m_per_s: f32,
    /// With `demo`: print one JSON object on the last line of stdout.
    pub json: bool,
    /// Queue this move (target m, dwell s) with the first command; on QEMU without
    /// `image` the image then runs the positioning drive of [`session::qemu_positioning_image`].
    /// With `demo`: the move demo ([`run_move_demo`]) instead of the capture demo.
    pub move_to: Option<Move>,
    /// QEMU only: the motor image the QEMU drive image runs (as a board reads its own
    /// from flash): with an axis a positioning drive, without one a speed drive.
    pub image: Option<PathBuf>,
}

/// `dcfo board`: the interactive session, or the demo (its report on stdout; an error
/// when the replay of the capture differs from the drive's estimates).
pub fn run_command(params: &Params) -> anyhow::Result<()> {
    if !params.speed_m_per_s.is_finite() {
        bail!("--speed must be a finite number of m/s");
    }
    if let Some(m) = params.move_to {
        check_move(m.target_m, m.dwell_s).map_err(|e| anyhow::anyhow!("--move-to/--dwell: {e}"))?;
    }
    let image = match (&params.image, &params.target) {
        (Some(path), Target::Qemu { .. }) => Some(crate::commands::motor_image::read_image(path)?),
        (Some(_), Target::Port { .. }) => {
            bail!("--image is for --qemu: a board reads its motor image from flash (write it with probe-rs)")
        }
        (None, _) => None,
    };
    let image = match params.target {
        Target::Qemu { .. } => qemu_image(image, params.move_to.is_some()),
        Target::Port { .. } => None,
    };
    if let Some(i) = &image {
        eprintln!("motor image: {}", crate::commands::motor_image::describe_axis(i.axis));
    }
    catch_interrupt()?;
    if !params.demo {
        return run_interactive(&params.target, image.as_ref(), params.record.as_deref(), params.move_to);
    }
    if let Some(m) = params.move_to {
        let report = run_move_demo(&params.target, image.as_ref(), m, Duration::from_secs(60))?;
        if params.json {
            println!("{}", serde_json::to_string(&report)?);
        } else {
            println!(
                "move to {:.4} m: x_hat {:.4} m (error {:+.3} mm, tolerance {:.3} mm){}; refused move reported: {}",
                report.target_m,
                report.x_hat_m,
                report.x_err_m * 1e3,
                report.tolerance_m * 1e3,
                match report.move_s {
                    Some(s) => format!(", reached {s:.2} s after the enable"),
                    None => String::new(),
                },
                report.refused_move_reported
            );
        }
        anyhow::ensure!(report.move_reached, "the move did not reach its target within the tolerance");
        anyhow::ensure!(report.refused_move_reported, "the refused move was not reported");
        return Ok(());
    }
    let report = run_demo(
        &params.target,
        image.as_ref(),
        params.speed_m_per_s,
        params.record.as_deref(),
        Duration::from_secs(60),
    )?;
    if params.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "drive reached {}; captured {} samples ({}); replay {} ({} differ{}); download {:.1} s at {:.0} round trips/s",
            report.state_reached,
            report.capture_samples,
            report.numeric,
            if report.replay_identical { "identical bit for bit" } else { "DIFFERS" },
            report.replay_differing,
            match report.replay_first_differing {
                Some(k) => format!(", the first at sample {k}"),
                None => String::new(),
            },
            report.download_s,
            report.round_trips_per_s
        );
    }
    anyhow::ensure!(report.replay_identical, "the replay of the capture differs from the drive's estimates");
    Ok(())
}
