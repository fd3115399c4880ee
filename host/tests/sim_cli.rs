//! `dcfo sim --motor FILE --scenario FILE`: a user's own motor and scenario, end to end
//! through the binary, and the errors a bad file gets.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn dcfo(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dcfo")).args(args).output().expect("the dcfo binary runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn repo(p: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(p).display().to_string()
}

fn assert_has(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "message {msg:?} lacks {p:?}");
    }
}

#[test]
fn a_motor_file_and_a_scenario_file_run_the_drive_tuned_from_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let out: PathBuf = dir.path().join("run");
    let o = dcfo(&[
        "sim",
        "--motor",
        &repo("motors/low_r.toml"),
        "--scenario",
        &repo("scenarios/load-step.toml"),
        "--observer",
        "dcfo",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    // The run is the file's motor (its pole pitch), the scenario's name, and it reached
    // sensorless operation without a fault.
    assert_eq!(summary["scenario"], "load-step");
    assert!((summary["motor_pole_pitch_m"].as_f64().unwrap() - 0.012).abs() < 1e-6, "{summary}");
    assert_eq!(summary["faults"], "none");
    assert!(summary["handover_s"].as_f64().is_some());
    let f = &summary["figures"];
    assert_eq!(f["healthy"], true);
    // The 20 N step on a plant with R +20 %: the angle stays within a fraction of a pole.
    let max = f["theta_err_max_deg"].as_f64().unwrap();
    assert!(max.is_finite() && max < 30.0, "{f}");
    for file in ["trace.csv", "estimates.csv", "load-step.png", "load-step.svg"] {
        assert!(out.join(file).is_file(), "{file} missing");
    }
}

#[test]
fn a_bare_mover_is_handed_over_from_the_damped_i_f_start_on_every_example_motor() {
    // The I/f vector is a spring on the mover; undamped, a bare mover (no payload) swung
    // about the open-loop speed and, with the speed loop starting from zero thrust at the
    // hand-over, was stopped by friction and tripped LOCK_LOST on all three motor files
    // (docs/low-speed-operation.md). Damped and preset, each reaches sensorless operation and follows
    // a speed step without a fault (measured 11.8, 6.4 and 4.9 deg max from 2.5 s on,
    // the paper mover's during the 0.4 -> 0.8 m/s step).
    for motor in ["paper", &repo("motors/salient.toml"), &repo("motors/low_r.toml")] {
        let dir = tempfile::tempdir().unwrap();
        let out: PathBuf = dir.path().join("run");
        let o = dcfo(&[
            "sim",
            "--motor",
            motor,
            "--scenario",
            &repo("scenarios/bare-mover.toml"),
            "--observer",
            "dcfo",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{motor}: {}", text(&o.stderr));
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
        assert_eq!(summary["faults"], "none", "{motor}: {summary}");
        let f = &summary["figures"];
        assert_eq!(f["healthy"], true, "{motor}: {f}");
        // Within the 15 deg the lock flag is held to (issue 8): the angle is trusted.
        let max = f["theta_err_max_deg"].as_f64().unwrap();
        assert!(max.is_finite() && max < 15.0, "{motor}: {f}");
    }
}

#[test]
fn a_paper_experiment_on_another_motor_is_scaled_to_it() {
    let sim = |motor: Option<&str>, out: &Path| {
        let mut args =
            vec!["sim", "--scenario", "dc-u", "--observer", "dcfo", "--out", out.to_str().unwrap()];
        if let Some(m) = motor {
            args.extend(["--motor", m]);
        }
        let o = dcfo(&args);
        assert!(o.status.success(), "{motor:?}: {}", text(&o.stderr));
        serde_json::from_str::<serde_json::Value>(&std::fs::read_to_string(out.join("summary.json")).unwrap())
            .unwrap()
    };
    let dir = tempfile::tempdir().unwrap();
    // Scaled to the paper motor, the experiment is the paper's on its axis (the 10 kg
    // carriage as payload): the same run, sample for sample.
    let paper_axis = dir.path().join("paper-axis");
    let paper_motor = dir.path().join("paper-motor");
    sim(None, &paper_axis);
    sim(Some("paper"), &paper_motor);
    let trace = |d: &Path| std::fs::read(d.join("trace.csv")).unwrap();
    assert!(trace(&paper_axis) == trace(&paper_motor), "the scaled paper motor ran another experiment");
    // The paper's +2 V is a fifth of its motor's back-EMF at 0.3 m/s; on the 48 V
    // low-resistance motor the same 2 V was half of it, and the drive lost the mover
    // and tripped LOCK_LOST. Scaled by the rated voltage (0.44 V, the same share of its
    // bus), at the same electrical frequency, on an axis of the paper's mass per rated
    // thrust, it is the paper's experiment again.
    let summary = sim(Some(&repo("motors/low_r.toml")), &dir.path().join("low-r"));
    assert_eq!(summary["faults"], "none", "{summary}");
    let f = &summary["figures"];
    assert_eq!(f["healthy"], true, "{f}");
    // Measured 10.9 deg (the paper motor's own: 14.3), within the 15 deg the lock flag
    // is held to.
    let max = f["theta_err_max_deg"].as_f64().unwrap();
    assert!(max.is_finite() && max < 15.0, "{f}");
}

#[test]
fn bad_scenario_and_motor_files_are_refused_with_file_line_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never");
    let scenario = dir.path().join("typo.toml");
    std::fs::write(&scenario, "duration_s = 2.0\n\n[[event]]\nt_s = 0.0\nspeed_m_per_s = 0.3\nload = 5.0\n")
        .unwrap();
    let args = |motor: &str, sc: &str| {
        vec![
            "sim".to_string(),
            "--motor".into(),
            motor.into(),
            "--scenario".into(),
            sc.into(),
            "--observer".into(),
            "dcfo".into(),
            "--out".into(),
            out.display().to_string(),
        ]
    };
    let run = |a: Vec<String>| dcfo(&a.iter().map(String::as_str).collect::<Vec<_>>());
    let o = run(args("paper", scenario.to_str().unwrap()));
    assert!(!o.status.success());
    assert_has(&text(&o.stderr), &["typo.toml", "line 6", "unknown field `load`"]);
    std::fs::write(&scenario, "duration_s = 2.0\n[plant]\nrs_factor = 0\n").unwrap();
    let o = run(args("paper", scenario.to_str().unwrap()));
    assert_has(&text(&o.stderr), &["typo.toml, line 3: `plant.rs_factor`"]);
    // A motor file without a mass cannot tune the speed loop.
    let motor = dir.path().join("m.toml");
    std::fs::write(
        &motor,
        "rs_ohm = 5.0\nld_h = 0.0085\nlq_h = 0.0085\npsi_f_wb = 0.16\npole_pitch_m = 0.015\n\
         rated_current_a = 2.1\nrated_voltage_v = 220.0\n",
    )
    .unwrap();
    let o = run(args(motor.to_str().unwrap(), &repo("scenarios/load-step.toml")));
    assert_has(&text(&o.stderr), &["m.toml", "`mass_kg` is required"]);
    // A motor file with a bad value names its line.
    std::fs::write(
        &motor,
        "mass_kg = 1\nrs_ohm = -5.0\nld_h = 0.0085\nlq_h = 0.0085\npsi_f_wb = 0.16\n\
         pole_pitch_m = 0.015\nrated_current_a = 2.1\nrated_voltage_v = 220.0\n",
    )
    .unwrap();
    let o = run(args(motor.to_str().unwrap(), &repo("scenarios/load-step.toml")));
    assert!(!o.status.success());
    assert_has(&text(&o.stderr), &["m.toml, line 2:", "`rs_ohm`"]);
    // Nothing was written for any of them.
    assert!(!out.exists());
}
