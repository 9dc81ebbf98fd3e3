//! The tweezer link over a real pseudo-terminal, against the tweezer
//! emulator served in a thread of the test: bead for bead the simulated
//! tweezer (block-synchronous and with a command lead), the scene and its
//! geometry, link failures reported as link failures and real escapes as
//! escapes.

#![allow(clippy::unwrap_used)]

use crate::common;

use common::Device;
use kilotouch_rig::config::{ObstacleConfig, RigConfig};
use kilotouch_rig::device::LinkErrorKind;
use kilotouch_rig::serial::emulator::{EmulatorConfig, FaultInjection, Instrument};
use kilotouch_rig::serial::frame::{self, Hello, Scene, TrapCommand, TweezerWireSample};
use kilotouch_rig::serial::{CommandLead, LinkTweezer, SerialConfig, TweezerInstrument};
use kilotouch_rig::tweezer::{SimTweezer, Tweezer, TweezerParams, TweezerSample};
use std::time::Duration;

fn emu_cfg() -> EmulatorConfig {
    EmulatorConfig {
        watchdog: Duration::from_millis(500),
        ..EmulatorConfig::default()
    }
}

/// The emulator sending `batch` samples a frame.
fn batched(batch: usize) -> EmulatorConfig {
    EmulatorConfig { batch, ..emu_cfg() }
}

/// The simulated tweezer of `rc` the link must follow, and its stiffness, N/m.
fn simulated(rc: &RigConfig) -> (SimTweezer, f64) {
    let p = TweezerParams::from_config(&rc.tweezer);
    let kappa = p.stiffness_n_per_m;
    (SimTweezer::new(p, rc.rig.sample_rate_hz).unwrap(), kappa)
}

fn tweezer(rc: &RigConfig, cfg: EmulatorConfig) -> Device<TweezerInstrument> {
    Device::spawn(TweezerInstrument::new(rc).unwrap(), cfg)
}

fn link(path: &str, lead: CommandLead) -> LinkTweezer {
    let mut cfg = SerialConfig::new(path);
    cfg.lead = lead;
    LinkTweezer::open(&cfg).unwrap()
}

/// A live sample equals the reference's: bead, state and events exactly;
/// force, gap and normal to rounding.
fn assert_same(g: &TweezerSample, w: &TweezerSample, kappa: f64, i: usize) {
    assert_eq!(g.bead_m, w.bead_m, "sample {i}");
    assert_eq!(g.trap_m, w.trap_m, "sample {i}");
    assert_eq!(g.trapped, w.trapped, "sample {i}");
    assert_eq!(g.in_contact, w.in_contact, "sample {i}");
    assert_eq!(g.events, w.events, "sample {i}");
    for k in 0..2 {
        assert!(
            (g.force_n[k] - w.force_n[k]).abs() <= 1e-9 * kappa * 1e-6,
            "sample {i}: force {:?} vs {:?}",
            g.force_n,
            w.force_n
        );
        assert!(
            (g.normal[k] - w.normal[k]).abs() <= 1e-12,
            "sample {i}: normal {:?} vs {:?}",
            g.normal,
            w.normal
        );
    }
    assert!(
        (g.gap_m - w.gap_m).abs() <= 1e-15,
        "sample {i}: gap {} vs {}",
        g.gap_m,
        w.gap_m
    );
}

/// The trap sweeps towards the obstacle at x = 12 µm (radius 5 µm).
fn sweep(i: usize) -> [f64; 2] {
    [
        1e-6 + 6e-6 * (i as f64 / 1500.0),
        0.2e-6 * (i as f64 * 0.01).sin(),
    ]
}

#[test]
fn link_tweezer_follows_the_simulated_tweezer_exactly() {
    let rc = RigConfig::default();
    let dev = tweezer(&rc, batched(1));
    let mut tw = link(&dev.path, CommandLead::Blocks(0));
    let (mut reference, kappa) = simulated(&rc);
    assert_eq!(tw.sample_rate_hz(), rc.rig.sample_rate_hz);
    assert_eq!(tw.stiffness_n_per_m(), kappa);
    assert_eq!(
        tw.loop_delay_samples(1),
        0,
        "block-synchronous: nothing beyond the block"
    );
    tw.reset([1e-6, 0.0]);
    reference.reset([1e-6, 0.0]);
    let mut contact = false;
    for i in 0..1500 {
        let g = tw.step(sweep(i));
        let w = reference.step(sweep(i));
        assert_same(&g, &w, kappa, i);
        assert!(g.gap_m.is_finite(), "the scene's obstacles give a gap");
        contact |= g.in_contact;
    }
    assert!(contact, "the sweep must reach the obstacle");
    assert_eq!(tw.failures(), 0);
    assert_eq!(tw.link_stats().lost, 0);
    assert_eq!(tw.link_error(), None);
}

/// With a lead of L samples the bead answers L samples later: block k's
/// samples are those of the set-points sent L samples earlier, the lead's
/// first L holding the trap where it was reset; each sample's force is
/// κ(applied set-point − bead). Blocks of 10 against a device that sends 7
/// samples per frame (frames across block boundaries).
#[test]
fn with_a_lead_the_bead_answers_the_set_point_applied_lead_samples_earlier() {
    let rc = RigConfig::default();
    let dev = tweezer(&rc, batched(7));
    let mut tw = link(&dev.path, CommandLead::Blocks(2));
    assert_eq!(tw.lead_samples(10), 20);
    assert_eq!(tw.loop_delay_samples(10), 20, "the lead, beyond the block");
    let (mut reference, kappa) = simulated(&rc);
    let start = [1e-6, 0.0];
    tw.reset(start);
    reference.reset(start);
    let (n, blocks) = (10, 150);
    let traps: Vec<[f64; 2]> = (0..n * blocks).map(sweep).collect();
    // What the device applies: the reset position for the lead, then the
    // set-points 20 samples late.
    let applied = |j: usize| if j < 20 { start } else { traps[j - 20] };
    let mut out = vec![TweezerSample::default(); n];
    let mut contact = false;
    for b in 0..blocks {
        tw.step_block(&traps[b * n..(b + 1) * n], &mut out);
        for (i, g) in out.iter().enumerate() {
            let j = b * n + i;
            let w = reference.step(applied(j));
            assert_same(g, &w, kappa, j);
            contact |= g.in_contact;
        }
    }
    assert!(contact, "the sweep must reach the obstacle");
    assert_eq!((tw.failures(), tw.link_stats().lost), (0, 0));
    assert_eq!(tw.link_stats().stray_samples, 0);
    // A reset begins a new run: the set-points already sent are dropped
    // (the old run's last ones would hold the trap near 7 µm), the new
    // lead holds the trap at the new position, the bead in it (within 10
    // thermal standard deviations, √(k_BT/κ) ≈ 14 nm). How many of the old
    // set-points the device ran before the STOP depends on timing, so the
    // noise no longer matches the reference's.
    let again = [2e-6, 1e-6];
    tw.reset(again);
    tw.step_block(&traps[..n], &mut out);
    let sd = (TweezerParams::from_config(&rc.tweezer).variance_theory()).sqrt();
    for g in &out {
        assert_eq!(g.trap_m, again);
        assert!(g.trapped);
        let d = ((g.bead_m[0] - again[0]).powi(2) + (g.bead_m[1] - again[1]).powi(2)).sqrt();
        assert!(d < 10.0 * sd, "bead {:?} vs trap {again:?}", g.bead_m);
    }
    assert_eq!(tw.link_error(), None);
}

/// The emulator serves its rig file's obstacles; the link reports them as
/// they are, with the bead radius. A rig file with more obstacles than a
/// scene carries is refused by the emulator.
#[test]
fn the_scene_the_link_reports_is_the_rig_files() {
    let mut rc = RigConfig::default();
    rc.tweezer.obstacles = vec![
        ObstacleConfig {
            x_m: 9e-6,
            y_m: -3e-6,
            radius_m: 4e-6,
        },
        ObstacleConfig {
            x_m: -7.5e-6,
            y_m: 2.25e-6,
            radius_m: 2.5e-6,
        },
        ObstacleConfig {
            x_m: 0.0,
            y_m: 20e-6,
            radius_m: 5e-6,
        },
    ];
    let dev = tweezer(&rc, emu_cfg());
    let tw = link(&dev.path, CommandLead::Auto);
    let got: Vec<[f64; 3]> = tw
        .obstacles()
        .iter()
        .map(|o| [o.centre_m[0], o.centre_m[1], o.radius_m])
        .collect();
    let want: Vec<[f64; 3]> = rc
        .tweezer
        .obstacles
        .iter()
        .map(|o| [o.x_m, o.y_m, o.radius_m])
        .collect();
    assert_eq!(got, want);
    assert_eq!(tw.bead_radius_m(), Some(rc.tweezer.radius_m));
    assert!(tw.round_trip_s().is_some_and(|r| r > 0.0 && r < 1.0));
    assert!(tw.lead_samples(10) >= 10, "lead=auto: at least one block");
    assert!(tw.hello().firmware.contains("emulate tweezer"));

    let mut many = RigConfig::default();
    many.tweezer.obstacles = (0..frame::MAX_SCENE_OBSTACLES + 1)
        .map(|i| ObstacleConfig {
            x_m: 20e-6 * i as f64,
            y_m: 30e-6,
            radius_m: 1e-6,
        })
        .collect();
    let e = TweezerInstrument::new(&many).unwrap_err().to_string();
    assert!(e.contains("at most 32"), "{e}");
}

/// A tweezer that serves no scene (a device of an older firmware): the
/// link works, the gap is unknown (+∞).
struct NoScene(TweezerInstrument);

impl Instrument for NoScene {
    type Command = TrapCommand;
    type Sample = TweezerWireSample;
    const COMMAND_TYPE: u8 = TweezerInstrument::COMMAND_TYPE;
    const SAMPLE_TYPE: u8 = TweezerInstrument::SAMPLE_TYPE;
    fn hello(&self) -> Hello {
        self.0.hello()
    }
    fn step(&mut self, cmd: &TrapCommand, extra_flags: u8) -> TweezerWireSample {
        self.0.step(cmd, extra_flags)
    }
    fn safe_command(&self, last: &TrapCommand) -> TrapCommand {
        self.0.safe_command(last)
    }
    fn reset(&mut self, cmd: &TrapCommand) {
        self.0.reset(cmd);
    }
    fn scene(&self) -> Option<Scene> {
        None
    }
}

#[test]
fn without_a_scene_the_gap_is_unknown() {
    let rc = RigConfig::default();
    let dev = Device::spawn(NoScene(TweezerInstrument::new(&rc).unwrap()), emu_cfg());
    let mut tw = link(&dev.path, CommandLead::Auto);
    assert!(tw.obstacles().is_empty());
    assert_eq!(tw.bead_radius_m(), None);
    tw.reset([0.0; 2]);
    let mut out = [TweezerSample::default(); 10];
    tw.step_block(&[[0.0; 2]; 10], &mut out);
    assert!(out.iter().all(|s| s.gap_m == f64::INFINITY && s.trapped));
    assert_eq!(tw.link_error(), None);
}

/// A real escape — the trap jumps 6 µm, the bead stays behind — is the
/// device's: the bead untrapped, an `escaped` event, no force; the link is
/// fine.
#[test]
fn an_escape_is_reported_as_an_escape() {
    let mut rc = RigConfig::default();
    rc.tweezer.obstacles.clear();
    let dev = tweezer(&rc, emu_cfg());
    let mut tw = link(&dev.path, CommandLead::Auto);
    tw.reset([0.0; 2]);
    let mut out = [TweezerSample::default(); 10];
    let mut escaped = false;
    for _ in 0..20 {
        tw.step_block(&[[6e-6, 0.0]; 10], &mut out);
        escaped |= out.iter().any(|s| s.events.escaped);
        if escaped {
            break;
        }
    }
    assert!(escaped, "the jump must lose the bead");
    assert!(!out[9].trapped);
    assert_eq!(out[9].force_n, [0.0; 2]);
    assert_eq!(tw.link_error(), None);
    assert_eq!(tw.failures(), 0);
}

/// Steps blocks until the link reports a failure (at most `limit` blocks).
fn until_failure(
    tw: &mut LinkTweezer,
    limit: usize,
) -> (Option<LinkErrorKind>, [TweezerSample; 10]) {
    let mut out = [TweezerSample::default(); 10];
    for _ in 0..limit {
        tw.step_block(&[[0.0; 2]; 10], &mut out);
        if tw.link_error().is_some() {
            break;
        }
    }
    (tw.link_error(), out)
}

/// The emulator goes away mid-run: the link reports a lost link (not an
/// escape): the samples carry no force and no event, the bead's trapped
/// state as last known, and further blocks say the same.
#[test]
fn a_vanished_tweezer_is_a_link_failure_not_an_escape() {
    let rc = RigConfig::default();
    let dev = tweezer(
        &rc,
        EmulatorConfig {
            faults: FaultInjection {
                disconnect_after: Some(Duration::from_millis(600)),
                ..FaultInjection::default()
            },
            ..emu_cfg()
        },
    );
    let mut tw = link(&dev.path, CommandLead::Auto);
    tw.reset([0.0; 2]);
    let (k, out) = until_failure(&mut tw, 100_000);
    assert_eq!(k, Some(LinkErrorKind::Disconnected));
    let e = tw.failure().unwrap().to_string();
    assert!(e.contains(&dev.path), "{e}");
    let mut after = [TweezerSample::default(); 10];
    tw.step_block(&[[1e-6, 0.0]; 10], &mut after);
    for s in out.iter().rev().take(1).chain(after.iter()) {
        assert_eq!(s.force_n, [0.0; 2]);
        assert!(s.trapped, "a lost link is not an escape");
        assert!(!s.events.any());
    }
    assert_eq!(after[0].trap_m, [1e-6, 0.0]);
    assert_eq!(tw.link_error(), Some(LinkErrorKind::Disconnected));
    assert!(tw.failures() >= 10);
    // A reset cannot bring a lost port back; recover() reopens it.
    tw.reset([0.0; 2]);
    assert_eq!(tw.link_error(), Some(LinkErrorKind::Disconnected));
    assert!(tw.recover().is_err());
}

/// The host goes silent longer than the device's watchdog: the next block
/// reports the watchdog trip; a reset starts a new run and the link works
/// again.
#[test]
fn a_watchdog_trip_is_a_link_failure_and_a_reset_restarts() {
    let rc = RigConfig::default();
    let dev = tweezer(
        &rc,
        EmulatorConfig {
            watchdog: Duration::from_millis(50),
            ..EmulatorConfig::default()
        },
    );
    let mut cfg = SerialConfig::new(&dev.path);
    cfg.lead = CommandLead::Blocks(1);
    cfg.timeout = Duration::from_secs(2);
    let mut tw = LinkTweezer::open(&cfg).unwrap();
    tw.reset([0.0; 2]);
    let mut out = [TweezerSample::default(); 10];
    tw.step_block(&[[0.0; 2]; 10], &mut out);
    assert_eq!(tw.link_error(), None);
    // Silent for 4 watchdog windows (the condition under test, not a wait
    // for an event).
    std::thread::sleep(Duration::from_millis(200));
    let (k, out) = until_failure(&mut tw, 10);
    assert_eq!(k, Some(LinkErrorKind::Watchdog));
    assert!(
        out.iter()
            .all(|s| s.force_n == [0.0; 2] && !s.events.escaped)
    );
    tw.reset([0.0; 2]);
    assert_eq!(tw.link_error(), None);
    let mut out = [TweezerSample::default(); 10];
    for _ in 0..10 {
        tw.step_block(&[[0.0; 2]; 10], &mut out);
    }
    assert_eq!(tw.link_error(), None);
    assert!(out.iter().all(|s| s.trapped));
    assert_eq!(dev.finish().stats().watchdog_trips, 1);
}
