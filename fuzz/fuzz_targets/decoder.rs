//! The stream decoder never panics on any byte sequence and returns only
//! frames that lie in the input as sent (`kilotouch_proto::contract`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Err(v) = kilotouch_proto::contract::check_fuzz_input(data) {
        panic!("decoder contract violated: {v:?}");
    }
});
