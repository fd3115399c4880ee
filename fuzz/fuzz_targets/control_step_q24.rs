//! The control step in Q8.24 (the Cortex-M3 drive, per-unit) fed arbitrary
//! measurements: with bit 7 of a record's command byte the four words are `f32` bit
//! patterns converted as the firmware converts link values (`Q24::from_f32`: saturating,
//! NaN to 0), otherwise raw Q8.24 bit patterns (the extremes included). See
//! `control_step.rs`.
#![no_main]

mod control_step;

use dcfo::motor::MotorParams;
use dcfo::num::{Q24, Scalar};
use dcfo::units::Base;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let base = Base::for_motor(&MotorParams::paper());
    control_step::run::<Q24>(data, &base, |bits, cmd| {
        if cmd & 0x80 != 0 { Q24::from_f32(f32::from_bits(bits)) } else { Q24::from_bits(bits as i32) }
    });
});
