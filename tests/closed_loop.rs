//! The paper's workflow end to end, across the crates: calibrate the
//! simulated rig → apply the calibration to the closed loop → press the
//! bead against an obstacle (feel) → run a study with that calibration →
//! check what the study recorded. And the stability analysis checked against
//! simulation where it matters: stiffer traps and larger force scales.
//!
//! The same steps through the command line are in
//! `crates/app/tests/closed_loop_cli.rs`.

use kilotouch_rig::calibration::{CalibrationConfig, NoProgress, calibrate_sim};
use kilotouch_rig::coupling::{ChainSource, LoopChain};
use kilotouch_rig::haptic_loop::Clearance;
use kilotouch_rig::press::{PressOptions, PressReport, simulate_press};
use kilotouch_rig::stability::analyse;
use kilotouch_rig::{Condition, RigConfig};
use kilotouch_study::protocol::Protocol;
use kilotouch_study::runner::RunnerConfig;
use kilotouch_study::simulate::{SimulateOptions, simulate};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("kilotouch-e2e-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}

fn calibrate(dir: &Path, cfg: &RigConfig) -> PathBuf {
    let path = dir.join("cal.toml");
    let rig_file = dir.join("rig.toml");
    std::fs::write(&rig_file, cfg.to_toml_string().expect("toml")).expect("write rig");
    calibrate_sim(
        Some(&rig_file),
        Some(7),
        &CalibrationConfig::default(),
        Some(&path),
        &mut NoProgress,
        &AtomicBool::new(false),
    )
    .expect("calibration of the simulated rig");
    path
}

fn press(cfg: &RigConfig, chain: &LoopChain, condition: Condition, seed: u64) -> PressReport {
    let opts = PressOptions {
        condition,
        duration_s: 5.0,
        seed,
        ..PressOptions::default()
    };
    // The press itself is what is judged here, so arm it whatever the
    // analysis says (simulated rig only).
    let clearance = Clearance::overridden(chain.source.clone());
    simulate_press(cfg, chain, clearance, &opts)
        .expect("press")
        .0
}

/// Calibrated or not, P and D meet the minimum margins, pressing is stable
/// in both, and applying the calibration leaves the pressed force unchanged
/// (≤ 0.5 dB).
#[test]
fn calibrate_apply_press() {
    let dir = tmp("press");
    let cfg = RigConfig::default();
    let cal_path = calibrate(&dir, &cfg);
    let calibrated = LoopChain::load(&cal_path, &cfg).expect("calibration loads for this rig");
    assert!(matches!(calibrated.source, ChainSource::Calibration { .. }));
    let designed = LoopChain::as_designed(&cfg).expect("chain");
    for chain in [&designed, &calibrated] {
        let r = analyse(&cfg, &chain.coefficients).expect("analysis");
        for c in Condition::HAPTIC {
            let m = r.condition(c).expect("analysed");
            assert!(
                m.stable && m.gain_margin_db >= 6.0 && m.phase_margin_deg >= 30.0,
                "{} {c}: {m:?}",
                chain.source.describe()
            );
        }
        Clearance::check(&cfg, chain).expect("cleared");
    }
    for c in Condition::HAPTIC {
        let a = press(&cfg, &designed, c, 3);
        let b = press(&cfg, &calibrated, c, 3);
        for r in [&a, &b] {
            assert!(r.stable && !r.escaped, "{r:?}");
            assert!(r.growth_db_per_s < 1.0, "{r:?}");
            assert!(r.contact_fraction > 0.99, "{r:?}");
            // The pressed force is the one asked for (the static balance).
            assert!(
                (r.handle_force_mean_n / r.expected_force_n - 1.0).abs() < 0.01,
                "{r:?}"
            );
        }
        let change_db = 20.0 * (b.handle_force_mean_n / a.handle_force_mean_n).log10();
        assert!(
            change_db.abs() <= 0.5,
            "{c}: calibration changed the force by {change_db} dB"
        );
    }
}

/// A one-participant study with the calibration records it (path and
/// SHA-256 in session.json and every session_started journal line); a
/// resume with another chain is refused.
#[test]
fn a_study_records_its_calibration() {
    let dir = tmp("study");
    let cfg = RigConfig::default();
    let cal_path = calibrate(&dir, &cfg);
    let mut protocol = Protocol::paper().expect("paper protocol");
    protocol.participants = 1;
    let out = dir.join("study");
    let runner = RunnerConfig {
        raw: None,
        ..RunnerConfig::default()
    };
    let mut opts = SimulateOptions {
        protocol,
        out: out.clone(),
        resume: false,
        rig: cfg.clone(),
        calibration: Some(cal_path.clone()),
        runner,
        threads: 2,
        fidelity: kilotouch_study::fidelity::Fidelity::Full,
        shard: None,
        new_sitting: None,
    };
    let rep = simulate(&opts, &mut |_, _| {}).expect("study");
    assert!(rep.test_rows > 0);
    let sha = sha256sum(&cal_path);
    let session: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("session.json")).expect("session"))
            .expect("json");
    assert_eq!(session["calibration"]["sha256"], sha.as_str());
    assert_eq!(
        session["calibration"]["path"],
        cal_path.display().to_string()
    );
    let journal = std::fs::read_to_string(out.join("journal.jsonl")).expect("journal");
    let starts: Vec<&str> = journal
        .lines()
        .filter(|l| l.contains("session_started"))
        .collect();
    assert!(!starts.is_empty());
    assert!(starts.iter().all(|l| l.contains(&sha)), "{starts:?}");

    // Resuming the (complete) study without the calibration, or with
    // another file, is refused before anything runs.
    opts.resume = true;
    opts.calibration = None;
    let e = simulate(&opts, &mut |_, _| {}).expect_err("another chain");
    assert!(e.to_string().contains("calibration"), "{e}");
    // The same calibration with a comment added: valid, but other bytes.
    let other = dir.join("other.toml");
    let mut text = std::fs::read_to_string(&cal_path).expect("read");
    text.push_str("\n# another file\n");
    std::fs::write(&other, text).expect("write");
    opts.calibration = Some(other);
    let e = simulate(&opts, &mut |_, _| {}).expect_err("another file");
    assert!(e.to_string().contains("mix"), "{e}");
}

/// For stiffer traps and larger force scales, the analysis' verdict and the
/// simulated one agree. The rig file's hand range is narrowed to the
/// simulated finger, so that the analysis' worst case is the simulated case;
/// the settings sit 30 % inside and 40 % beyond the critical values.
#[test]
fn predicted_and_simulated_stability_agree() {
    let mut cfg = RigConfig::default();
    cfg.stability.hand_stiffness_n_per_m = [cfg.plant.k_f; 2];
    cfg.stability.hand_damping_n_s_per_m = [cfg.plant.b_f; 2];
    let chain = LoopChain::as_designed(&cfg).expect("chain");
    let base = analyse(&cfg, &chain.coefficients).expect("analysis");
    let kappa_c = base.critical_trap_stiffness_n_per_m;
    let g_c = base.critical_force_scale;
    assert!(kappa_c.is_finite() && g_c.is_finite());
    let mut checked = 0;
    for (what, factor) in [("trap", 0.7), ("trap", 1.4), ("force", 0.7), ("force", 1.4)] {
        let mut c = cfg.clone();
        if what == "trap" {
            c.tweezer.stiffness_n_per_m = factor * kappa_c;
        } else {
            c.coupling.force_scale = factor * g_c;
        }
        let r = analyse(&c, &chain.coefficients).expect("analysis");
        // Same pressed force in every setting: the depth scales inversely.
        let depth = 0.8e-6 * cfg.coupling.force_scale / c.coupling.force_scale
            * cfg.tweezer.stiffness_n_per_m
            / c.tweezer.stiffness_n_per_m;
        for cond in Condition::HAPTIC {
            let predicted = r.condition(cond).expect("analysed").stable;
            let opts = PressOptions {
                condition: cond,
                duration_s: 5.0,
                seed: 11,
                depth_m: depth.min(0.9 * c.tweezer.escape_distance_m),
            };
            let sim = simulate_press(
                &c,
                &chain,
                Clearance::overridden(chain.source.clone()),
                &opts,
            )
            .expect("press")
            .0;
            assert_eq!(
                sim.stable,
                predicted,
                "{what} ×{factor}, {cond}: simulated {sim:?}, predicted {}",
                r.summary()
            );
            checked += usize::from(!predicted);
        }
    }
    assert!(checked >= 2, "the unstable side must be exercised");
}

/// The passivity observer/controller as a run-time net: a deliberately
/// unstable setting (no wall damper, twice the force scale) chatters and
/// loses contact without it, and stays pressed and quiet with it.
#[test]
fn the_passivity_controller_catches_a_deliberately_unstable_loop() {
    let mut cfg = RigConfig::default();
    cfg.coupling.contact_damping_n_s_per_m = 0.0;
    cfg.coupling.force_scale = 2e11;
    let chain = LoopChain::as_designed(&cfg).expect("chain");
    let r = analyse(&cfg, &chain.coefficients).expect("analysis");
    assert!(
        !r.condition(Condition::D).expect("D").nominal_stable,
        "{}",
        r.summary()
    );
    let opts = PressOptions {
        condition: Condition::D,
        duration_s: 5.0,
        seed: 5,
        depth_m: 0.4e-6,
    };
    let run = |pc: bool| {
        let mut c = cfg.clone();
        c.coupling.passivity_controller = pc;
        simulate_press(
            &c,
            &chain,
            Clearance::overridden(chain.source.clone()),
            &opts,
        )
        .expect("press")
        .0
    };
    let (off, on) = (run(false), run(true));
    assert!(!off.stable && off.passivity_active_samples == 0, "{off:?}");
    assert!(
        on.stable && !on.escaped && on.passivity_active_samples > 0,
        "{on:?}"
    );
    assert!(
        on.handle_force_osc_rms_n < 0.1 * off.handle_force_osc_rms_n,
        "{on:?} vs {off:?}"
    );
    assert!(
        (on.handle_force_mean_n / on.expected_force_n - 1.0).abs() < 0.02,
        "{on:?}"
    );
}

/// SHA-256 of the file at `path` from coreutils' `sha256sum`, an
/// implementation independent of the study crate's.
fn sha256sum(path: &Path) -> String {
    let out = std::process::Command::new("sha256sum")
        .arg(path)
        .output()
        .expect("sha256sum (coreutils) runs");
    assert!(out.status.success());
    String::from_utf8_lossy(&out.stdout)
        .split_whitespace()
        .next()
        .expect("a digest")
        .to_owned()
}
