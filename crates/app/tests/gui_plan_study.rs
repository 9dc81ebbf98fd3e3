//! The Results page's **Plan the next study** panel driven through
//! egui_kittest (CPU only): a pilot folder written with the study crate's
//! `StudyStore` from a known model (6 participants × V, P, D × 4 test
//! trials, displacement error with a P − D difference of 0.04 µm), the
//! panel opened, the participant counts typed, the simulation run; the
//! curve, its table and `n_for_target` must appear and equal what
//! `kilotouch_study::power` gives for the same options (results do not
//! depend on the thread count).

use kilotouch_testkit as common;

use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use kilotouch::gui::pages::results::ResultsPage;
use kilotouch_study::export::{StudyMeta, StudyStore, UtcTime};
use kilotouch_study::power::{EffectSpec, PowerOptions, PowerTest, power_from_path};
use kilotouch_study::protocol::{Condition, Protocol};
use kilotouch_study::seeds::Phase;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const N: usize = 6;
const TRIALS: u32 = 4;

/// Known displacement error of a test trial, µm: participant offset, a
/// condition effect (V 0.30, P 0.12, D 0.08) and a deterministic
/// within-cell spread.
fn disp_um(p: usize, c: Condition, t: u32) -> f64 {
    let cond = match c {
        Condition::V => 0.30,
        Condition::P => 0.12,
        Condition::D => 0.08,
    };
    let within = 0.01 * (((p * 7 + t as usize * 3 + cond_index(c) * 5) % 5) as f64 - 2.0);
    let pc = 0.006 * (((p * 3 + cond_index(c)) % 3) as f64 - 1.0);
    cond + 0.02 * p as f64 + within + pc
}

fn cond_index(c: Condition) -> usize {
    match c {
        Condition::V => 0,
        Condition::P => 1,
        Condition::D => 2,
    }
}

fn write_pilot(dir: &Path) {
    let text = format!(
        "name = \"gui-plan-test\"\nparticipants = {N}\nconditions = [\"V\", \"P\", \"D\"]\n\
         trials_per_session = {TRIALS}\n[training]\npractice_trials = 1\n\
         [task.circling]\n[seeds]\nstudy = 11\n"
    );
    let protocol = Protocol::from_toml_str(&text, "<test>").expect("test setup");
    let mut store =
        StudyStore::open(dir, &protocol, &StudyMeta::new("sim-test")).expect("test setup");
    while let Some(planned) = store.next_pending().cloned() {
        let key = planned.key;
        let ticket = store
            .begin_trial(key, UtcTime::from_unix_millis(1_767_225_600_000))
            .expect("test setup");
        let mut row = ticket.row();
        row.escaped = Some(false);
        row.success = true;
        row.time_s = Some(20.0);
        row.disp_err_mean_um = Some(if key.phase == Phase::Practice {
            50.0
        } else {
            disp_um(key.participant as usize, key.condition, key.trial)
        });
        store.commit_trial(ticket, &row).expect("test setup");
    }
    store.close().expect("test setup");
}

type State = common::PageState<ResultsPage>;

fn harness() -> Harness<'static, State> {
    common::page_harness(State::new(ResultsPage::new()), 6000.0)
}

#[test]
fn plan_panel_runs_the_power_simulation_and_shows_the_curve_and_n_for_target() {
    let tmp = tempfile::tempdir().unwrap();
    let dir: PathBuf = tmp.path().join("pilot");
    write_pilot(&dir);

    let mut h = harness();
    h.step();
    h.state_mut().page.set_folder(&dir);
    h.step();
    h.get_by_label("Open").click();
    h.step();
    h.step();
    assert_eq!(h.state().page.error(), None);

    // Open the panel, ask for n = 3, 4, 6 (few, small studies: quick in debug).
    h.get_by_label("Plan the next study").click();
    h.step();
    h.step();
    let field = h.get_by_label("Participants (n)");
    field.focus();
    h.step();
    h.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::A);
    h.step();
    h.get_by_label("Participants (n)").type_text("3,4,6");
    h.step();
    h.get_by_label("Simulate power").click();
    h.step();

    // Wait for the background simulation (progress bar, then the result).
    let t0 = Instant::now();
    while h.query_by_label_contains("n for power").is_none()
        && h.query_by_label_contains("is not reached").is_none()
    {
        assert!(
            h.query_by_label_contains("Error").is_none(),
            "the panel reports an error"
        );
        assert!(
            t0.elapsed() < Duration::from_secs(600),
            "no power result after 10 min"
        );
        std::thread::sleep(Duration::from_millis(50));
        h.step();
    }
    h.step();

    // The library on the same folder and options (the panel's defaults:
    // disp_err_mean_um, paired t of P − D, the pilot's effect, α 0.05,
    // target 0.8, 1000 replications, seed 1).
    let mut o = PowerOptions::new(
        "disp_err_mean_um",
        PowerTest::Contrast {
            a: "P".into(),
            b: "D".into(),
        },
        vec![3, 4, 6],
    );
    o.effect = EffectSpec::Pilot;
    o.alpha = 0.05;
    o.target = 0.8;
    o.replications = 1000;
    o.seed = 1;
    o.threads = 1;
    let r = power_from_path(&dir, &o, &|_, _| true).unwrap();
    assert_eq!(r.points.len(), 3);
    // The pilot's own P − D effect is the model's 0.04 µm (cell means).
    assert!((r.effect - 0.04).abs() < 0.01, "pilot effect {}", r.effect);
    // Power grows with n; with this effect and spread the target is met.
    assert!(r.points.windows(2).all(|w| w[1].power >= w[0].power));
    let n = r.n_for_target.expect("target reached");
    h.get_by_label(&format!("n for power ≥ 0.8: {n} participants"));
    // The table shows the same power and interval at every n.
    for p in &r.points {
        for text in [
            format!("{:.3}", p.power),
            format!("[{:.3}, {:.3}]", p.ci[0], p.ci[1]),
        ] {
            assert!(
                h.query_all_by_label(&text).next().is_some(),
                "n = {}: {text} not shown",
                p.n
            );
        }
    }
    // The curve is drawn.
    h.get_by_label_contains("power (95 % CI)");
}
