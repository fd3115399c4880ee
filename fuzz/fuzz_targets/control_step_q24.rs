//! The control step in Q8.24 (the Cortex-M3 drive, per-unit) fed arbitrary
//! measurements. A record's command bits 6..7 choose how its words are read: 0 or 1 raw
//! Q8.24 bit patterns (the extremes included), 2 `f32` bit patterns converted as the
//! firmware converts link values (`Base::current`/`voltage`, `Q24::from_f32`:
//! saturating, NaN to 0), 3 physical values. See `control_step.rs`.
#![no_main]

mod control_step;

use control_step::{Abc, physical};
use dcfo::drive::Measurements;
use dcfo::motor::MotorParams;
use dcfo::num::Q24;
use dcfo::num::units::Base;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let base = Base::for_motor(&MotorParams::paper());
    control_step::run::<Q24>(data, &base, |words, cmd| {
        let si = |v: [f32; 4]| Measurements {
            i_abc: Abc { a: base.current(v[0]), b: base.current(v[1]), c: base.current(v[2]) },
            vdc: base.voltage(v[3]),
        };
        match cmd >> 6 {
            3 => si(physical(words)),
            2 => si(words.map(f32::from_bits)),
            _ => {
                let q = words.map(|w| Q24::from_bits(w as i32));
                Measurements { i_abc: Abc { a: q[0], b: q[1], c: q[2] }, vdc: q[3] }
            }
        }
    });
});
