//! What an operator asks of the drive, as one value ([`Commands`]) applied in one place
//! ([`Drive::apply`]); the SI measurements as the drive's working units
//! ([`Measurements::from_si`]); and the drive state's telemetry code
//! ([`DriveState::code`], [`DriveState::from_code`]). Every path into the drive — the
//! lock-step link, the board link's setpoints, the firmware's control interrupt — goes
//! through these, so the mapping exists once.

use super::{Drive, DriveState, Measurements};
use crate::algorithms::transforms::Abc;
use crate::num::Scalar;
use crate::num::units::Base;

/// The operator's commands for one control period, SI units.
///
/// Moves of a positioning drive are not commands of a period but entries of a queue:
/// queue them with [`Drive::push_move`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Commands {
    /// The drive should run ([`Drive::enable`]); `false`: bridge off, [`Drive::disable`].
    pub enable: bool,
    /// Clear latched faults ([`Drive::clear_faults`]); an edge: set it for one period.
    pub clear_faults: bool,
    /// Linear speed reference, m/s (finite; converted with [`Drive::omega_from_speed`]).
    pub speed_ref_m_per_s: f32,
}

impl<T: Scalar> Drive<T> {
    /// Applies `commands`, in this order: clear faults (if asked), enable or disable,
    /// then the speed reference. The reference is converted to working units only when
    /// it changed since the last `apply` (a few float operations, soft-float on an
    /// FPU-less core); [`Drive::set_speed_reference`] in between forces the conversion.
    pub fn apply(&mut self, commands: &Commands) {
        if commands.clear_faults {
            self.clear_faults();
        }
        if commands.enable {
            self.enable();
        } else {
            self.disable();
        }
        let bits = commands.speed_ref_m_per_s.to_bits();
        if self.applied_speed_ref_bits != Some(bits) {
            let omega = self.omega_from_speed(commands.speed_ref_m_per_s);
            self.set_speed_reference(omega);
            self.applied_speed_ref_bits = Some(bits);
        }
    }
}

impl<T: Scalar> Measurements<T> {
    /// The measurements in the working units of `base` from SI: phase currents
    /// `i_abc_a` (A, phases a, b, c) and the DC-bus voltage `vdc_v` (V).
    pub fn from_si(i_abc_a: [f32; 3], vdc_v: f32, base: &Base) -> Self {
        let [a, b, c] = i_abc_a;
        Measurements {
            i_abc: Abc { a: base.current(a), b: base.current(b), c: base.current(c) },
            vdc: base.voltage(vdc_v),
        }
    }
}

impl DriveState {
    /// Every state, in code order: `ALL[k].code() == k`.
    pub const ALL: [DriveState; 8] = [
        DriveState::Disabled,
        DriveState::Calibrating,
        DriveState::Starting,
        DriveState::Running,
        DriveState::Fault,
        DriveState::Reacquiring,
        DriveState::LowSpeed,
        DriveState::Commissioning,
    ];

    /// A small number for telemetry frames (0..=7 in declaration order).
    pub const fn code(self) -> u8 {
        match self {
            DriveState::Disabled => 0,
            DriveState::Calibrating => 1,
            DriveState::Starting => 2,
            DriveState::Running => 3,
            DriveState::Fault => 4,
            DriveState::Reacquiring => 5,
            DriveState::LowSpeed => 6,
            DriveState::Commissioning => 7,
        }
    }

    /// The state with telemetry code `code` (the inverse of [`DriveState::code`]);
    /// `None` for an unknown code.
    pub const fn from_code(code: u8) -> Option<DriveState> {
        match code {
            0 => Some(DriveState::Disabled),
            1 => Some(DriveState::Calibrating),
            2 => Some(DriveState::Starting),
            3 => Some(DriveState::Running),
            4 => Some(DriveState::Fault),
            5 => Some(DriveState::Reacquiring),
            6 => Some(DriveState::LowSpeed),
            7 => Some(DriveState::Commissioning),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn state_codes_round_trip() {
        for (k, s) in DriveState::ALL.into_iter().enumerate() {
            assert_eq!(usize::from(s.code()), k);
            assert_eq!(DriveState::from_code(s.code()), Some(s));
        }
        assert_eq!(DriveState::Commissioning.code(), 7);
        assert_eq!(DriveState::from_code(8), None);
    }
}
