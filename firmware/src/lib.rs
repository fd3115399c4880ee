//! Firmware for the DCFO drive.
//!
//! - [`board`]: the traits a board provides to the drive ([`board::PhaseSensors`],
//!   [`board::PowerStage`]), a fake board for tests and, on Arm, the board support —
//!   the only code here that touches registers.
//! - [`control`]: the control interrupt's work on a power stage, with lock-free setpoints
//!   and telemetry.
//! - [`board_link`]: the drive image's side of the board link (`dcfo board`): commands,
//!   telemetry, the capture and the command watchdog.
//! - [`image_drive`]: the drive every drive image builds from its motor image
//!   (positioning with an axis in the image, a speed drive without), one function.
//! - [`hil`]: the lock-step HIL link's firmware side on any board (the library's
//!   [`dcfo::link::LinkServer`], a transmit queue and the watchdog).
//! - [`queue`]: the fixed-capacity queue between an interrupt and the thread, with no
//!   path to a panic.
//! - `runtime` (Arm only): what every image does the same way (the interrupt-owned state,
//!   the drive image's control period and board-link answers, SysTick), so that an image
//!   says only what is its own.
//! - `rtt_log` (ESC1 only): the defmt logger over RTT, without a path to a panic.
//! - `stack` (Arm only): the HardFault entry that survives a stack overflow, and stack
//!   painting for the high-water mark.
//!
//! The firmware images are `examples/` (one per board); on the host they build to an
//! empty `main` so that `cargo test --workspace --all-targets` and clippy work. What a new
//! board implements, and how its image is put together: `docs/new-board.md`.
#![no_std]
#![deny(unsafe_code)]
#![deny(missing_docs)]

pub mod board;
pub mod board_link;
pub mod control;
pub mod hil;
pub mod image_drive;
pub mod queue;
#[cfg(all(target_arch = "arm", feature = "esc1"))]
#[allow(unsafe_code)]
pub mod rtt_log;
#[cfg(target_arch = "arm")]
#[allow(unsafe_code)]
pub mod runtime;
#[cfg(target_arch = "arm")]
#[allow(unsafe_code)]
pub mod stack;
