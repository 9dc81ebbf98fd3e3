//! UI tests with egui_kittest, driving the app on the simulated rig (the real
//! engine on its own thread). CPU only: nothing here renders, so no GPU
//! adapter is needed (the scene uses the egui-painter fallback without a
//! wgpu render state, which these tests also check).

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::{engine_reporting, step_until};
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use kilotouch::engine::{SafetyState, flags};
use kilotouch::gui::{KilotouchApp, Page};
use std::time::{Duration, Instant};

fn app() -> KilotouchApp {
    common::fresh_app(None)
}

fn harness(app: KilotouchApp) -> Harness<'static, KilotouchApp> {
    common::app_harness(app, 1100.0, 700.0, Some(16))
}

#[test]
fn every_page_opens() {
    let mut h = harness(app());
    let marks = [
        (Page::Rig, "Identity"),
        (Page::Calibration, "Calibration"),
        (Page::Explore, "Condition"),
        (Page::Study, "Study"),
        (Page::Results, "Results"),
    ];
    assert!(step_until(&mut h, common::WAIT_S, engine_reporting));
    for (page, mark) in marks {
        h.get_by_label(page.title()).click();
        h.step();
        h.step();
        assert_eq!(h.state().page, page);
        assert!(
            h.query_all_by_label_contains(mark).next().is_some(),
            "page {page:?} lacks `{mark}`"
        );
    }
    // The scene runs on the painter fallback here (no wgpu render state).
    assert!(!h.state().explore.gpu);
    assert!(h.query_by_label_contains("egui painter").is_some());
}

fn outputs_zeroed_after_stop(h: &mut Harness<'_, KilotouchApp>) {
    assert!(
        step_until(h, common::WAIT_S, |a| common::engine_health(a)
            .is_some_and(|x| x.safety == SafetyState::EStop)),
        "engine did not report the emergency stop"
    );
    // Every sample the GUI receives from now on has all outputs at zero.
    let mut seen = 0;
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(300) {
        h.step();
        let a = h.state();
        if let Some(s) = a.explore.last {
            assert_eq!(
                s.output,
                Default::default(),
                "output not zero: {:?}",
                s.output
            );
            assert!(s.has(flags::ESTOP));
            seen += 1;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(seen > 5);
    assert!(h.state().estop_latched());
    assert!(h.query_by_label_contains("OUTPUTS HELD AT ZERO").is_some());
}

fn armed(h: &mut Harness<'_, KilotouchApp>) {
    assert!(
        step_until(h, common::WAIT_S, |a| common::engine_health(a)
            .is_some_and(|x| x.safety == SafetyState::Enabled)
            && a.explore.last.is_some_and(|s| s.output.force_n[0] != 0.0)),
        "engine never armed"
    );
}

#[test]
fn emergency_stop_button_zeroes_outputs_and_reset_needs_two_steps() {
    let mut h = harness(app());
    armed(&mut h);
    h.get_by_label_contains("EMERGENCY STOP").click();
    outputs_zeroed_after_stop(&mut h);
    // Reset: the dialog's button is disabled until the box is ticked.
    h.get_by_label("Reset emergency stop…").click();
    h.step();
    h.step();
    h.get_by_label("Re-enable outputs (ramped)").click();
    step_until(&mut h, 0.3, |_| false);
    assert!(
        h.state().estop_latched(),
        "released without the confirmation"
    );
    h.get_by_label("I have checked that the rig is safe")
        .click();
    h.step();
    h.get_by_label("Re-enable outputs (ramped)").click();
    h.step();
    armed(&mut h);
}

#[test]
fn escape_key_is_the_emergency_stop_shortcut() {
    let mut h = harness(app());
    armed(&mut h);
    h.key_press(egui::Key::Escape);
    h.step();
    outputs_zeroed_after_stop(&mut h);
}

#[test]
fn dragging_in_the_scene_moves_the_trap() {
    let mut a = app();
    a.page = Page::Explore;
    let mut h = harness(a);
    // Wait for the camera's first frame so that the scene is laid out.
    assert!(step_until(&mut h, common::WAIT_S, |a| a
        .explore
        .view
        .is_some()
        && a.explore.camera.visible().is_some()));
    let start = h.state().explore.last.unwrap().trap_m;
    // Drag from the centre to a point 6 µm right, 4 µm up. Screen positions
    // are recomputed from the scene's current view at every frame: under
    // load the layout can still change while the drag is in progress.
    let target = [6e-6, 4e-6];
    let at = |h: &Harness<'_, KilotouchApp>, frac: f32| {
        let view = h.state().explore.view.unwrap();
        let p0 = view.to_screen([0.0, 0.0]);
        let p1 = view.to_screen(target);
        p0 + (p1 - p0) * frac
    };
    let p0 = at(&h, 0.0);
    h.hover_at(p0);
    h.step();
    h.drag_at(p0);
    h.step();
    for k in 1..=10 {
        let p = at(&h, k as f32 / 10.0);
        h.hover_at(p);
        h.step();
    }
    // Hold the button down at the target while the rig moves.
    let t0 = Instant::now();
    let mut ok = false;
    while t0.elapsed().as_secs_f64() < 10.0 {
        let p = at(&h, 1.0);
        h.hover_at(p);
        h.step();
        if h.state().explore.last.is_some_and(|s| {
            ((s.trap_m[0] - target[0]).powi(2) + (s.trap_m[1] - target[1]).powi(2)).sqrt() < 0.5e-6
        }) {
            ok = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let p1 = at(&h, 1.0);
    h.drop_at(p1);
    h.step();
    let end = h.state().explore.last.unwrap().trap_m;
    assert!(ok, "trap went from {start:?} to {end:?}, target {target:?}");
}

fn kilotouch(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_kilotouch"))
        .args(args)
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .expect("run kilotouch")
}

#[test]
fn gui_arguments_are_checked_before_any_window_opens() {
    // --screenshot needs --quit-after: a usage error (2).
    let o = kilotouch(&["gui", "--screenshot", "x.png"]);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    // Bad numbers: clear errors, exit 1, no panic.
    for args in [
        &["gui", "--quit-after", "nan"][..],
        &["gui", "--quit-after", "inf"][..],
        &["gui", "--size", "5x5"][..],
        &["gui", "--size", "wide"][..],
    ] {
        let o = kilotouch(args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains("kilotouch: error:") && !err.contains("panicked"),
            "{err}"
        );
    }
    let o = kilotouch(&["gui", "--page", "nowhere"]);
    assert_eq!(o.status.code(), Some(2));
    // Without a display the app fails with a clear message instead of hanging.
    let o = kilotouch(&["gui", "--quit-after", "1"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("cannot open the GUI"), "{err}");
}
