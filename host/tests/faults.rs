//! `dcfo faults`: the fault campaign against its floors (issue 11, item 4) and each
//! case against the reaction the design promises (stated in `dcfo_host::faults::cases`
//! before it was measured). Measured figures are in the README's `dcfo faults` table.

use dcfo::drive::Faults;
use dcfo::observer::ObserverKind;
use dcfo_host::faults::{Expected, cases, run_all};
use dcfo_host::sim::Setup;

/// Cases that do not meet the expectation stated before measuring:
/// their floors (no silent failure, a named fault and the bridge off within a period on
/// any trip, no trip on a ride-through) are still asserted. None since the overload
/// supervision (`load-400N` tripped CURRENT_CONTROL after 320 ms, at 7.4 A, before it;
/// the open phase and the stuck sensor were shortfalls until the drive's phase-loss
/// check, `src/drive/phase_loss.rs`).
const SHORTFALLS: [&str; 0] = [];

#[test]
fn every_fault_trips_in_a_period_or_rides_through_and_none_fails_silently() {
    let (campaign, _) = run_all(2, |_| {}).expect("campaign runs");
    let overcurrent_a = f64::from(Setup::paper(ObserverKind::Dcfo).drive.faults.overcurrent_a);
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
        // The phase-loss check names a lost phase before its wrong currents grow to the
        // over-current trip (`src/drive/phase_loss.rs`): the true current stays below it.
        if ["open-phase", "sensor-stuck"].contains(&case.name) {
            assert!(
                r.i_peak_a < overcurrent_a,
                "{}: {} A peak, trip at {overcurrent_a} A",
                r.name,
                r.i_peak_a
            );
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
        Faults::COMMISSIONING,
        Faults::OVERLOAD,
    ];
    assert_eq!(all.len(), Faults::NAMES.len(), "every named fault is listed here");
    let mut seen = 0u16;
    for f in all {
        assert_eq!(f.bits().count_ones(), 1);
        assert_eq!(seen & f.bits(), 0);
        seen |= f.bits();
    }
}
