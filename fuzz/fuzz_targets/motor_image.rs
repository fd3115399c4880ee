//! The motor-image decoder (the flash record the ESC1 boots from) fed arbitrary bytes.
//! Contract: no panic; an accepted image holds a motor that validates and re-encodes to
//! the same magic, version and values (bit for bit), which decode to the same image.
//! The reserved bytes 6..8 and 50..56 are documented as 0 and not read (the CRC covers
//! 6..8, so a record with other reserved bytes re-encodes with another CRC).
//!
//! Random bytes almost never carry the record's CRC-16, so with the first byte odd the
//! rest is taken as a record whose CRC (bytes 48..50, over bytes 0..48, as
//! `MotorImage::encode` writes it) is set right: the fuzzer then explores the magic, the
//! version and every value check.
#![no_main]

use dcfo::motor::MotorParams;
use dcfo::motor_image::MotorImage;
use libfuzzer_sys::fuzz_target;

const CRC_AT: usize = 48;

fuzz_target!(|data: &[u8]| {
    let mut bytes = data.to_vec();
    if let Some((first, rest)) = data.split_first()
        && first & 1 == 1
        && rest.len() >= MotorImage::LEN
    {
        const CRC16: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_IBM_3740);
        bytes = rest.to_vec();
        let crc = CRC16.checksum(&bytes[..CRC_AT]).to_le_bytes();
        bytes[CRC_AT..CRC_AT + 2].copy_from_slice(&crc);
    }
    if let Ok(image) = MotorImage::decode(&bytes) {
        assert!(MotorParams::new(image.motor).is_ok());
        assert!(image.bus_v.is_finite() && image.bus_v > 0.0);
        let encoded = image.encode();
        assert_eq!(encoded[..6], bytes[..6]);
        assert_eq!(encoded[8..CRC_AT], bytes[8..CRC_AT]);
        assert_eq!(MotorImage::decode(&encoded), Ok(image));
    }
});
