//! The charts on scrolling pages (egui_kittest, the whole app at its
//! default window size): the mouse wheel over a Calibration plot scrolls
//! the page and leaves the plot's bounds alone; with the chart's "zoom /
//! pan" toggle on the same wheel pans the plot; "Reset view" restores the
//! automatic bounds.

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use egui_kittest::kittest::Queryable;
use egui_plot::PlotMemory;
use kilotouch::gui::Page;
use kilotouch::gui::charts::chart_plot_id;
use std::time::{Duration, Instant};

type H = egui_kittest::Harness<'static, kilotouch::gui::KilotouchApp>;

fn bounds(h: &H, id: &str) -> ([f64; 2], [f64; 2]) {
    let m = PlotMemory::load(&h.ctx, chart_plot_id(id)).expect("plot memory");
    let b = m.bounds();
    (b.min(), b.max())
}

fn wheel(h: &mut H, at: egui::Pos2, dy: f32) {
    h.hover_at(at);
    h.step();
    h.event(egui::Event::MouseWheel {
        unit: egui::MouseWheelUnit::Point,
        delta: egui::vec2(0.0, dy),
        phase: egui::TouchPhase::Move,
        source: egui::MouseWheelSource::Unknown,
        modifiers: egui::Modifiers::NONE,
    });
    // Smooth scrolling spreads the delta over a few frames.
    for _ in 0..30 {
        h.step();
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn the_wheel_scrolls_the_calibration_page_not_its_plots() {
    let app = common::fresh_app(Some(Page::Calibration));
    let mut h = common::app_harness(app, 1100.0, 700.0, None);
    h.step();
    h.get_by_label("Start calibration").click();
    let t0 = Instant::now();
    while h.query_by_label_contains("Verification PASS").is_none() {
        assert!(t0.elapsed() < Duration::from_secs(300), "no calibration");
        h.step();
        std::thread::sleep(Duration::from_millis(10));
    }
    for _ in 0..5 {
        h.step();
    }
    // The low channel's Bode plot: scroll the page until it is in view.
    for _ in 0..40 {
        let top = h
            .get_all_by_label("Reset view")
            .next()
            .unwrap()
            .rect()
            .top();
        if top < 300.0 {
            break;
        }
        wheel(&mut h, egui::pos2(550.0, 400.0), -150.0);
    }
    let reset = h.get_all_by_label("Reset view").next().unwrap().rect();
    assert!(reset.top() < 300.0, "the page does not scroll to the plots");
    let plot_at = reset.center() + egui::vec2(200.0, 90.0);
    let before = bounds(&h, "cal-low-mag");
    let top_before = reset.top();
    wheel(&mut h, plot_at, -120.0);
    let after = bounds(&h, "cal-low-mag");
    assert_eq!(before, after, "the wheel moved the plot");
    let top_after = h
        .get_all_by_label("Reset view")
        .next()
        .unwrap()
        .rect()
        .top();
    assert!(
        top_after < top_before - 20.0,
        "the page did not scroll: {top_before} → {top_after}"
    );

    // With the toggle on, the wheel pans the plot; Reset view restores it.
    h.get_all_by_label("zoom / pan").next().unwrap().click();
    h.step();
    let reset = h.get_all_by_label("Reset view").next().unwrap().rect();
    let plot_at = reset.center() + egui::vec2(200.0, 90.0);
    let free_before = bounds(&h, "cal-low-mag");
    wheel(&mut h, plot_at, -120.0);
    let panned = bounds(&h, "cal-low-mag");
    assert_ne!(free_before, panned, "the toggle did not free the plot");
    h.get_all_by_label("Reset view").next().unwrap().click();
    for _ in 0..3 {
        h.step();
    }
    let (lo, hi) = bounds(&h, "cal-low-mag");
    let (lo0, hi0) = before;
    for k in 0..2 {
        assert!(
            (lo[k] - lo0[k]).abs() < 1e-6 * (hi0[k] - lo0[k]).abs().max(1.0)
                && (hi[k] - hi0[k]).abs() < 1e-6 * (hi0[k] - lo0[k]).abs().max(1.0),
            "reset gave {lo:?}–{hi:?}, automatic {lo0:?}–{hi0:?}"
        );
    }
}
