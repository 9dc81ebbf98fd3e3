//! `kilotouch rig …` and `kilotouch sim …` through the real executable.

use kilotouch_testkit as common;

use common::{json_ok, kilotouch as run};

#[test]
fn default_config_round_trips_through_the_loader() {
    let out = run(&["rig", "default-config"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).expect("utf-8");
    // Table 2 names are all present.
    for k in [
        "m_h", "m_v", "m_1", "m_2", "k_v", "b_v", "k_1", "b_1", "k_2", "b_2", "k_f", "b_f",
    ] {
        assert!(
            text.lines()
                .any(|l| l.trim_start().starts_with(&format!("{k} ="))),
            "missing {k}"
        );
    }
    // Loading the printed file gives the same model response as the built-in default.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rig.toml");
    std::fs::write(&path, &text).unwrap();
    let p = path.to_string_lossy();
    let a = json_ok(&[
        "sim",
        "frf",
        "--channel",
        "high",
        "--freqs",
        "100,400,1000",
        "--json",
    ]);
    let b = json_ok(&[
        "sim",
        "frf",
        "--channel",
        "high",
        "--rig-config",
        &p,
        "--freqs",
        "100,400,1000",
        "--json",
    ]);
    assert_eq!(a, b);
}

/// `kilotouch sim frf --channel low --freqs 100` on the rig file `path`:
/// its output and stderr.
fn frf_at_100_hz(path: &std::path::Path) -> (std::process::Output, String) {
    let out = run(&[
        "sim",
        "frf",
        "--channel",
        "low",
        "--rig-config",
        &path.to_string_lossy(),
        "--freqs",
        "100",
    ]);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    (out, err)
}

#[test]
fn bad_rig_file_names_file_line_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let out = run(&["rig", "default-config"]);
    let text = String::from_utf8(out.stdout)
        .unwrap()
        .replace("m_h = 0.014", "m_h = -0.014");
    let path = dir.path().join("bad.toml");
    std::fs::write(&path, &text).unwrap();
    let line = text.lines().position(|l| l.starts_with("m_h =")).unwrap() + 1;
    let (out, err) = frf_at_100_hz(&path);
    assert!(!out.status.success());
    assert!(
        err.contains("bad.toml") && err.contains("m_h") && err.contains(&line.to_string()),
        "{err}"
    );

    let typo = text.replace("k_f =", "k_ff =");
    std::fs::write(&path, typo).unwrap();
    let (out, err) = frf_at_100_hz(&path);
    assert!(!out.status.success() && err.contains("k_ff"), "{err}");
}

#[test]
fn sim_frf_low_channel_is_flat_over_the_pantograph_band() {
    // Paper Fig. 5: flat within ±1 dB over 63–200 Hz.
    let v = json_ok(&[
        "sim",
        "frf",
        "--channel",
        "low",
        "--freqs",
        "63,80,100,125,160,200",
        "--json",
    ]);
    let db: Vec<f64> = v["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["db"].as_f64().unwrap())
        .collect();
    let mean = db.iter().sum::<f64>() / db.len() as f64;
    for d in &db {
        assert!((d - mean).abs() <= 1.0, "{db:?}");
    }
}

#[test]
fn sim_tweezer_obeys_equipartition_and_the_corner_frequency() {
    // ⟨x²⟩ = k_BT/κ and f_c = κ/(2πγ0), γ0 = 6πηR (docs/REFERENCE-VALUES.md), computed here independently.
    let v = json_ok(&[
        "sim",
        "tweezer",
        "--duration",
        "20",
        "--fs",
        "10000",
        "--stiffness-pn-um",
        "20",
        "--radius-um",
        "1.5",
        "--temperature-k",
        "293.15",
        "--viscosity-pa-s",
        "1.0016e-3",
        "--seed",
        "7",
        "--json",
    ]);
    let kappa = 20e-12 / 1e-6;
    let var = 1.380649e-23 * 293.15 / kappa;
    let gamma = 6.0 * std::f64::consts::PI * 1.0016e-3 * 1.5e-6;
    let corner_hz = kappa / (2.0 * std::f64::consts::PI * gamma);
    assert!((v["var_theory_m2"].as_f64().unwrap() / var - 1.0).abs() < 1e-9);
    assert!((v["fc_theory_hz"].as_f64().unwrap() / corner_hz - 1.0).abs() < 1e-9);
    for k in ["var_x_m2", "var_y_m2"] {
        assert!(
            (v[k].as_f64().unwrap() / var - 1.0).abs() < 0.05,
            "{k}: {v}"
        );
    }
    assert!(
        (v["fc_fit_hz"].as_f64().unwrap() / corner_hz - 1.0).abs() < 0.05,
        "{v}"
    );
}
