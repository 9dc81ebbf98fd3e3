//! `kilotouch calibrate` through the real executable: the JSON contract of
//! the calibration procedure and the calibration file it writes.

use std::process::Command;

#[test]
fn calibrate_sim_meets_the_contract_and_flatness() {
    let dir = tempfile::tempdir().unwrap();
    let out_path = dir.path().join("cal.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_kilotouch"))
        .args(["calibrate", "--rig", "sim", "--seed", "1", "--out"])
        .arg(&out_path)
        .arg("--json")
        .output()
        .expect("run kilotouch");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    for k in [
        "crossover_hz",
        "low_gain",
        "max_abs_dev_db",
        "uncompensated_max_abs_dev_db",
        "group_delay_ms",
    ] {
        assert!(
            v[k].as_f64().is_some_and(f64::is_finite),
            "{k} missing in {v}"
        );
    }
    assert!(
        v["high_model"]["num"]
            .as_array()
            .is_some_and(|a| !a.is_empty())
    );
    assert!(
        v["high_model"]["den"]
            .as_array()
            .is_some_and(|a| a.len() >= 2)
    );
    // Flat within ±1 dB at every third-octave centre 63 Hz–1 kHz (the calibration criterion),
    // recomputed here from the bands rather than trusting `passed`.
    let bands = v["bands"].as_array().expect("bands");
    let main: Vec<(f64, f64)> = bands
        .iter()
        .map(|b| (b["f"].as_f64().unwrap(), b["db"].as_f64().unwrap()))
        .filter(|(f, _)| *f >= 63.0 && *f <= 1001.0)
        .collect();
    assert_eq!(main.len(), 13, "63 Hz … 1 kHz are 13 bands");
    let worst = main.iter().map(|(_, d)| d.abs()).fold(0.0, f64::max);
    assert!(worst <= 1.0, "worst band {worst} dB");
    assert!((v["max_abs_dev_db"].as_f64().unwrap() - worst).abs() < 1e-9);
    assert_eq!(v["passed"].as_bool(), Some(true));
    // Compensation must have bought something over the crossover alone.
    assert!(v["uncompensated_max_abs_dev_db"].as_f64().unwrap() > 3.0);
    // The calibration file exists and is a TOML document naming the rig.
    let text = std::fs::read_to_string(&out_path).expect("calibration file");
    assert!(text.contains("simulated dual-stage rig"), "{text}");
}

#[test]
fn calibrate_rejects_an_unknown_rig_clearly() {
    let out = Command::new(env!("CARGO_BIN_EXE_kilotouch"))
        .args(["calibrate", "--rig", "serial:/dev/nonexistent", "--json"])
        .output()
        .expect("run kilotouch");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--rig") && !err.contains("panicked"), "{err}");
}

/// `--out` never replaces an existing file silently (the GUI's rule): the
/// run is refused before calibrating, with the full path and the flag to
/// use, and the file is left as it was.
#[test]
fn calibrate_refuses_to_overwrite_without_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let out_path = dir.path().join("cal.toml");
    std::fs::write(&out_path, "keep me").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_kilotouch"))
        .current_dir(dir.path())
        .args([
            "calibrate",
            "--rig",
            "sim",
            "--seed",
            "1",
            "--out",
            "cal.toml",
        ])
        .output()
        .expect("run kilotouch");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--overwrite"), "{err}");
    // The full path, however the temporary directory is spelled.
    let full = [
        out_path.display().to_string(),
        out_path.canonicalize().unwrap().display().to_string(),
    ];
    assert!(full.iter().any(|f| err.contains(f.as_str())), "{err}");
    assert_eq!(std::fs::read_to_string(&out_path).unwrap(), "keep me");
}
