//! `kilotouch tweezer calibrate` and `kilotouch tweezer record` end to end
//! through the real executable: a stored record against pylake's values,
//! the plot, clear errors, and the whole live path — the simulated tweezer
//! behind `kilotouch emulate tweezer`, recorded over the serial link and
//! calibrated — recovering the simulated κ.
#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::{Emulator, json_ok, kilotouch as run};
use std::io::Write;
use std::path::{Path, PathBuf};

fn rig_tests_data() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../rig/tests/data/trap_psd")
}

/// Write a stored float32 record as a one-column CSV `v`.
fn record_csv(name: &str, dir: &Path) -> PathBuf {
    let b = std::fs::read(rig_tests_data().join(format!("{name}.f32"))).unwrap();
    let path = dir.join(format!("{name}.csv"));
    let mut w = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
    writeln!(w, "v").unwrap();
    for c in b.chunks_exact(4) {
        writeln!(w, "{:e}", f32::from_le_bytes([c[0], c[1], c[2], c[3]])).unwrap();
    }
    w.flush().unwrap();
    path
}

fn pylake(name: &str) -> serde_json::Value {
    let text = std::fs::read_to_string(rig_tests_data().join("pylake_reference.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["cases"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == name)
        .unwrap()["pylake"]
        .clone()
}

fn f(v: &serde_json::Value, k: &str) -> f64 {
    v[k].as_f64().unwrap_or_else(|| panic!("no `{k}` in {v}"))
}

#[test]
fn calibrates_a_diode_record_like_pylake_and_plots_it() {
    let dir = tempfile::tempdir().unwrap();
    let csv = record_csv("diode", dir.path());
    let png = dir.path().join("fit.png");
    let v = json_ok(&[
        "tweezer",
        "calibrate",
        csv.to_str().unwrap(),
        "--fs",
        "50000",
        "--column",
        "v",
        "--radius-um",
        "1.0",
        "--viscosity-pa-s",
        "1.002e-3",
        "--temperature-k",
        "293.15",
        "--fit-range",
        "100,23000",
        "--points-per-block",
        "100",
        "--diode",
        "--json",
        "--plot",
        png.to_str().unwrap(),
    ]);
    for k in [
        "fc_hz",
        "fc_se_hz",
        "diffusion_v2_s",
        "diffusion_se_v2_s",
        "kappa_pn_um",
        "kappa_se_pn_um",
        "rd_um_per_v",
        "rf_pn_per_v",
        "chi2_per_dof",
        "backing_pct",
        "f_diode_hz",
        "alpha",
    ] {
        assert!(v[k].is_number(), "`{k}` missing: {v}");
    }
    let py = pylake("diode");
    for (ours, theirs) in [
        ("fc_hz", "fc"),
        ("kappa_pn_um", "kappa_pn_um"),
        ("rd_um_per_v", "Rd"),
        ("rf_pn_per_v", "Rf"),
        ("f_diode_hz", "f_diode"),
        ("alpha", "alpha"),
    ] {
        let (a, b) = (f(&v, ours), f(&py, theirs));
        assert!((a / b - 1.0).abs() < 0.01, "{ours}: {a} vs pylake {b}");
    }
    let img = std::fs::read(&png).expect("plot written");
    assert!(
        img.starts_with(b"\x89PNG") && img.len() > 20_000,
        "{}",
        img.len()
    );
}

#[test]
fn plain_fit_has_no_diode_keys_and_errors_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let csv = record_csv("plain", dir.path());
    let base = [
        "tweezer",
        "calibrate",
        csv.to_str().unwrap(),
        "--fs",
        "50000",
        "--radius-um",
        "1.5",
        "--viscosity-pa-s",
        "1.002e-3",
        "--temperature-k",
        "293.15",
        "--points-per-block",
        "100",
    ];
    let mut args = base.to_vec();
    args.extend(["--column", "v", "--fit-range", "100,20000", "--json"]);
    let v = json_ok(&args);
    assert!(
        v.get("f_diode_hz").is_none() && v.get("alpha").is_none(),
        "{v}"
    );
    let py = pylake("plain");
    assert!((f(&v, "kappa_pn_um") / f(&py, "kappa_pn_um") - 1.0).abs() < 0.01);

    let mut args = base.to_vec();
    args.extend(["--column", "volts", "--fit-range", "100,20000"]);
    let out = run(&args);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("volts"), "{err}");

    let mut args = base.to_vec();
    args.extend(["--column", "v", "--fit-range", "100,30000"]);
    let err = String::from_utf8_lossy(&run(&args).stderr).to_string();
    assert!(err.contains("Nyquist"), "{err}");

    let mut args = base.to_vec();
    args.extend([
        "--column",
        "v",
        "--fit-range",
        "100,20000",
        "--aliased",
        "--diode",
    ]);
    let err = String::from_utf8_lossy(&run(&args).stderr).to_string();
    assert!(err.contains("--aliased"), "{err}");

    let mut args = base.to_vec();
    args.extend(["--column", "v", "--fit-range", "100-20000"]);
    assert_eq!(run(&args).status.code(), Some(2));
}

#[test]
fn emulated_tweezer_calibrates_to_its_simulated_stiffness_within_2_percent() {
    // A stiffer trap than the default scene (κ = 100 pN/µm, f_c = 468 Hz),
    // the bead 5 µm above the coverslip (Faxén 1.200) and no obstacles near the trap: 12 s at
    // 10 kHz through the serial link give σ_κ/κ ≈ 0.6 % from x and y.
    let dir = tempfile::tempdir().unwrap();
    let mut rc = kilotouch_rig::RigConfig::default();
    rc.tweezer.stiffness_n_per_m = 1e-4;
    rc.tweezer.wall_distance_m = Some(5e-6);
    rc.tweezer.obstacles.clear();
    let rig_file = dir.path().join("stiff.toml");
    std::fs::write(&rig_file, rc.to_toml_string().unwrap()).unwrap();
    let emu = Emulator::spawn("tweezer", &["--rig-config", rig_file.to_str().unwrap()]);
    let rec = dir.path().join("rec.csv");
    let r = json_ok(&[
        "tweezer",
        "record",
        "--rig",
        &format!("{},timeout-ms=1000", emu.rig()),
        "--duration-s",
        "12",
        "--out",
        rec.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(r["n_samples"].as_u64(), Some(120_000), "{r}");
    let mut kappa = Vec::new();
    for col in ["x_v", "y_v"] {
        let v = json_ok(&sim_calibrate_args(
            rec.to_str().unwrap(),
            col,
            &["--distance-to-surface-um", "5"],
        ));
        let rd = f(&v, "rd_um_per_v");
        assert!((rd / 2.0 - 1.0).abs() < 0.02, "{col}: R_d {rd} µm/V vs 2");
        assert!(f(&v, "chi2_per_dof") < 1.3, "{v}");
        kappa.push(f(&v, "kappa_pn_um"));
    }
    let mean = 0.5 * (kappa[0] + kappa[1]);
    assert!(
        (mean / 100.0 - 1.0).abs() < 0.02,
        "κ {kappa:?} pN/µm vs 100"
    );
}

/// `tweezer record` of 10 s of the simulated tweezer into `out` (JSON
/// report), with `extra`.
fn sim_record_args<'a>(out: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "tweezer",
        "record",
        "--rig",
        "sim",
        "--duration-s",
        "10",
        "--out",
        out,
        "--json",
    ];
    a.extend_from_slice(extra);
    a
}

/// `tweezer calibrate` of column `col` of a simulated-tweezer record `rec`
/// (10 kHz, 1.5 µm bead in water at 20 °C, aliased, JSON), with `extra`.
fn sim_calibrate_args<'a>(rec: &'a str, col: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "tweezer",
        "calibrate",
        rec,
        "--fs",
        "10000",
        "--column",
        col,
        "--radius-um",
        "1.5",
        "--viscosity-pa-s",
        "1.0016e-3",
        "--temperature-k",
        "293.15",
        "--fit-range",
        "10,5000",
        "--points-per-block",
        "100",
        "--aliased",
        "--json",
    ];
    a.extend_from_slice(extra);
    a
}

/// Calibrate one column of a simulated record (the default rig's bead,
/// aliased Lorentzian): the JSON.
fn calibrate_sim_column(rec: &Path, col: &str) -> serde_json::Value {
    json_ok(&sim_calibrate_args(rec.to_str().unwrap(), col, &[]))
}

#[test]
fn simulated_record_is_free_by_default_and_warns_next_to_an_obstacle() {
    // The default rig's scene has an obstacle of radius 5 µm at (12, 0) µm:
    // a trap at (0, 0) holds the bead 5.5 µm from its surface, where
    // Brenner's drag (x) and Faxén's (y) lower f_c and so κ by ≈ 24 % and
    // 12 % (kilotouch_rig::tweezer::spot). By default the record is taken
    // in free solution and calibrates to the rig's κ = 20 pN/µm.
    let dir = tempfile::tempdir().unwrap();
    let free = dir.path().join("free.csv");
    let r = json_ok(&sim_record_args(free.to_str().unwrap(), &[]));
    assert_eq!(r["spot"], "free", "{r}");
    assert!(r["warnings"].as_array().unwrap().is_empty(), "{r}");
    assert_eq!(r["kappa_bias"][0].as_f64(), Some(0.0), "{r}");
    for col in ["x_v", "y_v"] {
        let v = calibrate_sim_column(&free, col);
        assert!(v.get("warnings").is_none(), "{v}");
        let (k, se) = (f(&v, "kappa_pn_um"), f(&v, "kappa_se_pn_um"));
        assert!(
            (k - 20.0).abs() < 2.5 * se,
            "{col}: free κ {k} ± {se} pN/µm vs the rig's 20"
        );
    }

    let near = dir.path().join("near.csv");
    let out = run(&sim_record_args(
        near.to_str().unwrap(),
        &["--trap-um", "0,0"],
    ));
    assert!(out.status.success());
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("warning") && err.contains("5.50 µm") && err.contains("(12.0, 0.0) µm"),
        "{err}"
    );
    assert_eq!(r["spot"], "scene", "{r}");
    let bias = [0, 1].map(|k| r["kappa_bias"][k].as_f64().unwrap());
    for (k, col) in ["x_v", "y_v"].iter().enumerate() {
        let out = run(&sim_calibrate_args(near.to_str().unwrap(), col, &[]));
        assert!(out.status.success());
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("warning") && err.contains("free solution"),
            "{err}"
        );
        assert_eq!(v["warnings"].as_array().map(Vec::len), Some(1), "{v}");
        // The measured κ is as soft as the predicted drag says (the
        // prediction mixes the normal and tangential mobilities; within a
        // few per cent of κ).
        let (kappa, se) = (f(&v, "kappa_pn_um"), f(&v, "kappa_se_pn_um"));
        let predicted = 20.0 * (1.0 + bias[k]);
        assert!(
            (kappa - 20.0).abs() > 5.0 * se && (kappa / predicted - 1.0).abs() < 0.05,
            "{col}: κ {kappa} ± {se} pN/µm next to the obstacle, predicted {predicted}"
        );
    }
}
