//! The README's figures, generated from the tools' own output so that none is restated
//! by hand (`dcfo results`).
//!
//! Every table the README shows is a file under `results/`, `results/NAME.md`, and sits in
//! the README between the markers
//!
//! ```text
//! <!-- generated:NAME -->
//! ...the file's content, byte for byte...
//! <!-- /generated -->
//! ```
//!
//! A [`Table`] renders one such file from what a tool wrote: the JSON of `--json` or of
//! its `summary.json`, or `bench/recorded.json` for the cost. Two steps, each with a
//! `--check` that writes nothing and fails on a difference:
//!
//! - `dcfo results render NAME INPUT...` renders `results/NAME.md` from the inputs;
//! - `dcfo results readme` copies every `results/NAME.md` into its README block.
//!
//! `results/regenerate` runs the tools and both steps. `host/tests/readme.rs` checks,
//! without running any tool, that every block equals its file and that the cost table
//! equals the rendering of `bench/recorded.json`; CI renders the table of its own
//! `dcfo paper` run with `--check` against `results/paper.md`.
//!
//! What a table shows is chosen to be reproducible: the figures a deterministic
//! simulation or an instruction count gives, not wall-clock rates. Numbers are rounded
//! for reading (degrees to two decimals below 10 and one above), so a last-bit
//! difference of another machine's maths library does not change a table.

use crate::qemu::QemuCpu;
use anyhow::{Context, Result, anyhow, bail};
use serde_json::Value;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The README, relative to the workspace root.
pub const README: &str = "README.md";
/// The directory of the generated tables, relative to the workspace root.
pub const RESULTS_DIR: &str = "results";
/// The line that opens a generated block, followed by the table's name and [`BEGIN_END`].
pub const BEGIN_PREFIX: &str = "<!-- generated:";
/// The end of the opening line.
pub const BEGIN_END: &str = " -->";
/// The line that closes a generated block.
pub const END: &str = "<!-- /generated -->";

/// One tool output a table is rendered from: its JSON and where it came from.
#[derive(Debug, Clone)]
pub struct Input {
    /// A label the table uses where the JSON does not name its row (`LABEL=FILE` on the
    /// command line).
    pub label: Option<String>,
    /// The file read.
    pub path: PathBuf,
    /// Its JSON: the whole file, or its last non-empty line (a tool's stdout whose last
    /// line is the `--json` object).
    pub value: Value,
}

impl Input {
    /// Reads `arg`, `FILE` or `LABEL=FILE` (a label holds no `/`).
    ///
    /// # Errors
    /// The file cannot be read, or neither it nor its last line is JSON.
    pub fn read(arg: &str) -> Result<Input> {
        let (label, path) = match arg.split_once('=') {
            Some((l, p)) if !l.is_empty() && !l.contains('/') => (Some(l.to_owned()), p),
            _ => (None, arg),
        };
        let path = PathBuf::from(path);
        let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        Ok(Input { label, value: parse_json(&text).with_context(|| path.display().to_string())?, path })
    }

    /// An input from JSON already in memory (tests).
    pub fn from_value(label: Option<&str>, path: &str, value: Value) -> Input {
        Input { label: label.map(str::to_owned), path: PathBuf::from(path), value }
    }

    /// The value at `key` (dotted: `figures.theta_err_max_deg`).
    fn at(&self, key: &str) -> Result<&Value> {
        let mut v = &self.value;
        for part in key.split('.') {
            v = v.get(part).ok_or_else(|| anyhow!("{}: no key `{key}`", self.path.display()))?;
        }
        Ok(v)
    }

    /// The number at `key`.
    fn num(&self, key: &str) -> Result<f64> {
        self.at(key)?.as_f64().ok_or_else(|| anyhow!("{}: `{key}` is not a number", self.path.display()))
    }

    /// The number at `key`, `None` for `null`.
    fn opt_num(&self, key: &str) -> Result<Option<f64>> {
        let v = self.at(key)?;
        if v.is_null() { Ok(None) } else { self.num(key).map(Some) }
    }

    /// The text at `key`.
    fn text(&self, key: &str) -> Result<&str> {
        self.at(key)?.as_str().ok_or_else(|| anyhow!("{}: `{key}` is not a string", self.path.display()))
    }

    /// The boolean at `key`.
    fn flag(&self, key: &str) -> Result<bool> {
        self.at(key)?
            .as_bool()
            .ok_or_else(|| anyhow!("{}: `{key}` is not true or false", self.path.display()))
    }

    /// The label, or an error saying the table needs one.
    fn label(&self, what: &str) -> Result<&str> {
        self.label.as_deref().ok_or_else(|| {
            anyhow!("{}: give it as LABEL=FILE (the label names the {what})", self.path.display())
        })
    }
}

/// The whole text as JSON, or else its last non-empty line.
fn parse_json(text: &str) -> Result<Value> {
    serde_json::from_str(text).or_else(|whole| {
        let last = text.lines().rev().find(|l| !l.trim().is_empty()).unwrap_or("");
        serde_json::from_str(last).map_err(|_| anyhow!("not JSON, nor is its last line: {whole}"))
    })
}

/// The tables the README shows, one per tool (and the cost).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Table {
    /// `dcfo paper`'s `summary.json`: each experiment with the CFO and the DCFO.
    Paper,
    /// `dcfo acquire --json`: the cold starts per speed.
    Acquire,
    /// `dcfo sim`'s `summary.json`, `MOTOR=FILE` each: a row per motor, a column per
    /// scenario.
    Sim,
    /// `dcfo replay --json`, `OBSERVER=FILE` each: one trace through each observer.
    Replay,
    /// `dcfo track --json`, one per motor.
    Track,
    /// `dcfo stroke --json`, one per motor.
    Stroke,
    /// `dcfo identify --sim --json`, one per motor.
    Identify,
    /// `dcfo faults --json`: the campaign.
    Faults,
    /// `dcfo hil`'s `summary.json`, one per QEMU board.
    Hil,
    /// `dcfo board --qemu --demo --json`, one per QEMU board.
    Board,
    /// `bench/recorded.json`: the control step's cost and the images' sizes.
    Cost,
}

impl Table {
    /// Every table, in the README's order.
    pub const ALL: [Table; 11] = [
        Table::Paper,
        Table::Acquire,
        Table::Sim,
        Table::Replay,
        Table::Track,
        Table::Stroke,
        Table::Identify,
        Table::Faults,
        Table::Hil,
        Table::Board,
        Table::Cost,
    ];

    /// The table's name: its block's and its file's (`results/NAME.md`).
    pub fn name(self) -> &'static str {
        match self {
            Table::Paper => "paper",
            Table::Acquire => "acquire",
            Table::Sim => "sim",
            Table::Replay => "replay",
            Table::Track => "track",
            Table::Stroke => "stroke",
            Table::Identify => "identify",
            Table::Faults => "faults",
            Table::Hil => "hil",
            Table::Board => "board",
            Table::Cost => "cost",
        }
    }

    /// The table called `name`.
    pub fn from_name(name: &str) -> Option<Table> {
        Table::ALL.into_iter().find(|t| t.name() == name)
    }

    /// The table's file under `root`.
    pub fn path(self, root: &Path) -> PathBuf {
        root.join(RESULTS_DIR).join(format!("{}.md", self.name()))
    }

    /// The table rendered from `inputs` (markdown, ending in a newline).
    ///
    /// # Errors
    /// No input, a missing label, or a key missing from an input (named with its file).
    pub fn render(self, inputs: &[Input]) -> Result<String> {
        if inputs.is_empty() {
            bail!("table {}: no input", self.name());
        }
        match self {
            Table::Paper => paper(single(self, inputs)?),
            Table::Acquire => acquire(single(self, inputs)?),
            Table::Sim => sim(inputs),
            Table::Replay => replay(inputs),
            Table::Track => track(inputs),
            Table::Stroke => stroke(inputs),
            Table::Identify => identify(inputs),
            Table::Faults => faults(single(self, inputs)?),
            Table::Hil => hil(inputs),
            Table::Board => board(inputs),
            Table::Cost => cost(single(self, inputs)?),
        }
    }
}

fn single(table: Table, inputs: &[Input]) -> Result<&Input> {
    match inputs {
        [one] => Ok(one),
        _ => bail!("table {} is rendered from one input, got {}", table.name(), inputs.len()),
    }
}

/// Degrees: two decimals below 10, one from 10 on.
fn deg(x: f64) -> String {
    if x.abs() < 10.0 { format!("{x:.2}") } else { format!("{x:.1}") }
}

/// An optional number with `f`, `—` for none.
fn or_dash(x: Option<f64>, f: impl Fn(f64) -> String) -> String {
    x.map_or_else(|| "—".to_owned(), f)
}

/// Milliseconds of `s` seconds, whole.
fn ms(s: f64) -> String {
    format!("{:.0}", s * 1e3)
}

/// An integer with thousands separated by commas.
fn thousands(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// A motor argument as the table names it: `motors/salient.toml` as `salient`.
fn motor_name(arg: &str) -> String {
    Path::new(arg).file_stem().and_then(|s| s.to_str()).unwrap_or(arg).to_owned()
}

fn paper(input: &Input) -> Result<String> {
    let mut s = String::from(
        "| experiment | the paper reports | CFO max / rms (°) | DCFO max / rms (°) | flux offset at the end, CFO / DCFO (Wb) | DCFO false-lock samples |\n\
         |---|---|--:|--:|--:|--:|\n",
    );
    let scenarios = list(input, "scenarios")?;
    for i in 0..scenarios.len() {
        let get = |key: &str| -> Result<f64> { num_in(input, scenarios, i, key) };
        writeln!(
            s,
            "| {} | {} | {} / {} | **{} / {}** | {:.4} / {:.4} | {} |",
            str_in(input, scenarios, i, "description")?,
            str_in(input, scenarios, i, "paper")?,
            deg(get("cfo.theta_err_max_deg")?),
            deg(get("cfo.theta_err_rms_deg")?),
            deg(get("dcfo.theta_err_max_deg")?),
            deg(get("dcfo.theta_err_rms_deg")?),
            get("cfo.flux_offset_end_wb")?,
            get("dcfo.flux_offset_end_wb")?,
            get("dcfo.false_lock_samples")?,
        )?;
    }
    Ok(s)
}

/// The number at `key` of the `i`th element of `list` (an array inside `input`).
fn num_in(input: &Input, list: &[Value], i: usize, key: &str) -> Result<f64> {
    let mut v = &list[i];
    for part in key.split('.') {
        v = v.get(part).ok_or_else(|| anyhow!("{}: element {i}: no key `{key}`", input.path.display()))?;
    }
    v.as_f64().ok_or_else(|| anyhow!("{}: element {i}: `{key}` is not a number", input.path.display()))
}

/// The number or `null` at `key` of the `i`th element of `list`.
fn opt_num_in(input: &Input, list: &[Value], i: usize, key: &str) -> Result<Option<f64>> {
    match list[i].get(key) {
        Some(Value::Null) => Ok(None),
        _ => num_in(input, list, i, key).map(Some),
    }
}

/// The text at `key` of the `i`th element of `list`.
fn str_in<'a>(input: &Input, list: &'a [Value], i: usize, key: &str) -> Result<&'a str> {
    list[i]
        .get(key)
        .and_then(Value::as_str)
        .ok_or_else(|| anyhow!("{}: element {i}: no text `{key}`", input.path.display()))
}

fn list<'a>(input: &'a Input, key: &str) -> Result<&'a [Value]> {
    input
        .at(key)?
        .as_array()
        .map(Vec::as_slice)
        .ok_or_else(|| anyhow!("{}: `{key}` is not a list", input.path.display()))
}

fn acquire(input: &Input) -> Result<String> {
    let speeds = list(input, "speeds")?;
    let mut s = String::from(
        "| speed (m/s) | f_e (Hz) | budget (ms) | + lock median / max (ms) | + over budget | − lock median / max (ms) | − over budget | Q8.24 − f32, max (°) |\n\
         |--:|--:|--:|--:|--:|--:|--:|--:|\n",
    );
    let lock = |i: usize| -> Result<String> {
        let median = opt_num_in(input, speeds, i, "lock_time_median_s")?;
        let max = opt_num_in(input, speeds, i, "lock_time_max_s")?;
        Ok(format!("{} / {}", or_dash(median, ms), max.map_or_else(|| "never".to_owned(), ms)))
    };
    for i in 0..speeds.len() {
        let v = num_in(input, speeds, i, "speed_m_per_s")?;
        if v < 0.0 {
            continue;
        }
        let Some(j) = (0..speeds.len()).find(|&j| num_in(input, speeds, j, "speed_m_per_s").ok() == Some(-v))
        else {
            bail!("{}: speed {v} m/s has no row for {} m/s", input.path.display(), -v);
        };
        let q24 = [i, j]
            .iter()
            .map(|&k| opt_num_in(input, speeds, k, "q24_deviation_max_deg"))
            .collect::<Result<Vec<_>>>()?
            .into_iter()
            .flatten()
            .reduce(f64::max);
        writeln!(
            s,
            "| {v} | {:.1} | {} | {} | {} | {} | {} | {} |",
            num_in(input, speeds, i, "electrical_hz")?,
            ms(num_in(input, speeds, i, "budget_s")?),
            lock(i)?,
            num_in(input, speeds, i, "budget_violations")?,
            lock(j)?,
            num_in(input, speeds, j, "budget_violations")?,
            or_dash(q24, |d| format!("{d:.2}")),
        )?;
    }
    writeln!(
        s,
        "\n{} cold starts: {} over budget, {} never locked, {} with a false lock; the longest lock {} ms; \
         Q8.24 within {}° of f32.",
        input.num("runs")?,
        input.num("lock_time_budget_violations")?,
        input.num("never_locked")?,
        input.num("false_locks")?,
        or_dash(input.opt_num("lock_time_max_s")?, |t| format!("{:.0}", t * 1e3)),
        or_dash(input.opt_num("q24_deviation_max_deg")?, |d| format!("{d:.2}")),
    )?;
    Ok(s)
}

fn sim(inputs: &[Input]) -> Result<String> {
    let mut rows: Vec<&str> = Vec::new();
    let mut columns: Vec<&str> = Vec::new();
    for input in inputs {
        let row = input.label("motor")?;
        if !rows.contains(&row) {
            rows.push(row);
        }
        let col = input.text("scenario")?;
        if !columns.contains(&col) {
            columns.push(col);
        }
    }
    let mut s = String::from("| motor |");
    for c in &columns {
        write!(s, " `{c}` |")?;
    }
    s.push_str("\n|---|");
    s.push_str(&"--:|".repeat(columns.len()));
    s.push('\n');
    for row in &rows {
        write!(s, "| {row} |")?;
        for col in &columns {
            let cell = inputs
                .iter()
                .find(|i| i.label.as_deref() == Some(*row) && i.text("scenario").ok() == Some(*col));
            let text = match cell {
                None => "—".to_owned(),
                Some(i) => {
                    let faults = i.text("faults")?;
                    let figures = format!(
                        "{} / {}",
                        deg(i.num("figures.theta_err_max_deg")?),
                        deg(i.num("figures.theta_err_rms_deg")?)
                    );
                    if faults == "none" { figures } else { format!("{figures}, {faults}") }
                }
            };
            write!(s, " {text} |")?;
        }
        s.push('\n');
    }
    Ok(s)
}

fn replay(inputs: &[Input]) -> Result<String> {
    let false_locks = inputs.iter().all(|i| i.value.get("false_lock_samples").is_some());
    let mut s = String::from(
        "| observer | angle error rms / max (°) | speed error rms / max (m/s) | flux amplitude error rms (Wb) |",
    );
    s.push_str(if false_locks {
        " false-lock samples |\n|---|--:|--:|--:|--:|\n"
    } else {
        "\n|---|--:|--:|--:|\n"
    });
    for i in inputs {
        write!(
            s,
            "| {} | {} / {} | {:.4} / {:.4} | {:.4} |",
            i.label("observer")?,
            deg(i.num("theta_err_rms_deg")?),
            deg(i.num("theta_err_max_deg")?),
            i.num("v_err_rms")?,
            i.num("v_err_max")?,
            i.num("psi_amp_err_rms_wb")?,
        )?;
        if false_locks {
            write!(s, " {} |", thousands(i.num("false_lock_samples")? as u64))?;
        }
        s.push('\n');
    }
    Ok(s)
}

/// `dcfo track`: per motor, the f32 estimator's re-lock after a reversal and its error
/// through the sharp steps, the false locks of both number types, and how far Q8.24's
/// transient error is from f32's.
fn track(inputs: &[Input]) -> Result<String> {
    let mut s = String::from(
        "| motor | re-lock after a fast reversal / on a stroke (periods, ≤ 2) | error through a sharp / a wide step (°, ≤ 8) | false-lock samples | Q8.24 − f32, transient (°) |\n\
         |---|--:|--:|--:|--:|\n",
    );
    for input in inputs {
        let profiles = list(input, "profiles")?;
        let find = |name: &str, numeric: &str| -> Result<usize> {
            (0..profiles.len())
                .find(|&i| {
                    profiles[i].get("profile").and_then(Value::as_str) == Some(name)
                        && profiles[i].get("numeric").and_then(Value::as_str) == Some(numeric)
                })
                .ok_or_else(|| anyhow!("{}: no `{name}` profile in {numeric}", input.path.display()))
        };
        let relock = |name: &str| -> Result<String> {
            let i = find(name, "f32")?;
            Ok(opt_num_in(input, profiles, i, "relock_periods_max")?
                .map_or_else(|| "never".to_owned(), |p| format!("{p:.2}")))
        };
        let transient = |name: &str| -> Result<f64> {
            num_in(input, profiles, find(name, "f32")?, "transient_err_max_deg")
        };
        let mut false_locks = 0.0;
        let mut q24_gap: f64 = 0.0;
        for i in 0..profiles.len() {
            false_locks += num_in(input, profiles, i, "false_lock_samples")?;
            if str_in(input, profiles, i, "numeric")? == "q24" {
                let name = str_in(input, profiles, i, "profile")?;
                let f32_err = transient(name)?;
                q24_gap = q24_gap.max((num_in(input, profiles, i, "transient_err_max_deg")? - f32_err).abs());
            }
        }
        writeln!(
            s,
            "| {} | {} / {} | {} / {} | {} | {} |",
            motor_name(input.text("motor")?),
            relock("reversal")?,
            relock("stroke")?,
            deg(transient("step")?),
            deg(transient("step-wide")?),
            false_locks,
            deg(q24_gap),
        )?;
    }
    Ok(s)
}

fn stroke(inputs: &[Input]) -> Result<String> {
    let mut s = String::from(
        "| motor | moves / reversals / faults | max \\|x̂ − x\\| (≤ τ/4) | final \\|x̂ − x\\| (≤ τ/60, on HFI τ/18) | re-lock, longest (≤ 100 ms) | current step at a transition (limit) | speed overshoot, cruising (≤ 10 %) |\n\
         |---|--:|--:|--:|--:|--:|--:|\n",
    );
    for i in inputs {
        let tau_mm = i.num("pole_pitch_m")? * 1e3;
        writeln!(
            s,
            "| {} | {} / {} / {} | {:.2} mm ({:.2}) | {:.2} mm ({:.2}) | {} | {} ({:.3}) | {} |",
            motor_name(i.text("motor")?),
            i.num("moves_done")?,
            i.num("reversals")?,
            i.num("faults")?,
            i.num("x_err_max_m")? * 1e3,
            tau_mm / 4.0,
            i.num("x_err_final_m")? * 1e3,
            i.num("x_err_final_floor_m")? * 1e3,
            // A stroke below the motor's back-EMF floor never leaves the low-speed mode; an
            // exit the drive missed is marked as an unmet floor.
            match (i.num("exits_missed")?, i.opt_num("relock_time_max_s")?) {
                (missed, _) if missed > 0.0 => format!("**{missed} missed**"),
                (_, None) => "low-speed mode throughout".into(),
                (_, Some(t)) => format!("{} ms", ms(t)),
            },
            i.opt_num("current_ref_step_transition_max_a")?.map_or("none".into(), |a| format!("{a:.3} A")),
            i.num("current_step_limit_a")?,
            // Over its floor: in bold, as the fault table marks an unmet expectation.
            match i.num("speed_overshoot_max_pct")? {
                pct if pct > crate::commands::stroke::SPEED_OVERSHOOT_FLOOR_PCT => format!("**{pct:.1} %**"),
                pct => format!("{pct:.1} %"),
            },
        )?;
    }
    Ok(s)
}

fn identify(inputs: &[Input]) -> Result<String> {
    let mut s = String::from(
        "| motor | Rs (terminal) | Rs against the winding | Ld | Lq | ψf | inverter voltage error |\n\
         |---|--:|--:|--:|--:|--:|--:|\n",
    );
    for i in inputs {
        write!(s, "| {} |", motor_name(i.text("motor")?))?;
        for key in ["rs_ohm", "rs_winding_ohm", "ld_h", "lq_h", "psi_f_wb", "voltage_error_v"] {
            write!(s, " {:+.2} % |", i.num(&format!("{key}.err_pct"))?)?;
        }
        s.push('\n');
    }
    Ok(s)
}

/// One case of the fault campaign as a table cell pair: its name, and what happened
/// (for a trip the fault and when, for a ride-through the error it kept), marked when
/// not as expected.
struct FaultCase {
    name: String,
    trip: bool,
    bound: String,
    happened: String,
}

fn fault_case(input: &Input, results: &[Value], i: usize) -> Result<FaultCase> {
    let expected = str_in(input, results, i, "expected")?;
    let met = results[i]
        .get("met")
        .and_then(Value::as_bool)
        .ok_or_else(|| anyhow!("{}: element {i}: no `met`", input.path.display()))?;
    let trip = expected.starts_with("trip");
    let happened = if trip {
        let faults = str_in(input, results, i, "faults")?;
        let after = opt_num_in(input, results, i, "detect_s")?;
        format!("{faults}{}", after.map_or_else(String::new, |t| format!(" after {:.1} ms", t * 1e3)))
    } else {
        // The speed drive's angle error over the last 0.5 s, or the positioning drive's
        // distance from its target at the end.
        let err = match opt_num_in(input, results, i, "steady_err_deg")? {
            Some(deg) => Some(format!("{deg:.1}°")),
            None => opt_num_in(input, results, i, "x_off_target_m")?.map(|m| format!("{:.2} mm", m * 1e3)),
        };
        format!("{} {}", str_in(input, results, i, "faults")?, err.unwrap_or_else(|| "—".to_owned()))
            .trim_start_matches("none ")
            .to_owned()
    };
    // "trip X <= 1 period" / "ride through, <= 5 deg": the bound after "<= ".
    let bound = expected.rsplit_once("<= ").map_or(expected, |(_, b)| b).replace(" deg", "°");
    let happened = if met { happened } else { format!("**{happened}, expected {expected}**") };
    Ok(FaultCase { name: str_in(input, results, i, "name")?.to_owned(), trip, bound, happened })
}

fn faults(input: &Input) -> Result<String> {
    let results = list(input, "results")?;
    let cases = (0..results.len()).map(|i| fault_case(input, results, i)).collect::<Result<Vec<_>>>()?;
    let (trips, rides): (Vec<&FaultCase>, Vec<&FaultCase>) = cases.iter().partition(|c| c.trip);
    let mut s = String::from(
        "| trips | latched, detected after | rides through | angle error over the last 0.5 s, or distance off target at the end (bound) |\n\
         |---|---|---|--:|\n",
    );
    for k in 0..trips.len().max(rides.len()) {
        let trip =
            trips.get(k).map_or_else(|| " | ".to_owned(), |c| format!("`{}` | {}", c.name, c.happened));
        let ride = rides
            .get(k)
            .map_or_else(|| " | ".to_owned(), |c| format!("`{}` | {} ({})", c.name, c.happened, c.bound));
        writeln!(s, "| {trip} | {ride} |")?;
    }
    writeln!(
        s,
        "\n{} cases, {} not as expected, {} silent failures (the estimate claimed locked while more than 30° \
         off for over 50 ms); every trip switched the bridge off within {} period(s) of its condition.",
        input.num("cases")?,
        input.num("unmet")?,
        input.num("silent_failures")?,
        input.num("max_bridge_off_periods")?,
    )?;
    Ok(s)
}

/// The QEMU board a `qemu_cpu` names.
fn board_name(cpu: &str) -> &str {
    match cpu {
        "m4f" => "Cortex-M4F (`mps2-an386`), f32",
        "m3" => "Cortex-M3 (`mps2-an385`), Q8.24",
        other => other,
    }
}

fn hil(inputs: &[Input]) -> Result<String> {
    let mut s = String::from(
        "| target | scenario | angle error max / rms (°) | estimates equal to the in-process drive's | deepest stack (B) |\n\
         |---|---|--:|--:|--:|\n",
    );
    for i in inputs {
        let equal = match i.at("equivalence")? {
            Value::Null => "not checked".to_owned(),
            _ => {
                let n = i.num("equivalence.samples")? as u64;
                let differing = i.num("equivalence.differing")? as u64;
                format!("{} of {}", thousands(n - differing.min(n)), thousands(n))
            }
        };
        writeln!(
            s,
            "| {} | `{}` | {} / {} | {} | {} |",
            board_name(i.text("qemu_cpu")?),
            i.text("scenario")?,
            deg(i.num("figures.theta_err_max_deg")?),
            deg(i.num("figures.theta_err_rms_deg")?),
            equal,
            or_dash(i.opt_num("stack_high_water_bytes")?, |b| thousands(b as u64)),
        )?;
    }
    Ok(s)
}

fn board(inputs: &[Input]) -> Result<String> {
    let mut s = String::from(
        "| drive image | state reached | speed estimate (m/s) | faults | samples captured | replayed estimates equal, bit for bit |\n\
         |---|---|--:|---|--:|---|\n",
    );
    for i in inputs {
        let numeric = i.text("numeric")?;
        let image = match numeric {
            "f32" => "`qemu_drive`, Cortex-M4F, `Drive<f32>`",
            "q24" => "`qemu_drive`, Cortex-M3, `Drive<Q24>`",
            other => other,
        };
        let samples = i.num("capture_samples")? as u64;
        let equal = if i.flag("replay_identical")? {
            format!("all {}", thousands(samples))
        } else {
            format!("{} differ", thousands(i.num("replay_differing")? as u64))
        };
        writeln!(
            s,
            "| {image} | `{}` | {} | {} | {} | {equal} |",
            i.text("state_reached")?,
            or_dash(i.opt_num("speed_m_per_s")?, |v| format!("{v:.3}")),
            i.text("faults")?,
            thousands(samples),
        )?;
    }
    Ok(s)
}

/// What a per-core figure of `bench/recorded.json` (`NAME_m4f_f32`, `NAME_m3_q24`)
/// measures.
fn cost_row(name: &str) -> String {
    match name {
        "step" => "`Drive::step`, mean in `Running`".to_owned(),
        "worst_step" => "`Drive::step`, the worst of the run".to_owned(),
        "estimator" => "the estimator, mean in `Running`".to_owned(),
        "worst_estimator" => "the estimator, the worst of the run".to_owned(),
        other => format!("`{other}`"),
    }
}

/// Which image a size of `bench/recorded.json` (`flash_IMAGE_b`, `ram_IMAGE_b`) is.
fn image_row(image: &str) -> String {
    match image {
        "esc1_drive" => "`b_g431b_esc1` (the ESC1 drive image)".to_owned(),
        "esc1_hil" => "`b_g431b_esc1_hil`".to_owned(),
        "qemu_hil_m4f" => "`qemu_hil`, Cortex-M4F".to_owned(),
        "qemu_hil_m3" => "`qemu_hil`, Cortex-M3".to_owned(),
        other => format!("`{other}`"),
    }
}

fn cost(input: &Input) -> Result<String> {
    let figures = input
        .value
        .as_object()
        .ok_or_else(|| anyhow!("{}: not a JSON object of figures", input.path.display()))?;
    let mut steps: Vec<(String, Option<u64>, Option<u64>)> = Vec::new();
    let mut images: Vec<(String, Option<u64>, Option<u64>)> = Vec::new();
    for (key, v) in figures {
        let n =
            v.as_u64().ok_or_else(|| anyhow!("{}: `{key}` is not a whole number", input.path.display()))?;
        // (table, row, column 0 or 1)
        let (table, row, col) = if let Some(name) = key.strip_suffix("_m4f_f32") {
            (&mut steps, name, 0)
        } else if let Some(name) = key.strip_suffix("_m3_q24") {
            (&mut steps, name, 1)
        } else if let Some(image) = key.strip_prefix("flash_").and_then(|k| k.strip_suffix("_b")) {
            (&mut images, image, 0)
        } else if let Some(image) = key.strip_prefix("ram_").and_then(|k| k.strip_suffix("_b")) {
            (&mut images, image, 1)
        } else {
            bail!(
                "{}: `{key}` is neither a per-core figure (NAME_m4f_f32, NAME_m3_q24) nor a size \
                 (flash_IMAGE_b, ram_IMAGE_b); teach dcfo_host::commands::results::cost it",
                input.path.display()
            );
        };
        let entry = match table.iter_mut().find(|(r, _, _)| r == row) {
            Some(e) => e,
            None => {
                table.push((row.to_owned(), None, None));
                table.last_mut().ok_or_else(|| anyhow!("unreachable: pushed"))?
            }
        };
        if col == 0 { entry.1 = Some(n) } else { entry.2 = Some(n) }
    }
    let order = ["step", "worst_step", "estimator", "worst_estimator"];
    steps.sort_by_key(|(r, _, _)| order.iter().position(|o| o == r).unwrap_or(order.len()));
    let cell =
        |x: Option<u64>, unit: &str| x.map_or_else(|| "—".to_owned(), |n| format!("{}{unit}", thousands(n)));
    let mut s = String::from("| instructions | Cortex-M4F, f32 | Cortex-M3, Q8.24 |\n|---|--:|--:|\n");
    for (row, m4f, m3) in &steps {
        writeln!(s, "| {} | {} | {} |", cost_row(row), cell(*m4f, ""), cell(*m3, ""))?;
    }
    // The PWM rate the worst step allows on the real cores (QemuCpu::clock_and_cpi).
    if let Some((_, m4f, m3)) = steps.iter().find(|(r, _, _)| r == "worst_step") {
        let pwm = |cpu: QemuCpu, n: Option<u64>| {
            let (clock, cpi) = cpu.clock_and_cpi();
            n.map_or_else(
                || "—".to_owned(),
                |n| format!("{:.1} kHz ({:.0} MHz, CPI {cpi})", cpu.pwm_max_hz(n) / 1e3, clock / 1e6),
            )
        };
        writeln!(
            s,
            "| the PWM rate the worst step allows | {} | {} |",
            pwm(QemuCpu::M4f, *m4f),
            pwm(QemuCpu::M3, *m3)
        )?;
    }
    if !images.is_empty() {
        s.push_str("\n| image | flash | static RAM |\n|---|--:|--:|\n");
        for (image, flash, ram) in &images {
            writeln!(s, "| {} | {} | {} |", image_row(image), cell(*flash, " B"), cell(*ram, " B"))?;
        }
    }
    Ok(s)
}

/// A generated block of the README.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Block {
    /// The table's name.
    pub name: String,
    /// The lines between the markers, each with its newline.
    pub content: String,
    /// The opening marker's line, from 1.
    pub line: usize,
}

/// The generated blocks of `readme`, in order.
///
/// # Errors
/// A block that is not closed, a closing marker without an opening one, a block opened
/// inside another, or a name used twice.
pub fn blocks(readme: &str) -> Result<Vec<Block>> {
    let mut out: Vec<Block> = Vec::new();
    let mut open: Option<Block> = None;
    for (n, line) in readme.lines().enumerate() {
        let n = n + 1;
        if let Some(name) = line.strip_prefix(BEGIN_PREFIX).and_then(|l| l.strip_suffix(BEGIN_END)) {
            if let Some(b) = &open {
                bail!("README line {n}: block `{name}` opened inside block `{}` (line {})", b.name, b.line);
            }
            if out.iter().any(|b| b.name == name) {
                bail!("README line {n}: block `{name}` appears twice");
            }
            open = Some(Block { name: name.to_owned(), content: String::new(), line: n });
        } else if line == END {
            match open.take() {
                Some(b) => out.push(b),
                None => bail!("README line {n}: `{END}` without a block to close"),
            }
        } else if let Some(b) = &mut open {
            b.content.push_str(line);
            b.content.push('\n');
        }
    }
    if let Some(b) = open {
        bail!("README line {}: block `{}` is not closed by `{END}`", b.line, b.name);
    }
    Ok(out)
}

/// The README's differences from the results files under `root`: one line per block
/// whose content is not its file's, per block without a file and per results file that
/// no block shows. Empty when they agree.
///
/// # Errors
/// The blocks cannot be parsed ([`blocks`]) or a results file cannot be read.
pub fn readme_differences(readme: &str, root: &Path) -> Result<Vec<String>> {
    let blocks = blocks(readme)?;
    let mut out = Vec::new();
    for b in &blocks {
        let path = root.join(RESULTS_DIR).join(format!("{}.md", b.name));
        match std::fs::read_to_string(&path) {
            Ok(file) if file == b.content => {}
            Ok(file) => out.push(format!(
                "README block `{}` (line {}) differs from {}{}",
                b.name,
                b.line,
                path.display(),
                first_difference(&b.content, &file)
            )),
            Err(_) => {
                out.push(format!("README block `{}` (line {}): no file {}", b.name, b.line, path.display()))
            }
        }
    }
    for table in Table::ALL {
        if table.path(root).exists() && !blocks.iter().any(|b| b.name == table.name()) {
            out.push(format!("{} is in no README block `{}`", table.path(root).display(), table.name()));
        }
    }
    Ok(out)
}

/// `readme` with every block's content replaced by its results file under `root`.
///
/// # Errors
/// As [`readme_differences`], and a block whose file does not exist.
pub fn updated_readme(readme: &str, root: &Path) -> Result<String> {
    blocks(readme)?;
    let mut out = String::with_capacity(readme.len());
    let mut inside = false;
    for line in readme.split_inclusive('\n') {
        let bare = line.trim_end_matches('\n');
        if let Some(name) = bare.strip_prefix(BEGIN_PREFIX).and_then(|l| l.strip_suffix(BEGIN_END)) {
            let path = root.join(RESULTS_DIR).join(format!("{name}.md"));
            let file = std::fs::read_to_string(&path)
                .with_context(|| format!("block `{name}`: {}", path.display()))?;
            out.push_str(line);
            out.push_str(&file);
            inside = true;
        } else if bare == END {
            out.push_str(line);
            inside = false;
        } else if !inside {
            out.push_str(line);
        }
    }
    Ok(out)
}

/// Where `got` first departs from `want`, as `: line N: "..." against "..."`.
fn first_difference(got: &str, want: &str) -> String {
    let (g, w): (Vec<&str>, Vec<&str>) = (got.lines().collect(), want.lines().collect());
    for k in 0..g.len().max(w.len()) {
        let (a, b) = (g.get(k).copied().unwrap_or("<end>"), w.get(k).copied().unwrap_or("<end>"));
        if a != b {
            return format!(": its line {}: {a:?} against the file's {b:?}", k + 1);
        }
    }
    String::from(": only in the final newline")
}

/// What `dcfo results` is asked to do.
#[derive(Debug, Clone)]
pub enum Params {
    /// Render `table` from `inputs` (`FILE` or `LABEL=FILE`) into its file under `root`,
    /// or with `check` compare with that file.
    Render {
        /// The workspace root.
        root: PathBuf,
        /// The table.
        table: Table,
        /// The tool outputs.
        inputs: Vec<String>,
        /// Compare, write nothing.
        check: bool,
    },
    /// Copy every results file into its README block, or with `check` compare.
    Readme {
        /// The workspace root.
        root: PathBuf,
        /// Compare, write nothing.
        check: bool,
    },
}

/// `dcfo results`: `Ok(false)` when a check found a difference (printed on stderr).
///
/// # Errors
/// An input or a file cannot be read or written, or a table cannot be rendered.
pub fn run_command(params: &Params) -> Result<bool> {
    match params {
        Params::Render { root, table, inputs, check } => {
            let inputs = inputs.iter().map(|a| Input::read(a)).collect::<Result<Vec<_>>>()?;
            let text = table.render(&inputs)?;
            let path = table.path(root);
            if *check {
                let committed =
                    std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
                if committed != text {
                    eprintln!(
                        "dcfo results: {} differs from what the inputs render{}; run results/regenerate, \
                         or say in the commit why the figures moved",
                        path.display(),
                        first_difference(&text, &committed)
                    );
                    return Ok(false);
                }
                eprintln!("dcfo results: {} matches", path.display());
            } else {
                std::fs::create_dir_all(root.join(RESULTS_DIR))?;
                std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
                eprintln!("dcfo results: wrote {}", path.display());
            }
            Ok(true)
        }
        Params::Readme { root, check } => {
            let path = root.join(README);
            let readme =
                std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
            if *check {
                let differences = readme_differences(&readme, root)?;
                for d in &differences {
                    eprintln!("dcfo results: {d}");
                }
                Ok(differences.is_empty())
            } else {
                let updated = updated_readme(&readme, root)?;
                if updated != readme {
                    std::fs::write(&path, updated).with_context(|| format!("writing {}", path.display()))?;
                    eprintln!("dcfo results: updated {}", path.display());
                }
                Ok(true)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn blocks_are_found_and_malformed_ones_refused() {
        let text = "a\n<!-- generated:paper -->\n| x |\n<!-- /generated -->\nb\n<!-- generated:cost -->\n<!-- /generated -->\n";
        let b = blocks(text).unwrap();
        assert_eq!(b.len(), 2);
        assert_eq!((b[0].name.as_str(), b[0].content.as_str(), b[0].line), ("paper", "| x |\n", 2));
        assert_eq!((b[1].name.as_str(), b[1].content.as_str()), ("cost", ""));
        for bad in [
            "<!-- generated:paper -->\nx\n",
            "x\n<!-- /generated -->\n",
            "<!-- generated:a -->\n<!-- generated:b -->\n<!-- /generated -->\n",
            "<!-- generated:a -->\n<!-- /generated -->\n<!-- generated:a -->\n<!-- /generated -->\n",
        ] {
            assert!(blocks(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn a_block_is_replaced_by_its_file_and_a_difference_is_reported() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join(RESULTS_DIR)).unwrap();
        std::fs::write(dir.path().join("results/paper.md"), "| new |\n").unwrap();
        let readme = "top\n<!-- generated:paper -->\n| old |\n| older |\n<!-- /generated -->\nend\n";
        let diff = readme_differences(readme, dir.path()).unwrap();
        assert_eq!(diff.len(), 1, "{diff:?}");
        assert!(diff[0].contains("`paper`") && diff[0].contains("| old |"), "{diff:?}");
        let updated = updated_readme(readme, dir.path()).unwrap();
        assert_eq!(updated, "top\n<!-- generated:paper -->\n| new |\n<!-- /generated -->\nend\n");
        assert!(readme_differences(&updated, dir.path()).unwrap().is_empty());
        // A results file no block shows, and a block without a file, are differences.
        std::fs::write(dir.path().join("results/cost.md"), "x\n").unwrap();
        let diff = readme_differences(&updated, dir.path()).unwrap();
        assert!(diff.len() == 1 && diff[0].contains("cost.md"), "{diff:?}");
        let diff = readme_differences("<!-- generated:sim -->\n<!-- /generated -->\n", dir.path()).unwrap();
        assert!(diff.iter().any(|d| d.contains("no file")), "{diff:?}");
    }

    #[test]
    fn the_cost_table_has_a_row_per_figure_and_refuses_an_unknown_key() {
        let input = Input::from_value(
            None,
            "recorded.json",
            json!({"estimator_m3_q24": 3132, "step_m4f_f32": 2789, "step_m3_q24": 10219,
                   "worst_step_m4f_f32": 3400, "worst_step_m3_q24": 7200,
                   "flash_esc1_drive_b": 75260, "ram_esc1_drive_b": 8112, "flash_qemu_hil_m3_b": 95128}),
        );
        let t = Table::Cost.render(&[input]).unwrap();
        assert!(t.contains("| `Drive::step`, mean in `Running` | 2,789 | 10,219 |"), "{t}");
        assert!(t.contains("| the estimator, mean in `Running` | — | 3,132 |"), "{t}");
        assert!(t.contains("| `b_g431b_esc1` (the ESC1 drive image) | 75,260 B | 8,112 B |"), "{t}");
        assert!(t.contains("| `qemu_hil`, Cortex-M3 | 95,128 B | — |"), "{t}");
        // 170 MHz / (1.5 x 3,400) = 33.3 kHz; 72 MHz / (2 x 7,200) = 5 kHz.
        assert!(
            t.contains("| the PWM rate the worst step allows | 33.3 kHz (170 MHz, CPI 1.5) | 5.0 kHz (72 MHz, CPI 2) |"),
            "{t}"
        );
        let step = t.find("`Drive::step`, mean").unwrap();
        assert!(step < t.find("the estimator").unwrap(), "{t}");
        let unknown = Input::from_value(None, "recorded.json", json!({"pwm_hz": 1}));
        let e = Table::Cost.render(&[unknown]).unwrap_err().to_string();
        assert!(e.contains("pwm_hz"), "{e}");
    }

    #[test]
    fn a_missing_key_is_named_with_its_file() {
        let input = Input::from_value(None, "out/stroke.json", json!({"motor": "paper"}));
        let e = Table::Stroke.render(&[input]).unwrap_err().to_string();
        assert!(e.contains("out/stroke.json") && e.contains("pole_pitch_m"), "{e}");
        let unlabelled = Input::from_value(None, "s.json", json!({"scenario": "steady"}));
        assert!(Table::Sim.render(&[unlabelled]).unwrap_err().to_string().contains("LABEL=FILE"));
    }

    #[test]
    fn fault_cases_are_split_into_trips_and_ride_throughs_and_a_miss_is_marked() {
        let case = |name: &str, expected: &str, faults: &str, detect: Value, err: Value, met: bool| {
            json!({"name": name, "expected": expected, "faults": faults, "detect_s": detect,
                   "steady_err_deg": err, "met": met})
        };
        let input = Input::from_value(
            None,
            "faults.json",
            json!({"cases": 4, "unmet": 1, "silent_failures": 0, "max_bridge_off_periods": 1, "results": [
                case("open-phase", "trip CURRENT_CONTROL <= 1 period", "CURRENT_CONTROL", json!(0.0776), Value::Null, true),
                case("lock-loss", "ride through, <= 5 deg", "none", Value::Null, json!(1.26), true),
                case("load-400N", "trip OVERLOAD <= 1 period", "LOCK_LOST", json!(0.3), Value::Null, false),
                json!({"name": "stroke-load-20N", "expected": "complete, <= 3.75 mm", "faults": "none",
                       "detect_s": null, "steady_err_deg": null, "x_off_target_m": 0.0021, "met": true}),
            ]}),
        );
        let t = Table::Faults.render(&[input]).unwrap();
        let rows: Vec<&str> = t.lines().collect();
        assert_eq!(
            rows[2], "| `open-phase` | CURRENT_CONTROL after 77.6 ms | `lock-loss` | 1.3° (5°) |",
            "{t}"
        );
        assert_eq!(
            rows[3],
            "| `load-400N` | **LOCK_LOST after 300.0 ms, expected trip OVERLOAD <= 1 period** | `stroke-load-20N` | 2.10 mm (3.75 mm) |",
            "{t}"
        );
        assert!(t.contains("4 cases, 1 not as expected, 0 silent failures"), "{t}");
    }

    #[test]
    fn the_track_table_takes_f32_figures_and_the_largest_q24_gap() {
        let fig = |profile: &str, numeric: &str, relock: Value, transient: f64, false_locks: u64| {
            json!({"profile": profile, "numeric": numeric, "relock_periods_max": relock,
                   "transient_err_max_deg": transient, "false_lock_samples": false_locks})
        };
        let input = Input::from_value(
            None,
            "track.json",
            json!({"motor": "motors/salient.toml", "profiles": [
                fig("reversal", "f32", json!(1.57), 41.4, 0),
                fig("reversal", "q24", json!(1.6), 41.0, 0),
                fig("stroke", "f32", Value::Null, 10.0, 2),
                fig("stroke", "q24", json!(1.3), 10.0, 1),
                fig("step", "f32", Value::Null, 11.4, 0),
                fig("step", "q24", Value::Null, 11.5, 0),
                fig("step-wide", "f32", Value::Null, 6.5, 0),
                fig("step-wide", "q24", Value::Null, 7.25, 0),
            ]}),
        );
        let t = Table::Track.render(&[input]).unwrap();
        assert_eq!(t.lines().nth(2), Some("| salient | 1.57 / never | 11.4 / 6.50 | 3 | 0.75 |"), "{t}");
        let missing = Input::from_value(None, "t.json", json!({"motor": "paper", "profiles": []}));
        let e = Table::Track.render(&[missing]).unwrap_err().to_string();
        assert!(e.contains("t.json") && e.contains("reversal"), "{e}");
    }

    #[test]
    fn inputs_are_read_whole_or_by_their_last_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.txt");
        std::fs::write(&path, "a human table\n{\"x\": 1}\n\n").unwrap();
        let input = Input::read(&format!("dcfo={}", path.display())).unwrap();
        assert_eq!((input.label.as_deref(), input.value["x"].as_u64()), (Some("dcfo"), Some(1)));
        let whole = dir.path().join("w.json");
        std::fs::write(&whole, "{\n \"y\": 2\n}\n").unwrap();
        let input = Input::read(whole.to_str().unwrap()).unwrap();
        assert_eq!((input.label, input.value["y"].as_u64()), (None, Some(2)));
        std::fs::write(&whole, "no json\n").unwrap();
        assert!(Input::read(whole.to_str().unwrap()).is_err());
    }

    #[test]
    fn numbers_read_as_written() {
        assert_eq!(
            (deg(0.598), deg(9.72), deg(66.99), deg(-0.031)),
            ("0.60".into(), "9.72".into(), "67.0".into(), "-0.03".into())
        );
        assert_eq!(
            (thousands(7), thousands(1000), thousands(24_000), thousands(1_234_567)),
            ("7".into(), "1,000".into(), "24,000".into(), "1,234,567".into())
        );
        assert_eq!(motor_name("motors/salient.toml"), "salient");
        assert_eq!(motor_name("paper"), "paper");
    }
}
