//! Host-side tools for the DCFO drive (std): plant simulation, trace I/O, replay.
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod acquire;
pub mod board;
pub mod cli;
pub mod faults;
pub mod hil;
pub mod identify;
pub mod motor_file;
pub mod motor_image;
pub mod observer;
pub mod paper;
pub mod plant;
pub mod plot;
pub mod progress;
pub mod qemu;
pub mod recorder;
pub mod replay;
pub mod results;
pub mod scenario_file;
pub mod sim;
pub mod stroke;
pub mod summary;
pub mod target;
pub mod trace;
pub mod track;
