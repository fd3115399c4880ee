//! Commissioning inside the drive: aborts with a named error and the bridge off, in f32
//! and Q8.24, on synthetic measurements (the identification's accuracy is checked
//! against the simulated plant in `host/tests/identify.rs`).

use dcfo::algorithms::observer::ObserverKind;
use dcfo::algorithms::transforms::Abc;
use dcfo::drive::{
    CommissioningConfig, CommissioningError, Drive, DriveConfig, DriveState, Faults, Measurements,
};
use dcfo::num::units::Base;
use dcfo::num::{Q24, Scalar};

fn config() -> CommissioningConfig {
    CommissioningConfig { rated_current_a: 2.1, rated_voltage_v: 220.0, bus_v: 311.0, pole_pitch_m: 0.015 }
}

fn drive<T: Scalar>(base: &Base) -> Drive<T> {
    let c = config();
    let motor = c.placeholder_motor();
    Drive::new(&motor, &DriveConfig::for_motor(&motor, c.bus_v, ObserverKind::Dcfo), base).unwrap()
}

/// Steps `drive` with phase currents `current(step)` (A) on a 311 V bus until it leaves
/// `Commissioning` (or 5 s); returns the steps taken and whether the bridge was ever on
/// after it left.
fn run<T: Scalar>(drive: &mut Drive<T>, base: &Base, current: impl Fn(u32) -> f32) -> u32 {
    let mut entered = false;
    for k in 0..50_000u32 {
        let i = current(k);
        let m = Measurements {
            i_abc: Abc { a: base.current(i), b: base.current(-0.5 * i), c: base.current(-0.5 * i) },
            vdc: base.voltage(311.0),
        };
        let was_commissioning = drive.state() == DriveState::Commissioning;
        let out = drive.step(&m);
        entered |= out.state == DriveState::Commissioning;
        if entered && out.state != DriveState::Commissioning {
            // From the step that ended it on, the bridge stays off.
            for _ in 0..100 {
                let out = drive.step(&m);
                assert!(!out.bridge_enabled);
            }
            return k;
        }
        if was_commissioning {
            assert!(out.bridge_enabled, "step {k}: the bridge applies the test voltages");
        }
    }
    panic!("commissioning did not end");
}

fn no_current_is_an_open_phase<T: Scalar>(base: Base) {
    let mut d = drive::<T>(&base);
    d.start_commissioning(config()).unwrap();
    let steps = run(&mut d, &base, |_| 0.0);
    assert_eq!(d.commissioning_result(), Some(Err(CommissioningError::OpenPhase)));
    assert_eq!(d.state(), DriveState::Fault);
    assert!(d.faults().contains(Faults::COMMISSIONING));
    // The ramp (0.4 s) after the offset calibration (1024 periods).
    assert!((5000..5200).contains(&steps), "{steps}");
}

#[test]
fn no_current_is_an_open_phase_f32() {
    no_current_is_an_open_phase::<f32>(Base::SI);
}

#[test]
fn no_current_is_an_open_phase_q24() {
    no_current_is_an_open_phase::<Q24>(Base::for_motor(&config().placeholder_motor()));
}

#[test]
fn a_current_beyond_its_limit_is_a_runaway() {
    let base = Base::SI;
    let mut d = drive::<f32>(&base);
    d.start_commissioning(config()).unwrap();
    // 1.6 times the rated peak (2.97 A) after calibration: beyond commissioning's 1.5.
    run(&mut d, &base, |k| if k > 1100 { 4.75 } else { 0.0 });
    assert_eq!(d.commissioning_result(), Some(Err(CommissioningError::RunawayCurrent)));
    assert!(d.faults().contains(Faults::COMMISSIONING));
}

#[test]
fn commissioning_starts_only_from_disabled_and_checks_its_settings() {
    let base = Base::SI;
    let mut d = drive::<f32>(&base);
    let bad = CommissioningConfig { bus_v: f32::NAN, ..config() };
    assert_eq!(d.start_commissioning(bad), Err(CommissioningError::BadSetting("bus_v")));
    d.enable();
    let m = Measurements { i_abc: Abc::default(), vdc: 311.0 };
    d.step(&m);
    assert_eq!(d.state(), DriveState::Calibrating);
    assert!(matches!(d.start_commissioning(config()), Err(CommissioningError::BadSetting(_))));
}

#[test]
fn a_result_goes_into_the_motor_image_and_back() {
    use dcfo::drive::{CommissioningResult, SWEEP_LEVELS, VoltageErrorPoint};
    use dcfo::motor_image::{MotorImage, MotorImageError};
    let r = CommissioningResult {
        rs_ohm: 5.15,
        ld_h: 0.00854,
        lq_h: 0.00867,
        psi_f_wb: 0.1612,
        voltage_error_v: 7.25,
        current_band_a: 0.0097,
        bus_v: 314.7,
        curve: [VoltageErrorPoint::default(); SWEEP_LEVELS],
        direction: 1,
        duration_s: 3.8,
    };
    let image = r.motor_image(&config(), 0.66, 0.5, 1e-4).unwrap();
    let back = MotorImage::decode(&image.encode()).unwrap();
    assert_eq!(back, image);
    // The compensation: the error as a dead time at the commissioning's bus and period
    // (7.25 V of 314.7 V over 100 us: 2.30 us), the identified band, no separate drop.
    let c = back.compensation.expect("a compensation");
    assert_eq!(c.dead_time_s, 7.25 * 1e-4 / 314.7);
    assert!((c.dead_time_s - 2.3038e-6).abs() < 1e-9);
    assert_eq!((c.device_drop_v, c.current_band_a), (0.0, 0.0097));
    let m = back.motor;
    assert_eq!((m.rs_ohm, m.ld_h, m.lq_h, m.psi_f_wb), (5.15, 0.00854, 0.00867, 0.1612));
    assert_eq!((m.pole_pitch_m, m.rated_current_a, m.rated_voltage_v), (0.015, 2.1, 220.0));
    assert_eq!(back.bus_v, 311.0);
    // A result that is not physical never becomes an image.
    let bad = CommissioningResult { psi_f_wb: -0.1, ..r };
    assert!(matches!(bad.motor_image(&config(), 0.66, 0.5, 1e-4), Err(MotorImageError::Param(_))));
    let bad = CommissioningResult { current_band_a: f32::NAN, ..r };
    assert_eq!(bad.motor_image(&config(), 0.66, 0.5, 1e-4), Err(MotorImageError::Compensation));
}
