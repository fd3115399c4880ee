//! The motor-image decoder (the flash record the ESC1 boots from) fed arbitrary bytes.
//! Contract: no panic; an accepted image holds a motor that validates and re-encodes to
//! the same first `LEN` bytes.
#![no_main]

use dcfo::motor::MotorParams;
use dcfo::motor_image::MotorImage;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(image) = MotorImage::decode(data) {
        assert!(MotorParams::new(image.motor).is_ok());
        assert!(image.bus_v.is_finite() && image.bus_v > 0.0);
        let bytes = image.encode();
        assert_eq!(&bytes[..], &data[..MotorImage::LEN]);
        assert_eq!(MotorImage::decode(&bytes), Ok(image));
    }
});
