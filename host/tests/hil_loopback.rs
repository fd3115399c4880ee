//! The HIL path without a target: a fake firmware thread serves the link with the
//! library's `LinkServer` and a `Drive<f32>` — exactly what the QEMU firmware runs —
//! over a socket pair. The closed loop through the link must reproduce the in-process
//! run's angle estimates bit for bit, and survive a noisy line.

use dcfo::algorithms::observer::ObserverKind;
use dcfo::drive::Drive;
use dcfo::link::LinkServer;
use dcfo::num::units::Base;
use dcfo_host::commands::hil::compare_runs;
use dcfo_host::hil_link::SerialController;
use dcfo_host::simulation::{Setup, run, run_with, scenarios};
use std::io::{Read, Write};
use std::os::unix::net::UnixStream;

/// Serves frames until the host closes the socket; `noise` bytes are written before
/// every answer (garbage the host's receiver must skip). With `booting`, the first
/// `booting` bytes received are lost, as a target that is still starting loses them.
fn fake_firmware(mut stream: UnixStream, setup: Setup, noise: &'static [u8], mut booting: usize) {
    let mut drive: Drive<f32> = Drive::new(&setup.motor, &setup.drive, &Base::SI).expect("drive");
    let mut server = LinkServer::new();
    let mut out = [0u8; LinkServer::REPLY_LEN];
    let mut buf = [0u8; 256];
    loop {
        let n = match stream.read(&mut buf) {
            Ok(0) | Err(_) => return,
            Ok(n) => n,
        };
        for &byte in &buf[..n] {
            if booting > 0 {
                booting -= 1;
                continue;
            }
            let Some(len) = server.on_byte(byte, &mut drive, &Base::SI, &mut out) else { continue };
            if stream.write_all(noise).and_then(|_| stream.write_all(&out[..len])).is_err() {
                return;
            }
        }
    }
}

fn hil_run(
    noise: &'static [u8],
    booting: usize,
    duration_s: f64,
) -> (dcfo_host::simulation::Run, dcfo_host::simulation::Run) {
    let setup = Setup::paper(ObserverKind::Dcfo);
    let mut sc = scenarios::scenario("steady").expect("scenario");
    sc.duration_s = duration_s;
    let (host_end, firmware_end) = UnixStream::pair().expect("socket pair");
    let fw_setup = setup.clone();
    let firmware = std::thread::spawn(move || fake_firmware(firmware_end, fw_setup, noise, booting));
    let reader = host_end.try_clone().expect("clone");
    let closer = host_end.try_clone().expect("clone");
    let mut link = SerialController::new(host_end, reader);
    let over_link = run_with(&setup, &sc, &mut link, |_| {});
    // Close both directions: the reader thread holds a handle too, so dropping the
    // controller alone would leave the fake firmware waiting for bytes.
    closer.shutdown(std::net::Shutdown::Both).expect("shutdown");
    firmware.join().expect("firmware thread");
    let over_link = over_link.expect("HIL run");
    println!("{} round trips, {:.0}/s", link.round_trips, link.round_trips_per_s());
    let local = run(&setup, &sc, |_| {}).expect("in-process run");
    (over_link, local)
}

#[test]
fn closed_loop_through_the_link_equals_the_in_process_drive_bit_for_bit() {
    // Through the hand-over (about 1.6 s) into sensorless running.
    let (a, b) = hil_run(b"", 0, 2.0);
    assert!(a.handover_s.is_some(), "the drive reaches sensorless operation over the link");
    let e = compare_runs(&a, &b);
    println!("{e:?}");
    assert!(e.samples > 18_000);
    assert_eq!(e.differing, 0);
}

#[test]
fn garbage_on_the_line_is_skipped_without_changing_the_result() {
    // A zero (frame delimiter) followed by junk before every answer.
    let (a, b) = hil_run(&[0x00, 0x13, 0x37, 0xFF, 0x00], 0, 0.3);
    let e = compare_runs(&a, &b);
    assert!(e.samples > 1_500, "{e:?}"); // 0.3 s less 0.1 s of current-offset calibration
    assert_eq!(e.differing, 0);
}

#[test]
fn a_target_that_loses_the_first_bytes_gets_the_first_frame_again() {
    // The first 7 bytes (half a frame) are lost: the first frame arrives garbled, the
    // host sends it again after 0.5 s, and the run is the same as in-process.
    let (a, b) = hil_run(b"", 7, 0.2);
    let e = compare_runs(&a, &b);
    assert!(e.samples > 900, "{e:?}"); // 0.2 s less 0.1 s of calibration
    assert_eq!(e.differing, 0);
}
