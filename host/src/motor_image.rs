//! `dcfo motor-image`: the motor (file or preset) and the bus voltage as the binary
//! record a drive board reads from its reserved flash page ([`dcfo::motor_image`]).

use std::path::PathBuf;

use anyhow::Context;
use dcfo::motor_image::MotorImage;

use crate::motor_file::load_motor;

/// What `dcfo motor-image` is asked to write.
#[derive(Debug, Clone)]
pub struct Params {
    /// Motor: a preset name (`paper`) or a TOML motor file (shared/trace-format.md).
    pub motor: String,
    /// Nominal DC-bus voltage of the board, V.
    pub bus_v: f32,
    /// Output file (the encoded record).
    pub out: PathBuf,
}

/// `dcfo motor-image`: validates the motor and the bus voltage exactly as the firmware
/// will, then writes the record (nothing is written on an error) and says so on stdout.
pub fn run_command(params: &Params) -> anyhow::Result<()> {
    let motor = load_motor(&params.motor)?;
    let image =
        MotorImage::new(motor.params, params.bus_v).map_err(|e| anyhow::anyhow!("{}: {e}", params.motor))?;
    let bytes = image.encode();
    // The firmware's own check, on the bytes as written.
    MotorImage::decode(&bytes).map_err(|e| anyhow::anyhow!("encoded image: {e}"))?;
    std::fs::write(&params.out, bytes).with_context(|| format!("writing {}", params.out.display()))?;
    println!(
        "motor image of {} at {} V bus: {} bytes in {}",
        motor.name,
        params.bus_v,
        bytes.len(),
        params.out.display()
    );
    Ok(())
}
