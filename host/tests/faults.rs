//! `dcfo faults`: the fault campaign against its floors (issue 11, item 4) and each
//! case against the reaction the design promises (stated in `dcfo_host::faults::cases`
//! before it was measured). Measured figures are in the README's `dcfo faults` table.

use dcfo::drive::Faults;
use dcfo_host::faults::{Expected, cases, run_all};

/// Cases that do not meet the expectation stated before measuring (README, Status):
/// their floors (no silent failure, a named fault and the bridge off within a period on
/// any trip, no trip on a ride-through) are still asserted.
const SHORTFALLS: [&str; 3] = [
    // Expected CURRENT_CONTROL; trips OVER_CURRENT after 242 ms (10.1 A). At 0.3 m/s and
    // light load the open phase corrupts the flux estimate before the current loops
    // reach their voltage limit, and the drive pushes on a wrong angle until the current
    // overshoots. While the FLL took the notch back above 20 % disagreement (before
    // 2026-11-23) the loops saturated first (CURRENT_CONTROL at 127 ms); with the FLL's
    // band and before the angle's phase compensation it was OVER_CURRENT at 260 ms. A
    // per-phase current-imbalance check would name it; not done.
    "open-phase",
    // Expected CURRENT_CONTROL; trips OVER_CURRENT after 76 ms, the current behind the
    // stuck sensor at 20.3 A (27 A and CURRENT_CONTROL at 64 ms before the FLL's band):
    // the computed third current reaches the trip level before the loops' voltage
    // saturates.
    "sensor-stuck",
    // Expected LOCK_LOST; the mover reverses under the load and the drive trips
    // CURRENT_CONTROL after 320 ms at 7.4 A (OVER_CURRENT at 10.4 A before the FLL's band).
    // (Figures of 2026-11-25, as the README's table.)
    "load-400N",
];

#[test]
fn every_fault_trips_in_a_period_or_rides_through_and_none_fails_silently() {
    let (campaign, _) = run_all(2, |_| {}).expect("campaign runs");
    println!("{}", dcfo_host::faults::table(&campaign));
    assert!(campaign.cases >= 12, "{} cases", campaign.cases);
    assert_eq!(campaign.silent_failures, 0);
    assert!(campaign.max_bridge_off_periods <= 1, "{}", campaign.max_bridge_off_periods);
    for (case, r) in cases().iter().zip(&campaign.results) {
        assert_eq!(case.name, r.name);
        assert!(!r.silent_failure, "{}: locked and wrong for {} s", r.name, r.locked_wrong_s);
        match case.expected {
            Expected::Trip(_) => {
                assert_ne!(r.faults, "none", "{}: no fault latched", r.name);
                assert!(
                    r.bridge_off_periods.is_some_and(|p| p <= 1),
                    "{}: {:?}",
                    r.name,
                    r.bridge_off_periods
                );
            }
            Expected::RideThrough(_) => assert_eq!(r.faults, "none", "{}: tripped", r.name),
        }
        if SHORTFALLS.contains(&case.name) {
            println!("known shortfall {}: {}", r.name, r.happened);
        } else {
            assert!(r.met, "{}: expected {}, {}", r.name, r.expected, r.happened);
        }
    }
    // The link cases: no corrupted or replayed frame was acted on, duplicates were
    // answered with the same bytes.
    for r in campaign.results.iter().filter_map(|r| r.link.map(|l| (r.name.clone(), l))) {
        let (name, l) = r;
        assert_eq!((l.corrupted_answered, l.duplicate_mismatches, l.replays_answered), (0, 0, 0), "{name}");
    }
    let corrupted = campaign.results.iter().find(|r| r.name == "corrupted-frames").and_then(|r| r.link);
    assert!(corrupted.is_some_and(
        |l| l.corrupted > 100 && u32::from(l.drive_bad_crc) + u32::from(l.drive_malformed) >= l.corrupted
    ));
}

#[test]
fn the_faults_the_campaign_names_are_distinct_bits() {
    let all = [
        Faults::OVER_CURRENT,
        Faults::BUS_UNDER_VOLTAGE,
        Faults::BUS_OVER_VOLTAGE,
        Faults::NON_FINITE,
        Faults::ESTIMATOR,
        Faults::LOCK_LOST,
        Faults::CALIBRATION,
        Faults::MODULATION,
        Faults::EXTERNAL,
        Faults::CURRENT_CONTROL,
    ];
    let mut seen = 0u16;
    for f in all {
        assert_eq!(f.bits().count_ones(), 1);
        assert_eq!(seen & f.bits(), 0);
        seen |= f.bits();
    }
}
