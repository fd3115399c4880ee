//! Shared by `control_step_f32` and `control_step_q24`: a drive of the paper axis fed
//! arbitrary measurements and commands, with the drive's output contract asserted after
//! every step.
//!
//! Input: records of 17 bytes, one control period each: four 32-bit words (phase
//! currents a, b, c and the bus voltage) and a command byte (bit 0 enable, bit 1 clear
//! faults, bit 2 disable, bits 3..5 a speed reference, bits 6..7 how the words are read).
//! The words are taken as any bit pattern of the numeric type (NaN, infinities,
//! subnormals, the extremes of the range), or (bits 6..7 = 3) as *physical* values:
//! currents within +-10 A and a bus within 50..150 % of nominal, so that the fuzzer also
//! gets past the bus limits and the calibration into the control loops (float
//! comparisons are not traced by the coverage instrumentation, so it would rarely find
//! the bus window by itself). Calibration is shortened to 4 periods and the start-up
//! dwell to 0, and the first byte, when odd, turns the catch on enable off (the drive
//! then starts by I/f at once instead of probing for 50 ms in `Reacquiring`), so that
//! short inputs reach `Calibrating`, `Starting`, `Reacquiring` and `Fault`. `Running`
//! needs an estimate that tracks (a coherent rotating flux), which random input does
//! not make: the closed loop's faults are `dcfo faults`'s.

use dcfo::drive::{Drive, DriveConfig, DriveState, Faults, Measurements};
use dcfo::motor::MotorParams;
use dcfo::num::Scalar;
use dcfo::algorithms::observer::ObserverKind;
use dcfo::num::units::Base;

pub use dcfo::algorithms::transforms::Abc;

/// The four words of a record as physical SI values: currents within +-10 A, the bus
/// within 50..150 % of the paper axis' nominal bus (V).
pub fn physical(words: [u32; 4]) -> [f32; 4] {
    let unit = |w: u32| w as i32 as f32 / 2_147_483_648.0;
    [
        10.0 * unit(words[0]),
        10.0 * unit(words[1]),
        10.0 * unit(words[2]),
        dcfo::drive::PAPER_AXIS_BUS_V * (1.0 + 0.5 * unit(words[3])),
    ]
}

/// Runs `data` through a drive computing in `T` in `base`; `measure(words, command)` turns
/// a record's four words into the measurements.
pub fn run<T: Scalar>(data: &[u8], base: &Base, measure: impl Fn([u32; 4], u8) -> Measurements<T>) {
    let mut config = DriveConfig::paper_axis(ObserverKind::Dcfo);
    config.faults.calibration_samples = 4;
    config.startup.dwell_s = 0.0;
    let Some((first, data)) = data.split_first() else { return };
    if first & 1 == 1 {
        config.startup.catch_probe_s = None;
    }
    let Ok(mut drive) = Drive::<T>::new(&MotorParams::paper(), &config, base) else {
        panic!("the paper drive builds");
    };
    drive.enable();
    for rec in data.chunks_exact(17) {
        let word =
            |i: usize| u32::from_le_bytes([rec[4 * i], rec[4 * i + 1], rec[4 * i + 2], rec[4 * i + 3]]);
        let cmd = rec[16];
        if cmd & 2 != 0 {
            drive.clear_faults();
        }
        if cmd & 1 != 0 {
            drive.enable();
        }
        if cmd & 4 != 0 {
            drive.disable();
        }
        drive.set_speed_reference(drive.omega_from_speed(f32::from((cmd >> 3) & 7) * 0.2 - 0.7));
        let m = measure([word(0), word(1), word(2), word(3)], cmd);
        let was_faulted = drive.state() == DriveState::Fault;
        let out = drive.step(&m);
        for d in [out.duties.a, out.duties.b, out.duties.c] {
            let d = d.to_f32();
            assert!(d.is_finite() && (0.0..=1.0).contains(&d), "duty {d}");
        }
        if !out.bridge_enabled {
            assert!([out.duties.a, out.duties.b, out.duties.c].iter().all(|d| d.to_f32() == 0.5));
        }
        let invalid =
            !(m.i_abc.a.is_valid() && m.i_abc.b.is_valid() && m.i_abc.c.is_valid() && m.vdc.is_valid());
        if invalid && !was_faulted {
            assert!(out.faults.contains(Faults::NON_FINITE), "{:?}", out.faults);
        }
        if out.state == DriveState::Fault || invalid {
            assert!(!out.bridge_enabled && !out.faults.is_empty(), "{:?} {:?}", out.state, out.faults);
        }
        if out.bridge_enabled {
            assert!(out.faults.is_empty());
            assert!(matches!(
                out.state,
                DriveState::Starting | DriveState::Running | DriveState::Reacquiring | DriveState::LowSpeed
            ));
        }
        if let Some(e) = out.estimate {
            assert!(e.omega_e.is_valid() && e.psi_ab.alpha.is_valid() && e.psi_ab.beta.is_valid());
        }
    }
}
