//! Fault bits of the drive. Any fault switches the bridge off and latches until
//! cleared ([`super::Drive::clear_faults`]).

/// A set of fault bits. Each bit names one cause; several can be set at once.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Faults(u16);

impl Faults {
    /// No fault.
    pub const NONE: Faults = Faults(0);
    /// A phase current exceeded the trip level.
    pub const OVER_CURRENT: Faults = Faults(1 << 0);
    /// The DC-bus voltage fell below its minimum.
    pub const BUS_UNDER_VOLTAGE: Faults = Faults(1 << 1);
    /// The DC-bus voltage rose above its maximum.
    pub const BUS_OVER_VOLTAGE: Faults = Faults(1 << 2);
    /// A measurement was NaN, infinite or outside the number range.
    pub const NON_FINITE: Faults = Faults(1 << 3);
    /// The estimator (observer or PLL) refused a sample or overflowed.
    pub const ESTIMATOR: Faults = Faults(1 << 4);
    /// The PLL stayed unlocked for longer than allowed while running sensorless.
    pub const LOCK_LOST: Faults = Faults(1 << 5);
    /// Current-offset calibration measured an offset beyond its limit.
    pub const CALIBRATION: Faults = Faults(1 << 6);
    /// The modulator refused the command (bad bus value or command).
    pub const MODULATION: Faults = Faults(1 << 7);
    /// The board or host link reported a fault (e.g. a silent HIL link).
    pub const EXTERNAL: Faults = Faults(1 << 8);
    /// The current loops lost control: their voltage stayed on the bridge's limit while
    /// the measured current stayed off its reference, or one phase carried less than a
    /// quarter of its reference current while another carried its own (an open phase, a
    /// stuck or disconnected current sensor); see [`super::FaultConfig::current_error_a`]
    /// and [`super::FaultConfig::phase_loss_filter_s`].
    pub const CURRENT_CONTROL: Faults = Faults(1 << 9);
    /// Commissioning stopped: a named error of its own, or a protection of the drive
    /// while it ran ([`super::Drive::commissioning_result`]).
    pub const COMMISSIONING: Faults = Faults(1 << 10);
    /// The axis needs more thrust than the drive gives: the speed loop (running, or a
    /// positioning drive's low-speed mode on HFI) pushed on the thrust-current limit
    /// towards its reference, the speed off it by more than the hand-over's tolerance,
    /// for longer than [`super::FaultConfig::overload_s`] (the mover overpowered:
    /// stopped, or pushed back by the load); or, in the low-speed mode on the current
    /// vector, the back-EMF read a mover faster than the vector's spring lets it swing
    /// (it slips poles under a load the vector cannot hold).
    pub const OVERLOAD: Faults = Faults(1 << 11);

    /// Every fault bit with its name (as the constants are called), for logs and
    /// reports.
    pub const NAMES: [(Faults, &'static str); 12] = [
        (Faults::OVER_CURRENT, "OVER_CURRENT"),
        (Faults::BUS_UNDER_VOLTAGE, "BUS_UNDER_VOLTAGE"),
        (Faults::BUS_OVER_VOLTAGE, "BUS_OVER_VOLTAGE"),
        (Faults::NON_FINITE, "NON_FINITE"),
        (Faults::ESTIMATOR, "ESTIMATOR"),
        (Faults::LOCK_LOST, "LOCK_LOST"),
        (Faults::CALIBRATION, "CALIBRATION"),
        (Faults::MODULATION, "MODULATION"),
        (Faults::EXTERNAL, "EXTERNAL"),
        (Faults::CURRENT_CONTROL, "CURRENT_CONTROL"),
        (Faults::COMMISSIONING, "COMMISSIONING"),
        (Faults::OVERLOAD, "OVERLOAD"),
    ];

    /// The raw bits (for telemetry frames).
    pub const fn bits(self) -> u16 {
        self.0
    }
    /// From raw bits (unknown bits are kept).
    pub const fn from_bits(bits: u16) -> Self {
        Faults(bits)
    }
    /// `true` when no bit is set.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// `true` when every bit of `other` is set here.
    pub const fn contains(self, other: Faults) -> bool {
        self.0 & other.0 == other.0
    }
    /// Sets the bits of `other`.
    pub fn insert(&mut self, other: Faults) {
        self.0 |= other.0;
    }
}

impl core::ops::BitOr for Faults {
    type Output = Faults;
    fn bitor(self, rhs: Faults) -> Faults {
        Faults(self.0 | rhs.0)
    }
}
