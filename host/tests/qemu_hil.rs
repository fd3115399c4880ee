//! Hardware-in-the-loop on QEMU: the firmware (`examples/qemu_hil`: Cortex-M4F on
//! `mps2-an386` with f32, Cortex-M3 on `mps2-an385` with Q8.24) runs the drive in its
//! UART interrupt, the host runs the plant, lock-step over the emulated UART0. The paper's
//! steady scenario must reach its position-error figure, and every angle estimate must
//! equal the in-process run of the same numeric type bit for bit, and the firmware's
//! deepest stack (painted at boot, read through QEMU's monitor) must stay within its
//! budget. A silent link must switch the bridge off; corrupted, replayed and duplicated
//! frames must not be acted on. A stack overflow must fault before
//! it reaches the statics (flip-link, `examples/stack_guard`).
//!
//! Skips with a message when `qemu-system-arm` or a thumb target is missing, unless
//! `DCFO_REQUIRE_QEMU=1` (CI sets it), which turns a skip into a failure.

use dcfo::algorithms::observer::ObserverKind;
use dcfo::drive::{DriveState, Faults};
use dcfo::link::SensorFrame;
use dcfo_host::commands::hil::compare_runs;
use dcfo_host::qemu::{QemuCpu, QemuSession};
use dcfo_host::simulation::{Controller, Setup, figures, run_with, scenarios};
use std::process::Command;
use std::time::{Duration, Instant};

mod common;

fn steady_scenario_meets_its_figure_and_equals_the_host_bit_for_bit(cpu: QemuCpu) {
    let Some(elf) = common::hil_firmware(cpu) else { return };
    let setup = Setup::paper(ObserverKind::Dcfo);
    let sc = scenarios::scenario("steady").expect("scenario");
    let (session, mut link) = QemuSession::start(&elf, cpu).expect("qemu starts");
    let over_uart = run_with(&setup, &sc, &mut link, |_| {}).expect("HIL run");
    let rate = link.round_trips_per_s();
    let stack = session.stack_high_water().expect("stack high-water mark");
    drop(link);
    drop(session);
    println!("QEMU HIL {cpu:?}: deepest stack since boot {stack} bytes");
    assert!(stack > 0, "the stack was painted and used");
    // The budget catches a stack that grows by half; the ESC1 images, which run the
    // same receive path with f32, have 30,144 bytes (flip-link: all RAM below their
    // statics, less the 256-byte guard).
    assert!(stack <= STACK_BUDGET_BYTES, "{stack} bytes of stack, budget {STACK_BUDGET_BYTES}");
    let f = figures::figures(&over_uart, &sc);
    println!(
        "QEMU HIL {cpu:?}, {:.1} s simulated at {rate:.0} round trips/s: theta_err max {:.2} deg, rms {:.2} deg",
        over_uart.simulated_s, f.theta_err_max_deg, f.theta_err_rms_deg
    );
    assert!(f.healthy, "sensorless operation without a fault");
    // The figure for the steady scenario (as in host/tests/paper.rs).
    assert!(f.theta_err_max_deg <= 5.0 && f.theta_err_rms_deg <= 2.5);
    let local =
        run_with(&setup, &sc, cpu.local_drive(&setup).expect("drive").as_mut(), |_| {}).expect("local run");
    let e = compare_runs(&over_uart, &local);
    println!("equivalence {cpu:?}: {e:?}");
    assert!(e.samples > 30_000);
    assert_eq!(e.differing, 0, "the target's angle estimates differ from the host's");
}

/// The deepest stack the HIL image may use (bytes): see the steady-scenario test.
const STACK_BUDGET_BYTES: u32 = 4096;

#[test]
fn m4f_f32_steady_scenario_through_qemu() {
    steady_scenario_meets_its_figure_and_equals_the_host_bit_for_bit(QemuCpu::M4f);
}

#[test]
fn m3_fixed_point_steady_scenario_through_qemu() {
    steady_scenario_meets_its_figure_and_equals_the_host_bit_for_bit(QemuCpu::M3);
}

/// The firmware's link watchdog, in the host's periods: a frame whose sequence number
/// skips 10 (the host sent nothing for 10 control periods of its simulation) trips an
/// active drive with `EXTERNAL` (bridge off) before it steps, and that frame's answer
/// reports it; a disabled drive is left alone; a gap of 9 (lost frames) does not trip it,
/// and neither does a host that pauses between two consecutive frames, however long: the
/// plant does not run while it pauses. No wall clock is involved on either side.
#[test]
fn a_silent_link_switches_the_bridge_off() {
    let cpu = QemuCpu::M4f;
    let Some(elf) = common::hil_firmware(cpu) else { return };
    let (_session, mut link) = QemuSession::start(&elf, cpu).expect("qemu starts");
    let mut frame = SensorFrame {
        sequence: 0,
        i_a: 0.0,
        i_b: 0.0,
        i_c: 0.0,
        vdc: dcfo::drive::PAPER_AXIS_BUS_V,
        speed_ref: 0.0,
        enable: false,
        clear_faults: false,
        move_to: None,
    };
    // Sends the frame `skip` numbers after the last one.
    let send = |link: &mut dyn Controller, frame: &mut SensorFrame, skip: u16| {
        frame.sequence = frame.sequence.wrapping_add(skip);
        let reply = link.step(frame).expect("answer").frame;
        frame.sequence = frame.sequence.wrapping_add(1);
        reply
    };
    let limit = dcfo::link::SILENT_LINK_PERIODS;
    // Disabled: a long gap changes nothing.
    assert_eq!(send(&mut link, &mut frame, 0).state(), DriveState::Disabled);
    let reply = send(&mut link, &mut frame, 3 * limit);
    assert_eq!((reply.state(), reply.faults()), (DriveState::Disabled, Faults::NONE));
    // Enabled: current-offset calibration (bridge off, but the drive is active). Lost
    // frames (a gap of 9) and a host that pauses between consecutive frames do not trip it.
    frame.enable = true;
    assert_eq!(send(&mut link, &mut frame, 0).state(), DriveState::Calibrating);
    let reply = send(&mut link, &mut frame, limit - 1);
    assert_eq!(reply.faults(), Faults::NONE);
    std::thread::sleep(Duration::from_millis(1000));
    let reply = send(&mut link, &mut frame, 0);
    assert_eq!(reply.faults(), Faults::NONE, "a paused host is not a silent link");
    // Ten periods without a frame: tripped before the step.
    let reply = send(&mut link, &mut frame, limit);
    println!("after a gap of {limit}: {:?}, faults {:?}", reply.state(), reply.faults());
    assert_eq!(reply.state(), DriveState::Fault);
    assert!(reply.faults().contains(Faults::EXTERNAL) && !reply.bridge_enabled);
    // Cleared, it runs again.
    frame.clear_faults = true;
    frame.enable = false;
    assert_eq!(send(&mut link, &mut frame, 0).state(), DriveState::Disabled);
    frame.clear_faults = false;
    frame.enable = true;
    for _ in 0..5 {
        let reply = send(&mut link, &mut frame, 0);
        assert_ne!(reply.state(), DriveState::Fault, "{:?}", reply.faults());
    }
}

/// Link faults on the firmware (issue 11's fault campaign, the cases that live on the
/// link): a corrupted frame is counted and not acted on, a replayed old frame is counted
/// and not answered, a duplicate of the last frame is answered with the same answer
/// without a second step. `dcfo faults` runs the same `LinkServer` in process.
#[test]
fn corrupted_replayed_and_duplicated_frames_are_counted_and_never_acted_on() {
    let cpu = QemuCpu::M4f;
    let Some(elf) = common::hil_firmware(cpu) else { return };
    let (_session, mut link) = QemuSession::start(&elf, cpu).expect("qemu starts");
    let mut frame = SensorFrame {
        sequence: 0,
        i_a: 0.0,
        i_b: 0.0,
        i_c: 0.0,
        vdc: dcfo::drive::PAPER_AXIS_BUS_V,
        speed_ref: 0.0,
        enable: false,
        clear_faults: false,
        move_to: None,
    };
    let wire = |f: &SensorFrame| {
        let mut buf = [0u8; SensorFrame::WIRE_LEN];
        let n = dcfo::link::encode(f, &mut buf).expect("encodes");
        buf[..n].to_vec()
    };
    let mut sent = Vec::new();
    let mut last = None;
    for _ in 0..5 {
        sent.push(wire(&frame));
        last = Some(link.step(&frame).expect("answer").frame);
        frame.sequence += 1;
    }
    let before = last.expect("answered").stats;
    // Answers to the start-up's resends of the first frame (every START_RESEND of wall
    // time until the booting target answers, a duplicate answered with the same bytes)
    // count as stale too; the faults below must add none.
    let stale_before = link.stale_frames;
    // A corrupted copy of the next frame (one bit of a current), then the frame itself:
    // the corrupted one is dropped as a bad CRC, the good one answered.
    let mut bad = wire(&frame);
    bad[6] ^= 0x10;
    link.send_raw(&[0]).expect("write");
    link.send_raw(&bad).expect("write");
    let good = link.step(&frame).expect("answer").frame;
    assert_eq!(good.sequence, frame.sequence);
    assert_eq!(
        good.stats.bad_crc + good.stats.malformed,
        before.bad_crc + before.malformed + 1,
        "{:?}",
        good.stats
    );
    // A duplicate of that frame: the same answer again (the drive steps once).
    let again = link.step(&frame).expect("answer").frame;
    assert_eq!(again, good);
    frame.sequence += 1;
    // An old frame replayed: counted out of order, not answered.
    link.send_raw(&sent[1]).expect("write");
    let next = link.step(&frame).expect("answer").frame;
    assert_eq!(next.sequence, frame.sequence);
    // The duplicate and the replay.
    assert_eq!(next.stats.out_of_order, before.out_of_order + 2, "{:?}", next.stats);
    assert_eq!(link.stale_frames - stale_before, 0, "the target answered a frame it should have dropped");
}

/// flip-link: unbounded recursion (`examples/stack_guard`) faults at the bottom of the
/// stack, and the HardFault handler (on a fresh stack) finds `.data` and `.bss` intact.
fn a_stack_overflow_faults_before_it_reaches_the_statics(cpu: QemuCpu) {
    if !common::qemu_runs(cpu) {
        return;
    }
    let workspace = common::workspace();
    let status = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .current_dir(&workspace)
        .args(["build", "--release", "-p", "dcfo-firmware", "--features", "mps2", "--example", "stack_guard"])
        .args(["--target", cpu.target()])
        .status()
        .expect("cargo runs");
    assert!(status.success(), "stack_guard builds");
    let elf = workspace.join("target").join(cpu.target()).join("release/examples/stack_guard");
    let (machine, core) = match cpu {
        QemuCpu::M4f => ("mps2-an386", "cortex-m4"),
        QemuCpu::M3 => ("mps2-an385", "cortex-m3"),
    };
    let mut child = Command::new("qemu-system-arm")
        .args(["-M", machine, "-cpu", core, "-display", "none", "-monitor", "none"])
        .args(["-semihosting-config", "enable=on,target=native", "-serial", "stdio", "-kernel"])
        .arg(&elf)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("qemu starts");
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("qemu runs") {
            break status;
        }
        // A hang guard, not a measure: the image runs well under a second.
        if start.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("stack_guard did not finish in 120 s: hung");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut out = String::new();
    std::io::Read::read_to_string(&mut child.stdout.take().expect("stdout"), &mut out).expect("output");
    println!("{cpu:?}: {}", out.trim());
    assert!(out.contains("mpu guard true"), "{out}");
    assert!(out.contains("STACK_GUARD fault after") && out.contains("statics intact"), "{out}");
    assert!(status.success(), "semihosting exit status {status}");
}

#[test]
fn a_stack_overflow_faults_before_it_reaches_the_statics_m4f() {
    a_stack_overflow_faults_before_it_reaches_the_statics(QemuCpu::M4f);
}

#[test]
fn a_stack_overflow_faults_before_it_reaches_the_statics_m3() {
    a_stack_overflow_faults_before_it_reaches_the_statics(QemuCpu::M3);
}
