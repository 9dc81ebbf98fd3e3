//! End-to-end checks across crates.

/// The dsp crate's paper model evaluates to the published value at 1 kHz
/// (docs/REFERENCE-VALUES.md: |G_H(j2π·1000)| = 0.0453443).
#[test]
fn paper_model_is_reachable_from_the_workspace() {
    let g = kilotouch_dsp::Tf::new(vec![250.0, 6.40e5], vec![1.0, 2135.0, 4.56e6]).expect("valid");
    assert!((g.response_hz(1000.0).norm() - 0.0453443).abs() < 1e-7);
}

/// Each crate whose tests are one binary (`autotests = false`, `tests/main.rs`)
/// declares every file of its `tests/` directory as a module of that binary.
/// Cargo does not see a file left out, so its tests would silently never run.
#[test]
fn every_test_file_is_compiled() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut crates = vec![root.to_path_buf()];
    for entry in std::fs::read_dir(root.join("crates")).expect("crates/ is readable") {
        crates.push(entry.expect("crates/ entry").path());
    }
    let mut checked = 0;
    for krate in crates {
        let main = krate.join("tests/main.rs");
        let manifest = std::fs::read_to_string(krate.join("Cargo.toml")).unwrap_or_default();
        if !main.exists() {
            assert!(
                !manifest.contains("autotests = false"),
                "{}: autotests = false but no tests/main.rs",
                krate.display()
            );
            continue;
        }
        assert!(
            manifest.contains("autotests = false"),
            "{}: tests/main.rs exists but Cargo.toml does not say autotests = false",
            krate.display()
        );
        let text = std::fs::read_to_string(&main).expect("tests/main.rs is readable");
        let declared: Vec<&str> = text
            .lines()
            .filter_map(|l| l.trim().strip_prefix("mod ")?.strip_suffix(';'))
            .collect();
        for entry in std::fs::read_dir(krate.join("tests")).expect("tests/ is readable") {
            let path = entry.expect("tests/ entry").path();
            let Some(stem) = path.file_stem().and_then(|s| s.to_str()) else {
                continue;
            };
            let is_module = (path.extension().is_some_and(|e| e == "rs") && stem != "main")
                || path.join("mod.rs").exists();
            if is_module {
                assert!(
                    declared.contains(&stem),
                    "{} is not declared in {} (`mod {stem};`): its tests never run",
                    path.display(),
                    main.display()
                );
                checked += 1;
            }
        }
    }
    // The app, rig, study and end-to-end test directories hold 89 files.
    assert!(checked >= 80, "only {checked} test files found");
}
