//! Scene fidelity against the full model on a small study: for each
//! condition, the mean success rate, time, optical force, displacement
//! error and contact fraction of the test trials agree within 2.5 pooled
//! standard errors (the sampling error of the two means), and `--fidelity
//! full` is what a station without a fidelity setting runs.

#![allow(clippy::unwrap_used)]

use kilotouch_rig::config::RigConfig;
use kilotouch_study::export::{TRIALS_FILE, TrialRow, read_session, read_trials};
use kilotouch_study::fidelity::Fidelity;
use kilotouch_study::protocol::{Condition, Protocol};
use kilotouch_study::runner::RunnerConfig;
use kilotouch_study::seeds::Phase;
use kilotouch_study::simulate::{SimulateOptions, simulate};
use kilotouch_study::stats::agreement::{Compared, agreement};

fn run(fidelity: Fidelity, dir: &std::path::Path) -> Vec<TrialRow> {
    let mut protocol = Protocol::paper().unwrap();
    protocol.participants = 2;
    protocol.seeds.study = 33;
    let opts = SimulateOptions {
        runner: RunnerConfig {
            raw: None,
            ..RunnerConfig::default()
        },
        threads: 2,
        fidelity,
        ..SimulateOptions::new(protocol, dir)
    };
    simulate(&opts, &mut |_, _| {}).unwrap();
    let session = read_session(&dir.join("session.json")).unwrap();
    assert_eq!(session.simulation.map(|s| s.fidelity), Some(fidelity));
    read_trials(&dir.join(TRIALS_FILE))
        .unwrap()
        .rows
        .into_iter()
        .filter(|r| r.phase == Phase::Test)
        .collect()
}

/// `fidelity` against the full model on the same small study: every
/// condition × metric within `k` pooled standard errors (differences
/// printed).
fn agrees_with_full(fidelity: Fidelity, k: f64) {
    let tmp = tempfile::tempdir().unwrap();
    let full = run(Fidelity::Full, &tmp.path().join("full"));
    let other = run(fidelity, &tmp.path().join(fidelity.name()));
    assert_eq!(full.len(), other.len());
    let table = agreement(&full, &other, &Compared::CIRCLING, k);
    assert_eq!(table.len(), 15, "every condition × metric compared");
    for a in &table {
        eprintln!(
            "{fidelity} {} {}: full {} {fidelity} {} z {:.2}",
            a.condition, a.metric, a.mean_a, a.mean_b, a.z
        );
        assert!(a.n_a >= 10 && a.n_b >= 10, "too few trials: {a:?}");
    }
    for a in &table {
        assert!(
            a.agrees,
            "{fidelity} {} {}: full {} {fidelity} {}, pooled SE {}",
            a.condition, a.metric, a.mean_a, a.mean_b, a.pooled_se
        );
    }
}

#[test]
fn scene_and_full_studies_agree_within_sampling_error() {
    agrees_with_full(Fidelity::Scene, 2.5);
}

/// Which trials the scene runs at the control rate: V without a raw file;
/// never P or D, never with a raw file, never at full fidelity. The trial's
/// timing keeps its durations (the time-out and the trajectory's spacing).
#[test]
fn v_runs_at_the_control_rate_only_without_a_raw_file() {
    use kilotouch_study::operator::SimCohort;
    use kilotouch_study::rawsig::Dtype;
    use kilotouch_study::runner::{NoRaw, TrialEngine};
    use kilotouch_study::seeds::TrialKey;
    use kilotouch_study::task::sim_station::SimStation;

    let p = Protocol::paper().unwrap();
    let mut rates = Vec::new();
    for (fidelity, raw) in [
        (Fidelity::Scene, None),
        (Fidelity::Scene, Some(Dtype::F32)),
        (Fidelity::Full, None),
    ] {
        let mut station = SimStation::new(&RigConfig::default()).unwrap();
        station.set_fidelity(fidelity);
        let cfg = RunnerConfig {
            raw,
            ..RunnerConfig::default()
        };
        let mut e = TrialEngine::new(station, cfg).unwrap();
        for c in Condition::ALL {
            let key = TrialKey::new(0, c, Phase::Test, 1);
            let setup = e.setup(&p, key);
            let mut who = SimCohort::new(p.seeds.study, 1000.0, 10_000.0);
            let o = e.run_trial(&setup, &mut who, &mut NoRaw).unwrap();
            let t = o.samples as f64 / o.sample_rate_hz;
            assert!(
                t > 0.5 && t <= setup.params.timeout_s() + 1e-3,
                "{c}: {t} s"
            );
            // One trajectory point per 10 ms whatever the rate (start,
            // the decimated points and the end).
            let points = o.trajectory.len() as f64;
            assert!(
                (points - t / 0.01).abs() <= 3.0,
                "{c}: {points} points in {t} s"
            );
            rates.push((fidelity, raw.is_some(), c, o.sample_rate_hz));
        }
    }
    for (fidelity, raw, c, fs) in rates {
        let expected = if fidelity == Fidelity::Scene && !raw && c == Condition::V {
            1000.0
        } else {
            10_000.0
        };
        assert_eq!(fs, expected, "{fidelity} raw {raw} {c}");
    }
}

/// Draft against the full model on the same small study, within 3 pooled
/// standard errors.
#[test]
fn draft_and_full_studies_agree_within_three_pooled_se() {
    agrees_with_full(Fidelity::Draft, 3.0);
}

/// A draft loop whose margins at its lower rate are below the minimum is
/// refused with the numbers (a stiffer trap raises the loop gain), and the
/// shipped rig's draft loop clears.
#[test]
fn an_unsafe_draft_loop_is_refused_with_its_margins() {
    use kilotouch_rig::coupling::LoopChain;
    use kilotouch_study::fidelity::DRAFT_LOOP_DIVISOR;
    use kilotouch_study::runner::RunError;
    use kilotouch_study::task::sim_station::draft_loop;

    let base = RigConfig::default();
    let d = DRAFT_LOOP_DIVISOR;
    assert!(draft_loop(&base, &LoopChain::as_designed(&base).unwrap(), d).is_ok());
    let mut cfg = base.clone();
    cfg.tweezer.stiffness_n_per_m *= 2.0;
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let err = draft_loop(&cfg, &chain, d).map(|_| ()).unwrap_err();
    let text = err.to_string();
    eprintln!("{text}");
    match err {
        RunError::DraftLoopNotSafe {
            rate_hz, divisor, ..
        } => {
            assert_eq!(divisor, d);
            assert_eq!(rate_hz, base.rig.sample_rate_hz / f64::from(d));
        }
        other => panic!("expected a draft refusal, got {other}"),
    }
    assert!(
        text.contains("margin") && text.contains("minimum") && text.contains("Hz"),
        "{text}"
    );
}
