//! `dcfo identify`: the drive's commissioning on the simulated plant, against the plant's
//! truth (the floors), the refusals of motors that are not motors, the CLI, and
//! the firmware's commissioning through the HIL link on QEMU (`identify --qemu`): equal
//! to the in-process run of the same numeric type bit for bit, within the floors.
//!
//! The QEMU tests skip with a message when `qemu-system-arm` or a thumb target is
//! missing, unless `DCFO_REQUIRE_QEMU=1` (CI sets it), which turns a skip into a failure.

use dcfo::drive::CommissioningError;
use dcfo::motor::MotorParams;
use dcfo_host::commands::identify::{IdentifyError, IdentifyReport, PlantFault, identify, motor_toml};
use dcfo_host::motor_file::{load_motor, parse_motor_toml};

mod common;

fn motor(arg: &str) -> MotorParams {
    let path =
        if arg == "paper" { arg.to_string() } else { format!("{}/../{arg}", env!("CARGO_MANIFEST_DIR")) };
    load_motor(&path).unwrap().params
}

fn check_floors(r: &IdentifyReport) {
    println!("{}", dcfo_host::commands::identify::table(r));
    assert!(r.rs_ohm.err_pct.abs() <= 3.0, "Rs {:?}", r.rs_ohm);
    assert!(r.ld_h.err_pct.abs() <= 5.0, "Ld {:?}", r.ld_h);
    assert!(r.lq_h.err_pct.abs() <= 5.0, "Lq {:?}", r.lq_h);
    assert!(r.psi_f_wb.err_pct.abs() <= 3.0, "psi_f {:?}", r.psi_f_wb);
    assert!(r.voltage_error_v.err_pct.abs() <= 10.0, "voltage error {:?}", r.voltage_error_v);
    assert_eq!(r.direction, 1);
}

#[test]
fn paper_motor_within_the_floors() {
    check_floors(&identify("paper", &motor("paper"), 1, PlantFault::None).unwrap());
}

#[test]
fn salient_motor_within_the_floors() {
    let r = identify("salient", &motor("motors/salient.toml"), 2, PlantFault::None).unwrap();
    check_floors(&r);
    // The saliency itself is seen: Lq / Ld = 1.5 within the floors.
    assert!((r.lq_h.identified / r.ld_h.identified - 1.5).abs() < 0.1);
}

#[test]
fn low_resistance_motor_within_the_floors() {
    let r = identify("low_r", &motor("motors/low_r.toml"), 3, PlantFault::None).unwrap();
    check_floors(&r);
    // The device slope is in the terminal resistance: against the winding alone the
    // error is the slope's share (0.12 of 0.3 ohm), reported, not hidden.
    assert!(r.rs_winding_ohm.err_pct > 30.0, "{:?}", r.rs_winding_ohm);
}

fn refused(fault: PlantFault) -> CommissioningError {
    match identify("paper", &motor("paper"), 1, fault) {
        Err(IdentifyError::Commissioning(e)) => e,
        other => panic!("{fault:?}: expected a commissioning error, got {other:?}"),
    }
}

#[test]
fn open_phase_is_named() {
    // a: no current at all; b or c: the current is confined to one axis, off alpha.
    for k in 0..3 {
        assert_eq!(refused(PlantFault::OpenPhase(k)), CommissioningError::OpenPhase, "phase {k}");
    }
}

#[test]
fn shorted_terminals_are_named() {
    assert_eq!(refused(PlantFault::ShortedTerminals), CommissioningError::ShortedPhase);
}

#[test]
fn a_motor_without_back_emf_is_named() {
    assert_eq!(refused(PlantFault::NoMagnet), CommissioningError::NoBackEmf);
}

#[test]
fn a_bus_out_of_range_is_named() {
    assert_eq!(refused(PlantFault::LowBus), CommissioningError::BusOutOfRange);
}

#[test]
fn the_identified_motor_file_reads_back_as_identified() {
    let m = motor("motors/salient.toml");
    let r = identify("salient", &m, 1, PlantFault::None).unwrap();
    let text = motor_toml(&r, &m).unwrap();
    let back = parse_motor_toml(&text, "identified.toml").unwrap();
    let p = back.params;
    assert_eq!(p.rs_ohm as f64, r.rs_ohm.identified);
    assert_eq!(p.ld_h as f64, r.ld_h.identified);
    assert_eq!(p.lq_h as f64, r.lq_h.identified);
    assert_eq!(p.psi_f_wb as f64, r.psi_f_wb.identified);
    assert_eq!(
        (p.pole_pitch_m, p.rated_current_a, p.rated_voltage_v),
        (m.pole_pitch_m, m.rated_current_a, m.rated_voltage_v)
    );
}

#[test]
fn cli_writes_the_motor_file_and_one_json_object_last() {
    let dir = std::env::temp_dir().join(format!("dcfo-identify-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out_file = dir.join("paper-identified.toml");
    let image_file = dir.join("paper-identified.bin");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_dcfo"))
        .args(["identify", "--sim", "--motor", "paper", "--json", "-o"])
        .arg(&out_file)
        .arg("--image")
        .arg(&image_file)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8(out.stdout).unwrap();
    let last = stdout.lines().last().unwrap();
    let v: serde_json::Value = serde_json::from_str(last).unwrap();
    for key in ["rs_ohm", "ld_h", "lq_h", "psi_f_wb"] {
        for field in ["identified", "true", "err_pct"] {
            assert!(v[key][field].is_number(), "{key}.{field} in {last}");
        }
    }
    let back = parse_motor_toml(&std::fs::read_to_string(&out_file).unwrap(), "f").unwrap();
    assert_eq!(f64::from(back.params.psi_f_wb), v["psi_f_wb"]["identified"].as_f64().unwrap());
    let image = dcfo::motor_image::MotorImage::decode(&std::fs::read(&image_file).unwrap()).unwrap();
    assert_eq!(image.motor.psi_f_wb, back.params.psi_f_wb);
    assert!(image.compensation.is_some());
    // Where to run it must be said; --steady runs in process only.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_dcfo")).args(["identify"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--sim, --qemu or --port"));
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_dcfo"))
        .args(["identify", "--qemu", "--steady", "1"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("in process only"));
    std::fs::remove_dir_all(&dir).ok();
}

/// The firmware's commissioning on QEMU through the HIL link, against the in-process run
/// of the same numeric type (bit for bit) and the plant's truth (the floors).
fn commissioning_through_qemu(cpu: dcfo_host::qemu::QemuCpu) {
    use dcfo_host::commands::identify::{InProcess, identical, identify_over_link, identify_with};
    use dcfo_host::qemu::QemuCpu;
    let Some(elf) = common::hil_firmware(cpu) else { return };
    let m = motor("paper");
    let target = dcfo_host::target::Target::Qemu { cpu, elf: Some(elf) };
    let run = identify_over_link("paper", &m, 1, &target).expect("commissioning over the link");
    let over_link = run.report;
    let stack = run.stack_high_water_bytes.expect("stack high-water mark");
    println!(
        "QEMU {cpu:?}: commissioning took {:.1} s of wall time; deepest stack {stack} bytes",
        run.wall_s
    );
    // The start request builds the told drive in the receive interrupt
    // (docs/reliability.md, "Stack"): measured 11,704 B (M3) and 11,804 B (M4F), against 992 and 2,496 B for
    // the steady scenario (host/tests/qemu_hil.rs, budget 4,096 B). A budget that
    // catches growth beyond that.
    assert!(
        stack <= COMMISSIONING_STACK_BUDGET_BYTES,
        "{stack} bytes of stack, budget {COMMISSIONING_STACK_BUDGET_BYTES}"
    );
    let local = match cpu {
        QemuCpu::M4f => identify_with("paper", &m, 1, PlantFault::None, &mut InProcess::f32()),
        QemuCpu::M3 => identify_with("paper", &m, 1, PlantFault::None, &mut InProcess::q24()),
    }
    .expect("in-process commissioning");
    let (a, b) = (over_link.result.expect("a result"), local.result.expect("a result"));
    assert!(identical(&a, &b), "firmware {a:?}\nin process {b:?}");
    check_floors(&over_link);
}

/// The deepest stack the HIL image may use with a commissioning (bytes): see
/// `commissioning_through_qemu`.
const COMMISSIONING_STACK_BUDGET_BYTES: u32 = 12_288;

#[test]
fn m4f_f32_commissioning_through_qemu_equals_the_host_bit_for_bit() {
    commissioning_through_qemu(dcfo_host::qemu::QemuCpu::M4f);
}

#[test]
fn m3_fixed_point_commissioning_through_qemu_equals_the_host_bit_for_bit() {
    commissioning_through_qemu(dcfo_host::qemu::QemuCpu::M3);
}

#[test]
fn the_motor_image_carries_the_identified_motor_and_compensation() {
    use dcfo::motor_image::MotorImage;
    let m = motor("paper");
    let r = identify("paper", &m, 1, PlantFault::None).unwrap();
    let bytes = dcfo_host::commands::identify::motor_image(&r, &m, None).unwrap();
    let image = MotorImage::decode(&bytes).unwrap();
    let result = r.result.unwrap();
    assert_eq!(
        (image.motor.rs_ohm, image.motor.ld_h, image.motor.lq_h, image.motor.psi_f_wb),
        (result.rs_ohm, result.ld_h, result.lq_h, result.psi_f_wb)
    );
    assert_eq!(image.bus_v, dcfo_host::commands::identify::told(&m).bus_v);
    let c = image.compensation.expect("the identified compensation");
    assert_eq!(c, result.dead_time_compensation(1e-4));
    // As a voltage at the commissioning's bus and 100 us period it is the identified
    // error, which is within 10 % of the plant's (checked by the floors above).
    let volts = f64::from(c.dead_time_s) / 1e-4 * f64::from(result.bus_v);
    assert!((volts - r.voltage_error_v.identified).abs() < 1e-5 * volts, "{volts}");
    assert!(r.voltage_error_v.err_pct.abs() <= 10.0);
    assert_eq!(image.axis, None);
    // An axis (`dcfo identify --image` keeps the one of the image it overwrites) is
    // carried into the identified image, checked against the identified motor.
    let axis = dcfo::motor_image::MotorAxis { limits: dcfo::drive::STROKE_AXIS_LIMITS, payload_kg: 10.0 };
    let dir = tempfile::tempdir().unwrap();
    let old = dir.path().join("old.bin");
    std::fs::write(&old, image.with_axis(axis).unwrap().encode()).unwrap();
    assert_eq!(dcfo_host::commands::motor_image::existing_axis(&old), Some(axis));
    assert_eq!(dcfo_host::commands::motor_image::existing_axis(&dir.path().join("absent.bin")), None);
    let kept =
        MotorImage::decode(&dcfo_host::commands::identify::motor_image(&r, &m, Some(axis)).unwrap()).unwrap();
    assert_eq!(kept, MotorImage { axis: Some(axis), ..image });
    let too_fast = dcfo::motor_image::MotorAxis {
        limits: dcfo::algorithms::motion::ProfileLimits { max_speed_m_per_s: 100.0, ..axis.limits },
        ..axis
    };
    let e = dcfo_host::commands::identify::motor_image(&r, &m, Some(too_fast)).unwrap_err().to_string();
    assert!(e.contains("axis") && e.contains("max_speed_m_per_s"), "{e}");
}

#[test]
fn a_failed_commissioning_writes_no_files() {
    let dir = std::env::temp_dir().join(format!("dcfo-identify-fail-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // A winding of 100 ohm on a motor rated 1 A at 48 V: half the rated peak current
    // needs more voltage than the bus gives, so the alignment stops (open phase).
    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        "name = \"bad\"\nrs_ohm = 100.0\nld_h = 0.01\nlq_h = 0.01\npsi_f_wb = 0.1\npole_pitch_m = 0.02\n\
         rated_current_a = 1.0\nrated_voltage_v = 48.0\n",
    )
    .unwrap();
    let (toml, image) = (dir.join("m.toml"), dir.join("m.bin"));
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_dcfo"))
        .args(["identify", "--sim", "--motor"])
        .arg(&bad)
        .arg("-o")
        .arg(&toml)
        .arg("--image")
        .arg(&image)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("commissioning stopped"), "{stderr}");
    assert!(!toml.exists() && !image.exists());
    std::fs::remove_dir_all(&dir).ok();
}
