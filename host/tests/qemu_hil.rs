//! Hardware-in-the-loop on QEMU: the firmware (`qemu_m4f`, Cortex-M4F on `mps2-an386`)
//! runs the drive, the host runs the plant, lock-step over the emulated UART0. The paper's
//! steady scenario must reach its position-error figure, and every angle estimate must
//! equal the in-process run's bit for bit (the firmware's f32 arithmetic is IEEE, as the
//! host's).
//!
//! Skips with a message when `qemu-system-arm` or the thumbv7em target is missing, unless
//! `DCFO_REQUIRE_QEMU=1` (CI sets it), which turns a skip into a failure.
//! `DCFO_FIRMWARE_ELF` names a prebuilt image instead of building one.

use dcfo::observer::ObserverKind;
use dcfo_host::hil::{QemuSession, build_qemu_firmware, compare_runs};
use dcfo_host::sim::{Setup, run, run_with, scenarios};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Returns why QEMU HIL cannot run here, if it cannot.
fn missing_tools() -> Option<String> {
    if Command::new("qemu-system-arm").arg("--version").output().is_err() {
        return Some("qemu-system-arm is not installed (apt-get install qemu-system-arm)".into());
    }
    let rustc = std::env::var_os("RUSTC").unwrap_or_else(|| "rustc".into());
    let libdir =
        Command::new(rustc).args(["--print", "target-libdir", "--target", "thumbv7em-none-eabihf"]).output();
    let installed = libdir.is_ok_and(|o| {
        o.status.success()
            && std::fs::read_dir(String::from_utf8_lossy(&o.stdout).trim())
                .is_ok_and(|d| d.flatten().any(|e| e.file_name().to_string_lossy().starts_with("libcore-")))
    });
    (!installed).then(|| "the thumbv7em-none-eabihf target is not installed".into())
}

fn firmware() -> PathBuf {
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("workspace root").to_path_buf();
    match std::env::var_os("DCFO_FIRMWARE_ELF") {
        Some(p) => workspace.join(p),
        None => build_qemu_firmware(&workspace).expect("firmware builds"),
    }
}

#[test]
fn steady_scenario_through_qemu_meets_its_figure_and_equals_the_host_bit_for_bit() {
    if let Some(why) = missing_tools() {
        assert!(std::env::var("DCFO_REQUIRE_QEMU").as_deref() != Ok("1"), "QEMU HIL required: {why}");
        println!("skipped: {why}");
        return;
    }
    let elf = firmware();
    let setup = Setup::paper(ObserverKind::Dcfo);
    let sc = scenarios::scenario("steady").expect("scenario");
    let (session, mut link) = QemuSession::start(&elf).expect("qemu starts");
    let over_uart = run_with(&setup, &sc, &mut link, |_| {}).expect("HIL run");
    let rate = link.round_trips_per_s();
    drop(link);
    drop(session);
    let f = scenarios::figures(&over_uart, &sc);
    println!(
        "QEMU HIL, {:.1} s simulated at {rate:.0} round trips/s: theta_err max {:.2} deg, rms {:.2} deg",
        over_uart.simulated_s, f.theta_err_max_deg, f.theta_err_rms_deg
    );
    assert!(f.healthy, "sensorless operation without a fault");
    // The figure for the steady scenario (as in host/tests/paper.rs).
    assert!(f.theta_err_max_deg <= 5.0 && f.theta_err_rms_deg <= 2.5);
    let local = run(&setup, &sc, |_| {}).expect("in-process run");
    let e = compare_runs(&over_uart, &local);
    println!("equivalence: {e:?}");
    assert!(e.samples > 30_000);
    assert_eq!(e.differing, 0, "the target's angle estimates differ from the host's");
}
