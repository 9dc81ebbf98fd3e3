//! The calibrate → apply → feel → study workflow through the executable, as
//! a user runs it: `calibrate`, `rig margins`, `sim press`, `study simulate
//! --calibration`; and the JSON contracts of those commands.

use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output};

fn kilotouch(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kilotouch"))
        .args(args)
        .output()
        .expect("run kilotouch")
}

fn json(out: &Output) -> Value {
    assert!(
        out.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("one JSON document")
}

fn p(path: &Path) -> &str {
    path.to_str().expect("utf-8 path")
}

#[test]
fn calibrate_margins_press_and_study() {
    let dir = tempfile::tempdir().unwrap();
    let cal = dir.path().join("cal.toml");
    json(&kilotouch(&[
        "calibrate",
        "--rig",
        "sim",
        "--seed",
        "2",
        "--out",
        p(&cal),
        "--json",
    ]));

    // Margins, uncalibrated and calibrated: the contract and the minimum.
    for extra in [vec![], vec!["--calibration", p(&cal)]] {
        let mut args = vec!["rig", "margins", "--json"];
        args.extend(&extra);
        let v = json(&kilotouch(&args));
        let conds = v["conditions"].as_array().expect("conditions");
        let names: Vec<&str> = conds
            .iter()
            .map(|c| c["condition"].as_str().unwrap())
            .collect();
        assert_eq!(names, ["P", "D"]);
        for c in conds {
            assert!(c["gain_margin_db"].as_f64().unwrap() >= 6.0, "{c}");
            assert!(c["phase_margin_deg"].as_f64().unwrap() >= 30.0, "{c}");
            assert_eq!(c["stable"], true);
        }
        assert!(v["critical_trap_stiffness_pn_um"].as_f64().unwrap() > 20.0);
        assert!(v["max_force_scale"].as_f64().unwrap() >= 1e11);
        let kind = v["chain"]["kind"].as_str().unwrap();
        assert_eq!(
            kind,
            if extra.is_empty() {
                "as-designed"
            } else {
                "calibration"
            }
        );
    }

    // Press in D, with and without the calibration: stable, same force.
    let mut force = Vec::new();
    for extra in [vec![], vec!["--calibration", p(&cal)]] {
        let mut args = vec![
            "sim",
            "press",
            "--condition",
            "D",
            "--duration",
            "5",
            "--seed",
            "4",
            "--json",
        ];
        args.extend(&extra);
        let v = json(&kilotouch(&args));
        for k in [
            "growth_db_per_s",
            "handle_force_mean_n",
            "handle_force_osc_rms_n",
        ] {
            assert!(v[k].as_f64().is_some_and(f64::is_finite), "{k} in {v}");
        }
        assert_eq!(v["stable"], true, "{v}");
        assert_eq!(v["escaped"], false, "{v}");
        force.push(v["handle_force_mean_n"].as_f64().unwrap());
    }
    let change_db = 20.0 * (force[1] / force[0]).log10();
    assert!(change_db.abs() <= 0.5, "{change_db} dB");

    // A one-participant study with the calibration records it.
    let out = dir.path().join("study");
    let v = json(&kilotouch(&[
        "study",
        "simulate",
        "--participants",
        "1",
        "--seed",
        "5",
        "--no-raw",
        "--threads",
        "2",
        "--calibration",
        p(&cal),
        "--out",
        p(&out),
        "--json",
    ]));
    assert!(v["test_rows"].as_u64().unwrap() > 0);
    let session: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("session.json")).unwrap()).unwrap();
    assert_eq!(session["calibration"]["path"], p(&cal));
    assert_eq!(session["calibration"]["sha256"].as_str().unwrap().len(), 64);
}

#[test]
fn an_unsafe_setting_is_reported_and_refused() {
    let dir = tempfile::tempdir().unwrap();
    // The default rig without its wall damper: D has almost no phase margin.
    let text = kilotouch_rig::default_config_text().replace(
        "contact_damping_n_s_per_m = 15.0",
        "contact_damping_n_s_per_m = 0.0",
    );
    let rig = dir.path().join("bare.toml");
    std::fs::write(&rig, text).unwrap();
    // `rig margins` exits 0 and says so in the JSON.
    let v = json(&kilotouch(&[
        "rig",
        "margins",
        "--rig-config",
        p(&rig),
        "--json",
    ]));
    assert_eq!(v["safe"], false);
    let d = &v["conditions"][1];
    assert_eq!(d["condition"], "D");
    assert!(d["phase_margin_deg"].as_f64().unwrap() < 30.0);
    // `sim press` refuses, naming the margin and the largest safe force scale.
    let out = kilotouch(&["sim", "press", "--rig-config", p(&rig), "--json"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("phase margin") && err.contains("largest safe force scale"),
        "{err}"
    );
    // …unless asked to simulate it anyway.
    let v = json(&kilotouch(&[
        "sim",
        "press",
        "--rig-config",
        p(&rig),
        "--allow-unstable",
        "--duration",
        "3",
        "--json",
    ]));
    assert!(v["stable"].is_boolean());
}

/// `rig margins --latency-ms 3 --json`: the same report for a loop with
/// 3 ms (30 samples at 10 kHz) of extra delay. Every key of the plain
/// report is kept; D's phase margin is lower by the phase of the delay at
/// its gain crossover, 360°·f_c·d/f_s (the delay leaves |L| and so the
/// crossover alone); bad values are refused naming the option.
#[test]
fn margins_with_an_extra_loop_delay() {
    let v0 = json(&kilotouch(&["rig", "margins", "--json"]));
    let v3 = json(&kilotouch(&[
        "rig",
        "margins",
        "--latency-ms",
        "3",
        "--json",
    ]));
    let keys = |v: &Value| -> Vec<String> { v.as_object().unwrap().keys().cloned().collect() };
    for k in keys(&v0) {
        assert!(v3.get(&k).is_some(), "{k} missing with --latency-ms");
    }
    assert_eq!(v0["latency_ms"], 0.0);
    assert_eq!(v0["latency_samples"], 0);
    assert_eq!(v3["latency_ms"], 3.0);
    assert_eq!(v3["latency_samples"], 30);
    let (d0, d3) = (&v0["conditions"][1], &v3["conditions"][1]);
    assert_eq!(d3["condition"], "D");
    // The same worst case and crossover: the delay moves neither.
    assert_eq!(d0["worst_phase_case"], d3["worst_phase_case"]);
    let fc = d0["gain_crossover_hz"].as_f64().unwrap();
    assert!((d3["gain_crossover_hz"].as_f64().unwrap() / fc - 1.0).abs() < 1e-9);
    let fs = kilotouch_rig::RigConfig::default().rig.sample_rate_hz;
    let drop = 360.0 * fc * 30.0 / fs;
    let (pm0, pm3) = (
        d0["phase_margin_deg"].as_f64().unwrap(),
        d3["phase_margin_deg"].as_f64().unwrap(),
    );
    assert!(
        (pm0 - pm3 - drop).abs() < 1e-6,
        "PM {pm0}° → {pm3}°, predicted drop {drop}°"
    );
    // Below the rig file's 30°: the report says so.
    assert!(pm3 < 30.0);
    assert_eq!(v3["safe"], false);
    assert!(v3["max_force_scale"].as_f64().unwrap() < v0["max_force_scale"].as_f64().unwrap());
    // The text states the delay.
    let out = kilotouch(&["rig", "margins", "--latency-ms", "3"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("3.00 ms (30 samples)"), "{text}");
    assert!(text.contains("NOT SAFE"), "{text}");
    for bad in ["nan", "-1", "1000", "inf", "3ms"] {
        let out = kilotouch(&["rig", "margins", "--latency-ms", bad, "--json"]);
        assert!(!out.status.success(), "{bad}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("--latency-ms"), "{bad}: {err}");
    }
}
