//! Trace replay: runs the drive's estimator (flux observer + PLL) over an input trace.
//!
//! [`replay_trace`] is the whole algorithm; the `dcfo replay` command (see
//! [`run_command`]) adds file I/O, the summary and a progress bar around it.
//!
//! # Semantics (bit-exact with the closed-loop simulator)
//!
//! The estimator is [`dcfo::estimator::Estimator<f32>`] in SI units ([`Base::SI`]) with
//! [`EstimatorConfig::for_motor`], exactly as the drive runs it; or, with
//! [`CaptureFormat::Q24`] (`dcfo replay --numeric q24`), `Estimator<Q24>` in the motor's
//! per-unit base ([`Base::for_motor`]), exactly as the Q8.24 drive (the M3 image) runs
//! it. For row `k` of the trace it is given:
//!
//! - `u_applied` = row `k - 1`'s `(u_alpha, u_beta)` in working units
//!   ([`CaptureFormat::from_si`]: `f32`, or the nearest Q8.24 value; a trace written
//!   from a capture holds values that convert back to the drive's exact bits): a row's voltage is the
//!   one applied during `[t_k, t_k + Ts)` (trace format), so the voltage applied
//!   during the period that ends at `t_k` is the previous row's. **Row 0 gets zero
//!   voltage**: the voltage before the trace is unknown. The first step then integrates
//!   only the resistive drop, which leaves a flux offset of at most `|u| Ts` (1.5 mWb
//!   for 15 V at 100 µs): the CFO and the DCFO remove it, a pure integrator keeps it.
//!   The last row's voltage is never used (it acts after the last sample).
//! - `i` = row `k`'s `(i_alpha, i_beta)` in working units likewise, sampled at `t_k`.
//! - the commanded acceleration, where the trace has its column, likewise.
//! - `dt` = [`InputTrace::sample_period_s`] as `f32` (s), in working units as the drive
//!   converts its control period ([`Base::time`]), the same for every row.
//!
//! Output row `k` is the estimate at `t_k`: `theta_hat` = the estimate's angle in
//! radians (in `[-pi, pi)`), `v_hat` its speed (m/s), `psi_*_hat` its mover flux
//! (Wb), each in SI as `f64` ([`CaptureFormat::to_si`]: exact for `f32`, and for Q8.24
//! a value that converts back to the same bits), and `locked` the estimator's claim
//! that the angle is valid (`Estimate::locked` of `dcfo::estimator`, 1 or 0). With
//! ground truth the summary counts the false-lock samples: locked with the angle more
//! than 15 electrical degrees off.
//!
//! A value that does not fit the number type (|x| above 3.4e38 for `f32`; 128 working
//! units for Q8.24, e.g. 23 kV on the paper motor) and an estimator fault stop the
//! replay with a [`ReplayError`] naming the data row and its time: no estimates are
//! returned, so no output can be written as if complete.

use std::fmt;
use std::path::{Path, PathBuf};

use dcfo::algorithms::observer::{ObserverFault, ObserverKind};
use dcfo::algorithms::pll::PllFault;
use dcfo::algorithms::transforms::AlphaBeta;
use dcfo::capture::{CaptureFormat, CaptureScalar, Quantity};
use dcfo::estimator::{Estimator, EstimatorConfig, EstimatorConfigError, EstimatorFault};
use dcfo::motor::MotorParams;
use dcfo::num::Q24;
use dcfo::num::units::Base;

use crate::motor_file::load_motor;
use crate::observer::observer_name;
use crate::progress::{Progress, with_spinner};
use crate::summary::Summary;
use crate::trace::{Estimate, InputTrace, TraceRow, write_output_trace};

/// How often (in rows) [`replay_trace_with_progress`] reports progress.
pub const PROGRESS_EVERY_ROWS: usize = 4096;

/// Why a replay stopped. Rows are counted from 1 over the data rows (the header and
/// comment lines are not counted); the time `t` (s) identifies the row in the file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReplayError {
    /// The estimator could not be built for this motor (a setting was refused).
    #[error("cannot build the {kind} estimator: {error:?}")]
    Config {
        /// The observer asked for.
        kind: KindName,
        /// The library's reason.
        error: EstimatorConfigError,
    },
    /// The trace's sample period is not a positive `f32` (e.g. below 1e-45 s), or not a
    /// usable working value of the number type.
    #[error("sample period {period_s} s is not a positive number in {}", numeric.name())]
    Period {
        /// The trace's sample period, s.
        period_s: f64,
        /// The estimator's number type.
        numeric: CaptureFormat,
    },
    /// A value does not fit in the estimator's number type.
    #[error(
        "data row {row} (t = {t} s), column `{column}`: {value:e} does not fit in {} ({})",
        numeric.name(),
        range_text(*numeric)
    )]
    OutOfRange {
        /// The estimator's number type.
        numeric: CaptureFormat,
        /// 1-based data row.
        row: usize,
        /// The row's time, s.
        t: f64,
        /// The column.
        column: &'static str,
        /// The value in the trace.
        value: f64,
    },
    /// The estimator refused a sample.
    #[error("data row {row} (t = {t} s): {}", describe_fault(*fault))]
    Fault {
        /// 1-based data row.
        row: usize,
        /// The row's time, s.
        t: f64,
        /// The library's fault.
        fault: EstimatorFault,
    },
}

/// An [`ObserverKind`] that prints as its command-line name (`pi`, `cfo`, `dcfo`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KindName(pub ObserverKind);

impl fmt::Display for KindName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(observer_name(self.0))
    }
}

fn describe_fault(fault: EstimatorFault) -> &'static str {
    match fault {
        EstimatorFault::Observer(ObserverFault::InvalidInput) => {
            "the observer refused the voltage or current (not a usable number)"
        }
        EstimatorFault::Observer(ObserverFault::InvalidPeriod)
        | EstimatorFault::Pll(PllFault::InvalidPeriod) => "the estimator refused the sample period",
        EstimatorFault::Observer(ObserverFault::StateOverflow) => {
            "the flux observer's state overflowed its number type (the observer diverged)"
        }
        EstimatorFault::Pll(PllFault::InvalidInput) => "the PLL refused the flux estimate (not finite)",
    }
}

fn range_text(numeric: CaptureFormat) -> &'static str {
    match numeric {
        CaptureFormat::F32 => "|x| must be below 3.4e38",
        CaptureFormat::Q24 => "|x| must be below 128 in the motor's per-unit base",
    }
}

/// The working units the drive of `motor` runs a number type in: SI for `f32`, the
/// motor's per-unit base for Q8.24 (as the firmware images do).
pub fn working_base(numeric: CaptureFormat, motor: &MotorParams) -> Base {
    match numeric {
        CaptureFormat::F32 => Base::SI,
        CaptureFormat::Q24 => Base::for_motor(motor),
    }
}

/// Replays `trace` through the `f32` estimator for `motor` with observer `kind`; one
/// estimate per row. See the module documentation for the exact semantics.
pub fn replay_trace(
    trace: &InputTrace,
    motor: &MotorParams,
    kind: ObserverKind,
) -> Result<Vec<Estimate>, ReplayError> {
    replay_trace_with_progress(trace, motor, kind, CaptureFormat::F32, |_| {})
}

/// [`replay_trace`] in the number type `numeric` (and its working units, see
/// [`working_base`]).
pub fn replay_trace_as(
    trace: &InputTrace,
    motor: &MotorParams,
    kind: ObserverKind,
    numeric: CaptureFormat,
) -> Result<Vec<Estimate>, ReplayError> {
    replay_trace_with_progress(trace, motor, kind, numeric, |_| {})
}

/// [`replay_trace_as`], calling `progress(rows_done)` every [`PROGRESS_EVERY_ROWS`] rows
/// and once at the end.
pub fn replay_trace_with_progress(
    trace: &InputTrace,
    motor: &MotorParams,
    kind: ObserverKind,
    numeric: CaptureFormat,
    progress: impl FnMut(usize),
) -> Result<Vec<Estimate>, ReplayError> {
    match numeric {
        CaptureFormat::F32 => replay_in::<f32>(trace, motor, kind, progress),
        CaptureFormat::Q24 => replay_in::<Q24>(trace, motor, kind, progress),
    }
}

fn replay_in<T: CaptureScalar>(
    trace: &InputTrace,
    motor: &MotorParams,
    kind: ObserverKind,
    mut progress: impl FnMut(usize),
) -> Result<Vec<Estimate>, ReplayError> {
    let numeric = T::FORMAT;
    let base = working_base(numeric, motor);
    let config = EstimatorConfig::for_motor(motor, kind);
    let mut est = Estimator::<T>::new(motor, &config, &base)
        .map_err(|error| ReplayError::Config { kind: KindName(kind), error })?;
    let period_s = trace.sample_period_s();
    let dt_s = period_s as f32;
    // As the drive converts its control period (`Base::time`).
    let dt: T = base.time(dt_s);
    if !(dt_s.is_finite() && dt_s > 0.0 && dt.is_valid() && dt > T::ZERO) {
        return Err(ReplayError::Period { period_s, numeric });
    }
    let rows = trace.rows();
    let mut out = Vec::with_capacity(rows.len());
    let mut u_applied = AlphaBeta::new(T::ZERO, T::ZERO);
    let accel = trace.commanded_acceleration();
    let si = |word: T, q: Quantity| numeric.to_si(word.to_word(), q, &base);
    for (index, row) in rows.iter().enumerate() {
        let [u_alpha, u_beta, i_alpha, i_beta] = to_working::<T>(row, index + 1, &base)?;
        if let Some(a) = accel.and_then(|a| a.get(index)) {
            // What the drive commanded its estimator for this update (finite: checked
            // by the reader).
            let word = numeric.from_si(*a, Quantity::Acceleration, &base).ok_or(ReplayError::OutOfRange {
                numeric,
                row: index + 1,
                t: row.t,
                column: crate::trace::COMMANDED_ACCEL_COLUMN,
                value: *a,
            })?;
            est.set_commanded_acceleration(T::from_word(word));
        }
        let e = est
            .update(u_applied, AlphaBeta::new(i_alpha, i_beta), dt)
            .map_err(|fault| ReplayError::Fault { row: index + 1, t: row.t, fault })?;
        out.push(Estimate {
            theta_hat: e.theta_e.to_radians::<f64>(),
            v_hat: si(e.speed_m_per_s, Quantity::Speed),
            psi_alpha_hat: si(e.psi_ab.alpha, Quantity::Flux),
            psi_beta_hat: si(e.psi_ab.beta, Quantity::Flux),
            locked: e.locked,
        });
        // This row's voltage acts during the period that ends at the next sample.
        u_applied = AlphaBeta::new(u_alpha, u_beta);
        if (index + 1) % PROGRESS_EVERY_ROWS == 0 {
            progress(index + 1);
        }
    }
    progress(rows.len());
    Ok(out)
}

/// The row's voltages and currents in working units of `T`, or the first that does not
/// fit.
fn to_working<T: CaptureScalar>(
    row: &TraceRow,
    row_number: usize,
    base: &Base,
) -> Result<[T; 4], ReplayError> {
    let named = [
        ("u_alpha", row.u_alpha, Quantity::Voltage),
        ("u_beta", row.u_beta, Quantity::Voltage),
        ("i_alpha", row.i_alpha, Quantity::Current),
        ("i_beta", row.i_beta, Quantity::Current),
    ];
    let mut out = [T::ZERO; 4];
    for (slot, (column, value, q)) in out.iter_mut().zip(named) {
        let word = T::FORMAT.from_si(value, q, base).ok_or(ReplayError::OutOfRange {
            numeric: T::FORMAT,
            row: row_number,
            t: row.t,
            column,
            value,
        })?;
        *slot = T::from_word(word);
    }
    Ok(out)
}

// ---- The command.

/// What `dcfo replay` is asked to do.
#[derive(Debug, Clone)]
pub struct Params {
    /// Motor: a preset name (`paper`) or a TOML motor file.
    pub motor: String,
    /// Flux observer feeding the PLL.
    pub observer: ObserverKind,
    /// Input trace (CSV, docs/trace-format.md).
    pub trace: PathBuf,
    /// Output trace (CSV), written atomically.
    pub output: PathBuf,
    /// Print the summary as exactly one JSON object on stdout.
    pub json: bool,
    /// Settle time, s: the summary covers the samples from the first row's time plus this.
    pub settle_s: f64,
    /// The estimator's number type (and with it the working units, [`working_base`]).
    pub numeric: CaptureFormat,
}

/// `dcfo replay`: read, replay, summarise, then write the output trace and print the
/// summary. Nothing is written unless every step succeeds.
pub fn run_command(params: &Params) -> anyhow::Result<()> {
    use anyhow::{Context, bail};
    let motor = load_motor(&params.motor)?;
    if same_file(&params.trace, &params.output) {
        bail!("output {} is the input trace; choose another output file", params.output.display());
    }
    let trace =
        with_spinner(format!("reading {}", params.trace.display()), || InputTrace::read_path(&params.trace))?;
    if let Some(declared) = declared_numeric(&params.trace)
        && declared != params.numeric
    {
        eprintln!(
            "note: {} says it was captured in {} (`# numeric: {}`); replayed in {}, the estimates will not be the drive's (use --numeric {})",
            params.trace.display(),
            declared.name(),
            declared.name(),
            params.numeric.name(),
            declared.name()
        );
    }
    let kind = params.observer;
    let rows = trace.rows().len();
    let mut progress = Progress::new(rows);
    let estimates =
        replay_trace_with_progress(&trace, &motor.params, kind, params.numeric, |n| progress.update(n))
            .with_context(|| {
                format!(
                    "{}: replay with the {} observer in {} stopped",
                    params.trace.display(),
                    observer_name(kind),
                    params.numeric.name()
                )
            });
    progress.finish();
    let estimates = estimates?;
    let summary =
        Summary::compute(&trace, &estimates, &motor.params, params.settle_s).with_context(|| {
            format!("{}: cannot summarise (adjust --settle; no output was written)", params.trace.display())
        })?;
    with_spinner(format!("writing {}", params.output.display()), || {
        write_output_trace(&params.output, &trace, &estimates)
    })?;
    if params.json {
        println!("{}", summary.to_json());
    } else {
        let ts = trace.sample_period_s();
        let span = match (trace.rows().first(), trace.rows().last()) {
            (Some(a), Some(b)) => b.t - a.t,
            _ => 0.0,
        };
        println!(
            "replay of {} ({rows} rows, Ts = {:.4} ms, {span:.4} s) with the {} observer in {}, motor {}",
            params.trace.display(),
            ts * 1e3,
            observer_name(kind),
            params.numeric.name(),
            motor.name
        );
        println!("wrote {}", params.output.display());
        println!("{summary}");
    }
    Ok(())
}

/// The number type a capture's trace declares in a comment line before its header
/// (`# numeric: q24 ...`, as `dcfo board --record` writes it), if any.
pub fn declared_numeric(path: &Path) -> Option<CaptureFormat> {
    use std::io::BufRead;
    let file = std::fs::File::open(path).ok()?;
    for line in std::io::BufReader::new(file).lines() {
        let line = line.ok()?;
        let Some(comment) = line.trim_start_matches('\u{feff}').trim_start().strip_prefix('#') else {
            // The header (or a blank line before it): comments after it are not looked at.
            if line.trim().is_empty() {
                continue;
            }
            return None;
        };
        if let Some(rest) = comment.trim_start().strip_prefix("numeric:") {
            let name = rest.split_whitespace().next()?;
            return [CaptureFormat::F32, CaptureFormat::Q24].into_iter().find(|f| f.name() == name);
        }
    }
    None
}

/// `true` when both paths name the same existing file.
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trace(n: usize, u: impl Fn(usize) -> (f64, f64), i: impl Fn(usize) -> (f64, f64)) -> InputTrace {
        trace_dt(n, 1e-4, u, i)
    }

    fn trace_dt(
        n: usize,
        dt: f64,
        u: impl Fn(usize) -> (f64, f64),
        i: impl Fn(usize) -> (f64, f64),
    ) -> InputTrace {
        let rows = (0..n)
            .map(|k| TraceRow {
                t: k as f64 * dt,
                u_alpha: u(k).0,
                u_beta: u(k).1,
                i_alpha: i(k).0,
                i_beta: i(k).1,
                theta: None,
                v: None,
                x: None,
            })
            .collect();
        InputTrace::from_rows(rows, "mem").unwrap()
    }

    /// The replay feeds row k-1's voltage (zero for row 0) with row k's current: the
    /// same as driving the estimator by hand with that timing.
    #[test]
    fn voltage_is_delayed_by_one_row_and_matches_a_hand_driven_estimator() {
        let u = |k: usize| (10.0 * (k as f64 * 0.07).cos(), 10.0 * (k as f64 * 0.07).sin() + 0.3);
        let i = |k: usize| (0.5 * (k as f64 * 0.05).sin(), -0.25);
        let tr = trace(300, u, i);
        let motor = MotorParams::paper();
        for kind in [ObserverKind::PureIntegrator, ObserverKind::Cfo, ObserverKind::Dcfo] {
            let got = replay_trace(&tr, &motor, kind).unwrap();
            assert_eq!(got.len(), 300);
            let cfg = EstimatorConfig::for_motor(&motor, kind);
            let mut est = Estimator::<f32>::new(&motor, &cfg, &Base::SI).unwrap();
            let dt = tr.sample_period_s() as f32;
            for (k, g) in got.iter().enumerate() {
                let (ua, ub) = if k == 0 { (0.0, 0.0) } else { u(k - 1) };
                let (ia, ib) = i(k);
                let e = est
                    .update(AlphaBeta::new(ua as f32, ub as f32), AlphaBeta::new(ia as f32, ib as f32), dt)
                    .unwrap();
                assert_eq!(g.theta_hat.to_bits(), e.theta_e.to_radians::<f64>().to_bits(), "{kind:?} {k}");
                assert_eq!(g.v_hat.to_bits(), f64::from(e.speed_m_per_s).to_bits());
                assert_eq!(g.psi_alpha_hat.to_bits(), f64::from(e.psi_ab.alpha).to_bits());
                assert_eq!(g.psi_beta_hat.to_bits(), f64::from(e.psi_ab.beta).to_bits());
            }
        }
    }

    #[test]
    fn values_beyond_f32_are_refused_with_row_and_column() {
        let tr = trace(10, |k| if k == 6 { (1.0, 1e39) } else { (1.0, 2.0) }, |_| (0.0, 0.0));
        let err = replay_trace(&tr, &MotorParams::paper(), ObserverKind::Dcfo).unwrap_err();
        match &err {
            ReplayError::OutOfRange { row, t, column, value, .. } => {
                assert_eq!((*row, *column, *value), (7, "u_beta", 1e39));
                assert!((t - 6e-4).abs() < 1e-15, "{t}");
            }
            other => panic!("{other:?}"),
        }
        let msg = err.to_string();
        assert!(msg.contains("data row 7") && msg.contains("`u_beta`") && msg.contains("f32"), "{msg}");
    }

    #[test]
    fn a_diverging_observer_is_a_fault_naming_the_row() {
        // 3e38 V held for 1000 s overflows the f32 integrator state on the next row.
        let tr = trace_dt(10, 1e3, |k| if k == 3 { (3e38, 3e38) } else { (0.0, 0.0) }, |_| (0.0, 0.0));
        let err = replay_trace(&tr, &MotorParams::paper(), ObserverKind::PureIntegrator).unwrap_err();
        match &err {
            ReplayError::Fault { row, fault, .. } => {
                assert_eq!((*row, *fault), (5, EstimatorFault::Observer(ObserverFault::StateOverflow)));
            }
            other => panic!("{other:?}"),
        }
        assert!(err.to_string().contains("data row 5 (t = 4000 s)"), "{err}");
    }

    #[test]
    fn the_declared_number_type_is_read_from_the_comments_before_the_header() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.csv");
        let h = "t,u_alpha,u_beta,i_alpha,i_beta\n0,0,0,0,0\n";
        std::fs::write(&p, format!("# dcfo capture\n# numeric: q24 (per unit)\n{h}")).unwrap();
        assert_eq!(declared_numeric(&p), Some(CaptureFormat::Q24));
        std::fs::write(&p, format!("\n#numeric: f32\n{h}")).unwrap();
        assert_eq!(declared_numeric(&p), Some(CaptureFormat::F32));
        std::fs::write(&p, format!("{h}# numeric: q24\n")).unwrap();
        assert_eq!(declared_numeric(&p), None, "after the header: data, not metadata");
        std::fs::write(&p, format!("# numeric: f64\n{h}")).unwrap();
        assert_eq!(declared_numeric(&p), None);
    }

    /// The Q8.24 replay refuses a value beyond its range, naming the row, the column and
    /// the number type.
    #[test]
    fn q24_values_beyond_the_range_are_refused_with_row_and_column() {
        // 128 per unit of the paper motor's 179.6 V base is 23 kV.
        let tr = trace(10, |k| if k == 4 { (3e4, 0.0) } else { (1.0, 2.0) }, |_| (0.0, 0.0));
        let err =
            replay_trace_as(&tr, &MotorParams::paper(), ObserverKind::Dcfo, CaptureFormat::Q24).unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains("data row 5") && msg.contains("`u_alpha`") && msg.contains("q24"), "{msg}");
    }

    #[test]
    fn progress_reports_every_block_and_the_end() {
        let tr = trace(10_000, |_| (0.0, 0.0), |_| (0.0, 0.0));
        let mut calls = Vec::new();
        replay_trace_with_progress(&tr, &MotorParams::paper(), ObserverKind::Cfo, CaptureFormat::F32, |n| {
            calls.push(n)
        })
        .unwrap();
        assert_eq!(calls, [4096, 8192, 10_000]);
    }
}
