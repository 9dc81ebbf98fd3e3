//! Any text is a protocol or an error; an accepted protocol validates,
//! counterbalances, hashes and fits the scene (never a wrong "ok").
#![no_main]

use kilotouch_study::protocol::{Protocol, SCENE_REACH_UM, Task};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(p) = Protocol::from_toml_str(text, "fuzz.toml") else {
        return;
    };
    assert!(p.validate().is_ok());
    assert!(p.assignment().is_ok());
    assert!(kilotouch_study::export::session::protocol_identity(&p).is_ok());
    let extent = match &p.task {
        Task::Circling(t) => 2.0 * (t.obstacle_radius_um + t.bead_radius_um) + 2.0,
        Task::BlindNavigation(t) => t.start_distance_um + t.retreat_distance_um,
    };
    assert!(extent <= SCENE_REACH_UM + 1e-9, "{:?}", p.task);
});
