//! Property tests of the protocol and rig-file loaders: for a real file
//! with one value replaced by something hostile (huge, tiny, negative,
//! non-finite, of the wrong type), the loader refuses — naming the file —
//! or accepts, and what it accepts is accepted by everything downstream:
//! an accepted protocol plans, counterbalances, hashes and draws scenes
//! that fit the scene's reach; an accepted rig file builds the chain, the
//! designed chain, the simulated rig and the safety limits (so no
//! command refuses later what the loader let through: `rig margins` and
//! `sim press` agree).
//!
//! Cases per property: `PROPTEST_CASES` (default 64 for the rig file, 256
//! for protocols; the closing-note figures were run with 100 000).

#![allow(clippy::unwrap_used)]

use crate::common::replace_value;
use kilotouch_rig::config::{RigConfig, default_config_text};
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::safety::HardLimits;
use kilotouch_rig::sim::SimRig;
use kilotouch_study::export::session::protocol_identity;
use kilotouch_study::protocol::{BLIND_TOML, PAPER_TOML, Protocol, SCENE_REACH_UM, Task};
use kilotouch_study::task::Scene;
use proptest::prelude::*;
use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::SeedableRng;

fn config(default: u32) -> ProptestConfig {
    let cases = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default);
    ProptestConfig {
        cases,
        ..ProptestConfig::default()
    }
}

/// Hostile replacement values for one `key = value` line.
fn hostile_value() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<f64>().prop_map(|x| format!("{x:e}")),
        (-30_i32..30).prop_map(|e| format!("1e{e}")),
        (-30_i32..30).prop_map(|e| format!("-2.5e{e}")),
        any::<i64>().prop_map(|x| x.to_string()),
        (0_u32..100).prop_map(|x| x.to_string()),
        Just("1e308".to_owned()),
        Just("1e300".to_owned()),
        Just("5e-324".to_owned()),
        Just("nan".to_owned()),
        Just("inf".to_owned()),
        Just("-inf".to_owned()),
        Just("0".to_owned()),
        Just("0.0".to_owned()),
        Just("[1.0, 2.0]".to_owned()),
        "[ -~]{0,12}".prop_map(|s| format!("\"{s}\"")),
    ]
}

/// How far from its start the task takes the bead, µm.
fn extent_um(task: &Task) -> f64 {
    match task {
        Task::Circling(t) => 2.0 * (t.obstacle_radius_um + t.bead_radius_um) + 2.0,
        Task::BlindNavigation(t) => t.start_distance_um + t.retreat_distance_um,
    }
}

proptest! {
    #![proptest_config(config(256))]

    #[test]
    fn an_accepted_protocol_is_usable_and_fits_the_scene(
        blind in any::<bool>(),
        line in 0_usize..64,
        value in hostile_value(),
        seed in any::<u64>(),
    ) {
        let (base, name) = if blind { (BLIND_TOML, "blind.toml") } else { (PAPER_TOML, "paper.toml") };
        let text = replace_value(base, line, &value);
        let p = match Protocol::from_toml_str(&text, name) {
            Ok(p) => p,
            Err(e) => {
                prop_assert!(e.to_string().contains(name), "{e}");
                return Ok(());
            }
        };
        prop_assert!(p.validate().is_ok());
        prop_assert!(p.assignment().is_ok());
        prop_assert!(protocol_identity(&p).is_ok());
        prop_assert!(extent_um(&p.task) <= SCENE_REACH_UM + 1e-9, "{:?}", p.task);
        let scene = Scene::draw(&p.task, [0.0, 0.0], &mut ChaCha20Rng::seed_from_u64(seed));
        let g = scene.geometry;
        for x in [g.obstacle_m[0], g.obstacle_m[1], g.obstacle_radius_m, g.bead_radius_m,
                  scene.heading[0], scene.heading[1]] {
            prop_assert!(x.is_finite(), "{scene:?}");
        }
        let centre = g.obstacle_m[0].hypot(g.obstacle_m[1]);
        prop_assert!(centre + g.obstacle_radius_m <= SCENE_REACH_UM * 1e-6 * 2.0, "{scene:?}");
    }
}

proptest! {
    #![proptest_config(config(64))]

    #[test]
    fn an_accepted_rig_file_is_accepted_by_every_command(
        line in 0_usize..160,
        value in hostile_value(),
    ) {
        let text = replace_value(default_config_text(), line, &value);
        let cfg = match RigConfig::from_toml_str(&text, "rig.toml") {
            Ok(c) => c,
            Err(e) => {
                prop_assert!(e.to_string().contains("rig.toml"), "{e}");
                return Ok(());
            }
        };
        // What `rig margins` builds (its stability analysis costs seconds:
        // the command-level test covers it) …
        let chain = LoopChain::as_designed(&cfg);
        prop_assert!(chain.is_ok(), "chain: {:?}", chain.err());
        // … and what `sim press`, `rig check --rig sim` and the engine build.
        let rig = SimRig::new(&cfg);
        prop_assert!(rig.is_ok(), "simulated rig: {:?}", rig.err());
        let lim = HardLimits::from_config(&cfg);
        prop_assert!(lim.is_ok(), "limits: {:?}", lim.err());
    }
}
