//! The control step in `f32` (the Cortex-M4F drive, SI units) fed arbitrary
//! measurements: see `control_step.rs`.
#![no_main]

mod control_step;

use dcfo::units::Base;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    control_step::run::<f32>(data, &Base::SI, |bits, _| f32::from_bits(bits));
});
