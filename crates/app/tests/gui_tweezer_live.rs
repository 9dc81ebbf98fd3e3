//! The Rig page's Tweezer section with a live tweezer (its emulator,
//! `kilotouch emulate tweezer --pty`), through the UI (egui_kittest, no
//! GPU): record and calibrate the tweezer through its link; Apply is
//! refused while the engine's loop drives the rig file's simulated tweezer
//! (the record is of another tweezer), recording is refused while the
//! engine holds the tweezer's port, and once the Rig page connects the
//! engine to the live tweezer the calibration applies: the engine's
//! tweezer reports through it (the force it then computes is tested
//! against the emulator in `engine_live_tweezer.rs`).

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::{Emulator, engine_reporting, step_until};
use egui_kittest::kittest::Queryable;
use kilotouch::gui::{KilotouchApp, Page};
use kilotouch_rig::tweezer::surface_drag;
use kilotouch_rig::units::to_pn_per_um;
use kilotouch_rig::{RigConfig, TweezerParams};

fn live_tweezer_running(a: &KilotouchApp, path: &str) -> bool {
    a.engine.as_ref().is_some_and(|e| {
        e.live_tweezer()
            .is_some_and(|l| l.spec.describe().ends_with(path))
            && e.health().is_some_and(|x| x.running)
    })
}

#[test]
fn calibrate_the_live_tweezer_and_apply_it_to_the_engine_that_drives_it() {
    let emu = Emulator::spawn("tweezer", &[]);
    let mut h = common::app_harness(common::fresh_app(Some(Page::Rig)), 1400.0, 2200.0, Some(16));
    assert!(step_until(&mut h, common::WAIT_S, engine_reporting));
    {
        let t = &mut h.state_mut().rig_page_mut().tweezer;
        t.source_text = emu.rig();
        t.duration_s = 2.0;
    }
    h.step();
    common::record_and_calibrate(&mut h);
    assert_eq!(h.state().rig_page().tweezer.error(), None);
    let r = h.state().rig_page().tweezer.result().unwrap().clone();
    assert_eq!(r.source, emu.rig());
    assert_eq!(r.n_samples, 20_000);
    // κ of the emulated trap (the rig file's) per axis, as the drag of the
    // scene's nearest obstacle biases it at the trap's spot (0, 0): 5.5 µm
    // from the obstacle at (12, 0) µm (`tweezer::spot`; −24 % in x, −12 %
    // in y): a live tweezer has no "free solution" the host could choose.
    let rc = RigConfig::default();
    let truth = rc.tweezer.stiffness_n_per_m;
    let bias = surface_drag(&TweezerParams::from_config(&rc.tweezer), [0.0; 2]).kappa_bias();
    for (axis, c) in [&r.x, &r.y].into_iter().enumerate() {
        let want = truth * (1.0 + bias[axis]);
        assert!(
            (c.kappa_n_per_m - want).abs() < 4.0 * c.kappa_se_n_per_m + 0.05 * want,
            "axis {axis}: κ {} ± {} pN/µm against {} (the trap's {}, drag bias {:+.3})",
            to_pn_per_um(c.kappa_n_per_m),
            to_pn_per_um(c.kappa_se_n_per_m),
            to_pn_per_um(want),
            to_pn_per_um(truth),
            bias[axis]
        );
    }
    h.get_by_label("fit accepted");

    // The engine drives the simulated tweezer: another tweezer, refused.
    h.get_by_label("Apply").click();
    h.step();
    h.step();
    h.get_by_label_contains(&format!(
        "trap calibration not applied: it was recorded from {}, and the engine's loop drives \
         the rig file's simulated tweezer",
        emu.rig()
    ));
    assert!(h.state().trap_calibration().is_none());

    // The Rig page connects the engine to the live tweezer
    // (block-synchronous: no lead, so the loop delay stays inside D's
    // margins on the simulated rig).
    h.state_mut().rig_page_mut().tweezer_text = format!("{},lead=0", emu.rig());
    h.step();
    h.get_by_label("Connect (restart)").click();
    assert!(
        step_until(&mut h, common::WAIT_S, |a| live_tweezer_running(
            a, &emu.path
        )),
        "the live tweezer did not come up"
    );
    h.step();

    // Recording from the port the engine holds is refused, saying why.
    h.get_by_label("Record and calibrate").click();
    h.step();
    assert!(
        h.state()
            .rig_page()
            .tweezer
            .error()
            .is_some_and(|e| e.contains("the engine's loop runs the tweezer on")),
        "{:?}",
        h.state().rig_page().tweezer.error()
    );
    // The calibration of this tweezer now applies.
    h.get_by_label("Apply").click();
    assert!(step_until(&mut h, common::WAIT_S, |a| a
        .trap_calibration()
        .is_some()));
    assert!(step_until(&mut h, common::WAIT_S, |a| {
        common::engine_health(a)
            .is_some_and(|x| x.running && x.trap_calibration == Some(r.applied()))
    }));
    h.step();
    h.get_by_label_contains("Active trap calibration: κ =");
}
