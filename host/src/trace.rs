//! Trace files (CSV): reading input traces, writing output traces and input traces.
//!
//! The format is the project's interchange contract, `trace-format.md` ("Trace and
//! motor-file formats"). All quantities are SI: seconds, volts, amperes, radians,
//! metres, m/s, webers.
//!
//! # Reading
//!
//! [`InputTrace::read_path`] / [`InputTrace::from_reader`] parse an input trace:
//!
//! - Lines whose first non-blank character is `#` are comments, anywhere in the file.
//!   Blank lines are skipped. A UTF-8 byte-order mark on line 1 is ignored.
//! - The first line that is not a comment is the header. Columns are found by name
//!   (exact, case-sensitive), in any order; unknown columns (including an unnamed
//!   index column such as pandas writes) are ignored and their cells are not parsed.
//!   A known column named twice is refused as ambiguous.
//! - Fields are comma-separated and trimmed of surrounding blanks; a field may be
//!   wrapped in double quotes (`""` inside quotes is a literal quote). A record must
//!   fit on one line.
//! - Required columns: [`REQUIRED_COLUMNS`]. Optional ground truth: `theta` (rad,
//!   wrapped or unwrapped), `v` (m/s), `x` (m). A column present in the header must
//!   have a number in every row.
//! - Every refusal is a [`TraceError`] whose message names the file, the 1-based file
//!   line (counting comment and blank lines, as a text editor shows) and the column.
//!
//! # Time step
//!
//! `t` must strictly increase with a uniform step. The reference step is the (lower)
//! median of all steps, so one dropped or repeated sample is reported at its own
//! line rather than skewing the reference. A step `dt` is accepted when
//! `|dt - median| <= T_STEP_REL_TOL * median + min(T_STEP_ABS_TOL_S, median / 4)`:
//!
//! - [`T_STEP_REL_TOL`] = 1e-6 covers the f64 rounding of `t` itself: each time is
//!   off by up to 1.1e-16 × `t`, which relative to the step is 1.1e-16 × `t / Ts`,
//!   about 2e-10 even a million periods into a trace, so exactly printed times never
//!   come near it. Data that jitters by more than a millionth of a period is not
//!   uniform (unless within the absolute floor below).
//! - [`T_STEP_ABS_TOL_S`] = 2 µs covers times printed with a limited number of
//!   decimals. C's `printf("%f")` prints 6 decimals: each time is off by up to
//!   0.5 µs, so a step is off by up to 1 µs from the true one and from its neighbours
//!   (e.g. 62.5 µs at 16 kHz prints as steps of 62 and 63 µs). 2 µs also covers `t`
//!   kept in f32 up to 32 s (f32 spacing 1.9 µs there). It is still far below any
//!   drive's control period (50-200 µs), so a dropped sample (an error of a whole
//!   period) is always caught. The `median / 4` cap keeps that true for very short
//!   periods (below 8 µs) as well.
//!
//! [`InputTrace::sample_period_s`] then returns the mean step `(t_last - t_first) /
//! (n - 1)`, the best estimate from rounded times.
//!
//! # Writing
//!
//! Both writers are atomic: rows go to a temporary file in the destination directory,
//! which is flushed, synced and renamed over the destination only by `finish()`.
//! If anything fails, or the writer is dropped without `finish()`, the temporary file
//! is removed and the destination is untouched (absent, or its old content kept).
//! Numbers are written with Rust's shortest round-trip `f64` formatting (`{}`), so
//! reading a written file gives back the same bits.
//!
//! - [`OutputTraceWriter`] (and the one-call [`write_output_trace`]) writes a replay
//!   result, one row per input row: `t,theta_hat,v_hat,psi_alpha_hat,psi_beta_hat,locked`,
//!   then `theta_err` only if the input had `theta`, and `v_err` only if it had `v`.
//!   Each error column exists exactly when its ground truth does, so a column is never
//!   filled with placeholders and a reader can tell "no ground truth" from "zero
//!   error". Non-finite estimates are written as `NaN` / `inf`, so a diverging
//!   observer is visible in the output rather than hidden.
//! - [`InputTraceWriter`] writes a trace in the input format (for simulators), with
//!   the ground-truth columns chosen up front and optional extra columns. It refuses
//!   anything the reader would refuse (non-finite values, non-increasing or
//!   non-uniform `t`, fewer than 2 rows), so what it writes always reads back.

use std::borrow::Cow;
use std::f64::consts::PI;
use std::fmt::Write as _;
use std::io::{self, BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// Columns an input trace must have: time (s), stator voltage (V) and measured
/// current (A), alpha and beta.
pub const REQUIRED_COLUMNS: [&str; 5] = ["t", "u_alpha", "u_beta", "i_alpha", "i_beta"];

/// Optional ground-truth columns of an input trace: electrical angle `theta` (rad),
/// speed `v` (m/s), position `x` (m).
pub const GROUND_TRUTH_COLUMNS: [&str; 3] = ["theta", "v", "x"];

/// Relative part of the time-step tolerance (dimensionless, times the median step).
/// See the module documentation for the reasoning.
pub const T_STEP_REL_TOL: f64 = 1e-6;

/// Absolute part of the time-step tolerance, seconds (capped at a quarter of the
/// median step). See the module documentation for the reasoning.
pub const T_STEP_ABS_TOL_S: f64 = 2e-6;

/// Optional drive-input column of an input trace: the electrical acceleration
/// (rad/s^2) the drive commanded to its estimator for that row's update
/// (`dcfo::estimator::Estimator::set_commanded_acceleration`). Not part of the shared
/// format's named columns: other readers ignore it as an unknown column; this
/// project's writer adds it and its replay uses it, so that a trace of a drive that
/// ramps its speed still replays bit for bit.
pub const COMMANDED_ACCEL_COLUMN: &str = "alpha_e_ref";

/// Header of an output trace before the optional error columns.
pub const OUTPUT_COLUMNS: [&str; 6] = ["t", "theta_hat", "v_hat", "psi_alpha_hat", "psi_beta_hat", "locked"];

/// Wraps an angle (rad) to the half-open interval (-pi, pi].
///
/// Exactly `pi` stays `pi`; `-pi` maps to `pi`. Non-finite input gives NaN.
pub fn wrap_angle(angle_rad: f64) -> f64 {
    let two_pi = 2.0 * PI;
    // rem_euclid gives [0, 2pi); shift so the result is in (-pi, pi].
    let r = (angle_rad + PI).rem_euclid(two_pi) - PI;
    if r <= -PI { r + two_pi } else { r }
}

/// Why a trace was refused or could not be written. Every message names the file
/// and, where one applies, the 1-based line (or written row) and the column.
#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    /// Reading, creating, writing or renaming the file failed.
    #[error("{file}: {source}")]
    Io {
        /// The file concerned.
        file: String,
        /// The underlying I/O error.
        #[source]
        source: io::Error,
    },
    /// A line is not valid UTF-8.
    #[error("{file}:{line}: line is not valid UTF-8 text")]
    NotUtf8 {
        /// The file concerned.
        file: String,
        /// 1-based line number.
        line: u64,
    },
    /// A double quote opened a field and was never closed on that line.
    #[error("{file}:{line}: unterminated quoted field (records must fit on one line)")]
    UnterminatedQuote {
        /// The file concerned.
        file: String,
        /// 1-based line number.
        line: u64,
    },
    /// The file holds no header line: it is empty, or only comments and blank lines.
    #[error("{file}: empty trace: no header line (the file is empty or holds only comments)")]
    NoHeader {
        /// The file concerned.
        file: String,
    },
    /// The header lacks one or more required columns.
    #[error(
        "{file}:{line}: header is missing required column {missing} (required: t, u_alpha, u_beta, i_alpha, i_beta)"
    )]
    MissingColumn {
        /// The file concerned.
        file: String,
        /// 1-based line number of the header.
        line: u64,
        /// The missing column names, each in backquotes, comma-separated.
        missing: String,
    },
    /// A known column is named twice in the header.
    #[error("{file}:{line}: column `{column}` appears more than once in the header")]
    DuplicateColumn {
        /// The file concerned.
        file: String,
        /// 1-based line number of the header.
        line: u64,
        /// The repeated column name.
        column: String,
    },
    /// A data line has a different number of fields from the header.
    #[error(
        "{file}:{line}: expected {expected} fields as in the header (line {header_line}), found {found}{}",
        missing_column_note(column)
    )]
    FieldCount {
        /// The file concerned.
        file: String,
        /// 1-based line number of the data line.
        line: u64,
        /// 1-based line number of the header.
        header_line: u64,
        /// Number of header fields.
        expected: usize,
        /// Number of fields on this line.
        found: usize,
        /// The first header column with no field on this line, if the line is short.
        column: Option<String>,
    },
    /// A cell of a known column is empty or not a number.
    #[error("{file}:{line}: column `{column}`: {} is not a number", describe_cell(text))]
    NotNumeric {
        /// The file concerned.
        file: String,
        /// 1-based line number.
        line: u64,
        /// The column name.
        column: String,
        /// The cell's text (shortened if long).
        text: String,
    },
    /// A cell is NaN or infinite.
    #[error("{file}:{line}: column `{column}`: value `{text}` is not finite (NaN or infinity)")]
    NotFinite {
        /// The file concerned.
        file: String,
        /// 1-based line number (for written traces: data row + 1, the header being line 1).
        line: u64,
        /// The column name.
        column: String,
        /// The value as text.
        text: String,
    },
    /// `t` does not strictly increase.
    #[error(
        "{file}:{line}: column `t`: {t} s is not greater than {prev_t} s on line {prev_line}; t must strictly increase"
    )]
    TimeNotIncreasing {
        /// The file concerned.
        file: String,
        /// 1-based line number of the offending row.
        line: u64,
        /// Its time, s.
        t: f64,
        /// 1-based line number of the previous row.
        prev_line: u64,
        /// The previous row's time, s.
        prev_t: f64,
    },
    /// A step of `t` differs from the median step by more than the tolerance.
    #[error(
        "{file}:{line}: column `t`: step {step_s} s from line {prev_line} differs from the trace's median step {median_s} s by more than {tolerance_s} s (dropped or repeated samples?); t must have a uniform step"
    )]
    StepNotUniform {
        /// The file concerned.
        file: String,
        /// 1-based line number of the row ending the step.
        line: u64,
        /// 1-based line number of the row starting the step.
        prev_line: u64,
        /// The step, s.
        step_s: f64,
        /// The median step, s.
        median_s: f64,
        /// The tolerance used, s (see the module documentation).
        tolerance_s: f64,
    },
    /// A header but no data rows.
    #[error("{file}: empty trace: no data rows after the header on line {header_line}")]
    NoRows {
        /// The file concerned.
        file: String,
        /// 1-based line number of the header.
        header_line: u64,
    },
    /// Fewer than 2 data rows: the sample period is unknown.
    #[error(
        "{file}:{line}: only {rows} data row(s); at least 2 are needed to know the sample period (column `t`)"
    )]
    TooFewRows {
        /// The file concerned.
        file: String,
        /// 1-based line number of the only row (for a writer: of where the next row would go).
        line: u64,
        /// Number of data rows.
        rows: usize,
    },
    /// In-memory rows or a writer's row disagree with the columns being used: a
    /// ground-truth value is present in some rows and absent in others, or the number
    /// of extra values differs from the number of extra columns.
    #[error("{file}:{line}: column `{column}`: {reason}")]
    RowShape {
        /// The file concerned.
        file: String,
        /// 1-based line the row has (would have) in the file: data row + 1.
        line: u64,
        /// The column concerned.
        column: String,
        /// What is wrong.
        reason: String,
    },
    /// An extra column name cannot be written (empty, blank at either end, holds a
    /// comma, quote or line break, starts with `#`, or repeats another column).
    #[error("{file}: extra column name `{name}`: {reason}")]
    BadColumnName {
        /// The file concerned.
        file: String,
        /// The refused name.
        name: String,
        /// What is wrong.
        reason: &'static str,
    },
    /// An output trace got a different number of estimates than the input has rows.
    #[error(
        "{file}: {written} estimate rows for {expected} input rows; an output trace has one row per input row"
    )]
    RowCount {
        /// The file concerned.
        file: String,
        /// Input rows.
        expected: usize,
        /// Estimates given (so far, if more than expected).
        written: usize,
    },
}

fn missing_column_note(column: &Option<String>) -> String {
    match column {
        Some(c) => format!(" (no value for column `{c}`)"),
        None => String::new(),
    }
}

fn describe_cell(text: &str) -> String {
    if text.is_empty() { "empty cell".to_string() } else { format!("`{text}`") }
}

/// Which ground-truth columns a trace has (or a writer writes).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GroundTruth {
    /// Electrical angle `theta`, rad.
    pub theta: bool,
    /// Speed `v`, m/s.
    pub v: bool,
    /// Position `x`, m.
    pub x: bool,
}

impl GroundTruth {
    /// All three ground-truth columns.
    pub const ALL: GroundTruth = GroundTruth { theta: true, v: true, x: true };
    /// No ground truth.
    pub const NONE: GroundTruth = GroundTruth { theta: false, v: false, x: false };

    fn of_row(row: &TraceRow) -> GroundTruth {
        GroundTruth { theta: row.theta.is_some(), v: row.v.is_some(), x: row.x.is_some() }
    }
}

/// One sample of an input trace (SI units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraceRow {
    /// Sample time, s.
    pub t: f64,
    /// Stator voltage applied during `[t, t + Ts)`, alpha axis, V.
    pub u_alpha: f64,
    /// Stator voltage applied during `[t, t + Ts)`, beta axis, V.
    pub u_beta: f64,
    /// Measured stator current at `t`, alpha axis, A.
    pub i_alpha: f64,
    /// Measured stator current at `t`, beta axis, A.
    pub i_beta: f64,
    /// Ground-truth electrical angle, rad (wrapped or unwrapped), if the trace has it.
    pub theta: Option<f64>,
    /// Ground-truth speed, m/s, if the trace has it.
    pub v: Option<f64>,
    /// Ground-truth position, m, if the trace has it.
    pub x: Option<f64>,
}

impl TraceRow {
    /// The row's values with their column names, in file order; absent ground truth
    /// is left out.
    fn named_values(&self) -> impl Iterator<Item = (&'static str, f64)> {
        [
            ("t", Some(self.t)),
            ("u_alpha", Some(self.u_alpha)),
            ("u_beta", Some(self.u_beta)),
            ("i_alpha", Some(self.i_alpha)),
            ("i_beta", Some(self.i_beta)),
            ("theta", self.theta),
            ("v", self.v),
            ("x", self.x),
        ]
        .into_iter()
        .filter_map(|(name, value)| value.map(|v| (name, v)))
    }
}

/// A validated input trace: at least 2 rows, all values finite, `t` strictly
/// increasing with a uniform step, every row with the same ground-truth columns.
#[derive(Clone, Debug, PartialEq)]
pub struct InputTrace {
    rows: Vec<TraceRow>,
    ground_truth: GroundTruth,
    /// One value per row from the [`COMMANDED_ACCEL_COLUMN`], if the trace has it.
    commanded_accel: Option<Vec<f64>>,
}

impl InputTrace {
    /// Reads and validates the input trace at `path`. Errors name the file as given.
    pub fn read_path(path: impl AsRef<Path>) -> Result<Self, TraceError> {
        let path = path.as_ref();
        let file = path.display().to_string();
        let f = std::fs::File::open(path).map_err(|source| TraceError::Io { file: file.clone(), source })?;
        Self::from_reader(f, &file)
    }

    /// Reads and validates an input trace from any reader; `source` names it in
    /// error messages (a file name, or e.g. `<stdin>`).
    pub fn from_reader(reader: impl Read, source: &str) -> Result<Self, TraceError> {
        parse(BufReader::new(reader), source)
    }

    /// Validates rows built in memory (e.g. by a simulator) with the same rules as a
    /// file. The ground-truth columns are those of the first row; error lines are
    /// those the rows would have in a file with the header on line 1 (row k, 1-based,
    /// on line k + 1), `source` names them.
    pub fn from_rows(rows: Vec<TraceRow>, source: &str) -> Result<Self, TraceError> {
        let Some(first) = rows.first() else {
            return Err(TraceError::NoRows { file: source.to_string(), header_line: 1 });
        };
        let ground_truth = GroundTruth::of_row(first);
        let mut lines = Vec::with_capacity(rows.len());
        for (k, row) in rows.iter().enumerate() {
            let line = k as u64 + 2;
            check_row_shape(source, line, row, ground_truth)?;
            for (column, value) in row.named_values() {
                if !value.is_finite() {
                    return Err(TraceError::NotFinite {
                        file: source.to_string(),
                        line,
                        column: column.to_string(),
                        text: value.to_string(),
                    });
                }
            }
            if k > 0 {
                check_increasing(source, &rows[k - 1], line - 1, row, line)?;
            }
            lines.push(line);
        }
        let times: Vec<f64> = rows.iter().map(|r| r.t).collect();
        check_time_step(source, &times, &lines)?;
        Ok(InputTrace { rows, ground_truth, commanded_accel: None })
    }

    /// Adds the commanded electrical acceleration of every row (rad/s^2, see
    /// [`COMMANDED_ACCEL_COLUMN`]); refused unless there is one finite value per row.
    pub fn with_commanded_acceleration(mut self, values: Vec<f64>, source: &str) -> Result<Self, TraceError> {
        if values.len() != self.rows.len() {
            return Err(TraceError::RowShape {
                file: source.to_string(),
                line: 1,
                column: COMMANDED_ACCEL_COLUMN.to_string(),
                reason: format!("{} values for {} rows", values.len(), self.rows.len()),
            });
        }
        if let Some(k) = values.iter().position(|v| !v.is_finite()) {
            return Err(TraceError::NotFinite {
                file: source.to_string(),
                line: k as u64 + 2,
                column: COMMANDED_ACCEL_COLUMN.to_string(),
                text: values[k].to_string(),
            });
        }
        self.commanded_accel = Some(values);
        Ok(self)
    }

    /// The commanded electrical acceleration per row (rad/s^2), if the trace has it.
    pub fn commanded_acceleration(&self) -> Option<&[f64]> {
        self.commanded_accel.as_deref()
    }

    /// The rows, in time order (at least 2).
    pub fn rows(&self) -> &[TraceRow] {
        &self.rows
    }

    /// Which ground-truth columns the trace has.
    pub fn ground_truth(&self) -> GroundTruth {
        self.ground_truth
    }

    /// The sample (control) period, s: the mean step `(t_last - t_first) / (n - 1)`.
    pub fn sample_period_s(&self) -> f64 {
        let (first, last) = match (self.rows.first(), self.rows.last()) {
            (Some(f), Some(l)) => (f.t, l.t),
            _ => return f64::NAN, // unreachable: a trace has at least 2 rows
        };
        (last - first) / (self.rows.len() - 1) as f64
    }
}

fn check_row_shape(file: &str, line: u64, row: &TraceRow, expected: GroundTruth) -> Result<(), TraceError> {
    let have = GroundTruth::of_row(row);
    for (name, want, got) in
        [("theta", expected.theta, have.theta), ("v", expected.v, have.v), ("x", expected.x, have.x)]
    {
        if want != got {
            let reason = if want {
                "value missing, but the trace has this column"
            } else {
                "value given, but the trace does not have this column"
            };
            return Err(TraceError::RowShape {
                file: file.to_string(),
                line,
                column: name.to_string(),
                reason: reason.to_string(),
            });
        }
    }
    Ok(())
}

fn check_increasing(
    file: &str,
    prev: &TraceRow,
    prev_line: u64,
    row: &TraceRow,
    line: u64,
) -> Result<(), TraceError> {
    // Written so that NaN (never expected here) is refused too.
    if row.t.partial_cmp(&prev.t) != Some(std::cmp::Ordering::Greater) {
        return Err(TraceError::TimeNotIncreasing {
            file: file.to_string(),
            line,
            t: row.t,
            prev_line,
            prev_t: prev.t,
        });
    }
    Ok(())
}

/// Checks the number of rows and the uniformity of the steps of strictly increasing
/// `times`, whose file lines are `lines`.
fn check_time_step(file: &str, times: &[f64], lines: &[u64]) -> Result<(), TraceError> {
    if times.len() < 2 {
        return Err(TraceError::TooFewRows {
            file: file.to_string(),
            line: lines.first().copied().unwrap_or(2),
            rows: times.len(),
        });
    }
    let steps: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    let mut sorted = steps.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[(sorted.len() - 1) / 2];
    let tolerance = T_STEP_REL_TOL * median + T_STEP_ABS_TOL_S.min(0.25 * median);
    for (k, step) in steps.iter().enumerate() {
        if (step - median).abs() > tolerance {
            return Err(TraceError::StepNotUniform {
                file: file.to_string(),
                line: lines[k + 1],
                prev_line: lines[k],
                step_s: *step,
                median_s: median,
                tolerance_s: tolerance,
            });
        }
    }
    Ok(())
}

/// Splits one CSV line into trimmed fields, unquoting double-quoted ones (`""` inside
/// quotes is a literal quote). `None` for an unterminated quote.
///
/// Why not the `csv` crate: the format requires errors to name the file line, and the
/// crate's `Position::line` is wrong for the first record after a skipped (blank or
/// comment) line (BurntSushi/rust-csv issue 208). Traces are one record per line, so
/// the reader keeps its own line count and splits each line here.
fn split_fields(line: &str) -> Option<Vec<Cow<'_, str>>> {
    if !line.contains('"') {
        return Some(line.split(',').map(|f| Cow::Borrowed(f.trim())).collect());
    }
    let mut fields = Vec::new();
    let mut field = String::new();
    let mut in_quotes = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        if in_quotes {
            if c != '"' {
                field.push(c);
            } else if chars.peek() == Some(&'"') {
                chars.next();
                field.push('"');
            } else {
                in_quotes = false;
            }
        } else if c == '"' && field.trim().is_empty() {
            // An opening quote at the start of a field (after optional blanks).
            field.clear();
            in_quotes = true;
        } else if c == ',' {
            fields.push(Cow::Owned(field.trim().to_string()));
            field.clear();
        } else {
            field.push(c);
        }
    }
    if in_quotes {
        return None;
    }
    fields.push(Cow::Owned(field.trim().to_string()));
    Some(fields)
}

/// Where each known column sits in the header.
struct Header {
    line: u64,
    len: usize,
    /// Field index of the optional [`COMMANDED_ACCEL_COLUMN`].
    commanded_accel: Option<usize>,
    /// Field index of t, u_alpha, u_beta, i_alpha, i_beta, theta, v, x.
    index: [Option<usize>; 8],
}

const KNOWN_COLUMNS: [&str; 8] = ["t", "u_alpha", "u_beta", "i_alpha", "i_beta", "theta", "v", "x"];

impl Header {
    fn parse(file: &str, line: u64, fields: &[Cow<'_, str>]) -> Result<Header, TraceError> {
        let mut index = [None; 8];
        for (i, name) in fields.iter().enumerate() {
            if let Some(k) = KNOWN_COLUMNS.iter().position(|c| *c == name.as_ref()) {
                if index[k].is_some() {
                    return Err(TraceError::DuplicateColumn {
                        file: file.to_string(),
                        line,
                        column: name.to_string(),
                    });
                }
                index[k] = Some(i);
            }
        }
        let missing: Vec<String> = REQUIRED_COLUMNS
            .iter()
            .zip(index)
            .filter(|(_, i)| i.is_none())
            .map(|(name, _)| format!("`{name}`"))
            .collect();
        if !missing.is_empty() {
            return Err(TraceError::MissingColumn {
                file: file.to_string(),
                line,
                missing: missing.join(", "),
            });
        }
        let commanded_accel = fields.iter().position(|f| f.as_ref() == COMMANDED_ACCEL_COLUMN);
        Ok(Header { line, len: fields.len(), index, commanded_accel })
    }

    fn ground_truth(&self) -> GroundTruth {
        GroundTruth { theta: self.index[5].is_some(), v: self.index[6].is_some(), x: self.index[7].is_some() }
    }

    fn row(&self, file: &str, line: u64, fields: &[Cow<'_, str>]) -> Result<TraceRow, TraceError> {
        if fields.len() != self.len {
            return Err(TraceError::FieldCount {
                file: file.to_string(),
                line,
                header_line: self.line,
                expected: self.len,
                found: fields.len(),
                column: self
                    .index
                    .iter()
                    .zip(KNOWN_COLUMNS)
                    .filter_map(|(i, name)| i.filter(|i| *i >= fields.len()).map(|i| (i, name)))
                    .min()
                    .map(|(_, name)| name.to_string()),
            });
        }
        let mut values = [None; 8];
        for (k, slot) in values.iter_mut().enumerate() {
            if let Some(i) = self.index[k] {
                *slot = Some(parse_cell(file, line, KNOWN_COLUMNS[k], &fields[i])?);
            }
        }
        // The five required columns are present (checked by `Header::parse`).
        let req = |k: usize| values[k].unwrap_or(f64::NAN);
        Ok(TraceRow {
            t: req(0),
            u_alpha: req(1),
            u_beta: req(2),
            i_alpha: req(3),
            i_beta: req(4),
            theta: values[5],
            v: values[6],
            x: values[7],
        })
    }
}

fn parse_cell(file: &str, line: u64, column: &str, text: &str) -> Result<f64, TraceError> {
    let shown = || {
        const MAX: usize = 40;
        if text.chars().count() > MAX {
            let mut s: String = text.chars().take(MAX).collect();
            s.push_str("...");
            s
        } else {
            text.to_string()
        }
    };
    let value: f64 = text.parse().map_err(|_| TraceError::NotNumeric {
        file: file.to_string(),
        line,
        column: column.to_string(),
        text: shown(),
    })?;
    if !value.is_finite() {
        return Err(TraceError::NotFinite {
            file: file.to_string(),
            line,
            column: column.to_string(),
            text: shown(),
        });
    }
    Ok(value)
}

fn parse(mut reader: impl BufRead, file: &str) -> Result<InputTrace, TraceError> {
    let mut buf = Vec::new();
    let mut line = 0u64;
    let mut header: Option<Header> = None;
    let mut rows: Vec<TraceRow> = Vec::new();
    let mut lines: Vec<u64> = Vec::new();
    let mut accel: Vec<f64> = Vec::new();
    loop {
        buf.clear();
        let n = reader
            .read_until(b'\n', &mut buf)
            .map_err(|source| TraceError::Io { file: file.to_string(), source })?;
        if n == 0 {
            break;
        }
        line += 1;
        let text =
            std::str::from_utf8(&buf).map_err(|_| TraceError::NotUtf8 { file: file.to_string(), line })?;
        let text = if line == 1 { text.strip_prefix('\u{feff}').unwrap_or(text) } else { text };
        let text = text.trim_end_matches(['\n', '\r']);
        let trimmed = text.trim_start();
        if trimmed.trim_end().is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let fields = split_fields(text)
            .ok_or_else(|| TraceError::UnterminatedQuote { file: file.to_string(), line })?;
        match &header {
            None => header = Some(Header::parse(file, line, &fields)?),
            Some(h) => {
                let row = h.row(file, line, &fields)?;
                if let Some(i) = h.commanded_accel {
                    // The field count was checked by `row`.
                    let text = fields.get(i).map_or("", |f| f.as_ref());
                    accel.push(parse_cell(file, line, COMMANDED_ACCEL_COLUMN, text)?);
                }
                if let (Some(prev), Some(prev_line)) = (rows.last(), lines.last()) {
                    check_increasing(file, prev, *prev_line, &row, line)?;
                }
                rows.push(row);
                lines.push(line);
            }
        }
    }
    let Some(header) = header else {
        return Err(TraceError::NoHeader { file: file.to_string() });
    };
    if rows.is_empty() {
        return Err(TraceError::NoRows { file: file.to_string(), header_line: header.line });
    }
    let times: Vec<f64> = rows.iter().map(|r| r.t).collect();
    check_time_step(file, &times, &lines)?;
    let commanded_accel = header.commanded_accel.map(|_| accel);
    Ok(InputTrace { rows, ground_truth: header.ground_truth(), commanded_accel })
}

/// One sample of an observer's output (SI units), paired with the input row of the
/// same index.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Estimate {
    /// Estimated electrical angle, rad.
    pub theta_hat: f64,
    /// Estimated speed, m/s.
    pub v_hat: f64,
    /// Estimated mover flux, alpha axis, Wb.
    pub psi_alpha_hat: f64,
    /// Estimated mover flux, beta axis, Wb.
    pub psi_beta_hat: f64,
    /// The estimator's claim that the angle is valid (written as 1 or 0).
    pub locked: bool,
}

/// Angle error (rad) above which a locked sample is a false lock (15 electrical degrees,
/// the output format's definition, `docs/trace-format.md`).
pub const FALSE_LOCK_ERROR_RAD: f64 = 15.0 * std::f64::consts::PI / 180.0;

impl Estimate {
    /// `true` when the estimate claims lock while its angle is more than
    /// [`FALSE_LOCK_ERROR_RAD`] off; `None` without ground-truth `theta`.
    pub fn false_lock(&self, truth: &TraceRow) -> Option<bool> {
        self.theta_err(truth).map(|e| self.locked && e.abs() > FALSE_LOCK_ERROR_RAD)
    }

    /// Angle error `theta - theta_hat` wrapped to (-pi, pi], rad; `None` without
    /// ground-truth `theta`.
    pub fn theta_err(&self, truth: &TraceRow) -> Option<f64> {
        truth.theta.map(|theta| wrap_angle(theta - self.theta_hat))
    }

    /// Speed error `v - v_hat`, m/s; `None` without ground-truth `v`.
    pub fn v_err(&self, truth: &TraceRow) -> Option<f64> {
        truth.v.map(|v| v - self.v_hat)
    }

    /// Flux amplitude `|psi_hat|`, Wb.
    pub fn psi_amplitude(&self) -> f64 {
        self.psi_alpha_hat.hypot(self.psi_beta_hat)
    }
}

/// A file written atomically: a temporary file in the destination's directory,
/// renamed over the destination by [`AtomicFile::commit`] and removed if dropped.
struct AtomicFile {
    dest: PathBuf,
    file: String,
    out: BufWriter<tempfile::NamedTempFile>,
}

impl AtomicFile {
    fn create(dest: &Path) -> Result<Self, TraceError> {
        let file = dest.display().to_string();
        let io_err = |source| TraceError::Io { file: file.clone(), source };
        let dir = match dest.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        let Some(name) = dest.file_name() else {
            return Err(io_err(io::Error::new(io::ErrorKind::InvalidInput, "not a file name")));
        };
        let prefix = format!(".{}.", name.to_string_lossy());
        let mut builder = tempfile::Builder::new();
        builder.prefix(&prefix).suffix(".partial");
        #[cfg(unix)]
        {
            // As for an ordinary new file (subject to the umask), not 0600.
            use std::os::unix::fs::PermissionsExt;
            builder.permissions(std::fs::Permissions::from_mode(0o666));
        }
        let tmp = builder.tempfile_in(dir).map_err(io_err)?;
        Ok(AtomicFile { dest: dest.to_path_buf(), file, out: BufWriter::new(tmp) })
    }

    fn io_err(&self, source: io::Error) -> TraceError {
        TraceError::Io { file: self.file.clone(), source }
    }

    fn write_line(&mut self, line: &str) -> Result<(), TraceError> {
        let r = self.out.write_all(line.as_bytes()).and_then(|()| self.out.write_all(b"\n"));
        r.map_err(|e| self.io_err(e))
    }

    fn commit(self) -> Result<(), TraceError> {
        let AtomicFile { dest, file, out } = self;
        let io_err = |source| TraceError::Io { file: file.clone(), source };
        let tmp = out.into_inner().map_err(|e| io_err(e.into_error()))?;
        tmp.as_file().sync_all().map_err(io_err)?;
        tmp.persist(&dest).map_err(|e| io_err(e.error))?;
        Ok(())
    }
}

fn push_number(line: &mut String, value: f64) {
    if !line.is_empty() {
        line.push(',');
    }
    // Display for f64 is the shortest text that parses back to the same value.
    let _ = write!(line, "{value}");
}

/// Writes an output trace atomically, row by row; see the module documentation.
///
/// ```no_run
/// # use dcfo_host::trace::*;
/// # fn f(input: &InputTrace, estimates: &[Estimate]) -> Result<(), TraceError> {
/// let mut w = OutputTraceWriter::create("out.csv", input)?;
/// for e in estimates {
///     w.write(e)?;
/// }
/// w.finish()?; // only now does out.csv appear (or change)
/// # Ok(()) }
/// ```
pub struct OutputTraceWriter<'a> {
    out: AtomicFile,
    input: &'a InputTrace,
    next: usize,
    line: String,
}

impl<'a> OutputTraceWriter<'a> {
    /// Starts an output trace for `input` at `path`. The header has `theta_err` if
    /// `input` has `theta`, and `v_err` if it has `v`.
    pub fn create(path: impl AsRef<Path>, input: &'a InputTrace) -> Result<Self, TraceError> {
        let mut out = AtomicFile::create(path.as_ref())?;
        let mut header = OUTPUT_COLUMNS.join(",");
        let gt = input.ground_truth();
        if gt.theta {
            header.push_str(",theta_err");
        }
        if gt.v {
            header.push_str(",v_err");
        }
        out.write_line(&header)?;
        Ok(OutputTraceWriter { out, input, next: 0, line: String::new() })
    }

    /// Writes the row for the next input row (its `t` and ground truth are taken from
    /// the input). Refuses more estimates than input rows.
    pub fn write(&mut self, estimate: &Estimate) -> Result<(), TraceError> {
        let rows = self.input.rows();
        let Some(row) = rows.get(self.next) else {
            return Err(TraceError::RowCount {
                file: self.out.file.clone(),
                expected: rows.len(),
                written: self.next + 1,
            });
        };
        self.next += 1;
        let mut line = std::mem::take(&mut self.line);
        line.clear();
        for value in
            [row.t, estimate.theta_hat, estimate.v_hat, estimate.psi_alpha_hat, estimate.psi_beta_hat]
        {
            push_number(&mut line, value);
        }
        push_number(&mut line, if estimate.locked { 1.0 } else { 0.0 });
        for value in [estimate.theta_err(row), estimate.v_err(row)].into_iter().flatten() {
            push_number(&mut line, value);
        }
        let r = self.out.write_line(&line);
        self.line = line;
        r
    }

    /// Checks that every input row got an estimate, then publishes the file.
    pub fn finish(self) -> Result<(), TraceError> {
        let expected = self.input.rows().len();
        if self.next != expected {
            return Err(TraceError::RowCount { file: self.out.file.clone(), expected, written: self.next });
        }
        self.out.commit()
    }
}

/// Writes the output trace for `input` and its `estimates` (one per input row) to
/// `path` in one call, atomically.
pub fn write_output_trace(
    path: impl AsRef<Path>,
    input: &InputTrace,
    estimates: &[Estimate],
) -> Result<(), TraceError> {
    let path = path.as_ref();
    if estimates.len() != input.rows().len() {
        return Err(TraceError::RowCount {
            file: path.display().to_string(),
            expected: input.rows().len(),
            written: estimates.len(),
        });
    }
    let mut w = OutputTraceWriter::create(path, input)?;
    for e in estimates {
        w.write(e)?;
    }
    w.finish()
}

/// Writes a trace in the input format atomically (e.g. a simulator's log with ground
/// truth), row by row; see the module documentation.
///
/// Header: `t,u_alpha,u_beta,i_alpha,i_beta`, then the chosen ground-truth columns
/// (`theta`, `v`, `x`, in that order), then the extra columns. Extra values are
/// written as given (even if not finite: readers ignore unknown columns).
pub struct InputTraceWriter {
    out: AtomicFile,
    /// Line number of the first data row (after the comments and the header).
    first_line: u64,
    ground_truth: GroundTruth,
    extra_columns: Vec<String>,
    prev: Option<TraceRow>,
    times: Vec<f64>,
    line: String,
}

impl InputTraceWriter {
    /// Starts an input-format trace at `path` with the given ground-truth columns and
    /// extra column names (which must not be a known column name, be empty, have
    /// blanks at either end, start with `#`, or hold a comma, quote or line break).
    pub fn create(
        path: impl AsRef<Path>,
        ground_truth: GroundTruth,
        extra_columns: &[&str],
    ) -> Result<Self, TraceError> {
        Self::create_with_comments(path, ground_truth, extra_columns, &[])
    }

    /// [`InputTraceWriter::create`] with comment lines before the header (each written
    /// as `# ` and the text, line breaks in it replaced by blanks): metadata such as the
    /// number type a capture was recorded in. Line numbers in errors count them.
    pub fn create_with_comments(
        path: impl AsRef<Path>,
        ground_truth: GroundTruth,
        extra_columns: &[&str],
        comments: &[&str],
    ) -> Result<Self, TraceError> {
        let path = path.as_ref();
        let file = path.display().to_string();
        for (k, name) in extra_columns.iter().enumerate() {
            let reason = if name.is_empty() {
                Some("empty")
            } else if name.trim() != *name {
                Some("has blanks at the start or end")
            } else if name.contains([',', '"', '\n', '\r']) {
                Some("holds a comma, quote or line break")
            } else if name.starts_with('#') {
                Some("starts with `#` (the line would read as a comment)")
            } else if KNOWN_COLUMNS.contains(name) {
                Some("is a standard trace column")
            } else if extra_columns[..k].contains(name) {
                Some("appears more than once")
            } else {
                None
            };
            if let Some(reason) = reason {
                return Err(TraceError::BadColumnName { file, name: name.to_string(), reason });
            }
        }
        let mut out = AtomicFile::create(path)?;
        for c in comments {
            out.write_line(&format!("# {}", c.replace(['\n', '\r'], " ")))?;
        }
        let mut header: Vec<&str> = REQUIRED_COLUMNS.to_vec();
        for (name, on) in [("theta", ground_truth.theta), ("v", ground_truth.v), ("x", ground_truth.x)] {
            if on {
                header.push(name);
            }
        }
        header.extend_from_slice(extra_columns);
        out.write_line(&header.join(","))?;
        Ok(InputTraceWriter {
            out,
            first_line: comments.len() as u64 + 2,
            ground_truth,
            extra_columns: extra_columns.iter().map(|s| s.to_string()).collect(),
            prev: None,
            times: Vec::new(),
            line: String::new(),
        })
    }

    /// Writes one row. Its ground-truth values must match the columns chosen in
    /// [`InputTraceWriter::create`], `extra` must have one value per extra column, all
    /// standard values must be finite and `t` must exceed the previous row's.
    pub fn write(&mut self, row: &TraceRow, extra: &[f64]) -> Result<(), TraceError> {
        let file = &self.out.file;
        let line_no = self.times.len() as u64 + self.first_line;
        check_row_shape(file, line_no, row, self.ground_truth)?;
        if extra.len() != self.extra_columns.len() {
            let column = if extra.len() > self.extra_columns.len() {
                "(beyond the last)".to_string()
            } else {
                self.extra_columns[extra.len()].clone()
            };
            return Err(TraceError::RowShape {
                file: file.clone(),
                line: line_no,
                column,
                reason: format!(
                    "{} extra values for {} extra columns",
                    extra.len(),
                    self.extra_columns.len()
                ),
            });
        }
        for (column, value) in row.named_values() {
            if !value.is_finite() {
                return Err(TraceError::NotFinite {
                    file: file.clone(),
                    line: line_no,
                    column: column.to_string(),
                    text: value.to_string(),
                });
            }
        }
        if let Some(prev) = &self.prev {
            check_increasing(file, prev, line_no - 1, row, line_no)?;
        }
        let mut line = std::mem::take(&mut self.line);
        line.clear();
        for (_, value) in row.named_values() {
            push_number(&mut line, value);
        }
        for value in extra {
            push_number(&mut line, *value);
        }
        let r = self.out.write_line(&line);
        self.line = line;
        r?;
        self.prev = Some(*row);
        self.times.push(row.t);
        Ok(())
    }

    /// Checks that the trace is readable (at least 2 rows, uniform step), then
    /// publishes the file.
    pub fn finish(self) -> Result<(), TraceError> {
        if self.times.len() < 2 {
            return Err(TraceError::TooFewRows {
                file: self.out.file.clone(),
                line: self.times.len() as u64 + self.first_line,
                rows: self.times.len(),
            });
        }
        let lines: Vec<u64> = (0..self.times.len() as u64).map(|k| k + self.first_line).collect();
        check_time_step(&self.out.file, &self.times, &lines)?;
        self.out.commit()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str = "t,u_alpha,u_beta,i_alpha,i_beta";

    fn read(text: &str) -> Result<InputTrace, TraceError> {
        InputTrace::from_reader(text.as_bytes(), "mem.csv")
    }

    fn err(text: &str) -> String {
        match read(text) {
            Ok(_) => panic!("accepted:\n{text}"),
            Err(e) => e.to_string(),
        }
    }

    fn assert_has(msg: &str, parts: &[&str]) {
        for p in parts {
            assert!(msg.contains(p), "message {msg:?} lacks {p:?}");
        }
    }

    fn row(t: f64) -> TraceRow {
        TraceRow { t, u_alpha: 1.0, u_beta: -2.0, i_alpha: 0.5, i_beta: 0.25, theta: None, v: None, x: None }
    }

    /// Plain, small trace with `n` rows at 10 kHz.
    fn plain(n: usize) -> String {
        let mut s = format!("{HEADER}\n");
        for k in 0..n {
            s.push_str(&format!("{},1,2,3,4\n", k as f64 * 1e-4));
        }
        s
    }

    #[test]
    fn reads_a_plain_trace() {
        let tr = read(&plain(5)).unwrap();
        assert_eq!(tr.rows().len(), 5);
        assert_eq!(tr.ground_truth(), GroundTruth::NONE);
        assert!((tr.sample_period_s() - 1e-4).abs() < 1e-15);
        assert_eq!(tr.rows()[2].u_beta, 2.0);
        assert_eq!(tr.rows()[2].theta, None);
    }

    #[test]
    fn comments_blank_lines_bom_and_crlf() {
        let text = "\u{feff}# recorded on bench 2\r\n\r\n  # indented comment\r\n\
                    t,u_alpha,u_beta,i_alpha,i_beta,theta\r\n# after the header\r\n\
                    0,1,2,3,4,0.1\r\n\r\n# between rows\r\n0.001,1,2,3,4,0.2\r\n# trailing\r\n";
        let tr = read(text).unwrap();
        assert_eq!(tr.rows().len(), 2);
        assert_eq!(tr.rows()[1].theta, Some(0.2));
        assert_eq!(tr.ground_truth(), GroundTruth { theta: true, v: false, x: false });
        // Line numbers count comments and blank lines, as an editor shows them.
        let bad = "# c1\n# c2\nt,u_alpha,u_beta,i_alpha,i_beta\n# c4\n0,1,2,3,4\n\n0.1,1,nan,3,4\n";
        assert_has(&err(bad), &["mem.csv:7:", "`u_beta`", "not finite"]);
    }

    #[test]
    fn column_order_is_free_and_unknown_columns_are_ignored() {
        let text = ",note,v,i_beta,x,t,theta,u_beta,i_alpha,u_alpha,extra\n\
                    0,start,0.3,4,0.01,0,1.5,2,3,1,\n\
                    1,\"a, b\",0.3,4.5,0.02,0.5,1.6,2,3,1,zz\n";
        let tr = read(text).unwrap();
        assert_eq!(tr.ground_truth(), GroundTruth::ALL);
        let r = tr.rows()[1];
        assert_eq!(
            r,
            TraceRow {
                t: 0.5,
                u_alpha: 1.0,
                u_beta: 2.0,
                i_alpha: 3.0,
                i_beta: 4.5,
                theta: Some(1.6),
                v: Some(0.3),
                x: Some(0.02),
            }
        );
        assert_eq!(tr.sample_period_s(), 0.5);
    }

    #[test]
    fn quoted_fields_and_blanks_around_fields() {
        let text = "\"t\", \"u_alpha\" ,u_beta,i_alpha,\"i_beta\"\n 0 , \"1\",2,3,4\n\"1e-3\",1,2,3,\"4\"\n";
        let tr = read(text).unwrap();
        assert_eq!(tr.rows()[1].t, 1e-3);
        assert_eq!(tr.rows()[0].u_alpha, 1.0);
        assert_eq!(split_fields("a,\"b \"\"q\"\", c\",,d").unwrap(), ["a", "b \"q\", c", "", "d"]);
        assert_eq!(split_fields("a,b,").unwrap(), ["a", "b", ""]);
        assert_has(&err(&format!("{HEADER}\n0,\"1,2,3,4\n")), &["mem.csv:2:", "unterminated"]);
    }

    #[test]
    fn missing_required_columns_are_named() {
        let m = err("# c\nt,u_alpha,i_alpha,theta\n0,1,2,3\n");
        assert_has(&m, &["mem.csv:2:", "`u_beta`, `i_beta`"]);
        let m = err("time,u_alpha,u_beta,i_alpha,i_beta\n0,1,2,3,4\n");
        assert_has(&m, &["mem.csv:1:", "missing required column `t`"]);
    }

    #[test]
    fn duplicate_known_column_is_refused() {
        let m = err("t,u_alpha,u_beta,i_alpha,i_beta,theta,theta\n0,1,2,3,4,5,6\n");
        assert_has(&m, &["mem.csv:1:", "`theta`", "more than once"]);
        // Repeated unknown columns do not matter.
        read("t,u_alpha,u_beta,i_alpha,i_beta,,\n0,1,2,3,4,,\n1,1,2,3,4,,\n").unwrap();
    }

    #[test]
    fn wrong_number_of_fields() {
        let short = format!("{HEADER},v\n0,1,2,3,4,0\n1,1,2,3\n");
        assert_has(&err(&short), &["mem.csv:3:", "expected 6 fields", "found 4", "`i_beta`"]);
        let long = format!("{HEADER}\n0,1,2,3,4\n1,1,2,3,4,5\n");
        assert_has(&err(&long), &["mem.csv:3:", "expected 5 fields", "found 6"]);
    }

    #[test]
    fn non_numeric_and_empty_cells() {
        let m = err(&format!("{HEADER}\n0,1,2,3,4\n1,1,2,abc,4\n"));
        assert_has(&m, &["mem.csv:3:", "column `i_alpha`", "`abc` is not a number"]);
        let m = err(&format!("{HEADER},theta\n0,1,2,3,4,0\n1,1,2,3,4,\n"));
        assert_has(&m, &["mem.csv:3:", "column `theta`", "empty cell"]);
        let long = "9".repeat(30) + &"x".repeat(30);
        let m = err(&format!("{HEADER}\n{long},1,2,3,4\n"));
        assert_has(&m, &["mem.csv:2:", "column `t`", "..."]);
        assert!(!m.contains(&long));
    }

    #[test]
    fn nan_and_infinity_are_refused() {
        for (cell, col) in [("NaN", "u_alpha"), ("inf", "u_alpha"), ("-infinity", "u_alpha")] {
            let m = err(&format!("{HEADER}\n0,1,2,3,4\n1,{cell},2,3,4\n"));
            assert_has(&m, &["mem.csv:3:", &format!("column `{col}`"), cell, "not finite"]);
        }
        let m = err(&format!("{HEADER},x\n0,1,2,3,4,1e999\n"));
        assert_has(&m, &["mem.csv:2:", "column `x`", "not finite"]);
    }

    #[test]
    fn time_must_strictly_increase() {
        let m = err(&format!("{HEADER}\n0,1,2,3,4\n# c\n0.1,1,2,3,4\n0.1,1,2,3,4\n"));
        assert_has(&m, &["mem.csv:5:", "column `t`", "line 4", "strictly increase"]);
        let m = err(&format!("{HEADER}\n0,1,2,3,4\n-0.1,1,2,3,4\n"));
        assert_has(&m, &["mem.csv:3:", "column `t`", "strictly increase"]);
    }

    #[test]
    fn dropped_sample_is_reported_at_its_line() {
        // Steps of 100 us, one of 200 us ending on line 5.
        let text =
            format!("{HEADER}\n0,1,2,3,4\n0.0001,1,2,3,4\n0.0002,1,2,3,4\n0.0004,1,2,3,4\n0.0005,1,2,3,4\n");
        let m = err(&text);
        assert_has(&m, &["mem.csv:5:", "column `t`", "from line 4", "uniform"]);
        // Two steps only, one doubled: refused whichever it names.
        assert_has(&err(&format!("{HEADER}\n0,1,2,3,4\n1,1,2,3,4\n3,1,2,3,4\n")), &["column `t`", "uniform"]);
    }

    #[test]
    fn step_tolerance_accepts_six_decimal_printing_and_refuses_jitter() {
        // 16 kHz (62.5 us) printed with 6 decimals: steps of 62 and 63 us.
        let mut text = format!("{HEADER}\n");
        for k in 0..2000 {
            text.push_str(&format!("{:.6},1,2,3,4\n", 1000.0 + k as f64 * 62.5e-6));
        }
        let tr = read(&text).unwrap();
        assert!((tr.sample_period_s() - 62.5e-6).abs() < 1e-9);
        // The same with one time 3 us late (steps +3 us and -3 us).
        let mut times: Vec<f64> = (0..50).map(|k| k as f64 * 1e-4).collect();
        times[20] += 3e-6;
        let mut text = format!("{HEADER}\n");
        for t in &times {
            text.push_str(&format!("{t:.7},1,2,3,4\n"));
        }
        assert_has(&err(&text), &["mem.csv:22:", "column `t`", "uniform"]);
        // 1.5 us late is within the 2 us floor.
        times[20] -= 1.5e-6;
        let mut text = format!("{HEADER}\n");
        for t in &times {
            text.push_str(&format!("{t:.7},1,2,3,4\n"));
        }
        read(&text).unwrap();
    }

    #[test]
    fn short_period_keeps_dropped_sample_detection() {
        // 1 MHz: the absolute floor is capped at a quarter step (0.25 us).
        let mut times: Vec<f64> = (0..10).map(|k| k as f64 * 1e-6).collect();
        times.remove(5);
        let mut text = format!("{HEADER}\n");
        for t in &times {
            text.push_str(&format!("{t},1,2,3,4\n"));
        }
        assert_has(&err(&text), &["mem.csv:7:", "uniform"]);
    }

    #[test]
    fn empty_traces_are_refused() {
        assert_has(&err(""), &["mem.csv", "empty trace", "no header"]);
        assert_has(&err("# only\n\n# comments\n"), &["empty trace", "no header"]);
        assert_has(&err(&format!("# c\n{HEADER}\n# c\n")), &["mem.csv", "empty trace", "line 2"]);
        assert_has(&err(&format!("{HEADER}\n# c\n0,1,2,3,4\n")), &["mem.csv:3:", "only 1 data row", "`t`"]);
    }

    #[test]
    fn invalid_utf8_names_the_line() {
        let mut bytes = format!("{HEADER}\n0,1,2,3,4\n").into_bytes();
        bytes.extend_from_slice(b"1,\xff,2,3,4\n");
        let e = InputTrace::from_reader(&bytes[..], "mem.csv").unwrap_err();
        assert_has(&e.to_string(), &["mem.csv:3:", "UTF-8"]);
    }

    #[test]
    fn from_rows_validates_like_a_file() {
        let rows: Vec<TraceRow> = (0..4).map(|k| row(k as f64 * 1e-3)).collect();
        let tr = InputTrace::from_rows(rows.clone(), "sim").unwrap();
        assert!((tr.sample_period_s() - 1e-3).abs() < 1e-15);

        let mut bad = rows.clone();
        bad[2].theta = Some(1.0);
        assert_has(&InputTrace::from_rows(bad, "sim").unwrap_err().to_string(), &["sim:4:", "`theta`"]);
        let mut bad = rows.clone();
        bad[1].i_beta = f64::NAN;
        assert_has(
            &InputTrace::from_rows(bad, "sim").unwrap_err().to_string(),
            &["sim:3:", "`i_beta`", "not finite"],
        );
        let mut bad = rows.clone();
        bad[3].t = bad[2].t;
        assert_has(&InputTrace::from_rows(bad, "sim").unwrap_err().to_string(), &["sim:5:", "`t`"]);
        assert_has(&InputTrace::from_rows(vec![], "sim").unwrap_err().to_string(), &["empty trace"]);
        assert_has(
            &InputTrace::from_rows(vec![row(0.0)], "sim").unwrap_err().to_string(),
            &["sim:2:", "only 1"],
        );
    }

    #[test]
    fn wrap_angle_boundaries() {
        assert_eq!(wrap_angle(PI), PI);
        assert_eq!(wrap_angle(-PI), PI);
        assert_eq!(wrap_angle(0.0), 0.0);
        assert_eq!(wrap_angle(1.0), 1.0);
        assert_eq!(wrap_angle(-1.0), -1.0);
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(-3.0 * PI) - PI).abs() < 1e-12 || (wrap_angle(-3.0 * PI) + PI).abs() < 1e-12);
        assert!((wrap_angle(2.0 * PI + 0.1) - 0.1).abs() < 1e-12);
        assert!((wrap_angle(-2.0 * PI - 0.1) + 0.1).abs() < 1e-12);
        // Just inside the lower bound stays there.
        let just_above = -PI + 1e-9;
        assert!((wrap_angle(just_above) - just_above).abs() < 1e-15);
        for k in -2000..2000 {
            let w = wrap_angle(k as f64 * 0.01 + 1000.0);
            assert!(w > -PI && w <= PI, "{w}");
        }
        assert!(wrap_angle(f64::NAN).is_nan());
    }

    // ---- writers ----

    fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
        let text = std::fs::read_to_string(path).unwrap();
        let mut lines = text.lines();
        let header = lines.next().unwrap().split(',').map(str::to_string).collect();
        let rows = lines.map(|l| l.split(',').map(|c| c.parse().unwrap()).collect()).collect();
        (header, rows)
    }

    fn dir_entries(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    fn with_truth(theta: bool, v: bool) -> InputTrace {
        let rows = (0..4)
            .map(|k| TraceRow {
                theta: theta.then_some(3.1 + k as f64),
                v: v.then_some(0.3),
                ..row(k as f64 * 1e-4)
            })
            .collect();
        InputTrace::from_rows(rows, "mem").unwrap()
    }

    fn est(k: usize) -> Estimate {
        Estimate {
            theta_hat: -3.1 + k as f64,
            v_hat: 0.1 + 0.2 * k as f64,
            psi_alpha_hat: 0.16 / 3.0,
            psi_beta_hat: -1e-300,
            locked: k % 2 == 1,
        }
    }

    #[test]
    fn output_trace_round_trips_with_error_columns() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.csv");
        let input = with_truth(true, true);
        let estimates: Vec<Estimate> = (0..4).map(est).collect();
        write_output_trace(&path, &input, &estimates).unwrap();
        let (header, rows) = read_csv(&path);
        assert_eq!(
            header,
            ["t", "theta_hat", "v_hat", "psi_alpha_hat", "psi_beta_hat", "locked", "theta_err", "v_err"]
        );
        assert_eq!(rows.len(), 4);
        for (k, r) in rows.iter().enumerate() {
            let e = est(k);
            // Shortest round-trip formatting: the same bits come back.
            assert_eq!(r[0].to_bits(), input.rows()[k].t.to_bits());
            assert_eq!(r[1].to_bits(), e.theta_hat.to_bits());
            assert_eq!(r[2].to_bits(), e.v_hat.to_bits());
            assert_eq!(r[3].to_bits(), e.psi_alpha_hat.to_bits());
            assert_eq!(r[4].to_bits(), e.psi_beta_hat.to_bits());
            assert_eq!(r[5], if k % 2 == 1 { 1.0 } else { 0.0 });
            // 3.1 - (-3.1) = 6.2 rad wraps to 6.2 - 2 pi.
            assert!((r[6] - (6.2 - 2.0 * PI)).abs() < 1e-12, "{}", r[6]);
            assert_eq!(r[7], 0.3 - e.v_hat);
        }
        assert_eq!(dir_entries(dir.path()), ["out.csv"]);
    }

    #[test]
    fn output_error_columns_follow_the_ground_truth() {
        let dir = tempfile::tempdir().unwrap();
        for (theta, v, extra) in
            [(false, false, vec![]), (true, false, vec!["theta_err"]), (false, true, vec!["v_err"])]
        {
            let path = dir.path().join("out.csv");
            let input = with_truth(theta, v);
            let estimates: Vec<Estimate> = (0..4).map(est).collect();
            write_output_trace(&path, &input, &estimates).unwrap();
            let (header, rows) = read_csv(&path);
            let mut want: Vec<&str> = OUTPUT_COLUMNS.to_vec();
            want.extend(extra);
            assert_eq!(header, want);
            assert!(rows.iter().all(|r| r.len() == want.len()));
        }
    }

    #[test]
    fn output_keeps_non_finite_estimates_visible() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.csv");
        let input = with_truth(false, false);
        let mut estimates: Vec<Estimate> = (0..4).map(est).collect();
        estimates[3].v_hat = f64::NAN;
        write_output_trace(&path, &input, &estimates).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.lines().nth(4).unwrap().contains("NaN"));
    }

    /// A replay loop whose observer fails after `fail_after` rows.
    fn replay_failing(path: &Path, input: &InputTrace, fail_after: usize) -> anyhow::Result<()> {
        let mut w = OutputTraceWriter::create(path, input)?;
        for k in 0..input.rows().len() {
            let e = if k < fail_after { Ok(est(k)) } else { Err(anyhow::anyhow!("observer failed")) };
            w.write(&e?)?;
        }
        w.finish()?;
        Ok(())
    }

    #[test]
    fn output_failure_midway_leaves_no_file_and_keeps_old_content() {
        let dir = tempfile::tempdir().unwrap();
        let input = with_truth(true, true);
        let path = dir.path().join("out.csv");
        assert!(replay_failing(&path, &input, 2).is_err());
        assert!(!path.exists());
        assert!(dir_entries(dir.path()).is_empty(), "{:?}", dir_entries(dir.path()));

        std::fs::write(&path, "old content\n").unwrap();
        assert!(replay_failing(&path, &input, 3).is_err());
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "old content\n");
        assert_eq!(dir_entries(dir.path()), ["out.csv"]);

        replay_failing(&path, &input, 4).unwrap();
        assert_eq!(read_csv(&path).1.len(), 4);
    }

    #[test]
    fn output_row_count_must_match_the_input() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.csv");
        let input = with_truth(false, true);
        let mut w = OutputTraceWriter::create(&path, &input).unwrap();
        for k in 0..3 {
            w.write(&est(k)).unwrap();
        }
        assert_has(&w.finish().unwrap_err().to_string(), &["out.csv", "3 estimate rows for 4 input rows"]);
        assert!(!path.exists());

        let mut w = OutputTraceWriter::create(&path, &input).unwrap();
        for k in 0..4 {
            w.write(&est(k)).unwrap();
        }
        assert_has(&w.write(&est(4)).unwrap_err().to_string(), &["5 estimate rows for 4 input rows"]);
        drop(w);
        assert!(!path.exists());

        let five: Vec<Estimate> = (0..5).map(est).collect();
        assert!(write_output_trace(&path, &input, &five).is_err());
        assert!(dir_entries(dir.path()).is_empty());
    }

    #[test]
    fn failed_rename_leaves_no_temporary_file() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("taken");
        std::fs::create_dir(&target).unwrap();
        std::fs::write(target.join("keep"), "x").unwrap();
        let input = with_truth(false, false);
        let estimates: Vec<Estimate> = (0..4).map(est).collect();
        let e = write_output_trace(&target, &input, &estimates).unwrap_err();
        assert_has(&e.to_string(), &["taken"]);
        assert_eq!(dir_entries(dir.path()), ["taken"]);
        // Nor does a missing directory.
        let e = write_output_trace(dir.path().join("no/such/dir/out.csv"), &input, &estimates).unwrap_err();
        assert_has(&e.to_string(), &["no/such/dir/out.csv"]);
    }

    #[test]
    fn input_trace_round_trips_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sim.csv");
        let tricky = [0.1 + 0.2, 1e-300, -0.0, 123456.789e10, f64::MIN_POSITIVE, -1.0 / 3.0];
        let rows: Vec<TraceRow> = (0..6)
            .map(|k| TraceRow {
                t: 10.0 + k as f64 * 1e-4,
                u_alpha: tricky[k],
                u_beta: -tricky[k],
                i_alpha: tricky[(k + 1) % 6],
                i_beta: 2.0,
                theta: Some(100.0 * k as f64 + 0.123),
                v: Some(tricky[(k + 2) % 6]),
                x: Some(k as f64),
            })
            .collect();
        let mut w = InputTraceWriter::create(&path, GroundTruth::ALL, &["i_d", "load_n"]).unwrap();
        for (k, r) in rows.iter().enumerate() {
            w.write(r, &[k as f64, f64::NAN]).unwrap();
        }
        w.finish().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("t,u_alpha,u_beta,i_alpha,i_beta,theta,v,x,i_d,load_n\n"));
        let back = InputTrace::read_path(&path).unwrap();
        assert_eq!(back.ground_truth(), GroundTruth::ALL);
        assert_eq!(back.rows().len(), rows.len());
        for (a, b) in back.rows().iter().zip(&rows) {
            for ((_, x), (_, y)) in a.named_values().zip(b.named_values()) {
                assert_eq!(x.to_bits(), y.to_bits());
            }
        }
        // Only the ground truth chosen is written.
        let path2 = dir.path().join("sim2.csv");
        let mut w =
            InputTraceWriter::create(&path2, GroundTruth { theta: false, v: true, x: false }, &[]).unwrap();
        for r in &rows {
            w.write(&TraceRow { theta: None, x: None, ..*r }, &[]).unwrap();
        }
        w.finish().unwrap();
        let back = InputTrace::read_path(&path2).unwrap();
        assert_eq!(back.ground_truth(), GroundTruth { theta: false, v: true, x: false });
    }

    #[test]
    fn input_writer_refuses_what_the_reader_would() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sim.csv");
        let gt = GroundTruth { theta: true, v: false, x: false };
        let good = |k: usize| TraceRow { theta: Some(0.0), ..row(k as f64 * 1e-4) };
        let start = || {
            let mut w = InputTraceWriter::create(&path, gt, &["i_d"]).unwrap();
            w.write(&good(0), &[0.0]).unwrap();
            w
        };
        let mut w = start();
        let m = w.write(&TraceRow { theta: None, ..good(1) }, &[0.0]).unwrap_err().to_string();
        assert_has(&m, &["sim.csv:3:", "`theta`", "missing"]);
        let m = w.write(&TraceRow { v: Some(1.0), ..good(1) }, &[0.0]).unwrap_err().to_string();
        assert_has(&m, &["sim.csv:3:", "`v`"]);
        let m = w.write(&good(1), &[]).unwrap_err().to_string();
        assert_has(&m, &["sim.csv:3:", "`i_d`", "0 extra values for 1"]);
        let m = w.write(&TraceRow { u_beta: f64::INFINITY, ..good(1) }, &[0.0]).unwrap_err().to_string();
        assert_has(&m, &["sim.csv:3:", "`u_beta`", "not finite"]);
        let m = w.write(&good(0), &[0.0]).unwrap_err().to_string();
        assert_has(&m, &["sim.csv:3:", "`t`", "strictly increase"]);
        // Fewer than 2 rows: nothing is published.
        assert_has(&w.finish().unwrap_err().to_string(), &["sim.csv", "only 1 data row"]);
        assert!(!path.exists());

        let mut w = start();
        w.write(&good(1), &[0.0]).unwrap();
        w.write(&good(3), &[0.0]).unwrap();
        w.write(&good(4), &[0.0]).unwrap();
        assert_has(&w.finish().unwrap_err().to_string(), &["sim.csv:4:", "`t`", "uniform"]);
        assert!(!path.exists());

        // Dropped without finish: nothing published, no temporary left.
        let mut w = start();
        w.write(&good(1), &[0.0]).unwrap();
        drop(w);
        assert!(dir_entries(dir.path()).is_empty());
    }

    /// Comment lines before the header: written as `# text` (line breaks made blanks),
    /// read back as comments, and counted in the line numbers of the writer's errors
    /// as the reader would count them.
    #[test]
    fn input_writer_comments_precede_the_header_and_count_in_line_numbers() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.csv");
        let mut w =
            InputTraceWriter::create_with_comments(&path, GroundTruth::NONE, &[], &["numeric: q24", "a\nb"])
                .unwrap();
        w.write(&row(0.0), &[]).unwrap();
        w.write(&row(1e-4), &[]).unwrap();
        let m = w.write(&row(1e-4), &[]).unwrap_err().to_string();
        assert_has(&m, &["c.csv:6:", "`t`"]);
        w.finish().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("# numeric: q24\n# a b\nt,u_alpha,"), "{text}");
        assert_eq!(InputTrace::read_path(&path).unwrap().rows().len(), 2);
    }

    #[test]
    fn input_writer_refuses_bad_extra_column_names() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sim.csv");
        for (names, bad) in [
            (vec![""], ""),
            (vec![" a"], " a"),
            (vec!["a,b"], "a,b"),
            (vec!["q\""], "q\""),
            (vec!["#a"], "#a"),
            (vec!["theta"], "theta"),
            (vec!["t"], "t"),
            (vec!["a", "b", "a"], "a"),
        ] {
            let m = InputTraceWriter::create(&path, GroundTruth::NONE, &names).err().unwrap().to_string();
            assert_has(&m, &["sim.csv", &format!("extra column name `{bad}`")]);
        }
        assert!(dir_entries(dir.path()).is_empty());
    }
}
