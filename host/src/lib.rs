//! Host-side tools for the DCFO drive (std): the `dcfo` commands and what they share.
//!
//! - [`commands`]: one module per `dcfo` command, each with its parameters and its run
//!   function; [`cli`] parses the command line and dispatches to them.
//! - The simulated axis: [`plant`] (motor, inverter, sensors; SI readings),
//!   [`closed_loop`] (the plant in closed loop with a controller one PWM period late),
//!   [`simulation`] (the drive in closed loop over a scenario), [`recorder`] (sensored
//!   recordings for the estimator alone).
//! - The drive images: [`hil_link`] (the host end of the lock-step HIL link), [`qemu`],
//!   [`target`], [`exec_profile`] (where an image's instructions go, from QEMU's log).
//! - Files and output: [`trace`], [`motor_file`], [`scenario_file`], [`summary`],
//!   [`plot`], [`observer`], [`progress`].
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod cli;
pub mod closed_loop;
pub mod commands;
pub mod exec_profile;
pub mod hil_link;
pub mod motor_file;
pub mod observer;
pub mod plant;
pub mod plot;
pub mod progress;
pub mod qemu;
pub mod recorder;
pub mod scenario_file;
pub mod simulation;
pub mod summary;
pub mod target;
pub mod trace;
