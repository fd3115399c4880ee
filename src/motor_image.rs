//! The motor as configuration on a board: a fixed-size binary record of the motor file's
//! parameters, the nominal DC-bus voltage and (since version 2) the inverter's
//! voltage-error compensation, protected by a CRC, that a host tool writes
//! (`dcfo motor-image`, `dcfo identify --image`) and a firmware reads from a reserved
//! flash page at boot.
//!
//! The drive code is never compiled for one motor: the firmware validates the record
//! exactly as the host validates a motor file ([`MotorParams::new`]) and refuses to run
//! without a valid one.
//!
//! Layout of version 2, little-endian, [`MotorImage::LEN`] = 64 bytes (a multiple of the
//! 8-byte flash programming unit of STM32G4 parts):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 4]` | magic `b"DCFM"` |
//! | 4 | u16 | format version ([`MotorImage::VERSION`] = 2) |
//! | 6 | u16 | flags: bit 0 = the compensation fields hold a compensation; other bits 0 |
//! | 8 | 9 × f32 | `rs_ohm`, `ld_h`, `lq_h`, `psi_f_wb`, `pole_pitch_m`, `mass_kg`, `viscous_n_s_per_m`, `rated_current_a`, `rated_voltage_v` (the motor file's keys and units) |
//! | 44 | f32 | nominal DC-bus voltage, V |
//! | 48 | 3 × f32 | inverter compensation ([`DeadTimeCompensation`]): dead time (s), device drop (V), current band (A); zero without one |
//! | 60 | u16 | CRC-16/IBM-3740 of bytes 0..60 |
//! | 62 | `[u8; 2]` | reserved, 0 |
//!
//! **Version 1** (56 bytes: bytes 0..48 as above with byte 6..8 reserved, the CRC of
//! bytes 0..48 at 48, 6 reserved bytes) is still read, CRC-checked and validated the same
//! way, and migrated: it holds no compensation ([`MotorImage::compensation`] is `None`).
//! [`MotorImage::encode`] writes version 2 only. Any other version is
//! [`MotorImageError::UnsupportedVersion`].

use crate::drive::DeadTimeCompensation;
use crate::motor::{MotorParams, ParamError};
use crc::{CRC_16_IBM_3740, Crc};

const MAGIC: [u8; 4] = *b"DCFM";
const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);
/// Where the CRC is in a version-2 record.
const CRC_AT: usize = 60;
/// Where the CRC is in a version-1 record, and that record's length.
const CRC_AT_V1: usize = 48;
const LEN_V1: usize = 56;
/// Flag bit: the record holds a compensation.
const FLAG_COMPENSATION: u16 = 1 << 0;

/// Why a byte record is not a usable motor image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MotorImageError {
    /// Fewer than [`MotorImage::LEN`] bytes.
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
}

impl core::fmt::Display for MotorImageError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            MotorImageError::TooShort => write!(f, "motor image shorter than {} bytes", MotorImage::LEN),
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
        }
    }
}

/// A validated motor, the nominal DC-bus voltage it runs on and the inverter's
/// voltage-error compensation, if one was identified or typed in.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotorImage {
    /// The motor (SI units, validated).
    pub motor: MotorParams,
    /// Nominal DC-bus voltage, V (> 0): sets the drive's bus limits and per-unit base.
    pub bus_v: f32,
    /// The inverter compensation the drive should use
    /// ([`DriveConfig::dead_time_compensation`](crate::drive::DriveConfig)); `None`: not
    /// known (a version-1 record, or written without one).
    pub compensation: Option<DeadTimeCompensation>,
}

/// The longest dead time a compensation may hold, s (10 us: beyond any drive's).
const MAX_DEAD_TIME_S: f32 = 10e-6;

impl MotorImage {
    /// Length of the record, bytes (version 2).
    pub const LEN: usize = 64;
    /// Format version written (versions 1 and 2 are read).
    pub const VERSION: u16 = 2;

    /// Validates `motor` and `bus_v`; no compensation.
    pub fn new(motor: MotorParams, bus_v: f32) -> Result<Self, MotorImageError> {
        let motor = MotorParams::new(motor).map_err(MotorImageError::Param)?;
        if !(bus_v.is_finite() && bus_v > 0.0) {
            return Err(MotorImageError::BusVoltage);
        }
        Ok(MotorImage { motor, bus_v, compensation: None })
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

    /// The record's bytes (version 2).
    pub fn encode(&self) -> [u8; Self::LEN] {
        let mut out = [0u8; Self::LEN];
        out[..4].copy_from_slice(&MAGIC);
        out[4..6].copy_from_slice(&Self::VERSION.to_le_bytes());
        let flags = if self.compensation.is_some() { FLAG_COMPENSATION } else { 0 };
        out[6..8].copy_from_slice(&flags.to_le_bytes());
        for (i, v) in self.values().iter().enumerate() {
            out[8 + 4 * i..12 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
        let crc = CRC16.checksum(&out[..CRC_AT]);
        out[CRC_AT..CRC_AT + 2].copy_from_slice(&crc.to_le_bytes());
        out
    }

    /// Reads and validates a record of version 2, or of version 1 (migrated, no
    /// compensation; module docs). Bytes beyond the record are ignored: a version-1
    /// record needs only its 56 bytes.
    pub fn decode(bytes: &[u8]) -> Result<Self, MotorImageError> {
        let Some(head) = bytes.get(..8) else {
            return Err(MotorImageError::TooShort);
        };
        let version = u16::from_le_bytes([head[4], head[5]]);
        let len = if version == 1 { LEN_V1 } else { Self::LEN };
        let Some(raw) = bytes.get(..len) else {
            return Err(MotorImageError::TooShort);
        };
        if raw.iter().all(|&b| b == 0xFF) {
            return Err(MotorImageError::Erased);
        }
        // The record in a fixed-size buffer (a version-1 record padded with zeros): every
        // index below is a constant within it, so no bounds check can fail (the ESC1
        // images link no panic path, `.ci/no-panic`).
        let mut rec = [0u8; Self::LEN];
        rec.iter_mut().zip(raw).for_each(|(d, s)| *d = *s);
        if rec[..4] != MAGIC {
            return Err(MotorImageError::BadMagic);
        }
        let crc_at = match version {
            1 => CRC_AT_V1,
            Self::VERSION => CRC_AT,
            v => return Err(MotorImageError::UnsupportedVersion(v)),
        };
        let (covered, rest) = rec.split_at(crc_at.min(Self::LEN));
        let sent = rest.get(..2).map(|c| u16::from_le_bytes([c[0], c[1]]));
        if sent != Some(CRC16.checksum(covered)) {
            return Err(MotorImageError::BadCrc);
        }
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
        let image = Self::new(motor, f(9))?;
        if version == 1 {
            // Version 1's bytes 6..8 were reserved and are not read.
            return Ok(image);
        }
        let flags = u16::from_le_bytes([rec[6], rec[7]]);
        let compensation = [f(10), f(11), f(12)];
        match flags {
            FLAG_COMPENSATION => image.with_compensation(DeadTimeCompensation {
                dead_time_s: compensation[0],
                device_drop_v: compensation[1],
                current_band_a: compensation[2],
            }),
            0 if compensation.iter().all(|x| x.to_bits() == 0) => Ok(image),
            _ => Err(MotorImageError::Compensation),
        }
    }

    fn values(&self) -> [f32; 13] {
        let m = &self.motor;
        let c = self.compensation.map_or([0.0; 3], |c| [c.dead_time_s, c.device_drop_v, c.current_band_a]);
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
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motor::ParamFault;

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
        let crc = CRC16.checksum(&b[..48]);
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
        bytes[62..].fill(0xA5);
        assert_eq!(MotorImage::decode(&bytes), Ok(image));
        // Version 1: bytes 6..8 and 50..56 were reserved.
        let mut v1 = v1_record(&MotorParams::paper(), 24.0);
        v1[6] = 0x44;
        v1[7] = 0x43;
        let crc = CRC16.checksum(&v1[..48]);
        v1[48..50].copy_from_slice(&crc.to_le_bytes());
        v1[50..].fill(0xA5);
        assert_eq!(MotorImage::decode(&v1), MotorImage::new(MotorParams::paper(), 24.0));
    }

    #[test]
    fn round_trips_and_matches_the_documented_layout() {
        for compensation in [None, Some(comp())] {
            let mut image = MotorImage::new(MotorParams::paper(), 24.0).unwrap();
            if let Some(c) = compensation {
                image = image.with_compensation(c).unwrap();
            }
            let bytes = image.encode();
            assert_eq!(bytes.len(), 64);
            assert_eq!(&bytes[..4], b"DCFM");
            assert_eq!(u16::from_le_bytes([bytes[4], bytes[5]]), 2);
            assert_eq!(u16::from_le_bytes([bytes[6], bytes[7]]), u16::from(compensation.is_some()));
            // rs_ohm = 5.0 at offset 8, bus 24 V at offset 44, the dead time at 48, the
            // band at 56, the CRC of 0..60 at 60, independently of `values`.
            assert_eq!(f32::from_le_bytes(bytes[8..12].try_into().unwrap()), 5.0);
            assert_eq!(f32::from_le_bytes(bytes[44..48].try_into().unwrap()), 24.0);
            let dead_time = compensation.map_or(0.0, |c| c.dead_time_s);
            let band = compensation.map_or(0.0, |c| c.current_band_a);
            assert_eq!(f32::from_le_bytes(bytes[48..52].try_into().unwrap()), dead_time);
            assert_eq!(f32::from_le_bytes(bytes[56..60].try_into().unwrap()), band);
            assert_eq!(u16::from_le_bytes([bytes[60], bytes[61]]), CRC16.checksum(&bytes[..60]));
            assert_eq!(bytes[62..], [0; 2]);
            let back = MotorImage::decode(&bytes).unwrap();
            assert_eq!(back, image);
            assert_eq!(back.compensation, compensation);
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
        // Re-encoded, it is version 2.
        assert_eq!(MotorImage::decode(&image.encode()), Ok(image));
    }

    #[test]
    fn every_corruption_is_refused() {
        let good =
            MotorImage::new(MotorParams::paper(), 24.0).unwrap().with_compensation(comp()).unwrap().encode();
        // Any single flipped bit in the CRC-covered part or the CRC itself.
        for byte in 0..CRC_AT + 2 {
            for bit in 0..8 {
                let mut bad = good;
                bad[byte] ^= 1 << bit;
                assert!(MotorImage::decode(&bad).is_err(), "byte {byte} bit {bit}");
            }
        }
        assert_eq!(MotorImage::decode(&good[..63]), Err(MotorImageError::TooShort));
        assert_eq!(MotorImage::decode(&good[..7]), Err(MotorImageError::TooShort));
        assert_eq!(MotorImage::decode(&[0xFF; 64]), Err(MotorImageError::Erased));
        assert_eq!(MotorImage::decode(&[0; 64]), Err(MotorImageError::BadMagic));
        let mut magic = good;
        magic[0] = b'X';
        assert_eq!(MotorImage::decode(&magic), Err(MotorImageError::BadMagic));
        let mut v3 = good;
        v3[4] = 3;
        assert_eq!(MotorImage::decode(&v3), Err(MotorImageError::UnsupportedVersion(3)));
    }

    #[test]
    fn unphysical_values_are_named_even_with_a_good_crc() {
        let mut motor = MotorParams::paper();
        motor.ld_h = -1.0;
        // Bypass `new` to write a record a careless tool might produce.
        let bytes = MotorImage { motor, bus_v: 24.0, compensation: None }.encode();
        assert_eq!(
            MotorImage::decode(&bytes),
            Err(MotorImageError::Param(ParamError { field: "ld_h", reason: ParamFault::NotPositive }))
        );
        let bytes = MotorImage { motor: MotorParams::paper(), bus_v: f32::NAN, compensation: None }.encode();
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
        for flags in [0u16, 2, 3] {
            bytes[6..8].copy_from_slice(&flags.to_le_bytes());
            let crc = CRC16.checksum(&bytes[..CRC_AT]);
            bytes[CRC_AT..CRC_AT + 2].copy_from_slice(&crc.to_le_bytes());
            assert_eq!(MotorImage::decode(&bytes), Err(MotorImageError::Compensation), "flags {flags}");
        }
    }
}
