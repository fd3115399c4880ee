//! # dcfo — sensorless PMSLM drive core
//!
//! The algorithms of a sensorless field-oriented drive for a permanent-magnet
//! synchronous linear motor, built around the *disturbance compensated flux observer*
//! (DCFO) of Liu, Yin, Bai and Yuan (`docs/method.md`: the method in this project's
//! notation, the paper cited and its slips corrected). `no_std`, no allocation, no
//! `unsafe`, no panics in per-sample code.
//!
//! | module | `docs/method.md` | contents |
//! |---|---|---|
//! | [`num`] | — | the [`Scalar`](num::Scalar) trait (f32, f64, [`Q24`](num::Q24)) and the binary [`Angle`](num::Angle) |
//! | [`units`] | — | SI or per-unit working units |
//! | [`motor`] | §1 | validated motor parameters |
//! | [`motor_image`] | — | the motor as a CRC-protected binary record for a board's flash |
//! | [`transforms`] | §5 | Clarke, Park and inverses |
//! | [`pi`] | §5 | PI controller with anti-windup |
//! | [`svpwm`] | §5 | space-vector modulation |
//! | [`dead_time`] | §8 | the inverter's dead-time and drop error with the PWM ripple at the switching edges, as the drive compensates it |
//! | [`observer`] | §2–3 | pure integrator, LPF (CFO) and DCFO flux observers |
//! | [`pll`] | §4 | angle and speed from the flux |
//! | [`fll`] | — | the frequency from the flux vector's rotation: tunes the DCFO's notch, acquires a moving mover |
//! | [`hfi`] | — | high-frequency injection: the angle of a salient motor at standstill and low speed, magnet polarity |
//! | [`estimator`] | §4–5 | observer + PLL as the drive and trace replay run them |
//! | [`drive`] | §5 | the control step: FOC loop, I/f start-up, protection state machine |
//! | [`link`] | — | hardware-in-the-loop serial protocol: sensor and actuation frames, COBS + CRC-16, receiver, watchdog |
//! | [`capture`] | — | the drive's triggered full-rate capture (estimator inputs and estimates), replayable bit for bit |
//! | [`virtual_motor`] | — | a PMSLM and an averaged inverter in `f32`, for a drive image to run closed loop on no hardware |
//!
//! ## Numbers
//! Every algorithm is generic over [`num::Scalar`] and instantiated three times: `f32`
//! for Cortex-M4F, saturating fixed point [`num::Q24`] (Q8.24) for FPU-less cores, and
//! `f64` as the host reference. Generics (rather than macros or a feature-selected type
//! alias) keep one type-checked source, let a host test run all three side by side, and
//! cost nothing at run time. Fixed point runs in per-unit ([`units::Base::for_motor`]):
//! on the paper motor at twice rated current and twice its top speed, currents reach
//! 2 pu and the bus 1.7 pu, in a range of +-128 with a resolution of 6e-8.
//!
//! ## Angles
//! [`num::Angle`] is a 32-bit binary angle: wrapping is exact and free. Cosine and sine
//! come from idsp's table-interpolated `cossin` (measured max error 1.9e-5, about 40
//! Cortex-M instructions, bounded time) for f32 and fixed point, and from libm for the f64
//! reference.
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod arc_fit;
pub mod capture;
pub mod dead_time;
pub mod drive;
pub mod estimator;
pub mod fll;
pub mod hfi;
pub mod link;
pub mod load_observer;
pub mod motion;
pub mod motor;
pub mod motor_image;
pub mod num;
pub mod observer;
pub mod pi;
pub mod pll;
pub mod svpwm;
pub mod transforms;
pub mod units;
pub mod virtual_motor;
