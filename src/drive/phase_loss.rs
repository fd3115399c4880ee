//! Phase-loss supervision: a phase that carries far less current than the loops ask of
//! it while another carries its own, i.e. an open phase (its current is zero whatever
//! the bridge applies) or a current sensor stuck near zero.
//!
//! ## Why a check of its own
//! The current-control supervision (`FaultConfig::current_error_a`) trips once the
//! loops' voltage sits on the bridge's limit with the current off its reference. At
//! light load an open phase does not saturate the voltage: the two remaining phases
//! carry a current vector on a line, the flux estimate is corrupted by it, and without a
//! check of its own the drive pushes on a wrong angle until the over-current trip (`dcfo
//! faults`: an open phase at 0.3 m/s takes a quarter of a second to trip, and a stuck
//! sensor has several times the rated current behind it by then).
//!
//! ## The check
//! Per phase `k`, the magnitudes of the measured current `|i_k|` and of the reference
//! current `|i_ref,k|` (the loops' dq reference in the control frame, in phase
//! coordinates) pass the same first-order low-pass of time constant
//! `FaultConfig::phase_loss_filter_s` (`m_k`, `r_k`). A phase is *starved* when
//! `r_k > current_error_a` and `4 m_k < r_k`; it *carries* when `2 m_k >= r_k`. One
//! starved phase while another carries, for longer than `current_error_s`, is a lost
//! phase.
//! - Both magnitudes pass the same filter, so a healthy phase's `m_k / r_k` is the
//!   ratio of its current to its reference, near 1 at any speed: through zero crossings,
//!   at standstill (DC currents), at any filter time constant. The filter only averages
//!   the sensors' noise and the PWM ripple, and bridges the zero crossings.
//! - A drive that cannot push its currents at all (the voltage on its limit at high
//!   speed, a bus sag) falls short on every phase alike: no phase carries while another
//!   starves, and the saturation check is the one that speaks.
//! - A phase with no reference "carries" (`0 >= 0`). A reference of its own is not
//!   required too (a quarter of the starved phase's): that lets the current behind a
//!   stuck sensor grow to twice as much before the trip (`dcfo faults`), and the case it
//!   would exclude, a current vector across two phases that the loops deliver short at
//!   standstill, has the loops' voltage on its limit: the saturation check names it the
//!   same.
//! - After a phase opens, `m_k` decays from about `r_k` as `exp(-n Ts / tau)` (n
//!   periods; checked in every fourth, below): it is below
//!   a quarter after `tau ln 4` (13.9 ms for `tau` = 10 ms), and the trip follows
//!   `current_error_s` later, provided the reference averages above the threshold (an
//!   open phase at light load waits for the reference to grow above 10 % of rated peak).
//!   `dcfo faults` prints the detection times of an open phase and a stuck sensor.
//!
//! The drive runs it wherever its current loops run (not while HFI aligns, when the
//! loops are held), on the currents its loops see (with HFI the fundamental).
//!
//! ## In every fourth period
//! The check runs in one period of [`CHECK_PERIODS`] (4), its filters at the rate
//! `4 Ts / tau` and its persistence counted in checks. The measured and the reference
//! magnitudes are sampled at the same instants, so a healthy phase's ratio stays near 1
//! whatever the speed (no aliasing can part the two), and the filter's passband, a few
//! hertz for `tau` = 10 ms, is far below the 2.5 kHz it is sampled at. The trip comes
//! within a check (0.4 ms at 10 kHz) of where it would every period. A check is about
//! twenty multiplications and comparisons, no division; the periods between pay only
//! the count (`docs/cost-budget.md` has what that saves the step).

#![forbid(unsafe_code)]

use crate::algorithms::transforms::Abc;
use crate::num::Scalar;

/// Periods per check: the check runs in one of every `CHECK_PERIODS` (module docs).
const CHECK_PERIODS: u32 = 4;

/// The phase-loss check's state (see the module docs). Working units throughout.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PhaseLoss<T> {
    /// Rate of the low-pass per check, `CHECK_PERIODS Ts / tau` (dimensionless, at most
    /// 1).
    rate: T,
    /// Reference magnitude a phase must average to be judged (A).
    threshold: T,
    /// Checks a lost phase must persist for before it trips.
    checks: u32,
    /// Periods since the last check, `0..CHECK_PERIODS`.
    since_check: u32,
    /// Measured current magnitudes, low-passed (A; a, b, c).
    current_mean: [T; 3],
    /// Reference current magnitudes, low-passed alike (A; a, b, c).
    reference_mean: [T; 3],
    /// Consecutive checks with a lost phase.
    count: u32,
}

impl<T: Scalar> PhaseLoss<T> {
    /// A check for the control period over the filter's time constant `period_per_tau`
    /// (`Ts / tau`, dimensionless; the rate per check is [`CHECK_PERIODS`] times it,
    /// clamped to 1), the reference `threshold` (A) and the persistence `samples`
    /// (periods, counted in whole checks: `samples / CHECK_PERIODS`).
    pub(crate) fn new(period_per_tau: f32, threshold: T, samples: u32) -> Self {
        let rate = T::from_f32(CHECK_PERIODS as f32 * period_per_tau);
        PhaseLoss {
            rate: rate.clamp_to(T::ZERO, T::ONE),
            threshold,
            checks: samples / CHECK_PERIODS,
            since_check: 0,
            current_mean: [T::ZERO; 3],
            reference_mean: [T::ZERO; 3],
            count: 0,
        }
    }

    /// Forgets the history (a new start).
    pub(crate) fn reset(&mut self) {
        self.current_mean = [T::ZERO; 3];
        self.reference_mean = [T::ZERO; 3];
        self.count = 0;
        self.since_check = 0;
    }

    /// Counts one period: `true` in the period the check runs in (one of every
    /// [`CHECK_PERIODS`]), which starts the count again.
    pub(crate) fn due(&mut self) -> bool {
        self.since_check += 1;
        let due = self.since_check >= CHECK_PERIODS;
        if due {
            self.since_check = 0;
        }
        due
    }

    /// One check: the measured phase currents and the reference phase currents (A).
    /// `true` once a phase has been lost for longer than the persistence.
    pub(crate) fn update(&mut self, measured: Abc<T>, reference: Abc<T>) -> bool {
        let rate = self.rate;
        // rate <= 1 (clamped in `new`).
        let follow = |mean: &mut T, x: T| *mean = *mean + (x.abs() - *mean).mul_unit(rate);
        let [ma, mb, mc] = &mut self.current_mean;
        follow(ma, measured.a);
        follow(mb, measured.b);
        follow(mc, measured.c);
        let [ra, rb, rc] = &mut self.reference_mean;
        follow(ra, reference.a);
        follow(rb, reference.b);
        follow(rc, reference.c);
        let ([ma, mb, mc], [ra, rb, rc]) = (self.current_mean, self.reference_mean);
        let threshold = self.threshold;
        let carries = |m: T, r: T| m >= r.mul_unit(T::HALF);
        let starved = |m: T, r: T| r > threshold && m * T::TWO * T::TWO < r;
        let lost = (starved(ma, ra) && (carries(mb, rb) || carries(mc, rc)))
            || (starved(mb, rb) && (carries(ma, ra) || carries(mc, rc)))
            || (starved(mc, rc) && (carries(ma, ra) || carries(mb, rb)));
        self.count = if lost { self.count.saturating_add(1) } else { 0 };
        self.count > self.checks
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::num::Q24;
    use core::f64::consts::PI;

    const TS: f64 = 1e-4;
    const TAU: f64 = 0.01;
    const THRESHOLD: f64 = 0.3;
    const SAMPLES: u32 = 50;

    fn check<T: Scalar>() -> PhaseLoss<T> {
        PhaseLoss::new((TS / TAU) as f32, T::from_f32(THRESHOLD as f32), SAMPLES)
    }

    /// Balanced phase currents of amplitude `amp` (A) at `hz`, at sample `n`.
    fn phases(amp: f64, hz: f64, n: usize) -> [f64; 3] {
        let th = 2.0 * PI * hz * n as f64 * TS;
        [0.0, -2.0 * PI / 3.0, 2.0 * PI / 3.0].map(|o| amp * (th + o).cos())
    }

    fn abc<T: Scalar>(x: [f64; 3]) -> Abc<T> {
        Abc { a: T::from_f32(x[0] as f32), b: T::from_f32(x[1] as f32), c: T::from_f32(x[2] as f32) }
    }

    /// Runs `seconds`; `measured(n, reference)` gives the measurement. The sample at
    /// which the check first trips, if it does.
    fn run<T: Scalar>(
        seconds: f64,
        reference: impl Fn(usize) -> [f64; 3],
        measured: impl Fn(usize, [f64; 3]) -> [f64; 3],
    ) -> Option<usize> {
        let mut c = check::<T>();
        (0..(seconds / TS) as usize).find(|&n| {
            let r = reference(n);
            c.due() && c.update(abc(measured(n, r)), abc(r))
        })
    }

    /// A deterministic +-`amp` noise (A), uncorrelated with the phases.
    fn noise(n: usize, k: usize, amp: f64) -> f64 {
        let x = ((n * 7919 + k * 104_729) % 1000) as f64 / 1000.0;
        amp * (2.0 * x - 1.0)
    }

    #[test]
    fn healthy_phases_never_trip_at_any_speed_with_noise_and_at_standstill() {
        // 0 Hz: a parked current vector (one phase's reference at 0, the others at
        // +-0.87 amp); then 0.5 to 67 Hz, the paper motor's range and below.
        for hz in [0.0, 0.5, 3.3, 10.0, 40.0, 67.0] {
            for amp in [0.2, 1.0, 6.0] {
                let tripped = run::<f32>(
                    1.0,
                    |n| phases(amp, hz, n),
                    |n, r| [0, 1, 2].map(|k| r[k] * 0.97 + noise(n, k, 0.05)),
                );
                assert_eq!(tripped, None, "{hz} Hz, {amp} A");
            }
        }
    }

    #[test]
    fn all_phases_short_of_their_reference_alike_is_left_to_the_saturation_check() {
        // The bridge delivering a third of what is asked on every phase (the voltage on
        // its limit): no phase carries half of its reference, so none is "lost".
        let tripped = run::<f32>(1.0, |n| phases(3.0, 40.0, n), |_, r| r.map(|x| x / 3.0));
        assert_eq!(tripped, None);
    }

    #[test]
    fn a_reference_below_the_threshold_is_not_judged() {
        // 0.25 A peak: no phase's reference magnitude, filtered or not, reaches 0.3 A.
        let tripped = run::<f32>(1.0, |n| phases(0.25, 10.0, n), |_, r| [0.0, r[1], r[2]]);
        assert_eq!(tripped, None);
    }

    /// The window of trip samples the module docs predict for a phase lost at sample 0
    /// of a steady state at `hz`. The phase's mean decays as `(1 - 4 Ts/tau)^(n/4)` from
    /// where it was, which is its reference's mean (measured = reference before), read
    /// at the checks (up to a check later), and must fall below a quarter of the
    /// reference's mean, then persist for `SAMPLES / 4 + 1` more checks. Both
    /// means ripple about `M = (2/pi) amp`: `|cos|` has `2/3 M` at `2 f` and `2/15 M` at
    /// `4 f`, through the low-pass `1 / |1 + j w tau|`, so each is within `M (1 +- e)`
    /// and the ratio crossed at `(1 - e)/(4 (1 + e))` to `(1 + e)/(4 (1 - e))`.
    fn predicted_trip_window(hz: f64) -> (f64, f64) {
        let lp = |f: f64| 1.0 / (1.0 + (2.0 * PI * f * TAU).powi(2)).sqrt();
        let e = 2.0 / 3.0 * lp(2.0 * hz) + 2.0 / 15.0 * lp(4.0 * hz);
        let periods = f64::from(CHECK_PERIODS);
        let per_sample = -(1.0 - periods * TS / TAU).ln() / periods;
        let spread = ((1.0 + e) / (1.0 - e)).ln();
        let persist = f64::from(SAMPLES / CHECK_PERIODS) * periods;
        let at = |x: f64| x / per_sample + persist;
        (at(4f64.ln() - spread), at(4f64.ln() + spread) + periods)
    }

    fn open_phase_trips_when_predicted<T: Scalar>() {
        for (phase, hz) in [(0, 40.0), (1, 67.0), (2, 25.0)] {
            // 0.5 s healthy (the means settle), then the phase opens.
            let open_at = 5000;
            let tripped = run::<T>(
                1.0,
                |n| phases(2.0, hz, n),
                |n, r| {
                    let mut m = r;
                    if n >= open_at {
                        // Its current is zero; the other two carry the vector on a line.
                        let lost = m[phase];
                        m[phase] = 0.0;
                        m[(phase + 1) % 3] += lost / 2.0;
                        m[(phase + 2) % 3] += lost / 2.0;
                    }
                    m
                },
            )
            .expect("an open phase trips");
            let after = (tripped - open_at) as f64;
            let (first, last) = predicted_trip_window(hz);
            assert!(
                first <= after && after <= last + 1.0,
                "phase {phase} at {hz} Hz: {after} not in {first}..{last}"
            );
        }
    }

    #[test]
    fn an_open_phase_trips_when_the_analysis_says_in_f32() {
        open_phase_trips_when_predicted::<f32>();
    }

    #[test]
    fn an_open_phase_trips_when_the_analysis_says_in_q24() {
        open_phase_trips_when_predicted::<Q24>();
    }

    #[test]
    fn reset_forgets_the_history() {
        let mut c = check::<f32>();
        let tripped = (0..5000).find(|&n| {
            let r = phases(2.0, 40.0, n);
            c.due() && c.update(abc([0.0, r[1], r[2]]), abc(r))
        });
        assert!(tripped.is_some(), "phase a never carried: trips");
        c.reset();
        assert_eq!((c.current_mean, c.reference_mean, c.count, c.since_check), ([0.0; 3], [0.0; 3], 0, 0));
        let r = phases(2.0, 40.0, 0);
        assert!(!c.update(abc(r), abc(r)));
    }
}
