//! Both devices live: a participant's sitting with the DAQ emulator hosting
//! the study's simulated participant (`kilotouch emulate daq --pty
//! --participant operator:SEED`) and the tweezer emulator serving the
//! protocol's micro-world (`kilotouch emulate tweezer --pty --protocol
//! FILE`), through the one real-time engine — `kilotouch study run --rig
//! serial:PTY1 --tweezer serial:PTY2`. The folder is that of every study
//! and `session.json` names both devices and their delays; a tweezer killed
//! mid-trial ends the sitting naming the tweezer, and `--resume` with the
//! tweezer back continues at the aborted trial; both links' command leads
//! enter the stability check.

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use std::path::Path;
use std::time::Instant;

use common::{Emulator, kilotouch, rows_so_far as rows};
use kilotouch::engine::{EngineHandle, EngineOptions};
use kilotouch::session::FinishReason;
use kilotouch_rig::device::TweezerSpec;
use kilotouch_rig::tweezer::surface_drag;
use kilotouch_rig::{RigConfig, TweezerParams};
use kilotouch_study::protocol::Protocol;
use kilotouch_study::task::Geometry;
use serde_json::Value;

/// 2 participants × 3 conditions × 1 test trial, 1 practice trial per
/// condition, 2 s time-outs: P01's sitting is 6 trials.
const TINY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/tiny.toml");

fn tiny() -> Protocol {
    Protocol::load(Path::new(TINY)).unwrap()
}

/// The emulated DAQ with the protocol's simulated participants at its
/// handle.
fn daq() -> Emulator {
    let p = format!("operator:{}", tiny().seeds.study);
    Emulator::spawn("daq", &["--participant", p.as_str()])
}

/// The emulated tweezer serving the protocol's micro-world.
fn tweezer() -> Emulator {
    Emulator::spawn("tweezer", &["--protocol", TINY])
}

/// `study run` of P01 with the DAQ leading by one block and the tweezer
/// `tweezer_opts` (`,lead=0`: block-synchronous, so the loop delay is the
/// DAQ's 20 samples, inside D's margins).
fn study_run(
    daq: &Emulator,
    tw: &Emulator,
    tweezer_opts: &str,
    out: &Path,
    resume: bool,
) -> std::process::Output {
    study_run_with(daq, tw, tweezer_opts, out, resume, &[])
}

/// [`study_run`] with `extra` arguments.
fn study_run_with(
    daq: &Emulator,
    tw: &Emulator,
    tweezer_opts: &str,
    out: &Path,
    resume: bool,
    extra: &[&str],
) -> std::process::Output {
    let rig = format!("{},lead=1{}", daq.rig(), common::TEST_HOST_TIMEOUT);
    let tweezer = format!("{}{tweezer_opts}", tw.rig());
    let extra = [&["--tweezer", tweezer.as_str()], extra].concat();
    common::study_run_p01(TINY, &rig, out, resume, &extra)
}

/// `kilotouch tweezer record --rig SPEC --duration-s 2 --trap-um SPOT
/// --calibration-out FILE --json` into `dir`: the report and the
/// calibration file.
fn record_calibration(
    spec: &str,
    spot: &str,
    dir: &Path,
    name: &str,
) -> (Value, std::path::PathBuf) {
    let csv = dir.join(format!("{name}.csv"));
    let cal = dir.join(format!("{name}.json"));
    let out = kilotouch(&[
        "tweezer",
        "record",
        "--rig",
        spec,
        "--duration-s",
        "2",
        "--trap-um",
        spot,
        "--out",
        csv.to_str().unwrap(),
        "--calibration-out",
        cal.to_str().unwrap(),
        "--json",
    ]);
    assert!(
        out.status.success(),
        "tweezer record failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    (serde_json::from_slice(&out.stdout).unwrap(), cal)
}

#[test]
fn a_whole_participant_with_a_live_daq_and_a_live_tweezer() {
    let (d, t) = (daq(), tweezer());
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    // The trap calibrated through the live link first: κ per axis of the
    // emulated trap (the rig file's) as the drag of the protocol's
    // obstacle biases it at the recording spot (`tweezer::spot`), R_d of
    // its detector (1/S = 2 µm/V).
    // The trap 15 µm from the protocol's obstacle (at the emulator's
    // origin), a surface-to-surface gap of 8.5 µm.
    let (rec, cal) = record_calibration(&t.rig(), "15,0", dir.path(), "trap");
    let mut rc = RigConfig::default();
    let escape = rc.tweezer.escape_distance_m;
    Geometry::of_protocol(&tiny().task).apply_to(&mut rc.tweezer, escape);
    let truth = kilotouch_rig::units::to_pn_per_um(rc.tweezer.stiffness_n_per_m);
    let drag = surface_drag(&TweezerParams::from_config(&rc.tweezer), [15e-6, 0.0]);
    let bias = drag.kappa_bias();
    let file: Value = serde_json::from_str(&std::fs::read_to_string(&cal).unwrap()).unwrap();
    for (axis, name) in ["x", "y"].into_iter().enumerate() {
        let k = file[name]["kappa_pn_um"].as_f64().unwrap();
        let se = file[name]["kappa_se_pn_um"].as_f64().unwrap();
        let want = truth * (1.0 + bias[axis]);
        assert!(
            (k - want).abs() < 4.0 * se + 0.05 * want,
            "{name}: κ {k} ± {se} pN/µm against {want} (the trap's {truth}, bias {:+.3})",
            bias[axis]
        );
    }
    let kappa = rec["calibration"]["kappa_pn_um"].as_f64().unwrap();
    // R_d = √(D_theory / D_fit) grows with the drag: 2 µm/V × √(drag).
    for (axis, rd) in rec["calibration"]["rd_um_per_v"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
    {
        let rd = rd.as_f64().unwrap();
        let want = 2.0 * drag.drag_factor[axis].sqrt();
        assert!(
            (rd / want - 1.0).abs() < 0.05,
            "R_d {rd} µm/V against {want}"
        );
    }
    let cal_s = cal.to_str().unwrap();
    let run = study_run_with(
        &d,
        &t,
        ",lead=0",
        &out,
        false,
        &["--trap-calibration", cal_s],
    );
    assert!(
        run.status.success(),
        "study run failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report: Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(report["finish"], "participant_done", "{report}");
    assert_eq!(report["committed"], 6, "{report}");
    let got = rows(&out);
    assert_eq!(got.len(), 6);
    for r in &got {
        assert!(r.time_s.is_some_and(|t| t > 0.0 && t <= 2.1), "{r:?}");
        assert!(out.join(&r.raw_file).is_file(), "{}", r.raw_file);
    }
    // The live bead was pressed against the live obstacle: contact in some
    // trials (the circling task's scene is the tweezer's micro-world).
    assert!(
        got.iter()
            .any(|r| r.contact_fraction.is_some_and(|c| c > 0.0)),
        "{got:?}"
    );
    // session.json: both devices and their delays.
    let session: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("session.json")).unwrap()).unwrap();
    let dev = &session["sittings"][0]["device"];
    assert!(
        dev["spec"].as_str().is_some_and(|s| s.contains(&d.path)),
        "{session}"
    );
    assert_eq!(dev["loop_delay_samples"], 20, "{dev}");
    let tw = &dev["tweezer"];
    assert!(
        tw["spec"].as_str().is_some_and(|s| s.contains(&t.path)),
        "{dev}"
    );
    assert_eq!(tw["lead_samples"], 0, "{dev}");
    assert!(tw["name"].as_str().is_some_and(|n| n.contains("tweezer")));
    let journal = std::fs::read_to_string(out.join("journal.jsonl")).unwrap();
    assert!(journal.contains(&t.path), "{journal}");
    // The applied trap calibration, as the file gave it.
    let applied = &session["trap_calibration"];
    assert_eq!(applied["source"], t.rig().as_str(), "{applied}");
    assert_eq!(applied["kappa_pn_um"].as_f64(), Some(kappa), "{applied}");
}

/// `study run --trap-calibration` refuses, before any sitting, a
/// calibration recorded from another tweezer and one whose fit fails the
/// checks, saying why; the folder is not created.
#[test]
fn a_trap_calibration_of_another_tweezer_or_a_failed_fit_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    // `study run --trap-calibration FILE` on fresh emulators: refused, its
    // stderr; nothing written.
    let refused = |file: &Path, tw: &Emulator| {
        let d = daq();
        let file = file.to_str().unwrap();
        let run = study_run_with(
            &d,
            tw,
            ",lead=0",
            &out,
            false,
            &["--trap-calibration", file],
        );
        assert!(!run.status.success());
        assert!(!out.join("session.json").exists());
        String::from_utf8_lossy(&run.stderr).into_owned()
    };
    let (_, sim) = record_calibration("sim", "free", dir.path(), "sim");
    let t = tweezer();
    let err = refused(&sim, &t);
    assert!(
        err.contains("not applied: it was recorded from sim")
            && err.contains(&format!("the live tweezer on {}", t.rig())),
        "{err}"
    );
    // The same file from the right tweezer, but a fit that does not
    // describe the spectrum.
    drop(t);
    let t = tweezer();
    let mut bad: Value = serde_json::from_str(&std::fs::read_to_string(&sim).unwrap()).unwrap();
    bad["source"] = Value::from(t.rig());
    bad["y"]["backing_pct"] = Value::from(1e-6);
    let bad_file = dir.path().join("bad.json");
    std::fs::write(&bad_file, bad.to_string()).unwrap();
    let err = refused(&bad_file, &t);
    assert!(
        err.contains("not applied: y axis: the model does not describe the spectrum"),
        "{err}"
    );
}

#[test]
fn a_killed_tweezer_ends_the_sitting_naming_it_and_resume_continues() {
    let d = daq();
    let mut t = tweezer();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    let rig = RigConfig::default();
    let tspec: TweezerSpec = format!("{},lead=0", t.rig()).parse().unwrap();
    let mut engine = EngineHandle::spawn_devices(
        &rig,
        &d.spec(&format!(",lead=1{}", common::TEST_HOST_TIMEOUT)),
        &tspec,
        EngineOptions::default(),
    )
    .unwrap();
    let mut s = common::start_p01_at_the_handle(tiny(), &out, rig, &mut engine);
    let mut committed = common::until_trials_started(&mut engine, &mut s, 2);
    t.kill();
    let killed = Instant::now();
    let (reason, ended_s) = common::until_finished(&mut engine, &mut s, &mut committed, killed);
    let FinishReason::Failed(why) = reason else {
        panic!("{reason:?}")
    };
    assert!(
        why.contains("tweezer"),
        "the reason names the tweezer: {why}"
    );
    assert!(ended_s < 5.0, "ended {ended_s:.2} s after the kill");
    let _ = s.close(&mut engine);
    common::until_engine_stopped(&mut engine, 2.0);
    assert!(
        engine
            .health()
            .is_some_and(|h| !h.running && h.safety.latched()),
        "outputs held at zero"
    );
    engine.shutdown();
    drop(d);
    let on_disk = rows(&out);
    assert_eq!(on_disk, committed);
    assert!(!committed.is_empty() && committed.len() < 6);
    // Both devices back (new ptys): --resume continues at the aborted trial.
    let (d2, t2) = (daq(), tweezer());
    let run = study_run(&d2, &t2, ",lead=0", &out, true);
    common::assert_resumed(&run, &out, &committed, 6);
    eprintln!("the sitting ended {ended_s:.3} s after the tweezer was killed");
}

#[test]
fn both_links_leads_enter_the_stability_check() {
    // DAQ: 10-sample blocks + one block of lead; the tweezer another block
    // of lead: 30 samples of loop delay, 2.9 ms beyond the simulated
    // loop's one sample: D's phase margin is below the rig file's 30°
    // (docs/theory/coupling-and-stability.md, loop delay: below 30° from 28 samples).
    let (d, t) = (daq(), tweezer());
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    let run = study_run(&d, &t, ",lead=1", &out, false);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        err.contains("D has a phase margin of") || err.contains("D is unstable (phase margin"),
        "{err}"
    );
    assert!(err.contains("extra loop delay of 2.90 ms"), "{err}");
    assert!(rows(&out).is_empty());
}
