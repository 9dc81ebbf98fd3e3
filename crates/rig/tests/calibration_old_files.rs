//! Calibration files written before the crossover frequency had one name
//! (`format_version` 1: `crossover.fc_hz`, with copies in
//! `compensators.crossover_hz` and `compensators.crossover_order`) still
//! load, and give the crossover and compensators they were written with.
//! The fixtures in `tests/data/calibration/` were written by the software of
//! that time (how: the first line of each).

#![allow(clippy::unwrap_used)]

use kilotouch_rig::calibration::hash::content_hash;
use kilotouch_rig::calibration::*;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/calibration")
        .join(name)
}

/// The fixture's text and its TOML values as written.
fn raw(name: &str) -> (String, toml::Table) {
    let text = std::fs::read_to_string(fixture(name)).unwrap();
    let table = toml::from_str(&text).unwrap();
    (text, table)
}

fn float(t: &toml::Table, table: &str, key: &str) -> f64 {
    t[table][key].as_float().unwrap()
}

/// Both fixtures: the automatic crossover (`kilotouch calibrate --rig sim
/// --seed 7`) and one set in the settings (`settings.crossover.fc_hz`).
const FIXTURES: [(&str, Option<f64>); 2] = [
    ("before-crossover-rename.toml", None),
    ("before-crossover-rename-fixed.toml", Some(180.0)),
];

#[test]
fn old_files_load_with_the_crossover_and_compensators_they_hold() {
    for (name, fixed) in FIXTURES {
        let (_, t) = raw(name);
        let f = CalibrationFile::load(fixture(name)).unwrap();
        // The crossover as written, both copies.
        let fc = float(&t, "crossover", "fc_hz");
        assert_eq!(float(&t, "compensators", "crossover_hz"), fc, "{name}");
        assert_eq!(f.crossover.crossover_hz, fc, "{name}");
        assert_eq!(
            f.crossover.order as i64,
            t["crossover"]["order"].as_integer().unwrap()
        );
        assert_eq!(f.settings.crossover.crossover_hz, fixed, "{name}");
        if let Some(fixed) = fixed {
            assert_eq!(fc, fixed);
        }
        // The compensators as written.
        let c = &f.compensators;
        for (key, v) in [("k_sys", c.k_sys), ("g0_l", c.g0_l), ("c_l", c.c_l)] {
            assert_eq!(v, float(&t, "compensators", key), "{name}: {key}");
        }
        let c_h = t["compensators"]["c_h"]["num"].as_array().unwrap();
        let c_h: Vec<f64> = c_h.iter().map(|v| v.as_float().unwrap()).collect();
        assert_eq!(c.c_h.num, c_h, "{name}");
        assert_eq!(f.format_version, file::FORMAT_VERSION);

        // The same as this software's calibration of the same simulated rig
        // (same seed, same settings): behaviour unchanged by the rename.
        let mut cfg = CalibrationConfig::default();
        cfg.crossover.crossover_hz = fixed;
        assert_eq!(f.settings, cfg, "{name}");
        let cancel = AtomicBool::new(false);
        let now = calibrate_sim(None, Some(7), &cfg, None, &mut NoProgress, &cancel).unwrap();
        assert_eq!(f.crossover, now.crossover, "{name}");
        assert_eq!(f.compensators, now.design, "{name}");
        // (The raw records of the verification are not stored in files.)
        let mut verification = now.verification.clone();
        verification.raw.clear();
        assert!(f.verification == verification, "{name}: verification");
        assert_eq!(
            f.chain_coefficients().unwrap(),
            now.design.chain_coefficients(&now.crossover).unwrap()
        );
    }
}

#[test]
fn an_old_file_saved_again_stores_the_crossover_once() {
    let (name, _) = FIXTURES[0];
    let f = CalibrationFile::load(fixture(name)).unwrap();
    let text = f.to_toml_string().unwrap();
    assert!(!text.contains("fc_hz"), "{text}");
    assert_eq!(text.matches("crossover_hz =").count(), 1, "{text}");
    assert!(!text.contains("crossover_order"));
    assert!(text.contains("format_version = 2"));
    let again = CalibrationFile::from_toml_str(&text, "again.toml").unwrap();
    assert_eq!(again, f);
}

/// An old file whose contents were edited after writing is still refused
/// by its checksum.
#[test]
fn an_edited_old_file_is_corrupted() {
    let (name, _) = FIXTURES[0];
    let (text, t) = raw(name);
    let k = float(&t, "compensators", "k_sys");
    let edited = text.replacen(
        &format!("k_sys = {k:?}"),
        &format!("k_sys = {:?}", k * 1.01),
        1,
    );
    assert_ne!(edited, text);
    let e = CalibrationFile::from_toml_str(&edited, "edited.toml").unwrap_err();
    assert!(matches!(e, CalibrationError::Corrupted { .. }), "{e}");
}

/// An old file whose two copies of the crossover disagree (checksum right)
/// is refused, the error naming the file and both values.
#[test]
fn an_old_file_whose_crossover_copies_disagree_is_refused() {
    let (name, _) = FIXTURES[1];
    let (_, mut t) = raw(name);
    t["compensators"].as_table_mut().unwrap()["crossover_hz"] = toml::Value::Float(200.0);
    t["checksum"] = toml::Value::String(String::new());
    t["checksum"] = toml::Value::String(content_hash(&t).unwrap());
    let text = toml::to_string(&t).unwrap();
    let e = CalibrationFile::from_toml_str(&text, "two.toml").unwrap_err();
    assert!(matches!(e, CalibrationError::InvalidFile { .. }), "{e}");
    let msg = e.to_string();
    for part in [
        "two.toml",
        "crossover.fc_hz` = 180 Hz",
        "crossover_hz` = 200 Hz",
    ] {
        assert!(msg.contains(part), "{part}: {msg}");
    }
    // Both copies moved together load (C_L, C_H and G0_L do not depend on
    // the crossover frequency, so the contents stay consistent).
    t["crossover"].as_table_mut().unwrap()["fc_hz"] = toml::Value::Float(200.0);
    t["checksum"] = toml::Value::String(String::new());
    t["checksum"] = toml::Value::String(content_hash(&t).unwrap());
    let f = CalibrationFile::from_toml_str(&toml::to_string(&t).unwrap(), "two.toml").unwrap();
    assert_eq!(f.crossover.crossover_hz, 200.0);
}
