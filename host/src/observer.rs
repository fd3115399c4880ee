//! The host's one mapping between the library's flux observers
//! ([`dcfo::algorithms::observer::ObserverKind`]) and their names on the command line, in file
//! names, summaries and messages: `pi`, `cfo`, `dcfo`.

use dcfo::algorithms::observer::ObserverKind;

/// Every observer kind, in the order the names are listed.
pub const ALL: [ObserverKind; 3] = [ObserverKind::PureIntegrator, ObserverKind::Cfo, ObserverKind::Dcfo];

/// The name of an observer: `pi` (pure integrator), `cfo` (LPF, the paper's
/// conventional observer) or `dcfo` (disturbance compensated flux observer).
pub fn observer_name(kind: ObserverKind) -> &'static str {
    match kind {
        ObserverKind::PureIntegrator => "pi",
        ObserverKind::Cfo => "cfo",
        ObserverKind::Dcfo => "dcfo",
    }
}

/// The observer named `name` ([`observer_name`]'s inverse); `None` for any other text.
pub fn observer_from_name(name: &str) -> Option<ObserverKind> {
    ALL.into_iter().find(|&k| observer_name(k) == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_are_distinct() {
        for kind in ALL {
            assert_eq!(observer_from_name(observer_name(kind)), Some(kind));
        }
        assert_eq!(observer_from_name("lpf"), None);
        assert_eq!(observer_from_name("DCFO"), None);
    }
}
