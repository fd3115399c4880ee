//! # dcfo — sensorless PMSLM drive core
//!
//! The algorithms of a sensorless field-oriented drive for a permanent-magnet
//! synchronous linear motor, built around the *disturbance compensated flux observer*
//! (DCFO) of Liu, Yin, Bai and Yuan (`docs/method.md`: the method in this project's
//! notation, the paper cited and its slips corrected). `no_std`, no allocation, no
//! `unsafe`, no panics in per-sample code.
//!
//! The modules are the architecture's floors, from the ground up; each imports only the
//! floors below it.
//!
//! | module | `docs/method.md` | contents |
//! |---|---|---|
//! | [`motor`] | §1 | validated motor parameters: the plain data everything is parameterised by |
//! | [`num`] | — | the [`Scalar`](num::Scalar) trait (f32, f64, [`Q24`](num::Q24)), the binary [`Angle`](num::Angle), and SI or per-unit working [`units`](num::units) |
//! | [`algorithms`] | §2–5, §8 | the pure blocks, each on its own: transforms, PI, SVPWM, dead time, flux observers, PLL, FLL, arc fit, HFI, load observer, motion profiles |
//! | [`estimator`] | §4–5 | observer + PLL (+ FLL, arc fit) as the drive and trace replay run them |
//! | [`motor_image`] | — | the motor as a CRC-protected binary record for a board's flash, as the drive reads it |
//! | [`drive`] | §5 | the control step: FOC loop, I/f start-up, protection state machine |
//! | [`capture`] | — | the drive's triggered full-rate capture (estimator inputs and estimates), replayable bit for bit |
//! | [`link`] | — | hardware-in-the-loop serial protocol: sensor and actuation frames, COBS + CRC-16, receiver, watchdog |
//! | [`plant`] | — | at the edge: a virtual motor (a PMSLM and an averaged inverter in `f32`), for a drive image to run closed loop on no hardware |
//!
//! ## Numbers
//! Every algorithm is generic over [`num::Scalar`] and instantiated three times: `f32`
//! for Cortex-M4F, saturating fixed point [`num::Q24`] (Q8.24) for FPU-less cores, and
//! `f64` as the host reference. Generics (rather than macros or a feature-selected type
//! alias) keep one type-checked source, let a host test run all three side by side, and
//! cost nothing at run time. Fixed point runs in per-unit ([`num::units::Base::for_motor`]):
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

// The ground: the motor's parameters, and numbers and units.
pub mod motor;
pub mod num;

// The pure algorithms.
pub mod algorithms;

// What composes them: the estimator, and the motor's flash record.
pub mod estimator;
pub mod motor_image;

// The control step.
pub mod drive;

// Above the drive: its capture record, and the HIL link.
pub mod capture;
pub mod link;

// At the edge: a plant model, in place of a power stage.
pub mod plant;
