//! The motor TOML reader fed arbitrary text. Contract: no panic; an accepted file holds
//! a motor that validates.
#![no_main]

use dcfo::motor::MotorParams;
use dcfo_host::motor_file::parse_motor_toml;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = core::str::from_utf8(data)
        && let Ok(m) = parse_motor_toml(text, "<fuzz>")
    {
        assert!(MotorParams::new(m.params).is_ok());
    }
});
