//! Firmware for the DCFO drive.
//!
//! - `board` (arm only): board support, the only code here that touches registers.
//!
//! The lock-step HIL protocol is the library's [`dcfo::link::LinkServer`], which the
//! host's tests also run against a fake firmware.
//!
//! The binaries in `src/bin/` are the firmware images; on the host they build to an
//! empty `main` so that `cargo test --workspace` and `cargo clippy --workspace` work.
#![no_std]
#![deny(unsafe_code)]
#![deny(missing_docs)]

#[cfg(target_arch = "arm")]
#[allow(unsafe_code)]
pub mod board;
