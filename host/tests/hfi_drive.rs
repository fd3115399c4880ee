//! The positioning drive with HFI on the salient motor (`motors/salient.toml`, Lq/Ld =
//! 1.5), `Drive<f32>` as the M4F firmware runs it, on the plant of `dcfo stroke` (R +20 %,
//! L -5 % against the motor file, 10 kg carriage, 10 N friction (13 N break-away), end-effect
//! ripple, dead time, sensor errors, d saturation 10 % at rated peak current): it holds
//! position at standstill under 50 % of rated thrust, and starts from an unknown mover
//! position (polarity included) without moving the mover to align it. The same runs with
//! HFI switched off (the open-loop current vector of before) are printed for comparison.

use dcfo::algorithms::motion::Move;
use dcfo::drive::{Drive, DriveState};
use dcfo::motor::MotorParams;
use dcfo::num::units::Base;
use dcfo_host::closed_loop::ClosedLoop;
use dcfo_host::commands::stroke::{drive_for, plant_for};
use dcfo_host::motor_file::load_motor;
use dcfo_host::plant::{Plant, rated_thrust_n};
use dcfo_host::simulation::{measurements, output_bridge};

fn salient() -> MotorParams {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../motors/salient.toml");
    load_motor(path).expect("motor file").params
}

/// One logged period.
#[derive(Clone, Copy, Debug)]
struct Sample {
    t_s: f64,
    x_m: f64,
    x_hat_m: f64,
    x_ref_m: f64,
    state: DriveState,
    i_q_a: f32,
}

/// Runs the drive for `duration_s` with the mover starting at `x0_m`, `load_n(t)` on the
/// mover, `moves` queued from the start; `hfi`: as configured (salient: on) or off.
fn run(x0_m: f64, duration_s: f64, load_n: impl Fn(f64) -> f64, moves: &[Move], hfi: bool) -> Vec<Sample> {
    let m = salient();
    let mut config = drive_for(&m);
    if !hfi {
        let mut motion = config.motion.expect("positioning");
        motion.hfi = None;
        config.motion = Some(motion);
    }
    assert_eq!(config.motion.expect("positioning").hfi.is_some(), hfi);
    let mut drive = Drive::<f32>::new(&m, &config, &Base::SI).expect("drive");
    let mut plant = Plant::new(&plant_for(&m)).expect("plant");
    plant.set_position(x0_m).expect("position");
    for mv in moves {
        drive.push_move(*mv).expect("move");
    }
    let ts = plant.pwm_period_s();
    let mut closed_loop = ClosedLoop::new(plant);
    let mut log = Vec::new();
    for k in 0..(duration_s / ts).round() as usize {
        let t = k as f64 * ts;
        let sensed = closed_loop.sense();
        let truth = sensed.truth;
        drive.enable();
        let out = drive.step(&measurements(&sensed.reading));
        closed_loop.actuate(sensed, output_bridge(&out), load_n(t));
        log.push(Sample {
            t_s: t,
            x_m: truth.x_m,
            x_hat_m: f64::from(drive.position_m()),
            x_ref_m: f64::from(drive.setpoint().unwrap_or_default().position_m),
            state: out.state,
            i_q_a: out.i_dq.q,
        });
    }
    log
}

/// `x` wrapped into the frame of the position estimate: the zero is electrical angle 0,
/// the pole pair the mover starts in (`x0` within [-tau, tau)).
fn frame_offset(x0_m: f64, tau: f64) -> f64 {
    let wrapped = (x0_m + tau).rem_euclid(2.0 * tau) - tau;
    x0_m - wrapped
}

#[test]
fn holds_position_at_standstill_under_half_rated_load() {
    let m = salient();
    let tau = f64::from(m.pole_pitch_m);
    let load = 0.5 * rated_thrust_n(&m); // 60 N
    let x0 = 0.0073;
    let t_load = 0.5;
    let offset = frame_offset(x0, tau);
    for hfi in [true, false] {
        let log = run(x0, 2.0, |t| if t >= t_load { load } else { 0.0 }, &[], hfi);
        let at_load = log.iter().find(|s| s.t_s >= t_load).expect("load applied");
        let after: Vec<_> = log.iter().filter(|s| s.t_s >= t_load).collect();
        let deflection = after.iter().map(|s| (s.x_m - at_load.x_m).abs()).fold(0.0, f64::max);
        let est_err = after.iter().map(|s| (s.x_hat_m - (s.x_m - offset)).abs()).fold(0.0, f64::max);
        let end = log.last().expect("ran");
        let end_err = (end.x_hat_m - (end.x_m - offset)).abs();
        let end_off_ref = (end.x_m - offset - end.x_ref_m).abs();
        // The q current over the last 0.2 s (one sample carries the loops' noise).
        let late: Vec<f32> = log.iter().filter(|s| s.t_s >= 1.8).map(|s| s.i_q_a).collect();
        let i_q_late = late.iter().sum::<f32>() / late.len().max(1) as f32;
        println!(
            "HFI {hfi}: {load:.1} N from {t_load} s: deflection max {:.3} mm, |x_hat - x| max {:.3} mm, \
             at the end {:.3} mm, mover {:.3} mm from the reference, i_q {:.2} A (last 0.2 s), state {:?}",
            1e3 * deflection,
            1e3 * est_err,
            1e3 * end_err,
            1e3 * end_off_ref,
            i_q_late,
            end.state
        );
        if hfi {
            // In the low-speed (HFI) mode throughout, no fault; the estimate never slips
            // (|x_hat - x| within tau / 4, the floor, at all times) and is within
            // the standstill budget of host/tests/hfi.rs (10 deg, 1.1 mm) at the end; the
            // load carried by q current (60 N over K_f = 28.3 N/A is 2.1 A, plus up to
            // the friction's 0.46 A either way), not by a d-axis vector; the mover held:
            // deflected less than tau / 4 (the hold on the load observer: 2.8 mm; the speed
            // PI it replaced at rest, 12.9 mm) and back within tau / 60 of the reference.
            assert!(log.iter().filter(|s| s.t_s > 0.2).all(|s| s.state == DriveState::LowSpeed));
            assert!(deflection < tau / 4.0, "{deflection}");
            assert!(end_off_ref < tau / 60.0, "{end_off_ref}");
            assert!(est_err < tau / 4.0, "{est_err}");
            assert!(end_err < tau * 10.0 / 180.0, "{end_err}");
            let i_load = (load / f64::from(m.thrust_constant_n_per_a())) as f32;
            assert!((i_q_late - i_load).abs() < 0.6, "{i_q_late} vs {i_load}");
        }
    }
}

#[test]
fn starts_from_an_unknown_position_without_moving_to_align() {
    let m = salient();
    let tau = f64::from(m.pole_pitch_m);
    // Mover angles 66, 163, 113 and 302 deg electrical: two of them need the polarity
    // test's turn by pi (HFI converges from 0 to the nearer end of the magnet's axis).
    for x0 in [0.0073, 0.0181, 0.0125, 0.0335] {
        let offset = frame_offset(x0, tau);
        // Two moves in the estimate's frame: 0.2 m forward (through the hand-over to the
        // sensorless estimator at 0.44 m/s) and back to the start.
        let start = x0 - offset;
        let target = start as f32 + 0.2;
        let moves = [Move { target_m: target, dwell_s: 0.2 }, Move { target_m: start as f32, dwell_s: 0.5 }];
        for hfi in [true, false] {
            let log = run(x0, 2.4, |_| 0.0, &moves, hfi);
            // Aligned: the profile holds at the position estimate (the start, within the
            // estimate's error); the first move starts from there.
            let aligned_at = log.iter().position(|s| (s.x_ref_m - start).abs() < 1.5e-3).unwrap_or(log.len());
            let hold = log.get(aligned_at).map_or(start, |s| s.x_ref_m);
            let moving_at =
                log.iter().position(|s| (s.x_ref_m - hold).abs() > 1e-5 && s.t_s > 0.0).unwrap_or(0);
            let moving_at = moving_at.max(aligned_at);
            let align_move = log[..moving_at].iter().map(|s| (s.x_m - x0).abs()).fold(0.0, f64::max);
            let est_err =
                log.iter().skip(aligned_at).map(|s| (s.x_hat_m - (s.x_m - offset)).abs()).fold(0.0, f64::max);
            let reached = log.iter().map(|s| s.x_m - offset).fold(f64::MIN, f64::max);
            let end = log.last().expect("ran");
            let end_err = (end.x_hat_m - (end.x_m - offset)).abs();
            let ran = log.iter().any(|s| s.state == DriveState::Running);
            println!(
                "HFI {hfi}, x0 {:.1} mm: moved {:.3} mm before the first move, |x_hat - x| max {:.3} mm, \
                 at the end {:.3} mm, reached {:.1} mm (target {:.1}), sensorless stretch {ran}, \
                 end state {:?}, aligned after {:.3} s, mover {:.2} mm from the start at the end",
                1e3 * x0,
                1e3 * align_move,
                1e3 * est_err,
                1e3 * end_err,
                1e3 * reached,
                1e3 * f64::from(target),
                end.state,
                log.get(aligned_at).map_or(f64::NAN, |s| s.t_s),
                1e3 * (end.x_m - offset - start)
            );
            if hfi {
                // The mover is not moved to align (the old vector pulls it to the nearest
                // angle-0 position, up to tau away), the estimate knows where it is from the
                // start (polarity included: a wrong one is tau off), no pole slip, and the
                // move is done, through the sensorless hand-over and back.
                // At the end, at rest: the standstill error budget of host/tests/hfi.rs
                // (10 deg electrical, 1.1 mm), not the stroke's tau / 60.
                assert!(align_move < 1e-4, "{x0}: {align_move}");
                assert!(est_err < tau / 4.0, "{x0}: {est_err}");
                assert!(end_err < tau * 10.0 / 180.0, "{x0}: {end_err}");
                assert!(ran, "{x0}: never sensorless");
                assert!((reached - f64::from(target)).abs() < 0.005, "{x0}: {reached}");
                assert_eq!(end.state, DriveState::LowSpeed, "{x0}");
                // How close the mover settles at the start in the last 0.3 s is the loops'
                // stiffness (printed, not asserted).
            }
        }
    }
}
