//! The control step in `f32` (the Cortex-M4F drive, SI units) fed arbitrary
//! measurements: see `control_step.rs`.
#![no_main]

mod control_step;

use control_step::{Abc, physical};
use dcfo::drive::Measurements;
use dcfo::num::units::Base;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    control_step::run::<f32>(data, &Base::SI, |words, cmd| {
        let v = if cmd >> 6 == 3 { physical(words) } else { words.map(f32::from_bits) };
        Measurements { i_abc: Abc { a: v[0], b: v[1], c: v[2] }, vdc: v[3] }
    });
});
