//! The study folder `kilotouch study simulate` writes describes itself and
//! keeps its raw files consistent: `datapackage.json` (Frictionless Tabular
//! Data Package) agrees with the CSV headers and every value satisfies its
//! declared type and constraints; escaped trials carry event code 3 on
//! their escape sample and the end code on the next; the sidecar carries
//! the scene and `out_high` in volts; the journal's study seed is a string.

#![allow(clippy::unwrap_used)]

use std::collections::HashSet;
use std::path::Path;
use std::process::Command;

use kilotouch_study::export::{TRIALS_FILE, read_trials};
use kilotouch_study::rawsig::{read_npy, read_sidecar, sidecar_path};
use serde_json::Value;

fn simulate(dir: &Path, protocol: &str, participants: &str, seed: &str) -> std::path::PathBuf {
    let out = dir.join("study");
    let o = Command::new(env!("CARGO_BIN_EXE_kilotouch"))
        .args([
            "study",
            "simulate",
            "--protocol",
            protocol,
            "--participants",
            participants,
            "--seed",
            seed,
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

fn write_protocol(dir: &Path, trials: u32) -> String {
    kilotouch_testkit::write_circling_protocol(dir, "folder-test", trials, 1, 1)
}

/// Reads a CSV as header + text records.
fn csv_table(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let mut r = csv::Reader::from_path(path).unwrap();
    let header = r.headers().unwrap().iter().map(str::to_owned).collect();
    let rows = r
        .records()
        .map(|x| x.unwrap().iter().map(str::to_owned).collect())
        .collect();
    (header, rows)
}

/// Checks one cell against a Table Schema field (the subset of types and
/// constraints the descriptor uses); returns a message on violation.
fn check_cell(field: &Value, cell: &str, missing: &[String]) -> Result<(), String> {
    let name = field["name"].as_str().unwrap();
    let c = &field["constraints"];
    if missing.iter().any(|m| m == cell) {
        return if c["required"].as_bool() == Some(true) {
            Err(format!("{name}: required but empty"))
        } else {
            Ok(())
        };
    }
    let number = |s: &str| {
        s.parse::<f64>()
            .map_err(|_| format!("{name}: `{s}` not a number"))
    };
    match field["type"].as_str().unwrap() {
        "string" => {}
        "integer" => {
            cell.parse::<i64>()
                .map_err(|_| format!("{name}: `{cell}` not an integer"))?;
        }
        "number" => {
            number(cell)?;
        }
        "boolean" => {
            let t: Vec<&str> = field["trueValues"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_str().unwrap())
                .collect();
            let f: Vec<&str> = field["falseValues"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_str().unwrap())
                .collect();
            if !t.contains(&cell) && !f.contains(&cell) {
                return Err(format!("{name}: `{cell}` not a boolean"));
            }
        }
        other => return Err(format!("{name}: unexpected type {other}")),
    }
    if let Some(e) = c["enum"].as_array()
        && !e.iter().any(|v| v.as_str() == Some(cell))
    {
        return Err(format!("{name}: `{cell}` not in {e:?}"));
    }
    if let Some(min) = c["minimum"].as_f64()
        && number(cell)? < min
    {
        return Err(format!("{name}: `{cell}` < {min}"));
    }
    if let Some(max) = c["maximum"].as_f64()
        && number(cell)? > max
    {
        return Err(format!("{name}: `{cell}` > {max}"));
    }
    Ok(())
}

fn check_package(dir: &Path) {
    let text = std::fs::read_to_string(dir.join("datapackage.json")).unwrap();
    let pkg: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(pkg["profile"], "tabular-data-package");
    let resources = pkg["resources"].as_array().unwrap();
    let names: Vec<&str> = resources
        .iter()
        .map(|r| r["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["trials", "cells_long", "cells_wide"]);
    for r in resources {
        let path = dir.join(r["path"].as_str().unwrap());
        let (header, rows) = csv_table(&path);
        let schema = &r["schema"];
        let fields = schema["fields"].as_array().unwrap();
        let declared: Vec<&str> = fields.iter().map(|f| f["name"].as_str().unwrap()).collect();
        assert_eq!(declared, header, "{}: fields = CSV header", r["name"]);
        for f in fields {
            let d = f["description"].as_str().unwrap();
            if f["type"] == "number" {
                assert!(
                    d.contains("unit:") || d.contains("dimensionless"),
                    "{}: number without a unit: {d}",
                    f["name"]
                );
            }
        }
        let missing: Vec<String> = schema["missingValues"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap().to_owned())
            .collect();
        assert_eq!(missing, [""]);
        assert!(!rows.is_empty(), "{}: rows", r["name"]);
        let key: Vec<usize> = schema["primaryKey"]
            .as_array()
            .unwrap()
            .iter()
            .map(|k| {
                header
                    .iter()
                    .position(|h| h == k.as_str().unwrap())
                    .unwrap()
            })
            .collect();
        let mut seen = HashSet::new();
        for (i, row) in rows.iter().enumerate() {
            for (f, cell) in fields.iter().zip(row) {
                check_cell(f, cell, &missing)
                    .unwrap_or_else(|e| panic!("{} line {}: {e}", r["name"], i + 2));
            }
            let k: Vec<&str> = key.iter().map(|&j| row[j].as_str()).collect();
            assert!(seen.insert(k.join("\u{1f}")), "duplicate primary key {k:?}");
        }
    }
}

#[test]
fn simulated_folders_are_valid_data_packages() {
    let tmp = tempfile::tempdir().unwrap();
    let circling = simulate(tmp.path(), &write_protocol(tmp.path(), 2), "2", "5");
    check_package(&circling);
    let tmp2 = tempfile::tempdir().unwrap();
    let blind = simulate(tmp2.path(), "blind", "1", "3");
    check_package(&blind);
    // The blind study has blind-navigation metric columns in its
    // summaries, and the descriptor follows them.
    let pkg: Value =
        serde_json::from_str(&std::fs::read_to_string(blind.join("datapackage.json")).unwrap())
            .unwrap();
    let long = &pkg["resources"][1]["schema"]["fields"];
    assert!(
        long.as_array()
            .unwrap()
            .iter()
            .any(|f| f["name"] == "time_to_collision_s")
    );
}

#[test]
fn raw_files_carry_escapes_scene_and_units_and_the_journal_seed_is_text() {
    let tmp = tempfile::tempdir().unwrap();
    let out = simulate(tmp.path(), &write_protocol(tmp.path(), 6), "3", "11");
    let rows = read_trials(&out.join(TRIALS_FILE)).unwrap().rows;
    let mut escaped = 0;
    for r in &rows {
        let path = out.join(&r.raw_file);
        let side = read_sidecar(&sidecar_path(&path)).unwrap();
        let col = |n: &str| side.channels.iter().position(|c| c.name == n).unwrap();
        assert_eq!(side.channels[col("out_high")].unit, "V");
        let scene = &side.attrs["scene"];
        let centre: Vec<f64> = scene["obstacle_centre_m"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let start: Vec<f64> = scene["start_m"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let rc = scene["contact_radius_m"].as_f64().unwrap();
        assert!(
            (rc - scene["obstacle_radius_m"].as_f64().unwrap()
                - scene["bead_radius_m"].as_f64().unwrap())
            .abs()
                < 1e-15
        );
        // Circling starts 2 µm outside the contact circle
        // (task::CIRCLING_START_GAP_M).
        let gap = ((start[0] - centre[0]).hypot(start[1] - centre[1])) - rc;
        assert!((gap - 2e-6).abs() < 1e-12, "start gap {gap}");
        let arr = read_npy(&path).unwrap();
        let ev = col("event");
        let n = usize::try_from(arr.rows).unwrap();
        let codes: Vec<f64> = (0..n).map(|i| arr.row(i)[ev]).collect();
        assert_eq!(codes[n - 1], 9.0, "last sample ends the trial");
        assert_eq!(codes.iter().filter(|&&c| c == 9.0).count(), 1);
        if r.escaped == Some(true) {
            escaped += 1;
            let at = codes.iter().rposition(|&c| c == 3.0);
            assert!(at.is_some(), "{}: escaped without code 3", r.raw_file);
            // An escape that ends the trial: code 3, then the end code.
            if r.reject_reason == "escaped" {
                assert_eq!(at, Some(n - 2), "{}", r.raw_file);
            }
        }
    }
    assert!(escaped > 0, "the simulated study has escaped trials");
    let journal = std::fs::read_to_string(out.join("journal.jsonl")).unwrap();
    let first: Value = serde_json::from_str(journal.lines().next().unwrap()).unwrap();
    assert_eq!(first["type"], "session_started");
    assert_eq!(first["study_seed"], Value::String("11".into()));
}
