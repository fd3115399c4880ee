//! Where a host command reaches a drive image: an image on QEMU or a board on a serial
//! port. Shared by `dcfo hil` (the lock-step HIL image) and `dcfo board` (the drive
//! image operated from the host); each picks its own default image for QEMU.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;

use crate::qemu::QemuCpu;

/// How long a host command waits for an answer from the drive image before it gives
/// up (a lock-step HIL frame, a board command).
pub const ANSWER_TIMEOUT: Duration = Duration::from_secs(5);

/// Where the drive image runs.
#[derive(Debug, Clone)]
pub enum Target {
    /// An image on QEMU.
    Qemu {
        /// The board (and with it the numeric type).
        cpu: QemuCpu,
        /// The image; the command's default image is built with cargo when `None`.
        elf: Option<PathBuf>,
    },
    /// A board on a serial port.
    Port {
        /// The device, e.g. `/dev/ttyACM0`.
        device: PathBuf,
        /// Bit rate, bit/s (8N1).
        baud: u32,
    },
}

impl Target {
    /// The QEMU board, `None` for a serial port.
    pub fn qemu_cpu(&self) -> Option<QemuCpu> {
        match self {
            Target::Qemu { cpu, .. } => Some(*cpu),
            Target::Port { .. } => None,
        }
    }
}

/// A serial port opened at `baud` bit/s with reads timing out after
/// [`ANSWER_TIMEOUT`]: a writer and a second handle for a reader thread.
///
/// # Errors
/// The port cannot be opened or cloned; the message names the device.
pub fn open_serial(
    device: &std::path::Path,
    baud: u32,
) -> anyhow::Result<(Box<dyn serialport::SerialPort>, Box<dyn serialport::SerialPort>)> {
    let dev = device.to_string_lossy();
    let serial = serialport::new(dev.as_ref(), baud)
        .timeout(ANSWER_TIMEOUT)
        .open()
        .with_context(|| format!("opening {dev} at {baud} bit/s"))?;
    let reader = serial.try_clone().with_context(|| format!("{dev}: second handle"))?;
    Ok((serial, reader))
}
