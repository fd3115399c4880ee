//! The motor as configuration on a board: a fixed-size binary record of the motor file's
//! parameters and the nominal DC-bus voltage, protected by a CRC, that a host tool writes
//! (`dcfo motor-image`) and a firmware reads from a reserved flash page at boot.
//!
//! The drive code is never compiled for one motor: the firmware validates the record
//! exactly as the host validates a motor file ([`MotorParams::new`]) and refuses to run
//! without a valid one.
//!
//! Layout, little-endian, [`MotorImage::LEN`] = 56 bytes (a multiple of the 8-byte
//! flash programming unit of STM32G4 parts):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 4]` | magic `b"DCFM"` |
//! | 4 | u16 | format version ([`MotorImage::VERSION`]) |
//! | 6 | u16 | reserved, 0 |
//! | 8 | 9 × f32 | `rs_ohm`, `ld_h`, `lq_h`, `psi_f_wb`, `pole_pitch_m`, `mass_kg`, `viscous_n_s_per_m`, `rated_current_a`, `rated_voltage_v` (the motor file's keys and units) |
//! | 44 | f32 | nominal DC-bus voltage, V |
//! | 48 | u16 | CRC-16/IBM-3740 of bytes 0..48 |
//! | 50 | `[u8; 6]` | reserved, 0 |

use crate::motor::{MotorParams, ParamError};
use crc::{CRC_16_IBM_3740, Crc};

const MAGIC: [u8; 4] = *b"DCFM";
const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);
const CRC_AT: usize = 48;

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
        }
    }
}

/// A validated motor and the nominal DC-bus voltage it runs on.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotorImage {
    /// The motor (SI units, validated).
    pub motor: MotorParams,
    /// Nominal DC-bus voltage, V (> 0): sets the drive's bus limits and per-unit base.
    pub bus_v: f32,
}

impl MotorImage {
    /// Length of the record, bytes.
    pub const LEN: usize = 56;
    /// Format version written and read.
    pub const VERSION: u16 = 1;

    /// Validates `motor` and `bus_v`.
    pub fn new(motor: MotorParams, bus_v: f32) -> Result<Self, MotorImageError> {
        let motor = MotorParams::new(motor).map_err(MotorImageError::Param)?;
        if !(bus_v.is_finite() && bus_v > 0.0) {
            return Err(MotorImageError::BusVoltage);
        }
        Ok(MotorImage { motor, bus_v })
    }

    /// The record's bytes.
    pub fn encode(&self) -> [u8; Self::LEN] {
        let mut out = [0u8; Self::LEN];
        out[..4].copy_from_slice(&MAGIC);
        out[4..6].copy_from_slice(&Self::VERSION.to_le_bytes());
        for (i, v) in self.values().iter().enumerate() {
            out[8 + 4 * i..12 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
        let crc = CRC16.checksum(&out[..CRC_AT]);
        out[CRC_AT..CRC_AT + 2].copy_from_slice(&crc.to_le_bytes());
        out
    }

    /// Reads and validates a record (bytes beyond [`MotorImage::LEN`] are ignored).
    pub fn decode(bytes: &[u8]) -> Result<Self, MotorImageError> {
        let Some(raw) = bytes.get(..Self::LEN) else {
            return Err(MotorImageError::TooShort);
        };
        if raw.iter().all(|&b| b == 0xFF) {
            return Err(MotorImageError::Erased);
        }
        if raw[..4] != MAGIC {
            return Err(MotorImageError::BadMagic);
        }
        let version = u16::from_le_bytes([raw[4], raw[5]]);
        if version != Self::VERSION {
            return Err(MotorImageError::UnsupportedVersion(version));
        }
        if CRC16.checksum(&raw[..CRC_AT]).to_le_bytes() != [raw[CRC_AT], raw[CRC_AT + 1]] {
            return Err(MotorImageError::BadCrc);
        }
        let f =
            |i: usize| f32::from_le_bytes([raw[8 + 4 * i], raw[9 + 4 * i], raw[10 + 4 * i], raw[11 + 4 * i]]);
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
        Self::new(motor, f(9))
    }

    fn values(&self) -> [f32; 10] {
        let m = &self.motor;
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
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motor::ParamFault;

    /// Found by the fuzzer (`fuzz/fuzz_targets/motor_image.rs`, whose contract first
    /// compared the CRC too): the reserved bytes are documented as 0 and not read, so a
    /// record with other reserved bytes and its CRC over them is the same image (and
    /// re-encodes with zeros, so with another CRC).
    #[test]
    fn reserved_bytes_are_not_read() {
        let image = MotorImage::new(MotorParams::paper(), 24.0).unwrap();
        let mut bytes = image.encode();
        bytes[6] = 0x44;
        bytes[7] = 0x43;
        bytes[50..].fill(0xA5);
        let crc = CRC16.checksum(&bytes[..CRC_AT]);
        bytes[CRC_AT..CRC_AT + 2].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(MotorImage::decode(&bytes), Ok(image));
        assert_ne!(image.encode()[CRC_AT..CRC_AT + 2], bytes[CRC_AT..CRC_AT + 2]);
    }

    #[test]
    fn round_trips_and_matches_the_documented_layout() {
        let image = MotorImage::new(MotorParams::paper(), 24.0).unwrap();
        let bytes = image.encode();
        assert_eq!(&bytes[..4], b"DCFM");
        assert_eq!(u16::from_le_bytes([bytes[4], bytes[5]]), 1);
        // rs_ohm = 5.0 at offset 8, bus 24 V at offset 44, independently of `values`.
        assert_eq!(f32::from_le_bytes(bytes[8..12].try_into().unwrap()), 5.0);
        assert_eq!(f32::from_le_bytes(bytes[44..48].try_into().unwrap()), 24.0);
        assert_eq!(bytes[50..], [0; 6]);
        assert_eq!(MotorImage::decode(&bytes), Ok(image));
    }

    #[test]
    fn every_corruption_is_refused() {
        let good = MotorImage::new(MotorParams::paper(), 24.0).unwrap().encode();
        // Any single flipped bit in the CRC-covered part or the CRC itself.
        for byte in 0..CRC_AT + 2 {
            for bit in 0..8 {
                let mut bad = good;
                bad[byte] ^= 1 << bit;
                assert!(MotorImage::decode(&bad).is_err(), "byte {byte} bit {bit}");
            }
        }
        assert_eq!(MotorImage::decode(&good[..55]), Err(MotorImageError::TooShort));
        assert_eq!(MotorImage::decode(&[0xFF; 64]), Err(MotorImageError::Erased));
        assert_eq!(MotorImage::decode(&[0; 56]), Err(MotorImageError::BadMagic));
        let mut v2 = good;
        v2[4] = 2;
        assert_eq!(MotorImage::decode(&v2), Err(MotorImageError::UnsupportedVersion(2)));
    }

    #[test]
    fn unphysical_values_are_named_even_with_a_good_crc() {
        let mut motor = MotorParams::paper();
        motor.ld_h = -1.0;
        // Bypass `new` to write a record a careless tool might produce.
        let bytes = MotorImage { motor, bus_v: 24.0 }.encode();
        assert_eq!(
            MotorImage::decode(&bytes),
            Err(MotorImageError::Param(ParamError { field: "ld_h", reason: ParamFault::NotPositive }))
        );
        let bytes = MotorImage { motor: MotorParams::paper(), bus_v: f32::NAN }.encode();
        assert_eq!(MotorImage::decode(&bytes), Err(MotorImageError::BusVoltage));
    }
}
