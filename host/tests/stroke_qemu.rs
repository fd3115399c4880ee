//! The stroke through the lock-step HIL link on QEMU (issue 9, item 5, "same code
//! everywhere"): the `qemu_hil` image, started with the stroke axis of the paper motor
//! (`dcfo stroke --qemu`), takes its moves over the link (`Drive::push_move`) and
//! reports x̂; the host runs the plant. A short stroke (two moves: out, one reversal
//! through zero speed, back) must run without a fault and refused move, and every
//! period's θ̂ and x̂ must equal the in-process run of the same numeric type bit for
//! bit: `Drive<f32>` for the Cortex-M4F image, `Drive<Q24>` for the Cortex-M3 one.
//! Each stroke is over 30,000 lock-step round trips (asserted), about a minute of QEMU.
//!
//! The paper motor runs on the Cortex-M4F, where float code generation could differ from
//! the host's. The Cortex-M3 runs the salient motor (`motors/salient.toml`, Lq/Ld = 1.5):
//! its low-speed mode and the hold at rest are high-frequency injection and the load
//! observer, handing over to the back-EMF estimator on the way, so this one stroke is the
//! Q8.24 positioning drive with HFI on the target, bit for bit with the host's
//! `Drive<Q24>`. Q8.24 is integer arithmetic, the same on every target, so the paper
//! motor's Q8.24 stroke on the M3 would add a minute of CI and no coverage; the paper
//! motor's Q8.24 drive on the M3 is `qemu_hil`'s.
//!
//! Skips with a message when `qemu-system-arm` or a thumb target is missing, unless
//! `DCFO_REQUIRE_QEMU=1` (CI sets it), which turns a skip into a failure.

use dcfo::motor::MotorParams;
use dcfo_host::commands::stroke::{bus_for, compare, qemu_cmdline, run_with, setup_for};
use dcfo_host::qemu::{QemuCpu, QemuSession};

mod common;

/// Moves of the short stroke: out and back, one reversal through zero speed.
const MOVES: usize = 2;

/// The motor `name` (a preset or a file under the workspace root).
fn motor(name: &str) -> MotorParams {
    let arg =
        if name == "paper" { name.to_string() } else { common::workspace().join(name).display().to_string() };
    dcfo_host::motor_file::load_motor(&arg).expect("motor file").params
}

fn short_stroke_equals_the_host_bit_for_bit(cpu: QemuCpu, motor_name: &str) {
    let Some(elf) = common::hil_firmware(cpu) else { return };
    let motor = motor(motor_name);
    let setup = setup_for(&motor);
    let cmdline = qemu_cmdline(&motor, bus_for(&motor)).expect("motor image");
    let started = std::time::Instant::now();
    let (session, mut link) = QemuSession::start_with_cmdline(&elf, cpu, &cmdline).expect("qemu starts");
    let hil = run_with(motor_name, &setup, &mut link, MOVES, 100, |_| {}).expect("stroke over the link");
    let rate = link.round_trips_per_s();
    drop(link);
    drop(session);
    let s = &hil.summary;
    println!(
        "QEMU {cpu:?}: {:.1} s wall at {rate:.0} round trips/s: {s:#?}",
        started.elapsed().as_secs_f64()
    );
    assert_eq!(s.faults, 0, "{}", s.fault_names);
    assert_eq!((s.moves_sent, s.moves_done, s.reversals), (MOVES, MOVES, 1));
    // The link does not carry the drive's internals.
    assert_eq!((s.angle_err_running_max_deg, s.current_ref_step_max_a), (None, None));
    // The position estimate tracked the mover (the stroke's floor, tau / 4).
    assert!(s.x_err_max_m <= f64::from(motor.pole_pitch_m) / 4.0, "{}", s.x_err_max_m);
    // The reference went out to the stroke's end and x̂ followed it.
    let far = hil.rows.iter().map(|r| r.x_hat_m).fold(f64::MIN, f64::max);
    assert!(far > 0.29, "x̂ reached {far} m");
    let mut local = cpu.local_drive(&setup).expect("in-process drive");
    let l = run_with(motor_name, &setup, local.as_mut(), MOVES, 100, |_| {}).expect("in-process stroke");
    let e = compare(&hil.estimates, &l.estimates);
    println!("equivalence {cpu:?}: {e:?}");
    assert!(e.periods > 30_000, "{} periods", e.periods);
    assert!(hil.estimates.iter().filter(|x| x.theta_hat.is_some()).count() > 10_000);
    assert_eq!(e.differing, 0, "the target's θ̂ or x̂ differ from the host's");
}

#[test]
fn m4f_f32_short_stroke_through_qemu() {
    short_stroke_equals_the_host_bit_for_bit(QemuCpu::M4f, "paper");
}

#[test]
fn m3_fixed_point_salient_stroke_with_hfi_through_qemu() {
    let salient = motor("motors/salient.toml");
    assert!(salient.lq_h / salient.ld_h >= 1.15, "the HFI case needs a salient motor");
    short_stroke_equals_the_host_bit_for_bit(QemuCpu::M3, "motors/salient.toml");
}
