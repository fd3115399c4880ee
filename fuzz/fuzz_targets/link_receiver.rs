//! The link's receive path fed arbitrary bytes: both frame receivers, the board link's
//! command receiver and answer decoders (`dcfo board`), and the controller's
//! `LinkServer` with a drive behind it. Contract: no panic; every frame a
//! receiver accepts encodes back to a frame that decodes to itself; every answer the
//! server sends is a valid actuation frame (duties in [0, 1]).
//!
//! Random bytes almost never carry a valid CRC-16, so with the first byte odd the rest is
//! taken as a sequence of 32-byte sensor-frame payloads, each framed on the wire with
//! its correct CRC and COBS: the fuzzer then explores the payload checks (version,
//! flags, values), the sequence logic and the drive's step behind the server.
#![no_main]

use dcfo::drive::{Drive, DriveConfig};
use dcfo::link::board::{BoardCommand, BoardTelemetry, CaptureChunk};
use dcfo::link::{self, ActuationFrame, LinkServer, Receiver, SensorFrame};
use dcfo::motor::MotorParams;
use dcfo::algorithms::observer::ObserverKind;
use dcfo::num::units::Base;
use libfuzzer_sys::fuzz_target;

fn round_trips<F: link::Frame + PartialEq + core::fmt::Debug>(frame: &F) {
    let mut wire = [0u8; 256];
    let n = link::encode(frame, &mut wire).expect("an accepted frame encodes");
    let decoded = link::decode_in_place::<F>(&mut wire[..n - 1]).expect("and decodes");
    assert_eq!(&decoded, frame);
}

/// `data` as the byte stream, or (first byte odd) as payloads framed correctly.
fn stream(data: &[u8]) -> Vec<u8> {
    const CRC16: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_IBM_3740);
    match data.split_first() {
        Some((first, rest)) if first & 1 == 1 => {
            let mut out = Vec::new();
            for payload in rest.chunks(SensorFrame::PAYLOAD_LEN) {
                let mut raw = payload.to_vec();
                raw.extend_from_slice(&CRC16.checksum(payload).to_le_bytes());
                let mut wire = [0u8; 64];
                let n = link::cobs::encode(&raw, &mut wire).expect("fits");
                out.extend_from_slice(&wire[..n]);
                out.push(0);
            }
            out
        }
        _ => data.to_vec(),
    }
}

fuzz_target!(|data: &[u8]| {
    let data = &stream(data)[..];
    let mut sensor_rx = Receiver::<SensorFrame>::new();
    let mut actuation_rx = Receiver::<ActuationFrame>::new();
    let mut command_rx = Receiver::<BoardCommand>::new();
    // The host's answer decoding (`dcfo_host::commands::board::link::decode_answer`): by length.
    for encoded in data.split(|&b| b == 0) {
        let mut encoded = encoded.to_vec();
        if let Some(n) = link::cobs::decode_in_place(&mut encoded) {
            let raw = &encoded[..n];
            if let Ok(f) = link::decode_raw::<BoardTelemetry>(raw) {
                round_trips(&f);
            }
            if let Ok(f) = link::decode_raw::<CaptureChunk>(raw) {
                round_trips(&f);
            }
        }
    }
    for &b in data {
        if let Some(Ok(f)) = command_rx.push(b) {
            round_trips(&f);
        }
        if let Some(Ok(f)) = sensor_rx.push(b) {
            round_trips(&f);
        }
        if let Some(Ok(f)) = actuation_rx.push(b) {
            round_trips(&f);
        }
    }
    let mut drive =
        Drive::<f32>::new(&MotorParams::paper(), &DriveConfig::paper_axis(ObserverKind::Dcfo), &Base::SI)
            .expect("paper drive");
    let mut server = LinkServer::new();
    let mut out = [0u8; LinkServer::REPLY_LEN];
    for (i, &b) in data.iter().enumerate() {
        // A commissioning request may replace the drive and its base.
        let base = *drive.base();
        if let Some(n) = server.on_byte(b, &mut drive, &base, &mut out) {
            assert!(out[n - 1] == 0);
            if n == link::CommissioningReport::WIRE_LEN {
                link::decode_in_place::<link::CommissioningReport>(&mut out[..n - 1]).expect("a valid report");
                continue;
            }
            assert!(n == ActuationFrame::WIRE_LEN);
            let reply = link::decode_in_place::<ActuationFrame>(&mut out[..n - 1]).expect("a valid answer");
            for d in [reply.duty_a, reply.duty_b, reply.duty_c] {
                assert!((0.0..=1.0).contains(&d), "duty {d}");
            }
        }
        if i % 29 == 28 {
            server.silent_period(&mut drive);
        }
    }
});
