//! The Rig page's Tweezer section through the UI (egui_kittest, no GPU):
//! record the simulated tweezer's detector, calibrate both axes, read the κ
//! shown against the simulated trap's, apply it and see it active — in the
//! page, in the engine's tweezer and on the Study page, which records it in
//! `session.json`; remove it again. A fit the page must refuse (a model
//! that does not describe the spectrum) keeps Apply disabled and says why.

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::{engine_reporting, step_until};
use egui_kittest::kittest::{NodeT, Queryable};
use kilotouch::gui::{KilotouchApp, Page};
use kilotouch_rig::units::{to_pn_per_um, to_um_per_v};

fn shown_kappa(h: &egui_kittest::Harness<'_, KilotouchApp>) -> f64 {
    // "κ to apply: 20.123 ± 0.234 pN/µm (both axes, weighted)"
    let node = h.get_by_label_contains("κ to apply:");
    let text = node.accesskit_node().value().unwrap();
    let v = text.split("κ to apply:").nth(1).unwrap().trim();
    v.split_whitespace().next().unwrap().parse().unwrap()
}

#[test]
fn record_calibrate_and_apply_the_simulated_trap_from_the_rig_page() {
    let mut h = common::app_harness(common::fresh_app(Some(Page::Rig)), 1400.0, 2200.0, Some(16));
    assert!(step_until(&mut h, common::WAIT_S, engine_reporting));
    let truth = to_pn_per_um(h.state().rig_config.tweezer.stiffness_n_per_m);
    h.get_by_label("Tweezer: trap calibration");
    h.get_by_label_contains("Active trap calibration: none");
    h.get_by_label("Record and calibrate").click();
    // Background work: the page keeps drawing and shows its progress.
    h.step();
    assert!(step_until(&mut h, common::WAIT_S, |a| a
        .rig_page()
        .tweezer
        .result()
        .is_some()
        || a.rig_page().tweezer.error().is_some()));
    h.step();
    assert_eq!(h.state().rig_page().tweezer.error(), None);
    let r = h.state().rig_page().tweezer.result().unwrap().clone();
    assert_eq!(r.n_samples, 100_000);
    let kappa = shown_kappa(&h);
    assert!(
        (kappa - to_pn_per_um(r.kappa_n_per_m)).abs() < 1e-3,
        "{kappa} vs {r:?}"
    );
    assert!(
        (kappa / truth - 1.0).abs() < 0.04,
        "κ shown {kappa} pN/µm vs the simulated trap's {truth}"
    );
    assert!(
        (kappa - truth).abs() < 3.5 * to_pn_per_um(r.kappa_se_n_per_m),
        "{r:?}"
    );
    // R_d of the simulated detector: 1/S = 2 µm/V.
    for rd in r.rd_m_per_v.map(to_um_per_v) {
        assert!((rd / 2.0 - 1.0).abs() < 0.03, "R_d {rd}");
    }
    h.get_by_label("fit accepted");
    h.get_by_label_contains("simulated trap: κ =");

    h.get_by_label("Apply").click();
    assert!(step_until(&mut h, common::WAIT_S, |a| a
        .trap_calibration()
        .is_some()));
    assert_eq!(h.state().trap_calibration(), Some(&r));
    h.step();
    h.get_by_label_contains("Active trap calibration: κ =");
    // The engine's tweezer reports through it.
    assert!(step_until(&mut h, common::WAIT_S, |a| {
        common::engine_health(a).is_some_and(|x| x.trap_calibration == Some(r.applied()))
    }));
    // The Study page says what its session.json will record.
    h.state_mut().page = Page::Study;
    h.step();
    h.get_by_label_contains(&format!(
        "trap calibration recorded: κ = {:.3}",
        to_pn_per_um(r.kappa_n_per_m)
    ));

    // Removed again: the tweezer reports the simulated bead and κ.
    h.state_mut().page = Page::Rig;
    h.step();
    h.get_by_label("Remove").click();
    assert!(step_until(&mut h, common::WAIT_S, |a| a
        .trap_calibration()
        .is_none()));
    assert!(step_until(&mut h, common::WAIT_S, |a| {
        common::engine_health(a).is_some_and(|x| x.trap_calibration.is_none())
    }));

    // A plain Lorentzian on the point-sampled record misfits near Nyquist:
    // refused with the reason, Apply disabled.
    h.state_mut().rig_page_mut().tweezer.aliased = false;
    common::record_and_calibrate(&mut h);
    h.get_by_label_contains("not applicable:");
    assert!(h.get_by_label("Apply").accesskit_node().is_disabled());
}
