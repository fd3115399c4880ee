//! The `dcfo` commands, one module each: its parameters (`Params`, plain values that
//! [`crate::cli`] fills from the command line) and its run function (`run_command`).
//! Besides, the functions and types other commands and the tests use (a command may
//! use another's; none uses [`crate::cli`]).

pub mod acquire;
pub mod board;
pub mod faults;
pub mod hil;
pub mod identify;
pub mod motor_image;
pub mod paper;
pub mod replay;
pub mod results;
pub mod sim;
pub mod stroke;
pub mod track;
