//! Any bytes are a journal (records and a torn tail) or an error.
#![no_main]

use kilotouch_study::export::journal::parse_journal;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(j) = parse_journal(Path::new("journal.jsonl"), data) {
        assert_eq!(j.entries.len(), j.lines.len());
    }
});
