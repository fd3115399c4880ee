//! The virtual motor and the board path (issue 12, items 2 to 5).
//!
//! - The firmware's virtual motor (`dcfo::plant`, f32, averaged inverter) agrees
//!   with the host's f64 plant (switched ideal inverter, RK4) on the same duties.
//! - The drive on the virtual motor, captured as the drive image captures it, replays
//!   through `dcfo replay`'s code bit for bit (in process, no QEMU), in f32 (the M4F
//!   image's `Drive<f32>`) and in Q8.24 (the M3 image's `Drive<Q24>`), also after the
//!   trip through the trace file.
//! - `dcfo board --qemu --demo --json` on the virtual-motor image, on both QEMU boards
//!   (`--cpu m4f`, `--cpu m3`): Running at 0.3 m/s, at least 1000 samples captured, the
//!   replay identical, and `dcfo replay --numeric` of the recorded file gives the
//!   drive's estimates; and the image's command watchdog disables the drive when the
//!   host goes silent.
//!
//! The QEMU tests skip with a message when `qemu-system-arm` or the thumb target is
//! missing, unless `DCFO_REQUIRE_QEMU=1` (CI sets it), as `qemu_hil.rs` does.

use dcfo::algorithms::observer::ObserverKind;
use dcfo::algorithms::svpwm::svpwm;
use dcfo::algorithms::transforms::{Abc, AlphaBeta};
use dcfo::capture::{Capture, CaptureFormat, CaptureScalar, CaptureState, Quantity};
use dcfo::drive::{Drive, DriveConfig, DriveState, Measurements, PAPER_AXIS_BUS_V, PAPER_AXIS_PAYLOAD_KG};
use dcfo::motor::MotorParams;
use dcfo::num::Q24;
use dcfo::plant::{VirtualAxis, VirtualMotor};
use dcfo_host::commands::board::capture::{CaptureData, capture_trace, replay_matches, write_capture_trace};
use dcfo_host::commands::board::link::{Board, BoardLink, DriveClock};
use dcfo_host::commands::replay::working_base;
use dcfo_host::plant::{Plant, SimParams};
use dcfo_host::qemu::{GuestClock, QemuCpu, QemuSession, build_qemu_example};
use dcfo_host::trace::InputTrace;
use std::process::Command;
use std::time::Duration;

mod common;

/// The same duties into the virtual motor and into the host's plant (ideal inverter and
/// sensors, the same motor and mass): a voltage vector turning at 4 Hz that drags the
/// mover along. Currents and speed must agree at every sample within 2 % of their peaks
/// (the host plant switches the bridge and carries the current ripple; the virtual
/// motor averages it).
#[test]
fn virtual_motor_agrees_with_the_host_plant() {
    let motor = MotorParams::paper();
    let mut params = SimParams::ideal_from_motor(&motor);
    params.plant.mass_kg += f64::from(PAPER_AXIS_PAYLOAD_KG);
    let bus = params.inverter.dc_bus_v;
    let ts = params.inverter.pwm_period_s;
    let mut plant = Plant::new(&params).expect("plant");
    let axis = VirtualAxis {
        payload_kg: PAPER_AXIS_PAYLOAD_KG,
        load_n: 0.0,
        bus_v: bus as f32,
        period_s: ts as f32,
    };
    let mut vm = VirtualMotor::new(&motor, &axis).expect("virtual motor");
    let (mut i_peak, mut v_peak, mut i_err, mut v_err) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for k in 0..5000 {
        let t = k as f64 * ts;
        let angle = 2.0 * std::f64::consts::PI * 4.0 * t * (t / 0.5).min(1.0);
        let u = AlphaBeta::new((30.0 * angle.cos()) as f32, (30.0 * angle.sin()) as f32);
        let m = svpwm(u, bus as f32).expect("modulates");
        let d = [m.duties.a, m.duties.b, m.duties.c];
        plant.step(d.map(f64::from), 0.0);
        vm.step(d, true);
        let host = plant.state();
        let virt = vm.state();
        let i_host = [host.i_alpha_a, host.i_beta_a];
        let i_virt = [f64::from(virt.i_ab_a.alpha), f64::from(virt.i_ab_a.beta)];
        for (a, b) in i_host.iter().zip(i_virt) {
            i_peak = i_peak.max(a.abs());
            i_err = i_err.max((a - b).abs());
        }
        v_peak = v_peak.max(host.v_m_per_s.abs());
        v_err = v_err.max((host.v_m_per_s - f64::from(virt.v_m_per_s)).abs());
    }
    println!("peaks: {i_peak:.3} A, {v_peak:.4} m/s; largest differences {i_err:.4} A, {v_err:.5} m/s");
    assert!(v_peak > 0.05 && i_peak > 1.0, "the mover was dragged along");
    assert!(i_err < 0.02 * i_peak, "current: {i_err} A of {i_peak} A");
    assert!(v_err < 0.02 * v_peak, "speed: {v_err} m/s of {v_peak} m/s");
}

/// The drive of the QEMU image (`examples/qemu_drive.rs`: paper motor, paper axis's
/// carriage, no inverter compensation) in the number type `T` and its working units, on
/// the virtual motor with the board's one-period delay, captured from the estimator's
/// start as the image captures it: it reaches `Running` at 0.3 m/s, and its capture
/// (24,000 samples, as the image's).
fn captured_drive<T: CaptureScalar>() -> CaptureData {
    let motor = MotorParams::paper();
    let mut config = DriveConfig::for_motor(&motor, PAPER_AXIS_BUS_V, ObserverKind::Dcfo);
    config.moving_mass_kg = motor.mass_kg + PAPER_AXIS_PAYLOAD_KG;
    config.dead_time_compensation = None;
    let base = working_base(T::FORMAT, &motor);
    let mut drive = Drive::<T>::new(&motor, &config, &base).expect("drive");
    let axis = VirtualAxis {
        payload_kg: PAPER_AXIS_PAYLOAD_KG,
        load_n: 0.0,
        bus_v: PAPER_AXIS_BUS_V,
        period_s: config.control_period_s,
    };
    let mut vm = VirtualMotor::new(&motor, &axis).expect("virtual motor");
    let mut capture = Box::new(Capture::<24_000>::new());
    capture.arm();
    drive.enable();
    drive.set_speed_reference(drive.omega_from_speed(0.3));
    let mut pending = ([0.5f32; 3], false);
    let mut running = false;
    // The current calibration on enable (about 0.1 s), then the 2.4 s capture.
    for _ in 0..26_000 {
        vm.step(pending.0, pending.1);
        let i = vm.phase_currents_a();
        let measured = Measurements {
            i_abc: Abc { a: base.current(i[0]), b: base.current(i[1]), c: base.current(i[2]) },
            vdc: base.voltage(vm.bus_v()),
        };
        let out = drive.step(&measured);
        capture.record(&out);
        pending = ([out.duties.a, out.duties.b, out.duties.c].map(|d| d.to_f32()), out.bridge_enabled);
        running |= out.state == DriveState::Running;
    }
    assert!(running && drive.state() == DriveState::Running, "faults {:?}", drive.faults());
    let v = vm.state().v_m_per_s;
    assert!((v - 0.3).abs() < 0.02, "mover at {v} m/s");
    assert_eq!((capture.state(), capture.len(), capture.format()), (CaptureState::Done, 24_000, T::FORMAT));
    CaptureData::from_capture(&capture)
}

/// The f32 drive's capture, as a trace, replays to the drive's own estimates bit for bit;
/// and the check can fail.
#[test]
fn captured_drive_on_the_virtual_motor_replays_bit_for_bit() {
    let motor = MotorParams::paper();
    let data = captured_drive::<f32>();
    let ts = 1e-4;
    let trace = capture_trace(&data, &motor, ts).expect("trace");
    let cmp = replay_matches(&trace, &motor, &data).expect("replay");
    assert_eq!((cmp.differing, cmp.first_differing), (0, None));
    // And the check can fail: one current 1 mA off changes the estimates from there on.
    let mut altered = data.clone();
    altered.samples[100].i_alpha = (f32::from_bits(altered.samples[100].i_alpha) + 1e-3).to_bits();
    let trace = capture_trace(&altered, &motor, ts).expect("trace");
    let cmp = replay_matches(&trace, &motor, &data).expect("replay");
    assert!(cmp.differing > 0);
    assert!(cmp.first_differing.expect("one differs") >= 100, "{cmp:?}");
}

/// The Q8.24 drive (the M3 image's `Drive<Q24>` in the motor's per-unit base), run in
/// this process: its capture, written to a trace file and read back, replays through
/// `Estimator<Q24>` to the drive's own estimates bit for bit. The file holds SI `f64`
/// that convert back to the captured Q8.24 words exactly, and names the number type in
/// its comments. Replayed in f32 instead, it does not match (the check is real), and
/// one current 4096 LSB (1 mA) off shows at that sample or after (a single LSB can
/// vanish in the observer's truncating products).
#[test]
fn q24_drive_capture_replays_bit_for_bit_through_the_trace_file() {
    let motor = MotorParams::paper();
    let data = captured_drive::<Q24>();
    assert_eq!(data.format, CaptureFormat::Q24);
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("q24.csv");
    write_capture_trace(&path, &data, &motor, 1e-4).expect("written");
    let text = std::fs::read_to_string(&path).expect("read");
    assert!(text.starts_with("# dcfo capture: 24000 samples"), "{}", &text[..200]);
    assert!(text.lines().any(|l| l.starts_with("# numeric: q24")), "{}", &text[..400]);
    let trace = InputTrace::read_path(&path).expect("the file is a trace");
    // Every input word survives the file.
    let base = working_base(CaptureFormat::Q24, &motor);
    let accel = trace.commanded_acceleration().expect("alpha_e_ref column");
    for (k, (row, s)) in trace.rows().iter().zip(&data.samples).enumerate() {
        let back = |si: f64, q: Quantity| CaptureFormat::Q24.from_si(si, q, &base);
        assert_eq!(back(row.u_alpha, Quantity::Voltage), Some(s.u_alpha), "row {k}");
        assert_eq!(back(row.u_beta, Quantity::Voltage), Some(s.u_beta), "row {k}");
        assert_eq!(back(row.i_alpha, Quantity::Current), Some(s.i_alpha), "row {k}");
        assert_eq!(back(row.i_beta, Quantity::Current), Some(s.i_beta), "row {k}");
        assert_eq!(back(accel[k], Quantity::Acceleration), Some(s.alpha_e_ref), "row {k}");
    }
    let cmp = replay_matches(&trace, &motor, &data).expect("replay");
    assert_eq!((cmp.differing, cmp.first_differing), (0, None));
    // The same file through the f32 estimator: not the drive's estimates.
    let f32_replay =
        dcfo_host::commands::replay::replay_trace(&trace, &motor, ObserverKind::Dcfo).expect("replay");
    let same = f32_replay
        .iter()
        .zip(&data.samples)
        .filter(|(r, s)| r.theta_hat.to_bits() == s.theta_hat.to_radians::<f64>().to_bits())
        .count();
    assert!(same < data.samples.len() / 2, "{same} angles agree");
    // One current 4096 LSB (4096 * 2^-24 per unit of 4.2 A: 1.0 mA) off.
    let mut altered = data.clone();
    altered.samples[5000].i_beta = altered.samples[5000].i_beta.wrapping_add(4096);
    let trace = capture_trace(&altered, &motor, 1e-4).expect("trace");
    let cmp = replay_matches(&trace, &motor, &data).expect("replay");
    assert!(cmp.differing > 0);
    assert!(cmp.first_differing.expect("one differs") >= 5000, "{cmp:?}");
}

/// The drive image for `cpu`, or `None` (after saying why) when the test must skip.
fn drive_image(cpu: QemuCpu) -> Option<std::path::PathBuf> {
    common::qemu_runs(cpu)
        .then(|| build_qemu_example(&common::workspace(), cpu, "qemu_drive").expect("the drive image builds"))
}

/// `dcfo board --qemu --cpu <cpu> --demo --json`: the whole path from the command line,
/// then `dcfo replay --numeric <the image's number type>` of the recorded file.
fn board_demo_runs_captures_and_replays_identically(cpu: QemuCpu, cpu_arg: &str, numeric: &str) {
    let Some(elf) = drive_image(cpu) else { return };
    let dir = tempfile::tempdir().expect("temp dir");
    let trace = dir.path().join("capture.csv");
    let out = Command::new(env!("CARGO_BIN_EXE_dcfo"))
        .args(["board", "--qemu", "--cpu", cpu_arg, "--demo", "--json", "--elf"])
        .arg(&elf)
        .arg("--record")
        .arg(&trace)
        .output()
        .expect("dcfo board runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{}\n{stdout}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "exit status {}", out.status);
    let last = stdout.lines().last().expect("a JSON line");
    let report: serde_json::Value = serde_json::from_str(last).expect("the last line is JSON");
    assert_eq!(report["state_reached"], "Running");
    assert_eq!(report["faults"], "none");
    assert_eq!(report["numeric"], numeric);
    assert!(report["capture_samples"].as_u64().expect("count") >= 1000);
    assert_eq!(report["replay_identical"], true);
    assert_eq!(report["replay_differing"], 0);
    assert_eq!(report["replay_first_differing"], serde_json::Value::Null);
    let speed = report["speed_m_per_s"].as_f64().expect("speed");
    assert!((speed - 0.3).abs() < 0.03, "speed estimate {speed} m/s");
    let text = std::fs::read_to_string(&trace).expect("recorded");
    assert!(text.lines().any(|l| l.starts_with(&format!("# numeric: {numeric}"))), "{}", &text[..300]);
    // The recorded file is a trace `dcfo replay` takes.
    let replayed = dir.path().join("replayed.csv");
    let status = Command::new(env!("CARGO_BIN_EXE_dcfo"))
        .args(["replay", "--motor", "paper", "--observer", "dcfo", "--numeric", numeric])
        .arg(&trace)
        .arg("-o")
        .arg(&replayed)
        .status()
        .expect("dcfo replay runs");
    assert!(status.success());
    let rows = std::fs::read_to_string(&replayed).expect("replayed").lines().count();
    assert_eq!(rows as u64, report["capture_samples"].as_u64().expect("count") + 1);
}

/// The M4F image (mps2-an386): `Drive<f32>` in SI.
#[test]
fn board_demo_on_qemu_m4f_runs_captures_and_replays_identically() {
    board_demo_runs_captures_and_replays_identically(QemuCpu::M4f, "m4f", "f32");
}

/// The M3 image (mps2-an385): `Drive<Q24>` in the motor's per-unit base, replayed
/// through `Estimator<Q24>`.
#[test]
fn board_demo_on_qemu_m3_runs_captures_and_replays_identically() {
    board_demo_runs_captures_and_replays_identically(QemuCpu::M3, "m3", "q24");
}

/// The image's command watchdog: a running drive whose host goes silent is disabled
/// (bridge off) once the silence has lasted 5,000 of the drive's periods and 500 ms of
/// the host's time, and not before; commands again enable it. The drive's periods run as
/// fast as QEMU executes them, so the test paces its silence by them: it doubles the
/// silence until the drive has run past the limit in it, checking at each step that the
/// drive kept running while it had not.
#[test]
fn a_silent_host_disables_the_drive_image() {
    let cpu = QemuCpu::M4f;
    let Some(elf) = drive_image(cpu) else { return };
    let (_session, stdin, stdout) =
        QemuSession::spawn(&elf, cpu, GuestClock::Instructions).expect("qemu starts");
    let mut board = Board::new(BoardLink::new(stdin, stdout));
    board.wish.enable = true;
    board.wish.speed_m_per_s = 0.3;
    let mut t = board.poll(false, false).expect("telemetry");
    // The current calibration takes 0.1 s of the drive's time; 2 s is the limit.
    let mut clock = DriveClock::start(&t);
    while !t.bridge_enabled && clock.elapsed_s(&t).expect("the drive runs") < 2.0 {
        std::thread::sleep(Duration::from_millis(50));
        t = board.poll(false, false).expect("telemetry");
    }
    assert!(t.bridge_enabled, "the drive switched its bridge on: {t:?}");
    // The watchdog looks once a period, right after any command: a margin of 100 periods
    // around the limit either way.
    const LIMIT: u32 = 5000;
    const MARGIN: u32 = 100;
    let mut silence = Duration::from_millis(1000);
    loop {
        let before = t.periods;
        std::thread::sleep(silence);
        // The command that ends the silence wishes it enabled: its answer shows what the
        // watchdog did before it (the image answers right after applying the command; at
        // most one control period can run in between, which takes a disabled drive to
        // `Calibrating`, bridge still off).
        t = board.poll(false, false).expect("telemetry");
        let ran = t.periods.wrapping_sub(before);
        println!(
            "after {silence:?} of silence ({ran} periods): {:?}, bridge {}",
            t.state(),
            t.bridge_enabled
        );
        if ran > LIMIT + MARGIN {
            assert!(matches!(t.state(), DriveState::Disabled | DriveState::Calibrating), "{:?}", t.state());
            assert!(!t.bridge_enabled);
            break;
        }
        if ran + MARGIN < LIMIT {
            assert!(t.bridge_enabled, "disabled after {ran} periods of silence: {t:?}");
        }
        assert!(silence < Duration::from_secs(64), "the drive ran {ran} periods in {silence:?}");
        silence *= 2;
    }
    let t = board.disable().expect("disabled");
    assert_eq!(t.state(), DriveState::Disabled);
}

/// `dcfo board --qemu --demo --move-to 0.03 --json` on the M4F image's positioning
/// drive (without `--image`: the paper motor's image with the stroke axis, command line
/// `image <hex>`): the move goes over the board link, the position
/// report comes back with the reference at rest at the target and x̂ within a twentieth
/// of the pole pitch of it (0.75 mm on the paper motor, 9 electrical degrees), and a
/// move outside the stroke sent afterwards is reported refused. The true mover
/// position on the virtual motor is checked against the same tolerance by the
/// firmware's `board_link` unit test (the link carries only the drive's estimate).
#[test]
fn board_move_on_qemu_reaches_its_target_and_a_refused_move_is_reported() {
    let Some(elf) = drive_image(QemuCpu::M4f) else { return };
    let target = 0.03;
    let out = Command::new(env!("CARGO_BIN_EXE_dcfo"))
        .args(["board", "--qemu", "--demo", "--json", "--move-to", "0.03", "--dwell", "0.05", "--elf"])
        .arg(&elf)
        .output()
        .expect("dcfo board runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{}\n{stdout}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "exit status {}", out.status);
    let last = stdout.lines().last().expect("a JSON line");
    let report: serde_json::Value = serde_json::from_str(last).expect("the last line is JSON");
    let tolerance = f64::from(MotorParams::paper().pole_pitch_m) / 20.0;
    assert_eq!(report["faults"], "none");
    assert_eq!(report["move_reached"], true);
    assert!((report["tolerance_m"].as_f64().expect("tolerance") - tolerance).abs() < 1e-9);
    let x_err = report["x_err_m"].as_f64().expect("x_err_m");
    assert!(x_err.abs() < tolerance, "x_err {x_err} m");
    let x_ref = report["x_ref_m"].as_f64().expect("x_ref_m");
    assert!((x_ref - target).abs() < 1e-6, "reference {x_ref} m");
    assert_eq!(report["refused_move_reported"], true);
    assert_eq!(report["moves_rejected"], 1);
}

/// Bad move values are refused before anything starts, with an error naming them.
#[test]
fn a_bad_move_is_refused_with_a_named_error() {
    for (args, why) in [
        (["--move-to", "0.01", "--dwell", "-1"], "dwell must be a finite number of s, at least 0"),
        (["--move-to", "inf", "--dwell", "0"], "target must be a finite number of m"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_dcfo"))
            .args(["board", "--qemu", "--demo"])
            .args(args)
            .output()
            .expect("dcfo board runs");
        assert!(!out.status.success());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(why), "{stderr}");
    }
}

/// A motor image written by `dcfo motor-image` with an axis (version 3): the QEMU drive
/// image reads it from its command line and builds its drive with
/// `image_drive::drive_config`, the function the ESC1 images build theirs with from
/// flash. `dcfo board --qemu --image FILE --demo --move-to X` reaches the target within
/// the tolerance (a twentieth of the pole pitch) on the image's own axis (its payload,
/// not the default carriage), and the move outside the stroke is reported refused.
fn a_v3_image_with_an_axis_takes_moves(cpu: QemuCpu, cpu_arg: &str) {
    let Some(elf) = drive_image(cpu) else { return };
    let dir = tempfile::tempdir().expect("temp dir");
    let image = dir.path().join("axis.bin");
    let out = Command::new(env!("CARGO_BIN_EXE_dcfo"))
        .args(["motor-image", "--motor", "paper", "--bus-v", "311.127", "--stroke-min-m", "-0.02"])
        .args(["--stroke-max-m", "0.1", "--max-speed", "0.4", "--max-accel", "2", "--payload-kg", "5", "-o"])
        .arg(&image)
        .output()
        .expect("dcfo motor-image runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let decoded =
        dcfo::motor_image::MotorImage::decode(&std::fs::read(&image).expect("written")).expect("valid");
    assert_eq!(decoded.axis.map(|a| a.payload_kg), Some(5.0));
    let target = -0.015;
    let out = Command::new(env!("CARGO_BIN_EXE_dcfo"))
        .args(["board", "--qemu", "--cpu", cpu_arg, "--demo", "--json", "--move-to", "-0.015", "--image"])
        .arg(&image)
        .arg("--elf")
        .arg(&elf)
        .output()
        .expect("dcfo board runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stderr}\n{stdout}");
    assert!(out.status.success(), "exit status {}", out.status);
    assert!(stderr.contains("payload (positioning drive)"), "{stderr}");
    let last = stdout.lines().last().expect("a JSON line");
    let report: serde_json::Value = serde_json::from_str(last).expect("the last line is JSON");
    let tolerance = f64::from(MotorParams::paper().pole_pitch_m) / 20.0;
    assert_eq!(report["faults"], "none");
    assert_eq!(report["move_reached"], true);
    let x_err = report["x_err_m"].as_f64().expect("x_err_m");
    assert!(x_err.abs() < tolerance, "x_err {x_err} m");
    let x_ref = report["x_ref_m"].as_f64().expect("x_ref_m");
    assert!((x_ref - target).abs() < 1e-6, "reference {x_ref} m");
    assert_eq!(report["refused_move_reported"], true);
    assert_eq!(report["moves_rejected"], 1);
}

#[test]
fn a_v3_image_with_an_axis_takes_moves_on_qemu_m4f() {
    a_v3_image_with_an_axis_takes_moves(QemuCpu::M4f, "m4f");
}

#[test]
fn a_v3_image_with_an_axis_takes_moves_on_qemu_m3() {
    a_v3_image_with_an_axis_takes_moves(QemuCpu::M3, "m3");
}

/// CRC-16/IBM-3740 (poly 0x1021, init 0xFFFF), written here from its definition to
/// write a version-2 record by hand.
fn crc16(bytes: &[u8]) -> u16 {
    let mut crc = 0xFFFFu16;
    for &b in bytes {
        crc ^= u16::from(b) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 { (crc << 1) ^ 0x1021 } else { crc << 1 };
        }
    }
    crc
}

/// A version-2 motor image (64 bytes, as `dcfo motor-image` wrote before the axis) still
/// runs, as a speed drive: a move is refused, and `dcfo board --demo --move-to` says why
/// (no axis in the image) and how to write one.
#[test]
fn a_v2_image_runs_a_speed_drive_that_refuses_the_move_with_a_clear_message() {
    use dcfo::motor_image::MotorImage;
    let Some(elf) = drive_image(QemuCpu::M4f) else { return };
    let image = MotorImage::new(MotorParams::paper(), 311.127).expect("paper motor");
    let v3 = image.encode();
    let mut v2 = [0u8; 64];
    v2[..60].copy_from_slice(&v3[..60]);
    v2[4..6].copy_from_slice(&2u16.to_le_bytes());
    let crc = crc16(&v2[..60]);
    v2[60..62].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(MotorImage::decode(&v2), Ok(image));
    let dir = tempfile::tempdir().expect("temp dir");
    let file = dir.path().join("v2.bin");
    std::fs::write(&file, v2).expect("written");
    let out = Command::new(env!("CARGO_BIN_EXE_dcfo"))
        .args(["board", "--qemu", "--demo", "--json", "--move-to", "0.03", "--image"])
        .arg(&file)
        .arg("--elf")
        .arg(&elf)
        .output()
        .expect("dcfo board runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stderr}");
    assert!(!out.status.success());
    for words in ["no axis (speed drive)", "runs a speed drive, which refuses every move", "--stroke-min-m"] {
        assert!(stderr.contains(words), "`{words}` not in: {stderr}");
    }
}
