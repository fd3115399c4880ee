//! A capture downloaded from the drive ([`CaptureData`]: the drive's own words and their
//! [`CaptureFormat`]) as a trace in the trace format (docs/trace-format.md): `t`,
//! `u_alpha`, `u_beta`, `i_alpha`, `i_beta` and the commanded acceleration `alpha_e_ref`
//! (see [`crate::trace::COMMANDED_ACCEL_COLUMN`]); SI as `f64`, which for Q8.24 words
//! converts back to the same bits; comment lines name the number type. It starts at the
//! estimator's reset, so that `dcfo replay` (`--numeric q24` for the M3 image)
//! reproduces the drive's own estimates, which [`replay_matches`] checks bit for bit.

use std::path::Path;

use dcfo::algorithms::observer::ObserverKind;
use dcfo::capture::{Capture, CaptureFormat, CaptureSample, Quantity, SiSample};
use dcfo::motor::MotorParams;

use crate::commands::replay::{replay_trace_as, working_base};
use crate::trace::{COMMANDED_ACCEL_COLUMN, GroundTruth, InputTrace, InputTraceWriter, TraceRow};

/// A capture as downloaded: the drive's words and how they read.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CaptureData {
    /// The drive's number type and working units (the base then follows from the
    /// motor: [`working_base`]).
    pub format: CaptureFormat,
    /// The samples, from the estimator's first step.
    pub samples: Vec<CaptureSample>,
}

impl CaptureData {
    /// What `capture` holds (e.g. a drive run in this process).
    pub fn from_capture<const N: usize>(capture: &Capture<N>) -> Self {
        CaptureData {
            format: capture.format(),
            samples: (0..capture.len()).filter_map(|k| capture.sample(k).copied()).collect(),
        }
    }
}

/// The comment lines of a capture's trace: what was recorded, the number type and
/// working units, and the replay that reproduces it.
pub fn capture_comments(data: &CaptureData, motor: &MotorParams) -> Vec<String> {
    let base = working_base(data.format, motor);
    let units = match data.format {
        CaptureFormat::F32 => "f32 in SI units".to_string(),
        CaptureFormat::Q24 => format!(
            "Q8.24 in the motor's per-unit base (voltage {} V, current {} A, omega {} rad/s); \
             each value is exactly bits * 2^-24 * base as f64",
            base.voltage_v, base.current_a, base.omega_rad_s
        ),
    };
    vec![
        format!("dcfo capture: {} samples from the estimator's start", data.samples.len()),
        format!("numeric: {} ({units})", data.format.name()),
        format!(
            "replay bit for bit: dcfo replay --numeric {} --observer dcfo --motor <the drive's motor>",
            data.format.name()
        ),
    ]
}

/// The capture as a trace in the trace format (docs/trace-format.md): row `k` at `t = k Ts` (the estimator's
/// first step is `t = 0`), in SI ([`CaptureFormat::to_si`] in the working units of
/// `motor`), with the commanded acceleration column.
///
/// # Errors
/// Fewer than two samples, or a value the trace format refuses.
pub fn capture_trace(data: &CaptureData, motor: &MotorParams, period_s: f64) -> anyhow::Result<InputTrace> {
    let base = working_base(data.format, motor);
    let si: Vec<_> = data.samples.iter().map(|s| s.to_si(data.format, &base)).collect();
    let rows = si.iter().enumerate().map(|(k, s)| capture_row(k, s, period_s)).collect();
    let accel = si.iter().map(|s| s.alpha_e_ref).collect();
    Ok(InputTrace::from_rows(rows, "capture")?.with_commanded_acceleration(accel, "capture")?)
}

fn capture_row(k: usize, s: &SiSample, period_s: f64) -> TraceRow {
    TraceRow {
        t: k as f64 * period_s,
        u_alpha: s.u_alpha,
        u_beta: s.u_beta,
        i_alpha: s.i_alpha,
        i_beta: s.i_beta,
        theta: None,
        v: None,
        x: None,
    }
}

/// Writes the capture to `path` as a trace (see [`capture_trace`]; the comment lines of
/// [`capture_comments`] first), atomically.
///
/// # Errors
/// As [`InputTraceWriter`]: the file, the line and the column.
pub fn write_capture_trace(
    path: &Path,
    data: &CaptureData,
    motor: &MotorParams,
    period_s: f64,
) -> anyhow::Result<()> {
    let base = working_base(data.format, motor);
    let comments = capture_comments(data, motor);
    let comments: Vec<&str> = comments.iter().map(String::as_str).collect();
    let mut w = InputTraceWriter::create_with_comments(
        path,
        GroundTruth::NONE,
        &[COMMANDED_ACCEL_COLUMN],
        &comments,
    )?;
    for (k, s) in data.samples.iter().enumerate() {
        let s = s.to_si(data.format, &base);
        w.write(&capture_row(k, &s, period_s), &[s.alpha_e_ref])?;
    }
    w.finish()?;
    Ok(())
}

/// How a replay compares with the drive's own estimates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Comparison {
    /// Samples whose angle, speed or flux estimate differs in any bit.
    pub differing: usize,
    /// The first of them (0 is the estimator's first step), `None` when identical.
    pub first_differing: Option<usize>,
}

impl Comparison {
    /// Every sample identical (and there was at least one).
    pub fn identical(&self, samples: usize) -> bool {
        self.differing == 0 && samples > 0
    }
}

/// Replays `trace` through the estimator of `motor` (DCFO, in the capture's number
/// type: what `dcfo replay --numeric` runs) and compares, sample by sample, the angle,
/// speed and flux estimates with what the drive estimated on the target: the same words
/// bit for bit (compared in SI as `f64`, which is one to one with the words).
///
/// # Errors
/// The replay refused the trace.
pub fn replay_matches(
    trace: &InputTrace,
    motor: &MotorParams,
    data: &CaptureData,
) -> anyhow::Result<Comparison> {
    let replayed = replay_trace_as(trace, motor, ObserverKind::Dcfo, data.format)?;
    anyhow::ensure!(
        replayed.len() == data.samples.len(),
        "replay gave {} rows for {} samples",
        replayed.len(),
        data.samples.len()
    );
    let base = working_base(data.format, motor);
    let si = |w: u32, q: Quantity| data.format.to_si(w, q, &base).to_bits();
    let mut cmp = Comparison::default();
    for (k, (r, s)) in replayed.iter().zip(&data.samples).enumerate() {
        let same = r.theta_hat.to_bits() == s.theta_hat.to_radians::<f64>().to_bits()
            && r.v_hat.to_bits() == si(s.v_hat, Quantity::Speed)
            && r.psi_alpha_hat.to_bits() == si(s.psi_alpha_hat, Quantity::Flux)
            && r.psi_beta_hat.to_bits() == si(s.psi_beta_hat, Quantity::Flux);
        if !same {
            cmp.differing += 1;
            cmp.first_differing.get_or_insert(k);
        }
    }
    Ok(cmp)
}
