//! The drive a drive image runs for its motor image: one function for every image
//! ([`drive_config`]), so that the ESC1 on its bridge, the ESC1 on the virtual motor and
//! the QEMU drive image take the same path from the record (`dcfo::motor_image`) to the
//! drive. An image whose motor image holds an axis ([`MotorImage::axis`]) runs a
//! positioning drive and takes moves over the board link; one without runs a speed drive
//! (the board link reports every move refused).
//!
//! The library builds the drive ([`DriveConfig::for_image`]: the motor, the bus, the
//! axis); what is the board's is said here: its control period and its inverter (a real
//! bridge with a programmed dead time, or the virtual motor's ideal averaged inverter and
//! the virtual carriage it moves). Builds on every target and is tested on the host.

use dcfo::drive::{DeadTimeCompensation, DriveConfig, DriveConfigError, PAPER_AXIS_PAYLOAD_KG};
use dcfo::motor_image::MotorImage;
use dcfo::plant::VirtualAxis;

/// The inverter behind the drive, as [`drive_config`] needs to know it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Inverter {
    /// A real bridge switching with this programmed dead time, s (>= 0): the drive uses
    /// the image's compensation (identified by `dcfo identify --image`) or, without one,
    /// that dead time alone (no device drop; band 2 % of the motor's rated current).
    Bridge {
        /// The bridge's programmed dead time, s.
        dead_time_s: f32,
    },
    /// The virtual motor's averaged inverter (`dcfo::plant`): ideal, so no
    /// compensation. It moves the image's axis payload or, without an axis, the paper
    /// axis's carriage ([`PAPER_AXIS_PAYLOAD_KG`]: a bare mover trips after the I/f
    /// hand-over), and the speed drive is tuned for that mass ([`virtual_axis`]).
    Virtual,
}

/// The drive for `image` on a board with control period `control_period_s` (s) and
/// `inverter`: [`DriveConfig::for_image`] with the inverter's compensation; a
/// positioning drive when the image holds an axis, a speed drive otherwise. On the
/// virtual motor without an axis the speed drive moves the virtual carriage too.
///
/// # Errors
/// The drive setting that is out of range, named (e.g. `motion.limits.max_speed_m_per_s`
/// for an axis whose top speed the bus cannot reach: a record a careless tool wrote, as
/// [`MotorImage::decode`] refuses what `MotorImage::with_axis` refuses).
pub fn drive_config(
    image: &MotorImage,
    control_period_s: f32,
    inverter: Inverter,
) -> Result<DriveConfig, DriveConfigError> {
    let compensation = match inverter {
        Inverter::Bridge { dead_time_s } => Some(image.compensation.unwrap_or(DeadTimeCompensation {
            dead_time_s,
            // Low-voltage MOSFETs: the drop is small against the bus; not measured.
            device_drop_v: 0.0,
            current_band_a: 0.02 * image.motor.rated_current_a,
        })),
        Inverter::Virtual => None,
    };
    let mut config = DriveConfig::for_image(image, control_period_s, compensation)?;
    if inverter == Inverter::Virtual && image.axis.is_none() {
        config.moving_mass_kg = image.motor.mass_kg + PAPER_AXIS_PAYLOAD_KG;
        config.validate()?;
    }
    Ok(config)
}

/// The virtual motor's axis for `image` with control period `control_period_s` (s): the
/// image's payload (kg) or, without an axis, [`PAPER_AXIS_PAYLOAD_KG`]; no load; the
/// image's bus voltage. The mass the drive of [`drive_config`] with
/// [`Inverter::Virtual`] is tuned for.
pub fn virtual_axis(image: &MotorImage, control_period_s: f32) -> VirtualAxis {
    VirtualAxis {
        payload_kg: image.axis.map_or(PAPER_AXIS_PAYLOAD_KG, |a| a.payload_kg),
        load_n: 0.0,
        bus_v: image.bus_v,
        period_s: control_period_s,
    }
}

/// A motor image given as hexadecimal text (QEMU's command line, `dcfo board --qemu`,
/// `dcfo stroke --qemu`), decoded and validated as from flash ([`MotorImage::decode`]):
/// any version's record, two hex digits a byte, at most [`MotorImage::LEN`] bytes.
///
/// # Errors
/// What is wrong, as a message for the image's halt: odd length or too long, a character
/// that is not a hex digit, or the record refused (not named further: `dcfo` checks the
/// image before it sends it).
pub fn motor_image_from_hex(hex: &[u8]) -> Result<MotorImage, &'static str> {
    let mut bytes = [0u8; MotorImage::LEN];
    if !hex.len().is_multiple_of(2) || hex.len() > 2 * MotorImage::LEN {
        return Err("motor image: not whole bytes of hex, or longer than a record");
    }
    let digit = |c: u8| (c as char).to_digit(16);
    for (byte, pair) in bytes.iter_mut().zip(hex.chunks_exact(2)) {
        let (Some(&hi), Some(&lo)) = (pair.first(), pair.get(1)) else {
            return Err("motor image: bad hex");
        };
        match (digit(hi), digit(lo)) {
            (Some(h), Some(l)) => *byte = (h * 16 + l) as u8,
            _ => return Err("motor image: bad hex"),
        }
    }
    MotorImage::decode(bytes.get(..hex.len() / 2).unwrap_or(&[]))
        .map_err(|_| "motor image: the record is invalid")
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use dcfo::drive::{PAPER_AXIS_BUS_V, STROKE_AXIS_LIMITS};
    use dcfo::motor::MotorParams;
    use dcfo::motor_image::MotorAxis;
    use std::string::String;

    fn images() -> (MotorImage, MotorImage) {
        let speed = MotorImage::new(MotorParams::paper(), PAPER_AXIS_BUS_V).unwrap();
        let axis = MotorAxis { limits: STROKE_AXIS_LIMITS, payload_kg: 4.0 };
        (speed, speed.with_axis(axis).unwrap())
    }

    #[test]
    fn an_image_with_an_axis_gives_a_positioning_drive_on_every_board() {
        let (speed, positioning) = images();
        let motor = MotorParams::paper();
        for inverter in [Inverter::Bridge { dead_time_s: 800e-9 }, Inverter::Virtual] {
            let c = drive_config(&positioning, 1e-4, inverter).unwrap();
            let motion = c.motion.unwrap();
            assert_eq!(motion.limits, STROKE_AXIS_LIMITS);
            assert_eq!(c.moving_mass_kg, motor.mass_kg + 4.0);
            let s = drive_config(&speed, 1e-4, inverter).unwrap();
            assert_eq!(s.motion, None);
            // A bare mover on the bridge; the virtual carriage on the virtual motor.
            let carriage = if inverter == Inverter::Virtual { PAPER_AXIS_PAYLOAD_KG } else { 0.0 };
            assert_eq!(s.moving_mass_kg, motor.mass_kg + carriage);
            assert_eq!(virtual_axis(&speed, 1e-4).payload_kg, PAPER_AXIS_PAYLOAD_KG);
            assert_eq!(virtual_axis(&positioning, 1e-4).payload_kg, 4.0);
        }
        // The bridge's compensation: the image's, else the programmed dead time.
        let c = drive_config(&speed, 1e-4, Inverter::Bridge { dead_time_s: 800e-9 }).unwrap();
        assert_eq!(c.dead_time_compensation.map(|c| c.dead_time_s), Some(800e-9));
        let identified =
            DeadTimeCompensation { dead_time_s: 1.1e-6, device_drop_v: 0.1, current_band_a: 0.05 };
        let with = speed.with_compensation(identified).unwrap();
        let c = drive_config(&with, 1e-4, Inverter::Bridge { dead_time_s: 800e-9 }).unwrap();
        assert_eq!(c.dead_time_compensation, Some(identified));
        assert_eq!(drive_config(&with, 1e-4, Inverter::Virtual).unwrap().dead_time_compensation, None);
    }

    /// The QEMU drive image's positioning drive from the paper motor's image with the
    /// stroke axis (what `dcfo board --qemu --move-to` sends) is the drive it built
    /// before from the word `position`: `stroke_axis` without its compensation.
    #[test]
    fn the_stroke_axis_image_gives_the_former_qemu_positioning_drive() {
        let motor = MotorParams::paper();
        let image = MotorImage::new(motor, PAPER_AXIS_BUS_V)
            .unwrap()
            .with_axis(MotorAxis { limits: STROKE_AXIS_LIMITS, payload_kg: PAPER_AXIS_PAYLOAD_KG })
            .unwrap();
        let mut former = DriveConfig::stroke_axis(&motor, PAPER_AXIS_BUS_V);
        former.control_period_s = 1.0 / 10_000.0;
        former.dead_time_compensation = None;
        assert_eq!(drive_config(&image, 1.0 / 10_000.0, Inverter::Virtual), Ok(former));
        // And the speed drive without an image: `for_motor` moving the carriage.
        let speed = MotorImage::new(motor, PAPER_AXIS_BUS_V).unwrap();
        let mut former =
            DriveConfig::for_motor(&motor, PAPER_AXIS_BUS_V, dcfo::algorithms::observer::ObserverKind::Dcfo);
        former.moving_mass_kg = motor.mass_kg + PAPER_AXIS_PAYLOAD_KG;
        former.control_period_s = 1.0 / 10_000.0;
        assert_eq!(drive_config(&speed, 1.0 / 10_000.0, Inverter::Virtual), Ok(former));
    }

    #[test]
    fn hex_images_of_every_version_decode_and_bad_text_is_refused() {
        let (speed, positioning) = images();
        let hex = |b: &[u8]| b.iter().map(|b| std::format!("{b:02x}")).collect::<String>();
        for image in [speed, positioning] {
            assert_eq!(motor_image_from_hex(hex(&image.encode()).as_bytes()), Ok(image));
        }
        let good = hex(&positioning.encode());
        assert!(motor_image_from_hex(&good.as_bytes()[1..]).is_err());
        assert!(motor_image_from_hex(std::format!("{good}00").as_bytes()).is_err());
        assert!(motor_image_from_hex(good.replace('0', "g").as_bytes()).is_err());
        assert!(motor_image_from_hex(b"").is_err());
    }
}
