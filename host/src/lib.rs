//! Host-side tools for the DCFO drive (std): plant simulation, trace I/O, replay.
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod motor_file;
pub mod plant;
pub mod summary;
pub mod trace;
