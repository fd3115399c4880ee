//! The one checksum of the crate: CRC-16/IBM-3740 (polynomial `0x1021`, initial value
//! `0xFFFF`, no reflection, no final xor; the "CCITT-FALSE" CRC), over the link's frames
//! ([`crate::link`]) and the motor image's records ([`crate::motor_image`]).
//!
//! Computed bit by bit (the `crc` crate's `NoTable`), in one function that is not
//! inlined: about 40 instructions a byte where a 256-entry table takes 8, but the table
//! is 512 B of an image's flash, and neither caller runs in the control interrupt (the
//! link at low priority, the record once at power-up). It detects every error burst of
//! up to 16 bits and every odd number of flipped bits.

#![forbid(unsafe_code)]

use crc::{CRC_16_IBM_3740, Crc, NoTable};

const CRC16: Crc<u16, NoTable> = Crc::<u16, NoTable>::new(&CRC_16_IBM_3740);

/// CRC-16/IBM-3740 of `bytes` (exact: the catalogue's check value of `b"123456789"` is
/// `0x29B1`).
#[inline(never)]
pub fn crc16(bytes: &[u8]) -> u16 {
    CRC16.checksum(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_catalogue_check_value_and_a_flipped_bit() {
        assert_eq!(crc16(b"123456789"), 0x29B1);
        assert_eq!(crc16(b""), 0xFFFF);
        let mut b = *b"123456789";
        b[4] ^= 0x10;
        assert_ne!(crc16(&b), 0x29B1);
    }
}
