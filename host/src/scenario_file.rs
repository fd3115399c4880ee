//! Scenario files (TOML): what `dcfo sim --scenario FILE` runs, as a user writes it.
//! The format is documented for users in `docs/scenario-format.md`; in short:
//!
//! ```toml
//! name = "my-move"                 # optional; default: the file name without extension
//! description = "0.3 m/s, 40 N"    # optional, free text
//! duration_s = 5.0                 # simulated time, s (0 < d <= 120)
//!
//! [measure]                        # optional: the window the figures are measured over
//! from_s = 3.0                     # default: duration_s - 1 (or 0)
//! for_s = 1.0                      # default: to the end
//!
//! [plant]                          # optional: how the plant differs from the motor file
//! rs_factor = 1.2                  # plant R / file R (default 1)
//! ld_factor = 0.95                 # likewise ld_factor, lq_factor, psi_f_factor
//! payload_kg = 10.0                # carried besides the mover (default 0)
//! coulomb_friction_n = 10.0        # default none
//! viscous_n_s_per_m = 2.0          # default: the motor file's
//!
//! [[event]]                        # any number, in any order; one action each
//! t_s = 0.0
//! speed_m_per_s = 0.3              # speed reference (the drive ramps to it)
//!
//! [[event]]
//! t_s = 3.0
//! load_n = 40.0                    # load force opposing motion from then on
//! ```
//! Other actions: `observer_u_offset_v = [ua, ub]` and/or `observer_i_offset_a = [ia, ib]`
//! (DC offsets added to the observer's inputs, the paper's disturbance tests),
//! `reset_estimator = true` (a lock loss at speed), `mover_speed_m_per_s = v` (the
//! mover pushed to that speed at that instant).
//!
//! Every error names the file, the line and the key: TOML syntax, unknown keys (a
//! misspelt key would otherwise fall back to a default silently), wrong types, values
//! out of range, an event with no action or two.

use std::ops::Range;
use std::path::Path;

use serde::Deserialize;
use toml::Spanned;

use crate::simulation::{Event, PlantChanges, Scenario};

/// Longest simulated duration a scenario file may ask for, s: the run is kept in memory
/// (about 10 kHz of samples).
pub const MAX_DURATION_S: f64 = 120.0;

/// Why a scenario file was refused. The message names the file, the line and the key.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioFileError {
    /// The file could not be read.
    #[error("scenario file {file}: {source}")]
    Io {
        /// The file concerned.
        file: String,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// Not valid TOML, an unknown key or a wrong type (toml's message gives the line,
    /// the column and the key).
    #[error("scenario file {file}: {message}")]
    Syntax {
        /// The file concerned.
        file: String,
        /// The parser's message.
        message: String,
    },
    /// A value the format does not allow.
    #[error("scenario file {file}, line {line}: `{key}` {problem}")]
    Invalid {
        /// The file concerned.
        file: String,
        /// Line of the value (1-based).
        line: usize,
        /// The key (with its table, e.g. `plant.rs_factor`, `event.t_s`).
        key: String,
        /// What is wrong with it.
        problem: String,
    },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileScenario {
    name: Option<String>,
    description: Option<String>,
    duration_s: Spanned<f64>,
    measure: Option<FileMeasure>,
    plant: Option<FilePlant>,
    #[serde(default)]
    event: Vec<Spanned<FileEvent>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileMeasure {
    from_s: Option<Spanned<f64>>,
    for_s: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FilePlant {
    rs_factor: Option<Spanned<f64>>,
    ld_factor: Option<Spanned<f64>>,
    lq_factor: Option<Spanned<f64>>,
    psi_f_factor: Option<Spanned<f64>>,
    payload_kg: Option<Spanned<f64>>,
    coulomb_friction_n: Option<Spanned<f64>>,
    viscous_n_s_per_m: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FileEvent {
    t_s: Spanned<f64>,
    speed_m_per_s: Option<Spanned<f64>>,
    load_n: Option<Spanned<f64>>,
    observer_u_offset_v: Option<Spanned<[f64; 2]>>,
    observer_i_offset_a: Option<Spanned<[f64; 2]>>,
    reset_estimator: Option<Spanned<bool>>,
    mover_speed_m_per_s: Option<Spanned<f64>>,
}

/// Checks values against their ranges and turns spans into lines.
struct Checker<'a> {
    text: &'a str,
    file: &'a str,
}

impl Checker<'_> {
    fn line(&self, span: Range<usize>) -> usize {
        let end = span.start.min(self.text.len());
        self.text.as_bytes()[..end].iter().filter(|&&b| b == b'\n').count() + 1
    }

    fn error(&self, span: Range<usize>, key: &str, problem: impl Into<String>) -> ScenarioFileError {
        ScenarioFileError::Invalid {
            file: self.file.to_string(),
            line: self.line(span),
            key: key.to_string(),
            problem: problem.into(),
        }
    }

    /// A finite value within `[lo, hi]`.
    fn within(&self, v: &Spanned<f64>, key: &str, lo: f64, hi: f64) -> Result<f64, ScenarioFileError> {
        let x = *v.get_ref();
        if x.is_finite() && (lo..=hi).contains(&x) {
            Ok(x)
        } else {
            Err(self.error(v.span(), key, format!("must be a finite number in [{lo}, {hi}], found {x}")))
        }
    }

    fn factor(&self, v: &Option<Spanned<f64>>, key: &str) -> Result<f64, ScenarioFileError> {
        v.as_ref().map_or(Ok(1.0), |v| self.within(v, key, 0.1, 10.0))
    }

    fn optional(
        &self,
        v: &Option<Spanned<f64>>,
        key: &str,
        hi: f64,
    ) -> Result<Option<f64>, ScenarioFileError> {
        v.as_ref().map(|v| self.within(v, key, 0.0, hi)).transpose()
    }
}

/// Parses the text of a scenario file; `file` names it in messages and gives the default
/// name (its file stem).
pub fn parse_scenario_toml(text: &str, file: &str) -> Result<Scenario, ScenarioFileError> {
    let raw: FileScenario = toml::from_str(text)
        .map_err(|e| ScenarioFileError::Syntax { file: file.to_string(), message: e.to_string() })?;
    let c = Checker { text, file };
    let duration_s = c.within(&raw.duration_s, "duration_s", 1e-3, MAX_DURATION_S)?;
    let plant = match &raw.plant {
        None => PlantChanges::default(),
        Some(p) => PlantChanges {
            rs_factor: c.factor(&p.rs_factor, "plant.rs_factor")?,
            ld_factor: c.factor(&p.ld_factor, "plant.ld_factor")?,
            lq_factor: c.factor(&p.lq_factor, "plant.lq_factor")?,
            psi_f_factor: c.factor(&p.psi_f_factor, "plant.psi_f_factor")?,
            payload_kg: c.optional(&p.payload_kg, "plant.payload_kg", 1e4)?.unwrap_or(0.0),
            coulomb_friction_n: c.optional(&p.coulomb_friction_n, "plant.coulomb_friction_n", 1e5)?,
            viscous_n_s_per_m: c.optional(&p.viscous_n_s_per_m, "plant.viscous_n_s_per_m", 1e5)?,
        },
    };
    let mut events = Vec::with_capacity(raw.event.len());
    for ev in &raw.event {
        let span = ev.span();
        let e = ev.get_ref();
        let t = c.within(&e.t_s, "event.t_s", 0.0, duration_s)?;
        let mut actions = Vec::new();
        if let Some(v) = &e.speed_m_per_s {
            actions.push(Event::Speed(c.within(v, "event.speed_m_per_s", -100.0, 100.0)?));
        }
        if let Some(f) = &e.load_n {
            actions.push(Event::Load(c.within(f, "event.load_n", -1e6, 1e6)?));
        }
        if e.observer_u_offset_v.is_some() || e.observer_i_offset_a.is_some() {
            let pair = |v: &Option<Spanned<[f64; 2]>>,
                        key: &str,
                        hi: f64|
             -> Result<[f64; 2], ScenarioFileError> {
                match v {
                    None => Ok([0.0; 2]),
                    Some(s) if s.get_ref().iter().all(|x| x.is_finite() && x.abs() <= hi) => Ok(*s.get_ref()),
                    Some(s) => {
                        Err(c.error(s.span(), key, format!("must hold two finite numbers within +-{hi}")))
                    }
                }
            };
            actions.push(Event::ObserverOffsets {
                u_v: pair(&e.observer_u_offset_v, "event.observer_u_offset_v", 1e4)?,
                i_a: pair(&e.observer_i_offset_a, "event.observer_i_offset_a", 1e4)?,
            });
        }
        if let Some(r) = &e.reset_estimator {
            if !*r.get_ref() {
                return Err(c.error(r.span(), "event.reset_estimator", "must be true (or be left out)"));
            }
            actions.push(Event::ResetEstimator);
        }
        if let Some(v) = &e.mover_speed_m_per_s {
            actions.push(Event::MoverSpeed(c.within(v, "event.mover_speed_m_per_s", -100.0, 100.0)?));
        }
        match actions.as_slice() {
            [one] => events.push((t, *one)),
            [] => return Err(c.error(span, "event", "has no action (speed_m_per_s, load_n, observer_u_offset_v, observer_i_offset_a, reset_estimator, mover_speed_m_per_s)")),
            _ => return Err(c.error(span, "event", "has more than one action: give each its own [[event]]")),
        }
    }
    let (from_default, for_default) = {
        let from = (duration_s - 1.0).max(0.0);
        (from, duration_s - from)
    };
    let (event_s, window_s) = match &raw.measure {
        None => (from_default, for_default),
        Some(m) => {
            let from =
                m.from_s.as_ref().map(|v| c.within(v, "measure.from_s", 0.0, duration_s)).transpose()?;
            let from = from.unwrap_or(from_default);
            let length = m
                .for_s
                .as_ref()
                .map(|v| c.within(v, "measure.for_s", 1e-3, duration_s - from))
                .transpose()?;
            (from, length.unwrap_or(duration_s - from))
        }
    };
    let name = raw.name.unwrap_or_else(|| {
        Path::new(file).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
    });
    Ok(Scenario {
        name,
        description: raw.description.unwrap_or_default(),
        duration_s,
        events,
        plant,
        event_s,
        window_s,
        paper: String::new(),
    })
}

/// Reads and parses the scenario file at `path`.
pub fn read_scenario_file(path: impl AsRef<Path>) -> Result<Scenario, ScenarioFileError> {
    let path = path.as_ref();
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|source| ScenarioFileError::Io { file: file.clone(), source })?;
    parse_scenario_toml(&text, &file)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
name = "bench"
duration_s = 4.0

[measure]
from_s = 3.0

[plant]
rs_factor = 1.2
payload_kg = 10

[[event]]
t_s = 0.0
speed_m_per_s = 0.3

[[event]]
t_s = 3.0
load_n = 40.0

[[event]]
t_s = 3.5
observer_u_offset_v = [2.0, 0.0]
"#;

    fn err(text: &str) -> String {
        match parse_scenario_toml(text, "s.toml") {
            Ok(s) => panic!("accepted: {s:?}"),
            Err(e) => e.to_string(),
        }
    }

    fn assert_has(msg: &str, parts: &[&str]) {
        for p in parts {
            assert!(msg.contains(p), "message {msg:?} lacks {p:?}");
        }
    }

    #[test]
    fn a_full_file_reads_into_the_scenario_it_describes() {
        let s = parse_scenario_toml(GOOD, "dir/s.toml").unwrap();
        assert_eq!((s.name.as_str(), s.duration_s, s.event_s, s.window_s), ("bench", 4.0, 3.0, 1.0));
        assert_eq!(s.plant, PlantChanges { rs_factor: 1.2, payload_kg: 10.0, ..PlantChanges::default() });
        assert_eq!(
            s.events,
            vec![
                (0.0, Event::Speed(0.3)),
                (3.0, Event::Load(40.0)),
                (3.5, Event::ObserverOffsets { u_v: [2.0, 0.0], i_a: [0.0, 0.0] }),
            ]
        );
    }

    #[test]
    fn defaults_name_from_the_file_and_measure_the_last_second() {
        let s = parse_scenario_toml("duration_s = 2.5\n", "dir/my-run.toml").unwrap();
        assert_eq!((s.name.as_str(), s.event_s, s.window_s), ("my-run", 1.5, 1.0));
        assert_eq!(s.plant, PlantChanges::default());
        assert!(s.events.is_empty());
    }

    #[test]
    fn unknown_keys_and_wrong_types_name_line_and_key() {
        let m = err(&GOOD.replace("load_n = 40.0", "load = 40.0"));
        assert_has(&m, &["scenario file s.toml", "line 18", "unknown field `load`"]);
        let m = err(&GOOD.replace("rs_factor = 1.2", "rs_factr = 1.2"));
        assert_has(&m, &["line 9", "unknown field `rs_factr`"]);
        let m = err(&GOOD.replace("duration_s = 4.0", "duration_s = \"4 s\""));
        assert_has(&m, &["line 3", "duration_s"]);
        let m = err(&GOOD.replace("t_s = 3.0\n", "t_s = 3.0\nt_s = 4.0\n"));
        assert_has(&m, &["line 18"]);
    }

    #[test]
    fn out_of_range_values_name_line_and_key() {
        let m = err(&GOOD.replace("rs_factor = 1.2", "rs_factor = -1"));
        assert_has(
            &m,
            &["scenario file s.toml, line 9: `plant.rs_factor` must be a finite number in [0.1, 10]"],
        );
        let m = err(&GOOD.replace("t_s = 3.5", "t_s = 5.0"));
        assert_has(&m, &["line 21: `event.t_s`", "[0, 4]", "found 5"]);
        let m = err(&GOOD.replace("duration_s = 4.0", "duration_s = nan"));
        assert_has(&m, &["line 3: `duration_s`"]);
        let m = err(&GOOD.replace("duration_s = 4.0", "duration_s = 1e9"));
        assert_has(&m, &["line 3: `duration_s`", "120"]);
        let m = err(&GOOD.replace("from_s = 3.0", "from_s = 3.0\nfor_s = 2.0"));
        assert_has(&m, &["line 7: `measure.for_s`"]);
        let m = err(&GOOD.replace("[2.0, 0.0]", "[2.0, inf]"));
        assert_has(&m, &["line 22: `event.observer_u_offset_v`"]);
    }

    #[test]
    fn events_need_exactly_one_action() {
        let m = err(&GOOD.replace("speed_m_per_s = 0.3", ""));
        assert_has(&m, &["line 12: `event` has no action"]);
        let m = err(&GOOD.replace("load_n = 40.0", "load_n = 40.0\nspeed_m_per_s = 0.4"));
        assert_has(&m, &["line 16: `event` has more than one action"]);
        let m = err(&GOOD.replace("load_n = 40.0", "reset_estimator = false"));
        assert_has(&m, &["line 18: `event.reset_estimator` must be true"]);
    }
}
