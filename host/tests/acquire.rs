//! Cold-start acquisition (`dcfo acquire`) on a subset of the benchmark's sweep: a
//! mover held at 0.3 and 1.5 m/s in both directions, eight mover positions, with and
//! without +0.2 A / +2 V offsets present from the first sample, f32 and Q8.24.
//!
//! Measured on this subset (96 starts): at 1.5 m/s every start locks within 54 ms
//! (the budget there: 60 ms); at 0.3 m/s the median is 200 ms (+) and 303 ms (-),
//! the longest 564 ms (budget 200 ms: not met, see the README); no false lock; Q8.24
//! within 0.13 deg of f32 once locked. The -0.3 m/s median was 270 ms while the FLL took
//! the notch back above 20 % disagreement; with its band on the PLL's integrator
//! (2026-11-23) it is 303 ms here, and the whole sweep has 292 starts over budget
//! instead of 340.

use dcfo::observer::ObserverKind;
use dcfo_host::acquire::{Offset, Options, sweep};
use dcfo_host::sim::Setup;

#[test]
fn estimator_finds_a_moving_mover_from_its_zero_state() {
    let setup = Setup::paper(ObserverKind::Dcfo);
    let options = Options {
        speeds_m_per_s: vec![0.3, 1.5],
        positions: 8,
        offsets: Offset::ALL.to_vec(),
        fixed_point: true,
    };
    let starts = sweep(&setup, &options, |_, _| {}).unwrap();
    assert_eq!(starts.len(), 2 * 2 * 8 * 3);
    for s in &starts {
        println!(
            "{:5.2} m/s p{} {:7}: lock {:?} s, flag {:?} s, Q24 dev {:?} deg",
            s.speed_m_per_s,
            s.position,
            s.offset.label(),
            s.lock_time_s,
            s.flag_time_s,
            s.q24_deviation_deg
        );
        assert!(s.lock_time_s.is_some(), "never locked: {s:?}");
        assert_eq!(s.false_lock_samples, 0, "{s:?}");
        assert!(s.q24_deviation_deg.is_some_and(|d| d < 1.0), "{s:?}");
        if s.speed_m_per_s.abs() >= 1.5 {
            assert!(s.within_budget(), "{s:?}");
        }
    }
    for v in [0.3, -0.3] {
        let mut t: Vec<f64> =
            starts.iter().filter(|s| s.speed_m_per_s == v).filter_map(|s| s.lock_time_s).collect();
        t.sort_by(f64::total_cmp);
        let median = t[t.len() / 2];
        // The regression bound: the measured 0.303 s with a tenth of margin.
        assert!(median <= 0.33, "{v} m/s: median lock time {median} s");
    }
}
