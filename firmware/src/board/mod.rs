//! Board support: the only place in the firmware that touches hardware registers.

pub mod mps2_an386;
