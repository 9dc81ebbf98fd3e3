//! Any text is a rig file or an error; an accepted rig file builds the
//! simulated rig and its safety limits (what every command builds).
#![no_main]

use kilotouch_rig::config::RigConfig;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(cfg) = RigConfig::from_toml_str(text, "fuzz.toml") else {
        return;
    };
    assert!(kilotouch_rig::safety::HardLimits::from_config(&cfg).is_ok());
    assert!(kilotouch_rig::sim::SimRig::new(&cfg).is_ok());
});
