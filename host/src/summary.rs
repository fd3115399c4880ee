//! The replay summary: error statistics of an observer's output against ground truth.
//!
//! Computed over the samples with `t >= t_first + settle` (default
//! [`DEFAULT_SETTLE_S`]); to keep a sample printed exactly on that boundary from being
//! lost to rounding, the comparison allows a millionth of the sample period.
//!
//! - `theta_err_*_deg`: `theta - theta_hat` wrapped to (-pi, pi], in electrical
//!   degrees; RMS and maximum absolute value.
//! - `v_err_*`: `v - v_hat`, m/s; RMS and maximum absolute value.
//! - `psi_amp_err_rms_wb`: RMS of `|psi_hat| - psi_f_wb`, Wb, with `psi_f_wb` from
//!   the motor. With `ld_h != lq_h` the observers estimate the active flux, whose
//!   amplitude is `psi_f + (Ld - Lq) i_d`; this statistic still compares with
//!   `psi_f`, so it then includes that (known) difference.
//!
//! When the trace has no `theta` (or no `v`), the angle (or speed) statistics are
//! `None`, serialised as JSON `null`: never a made-up number. The flux statistic
//! needs no ground truth and is always present.
//!
//! Refused with a [`SummaryError`]: a settle time that is negative or not finite, a
//! settle time that leaves no samples, a number of estimates different from the number
//! of trace rows, and a non-finite estimate inside the window (a diverged observer has
//! no meaningful RMS, and JSON cannot carry NaN).

use std::fmt;

use dcfo::motor::MotorParams;
use serde::Serialize;

use crate::trace::{Estimate, InputTrace};

/// Default settle time, s: samples before `t_first + 0.5 s` are left out.
pub const DEFAULT_SETTLE_S: f64 = 0.5;

/// Error statistics of a replay. Field names are the JSON keys.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// Number of samples the statistics are computed over (after the settle time).
    pub samples: usize,
    /// Settle time used, s.
    pub settle_s: f64,
    /// RMS angle error, electrical degrees; `None` without ground-truth `theta`.
    pub theta_err_rms_deg: Option<f64>,
    /// Maximum absolute angle error, electrical degrees; `None` without `theta`.
    pub theta_err_max_deg: Option<f64>,
    /// RMS speed error, m/s; `None` without ground-truth `v`.
    pub v_err_rms: Option<f64>,
    /// Maximum absolute speed error, m/s; `None` without `v`.
    pub v_err_max: Option<f64>,
    /// RMS of the flux amplitude error `|psi_hat| - psi_f_wb`, Wb.
    pub psi_amp_err_rms_wb: f64,
    /// Samples claiming lock with the angle more than 15 electrical degrees off
    /// ([`crate::trace::FALSE_LOCK_ERROR_RAD`]); `None` without ground-truth `theta`.
    pub false_lock_samples: Option<usize>,
}

/// Why a summary could not be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SummaryError {
    /// The settle time is negative, NaN or infinite.
    #[error("settle time {settle_s} s must be a finite number >= 0")]
    BadSettle {
        /// The settle time given, s.
        settle_s: f64,
    },
    /// No sample is at or after `t_first + settle`.
    #[error(
        "settle time {settle_s} s leaves no samples: the trace spans only {span_s} s (t = {t_first} .. {t_last} s)"
    )]
    NoSamples {
        /// The settle time given, s.
        settle_s: f64,
        /// `t_last - t_first`, s.
        span_s: f64,
        /// First sample time, s.
        t_first: f64,
        /// Last sample time, s.
        t_last: f64,
    },
    /// The number of estimates differs from the number of trace rows.
    #[error("{estimates} estimates for {rows} trace rows; need one per row")]
    RowCount {
        /// Trace rows.
        rows: usize,
        /// Estimates given.
        estimates: usize,
    },
    /// An estimate inside the window is NaN or infinite.
    #[error("estimate `{column}` is {value} at t = {t} s (sample {index}): the observer diverged")]
    NotFinite {
        /// The estimate's name (`theta_hat`, `v_hat`, `psi_alpha_hat`, `psi_beta_hat`).
        column: &'static str,
        /// Its value.
        value: f64,
        /// Sample time, s.
        t: f64,
        /// 0-based sample index.
        index: usize,
    },
}

/// Running sum of squares and maximum absolute value.
#[derive(Default)]
struct Stat {
    n: usize,
    sum_sq: f64,
    max_abs: f64,
}

impl Stat {
    fn add(&mut self, x: f64) {
        self.n += 1;
        self.sum_sq += x * x;
        self.max_abs = self.max_abs.max(x.abs());
    }

    fn rms(&self) -> Option<f64> {
        (self.n > 0).then(|| (self.sum_sq / self.n as f64).sqrt())
    }

    fn max(&self) -> Option<f64> {
        (self.n > 0).then_some(self.max_abs)
    }
}

impl Summary {
    /// Computes the summary of `estimates` (one per row of `trace`, in order) against
    /// the trace's ground truth, over samples with `t >= t_first + settle_s`.
    pub fn compute(
        trace: &InputTrace,
        estimates: &[Estimate],
        motor: &MotorParams,
        settle_s: f64,
    ) -> Result<Summary, SummaryError> {
        if !(settle_s.is_finite() && settle_s >= 0.0) {
            return Err(SummaryError::BadSettle { settle_s });
        }
        let rows = trace.rows();
        if rows.len() != estimates.len() {
            return Err(SummaryError::RowCount { rows: rows.len(), estimates: estimates.len() });
        }
        let (t_first, t_last) = match (rows.first(), rows.last()) {
            (Some(first), Some(last)) => (first.t, last.t),
            _ => (f64::NAN, f64::NAN), // unreachable: a trace has at least 2 rows
        };
        let start = t_first + settle_s - 1e-6 * trace.sample_period_s();
        let psi_f = f64::from(motor.psi_f_wb);
        let (mut theta, mut v, mut psi) = (Stat::default(), Stat::default(), Stat::default());
        let mut false_locks: Option<usize> = None;
        for (index, (row, est)) in rows.iter().zip(estimates).enumerate() {
            if row.t < start {
                continue;
            }
            for (column, value) in [
                ("theta_hat", est.theta_hat),
                ("v_hat", est.v_hat),
                ("psi_alpha_hat", est.psi_alpha_hat),
                ("psi_beta_hat", est.psi_beta_hat),
            ] {
                if !value.is_finite() {
                    return Err(SummaryError::NotFinite { column, value, t: row.t, index });
                }
            }
            if let Some(e) = est.theta_err(row) {
                theta.add(e.to_degrees());
            }
            if let Some(e) = est.v_err(row) {
                v.add(e);
            }
            if let Some(false_lock) = est.false_lock(row) {
                *false_locks.get_or_insert(0) += usize::from(false_lock);
            }
            psi.add(est.psi_amplitude() - psi_f);
        }
        let Some(psi_amp_err_rms_wb) = psi.rms() else {
            return Err(SummaryError::NoSamples { settle_s, span_s: t_last - t_first, t_first, t_last });
        };
        Ok(Summary {
            samples: psi.n,
            settle_s,
            theta_err_rms_deg: theta.rms(),
            theta_err_max_deg: theta.max(),
            v_err_rms: v.rms(),
            v_err_max: v.max(),
            psi_amp_err_rms_wb,
            false_lock_samples: false_locks,
        })
    }

    /// The summary as one JSON object on one line (absent statistics are `null`).
    pub fn to_json(&self) -> String {
        // Serialising plain numbers and options cannot fail (non-finite numbers would
        // become `null`, but `compute` never produces them).
        serde_json::to_string(self).expect("a Summary always serialises")
    }
}

/// Four significant digits, without exponent for everyday magnitudes.
fn sig4(x: f64) -> String {
    let a = x.abs();
    if a == 0.0 {
        "0".to_string()
    } else if (1e-3..1e5).contains(&a) {
        let decimals = (3 - a.log10().floor() as i32).max(0) as usize;
        format!("{x:.decimals$}")
    } else {
        format!("{x:.3e}")
    }
}

fn pair(rms: Option<f64>, max: Option<f64>, unit: &str, column: &str) -> String {
    match (rms, max) {
        (Some(r), Some(m)) => format!("rms {} {unit}, max {} {unit}", sig4(r), sig4(m)),
        _ => format!("n/a (trace has no `{column}` column)"),
    }
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "{} samples after {} s settle", self.samples, self.settle_s)?;
        writeln!(
            f,
            "  angle error (electrical):  {}",
            pair(self.theta_err_rms_deg, self.theta_err_max_deg, "deg", "theta")
        )?;
        writeln!(f, "  speed error:  {}", pair(self.v_err_rms, self.v_err_max, "m/s", "v"))?;
        writeln!(f, "  flux amplitude error:  rms {} Wb", sig4(self.psi_amp_err_rms_wb))?;
        match self.false_lock_samples {
            Some(n) => write!(f, "  false-lock samples (locked, > 15 deg off):  {n}"),
            None => write!(f, "  false-lock samples:  n/a (trace has no `theta` column)"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::TraceRow;
    use std::f64::consts::PI;

    const TS: f64 = 1e-3;

    /// A trace of `n` rows at 1 kHz from t = 2 s, with the chosen ground truth.
    fn trace(n: usize, theta: impl Fn(f64) -> Option<f64>, v: impl Fn(f64) -> Option<f64>) -> InputTrace {
        let rows = (0..n)
            .map(|k| {
                let t = 2.0 + k as f64 * TS;
                TraceRow {
                    t,
                    u_alpha: 0.0,
                    u_beta: 0.0,
                    i_alpha: 0.0,
                    i_beta: 0.0,
                    theta: theta(t),
                    v: v(t),
                    x: None,
                }
            })
            .collect();
        InputTrace::from_rows(rows, "mem").unwrap()
    }

    fn motor() -> MotorParams {
        MotorParams::paper()
    }

    /// Estimates with angle `theta - dtheta(t)`, speed `v - dv(t)`, flux amplitude `amp`.
    fn estimates(
        tr: &InputTrace,
        dtheta: impl Fn(f64) -> f64,
        dv: impl Fn(f64) -> f64,
        amp: f64,
    ) -> Vec<Estimate> {
        tr.rows()
            .iter()
            .map(|r| {
                let theta_hat = r.theta.unwrap_or(0.0) - dtheta(r.t);
                Estimate {
                    theta_hat,
                    v_hat: r.v.unwrap_or(0.0) - dv(r.t),
                    psi_alpha_hat: amp * theta_hat.cos(),
                    psi_beta_hat: amp * theta_hat.sin(),
                    locked: true,
                }
            })
            .collect()
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn constant_errors() {
        let tr = trace(1000, |t| Some(20.0 * t), |_| Some(0.3));
        let est = estimates(&tr, |_| 1f64.to_radians(), |_| -0.01, 0.17);
        let s = Summary::compute(&tr, &est, &motor(), DEFAULT_SETTLE_S).unwrap();
        assert_eq!(s.samples, 500); // t = 2.5 .. 2.999 s
        let (rms, max) = (s.theta_err_rms_deg.unwrap(), s.theta_err_max_deg.unwrap());
        assert!(close(rms, 1.0, 1e-9) && close(max, 1.0, 1e-9), "{rms} {max}");
        let (rms, max) = (s.v_err_rms.unwrap(), s.v_err_max.unwrap());
        assert!(close(rms, 0.01, 1e-12) && close(max, 0.01, 1e-12), "{rms} {max}");
        // psi_f is the f32 0.16 of the motor: 0.01 Wb off within f32 rounding.
        assert!(close(s.psi_amp_err_rms_wb, 0.01, 1e-8), "{}", s.psi_amp_err_rms_wb);
    }

    #[test]
    fn sinusoidal_error_over_whole_periods() {
        // 10 Hz error of amplitude 2 deg and 0.05 m/s; the 0.5 s window holds 5 periods.
        let a_deg: f64 = 2.0;
        let tr = trace(1000, |t| Some(-7.0 + 3.0 * t), |t| Some(t.sin()));
        let est = estimates(
            &tr,
            |t| a_deg.to_radians() * (2.0 * PI * 10.0 * t).sin(),
            |t| 0.05 * (2.0 * PI * 10.0 * t).cos(),
            0.16,
        );
        let s = Summary::compute(&tr, &est, &motor(), 0.5).unwrap();
        assert_eq!(s.samples, 500);
        assert!(close(s.theta_err_rms_deg.unwrap(), a_deg / 2f64.sqrt(), 1e-9), "{:?}", s.theta_err_rms_deg);
        assert!(close(s.theta_err_max_deg.unwrap(), a_deg, 1e-9), "{:?}", s.theta_err_max_deg);
        assert!(close(s.v_err_rms.unwrap(), 0.05 / 2f64.sqrt(), 1e-12));
        assert!(close(s.v_err_max.unwrap(), 0.05, 1e-12));
        assert!(s.psi_amp_err_rms_wb < 1e-8);
    }

    #[test]
    fn settle_excludes_the_start_and_keeps_the_boundary_sample() {
        // Error of 90 deg before t = 2.3 s, 0 from then on.
        let tr = trace(400, |_| Some(0.5), |_| Some(0.0));
        let est = estimates(&tr, |t| if t < 2.3 - TS / 2.0 { PI / 2.0 } else { 0.0 }, |_| 0.0, 0.16);
        let s = Summary::compute(&tr, &est, &motor(), 0.3).unwrap();
        assert_eq!(s.samples, 100); // 2.3 s (boundary, 2.0 + 300 * 1e-3) .. 2.399 s
        assert!(s.theta_err_max_deg.unwrap() < 1e-9);
        let s = Summary::compute(&tr, &est, &motor(), 0.0).unwrap();
        assert_eq!(s.samples, 400);
        assert!(close(s.theta_err_max_deg.unwrap(), 90.0, 1e-9));
        assert!(close(s.theta_err_rms_deg.unwrap(), 90.0 * (300f64 / 400.0).sqrt(), 1e-9));
    }

    #[test]
    fn angle_error_is_wrapped() {
        // Truth 3.1 rad, estimate -3.1 rad: the error is 6.2 - 2 pi, not 6.2.
        let tr = trace(10, |_| Some(3.1), |_| None);
        let est = estimates(&tr, |_| 6.2, |_| 0.0, 0.16);
        let s = Summary::compute(&tr, &est, &motor(), 0.0).unwrap();
        assert!(close(s.theta_err_max_deg.unwrap(), (2.0 * PI - 6.2).to_degrees(), 1e-9));
    }

    #[test]
    fn missing_ground_truth_gives_null_not_numbers() {
        let tr = trace(10, |_| None, |_| None);
        let est = estimates(&tr, |_| 0.0, |_| 0.0, 0.15);
        let s = Summary::compute(&tr, &est, &motor(), 0.0).unwrap();
        assert_eq!(
            (s.theta_err_rms_deg, s.theta_err_max_deg, s.v_err_rms, s.v_err_max),
            (None, None, None, None)
        );
        let json: serde_json::Value = serde_json::from_str(&s.to_json()).unwrap();
        let obj = json.as_object().unwrap();
        for key in ["theta_err_rms_deg", "theta_err_max_deg", "v_err_rms", "v_err_max", "false_lock_samples"]
        {
            assert!(obj[key].is_null(), "{key}");
        }
        assert_eq!(obj["samples"], 10);
        assert!(close(obj["psi_amp_err_rms_wb"].as_f64().unwrap(), 0.01, 1e-8));
        let text = s.to_string();
        assert!(text.contains("10 samples"), "{text}");
        assert!(text.contains("n/a (trace has no `theta` column)"), "{text}");
        assert!(text.contains("n/a (trace has no `v` column)"), "{text}");

        // Only `v`: the angle statistics stay null, the speed ones are numbers.
        let tr = trace(10, |_| None, |_| Some(1.0));
        let s = Summary::compute(&tr, &estimates(&tr, |_| 0.0, |_| 0.5, 0.16), &motor(), 0.0).unwrap();
        assert_eq!((s.theta_err_rms_deg, s.v_err_max), (None, Some(0.5)));
    }

    #[test]
    fn json_has_every_key_and_display_is_short() {
        let tr = trace(1000, Some, |_| Some(0.3));
        let s = Summary::compute(&tr, &estimates(&tr, |_| 0.001, |_| 0.002, 0.161), &motor(), 0.5).unwrap();
        let json: serde_json::Value = serde_json::from_str(&s.to_json()).unwrap();
        for key in [
            "samples",
            "theta_err_rms_deg",
            "theta_err_max_deg",
            "v_err_rms",
            "v_err_max",
            "psi_amp_err_rms_wb",
            "false_lock_samples",
        ] {
            assert!(json[key].is_number(), "{key}: {json}");
        }
        assert_eq!(json["false_lock_samples"], 0);
        assert!(!s.to_json().contains('\n'));
        let text = s.to_string();
        assert!(text.contains("rms 0.05730 deg"), "{text}");
        assert!(text.contains("max 0.002000 m/s"), "{text}");
        assert_eq!(text.lines().count(), 5);
    }

    #[test]
    fn false_locks_are_locked_samples_more_than_15_degrees_off() {
        // The error steps 14 -> 16 deg at t = 2.5 s (sample 500); the estimate claims lock
        // on odd samples only: 250 of the 500 samples after the step are false locks, and
        // the settle window (from 2.2 s) does not change that.
        let tr = trace(1000, |_| Some(1.0), |_| Some(0.3));
        let mut est =
            estimates(&tr, |t| if t < 2.5 - 1e-9 { 14f64 } else { 16.0 }.to_radians(), |_| 0.0, 0.16);
        for (k, e) in est.iter_mut().enumerate() {
            e.locked = k % 2 == 1;
        }
        for settle in [0.0, 0.2] {
            let s = Summary::compute(&tr, &est, &motor(), settle).unwrap();
            assert_eq!(s.false_lock_samples, Some(250), "settle {settle}");
        }
        // Without ground-truth angle there is nothing to judge.
        let tr = trace(10, |_| None, |_| Some(0.3));
        let s = Summary::compute(&tr, &estimates(&tr, |_| 0.0, |_| 0.0, 0.16), &motor(), 0.0).unwrap();
        assert_eq!(s.false_lock_samples, None);
    }

    #[test]
    fn refusals() {
        let tr = trace(100, |_| Some(0.0), |_| Some(0.0));
        let est = estimates(&tr, |_| 0.0, |_| 0.0, 0.16);
        let e = Summary::compute(&tr, &est, &motor(), 0.2).unwrap_err();
        assert!(matches!(e, SummaryError::NoSamples { .. }), "{e}");
        assert!(e.to_string().contains("leaves no samples"), "{e}");
        for bad in [-0.1, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                Summary::compute(&tr, &est, &motor(), bad),
                Err(SummaryError::BadSettle { .. })
            ));
        }
        let e = Summary::compute(&tr, &est[..99], &motor(), 0.0).unwrap_err();
        assert_eq!(e, SummaryError::RowCount { rows: 100, estimates: 99 });

        // A diverged estimate inside the window is refused; before it, ignored.
        let mut est = est;
        est[10].psi_beta_hat = f64::NAN;
        let e = Summary::compute(&tr, &est, &motor(), 0.0).unwrap_err();
        assert!(e.to_string().contains("`psi_beta_hat` is NaN at t = 2.01 s (sample 10)"), "{e}");
        assert!(Summary::compute(&tr, &est, &motor(), 0.05).is_ok());
    }
}
