//! Any bytes are a `trials.csv` (rows and a torn tail) or an error.
#![no_main]

use kilotouch_study::export::ReadOptions;
use kilotouch_study::export::trials::parse_trials;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("trials.csv");
    if let Ok(read) = parse_trials(path, data, ReadOptions::default()) {
        assert_eq!(read.rows.len(), read.crcs.len());
        assert_eq!(read.rows.len(), read.lines.len());
    }
    let _ = parse_trials(
        path,
        data,
        ReadOptions {
            verify_checksums: false,
        },
    );
});
