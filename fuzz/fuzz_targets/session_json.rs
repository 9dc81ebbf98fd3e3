//! Any bytes are a `session.json` or an error; an accepted one is
//! consistent with its protocol text.
#![no_main]

use kilotouch_study::export::session::{check_derived, parse_session};
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("session.json");
    if let Ok(info) = parse_session(path, data) {
        assert!(check_derived(path, &info).is_ok());
    }
});
