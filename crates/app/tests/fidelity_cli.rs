//! Speed against error as a user asks for it: `kilotouch bench fidelity`
//! (the same cohort at full, scene and draft; JSON, table, frontier plot)
//! and `kilotouch study power --simulate` (the search at draft with its
//! final check at scene), on a tiny protocol.
#![allow(clippy::unwrap_used)]

use common::{assert_non_blank_png, json_ok, kilotouch, write_circling_protocol_timeout};
use kilotouch_testkit as common;
use serde_json::Value;

/// V/P/D × 2 test trials (1 practice), a 60 s time-out (so that P and D
/// succeed and every participant has the cells the power analysis needs),
/// seed 5; the commands set the participants.
fn tiny(dir: &std::path::Path) -> String {
    write_circling_protocol_timeout(dir, "tiny", 2, 1, 5, 60.0)
}

fn f(v: &Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("`{key}` is not a number in {v}"))
}

#[test]
fn bench_fidelity_reports_each_level_and_draws_the_frontier() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = tiny(tmp.path());
    let out = tmp.path().join("frontier");
    let out_s = out.to_str().unwrap();
    let r = json_ok(&[
        "bench",
        "fidelity",
        "--protocol",
        &proto,
        "--participants",
        "2",
        "--seed",
        "5",
        "--n",
        "3,6",
        "--replications",
        "50",
        "--out",
        out_s,
        "--json",
    ]);
    for key in [
        "participants",
        "seed",
        "threads",
        "bound_se",
        "question",
        "levels",
        "plot",
    ] {
        assert!(!r[key].is_null(), "`{key}` missing in {r}");
    }
    assert_eq!(r["test_trials_per_condition"], 2, "per participant");
    let levels = r["levels"].as_array().unwrap();
    let names: Vec<&str> = levels
        .iter()
        .map(|l| l["fidelity"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["full", "scene", "draft"]);
    for l in levels {
        for key in [
            "cpu_ms_per_trial",
            "cpu_s_per_participant",
            "speedup_vs_full",
            "max_abs_z",
        ] {
            assert!(f(l, key).is_finite(), "{key} in {l}");
        }
        assert!(
            f(l, "cpu_ms_per_trial") > 0.0 && f(l, "speedup_vs_full") > 0.0,
            "{l}"
        );
        // 2 participants × 3 conditions × (1 practice + 2 test) trials.
        assert_eq!(l["trials"], 18, "{l}");
        assert!(
            l.get("n_for_target").is_some(),
            "n_for_target missing in {l}"
        );
        assert!(l["power_error"].is_null(), "{l}");
        assert_eq!(l["power"].as_array().unwrap().len(), 2, "{l}");
        // Every condition × metric compared (success, time, force,
        // displacement error, contact fraction), z finite or 0.
        let d = l["differences"].as_array().unwrap();
        assert!(d.len() >= 12, "{} comparisons in {l}", d.len());
        let max = d.iter().map(|x| f(x, "z").abs()).fold(0.0, f64::max);
        assert!((max - f(l, "max_abs_z")).abs() < 1e-12, "{l}");
    }
    // Full is the reference: speed-up 1, no difference from itself.
    assert!((f(&levels[0], "speedup_vs_full") - 1.0).abs() < 1e-12);
    assert_eq!(f(&levels[0], "max_abs_z"), 0.0);
    // The studies, the plot and the JSON under --out.
    for level in ["full", "scene", "draft"] {
        assert!(out.join(level).join("trials.csv").is_file(), "{level}");
    }
    assert_non_blank_png(&out.join("frontier.png"));
    let svg = std::fs::read_to_string(out.join("frontier.svg")).unwrap();
    assert!(
        svg.contains("<svg") && svg.contains("scene"),
        "frontier.svg"
    );
    let saved: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("frontier.json")).unwrap()).unwrap();
    assert_eq!(saved["levels"], r["levels"]);

    // The table names every level; a second run into the same folder is
    // refused (nothing overwritten).
    let again = kilotouch(&[
        "bench",
        "fidelity",
        "--protocol",
        &proto,
        "--participants",
        "2",
        "--out",
        out_s,
    ]);
    assert!(!again.status.success());
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(err.contains("exists") && err.contains("--out"), "{err}");
}

/// `study power --simulate PARTICIPANTS` on `proto` for P − D of the
/// displacement error (seed 9), then `extra`.
fn power_simulate<'a>(participants: &'a str, proto: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "study",
        "power",
        "--simulate",
        participants,
        "--protocol",
        proto,
        "--dv",
        "disp_err_mean_um",
        "--contrast",
        "P-D",
        "--seed",
        "9",
    ];
    a.extend_from_slice(extra);
    a
}

#[test]
fn power_searches_at_draft_and_checks_at_scene() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = tiny(tmp.path());
    let keep = tmp.path().join("pilots");
    let keep_s = keep.to_str().unwrap();
    // An effect large enough that the search finds an n to check.
    let checked = ["--effect", "0.05", "--n", "3,6,12", "--replications", "100"];
    let mut json = power_simulate("3", &proto, &checked);
    json.extend(["--pilot-out", keep_s, "--json"]);
    let r = json_ok(&json);
    // The search's report keeps study power's keys.
    for key in ["points", "effect", "n_for_target", "pilot_effect", "test"] {
        assert!(r.get(key).is_some(), "`{key}` missing");
    }
    assert_eq!(r["simulated_pilot"]["fidelity"], "draft");
    assert_eq!(r["simulated_pilot"]["participants"], 3);
    let c = &r["final_check"];
    assert_eq!(c["pilot"]["fidelity"], "scene");
    assert_eq!(
        c["pilot"]["seed"], r["simulated_pilot"]["seed"],
        "the same cohort"
    );
    assert_eq!(c["n_checked"], r["n_for_target"]);
    assert_eq!(c["report"]["points"].as_array().unwrap().len(), 3);
    let n = c["n_checked"]
        .as_u64()
        .expect("an effect of 0.05 µm is found");
    let p = c["power_at_n"].as_f64().unwrap();
    let at = c["report"]["points"]
        .as_array()
        .unwrap()
        .iter()
        .find(|q| q["n"] == n)
        .unwrap();
    assert_eq!(at["power"].as_f64().unwrap(), p);
    assert_eq!(c["confirmed"].as_bool().unwrap(), p >= 0.8);
    for fidelity in ["draft", "scene"] {
        let kept = keep.join(format!("pilot-{fidelity}")).join("trials.csv");
        assert!(kept.is_file(), "{}", kept.display());
    }
    // The kept pilot folders are not overwritten.
    let mut again = power_simulate("3", &proto, &checked);
    again.extend(["--pilot-out", keep_s]);
    assert!(!kilotouch(&again).status.success());

    // The readable report shows both columns when it checks.
    let t = kilotouch(&power_simulate("3", &proto, &checked));
    assert!(t.status.success(), "{}", String::from_utf8_lossy(&t.stderr));
    let text = String::from_utf8_lossy(&t.stdout);
    for part in ["final check", "power at draft", "power at scene"] {
        assert!(text.contains(part), "{part}: {text}");
    }

    // At scene there is nothing to check; the pilot is removed without
    // --pilot-out.
    let scene = json_ok(&power_simulate(
        "3",
        &proto,
        &[
            "--n",
            "3,6",
            "--replications",
            "50",
            "--fidelity",
            "scene",
            "--json",
        ],
    ));
    assert!(scene.get("final_check").is_none());
    assert_eq!(scene["simulated_pilot"]["fidelity"], "scene");
    let pilot = scene["simulated_pilot"]["folder"].as_str().unwrap();
    assert!(!std::path::Path::new(pilot).exists(), "{pilot} left behind");

    // A pilot of one participant cannot show how participants vary.
    let one = kilotouch(&power_simulate(
        "1",
        &proto,
        &["--n", "3", "--replications", "10"],
    ));
    assert!(!one.status.success());
    assert!(String::from_utf8_lossy(&one.stderr).contains("--simulate must be 2"));
}
