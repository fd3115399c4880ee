//! Shared by `control_step_f32` and `control_step_q24`: a drive of the paper axis fed
//! arbitrary measurements and commands, with the drive's output contract asserted after
//! every step.
//!
//! Input: records of 17 bytes, one control period each: four 32-bit patterns (phase
//! currents a, b, c and the bus voltage: any bit pattern, so NaN, infinities,
//! subnormals and the extremes of the range) and a command byte (bit 0 enable, bit 1
//! clear faults, bit 2 disable, bits 3..7 a speed reference). Calibration is shortened
//! to 4 periods and the start-up dwell to 0 so that short inputs reach every state.

use dcfo::drive::{Drive, DriveConfig, DriveState, Faults, Measurements};
use dcfo::motor::MotorParams;
use dcfo::num::Scalar;
use dcfo::observer::ObserverKind;
use dcfo::transforms::Abc;
use dcfo::units::Base;

/// Runs `data` through a drive computing in `T` in `base`; `value(bits, command)` turns a
/// 32-bit pattern into a measurement.
pub fn run<T: Scalar>(data: &[u8], base: &Base, value: impl Fn(u32, u8) -> T) {
    let mut config = DriveConfig::paper_axis(ObserverKind::Dcfo);
    config.faults.calibration_samples = 4;
    config.startup.dwell_s = 0.0;
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
        drive.set_speed_reference(drive.omega_from_speed(f32::from(cmd >> 3) * 0.05 - 0.8));
        let m = Measurements {
            i_abc: Abc { a: value(word(0), cmd), b: value(word(1), cmd), c: value(word(2), cmd) },
            vdc: value(word(3), cmd),
        };
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
