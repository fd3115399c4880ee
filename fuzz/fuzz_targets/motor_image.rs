//! The motor-image decoder (the flash record the ESC1 boots from) fed arbitrary bytes.
//! Contract: no panic; an accepted image holds a motor that validates and re-encodes to
//! the same magic and values (bit for bit), which decode to the same image: a version-3
//! record also to the same version, flags, compensation and axis; a version-2 record
//! (migrated) to version 3 with the same flags and compensation and no axis; a version-1
//! record (migrated) to version 3 without a compensation or an axis. The reserved bytes
//! (version 3: 82..88; version 2: 62..64; version 1: 6..8 and 50..56) are documented as 0
//! and not read.
//!
//! Random bytes almost never carry the record's CRC-16, so with the first byte odd the
//! rest is taken as a record whose CRC (version 1: bytes 48..50 over bytes 0..48;
//! version 2: bytes 60..62 over 0..60; otherwise bytes 80..82 over 0..80, as
//! `MotorImage::encode` writes it) is set right: the fuzzer then explores the magic, the
//! version and every value check.
#![no_main]

use dcfo::motor::MotorParams;
use dcfo::motor_image::MotorImage;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut bytes = data.to_vec();
    if let Some((first, rest)) = data.split_first()
        && first & 1 == 1
        && rest.len() >= MotorImage::LEN
    {
        const CRC16: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_IBM_3740);
        bytes = rest.to_vec();
        let crc_at = match bytes[4..6] {
            [1, 0] => 48,
            [2, 0] => 60,
            _ => 80,
        };
        let crc = CRC16.checksum(&bytes[..crc_at]).to_le_bytes();
        bytes[crc_at..crc_at + 2].copy_from_slice(&crc);
    }
    if let Ok(image) = MotorImage::decode(&bytes) {
        assert!(MotorParams::new(image.motor).is_ok());
        assert!(image.bus_v.is_finite() && image.bus_v > 0.0);
        let encoded = image.encode();
        assert_eq!(encoded[..4], bytes[..4]);
        assert_eq!(encoded[8..48], bytes[8..48]);
        match bytes[4..6] {
            [1, 0] => {
                assert_eq!((image.compensation, image.axis), (None, None));
                assert_eq!(encoded[4..8], [3, 0, 0, 0]);
            }
            [2, 0] => {
                assert_eq!(image.axis, None);
                assert_eq!(encoded[4..6], [3, 0]);
                assert_eq!(encoded[6..60], bytes[6..60]);
                assert!(encoded[60..80].iter().all(|&b| b == 0));
            }
            _ => assert_eq!(encoded[4..80], bytes[4..80]),
        }
        assert_eq!(MotorImage::decode(&encoded), Ok(image));
    }
});
