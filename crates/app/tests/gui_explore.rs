//! The Explore page's plots read as a user reads them (egui_kittest, the
//! whole app, the real engine): in V, P and D and at several window sizes
//! every live plot labels its axis with a unit and at least two distinct
//! numbers (egui_plot paints tick labels as text, so the page records what
//! its axes drew: `ExplorePage::readouts`), and the agitation's SD now and
//! free is shown beside the histogram.
#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::{app_harness, engine_reporting, fresh_app, step_until};
use egui_kittest::kittest::Queryable;
use kilotouch::engine::Condition;
use kilotouch::gui::Page;
use kilotouch::gui::plot::{AxisReadout, format_si};

/// At least two distinct, non-empty numeric tick labels, and the unit (with
/// its SI prefix) in the axis label.
fn readable(what: &str, a: &AxisReadout, unit: &str) {
    assert!(
        a.label.ends_with(unit) || a.label.ends_with(&format!("{unit})")),
        "{what}: axis label `{}` has no unit {unit}",
        a.label
    );
    let mut numbers: Vec<&String> = a
        .ticks
        .iter()
        .filter(|t| t.trim().parse::<f64>().is_ok())
        .collect();
    numbers.dedup();
    assert!(
        numbers.len() >= 2,
        "{what}: ticks {:?} under `{}`",
        a.ticks,
        a.label
    );
}

#[test]
fn explore_plots_have_scales_with_units_in_every_condition_and_size() {
    for (w, hgt) in [(900.0, 600.0), (1100.0, 760.0), (1600.0, 1000.0)] {
        let mut h = app_harness(fresh_app(Some(Page::Explore)), w, hgt, Some(16));
        assert!(
            step_until(&mut h, common::WAIT_S, engine_reporting),
            "engine up"
        );
        for c in Condition::ALL {
            h.state_mut().engine.as_mut().unwrap().set_condition(c);
            // A second and a half of telemetry: the histogram's second and
            // the free agitation fill.
            let t0 = std::time::Instant::now();
            let filled = step_until(&mut h, common::WAIT_S, |a| {
                let r = a.explore.readouts();
                t0.elapsed().as_secs_f64() > 1.5
                    && r.sd_free_m_s2.is_some()
                    && r.sd_now_m_s2.is_some()
            });
            assert!(filled, "{c:?} at {w}×{hgt}: no SD after 20 s");
            let r = h.state().explore.readouts().clone();
            let at = format!("{} at {w}×{hgt}", c.code());
            readable(&format!("force, {at}"), &r.force, "N");
            readable(&format!("acceleration, {at}"), &r.accel, "m/s²");
            readable(&format!("histogram, {at}"), &r.histogram, "m/s²");
            let (now, free) = (r.sd_now_m_s2.unwrap(), r.sd_free_m_s2.unwrap());
            assert!(now > 0.0 && free > 0.0, "{at}: SD {now} / {free}");
            // The numbers are on the page, with their unit (the readouts
            // and the accessibility tree are of the same frame).
            h.get_by_label_contains(&format!(
                "SD now {} · free {}",
                format_si(now, "m/s²"),
                format_si(free, "m/s²")
            ));
        }
    }
}

#[test]
fn the_free_agitation_is_the_simulated_sensors_and_loops() {
    // In V nothing is rendered: the tip acceleration is the accelerometer's
    // own noise, density ρ = 350 µg/√Hz through its discrete one-pole
    // low-pass at 400 Hz (kilotouch_rig::accel: white noise of variance
    // ρ²·f_s/2 into s[n] = α s[n−1] + (1 − α) w[n], α = e^{−2π·400/f_s}),
    // σ = ρ·√(f_s/2 · (1 − α)/(1 + α)) = 85.8 mm/s² (the 14.5 mm/s²
    // quantisation adds 4 mm/s² in quadrature: 0.1 %). The SD now and free
    // reads within 15 % of it.
    let mut h = app_harness(fresh_app(Some(Page::Explore)), 1100.0, 760.0, Some(16));
    assert!(step_until(&mut h, common::WAIT_S, engine_reporting));
    h.state_mut()
        .engine
        .as_mut()
        .unwrap()
        .set_condition(Condition::V);
    let t0 = std::time::Instant::now();
    assert!(step_until(&mut h, common::WAIT_S, |a| {
        t0.elapsed().as_secs_f64() > 1.5 && a.explore.readouts().sd_free_m_s2.is_some()
    }));
    let r = h.state().explore.readouts().clone();
    let fs = 10_000.0;
    let alpha = (-2.0 * std::f64::consts::PI * 400.0 / fs).exp();
    let expected = 350e-6 * 9.80665 * (fs / 2.0 * (1.0 - alpha) / (1.0 + alpha)).sqrt();
    for (what, v) in [("now", r.sd_now_m_s2), ("free", r.sd_free_m_s2)] {
        let v = v.unwrap();
        assert!(
            (v / expected - 1.0).abs() < 0.15,
            "SD {what} {v} m/s² vs the sensor noise {expected}"
        );
    }
}
