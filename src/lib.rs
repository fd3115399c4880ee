//! # dcfo — sensorless PMSLM drive core
//!
//! (Crate documentation is completed with the numeric design below.)
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod motor;
