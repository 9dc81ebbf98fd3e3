//! The Rig page on a live rig, through the UI (egui_kittest, no GPU): type a
//! serial rig into the rig field, connect to the device emulator on its pty,
//! see the live-rig note and the device's identity; kill the emulator and
//! see the error, the FAULT state and the Reconnect button; reconnect to a
//! restarted emulator without restarting the app.

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::{Emulator, step_until};
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use kilotouch::engine::SafetyState;
use kilotouch::gui::{KilotouchApp, Page};
use kilotouch_rig::device::RigKind;
use std::time::{Duration, Instant};

fn harness() -> Harness<'static, KilotouchApp> {
    common::app_harness(common::fresh_app(Some(Page::Rig)), 1200.0, 900.0, Some(16))
}

/// Replace the rig field's text.
fn type_rig(h: &mut Harness<'_, KilotouchApp>, text: &str) {
    let field = h.get_by_label("Rig:");
    field.focus();
    h.step();
    h.key_press_modifiers(egui::Modifiers::COMMAND, egui::Key::A);
    h.step();
    h.get_by_label("Rig:").type_text(text);
    h.step();
}

/// The live rig's spec for `path`: the tests' host stall timeout, and a
/// command lead of one block. With the lead measured (`auto`), a loaded
/// machine measures a late link and the margins check rightly refuses the
/// loop (seen: an extra 3.9–7.9 ms with two CPU-bound processes alongside).
fn live_spec(path: &str) -> String {
    format!("serial:{path},lead=1{}", common::TEST_HOST_TIMEOUT)
}

fn live_running(a: &KilotouchApp) -> bool {
    a.engine.as_ref().is_some_and(|e| {
        e.identity().kind == RigKind::SerialDaq
            && e.health()
                .is_some_and(|x| x.running && x.loop_rate_hz > 5000.0)
    })
}

#[test]
fn connect_fault_and_reconnect_a_serial_rig_from_the_rig_page() {
    let mut h = harness();
    assert!(step_until(&mut h, common::WAIT_S, |a| a
        .engine
        .as_ref()
        .is_some_and(|e| e.health().is_some())));
    assert_eq!(
        h.state().engine.as_ref().unwrap().identity().kind,
        RigKind::Simulated
    );
    // A malformed rig is refused in place (Connect disabled, message shown).
    type_rig(&mut h, "serial:");
    h.get_by_label_contains("missing port path");

    let mut emu = Emulator::start();
    type_rig(&mut h, &live_spec(&emu.path));
    h.get_by_label_contains("the hand is the real handle");
    h.get_by_label("Connect (restart)").click();
    assert!(
        step_until(&mut h, common::WAIT_S, live_running),
        "the serial rig did not come up: {:?} {:?} connecting {} notices {:?}",
        h.state().engine.as_ref().and_then(|e| e.health()),
        h.state().engine.as_ref().and_then(|e| e.last_error()),
        h.state().is_connecting(),
        h.state().notices().collect::<Vec<_>>()
    );
    assert!(step_until(&mut h, common::WAIT_S, |a| {
        common::engine_health(a).is_some_and(|x| x.safety == SafetyState::Enabled)
    }));
    h.get_by_label_contains(&format!("serial:{}", emu.path));
    h.get_by_label("Identity");
    // The closed loop's margins with the chain the engine runs.
    h.get_by_label("Closed-loop stability");
    h.get_by_label_contains("D chain: as designed (uncalibrated)");
    assert!(
        h.query_all_by_label("safe").count() >= 2,
        "P and D are safe"
    );
    // Explore says that the mouse does not move a live rig's trap.
    h.state_mut().page = Page::Explore;
    h.step();
    h.step();
    h.get_by_label_contains("the trap follows the real handle");
    h.state_mut().page = Page::Rig;
    h.step();

    // The device vanishes: error on the page, FAULT in the status bar, the
    // app keeps running, Reconnect offered.
    emu.kill();
    assert!(step_until(&mut h, common::WAIT_S, |a| {
        common::engine_health(a).is_some_and(|x| x.safety == SafetyState::Fault && !x.running)
    }));
    h.step();
    h.get_by_label_contains("Rig error:");
    h.get_by_label("FAULT");
    assert!(h.state().engine.as_ref().unwrap().is_alive());

    // A restarted emulator (new pty): type its port, Reconnect.
    let emu2 = Emulator::start();
    type_rig(&mut h, &live_spec(&emu2.path));
    h.get_by_label("Reconnect").click();
    assert!(
        step_until(&mut h, common::WAIT_S, |a| live_running(a)
            && a.engine.as_ref().unwrap().last_error().is_none()),
        "no reconnect"
    );
    h.step();
    assert!(h.query_by_label_contains("Rig error:").is_none());
}

#[test]
fn a_silent_device_does_not_freeze_the_gui_while_connecting() {
    let mut h = harness();
    assert!(step_until(&mut h, common::WAIT_S, |a| a.engine.is_some()));
    // An emulator that hangs from the start: the handshake gets no answer.
    let emu = Emulator::spawn("daq", &["--stall-after-s", "0"]);
    type_rig(&mut h, &format!("serial:{}", emu.path));
    let t0 = Instant::now();
    h.get_by_label("Connect (restart)").click();
    h.step();
    h.step();
    // The frames keep coming while the device is silent.
    assert!(
        t0.elapsed() < Duration::from_millis(500),
        "the click blocked the GUI for {:?}",
        t0.elapsed()
    );
    assert!(h.state().is_connecting() && h.state().engine.is_none());
    h.get_by_label_contains(&format!("connecting to serial:{}", emu.path));
    // The handshake times out on the worker thread; the error reaches the page.
    assert!(
        step_until(&mut h, common::WAIT_S, |a| !a.is_connecting()),
        "the connect never ended"
    );
    h.step();
    assert!(h.state().engine.is_none());
    h.get_by_label_contains("cannot start the engine");
    // And the simulated rig comes back at once.
    type_rig(&mut h, "sim");
    h.get_by_label("Connect").click();
    h.step();
    assert!(h.state().engine.is_some() && !h.state().is_connecting());
}
