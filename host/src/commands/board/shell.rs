//! The interactive mode of `dcfo board` ([`run_interactive`]): the live status line and
//! typed commands ([`parse_typed`]).

use std::io::BufRead;
use std::path::Path;
use std::sync::mpsc;

use dcfo::algorithms::motion::Move;
use dcfo::capture::CaptureState;
use dcfo::link::board::BoardTelemetry;
use dcfo::motor::MotorParams;
use dcfo::motor_image::MotorImage;

use super::capture::{CaptureData, write_capture_trace};
use super::link::{BoardOps, CONTROL_PERIOD_S, POLL_PERIOD};
use super::session::{check_move, interrupted, qemu_drive_motor, status_line, with_board};
use crate::target::Target;

/// Capture chunks downloaded between two polls of the live display (about 0.1 s on
/// QEMU).
pub const DOWNLOAD_SLICE_CHUNKS: u32 = 40;

/// A line typed in the interactive mode.
#[derive(Clone, Debug, PartialEq)]
pub enum Typed {
    /// `e`: enable.
    Enable,
    /// `d`: disable.
    Disable,
    /// `c`: clear faults.
    Clear,
    /// `s <m/s>`: speed reference.
    Speed(f32),
    /// `r`: arm the capture (downloaded to `--record FILE` when it is over).
    Record,
    /// `m <target m> [dwell s]`: queue a move on a positioning drive.
    MoveTo(Move),
    /// `q`, or the end of the input: disable and quit.
    Quit,
}

/// Parses one typed line.
///
/// # Errors
/// What is wrong with the line, naming it.
pub fn parse_typed(line: &str) -> Result<Typed, String> {
    let mut words = line.split_whitespace();
    let cmd = words.next().unwrap_or("");
    let typed = match cmd {
        "e" | "enable" => Typed::Enable,
        "d" | "disable" => Typed::Disable,
        "c" | "clear" => Typed::Clear,
        "r" | "record" => Typed::Record,
        "q" | "quit" => Typed::Quit,
        "s" | "speed" => {
            let arg = words.next().ok_or_else(|| format!("`{line}`: `s` needs a speed in m/s"))?;
            let v: f32 = arg.parse().map_err(|_| format!("`{line}`: `{arg}` is not a speed in m/s"))?;
            if !v.is_finite() {
                return Err(format!("`{line}`: the speed must be a finite number of m/s"));
            }
            Typed::Speed(v)
        }
        "m" | "move" => {
            let arg = words.next().ok_or_else(|| format!("`{line}`: `m` needs a target position in m"))?;
            let target_m: f32 =
                arg.parse().map_err(|_| format!("`{line}`: `{arg}` is not a position in m"))?;
            let dwell_s: f32 = match words.next() {
                Some(d) => d.parse().map_err(|_| format!("`{line}`: `{d}` is not a dwell in s"))?,
                None => 0.0,
            };
            check_move(target_m, dwell_s).map_err(|e| format!("`{line}`: {e}"))?;
            Typed::MoveTo(Move { target_m, dwell_s })
        }
        _ => {
            return Err(format!(
                "`{line}`: commands are e(nable), d(isable), c(lear), s(peed) <m/s>, m(ove) <m> [dwell s], r(ecord), q(uit)"
            ));
        }
    };
    if let Some(extra) = words.next() {
        return Err(format!("`{line}`: unexpected `{extra}`"));
    }
    Ok(typed)
}

/// `dcfo board` without `--demo`: live state on stderr at [`POLL_PERIOD`], commands read
/// line by line from stdin; `q`, the end of the input or Ctrl-C (with
/// [`super::session::catch_interrupt`]) disables the drive and exits.
///
/// # Errors
/// The link failed (the image's watchdog then disables the drive within 0.5 s).
pub fn run_interactive(
    target: &Target,
    image: Option<&MotorImage>,
    record: Option<&Path>,
    first_move: Option<Move>,
) -> anyhow::Result<()> {
    let (tx, typed) = mpsc::channel::<String>();
    std::thread::spawn(move || {
        let stdin = std::io::stdin();
        for line in stdin.lock().lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                return;
            }
        }
        let _ = tx.send("q".into());
    });
    eprintln!(
        "commands: e(nable), d(isable), c(lear faults), s(peed) <m/s>, m(ove) <m> [dwell s], r(ecord: arm the capture), q(uit)"
    );
    with_board(target, image, |board| {
        if let Some(m) = first_move {
            board.queue_move(m);
        }
        let mut clear = false;
        let mut arm = record.is_some();
        let mut downloaded = false;
        let mut data = CaptureData::default();
        let motor = image.map_or_else(qemu_drive_motor, |i| i.motor);
        loop {
            let t = board.poll(std::mem::take(&mut clear), std::mem::take(&mut arm))?;
            eprint!("\r{}\x1b[K", status_line(&t));
            if let Some(path) = record
                && t.capture == CaptureState::Done
                && !downloaded
            {
                // A slice at a time (about 0.1 s), so that the display and the keys stay
                // live while a long capture downloads.
                board.download_more(&mut data, t.capture_len, DOWNLOAD_SLICE_CHUNKS)?;
                eprint!(" | download {}/{}", data.samples.len(), t.capture_len);
                if data.samples.len() as u32 >= t.capture_len {
                    write_capture_trace(path, &data, &motor, CONTROL_PERIOD_S)?;
                    eprintln!(
                        "\ncapture: {} samples ({}) written to {}",
                        data.samples.len(),
                        data.format.name(),
                        path.display()
                    );
                    downloaded = true;
                    data.samples.clear();
                }
            }
            std::thread::sleep(POLL_PERIOD);
            if interrupted() {
                let t = board.disable()?;
                eprintln!("\r{}\x1b[K\ninterrupted: drive disabled", status_line(&t));
                return finish_download(board, record, &mut data, &motor, &t);
            }
            while let Ok(line) = typed.try_recv() {
                if line.trim().is_empty() {
                    continue;
                }
                match parse_typed(&line) {
                    Ok(Typed::Enable) => board.wish_mut().enable = true,
                    Ok(Typed::Disable) => board.wish_mut().enable = false,
                    Ok(Typed::Clear) => clear = true,
                    Ok(Typed::Speed(v)) => board.wish_mut().speed_m_per_s = v,
                    Ok(Typed::MoveTo(m)) => board.queue_move(m),
                    Ok(Typed::Record) => {
                        arm = true;
                        downloaded = false;
                        data.samples.clear();
                        if record.is_none() {
                            eprintln!("\n(no --record FILE: the capture will not be downloaded)");
                        }
                    }
                    Ok(Typed::Quit) => {
                        let t = board.disable()?;
                        eprintln!("\r{}\x1b[K\ndrive disabled", status_line(&t));
                        return finish_download(board, record, &mut data, &motor, &t);
                    }
                    Err(e) => eprintln!("\n{e}"),
                }
            }
        }
    })
}

/// On the way out, with the drive already disabled: a capture download under way is
/// completed and written (the samples of a finished capture do not change).
pub(super) fn finish_download(
    board: &mut dyn BoardOps,
    record: Option<&Path>,
    data: &mut CaptureData,
    motor: &MotorParams,
    t: &BoardTelemetry,
) -> anyhow::Result<()> {
    let Some(path) = record else { return Ok(()) };
    if data.samples.is_empty() || t.capture != CaptureState::Done {
        return Ok(());
    }
    board.download_more(data, t.capture_len, u32::MAX)?;
    write_capture_trace(path, data, motor, CONTROL_PERIOD_S)?;
    eprintln!("capture: {} samples written to {}", data.samples.len(), path.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn typed_commands_parse_and_bad_ones_are_named() {
        assert_eq!(parse_typed("e"), Ok(Typed::Enable));
        assert_eq!(parse_typed(" s -0.25 "), Ok(Typed::Speed(-0.25)));
        assert!(parse_typed("s fast").unwrap_err().contains("`fast` is not a speed"));
        assert!(parse_typed("s").unwrap_err().contains("needs a speed"));
        assert_eq!(parse_typed("m 0.02 0.5"), Ok(Typed::MoveTo(Move { target_m: 0.02, dwell_s: 0.5 })));
        assert_eq!(parse_typed("move -0.01"), Ok(Typed::MoveTo(Move { target_m: -0.01, dwell_s: 0.0 })));
        assert!(parse_typed("m").unwrap_err().contains("needs a target"));
        assert!(parse_typed("m 0.1 -2").unwrap_err().contains("dwell must be"));
        assert!(parse_typed("x").unwrap_err().contains("commands are"));
        assert!(parse_typed("e now").unwrap_err().contains("unexpected `now`"));
        assert!(parse_typed("s inf").is_err());
    }
}
