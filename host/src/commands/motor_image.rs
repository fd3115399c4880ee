//! `dcfo motor-image`: the motor (file or preset), the bus voltage and optionally the
//! positioning axis as the binary record a drive board reads from its reserved flash
//! page ([`dcfo::motor_image`]).

use std::path::{Path, PathBuf};

use anyhow::Context;
use dcfo::algorithms::motion::ProfileLimits;
use dcfo::motor_image::{MotorAxis, MotorImage};

use crate::motor_file::load_motor;

/// The axis options of `dcfo motor-image`, as typed: all given or none.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AxisArgs {
    /// Lowest target position, m (`--stroke-min-m`).
    pub stroke_min_m: Option<f32>,
    /// Highest target position, m (`--stroke-max-m`).
    pub stroke_max_m: Option<f32>,
    /// The profile's top speed, m/s (`--max-speed`).
    pub max_speed_m_per_s: Option<f32>,
    /// The profile's acceleration, m/s^2 (`--max-accel`).
    pub max_accel_m_per_s2: Option<f32>,
    /// Carriage and payload moved besides the mover, kg (`--payload-kg`).
    pub payload_kg: Option<f32>,
}

/// The options' names, in [`AxisArgs`]'s order.
const AXIS_OPTIONS: [&str; 5] =
    ["--stroke-min-m", "--stroke-max-m", "--max-speed", "--max-accel", "--payload-kg"];

impl AxisArgs {
    /// The axis, if the options give one.
    ///
    /// # Errors
    /// Some axis options given and others not: the message names the missing ones.
    pub fn axis(&self) -> anyhow::Result<Option<MotorAxis>> {
        let values = [
            self.stroke_min_m,
            self.stroke_max_m,
            self.max_speed_m_per_s,
            self.max_accel_m_per_s2,
            self.payload_kg,
        ];
        match values {
            [
                Some(stroke_min_m),
                Some(stroke_max_m),
                Some(max_speed_m_per_s),
                Some(max_accel_m_per_s2),
                Some(payload_kg),
            ] => Ok(Some(MotorAxis {
                limits: ProfileLimits { stroke_min_m, stroke_max_m, max_speed_m_per_s, max_accel_m_per_s2 },
                payload_kg,
            })),
            [None, None, None, None, None] => Ok(None),
            _ => {
                let missing: Vec<&str> =
                    AXIS_OPTIONS.iter().zip(values).filter(|(_, v)| v.is_none()).map(|(n, _)| *n).collect();
                anyhow::bail!(
                    "an axis needs all of {}: missing {}",
                    AXIS_OPTIONS.join(", "),
                    missing.join(", ")
                )
            }
        }
    }
}

/// What `dcfo motor-image` is asked to write.
#[derive(Debug, Clone)]
pub struct Params {
    /// Motor: a preset name (`paper`) or a TOML motor file (docs/motor-format.md).
    pub motor: String,
    /// Nominal DC-bus voltage of the board, V.
    pub bus_v: f32,
    /// The positioning axis (all or none of its options).
    pub axis: AxisArgs,
    /// Output file (the encoded record).
    pub out: PathBuf,
}

/// `dcfo motor-image`: validates the motor, the bus voltage and the axis exactly as the
/// firmware will, then writes the record (nothing is written on an error) and says so
/// on stdout.
pub fn run_command(params: &Params) -> anyhow::Result<()> {
    let motor = load_motor(&params.motor)?;
    let axis = params.axis.axis()?;
    let mut image =
        MotorImage::new(motor.params, params.bus_v).map_err(|e| anyhow::anyhow!("{}: {e}", params.motor))?;
    if let Some(axis) = axis {
        image = image.with_axis(axis).map_err(|e| anyhow::anyhow!("{}: {e}", params.motor))?;
        // The drive's check, as the board's `DriveConfig::for_image` makes it.
        dcfo::drive::DriveConfig::check_image_axis(&image).map_err(|f| {
            anyhow::anyhow!("{}: axis `{}` is more than the motor can do", params.motor, f.name())
        })?;
    }
    let bytes = image.encode();
    // The firmware's own check, on the bytes as written.
    MotorImage::decode(&bytes).map_err(|e| anyhow::anyhow!("encoded image: {e}"))?;
    std::fs::write(&params.out, bytes).with_context(|| format!("writing {}", params.out.display()))?;
    println!(
        "motor image (version {}) of {} at {} V bus, {}: {} bytes in {}",
        MotorImage::VERSION,
        motor.name,
        params.bus_v,
        describe_axis(image.axis),
        bytes.len(),
        params.out.display()
    );
    Ok(())
}

/// The axis in words: the stroke, the profile and the payload, or `no axis (speed
/// drive)`.
pub fn describe_axis(axis: Option<MotorAxis>) -> String {
    match axis {
        Some(a) => format!(
            "axis {} to {} m at {} m/s and {} m/s^2 with {} kg of payload (positioning drive)",
            a.limits.stroke_min_m,
            a.limits.stroke_max_m,
            a.limits.max_speed_m_per_s,
            a.limits.max_accel_m_per_s2,
            a.payload_kg
        ),
        None => "no axis (speed drive)".into(),
    }
}

/// The motor image in `path`, decoded and validated as the firmware reads it.
///
/// # Errors
/// The file cannot be read, or its record is refused (named).
pub fn read_image(path: &Path) -> anyhow::Result<MotorImage> {
    let bytes = std::fs::read(path).with_context(|| format!("reading the motor image {}", path.display()))?;
    MotorImage::decode(&bytes).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// The axis of the motor image already in `path`, to be kept when the file is written
/// again (`dcfo identify --image`): `None` when there is no such file, or it holds no
/// valid image or one without an axis.
pub fn existing_axis(path: &Path) -> Option<MotorAxis> {
    let bytes = std::fs::read(path).ok()?;
    MotorImage::decode(&bytes).ok()?.axis
}
