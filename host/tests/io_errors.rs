//! Trace and motor-file I/O against real files: the example trace in `tests/data/`,
//! error messages naming file, line and column, and an end-to-end replay-shaped run.

use std::path::{Path, PathBuf};

use dcfo::motor::MotorParams;
use dcfo_host::motor_file::{load_motor, read_motor_file};
use dcfo_host::summary::{DEFAULT_SETTLE_S, Summary};
use dcfo_host::trace::{Estimate, GroundTruth, InputTrace, write_output_trace};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name)
}

fn assert_has(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "message {msg:?} lacks {p:?}");
    }
}

#[test]
fn example_trace_reads_with_ground_truth() {
    let tr = InputTrace::read_path(data("example_trace.csv")).unwrap();
    assert_eq!(tr.rows().len(), 20);
    assert_eq!(tr.ground_truth(), GroundTruth::ALL);
    assert!((tr.sample_period_s() - 1e-4).abs() < 1e-12);
    // Ground truth is consistent with the paper motor at 0.3 m/s.
    let m = MotorParams::paper();
    let w = std::f64::consts::PI * 0.3 / f64::from(m.pole_pitch_m);
    for r in tr.rows() {
        assert!((r.theta.unwrap() - w * r.t).abs() < 1e-6);
        assert!((r.i_alpha.hypot(r.i_beta) - 1.0).abs() < 1e-6);
        assert_eq!(r.v, Some(0.3));
    }
}

#[test]
fn example_trace_replays_end_to_end() {
    let tr = InputTrace::read_path(data("example_trace.csv")).unwrap();
    let psi_f = f64::from(MotorParams::paper().psi_f_wb);
    // A perfect observer, then one lagging by 1 degree.
    for (lag_deg, want) in [(0.0, 0.0), (1.0, 1.0)] {
        let est: Vec<Estimate> = tr
            .rows()
            .iter()
            .map(|r| {
                let th = r.theta.unwrap() - f64::to_radians(lag_deg);
                Estimate {
                    theta_hat: th,
                    v_hat: 0.3,
                    psi_alpha_hat: psi_f * th.cos(),
                    psi_beta_hat: psi_f * th.sin(),
                    locked: true,
                }
            })
            .collect();
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out.csv");
        write_output_trace(&out, &tr, &est).unwrap();
        let text = std::fs::read_to_string(&out).unwrap();
        assert!(text.starts_with("t,theta_hat,v_hat,psi_alpha_hat,psi_beta_hat,locked,theta_err,v_err\n"));
        assert_eq!(
            Summary::compute(&tr, &est, &MotorParams::paper(), 1e-3).unwrap().false_lock_samples,
            Some(0)
        );
        assert_eq!(text.lines().count(), 21);
        // The trace is 1.9 ms long: settle the first millisecond instead of 0.5 s.
        assert!(Summary::compute(&tr, &est, &MotorParams::paper(), DEFAULT_SETTLE_S).is_err());
        let s = Summary::compute(&tr, &est, &MotorParams::paper(), 1e-3).unwrap();
        assert_eq!(s.samples, 10);
        assert!((s.theta_err_rms_deg.unwrap() - want).abs() < 1e-9);
        assert!((s.theta_err_max_deg.unwrap() - want).abs() < 1e-9);
        assert!(s.v_err_max.unwrap().abs() < 1e-15);
        assert!(s.psi_amp_err_rms_wb < 1e-12);
    }
}

#[test]
fn trace_errors_name_the_file_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.csv");
    let header = "# recorder v1\nt,u_alpha,u_beta,i_alpha,i_beta,v";
    let cases: [(&str, &[&str]); 6] = [
        ("\n0,1,2,3,4,0\n0.001,1,2,3,4,x\n", &["bad.csv:4:", "column `v`", "`x` is not a number"]),
        ("\n0,1,2,3,4,0\n0.001,1,2,3,4,inf\n", &["bad.csv:4:", "column `v`", "not finite"]),
        ("\n0,1,2,3,4,0\n# pause\n0.001,1,2,3,4\n", &["bad.csv:5:", "expected 6 fields", "found 5", "`v`"]),
        ("\n0,1,2,3,4,0\n0,1,2,3,4,0\n", &["bad.csv:4:", "column `t`", "strictly increase"]),
        ("\n0,1,2,3,4,0\n0.001,1,2,3,4,0\n0.003,1,2,3,4,0\n", &["bad.csv:5:", "column `t`", "uniform"]),
        ("\n# nothing\n", &["bad.csv", "empty trace"]),
    ];
    for (body, parts) in cases {
        std::fs::write(&path, format!("{header}{body}")).unwrap();
        let e = InputTrace::read_path(&path).unwrap_err().to_string();
        assert_has(&e, parts);
        assert_has(&e, &[&path.display().to_string()]);
    }
    std::fs::write(&path, "t,u_alpha,i_alpha\n0,1,2\n").unwrap();
    let e = InputTrace::read_path(&path).unwrap_err().to_string();
    assert_has(&e, &["bad.csv:1:", "`u_beta`, `i_beta`"]);

    let e = InputTrace::read_path(dir.path().join("absent.csv")).unwrap_err().to_string();
    assert_has(&e, &["absent.csv"]);
}

#[test]
fn motor_files_on_disk() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.toml");
    std::fs::write(
        &path,
        "rs_ohm = 2.5\nld_h = 0.01\nlq_h = 0.012\npsi_f_wb = 0.1\npole_pitch_m = 0.02\n\
         rated_current_a = 3\nrated_voltage_v = 48\n",
    )
    .unwrap();
    let m = read_motor_file(&path).unwrap();
    assert_eq!(m.name, "m");
    assert_eq!(m.params.lq_h, 0.012);
    assert_eq!(m.defaulted, ["mass_kg", "viscous_n_s_per_m"]);
    assert_eq!(load_motor(&path.display().to_string()).unwrap(), m);

    std::fs::write(&path, "rs_ohm = 2.5\nld_h = 0.01\nlq_h = 0.012\npsi_f_wb = 0.1\nrs = 1\n").unwrap();
    let e = read_motor_file(&path).unwrap_err().to_string();
    assert_has(&e, &["motor file", "m.toml", "unknown key `rs`"]);

    let e = read_motor_file(dir.path().join("absent.toml")).unwrap_err().to_string();
    assert_has(&e, &["motor file", "absent.toml"]);
    assert_eq!(load_motor("paper").unwrap().params, MotorParams::paper());
}

#[test]
fn motor_image_command_writes_what_the_firmware_reads_and_refuses_bad_input() {
    use dcfo::motor_image::MotorImage;
    use std::process::Command;
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("motor.bin");
    let out = Command::new(env!("CARGO_BIN_EXE_dcfo"))
        .args(["motor-image", "--motor", "paper", "--bus-v", "24", "-o"])
        .arg(&good)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let image = MotorImage::decode(&std::fs::read(&good).unwrap()).unwrap();
    assert_eq!((image.motor, image.bus_v), (MotorParams::paper(), 24.0));
    // A motor file with an unphysical value, and a bad bus voltage: an error naming
    // what is wrong, and no file.
    let motor_toml = dir.path().join("bad.toml");
    std::fs::write(
        &motor_toml,
        "name = \"x\"\nrs_ohm = 1.0\nld_h = -0.001\nlq_h = 0.001\npsi_f_wb = 0.01\npole_pitch_m = 0.01\n\
         mass_kg = 1.0\nviscous_n_s_per_m = 0.0\nrated_current_a = 5.0\nrated_voltage_v = 24.0\n",
    )
    .unwrap();
    let bad = dir.path().join("bad.bin");
    for (motor, bus, expect) in [
        (motor_toml.to_str().unwrap(), "24", "ld_h"),
        ("paper", "0", "bus voltage"),
        ("paper", "nan", "bus voltage"),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_dcfo"))
            .args(["motor-image", "--motor", motor, &format!("--bus-v={bus}"), "-o"])
            .arg(&bad)
            .output()
            .unwrap();
        assert!(!out.status.success());
        assert_has(&String::from_utf8_lossy(&out.stderr), &[expect]);
        assert!(!bad.exists(), "no file on an error");
    }
}

#[test]
fn stroke_refuses_a_motor_file_without_the_mass_it_tunes_on() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("no_mass.toml");
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../motors/salient.toml"))
        .expect("example motor");
    let text: String = text.lines().filter(|l| !l.starts_with("mass_kg")).map(|l| format!("{l}\n")).collect();
    std::fs::write(&path, text).expect("write");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_dcfo"))
        .args(["stroke", "--out"])
        .arg(dir.path().join("out"))
        .arg("--motor")
        .arg(&path)
        .output()
        .expect("dcfo runs");
    assert!(!out.status.success());
    let msg = String::from_utf8_lossy(&out.stderr);
    assert_has(&msg, &["no_mass.toml", "`mass_kg`", "positioning"]);
    // Nothing written as if complete.
    assert!(!dir.path().join("out").join("stroke.json").exists());
}

/// `dcfo motor-image` with the axis options: all five write a version-3 image with the
/// axis; some of them, or a bad value, is an error naming the options or the field, and
/// no file.
#[test]
fn motor_image_axis_options_are_all_or_nothing_and_bad_values_are_named() {
    use dcfo::motor_image::MotorImage;
    use std::process::Command;
    let dir = tempfile::tempdir().unwrap();
    let run = |extra: &[&str], out: &std::path::Path| {
        Command::new(env!("CARGO_BIN_EXE_dcfo"))
            .args(["motor-image", "--motor", "paper", "--bus-v", "311"])
            .args(extra)
            .arg("-o")
            .arg(out)
            .output()
            .unwrap()
    };
    let axis = [
        "--stroke-min-m",
        "-0.01",
        "--stroke-max-m",
        "0.31",
        "--max-speed",
        "0.5",
        "--max-accel",
        "3",
        "--payload-kg",
        "10",
    ];
    let good = dir.path().join("axis.bin");
    let out = run(&axis, &good);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let bytes = std::fs::read(&good).unwrap();
    assert_eq!(bytes.len(), MotorImage::LEN);
    let image = MotorImage::decode(&bytes).unwrap();
    let a = image.axis.expect("the axis");
    assert_eq!(
        (
            a.limits.stroke_min_m,
            a.limits.stroke_max_m,
            a.limits.max_speed_m_per_s,
            a.limits.max_accel_m_per_s2,
            a.payload_kg
        ),
        (-0.01, 0.31, 0.5, 3.0, 10.0)
    );
    // Without the options: no axis.
    let plain = dir.path().join("plain.bin");
    assert!(run(&[], &plain).status.success());
    assert_eq!(MotorImage::decode(&std::fs::read(&plain).unwrap()).unwrap().axis, None);
    let bad = dir.path().join("bad.bin");
    // Partial: the missing options named.
    let out = run(&axis[..4], &bad);
    assert!(!out.status.success());
    assert_has(&String::from_utf8_lossy(&out.stderr), &["missing --max-speed, --max-accel, --payload-kg"]);
    assert!(!bad.exists());
    // A bad value: the field named, no file.
    for (option, value, field) in [
        ("--stroke-max-m", "-0.02", "stroke_max_m"),
        ("--stroke-min-m", "nan", "stroke_min_m"),
        ("--max-speed", "0", "max_speed_m_per_s"),
        ("--max-speed", "20", "max_speed_m_per_s"),
        ("--max-accel", "-1", "max_accel_m_per_s2"),
        ("--max-accel", "500", "max_accel_m_per_s2"),
        ("--payload-kg", "-1", "payload_kg"),
    ] {
        let mut args: Vec<&str> = axis.to_vec();
        let at = args.iter().position(|a| *a == option).unwrap();
        args[at + 1] = value;
        let out = run(&args, &bad);
        assert!(!out.status.success(), "{option} {value}");
        assert_has(&String::from_utf8_lossy(&out.stderr), &["axis", field]);
        assert!(!bad.exists(), "{option} {value}");
    }
}
