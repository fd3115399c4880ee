//! The figures of a simulated run over its scenario's measurement window: angle error,
//! speed error, lock, ripple ([`figures`]).

use super::scenarios::Scenario;
use super::{Run, Sample, theta_err_deg};

/// The figures of one run over its measurement window.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Figures {
    /// Max |theta - theta_hat|, electrical degrees.
    pub theta_err_max_deg: f64,
    /// RMS of theta - theta_hat, electrical degrees.
    pub theta_err_rms_deg: f64,
    /// Max |v - v_hat|, m/s.
    pub v_err_max: f64,
    /// Largest DC component (one-period moving average) of the flux estimate, Wb: the
    /// flux "drift" of the paper's Figs. 14-16.
    pub flux_drift_wb: f64,
    /// Largest deviation of the flux amplitude (one-period moving average) from its
    /// value just before the event, Wb, over the window.
    pub flux_amp_dev_wb: f64,
    /// Lasting DC offset of the flux estimate, Wb: the magnitude of its mean vector over
    /// the last 0.5 s of the window (five periods at 0.3 m/s). For an LPF observer under
    /// a DC input `dc` (V) the analysis gives `dc / wc`; for the DCFO, zero.
    pub flux_offset_end_wb: f64,
    /// Time after the event until the flux amplitude stays within 2 mWb of its value
    /// before the event, s (`None` if it never does within the window).
    pub flux_recovery_s: Option<f64>,
    /// `true` when the run reached sensorless operation and ended without a fault.
    pub healthy: bool,
    /// Samples of the whole run in which the estimator claimed lock while the true angle
    /// error exceeded 15 electrical degrees (0 when the lock flag is not known).
    pub false_lock_samples: usize,
}

/// Measures `run` over `[event_s, event_s + window_s]` (one electrical period of
/// moving average for the flux figures).
pub fn figures(run: &Run, scenario: &Scenario) -> Figures {
    let t0 = scenario.event_s;
    let t1 = scenario.event_s + scenario.window_s;
    let in_window = |s: &&Sample| s.row.t >= t0 && s.row.t <= t1;
    let errs: Vec<f64> = run.samples.iter().filter(in_window).map(theta_err_deg).collect();
    // No sample in the window (the drive stopped reporting before it): NaN, not zero.
    let nan_if_empty = |x: f64| if errs.is_empty() { f64::NAN } else { x };
    let theta_err_max_deg = nan_if_empty(errs.iter().fold(0.0f64, |m, e| m.max(e.abs())));
    let theta_err_rms_deg =
        nan_if_empty((errs.iter().map(|e| e * e).sum::<f64>() / errs.len().max(1) as f64).sqrt());
    let v_err_max = run
        .samples
        .iter()
        .filter(in_window)
        .filter_map(|s| s.row.v.map(|v| (v - s.v_hat).abs()))
        .fold(0.0f64, f64::max);
    let v_err_max = nan_if_empty(v_err_max);
    // One-period moving averages of the flux vector and of its amplitude.
    let period_samples = |s: &Sample| -> usize {
        let v = s.row.v.unwrap_or(0.3).abs().max(0.05);
        // electrical period = 2 tau / v
        ((2.0 * run.pole_pitch_m / v) / run.period_s).round().max(1.0) as usize
    };
    let mut flux_drift_wb = 0.0f64;
    let mut amp_before = f64::NAN;
    let mut flux_amp_dev_wb = 0.0f64;
    let mut last_out_of_band: Option<f64> = None;
    let samples = &run.samples;
    // Running sums of the flux vector and amplitude, so each window's sum is a difference
    // of two (one pass, not one pass per window: a window is up to thousands of samples).
    // Their rounding, about 1e-16 of the whole run's sum, is far below the figures' digits.
    let mut prefix = Vec::with_capacity(samples.len() + 1);
    prefix.push([0.0f64; 3]);
    for w in samples {
        let [a, b, m] = prefix[prefix.len() - 1];
        prefix.push([a + w.psi_hat[0], b + w.psi_hat[1], m + w.psi_hat[0].hypot(w.psi_hat[1])]);
    }
    for (j, s) in samples.iter().enumerate() {
        let n = period_samples(s);
        if j < n {
            continue;
        }
        let (first, last) = (prefix[j + 1 - n], prefix[j + 1]);
        let (sa, sb, amp) = (last[0] - first[0], last[1] - first[1], last[2] - first[2]);
        let nn = n as f64;
        let (da, db, amp) = (sa / nn, sb / nn, amp / nn);
        if s.row.t < t0 {
            amp_before = amp;
        } else if s.row.t <= t1 {
            flux_drift_wb = flux_drift_wb.max(da.hypot(db));
            let dev = (amp - amp_before).abs();
            flux_amp_dev_wb = flux_amp_dev_wb.max(dev);
            if dev > 2e-3 {
                last_out_of_band = Some(s.row.t);
            }
        }
    }
    let tail: Vec<&Sample> = run.samples.iter().filter(|s| s.row.t > t1 - 0.5 && s.row.t <= t1).collect();
    let n_tail = tail.len().max(1) as f64;
    let mean_a = tail.iter().map(|s| s.psi_hat[0]).sum::<f64>() / n_tail;
    let mean_b = tail.iter().map(|s| s.psi_hat[1]).sum::<f64>() / n_tail;
    let flux_recovery_s = match last_out_of_band {
        None => Some(0.0),
        Some(t) if t < t1 - 0.05 => Some(t - t0),
        Some(_) => None,
    };
    Figures {
        theta_err_max_deg,
        theta_err_rms_deg,
        v_err_max,
        flux_drift_wb,
        flux_amp_dev_wb,
        flux_offset_end_wb: mean_a.hypot(mean_b),
        flux_recovery_s,
        healthy: run.handover_s.is_some() && run.faults.is_empty(),
        false_lock_samples: run
            .samples
            .iter()
            .filter(|s| s.locked == Some(true) && theta_err_deg(s).abs() > 15.0)
            .count(),
    }
}
