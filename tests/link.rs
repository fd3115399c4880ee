//! The HIL serial link: byte-exact round trips, every error path with recovery,
//! sequence numbers across the wrap, the silent-link watchdog, and random streams.

use dcfo::algorithms::motion::Move;
use dcfo::algorithms::observer::ObserverKind;
use dcfo::drive::{Drive, DriveConfig, DriveState, Faults};
use dcfo::link::{
    ActuationFrame, EncodeError, EstimateReport, Frame, LinkError, LinkStats, LinkWatchdog, PROTOCOL_VERSION,
    PositionReport, RX_CAPACITY, Receiver, SILENT_LINK_PERIODS, SensorFrame, SequenceOrder, SequenceTracker,
    classify_sequence, decode_in_place, decode_raw, encode,
};
use dcfo::motor::MotorParams;
use dcfo::num::units::Base;
use proptest::prelude::*;

// ---------------------------------------------------------------- helpers

/// CRC-16/IBM-3740, bit by bit, independent of the `crc` crate.
fn crc16(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc ^= u16::from(b) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 { (crc << 1) ^ 0x1021 } else { crc << 1 };
        }
    }
    crc
}

fn wire<F: Frame>(frame: &F) -> Vec<u8> {
    let mut out = [0u8; 64];
    let n = encode(frame, &mut out).expect("encodes");
    assert_eq!(n, F::WIRE_LEN);
    out[..n].to_vec()
}

/// The raw frame (payload + CRC) inside one encoded frame.
fn raw_of(wire: &[u8]) -> Vec<u8> {
    let body = wire.strip_suffix(&[0]).expect("ends with the delimiter");
    let mut raw = vec![0u8; body.len()];
    let n = cobs::decode(body, &mut raw).expect("valid COBS").frame_size();
    raw.truncate(n);
    raw
}

/// COBS-frames `raw` as it is, CRC included.
fn frame_raw(raw: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; raw.len() + raw.len() / 254 + 2];
    let n = cobs::try_encode(raw, &mut out).expect("fits");
    out.truncate(n);
    out.push(0);
    out
}

/// Appends a correct CRC to `payload` and COBS-frames it.
fn frame_payload(payload: &[u8]) -> Vec<u8> {
    let mut raw = payload.to_vec();
    raw.extend_from_slice(&crc16(payload).to_le_bytes());
    frame_raw(&raw)
}

fn feed<F: Frame>(rx: &mut Receiver<F>, bytes: &[u8]) -> Vec<Result<F, LinkError>> {
    bytes.iter().filter_map(|&b| rx.push(b)).collect()
}

fn sensor() -> SensorFrame {
    SensorFrame {
        sequence: 0x1234,
        i_a: 1.5,
        i_b: -0.75,
        i_c: -0.75,
        vdc: 48.0,
        speed_ref: 0.3,
        enable: true,
        clear_faults: false,
        move_to: None,
    }
}

fn actuation() -> ActuationFrame {
    ActuationFrame {
        sequence: 0xBEEF,
        duty_a: 0.25,
        duty_b: 0.5,
        duty_c: 1.0,
        bridge_enabled: true,
        state_code: DriveState::Running.code(),
        fault_bits: (Faults::OVER_CURRENT | Faults::EXTERNAL).bits(),
        estimate: Some(EstimateReport { theta_hat: -1.0, speed: 0.29, psi_alpha: 0.1, psi_beta: -0.2 }),
        stats: LinkStats { malformed: 1, bad_crc: 2, out_of_order: 3 },
        position: Some(PositionReport {
            x_hat_m: 0.125,
            x_ref_m: 0.25,
            v_ref_m_per_s: -0.5,
            moves_queued: 7,
            idle: false,
            moves_rejected: 0x0102,
        }),
    }
}

/// Feeds `bad` then a good frame: nothing in `bad` may decode, the good frame must.
/// Returns the errors `bad` produced.
fn assert_recovers<F: Frame + PartialEq + core::fmt::Debug>(
    rx: &mut Receiver<F>,
    bad: &[u8],
    good: &F,
) -> Vec<LinkError> {
    let errors: Vec<LinkError> = feed(rx, bad)
        .into_iter()
        .map(|r| match r {
            Err(e) => e,
            Ok(f) => panic!("corrupted bytes decoded as {f:?}"),
        })
        .collect();
    // A corrupted tail without delimiter would swallow the good frame: terminate it.
    let mut next = Vec::new();
    if bad.last().is_some_and(|&b| b != 0) {
        next.push(0);
    }
    next.extend(wire(good));
    let results = feed(rx, &next);
    let (last, rest) = results.split_last().expect("the good frame gives a result");
    assert!(rest.iter().all(Result::is_err), "{rest:?}");
    assert_eq!(last.as_ref().ok(), Some(good));
    errors
}

fn finite_f32() -> impl Strategy<Value = f32> {
    use proptest::num::f32;
    f32::POSITIVE | f32::NEGATIVE | f32::NORMAL | f32::SUBNORMAL | f32::ZERO
}

fn duty() -> impl Strategy<Value = f32> {
    prop_oneof![Just(0.0f32), Just(-0.0f32), Just(1.0f32), 0.0f32..=1.0f32]
}

fn state() -> impl Strategy<Value = DriveState> {
    prop_oneof![
        Just(DriveState::Disabled),
        Just(DriveState::Calibrating),
        Just(DriveState::Starting),
        Just(DriveState::Running),
        Just(DriveState::Fault),
        Just(DriveState::Reacquiring),
        Just(DriveState::LowSpeed),
        Just(DriveState::Commissioning),
    ]
}

prop_compose! {
    fn arb_move()(target_m in finite_f32(), dwell_s in finite_f32()) -> Move {
        Move { target_m, dwell_s }
    }
}

prop_compose! {
    fn arb_sensor()(sequence in any::<u16>(), i_a in finite_f32(), i_b in finite_f32(), i_c in finite_f32(),
                    vdc in finite_f32(), speed_ref in finite_f32(), enable in any::<bool>(),
                    clear_faults in any::<bool>(),
                    move_to in proptest::option::of(arb_move())) -> SensorFrame {
        SensorFrame { sequence, i_a, i_b, i_c, vdc, speed_ref, enable, clear_faults, move_to }
    }
}

prop_compose! {
    fn arb_position()(x_hat_m in finite_f32(), x_ref_m in finite_f32(), v_ref_m_per_s in finite_f32(),
                      moves_queued in any::<u8>(), idle in any::<bool>(),
                      moves_rejected in any::<u16>()) -> PositionReport {
        PositionReport { x_hat_m, x_ref_m, v_ref_m_per_s, moves_queued, idle, moves_rejected }
    }
}

prop_compose! {
    fn arb_estimate()(theta_hat in finite_f32(), speed in finite_f32(), psi_alpha in finite_f32(),
                      psi_beta in finite_f32()) -> EstimateReport {
        EstimateReport { theta_hat, speed, psi_alpha, psi_beta }
    }
}

prop_compose! {
    fn arb_actuation()(sequence in any::<u16>(), duty_a in duty(), duty_b in duty(), duty_c in duty(),
                       bridge_enabled in any::<bool>(), state in state(), faults in any::<u16>(),
                       estimate in proptest::option::of(arb_estimate()),
                       stats in any::<(u16, u16, u16)>(),
                       position in proptest::option::of(arb_position())) -> ActuationFrame {
        ActuationFrame {
            sequence, duty_a, duty_b, duty_c, bridge_enabled, state_code: state.code(),
            fault_bits: faults, estimate,
            stats: LinkStats { malformed: stats.0, bad_crc: stats.1, out_of_order: stats.2 },
            position,
        }
    }
}

// ---------------------------------------------------------------- sizes and layout

#[test]
fn sizes_are_constant_and_as_documented() {
    assert_eq!((SensorFrame::PAYLOAD_LEN, SensorFrame::RAW_LEN, SensorFrame::WIRE_LEN), (32, 34, 36));
    assert_eq!(
        (ActuationFrame::PAYLOAD_LEN, ActuationFrame::RAW_LEN, ActuationFrame::WIRE_LEN),
        (56, 58, 60)
    );
    assert_eq!(RX_CAPACITY, ActuationFrame::WIRE_LEN - 1);
    // Worst case for COBS: no zero byte at all, and all zeros.
    let mut s = sensor();
    s.sequence = 0;
    s.i_a = 0.0;
    assert_eq!(wire(&s).len(), 36);
    s.move_to = Some(Move { target_m: 0.3, dwell_s: 0.2 });
    assert_eq!(wire(&s).len(), 36);
    let mut a = actuation();
    a.estimate = None;
    a.position = None;
    a.stats = LinkStats::default();
    a.fault_bits = Faults::NONE.bits();
    assert_eq!(wire(&a).len(), 60);
}

#[test]
fn crc_reference_check_value() {
    assert_eq!(crc16(b"123456789"), 0x29B1);
}

#[test]
fn sensor_frame_layout_is_byte_exact() {
    let f = SensorFrame { clear_faults: true, ..sensor() };
    let w = wire(&f);
    assert_eq!(w.iter().filter(|&&b| b == 0).count(), 1, "only the delimiter is zero");
    let raw = raw_of(&w);
    let mut expected = vec![PROTOCOL_VERSION];
    expected.extend_from_slice(&0x1234u16.to_le_bytes());
    for x in [1.5f32, -0.75, -0.75, 48.0, 0.3] {
        expected.extend_from_slice(&x.to_le_bytes());
    }
    expected.push(0b11);
    expected.extend_from_slice(&[0; 8]); // no move: zero bytes
    assert_eq!(expected.len(), 32);
    expected.extend_from_slice(&crc16(&expected.clone()).to_le_bytes());
    assert_eq!(raw, expected);

    // With a move: flag bit 2, target and dwell at offsets 24 and 28.
    let m = SensorFrame { move_to: Some(Move { target_m: 0.3, dwell_s: 0.2 }), ..f };
    let raw = raw_of(&wire(&m));
    assert_eq!(raw[23], 0b111);
    assert_eq!(raw[24..28], 0.3f32.to_le_bytes());
    assert_eq!(raw[28..32], 0.2f32.to_le_bytes());
}

#[test]
fn actuation_frame_layout_is_byte_exact() {
    let f = actuation();
    let raw = raw_of(&wire(&f));
    let mut expected = vec![PROTOCOL_VERSION];
    expected.extend_from_slice(&0xBEEFu16.to_le_bytes());
    for x in [0.25f32, 0.5, 1.0] {
        expected.extend_from_slice(&x.to_le_bytes());
    }
    expected.push(0b111); // bridge enabled, estimate valid, position valid (not idle)
    expected.push(3); // Running
    expected.extend_from_slice(&(1u16 | 1 << 8).to_le_bytes());
    for x in [-1.0f32, 0.29, 0.1, -0.2] {
        expected.extend_from_slice(&x.to_le_bytes());
    }
    for x in [1u16, 2, 3] {
        expected.extend_from_slice(&x.to_le_bytes());
    }
    for x in [0.125f32, 0.25, -0.5] {
        expected.extend_from_slice(&x.to_le_bytes());
    }
    expected.push(7);
    expected.extend_from_slice(&0x0102u16.to_le_bytes());
    assert_eq!(expected.len(), 56);
    expected.extend_from_slice(&crc16(&expected.clone()).to_le_bytes());
    assert_eq!(raw, expected);

    // Without an estimate and a position: flags clear, zero bytes.
    let raw = raw_of(&wire(&ActuationFrame { estimate: None, bridge_enabled: false, position: None, ..f }));
    assert_eq!(raw[15], 0);
    assert!(raw[19..35].iter().all(|&b| b == 0));
    assert!(raw[41..56].iter().all(|&b| b == 0));
    // Idle: flag bit 3.
    let idle = PositionReport { idle: true, ..f.position.unwrap() };
    let raw = raw_of(&wire(&ActuationFrame { position: Some(idle), ..f }));
    assert_eq!(raw[15], 0b1111);
}

#[test]
fn move_and_position_fields_without_their_flag_and_non_finite_values_are_rejected() {
    // A sensor frame: move bytes without the move flag; a non-finite target or dwell.
    let base = wire(&SensorFrame { move_to: Some(Move { target_m: 0.3, dwell_s: 0.0 }), ..sensor() });
    let mut payload = raw_of(&base);
    payload.truncate(SensorFrame::PAYLOAD_LEN);
    let mut rx = Receiver::<SensorFrame>::new();
    let mut no_flag = payload.clone();
    no_flag[23] &= !dcfo::link::SENSOR_FLAG_MOVE;
    assert_eq!(feed(&mut rx, &frame_payload(&no_flag)), [Err(LinkError::Value)]);
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        for offset in [24, 28] {
            let mut p = payload.clone();
            p[offset..offset + 4].copy_from_slice(&bad.to_le_bytes());
            assert_eq!(feed(&mut rx, &frame_payload(&p)), [Err(LinkError::Value)], "{bad} at {offset}");
        }
    }
    let mut unknown = payload.clone();
    unknown[23] |= 1 << 3;
    assert_eq!(feed(&mut rx, &frame_payload(&unknown)), [Err(LinkError::Flags)]);
    assert_eq!(feed(&mut rx, &frame_payload(&payload)).len(), 1);

    // An actuation frame: position bytes or the idle flag without the position flag; a
    // non-finite position field.
    let mut payload = raw_of(&wire(&actuation()));
    payload.truncate(ActuationFrame::PAYLOAD_LEN);
    let mut rx = Receiver::<ActuationFrame>::new();
    let mut no_flag = payload.clone();
    no_flag[15] &= !dcfo::link::ACTUATION_FLAG_POSITION_VALID;
    assert_eq!(feed(&mut rx, &frame_payload(&no_flag)), [Err(LinkError::Value)]);
    let mut p = raw_of(&wire(&ActuationFrame { position: None, ..actuation() }));
    p.truncate(ActuationFrame::PAYLOAD_LEN);
    p[15] |= dcfo::link::ACTUATION_FLAG_MOTION_IDLE;
    assert_eq!(feed(&mut rx, &frame_payload(&p)), [Err(LinkError::Value)]);
    for bad in [f32::NAN, f32::INFINITY] {
        for offset in [41, 45, 49] {
            let mut p = payload.clone();
            p[offset..offset + 4].copy_from_slice(&bad.to_le_bytes());
            assert_eq!(feed(&mut rx, &frame_payload(&p)), [Err(LinkError::Value)], "{bad} at {offset}");
        }
    }
    let mut unknown = payload.clone();
    unknown[15] |= 1 << 4;
    assert_eq!(feed(&mut rx, &frame_payload(&unknown)), [Err(LinkError::Flags)]);
    assert_eq!(feed(&mut rx, &frame_payload(&payload)), [Ok(actuation())]);

    // Encoding refuses what decoding would.
    let mut out = [0u8; 64];
    let nan_move = SensorFrame { move_to: Some(Move { target_m: 0.0, dwell_s: f32::NAN }), ..sensor() };
    assert_eq!(encode(&nan_move, &mut out), Err(EncodeError::InvalidValue));
    let nan_x = PositionReport { x_hat_m: f32::INFINITY, ..actuation().position.unwrap() };
    assert_eq!(
        encode(&ActuationFrame { position: Some(nan_x), ..actuation() }, &mut out),
        Err(EncodeError::InvalidValue)
    );
}

// ---------------------------------------------------------------- round trips

proptest! {
    #[test]
    fn sensor_frames_round_trip_byte_exact(f in arb_sensor()) {
        let w = wire(&f);
        let mut rx = Receiver::<SensorFrame>::new();
        let got = feed(&mut rx, &w);
        prop_assert_eq!(got.len(), 1);
        let back = got[0].expect("decodes");
        prop_assert_eq!(back, f);
        prop_assert_eq!(&wire(&back), &w);
        prop_assert_eq!(rx.stats(), LinkStats::default());
    }

    #[test]
    fn actuation_frames_round_trip_byte_exact(f in arb_actuation()) {
        let w = wire(&f);
        let mut rx = Receiver::<ActuationFrame>::new();
        let got = feed(&mut rx, &w);
        prop_assert_eq!(got.len(), 1);
        let back = got[0].expect("decodes");
        prop_assert_eq!(back, f);
        prop_assert_eq!(&wire(&back), &w);
        // The one-shot decoder agrees with the receiver.
        let mut body = w[..w.len() - 1].to_vec();
        prop_assert_eq!(decode_in_place::<ActuationFrame>(&mut body), Ok(f));
    }

    #[test]
    fn back_to_back_frames_all_decode(frames in proptest::collection::vec(arb_sensor(), 1..20)) {
        let bytes: Vec<u8> = frames.iter().flat_map(wire).collect();
        let mut rx = Receiver::<SensorFrame>::new();
        let got: Vec<SensorFrame> = feed(&mut rx, &bytes).into_iter().map(|r| r.expect("decodes")).collect();
        prop_assert_eq!(got, frames);
    }
}

// ---------------------------------------------------------------- encoding errors

#[test]
fn encode_refuses_a_short_buffer_and_bad_values() {
    let mut out = [0u8; 64];
    assert_eq!(encode(&sensor(), &mut out[..35]), Err(EncodeError::BufferTooSmall { needed: 36 }));
    assert_eq!(encode(&sensor(), &mut out[..36]), Ok(36));
    assert_eq!(encode(&actuation(), &mut out[..59]), Err(EncodeError::BufferTooSmall { needed: 60 }));
    assert_eq!(encode(&actuation(), &mut out[..]), Ok(60));
    assert_eq!(encode(&actuation(), &mut []), Err(EncodeError::BufferTooSmall { needed: 60 }));

    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        assert_eq!(encode(&SensorFrame { vdc: bad, ..sensor() }, &mut out), Err(EncodeError::InvalidValue));
        assert_eq!(
            encode(&SensorFrame { speed_ref: bad, ..sensor() }, &mut out),
            Err(EncodeError::InvalidValue)
        );
        let est = Some(EstimateReport { psi_beta: bad, ..EstimateReport::default() });
        assert_eq!(
            encode(&ActuationFrame { estimate: est, ..actuation() }, &mut out),
            Err(EncodeError::InvalidValue)
        );
    }
    for bad in [f32::NAN, -0.01, 1.01, f32::INFINITY] {
        assert_eq!(
            encode(&ActuationFrame { duty_b: bad, ..actuation() }, &mut out),
            Err(EncodeError::InvalidValue)
        );
    }
}

// ---------------------------------------------------------------- receive errors

#[test]
fn truncated_frames_are_rejected_and_the_next_decodes() {
    let good = sensor();
    let w = wire(&good);
    let body = &w[..w.len() - 1];
    let mut rx = Receiver::<SensorFrame>::new();
    for keep in 1..body.len() {
        let mut bad = body[..keep].to_vec();
        bad.push(0);
        let errors = assert_recovers(&mut rx, &bad, &good);
        assert_eq!(errors.len(), 1, "keep {keep}");
        assert!(matches!(errors[0], LinkError::Length | LinkError::Cobs), "keep {keep}: {errors:?}");
    }
    assert_eq!(rx.stats(), LinkStats { malformed: (body.len() - 1) as u16, bad_crc: 0, out_of_order: 0 });
    // The raw frame cut short and re-framed (valid COBS): a length error.
    let raw = raw_of(&w);
    assert_eq!(assert_recovers(&mut rx, &frame_raw(&raw[..raw.len() - 1]), &good), [LinkError::Length]);
}

#[test]
fn every_single_bit_flip_on_the_wire_is_rejected() {
    fn check<F: Frame + PartialEq + core::fmt::Debug + Copy>(good: F) {
        let w = wire(&good);
        let mut rx = Receiver::<F>::new();
        let mut dropped = 0;
        for bit in 0..(w.len() - 1) * 8 {
            let mut bad = w.clone();
            bad[bit / 8] ^= 1 << (bit % 8);
            dropped += assert_recovers(&mut rx, &bad, &good).len();
        }
        let s = rx.stats();
        assert_eq!(usize::from(s.malformed) + usize::from(s.bad_crc), dropped);
        assert!(s.bad_crc > 0);
    }
    check(sensor());
    check(actuation());
}

#[test]
fn every_flipped_bit_in_a_validly_framed_frame_is_a_crc_error() {
    fn check<F: Frame + PartialEq + core::fmt::Debug + Copy>(good: F) {
        let raw = raw_of(&wire(&good));
        let mut rx = Receiver::<F>::new();
        for bit in 0..raw.len() * 8 {
            let mut bad = raw.clone();
            bad[bit / 8] ^= 1 << (bit % 8);
            assert_eq!(assert_recovers(&mut rx, &frame_raw(&bad), &good), [LinkError::Crc], "bit {bit}");
        }
        assert_eq!(rx.stats().bad_crc as usize, raw.len() * 8);
        assert_eq!(rx.stats().malformed, 0);
    }
    check(sensor());
    check(actuation());
}

#[test]
fn every_two_and_three_bit_error_is_caught() {
    // The Hamming distance 4 claimed in the module docs, exhaustively on both frames.
    fn check<F: Frame>(good: &F) {
        let raw = raw_of(&wire(good));
        let bits = raw.len() * 8;
        let mut bad = raw.clone();
        let flip = |b: &mut Vec<u8>, i: usize| b[i / 8] ^= 1 << (i % 8);
        for i in 0..bits {
            flip(&mut bad, i);
            for j in i + 1..bits {
                flip(&mut bad, j);
                assert_eq!(decode_raw::<F>(&bad).err(), Some(LinkError::Crc));
                for k in j + 1..bits {
                    flip(&mut bad, k);
                    assert_eq!(decode_raw::<F>(&bad).err(), Some(LinkError::Crc));
                    flip(&mut bad, k);
                }
                flip(&mut bad, j);
            }
            flip(&mut bad, i);
        }
    }
    check(&sensor());
    check(&actuation());
}

#[test]
fn wrong_version_is_rejected() {
    let good = sensor();
    let mut rx = Receiver::<SensorFrame>::new();
    // 0, the version before this one (an older peer), the next one and 0xFF.
    for v in [0u8, PROTOCOL_VERSION - 1, PROTOCOL_VERSION + 1, 0xFF] {
        let mut payload = raw_of(&wire(&good))[..32].to_vec();
        payload[0] = v;
        assert_eq!(assert_recovers(&mut rx, &frame_payload(&payload), &good), [LinkError::Version]);
    }
    let good = actuation();
    let mut rx = Receiver::<ActuationFrame>::new();
    let mut payload = raw_of(&wire(&good))[..56].to_vec();
    payload[0] = PROTOCOL_VERSION - 1; // the version before the move and position fields
    assert_eq!(assert_recovers(&mut rx, &frame_payload(&payload), &good), [LinkError::Version]);
    assert_eq!(rx.stats().malformed, 1);
}

#[test]
fn unknown_flags_and_bad_values_are_malformed() {
    let good = sensor();
    let payload = raw_of(&wire(&good))[..32].to_vec();
    let mut rx = Receiver::<SensorFrame>::new();
    for flags in [0b1000u8, 0x80, 0xFF] {
        let mut p = payload.clone();
        p[23] = flags;
        assert_eq!(assert_recovers(&mut rx, &frame_payload(&p), &good), [LinkError::Flags]);
    }
    for (offset, bad) in
        [(3, f32::NAN), (7, f32::INFINITY), (11, f32::NEG_INFINITY), (15, f32::NAN), (19, f32::INFINITY)]
    {
        let mut p = payload.clone();
        p[offset..offset + 4].copy_from_slice(&bad.to_le_bytes());
        assert_eq!(
            assert_recovers(&mut rx, &frame_payload(&p), &good),
            [LinkError::Value],
            "offset {offset}"
        );
    }
    assert_eq!(rx.stats(), LinkStats { malformed: 8, bad_crc: 0, out_of_order: 0 });

    let good = actuation();
    let payload = raw_of(&wire(&good))[..56].to_vec();
    let mut rx = Receiver::<ActuationFrame>::new();
    let mut cases: Vec<(Vec<u8>, LinkError)> = Vec::new();
    let mut p = payload.clone();
    p[15] |= 0b1_0000;
    cases.push((p, LinkError::Flags));
    for bad in [f32::NAN, -0.5, 1.5] {
        let mut p = payload.clone();
        p[7..11].copy_from_slice(&bad.to_le_bytes());
        cases.push((p, LinkError::Value));
    }
    let mut p = payload.clone();
    p[16] = 8; // no such drive state
    cases.push((p, LinkError::Value));
    let mut p = payload.clone();
    p[27..31].copy_from_slice(&f32::NAN.to_le_bytes()); // psi_alpha with the estimate valid
    cases.push((p, LinkError::Value));
    let mut p = payload.clone();
    p[15] &= !0b10; // estimate flag cleared but estimate bytes present
    cases.push((p, LinkError::Value));
    for (p, e) in &cases {
        assert_eq!(assert_recovers(&mut rx, &frame_payload(p), &good), [*e]);
    }
    assert_eq!(rx.stats().malformed as usize, cases.len());
}

#[test]
fn wrong_length_with_a_good_crc_is_malformed() {
    // An actuation frame sent to a sensor receiver and the other way round.
    let mut rx = Receiver::<SensorFrame>::new();
    assert_eq!(assert_recovers(&mut rx, &wire(&actuation()), &sensor()), [LinkError::Length]);
    let mut rx = Receiver::<ActuationFrame>::new();
    assert_eq!(assert_recovers(&mut rx, &wire(&sensor()), &actuation()), [LinkError::Length]);
    // One extra byte with a CRC over it.
    let mut payload = raw_of(&wire(&sensor()))[..24].to_vec();
    payload.push(0);
    let mut rx = Receiver::<SensorFrame>::new();
    assert_eq!(assert_recovers(&mut rx, &frame_payload(&payload), &sensor()), [LinkError::Length]);
}

#[test]
fn invalid_cobs_is_malformed() {
    // A code byte that points past the end of the frame.
    let mut rx = Receiver::<SensorFrame>::new();
    assert_eq!(assert_recovers(&mut rx, &[0x10, 1, 2, 0], &sensor()), [LinkError::Cobs]);
}

#[test]
fn garbage_between_frames() {
    let (f1, f2, f3) =
        (sensor(), SensorFrame { sequence: 2, ..sensor() }, SensorFrame { sequence: 3, ..sensor() });
    let garbage = [0x55u8, 0xAA, 0x01, 0xFF, 0x13];
    // Garbage runs into the next frame, which is lost (and counted); the one after decodes.
    let mut bytes = wire(&f1);
    bytes.extend_from_slice(&garbage);
    bytes.extend(wire(&f2));
    bytes.extend(wire(&f3));
    let mut rx = Receiver::<SensorFrame>::new();
    let got = feed(&mut rx, &bytes);
    assert_eq!(got.len(), 3);
    assert_eq!(got[0], Ok(f1));
    assert!(got[1].is_err());
    assert_eq!(got[2], Ok(f3));
    assert_eq!(rx.stats().malformed + rx.stats().bad_crc, 1);
    // A sender that puts a delimiter before each frame loses nothing to idle-line noise.
    let mut bytes = vec![0];
    bytes.extend(wire(&f1));
    bytes.extend_from_slice(&garbage);
    bytes.push(0);
    bytes.extend(wire(&f2));
    let mut rx = Receiver::<SensorFrame>::new();
    let got = feed(&mut rx, &bytes);
    assert_eq!(got.len(), 3);
    assert_eq!((got[0], got[2]), (Ok(f1), Ok(f2)));
    assert!(got[1].is_err());
    // Runs of delimiters are empty frames: ignored, not counted.
    assert!(feed(&mut rx, &[0, 0, 0, 0]).is_empty());
    assert_eq!(rx.stats().malformed + rx.stats().bad_crc, 1);
}

#[test]
fn a_frame_longer_than_the_buffer_overflows_once_and_the_next_decodes() {
    let good = actuation();
    let mut rx = Receiver::<ActuationFrame>::new();
    let mut long = vec![0x11u8; 300];
    long.push(0);
    assert_eq!(assert_recovers(&mut rx, &long, &good), [LinkError::Overflow]);
    assert_eq!(rx.stats(), LinkStats { malformed: 1, bad_crc: 0, out_of_order: 0 });
    // Exactly the capacity still fits (and fails later, at COBS or length); one more overflows.
    let mut fits = vec![0x11u8; RX_CAPACITY];
    fits.push(0);
    let errors = assert_recovers(&mut rx, &fits, &good);
    assert_eq!(errors.len(), 1);
    assert_ne!(errors[0], LinkError::Overflow);
    let mut over = vec![0x11u8; RX_CAPACITY + 1];
    over.push(0);
    assert_eq!(assert_recovers(&mut rx, &over, &good), [LinkError::Overflow]);
    // Without its delimiter the overflow swallows what follows, up to the next 0x00.
    let mut rx = Receiver::<SensorFrame>::new();
    let mut bytes = vec![0x22u8; 100];
    bytes.extend(wire(&sensor()));
    bytes.extend(wire(&sensor()));
    let got = feed(&mut rx, &bytes);
    assert_eq!(got, [Err(LinkError::Overflow), Ok(sensor())]);
}

#[test]
fn a_zero_in_the_middle_splits_the_frame_and_both_halves_are_dropped() {
    let good = sensor();
    let w = wire(&good);
    let mut rx = Receiver::<SensorFrame>::new();
    for at in 1..w.len() - 1 {
        let mut bad = w.clone();
        bad.insert(at, 0);
        assert_eq!(assert_recovers(&mut rx, &bad, &good).len(), 2, "at {at}");
        let mut bad = w.clone();
        bad[at] = 0; // overwritten rather than inserted
        let errors = assert_recovers(&mut rx, &bad, &good);
        assert!(!errors.is_empty() && errors.len() <= 2, "at {at}");
    }
}

#[test]
fn reset_forgets_a_partial_frame_and_keeps_the_counts() {
    let mut rx = Receiver::<SensorFrame>::new();
    rx.stats_mut().record_out_of_order();
    let w = wire(&sensor());
    assert!(feed(&mut rx, &w[..10]).is_empty());
    rx.reset();
    assert_eq!(feed(&mut rx, &w), [Ok(sensor())]);
    assert_eq!(rx.stats().out_of_order, 1);
}

#[test]
fn counts_saturate() {
    let mut s = LinkStats { malformed: u16::MAX, bad_crc: u16::MAX, out_of_order: u16::MAX };
    s.record(LinkError::Crc);
    s.record(LinkError::Overflow);
    s.record_out_of_order();
    assert_eq!(s, LinkStats { malformed: u16::MAX, bad_crc: u16::MAX, out_of_order: u16::MAX });
}

// ---------------------------------------------------------------- sequence numbers

#[test]
fn sequence_classification_across_the_wrap() {
    use SequenceOrder::*;
    assert_eq!(classify_sequence(5, 6), InOrder { skipped: 0 });
    assert_eq!(classify_sequence(5, 9), InOrder { skipped: 3 });
    assert_eq!(classify_sequence(5, 5), Duplicate);
    assert_eq!(classify_sequence(5, 4), OutOfOrder);
    assert_eq!(classify_sequence(u16::MAX, 0), InOrder { skipped: 0 });
    assert_eq!(classify_sequence(u16::MAX - 1, 1), InOrder { skipped: 2 });
    assert_eq!(classify_sequence(0, u16::MAX), OutOfOrder);
    assert_eq!(classify_sequence(1, u16::MAX - 1), OutOfOrder);
    assert_eq!(classify_sequence(u16::MAX, u16::MAX), Duplicate);
    // The window: 32 767 ahead is in order, 32 768 away is not.
    assert_eq!(classify_sequence(40_000, 40_000u16.wrapping_add(0x7FFF)), InOrder { skipped: 0x7FFE });
    assert_eq!(classify_sequence(40_000, 40_000u16.wrapping_add(0x8000)), OutOfOrder);
    for last in [0u16, 1, 0x7FFF, 0x8000, u16::MAX] {
        for d in 1..=0x7FFFu16 {
            assert_eq!(classify_sequence(last, last.wrapping_add(d)), InOrder { skipped: d - 1 });
            assert_eq!(classify_sequence(last, last.wrapping_sub(d)), OutOfOrder);
        }
    }
}

#[test]
fn tracker_accepts_in_order_frames_only() {
    use SequenceOrder::*;
    let mut t = SequenceTracker::new();
    assert_eq!(t.last(), None);
    assert_eq!(t.check(65_534), InOrder { skipped: 0 });
    assert_eq!(t.check(65_535), InOrder { skipped: 0 });
    assert_eq!(t.check(65_535), Duplicate);
    assert_eq!(t.check(1), InOrder { skipped: 1 });
    assert_eq!(t.check(65_535), OutOfOrder);
    assert_eq!(t.check(0), OutOfOrder);
    assert_eq!(t.last(), Some(1));
    assert_eq!(t.check(2), InOrder { skipped: 0 });
    // A restarted host: dropped until the tracker is reset.
    assert_eq!(t.check(0), OutOfOrder);
    t.reset();
    assert_eq!(t.check(0), InOrder { skipped: 0 });
    assert_eq!(t.last(), Some(0));
}

// ---------------------------------------------------------------- watchdog

#[test]
fn watchdog_trips_after_exactly_the_stated_periods() {
    assert_eq!(SILENT_LINK_PERIODS, 10);
    let mut w = LinkWatchdog::default();
    assert_eq!(w.limit_periods(), SILENT_LINK_PERIODS);
    for _ in 0..3 {
        for k in 1..SILENT_LINK_PERIODS {
            assert!(!w.period(false), "tripped after {k} periods");
            assert_eq!(w.silent_periods(), k);
        }
        assert!(w.period(false), "must trip at period {SILENT_LINK_PERIODS}");
        assert!(w.tripped());
        assert!(w.period(false), "stays tripped while silent");
        // One accepted frame restarts the count.
        assert!(!w.period(true));
        assert_eq!(w.silent_periods(), 0);
        assert!(!w.tripped());
    }
    // A frame within the limit keeps it from tripping.
    for _ in 0..100 {
        for _ in 1..SILENT_LINK_PERIODS {
            assert!(!w.period(false));
        }
        assert!(!w.period(true));
    }
    // Other limits; a limit of 0 means 1; the count saturates.
    let mut w = LinkWatchdog::new(3);
    assert_eq!([w.period(false), w.period(false), w.period(false)], [false, false, true]);
    let mut w = LinkWatchdog::new(0);
    assert!(w.period(false));
    for _ in 0..70_000 {
        assert!(w.period(false));
    }
    assert_eq!(w.silent_periods(), u16::MAX);
}

// ---------------------------------------------------------------- random streams

/// Checks every frame a receiver yields against the bytes it came from, independently
/// of the library: valid COBS, the raw length, and the CRC.
fn run_stream<F: Frame>(bytes: &[u8]) -> Result<usize, TestCaseError> {
    let mut rx = Receiver::<F>::new();
    let mut current: Vec<u8> = Vec::new();
    let (mut ok, mut err) = (0usize, 0usize);
    for &b in bytes {
        let result = rx.push(b);
        if b == 0 {
            if let Some(Ok(_)) = result {
                let mut raw = vec![0u8; current.len()];
                let n =
                    cobs::decode(&current, &mut raw).map_err(|e| TestCaseError::fail(format!("{e:?}")))?;
                let raw = &raw[..n.frame_size()];
                prop_assert_eq!(raw.len(), F::RAW_LEN);
                let (payload, crc) = raw.split_at(F::PAYLOAD_LEN);
                prop_assert_eq!(crc16(payload).to_le_bytes(), [crc[0], crc[1]]);
                ok += 1;
            }
            current.clear();
        } else {
            current.push(b);
        }
        if let Some(Err(_)) = result {
            err += 1;
        }
    }
    let s = rx.stats();
    prop_assert_eq!(usize::from(s.malformed) + usize::from(s.bad_crc), err);
    Ok(ok)
}

#[derive(Clone, Debug)]
enum Chunk {
    Frame(SensorFrame),
    Corrupted(SensorFrame, usize, u8),
    Noise(Vec<u8>),
}

fn chunk() -> impl Strategy<Value = Chunk> {
    prop_oneof![
        arb_sensor().prop_map(Chunk::Frame),
        (arb_sensor(), 0usize..28, any::<u8>()).prop_map(|(f, i, x)| Chunk::Corrupted(f, i, x)),
        proptest::collection::vec(any::<u8>(), 0..40).prop_map(Chunk::Noise),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn random_byte_streams_never_panic_nor_pass_a_bad_crc(bytes in proptest::collection::vec(any::<u8>(), 0..2000)) {
        run_stream::<SensorFrame>(&bytes)?;
        run_stream::<ActuationFrame>(&bytes)?;
    }

    #[test]
    fn mixed_streams_yield_only_crc_valid_frames(chunks in proptest::collection::vec(chunk(), 0..30)) {
        let mut bytes = Vec::new();
        let mut clean = 0;
        for c in &chunks {
            match c {
                Chunk::Frame(f) => { bytes.extend(wire(f)); clean += 1; }
                Chunk::Corrupted(f, i, x) => {
                    let mut w = wire(f);
                    w[*i] ^= x;
                    bytes.extend(w);
                }
                Chunk::Noise(n) => bytes.extend_from_slice(n),
            }
        }
        let ok = run_stream::<SensorFrame>(&bytes)?;
        prop_assert!(ok <= chunks.len());
        // Noise, or a corrupted frame that lost its delimiter, eats at most the frame
        // that follows it.
        let spoilers = chunks.iter().filter(|c| !matches!(c, Chunk::Frame(_))).count();
        prop_assert!(ok + spoilers >= clean, "ok {} spoilers {} clean {}", ok, spoilers, clean);
    }
}

// ---------------------------------------------------------------- COBS against the `cobs` crate

proptest! {
    #![proptest_config(ProptestConfig { cases: 1024, ..ProptestConfig::default() })]

    /// `link::cobs` encodes byte for byte as the `cobs` crate does (zeros are made
    /// likely, and lengths cross the 254-byte block), and decodes what either encoded.
    #[test]
    fn cobs_matches_the_cobs_crate(
        data in proptest::collection::vec(prop_oneof![Just(0u8), any::<u8>()], 0..600)
    ) {
        let mut ours = vec![0u8; data.len() + data.len() / 254 + 1];
        let mut theirs = ours.clone();
        let n = dcfo::link::cobs::encode(&data, &mut ours).expect("fits");
        let m = cobs::try_encode(&data, &mut theirs).expect("fits");
        prop_assert_eq!(&ours[..n], &theirs[..m]);
        let k = dcfo::link::cobs::decode_in_place(&mut ours[..n]).expect("valid");
        prop_assert_eq!(&ours[..k], &data[..]);
        // Too short by one byte: an error, not a panic.
        prop_assert_eq!(dcfo::link::cobs::encode(&data, &mut vec![0u8; n - 1]), None);
    }

    /// On any zero-free input the decoder accepts exactly what the `cobs` crate accepts,
    /// with the same result (the link's receiver never passes it a `0x00`).
    #[test]
    fn cobs_decodes_as_the_cobs_crate(encoded in proptest::collection::vec(1u8..=255, 1..300)) {
        let mut ours = encoded.clone();
        let mut theirs = vec![0u8; encoded.len()];
        let got = dcfo::link::cobs::decode_in_place(&mut ours);
        let want = cobs::decode(&encoded, &mut theirs).ok().map(|r| r.frame_size());
        prop_assert_eq!(got, want);
        if let Some(n) = got {
            prop_assert_eq!(&ours[..n], &theirs[..n]);
        }
    }
}

// ---------------------------------------------------------------- with the drive

#[test]
fn a_drive_answers_sensor_frames_over_the_link() {
    let motor = MotorParams::new(MotorParams::paper()).expect("paper motor");
    let config = DriveConfig::for_motor(&motor, 48.0, ObserverKind::Dcfo);
    let mut drive: Drive<f32> = Drive::new(&motor, &config, &Base::SI).expect("drive");
    let mut ctl_rx = Receiver::<SensorFrame>::new();
    let mut host_rx = Receiver::<ActuationFrame>::new();
    let mut tracker = SequenceTracker::new();
    let mut watchdog = LinkWatchdog::default();
    let mut buf = [0u8; ActuationFrame::WIRE_LEN];
    for k in 0..50u16 {
        let sent = SensorFrame { sequence: k.wrapping_add(65_530), i_a: 0.0, i_b: 0.0, i_c: 0.0, ..sensor() };
        let mut frames = feed(&mut ctl_rx, &wire(&sent));
        let frame = frames.pop().expect("one frame").expect("decodes");
        assert_eq!(tracker.check(frame.sequence), SequenceOrder::InOrder { skipped: 0 });
        assert!(!watchdog.period(true));
        assert_eq!(frame.apply_commands(&mut drive), Ok(()));
        let out = drive.step(&frame.measurements(&Base::SI));
        let reply = ActuationFrame::from_step(frame.sequence, &out, &Base::SI, ctl_rx.stats());
        let n = encode(&reply, &mut buf).expect("encodes");
        let got = feed(&mut host_rx, &buf[..n]);
        assert_eq!(got, [Ok(reply)]);
        assert_eq!(reply.sequence, sent.sequence);
        assert_eq!(reply.state(), out.state);
        assert_eq!(reply.bridge_enabled, out.bridge_enabled);
        assert!(
            matches!(reply.state(), DriveState::Calibrating | DriveState::Disabled),
            "{:?}",
            reply.state()
        );
    }
}

#[test]
fn measurements_use_the_working_units() {
    let motor = MotorParams::new(MotorParams::paper()).expect("paper motor");
    let pu = Base::for_motor(&motor);
    let f = sensor();
    let m = f.measurements::<f32>(&pu);
    assert!((m.i_abc.a - f.i_a / pu.current_a).abs() < 1e-6);
    assert!((m.vdc - f.vdc / pu.voltage_v).abs() < 1e-6);
    let si = f.measurements::<f64>(&Base::SI);
    assert_eq!(si.i_abc.b, f64::from(f.i_b));
}

/// The controller side: a silent link trips the drive after exactly the stated number of
/// periods, and an in-order frame is answered with the frame of its sequence number.
#[test]
fn link_server_answers_in_order_frames_and_trips_a_silent_link() {
    use dcfo::link::{LinkServer, SILENT_LINK_PERIODS};

    let m = MotorParams::paper();
    let mut drive: Drive<f32> =
        Drive::new(&m, &DriveConfig::for_motor(&m, 311.0, ObserverKind::Dcfo), &Base::SI).unwrap();
    let mut server = LinkServer::new();
    let mut out = [0u8; LinkServer::REPLY_LEN];
    let frame = SensorFrame {
        sequence: 41,
        i_a: 0.0,
        i_b: 0.0,
        i_c: 0.0,
        vdc: 311.0,
        speed_ref: 0.3,
        enable: true,
        clear_faults: false,
        move_to: None,
    };
    let mut wire = [0u8; SensorFrame::WIRE_LEN];
    let n = encode(&frame, &mut wire).unwrap();
    let mut answered = None;
    for &b in &wire[..n] {
        if let Some(len) = server.on_byte(b, &mut drive, &Base::SI, &mut out) {
            answered = Some(len);
        }
    }
    let len = answered.expect("an in-order frame is answered");
    // The answer is COBS-framed; decode it as the host does.
    let mut rx = Receiver::<ActuationFrame>::new();
    let reply = out[..len].iter().find_map(|&b| rx.push(b)).expect("a frame").expect("valid");
    assert_eq!(reply.sequence, 41);
    for period in 1..=SILENT_LINK_PERIODS {
        let tripped = server.silent_period(&mut drive);
        assert_eq!(tripped, period == SILENT_LINK_PERIODS, "period {period}");
    }
    assert!(drive.faults().contains(Faults::EXTERNAL));
    assert_eq!(drive.state(), DriveState::Fault);
    // The sequence was forgotten: a restarted host (sequence 0) is answered again.
    let restart = SensorFrame { sequence: 0, clear_faults: true, enable: false, ..frame };
    let n = encode(&restart, &mut wire).unwrap();
    let answers = wire[..n].iter().filter(|&&b| server.on_byte(b, &mut drive, &Base::SI, &mut out).is_some());
    assert_eq!(answers.count(), 1);
    assert_eq!(drive.state(), DriveState::Disabled);
    // A silent link does not latch a fault in a drive whose bridge is already off.
    for _ in 0..3 * SILENT_LINK_PERIODS {
        server.silent_period(&mut drive);
    }
    assert_eq!((drive.state(), drive.faults()), (DriveState::Disabled, Faults::NONE));
}
