//! Motor files (TOML) and presets, read into [`dcfo::motor::MotorParams`].
//!
//! The format is the project's interchange contract, `docs/motor-format.md`: top-level
//! keys, SI units, integers accepted where a number is expected (`rs_ohm = 5` is 5.0
//! ohm).
//!
//! | key | unit | required |
//! |---|---|---|
//! | `name` | free text | no (default: the file name without extension) |
//! | `rs_ohm` | ohm | yes |
//! | `ld_h`, `lq_h` | henry | yes |
//! | `psi_f_wb` | weber (amplitude-invariant) | yes |
//! | `pole_pitch_m` | metre | yes |
//! | `mass_kg` | kilogram | no: [`DEFAULT_MASS_KG`] |
//! | `viscous_n_s_per_m` | N·s/m | no: [`DEFAULT_VISCOUS_N_S_PER_M`] |
//! | `rated_current_a` | ampere RMS | yes |
//! | `rated_voltage_v` | volt RMS | yes |
//!
//! Mass and friction are only used by plant models, so a file without them can still
//! be replayed. The defaults are accepted by [`MotorParams::new`] (it wants a mass
//! above zero and a friction of at least zero); [`MotorFile::defaulted`] lists the
//! keys that were filled in, so a simulator can refuse (or warn about) a motor whose
//! mechanics were not given.
//!
//! Unknown keys (including tables such as `[motor]`) are refused with an error naming
//! the key: a misspelt optional key (`mass = 0.66`) would otherwise be silently
//! replaced by its default.
//!
//! Every value is validated by [`MotorParams::new`] after reading; errors name the
//! file and the key.

use std::path::Path;

use dcfo::motor::{MotorParams, ParamError};

/// Mover mass used when a motor file has no `mass_kg`, kg. A placeholder (1 kg), not
/// an estimate: only plant models use the mass.
pub const DEFAULT_MASS_KG: f32 = 1.0;

/// Viscous friction used when a motor file has no `viscous_n_s_per_m`, N·s/m:
/// frictionless. Only plant models use it.
pub const DEFAULT_VISCOUS_N_S_PER_M: f32 = 0.0;

/// Names accepted by [`load_motor`] as presets (each resolves with
/// [`MotorParams::preset`]).
pub const PRESETS: &[&str] = &["paper"];

/// The keys a motor file may hold.
pub const KEYS: [&str; 10] = [
    "name",
    "rs_ohm",
    "ld_h",
    "lq_h",
    "psi_f_wb",
    "pole_pitch_m",
    "mass_kg",
    "viscous_n_s_per_m",
    "rated_current_a",
    "rated_voltage_v",
];

/// A motor read from a file or a preset.
#[derive(Clone, Debug, PartialEq)]
pub struct MotorFile {
    /// Free-text name: the file's `name`, else its file name without extension; for a
    /// preset, the preset's name.
    pub name: String,
    /// The validated parameters (SI).
    pub params: MotorParams,
    /// Optional keys that were absent and filled with their defaults (`"mass_kg"`,
    /// `"viscous_n_s_per_m"`); empty for presets.
    pub defaulted: Vec<&'static str>,
}

/// Why a motor could not be loaded. Messages start with `motor file <file>:` and name
/// the key concerned.
#[derive(Debug, thiserror::Error)]
pub enum MotorFileError {
    /// The file could not be read.
    #[error("motor file {file}: {source}")]
    Io {
        /// The file concerned.
        file: String,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The text is not valid TOML (the message gives line and column).
    #[error("motor file {file}: {source}")]
    Toml {
        /// The file concerned.
        file: String,
        /// The TOML parser's error.
        #[source]
        source: toml::de::Error,
    },
    /// A key that is not part of the format (often a typo).
    #[error("motor file {file}{}: unknown key `{key}` (known keys: {})", at_line(*line), KEYS.join(", "))]
    UnknownKey {
        /// The file concerned.
        file: String,
        /// Its line (1-based), where found.
        line: Option<usize>,
        /// The unknown key.
        key: String,
    },
    /// A required key is absent.
    #[error("motor file {file}: missing key `{key}`")]
    MissingKey {
        /// The file concerned.
        file: String,
        /// The missing key.
        key: &'static str,
    },
    /// A key's value has the wrong TOML type.
    #[error("motor file {file}{}: `{key}` must be {expected}, found {found}", at_line(*line))]
    WrongType {
        /// The file concerned.
        file: String,
        /// Its line (1-based), where found.
        line: Option<usize>,
        /// The key.
        key: &'static str,
        /// The type wanted (`a number`, `a string`).
        expected: &'static str,
        /// The TOML type found.
        found: &'static str,
    },
    /// A value was refused by [`MotorParams::new`].
    #[error("motor file {file}{}: {error} (value {value})", at_line(*line))]
    Invalid {
        /// The file concerned.
        file: String,
        /// The line (1-based) of the refused key, where the file has it.
        line: Option<usize>,
        /// The refused value (as f32, the library's type).
        value: f32,
        /// The validation error; its `field` is the key. (Shown in the message, not
        /// chained as a `source`: the no_std library's error does not implement
        /// `std::error::Error`.)
        error: ParamError,
    },
    /// `load_motor`'s argument is neither a preset nor an existing file.
    #[error(
        "motor `{arg}` is neither a known preset ({}) nor a readable file",
        PRESETS.join(", ")
    )]
    NotFound {
        /// The argument as given.
        arg: String,
    },
}

/// `", line N"` for a known line, else nothing: the place in an error message.
fn at_line(line: Option<usize>) -> String {
    line.map(|n| format!(", line {n}")).unwrap_or_default()
}

/// The line (1-based) of `text` that sets the top-level key `key` (`key = ...`, bare or
/// quoted, or a table header `[key]`), if any: motor files are flat, so the first such
/// line is the key's.
pub fn key_line(text: &str, key: &str) -> Option<usize> {
    text.lines()
        .position(|l| {
            let l = l.trim_start();
            // A table header `[key]` (refused as an unknown key) counts too.
            let header = l.strip_prefix('[').and_then(|r| r.trim().strip_suffix(']')).map(str::trim);
            let rest = l.strip_prefix(key).or_else(|| {
                l.strip_prefix('"').and_then(|r| r.strip_prefix(key)).and_then(|r| r.strip_prefix('"'))
            });
            header == Some(key) || rest.is_some_and(|r| r.trim_start().starts_with('='))
        })
        .map(|i| i + 1)
}

/// Parses the text of a motor file; `file` names it in messages and gives the
/// default `name` (its file stem).
pub fn parse_motor_toml(text: &str, file: &str) -> Result<MotorFile, MotorFileError> {
    let table: toml::Table =
        text.parse().map_err(|source| MotorFileError::Toml { file: file.to_string(), source })?;
    if let Some(key) = table.keys().find(|k| !KEYS.contains(&k.as_str())) {
        return Err(MotorFileError::UnknownKey {
            file: file.to_string(),
            line: key_line(text, key),
            key: key.clone(),
        });
    }
    let wrong_type = |key: &'static str, expected: &'static str, v: &toml::Value| MotorFileError::WrongType {
        file: file.to_string(),
        line: key_line(text, key),
        key,
        expected,
        found: v.type_str(),
    };
    let number = |key: &'static str| -> Result<Option<f32>, MotorFileError> {
        match table.get(key) {
            None => Ok(None),
            // Integers are accepted; the conversion to f32 may round (as any decimal does).
            Some(toml::Value::Integer(i)) => Ok(Some(*i as f32)),
            Some(toml::Value::Float(x)) => Ok(Some(*x as f32)),
            Some(v) => Err(wrong_type(key, "a number", v)),
        }
    };
    let required = |key: &'static str| -> Result<f32, MotorFileError> {
        number(key)?.ok_or(MotorFileError::MissingKey { file: file.to_string(), key })
    };
    let name = match table.get("name") {
        None => Path::new(file).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default(),
        Some(toml::Value::String(s)) => s.clone(),
        Some(v) => return Err(wrong_type("name", "a string", v)),
    };
    let mut defaulted = Vec::new();
    let mut optional = |key: &'static str, default: f32| -> Result<f32, MotorFileError> {
        Ok(number(key)?.unwrap_or_else(|| {
            defaulted.push(key);
            default
        }))
    };
    let mass_kg = optional("mass_kg", DEFAULT_MASS_KG)?;
    let viscous_n_s_per_m = optional("viscous_n_s_per_m", DEFAULT_VISCOUS_N_S_PER_M)?;
    let raw = MotorParams {
        rs_ohm: required("rs_ohm")?,
        ld_h: required("ld_h")?,
        lq_h: required("lq_h")?,
        psi_f_wb: required("psi_f_wb")?,
        pole_pitch_m: required("pole_pitch_m")?,
        mass_kg,
        viscous_n_s_per_m,
        rated_current_a: required("rated_current_a")?,
        rated_voltage_v: required("rated_voltage_v")?,
    };
    let params = MotorParams::new(raw).map_err(|error| MotorFileError::Invalid {
        file: file.to_string(),
        line: key_line(text, error.field),
        value: field_value(&raw, error.field),
        error,
    })?;
    Ok(MotorFile { name, params, defaulted })
}

fn field_value(p: &MotorParams, field: &str) -> f32 {
    match field {
        "rs_ohm" => p.rs_ohm,
        "ld_h" => p.ld_h,
        "lq_h" => p.lq_h,
        "psi_f_wb" => p.psi_f_wb,
        "pole_pitch_m" => p.pole_pitch_m,
        "mass_kg" => p.mass_kg,
        "viscous_n_s_per_m" => p.viscous_n_s_per_m,
        "rated_current_a" => p.rated_current_a,
        "rated_voltage_v" => p.rated_voltage_v,
        _ => f32::NAN,
    }
}

/// Reads and parses the motor file at `path`.
pub fn read_motor_file(path: impl AsRef<Path>) -> Result<MotorFile, MotorFileError> {
    let path = path.as_ref();
    let file = path.display().to_string();
    let text =
        std::fs::read_to_string(path).map_err(|source| MotorFileError::Io { file: file.clone(), source })?;
    parse_motor_toml(&text, &file)
}

/// Resolves a command-line motor argument: a preset name ([`PRESETS`]; a preset wins
/// over a file of the same name), else the path of an existing file, which is parsed.
/// Otherwise an error saying it is neither, listing the presets.
pub fn load_motor(arg: &str) -> Result<MotorFile, MotorFileError> {
    if let Some(params) = PRESETS.contains(&arg).then(|| MotorParams::preset(arg)).flatten() {
        return Ok(MotorFile { name: arg.to_string(), params, defaulted: Vec::new() });
    }
    let path = Path::new(arg);
    if path.is_file() {
        read_motor_file(path)
    } else {
        Err(MotorFileError::NotFound { arg: arg.to_string() })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PAPER: &str = r#"
name = "paper"            # free text
rs_ohm = 5.0              # stator resistance per phase
ld_h = 0.0085             # d-axis inductance
lq_h = 0.0085             # q-axis inductance
psi_f_wb = 0.16           # PM flux linkage (amplitude-invariant)
pole_pitch_m = 0.015      # see conventions; omega_e = pi v / pole_pitch_m
mass_kg = 0.66            # mover mass (plant only)
viscous_n_s_per_m = 0.5   # viscous friction B (plant only)
rated_current_a = 2.1
rated_voltage_v = 220.0
"#;

    fn err(text: &str) -> String {
        match parse_motor_toml(text, "m.toml") {
            Ok(m) => panic!("accepted: {m:?}"),
            Err(e) => e.to_string(),
        }
    }

    fn without(key: &str) -> String {
        PAPER.lines().filter(|l| !l.starts_with(&format!("{key} "))).collect::<Vec<_>>().join("\n")
    }

    fn assert_has(msg: &str, parts: &[&str]) {
        for p in parts {
            assert!(msg.contains(p), "message {msg:?} lacks {p:?}");
        }
    }

    #[test]
    fn the_format_page_example_is_the_paper_preset() {
        let m = parse_motor_toml(PAPER, "m.toml").unwrap();
        assert_eq!(m.name, "paper");
        assert_eq!(m.params, MotorParams::paper());
        assert!(m.defaulted.is_empty());
    }

    #[test]
    fn integers_are_numbers_and_name_defaults_to_the_file_stem() {
        let text = without("name").replace("rs_ohm = 5.0", "rs_ohm = 5").replace("220.0", "220");
        let m = parse_motor_toml(&text, "motors/bench-2.toml").unwrap();
        assert_eq!(m.name, "bench-2");
        assert_eq!(m.params, MotorParams::paper());
        let m = parse_motor_toml(&text.replace("0.16 ", "0.16\nname = \"long stator, 3 coils\" "), "x.toml");
        assert_eq!(m.unwrap().name, "long stator, 3 coils");
    }

    #[test]
    fn mass_and_friction_are_optional() {
        let text = without("mass_kg").replace("viscous_n_s_per_m = 0.5", "");
        let m = parse_motor_toml(&text, "m.toml").unwrap();
        assert_eq!(m.params.mass_kg, DEFAULT_MASS_KG);
        assert_eq!(m.params.viscous_n_s_per_m, DEFAULT_VISCOUS_N_S_PER_M);
        assert_eq!(m.defaulted, ["mass_kg", "viscous_n_s_per_m"]);
        // The defaults are accepted by the library's validation.
        assert!(MotorParams::new(m.params).is_ok());
        let m = parse_motor_toml(&without("viscous_n_s_per_m"), "m.toml").unwrap();
        assert_eq!((m.params.mass_kg, m.defaulted), (0.66, vec!["viscous_n_s_per_m"]));
    }

    #[test]
    fn unknown_keys_are_refused_by_name() {
        let m = err(&without("mass_kg").replace("rated_current_a", "mass = 0.66\nrated_current_a"));
        assert_has(&m, &["motor file m.toml, line 9:", "unknown key `mass`", "mass_kg"]);
        let m = err(&format!("{PAPER}\n[motor]\nrs_ohm = 1.0\n"));
        let line = PAPER.lines().count() + 2;
        assert_has(&m, &[&format!("motor file m.toml, line {line}:"), "unknown key `motor`"]);
    }

    #[test]
    fn key_lines_are_found_for_bare_and_quoted_keys_only() {
        let text = "# rs_ohm = 1\nname = \"x\"\n  rs_ohm=5\n\"ld_h\" = 1\nrs_ohm_extra = 2\n";
        assert_eq!(key_line(text, "name"), Some(2));
        assert_eq!(key_line(text, "rs_ohm"), Some(3));
        assert_eq!(key_line(text, "ld_h"), Some(4));
        assert_eq!(key_line(text, "lq_h"), None);
        assert_eq!(key_line("a = 1\n[ motor ]\n", "motor"), Some(2));
    }

    #[test]
    fn missing_keys_are_named() {
        for key in
            ["rs_ohm", "ld_h", "lq_h", "psi_f_wb", "pole_pitch_m", "rated_current_a", "rated_voltage_v"]
        {
            assert_has(&err(&without(key)), &["motor file m.toml:", &format!("missing key `{key}`")]);
        }
    }

    #[test]
    fn wrong_types_are_named() {
        let m = err(&PAPER.replace("ld_h = 0.0085", "ld_h = \"8.5 mH\""));
        assert_has(&m, &["motor file m.toml, line 4:", "`ld_h` must be a number, found string"]);
        let m = err(&PAPER.replace("name = \"paper\"", "name = 3"));
        assert_has(&m, &["motor file m.toml, line 2:", "`name` must be a string, found integer"]);
    }

    #[test]
    fn invalid_values_carry_the_validation_error() {
        let m = err(&PAPER.replace("ld_h = 0.0085", "ld_h = 0"));
        assert_has(&m, &["motor file m.toml, line 4:", "`ld_h` must be greater than zero", "value 0"]);
        let m = err(&PAPER.replace("psi_f_wb = 0.16", "psi_f_wb = nan"));
        assert_has(&m, &["motor file m.toml, line 6:", "`psi_f_wb` must be a finite number"]);
        let m = err(&PAPER.replace("rs_ohm = 5.0", "rs_ohm = 1e300"));
        assert_has(&m, &["m.toml, line 3:", "`rs_ohm` must be a finite number"]);
        let m = err(&PAPER.replace("viscous_n_s_per_m = 0.5", "viscous_n_s_per_m = -0.5"));
        assert_has(&m, &["m.toml, line 9:", "`viscous_n_s_per_m` must not be negative", "value -0.5"]);
        match parse_motor_toml(&PAPER.replace("mass_kg = 0.66", "mass_kg = -1"), "m.toml") {
            Err(MotorFileError::Invalid { error, value, .. }) => {
                assert_eq!((error.field, value), ("mass_kg", -1.0));
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn toml_syntax_errors_name_the_file_and_line() {
        let m = err("rs_ohm = 5.0\nld_h = = 1\n");
        assert_has(&m, &["motor file m.toml:", "line 2"]);
    }

    #[test]
    fn presets_load_and_unknown_arguments_are_explained() {
        for name in PRESETS {
            let m = load_motor(name).unwrap();
            assert_eq!(m.name, *name);
            assert_eq!(Some(m.params), MotorParams::preset(name));
            assert!(MotorParams::new(m.params).is_ok());
        }
        let m = load_motor("no-such-motor.toml").unwrap_err().to_string();
        assert_has(&m, &["`no-such-motor.toml`", "neither a known preset (paper)", "nor a readable file"]);
        let dir = tempfile::tempdir().unwrap();
        let arg = dir.path().display().to_string();
        assert_has(&load_motor(&arg).unwrap_err().to_string(), &["neither a known preset"]);
        let path = dir.path().join("bench.toml");
        std::fs::write(&path, without("name")).unwrap();
        let m = load_motor(&path.display().to_string()).unwrap();
        assert_eq!((m.name.as_str(), m.params), ("bench", MotorParams::paper()));
        std::fs::write(&path, PAPER.replace("lq_h = 0.0085", "lq_h = -1")).unwrap();
        let m = load_motor(&path.display().to_string()).unwrap_err().to_string();
        assert_has(&m, &["bench.toml, line 5:", "`lq_h` must be greater than zero"]);
    }
}
