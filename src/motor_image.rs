//! The motor as configuration on a board: a fixed-size binary record of the motor file's
//! parameters, the nominal DC-bus voltage, (since version 2) the inverter's
//! voltage-error compensation and (since version 3) the positioning axis, protected by a
//! CRC, that a host tool writes (`dcfo motor-image`, `dcfo identify --image`) and a
//! firmware reads from a reserved flash page at boot.
//!
//! The drive code is never compiled for one motor: the firmware validates the record
//! exactly as the host validates a motor file ([`MotorParams::new`]) and refuses to run
//! without a valid one. A record with an axis makes the board's drive a positioning
//! drive (`DriveConfig::for_image`), one without a speed drive.
//!
//! Layout of version 3, little-endian, [`MotorImage::LEN`] = 88 bytes (a multiple of the
//! 8-byte flash programming unit of STM32G4 parts):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 4]` | magic `b"DCFM"` |
//! | 4 | u16 | format version ([`MotorImage::VERSION`] = 3) |
//! | 6 | u16 | flags: bit 0 = the compensation fields hold a compensation; bit 1 = the axis fields hold an axis; other bits 0 |
//! | 8 | 9 × f32 | `rs_ohm`, `ld_h`, `lq_h`, `psi_f_wb`, `pole_pitch_m`, `mass_kg`, `viscous_n_s_per_m`, `rated_current_a`, `rated_voltage_v` (the motor file's keys and units) |
//! | 44 | f32 | nominal DC-bus voltage, V |
//! | 48 | 3 × f32 | inverter compensation ([`DeadTimeCompensation`]): dead time (s), device drop (V), current band (A); zero without one |
//! | 60 | 5 × f32 | axis ([`MotorAxis`]): `stroke_min_m` (m), `stroke_max_m` (m), `max_speed_m_per_s` (m/s), `max_accel_m_per_s2` (m/s²), `payload_kg` (kg, moved besides the mover); zero without one |
//! | 80 | u16 | CRC-16/IBM-3740 of bytes 0..80 |
//! | 82 | `[u8; 6]` | reserved, 0 |
//!
//! **Version 2** (64 bytes: bytes 0..60 as above, flags bit 0 only, the CRC of bytes
//! 0..60 at 60, 2 reserved bytes) and **version 1** (56 bytes: bytes 0..48 as above with
//! bytes 6..8 reserved, the CRC of bytes 0..48 at 48, 6 reserved bytes) are still read,
//! CRC-checked and validated the same way, and migrated: neither holds an axis
//! ([`MotorImage::axis`] is `None`), version 1 no compensation either.
//! [`MotorImage::encode`] writes version 3 only. Any other version is
//! [`MotorImageError::UnsupportedVersion`].

use crate::algorithms::dead_time::DeadTimeCompensation;
use crate::algorithms::motion::ProfileLimits;
use crate::motor::{MotorParams, ParamError};
use crate::num::checksum::crc16;

const MAGIC: [u8; 4] = *b"DCFM";
/// Where the CRC is in a version-3 record.
const CRC_AT: usize = 80;
/// Where the CRC is in a version-2 record, and that record's length.
const CRC_AT_V2: usize = 60;
const LEN_V2: usize = 64;
/// Where the CRC is in a version-1 record, and that record's length.
const CRC_AT_V1: usize = 48;
const LEN_V1: usize = 56;
/// Flag bit: the record holds a compensation.
const FLAG_COMPENSATION: u16 = 1 << 0;
/// Flag bit: the record holds an axis (version 3).
const FLAG_AXIS: u16 = 1 << 1;
/// The f32 values of a version-3 record (from offset 8).
const VALUES: usize = 18;

/// Why a byte record is not a usable motor image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MotorImageError {
    /// Fewer bytes than the record's version needs ([`MotorImage::LEN`] for version 3,
    /// 64 for version 2, 56 for version 1; 8 to read the version).
    TooShort,
    /// Every byte is 0xFF: erased flash, nothing was programmed.
    Erased,
    /// The first four bytes are not `DCFM`.
    BadMagic,
    /// A format version this firmware does not read.
    UnsupportedVersion(u16),
    /// The CRC does not match: a corrupted or partly written record.
    BadCrc,
    /// A motor parameter is not physical (named).
    Param(ParamError),
    /// The nominal bus voltage is not a positive finite number of volts.
    BusVoltage,
    /// The inverter compensation is not physical: a dead time outside `[0, 10 us]`, a
    /// negative or non-finite device drop, a band that is not a positive finite current,
    /// or unknown flag bits.
    Compensation,
    /// The axis is not usable; names the field ([`MotorAxis`]'s: `stroke_min_m`,
    /// `stroke_max_m`, `max_speed_m_per_s`, `max_accel_m_per_s2`, `payload_kg`; or
    /// `flags` for axis values without the axis flag).
    Axis(&'static str),
}

impl core::fmt::Display for MotorImageError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            MotorImageError::TooShort => {
                write!(
                    f,
                    "motor image shorter than its version's record ({} bytes for version 3)",
                    MotorImage::LEN
                )
            }
            MotorImageError::Erased => write!(f, "no motor image programmed (erased flash)"),
            MotorImageError::BadMagic => write!(f, "not a motor image (magic is not DCFM)"),
            MotorImageError::UnsupportedVersion(v) => write!(f, "motor image version {v} is not supported"),
            MotorImageError::BadCrc => write!(f, "motor image CRC mismatch (corrupted record)"),
            MotorImageError::Param(e) => write!(f, "motor image: {e}"),
            MotorImageError::BusVoltage => {
                write!(f, "motor image: bus voltage must be a positive number of volts")
            }
            MotorImageError::Compensation => write!(
                f,
                "motor image: inverter compensation out of range (dead time 0-10 us, drop >= 0 V, band > 0 A)"
            ),
            MotorImageError::Axis("flags") => {
                write!(f, "motor image: axis values without the axis flag")
            }
            MotorImageError::Axis(field @ ("max_speed_m_per_s" | "max_accel_m_per_s2")) => {
                write!(f, "motor image: axis `{field}` must be a positive finite number")
            }
            MotorImageError::Axis("payload_kg") => {
                write!(f, "motor image: axis `payload_kg` must be a finite mass of at least 0 kg")
            }
            MotorImageError::Axis("stroke_max_m") => {
                write!(f, "motor image: axis `stroke_max_m` must be a finite position above `stroke_min_m`")
            }
            MotorImageError::Axis(field) => write!(f, "motor image: axis `{field}` must be a finite number"),
        }
    }
}

/// The positioning axis a motor drives (a motor image's optional section): the stroke
/// the targets must lie in, the move profile's limits and the mass carried besides the
/// mover.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotorAxis {
    /// The stroke (m) and the profile's top speed (m/s) and acceleration (m/s²).
    pub limits: ProfileLimits,
    /// Carriage and payload moved besides the mover, kg (>= 0): the drive's moving mass
    /// is the motor's `mass_kg` plus this.
    pub payload_kg: f32,
}

/// A validated motor, the nominal DC-bus voltage it runs on, the inverter's
/// voltage-error compensation, if one was identified or typed in, and the positioning
/// axis, if one was given.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotorImage {
    /// The motor (SI units, validated).
    pub motor: MotorParams,
    /// Nominal DC-bus voltage, V (> 0): sets the drive's bus limits and per-unit base.
    pub bus_v: f32,
    /// The inverter compensation the drive should use
    /// (`DriveConfig::dead_time_compensation`); `None`: not
    /// known (a version-1 record, or written without one).
    pub compensation: Option<DeadTimeCompensation>,
    /// The positioning axis ([`MotorImage::with_axis`]); `None`: a speed drive (a
    /// version-1 or -2 record, or written without one).
    pub axis: Option<MotorAxis>,
}

/// The longest dead time a compensation may hold, s (10 us: beyond any drive's).
const MAX_DEAD_TIME_S: f32 = 10e-6;

impl MotorImage {
    /// Length of the record, bytes (version 3; the longest read).
    pub const LEN: usize = 88;
    /// Format version written (versions 1, 2 and 3 are read).
    pub const VERSION: u16 = 3;

    /// Validates `motor` and `bus_v`; no compensation.
    pub fn new(motor: MotorParams, bus_v: f32) -> Result<Self, MotorImageError> {
        let motor = MotorParams::new(motor).map_err(MotorImageError::Param)?;
        if !(bus_v.is_finite() && bus_v > 0.0) {
            return Err(MotorImageError::BusVoltage);
        }
        Ok(MotorImage { motor, bus_v, compensation: None, axis: None })
    }

    /// The same image with the inverter compensation `compensation`, validated (dead time
    /// in `[0, 10 us]`, device drop `>= 0` V, band `> 0` A, all finite).
    pub fn with_compensation(self, compensation: DeadTimeCompensation) -> Result<Self, MotorImageError> {
        let c = compensation;
        let ok = (0.0..=MAX_DEAD_TIME_S).contains(&c.dead_time_s)
            && c.device_drop_v.is_finite()
            && c.device_drop_v >= 0.0
            && c.current_band_a.is_finite()
            && c.current_band_a > 0.0;
        if !ok {
            return Err(MotorImageError::Compensation);
        }
        Ok(MotorImage { compensation: Some(c), ..self })
    }

    /// The same image with the positioning axis `axis`, validated as a record: every
    /// value finite, `stroke_min_m < stroke_max_m`, speed and acceleration `> 0`
    /// ([`ProfileLimits::validate`]), `payload_kg >= 0`. The first bad field is named.
    /// Whether the motor can follow it is the drive's to say
    /// (`DriveConfig::check_image_axis`, `DriveConfig::for_image`).
    pub fn with_axis(self, axis: MotorAxis) -> Result<Self, MotorImageError> {
        axis.limits.validate().map_err(|f| MotorImageError::Axis(f.name()))?;
        if !(axis.payload_kg.is_finite() && axis.payload_kg >= 0.0) {
            return Err(MotorImageError::Axis("payload_kg"));
        }
        Ok(MotorImage { axis: Some(axis), ..self })
    }

    /// The record's bytes (version 3).
    pub fn encode(&self) -> [u8; Self::LEN] {
        let mut out = [0u8; Self::LEN];
        out[..4].copy_from_slice(&MAGIC);
        out[4..6].copy_from_slice(&Self::VERSION.to_le_bytes());
        let mut flags = 0;
        if self.compensation.is_some() {
            flags |= FLAG_COMPENSATION;
        }
        if self.axis.is_some() {
            flags |= FLAG_AXIS;
        }
        out[6..8].copy_from_slice(&flags.to_le_bytes());
        for (i, v) in self.values().iter().enumerate() {
            out[8 + 4 * i..12 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
        let crc = crc16(&out[..CRC_AT]);
        out[CRC_AT..CRC_AT + 2].copy_from_slice(&crc.to_le_bytes());
        out
    }

    /// Reads and validates a record of version 3, 2 or 1 (migrated: no axis, and for
    /// version 1 no compensation; module docs). Bytes beyond the record are ignored: a
    /// version-1 record needs only its 56 bytes, a version-2 record its 64.
    pub fn decode(bytes: &[u8]) -> Result<Self, MotorImageError> {
        let Some(head) = bytes.get(..8) else {
            return Err(MotorImageError::TooShort);
        };
        let version = u16::from_le_bytes([head[4], head[5]]);
        let (len, crc_at) = match version {
            1 => (LEN_V1, CRC_AT_V1),
            2 => (LEN_V2, CRC_AT_V2),
            Self::VERSION => (Self::LEN, CRC_AT),
            // An unknown version: only the head is looked at (erased, magic, version).
            _ => (8, 0),
        };
        let Some(raw) = bytes.get(..len) else {
            return Err(MotorImageError::TooShort);
        };
        if raw.iter().all(|&b| b == 0xFF) {
            return Err(MotorImageError::Erased);
        }
        // The record in a fixed-size buffer (an older record padded with zeros): every
        // index below is a constant within it, so no bounds check can fail (the ESC1
        // images link no panic path, `.ci/no-panic`).
        let mut rec = [0u8; Self::LEN];
        rec.iter_mut().zip(raw).for_each(|(d, s)| *d = *s);
        if rec[..4] != MAGIC {
            return Err(MotorImageError::BadMagic);
        }
        if crc_at == 0 {
            return Err(MotorImageError::UnsupportedVersion(version));
        }
        let (covered, rest) = rec.split_at(crc_at.min(Self::LEN));
        let sent = rest.get(..2).map(|c| u16::from_le_bytes([c[0], c[1]]));
        if sent != Some(crc16(covered)) {
            return Err(MotorImageError::BadCrc);
        }
        // Older records: the CRC and reserved bytes where the newer fields are read as
        // zeros (the flags below say none is present).
        rec[crc_at.min(Self::LEN)..].fill(0);
        let f = |i: usize| {
            let at = (8 + 4 * i).min(Self::LEN - 4);
            f32::from_le_bytes([rec[at], rec[at + 1], rec[at + 2], rec[at + 3]])
        };
        let motor = MotorParams {
            rs_ohm: f(0),
            ld_h: f(1),
            lq_h: f(2),
            psi_f_wb: f(3),
            pole_pitch_m: f(4),
            mass_kg: f(5),
            viscous_n_s_per_m: f(6),
            rated_current_a: f(7),
            rated_voltage_v: f(8),
        };
        let mut image = Self::new(motor, f(9))?;
        if version == 1 {
            // Version 1's bytes 6..8 were reserved and are not read.
            return Ok(image);
        }
        let flags = u16::from_le_bytes([rec[6], rec[7]]);
        let known = if version == 2 { FLAG_COMPENSATION } else { FLAG_COMPENSATION | FLAG_AXIS };
        if flags & !known != 0 {
            return Err(MotorImageError::Compensation);
        }
        let zero = |from: usize, n: usize| (from..from + n).all(|i| f(i).to_bits() == 0);
        if flags & FLAG_COMPENSATION != 0 {
            image = image.with_compensation(DeadTimeCompensation {
                dead_time_s: f(10),
                device_drop_v: f(11),
                current_band_a: f(12),
            })?;
        } else if !zero(10, 3) {
            return Err(MotorImageError::Compensation);
        }
        if flags & FLAG_AXIS != 0 {
            image = image.with_axis(MotorAxis {
                limits: ProfileLimits {
                    stroke_min_m: f(13),
                    stroke_max_m: f(14),
                    max_speed_m_per_s: f(15),
                    max_accel_m_per_s2: f(16),
                },
                payload_kg: f(17),
            })?;
        } else if !zero(13, 5) {
            return Err(MotorImageError::Axis("flags"));
        }
        Ok(image)
    }

    fn values(&self) -> [f32; VALUES] {
        let m = &self.motor;
        let c = self.compensation.map_or([0.0; 3], |c| [c.dead_time_s, c.device_drop_v, c.current_band_a]);
        let a = self.axis.map_or([0.0; 5], |a| {
            let l = a.limits;
            [l.stroke_min_m, l.stroke_max_m, l.max_speed_m_per_s, l.max_accel_m_per_s2, a.payload_kg]
        });
        [
            m.rs_ohm,
            m.ld_h,
            m.lq_h,
            m.psi_f_wb,
            m.pole_pitch_m,
            m.mass_kg,
            m.viscous_n_s_per_m,
            m.rated_current_a,
            m.rated_voltage_v,
            self.bus_v,
            c[0],
            c[1],
            c[2],
            a[0],
            a[1],
            a[2],
            a[3],
            a[4],
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motor::ParamFault;
    extern crate alloc;

    fn comp() -> DeadTimeCompensation {
        DeadTimeCompensation { dead_time_s: 2.3e-6, device_drop_v: 0.0, current_band_a: 0.0097 }
    }

    /// A version-1 record written by hand from its documented layout (as `dcfo
    /// motor-image` wrote it before version 2).
    fn v1_record(motor: &MotorParams, bus_v: f32) -> [u8; 56] {
        let mut b = [0u8; 56];
        b[..4].copy_from_slice(b"DCFM");
        b[4..6].copy_from_slice(&1u16.to_le_bytes());
        let values = [
            motor.rs_ohm,
            motor.ld_h,
            motor.lq_h,
            motor.psi_f_wb,
            motor.pole_pitch_m,
            motor.mass_kg,
            motor.viscous_n_s_per_m,
            motor.rated_current_a,
            motor.rated_voltage_v,
            bus_v,
        ];
        for (i, v) in values.iter().enumerate() {
            b[8 + 4 * i..12 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
        let crc = crc16(&b[..48]);
        b[48..50].copy_from_slice(&crc.to_le_bytes());
        b
    }

    /// Found by the fuzzer (`fuzz/fuzz_targets/motor_image.rs`, whose contract first
    /// compared the CRC too): the reserved bytes are documented as 0 and not read, so a
    /// record with other reserved bytes and its CRC over them is the same image (and
    /// re-encodes with zeros, so with another CRC).
    #[test]
    fn reserved_bytes_are_not_read() {
        let image = MotorImage::new(MotorParams::paper(), 24.0).unwrap().with_compensation(comp()).unwrap();
        let mut bytes = image.encode();
        bytes[82..].fill(0xA5);
        assert_eq!(MotorImage::decode(&bytes), Ok(image));
        // Version 1: bytes 6..8 and 50..56 were reserved.
        let mut v1 = v1_record(&MotorParams::paper(), 24.0);
        v1[6] = 0x44;
        v1[7] = 0x43;
        let crc = crc16(&v1[..48]);
        v1[48..50].copy_from_slice(&crc.to_le_bytes());
        v1[50..].fill(0xA5);
        assert_eq!(MotorImage::decode(&v1), MotorImage::new(MotorParams::paper(), 24.0));
    }

    fn axis() -> MotorAxis {
        MotorAxis {
            limits: ProfileLimits {
                stroke_min_m: -0.01,
                stroke_max_m: 0.31,
                max_speed_m_per_s: 0.5,
                max_accel_m_per_s2: 3.0,
            },
            payload_kg: 10.0,
        }
    }

    #[test]
    fn round_trips_and_matches_the_documented_layout() {
        for compensation in [None, Some(comp())] {
            for with_axis in [None, Some(axis())] {
                let mut image = MotorImage::new(MotorParams::paper(), 311.0).unwrap();
                if let Some(c) = compensation {
                    image = image.with_compensation(c).unwrap();
                }
                if let Some(a) = with_axis {
                    image = image.with_axis(a).unwrap();
                }
                let bytes = image.encode();
                assert_eq!(bytes.len(), 88);
                assert_eq!(&bytes[..4], b"DCFM");
                assert_eq!(u16::from_le_bytes([bytes[4], bytes[5]]), 3);
                let flags = u16::from(compensation.is_some()) | (u16::from(with_axis.is_some()) << 1);
                assert_eq!(u16::from_le_bytes([bytes[6], bytes[7]]), flags);
                // rs_ohm = 5.0 at offset 8, bus at offset 44, the dead time at 48, the
                // band at 56, the stroke's ends at 60 and 64, the speed at 68, the
                // acceleration at 72, the payload at 76, the CRC of 0..80 at 80,
                // independently of `values`.
                let at = |i: usize| f32::from_le_bytes(bytes[i..i + 4].try_into().unwrap());
                assert_eq!(at(8), 5.0);
                assert_eq!(at(44), 311.0);
                assert_eq!(at(48), compensation.map_or(0.0, |c| c.dead_time_s));
                assert_eq!(at(56), compensation.map_or(0.0, |c| c.current_band_a));
                let a = with_axis.map(|a| a.limits);
                assert_eq!(at(60), a.map_or(0.0, |l| l.stroke_min_m));
                assert_eq!(at(64), a.map_or(0.0, |l| l.stroke_max_m));
                assert_eq!(at(68), a.map_or(0.0, |l| l.max_speed_m_per_s));
                assert_eq!(at(72), a.map_or(0.0, |l| l.max_accel_m_per_s2));
                assert_eq!(at(76), with_axis.map_or(0.0, |a| a.payload_kg));
                assert_eq!(u16::from_le_bytes([bytes[80], bytes[81]]), crc16(&bytes[..80]));
                assert_eq!(bytes[82..], [0; 6]);
                let back = MotorImage::decode(&bytes).unwrap();
                assert_eq!(back, image);
                assert_eq!((back.compensation, back.axis), (compensation, with_axis));
            }
        }
    }

    /// A version-2 record written by hand from its documented layout (as `dcfo
    /// motor-image` and `dcfo identify --image` wrote it before version 3).
    fn v2_record(motor: &MotorParams, bus_v: f32, compensation: Option<DeadTimeCompensation>) -> [u8; 64] {
        let mut b = [0u8; 64];
        b[..56].copy_from_slice(&v1_record(motor, bus_v));
        b[4..6].copy_from_slice(&2u16.to_le_bytes());
        b[6..8].copy_from_slice(&u16::from(compensation.is_some()).to_le_bytes());
        let c = compensation.map_or([0.0; 3], |c| [c.dead_time_s, c.device_drop_v, c.current_band_a]);
        for (i, v) in c.iter().enumerate() {
            b[48 + 4 * i..52 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
        let crc = crc16(&b[..60]);
        b[60..62].copy_from_slice(&crc.to_le_bytes());
        b
    }

    #[test]
    fn a_version_2_record_is_migrated_without_an_axis() {
        for compensation in [None, Some(comp())] {
            let v2 = v2_record(&MotorParams::paper(), 24.0, compensation);
            let image = MotorImage::decode(&v2).unwrap();
            assert_eq!((image.motor, image.bus_v), (MotorParams::paper(), 24.0));
            assert_eq!((image.compensation, image.axis), (compensation, None));
            // Its 64 bytes suffice (a page read of 88 bytes sees erased flash after them).
            let mut page = [0xFFu8; 88];
            page[..64].copy_from_slice(&v2);
            assert_eq!(MotorImage::decode(&page), Ok(image));
            // Version 2 is CRC-checked as version 2 was, and knows no axis flag.
            let mut bad = v2;
            bad[20] ^= 0x10;
            assert_eq!(MotorImage::decode(&bad), Err(MotorImageError::BadCrc));
            assert_eq!(MotorImage::decode(&v2[..63]), Err(MotorImageError::TooShort));
            let mut axis_flag = v2;
            axis_flag[6] |= 2;
            let crc = crc16(&axis_flag[..60]);
            axis_flag[60..62].copy_from_slice(&crc.to_le_bytes());
            assert_eq!(MotorImage::decode(&axis_flag), Err(MotorImageError::Compensation));
            // Re-encoded, it is version 3 without an axis.
            let again = image.encode();
            assert_eq!(u16::from_le_bytes([again[4], again[5]]), 3);
            assert_eq!(MotorImage::decode(&again), Ok(image));
        }
    }

    #[test]
    fn every_bad_axis_field_is_named() {
        let image = MotorImage::new(MotorParams::paper(), 311.0).unwrap();
        type Spoil = fn(&mut MotorAxis);
        let bad: [(Spoil, MotorImageError); 11] = [
            (|a| a.limits.stroke_min_m = f32::NAN, MotorImageError::Axis("stroke_min_m")),
            (|a| a.limits.stroke_min_m = f32::NEG_INFINITY, MotorImageError::Axis("stroke_min_m")),
            (|a| a.limits.stroke_max_m = f32::INFINITY, MotorImageError::Axis("stroke_max_m")),
            (|a| a.limits.stroke_max_m = -0.01, MotorImageError::Axis("stroke_max_m")),
            (|a| a.limits.stroke_max_m = -0.02, MotorImageError::Axis("stroke_max_m")),
            (|a| a.limits.max_speed_m_per_s = 0.0, MotorImageError::Axis("max_speed_m_per_s")),
            (|a| a.limits.max_speed_m_per_s = f32::NAN, MotorImageError::Axis("max_speed_m_per_s")),
            (|a| a.limits.max_accel_m_per_s2 = -3.0, MotorImageError::Axis("max_accel_m_per_s2")),
            (|a| a.limits.max_accel_m_per_s2 = f32::INFINITY, MotorImageError::Axis("max_accel_m_per_s2")),
            (|a| a.payload_kg = -0.1, MotorImageError::Axis("payload_kg")),
            (|a| a.payload_kg = f32::NAN, MotorImageError::Axis("payload_kg")),
        ];
        for (spoil, error) in bad {
            let mut a = axis();
            spoil(&mut a);
            assert_eq!(image.with_axis(a), Err(error), "{a:?}");
            // The same record written by a careless tool, with its CRC right.
            let bytes = MotorImage { axis: Some(a), ..image }.encode();
            assert_eq!(MotorImage::decode(&bytes), Err(error), "{a:?}");
        }
        // Axis values without the axis flag, with the CRC right.
        let mut bytes = MotorImage { axis: Some(axis()), ..image }.encode();
        bytes[6..8].copy_from_slice(&0u16.to_le_bytes());
        let crc = crc16(&bytes[..CRC_AT]);
        bytes[CRC_AT..CRC_AT + 2].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(MotorImage::decode(&bytes), Err(MotorImageError::Axis("flags")));
        // Every message names the field.
        for field in ["stroke_min_m", "stroke_max_m", "max_speed_m_per_s", "max_accel_m_per_s2", "payload_kg"]
        {
            let text = alloc::string::ToString::to_string(&MotorImageError::Axis(field));
            assert!(text.contains(field), "{text}");
        }
    }

    #[test]
    fn a_version_1_record_is_migrated_without_a_compensation() {
        let mut motor = MotorParams::paper();
        motor.mass_kg = 2.5;
        let v1 = v1_record(&motor, 48.0);
        let image = MotorImage::decode(&v1).unwrap();
        assert_eq!((image.motor, image.bus_v, image.compensation), (motor, 48.0, None));
        // Its 56 bytes suffice (a page read of 64 bytes sees erased flash after them).
        let mut page = [0xFFu8; 64];
        page[..56].copy_from_slice(&v1);
        assert_eq!(MotorImage::decode(&page), Ok(image));
        // Version 1 is CRC-checked as version 1 was.
        let mut bad = v1;
        bad[20] ^= 0x10;
        assert_eq!(MotorImage::decode(&bad), Err(MotorImageError::BadCrc));
        assert_eq!(MotorImage::decode(&v1[..55]), Err(MotorImageError::TooShort));
        // Re-encoded, it is version 3.
        assert_eq!(MotorImage::decode(&image.encode()), Ok(image));
    }

    #[test]
    fn every_corruption_is_refused() {
        let good = MotorImage::new(MotorParams::paper(), 311.0)
            .unwrap()
            .with_compensation(comp())
            .unwrap()
            .with_axis(axis())
            .unwrap()
            .encode();
        // Any single flipped bit in the CRC-covered part or the CRC itself.
        for byte in 0..CRC_AT + 2 {
            for bit in 0..8 {
                let mut bad = good;
                bad[byte] ^= 1 << bit;
                assert!(MotorImage::decode(&bad).is_err(), "byte {byte} bit {bit}");
            }
        }
        assert_eq!(MotorImage::decode(&good[..87]), Err(MotorImageError::TooShort));
        assert_eq!(MotorImage::decode(&good[..7]), Err(MotorImageError::TooShort));
        assert_eq!(MotorImage::decode(&[0xFF; 64]), Err(MotorImageError::Erased));
        assert_eq!(MotorImage::decode(&[0; 64]), Err(MotorImageError::BadMagic));
        let mut magic = good;
        magic[0] = b'X';
        assert_eq!(MotorImage::decode(&magic), Err(MotorImageError::BadMagic));
        let mut v4 = good;
        v4[4] = 4;
        assert_eq!(MotorImage::decode(&v4), Err(MotorImageError::UnsupportedVersion(4)));
    }

    #[test]
    fn unphysical_values_are_named_even_with_a_good_crc() {
        let mut motor = MotorParams::paper();
        motor.ld_h = -1.0;
        // Bypass `new` to write a record a careless tool might produce.
        let bytes = MotorImage { motor, bus_v: 24.0, compensation: None, axis: None }.encode();
        assert_eq!(
            MotorImage::decode(&bytes),
            Err(MotorImageError::Param(ParamError { field: "ld_h", reason: ParamFault::NotPositive }))
        );
        let bytes =
            MotorImage { motor: MotorParams::paper(), bus_v: f32::NAN, compensation: None, axis: None }
                .encode();
        assert_eq!(MotorImage::decode(&bytes), Err(MotorImageError::BusVoltage));
        let paper = MotorImage::new(MotorParams::paper(), 24.0).unwrap();
        for bad in [
            DeadTimeCompensation { dead_time_s: -1e-9, ..comp() },
            DeadTimeCompensation { dead_time_s: 20e-6, ..comp() },
            DeadTimeCompensation { device_drop_v: f32::INFINITY, ..comp() },
            DeadTimeCompensation { current_band_a: 0.0, ..comp() },
        ] {
            assert_eq!(paper.with_compensation(bad), Err(MotorImageError::Compensation), "{bad:?}");
            let bytes = MotorImage { compensation: Some(bad), ..paper }.encode();
            assert_eq!(MotorImage::decode(&bytes), Err(MotorImageError::Compensation), "{bad:?}");
        }
        // Compensation values without the flag, or unknown flags, with the CRC right.
        let mut bytes = MotorImage { compensation: Some(comp()), ..paper }.encode();
        for flags in [0u16, 4, 5, 0x8001] {
            bytes[6..8].copy_from_slice(&flags.to_le_bytes());
            let crc = crc16(&bytes[..CRC_AT]);
            bytes[CRC_AT..CRC_AT + 2].copy_from_slice(&crc.to_le_bytes());
            assert_eq!(MotorImage::decode(&bytes), Err(MotorImageError::Compensation), "flags {flags}");
        }
    }
}
