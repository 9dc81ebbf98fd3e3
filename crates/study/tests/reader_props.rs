//! Property tests of the readers of researcher-written and recorded files:
//! protocol files and rig files (TOML) and `trials.csv` (CSV). For ANY
//! text — arbitrary, or a real file with one value replaced by something
//! hostile (huge, negative, non-finite, of the wrong type) — the readers
//! return a value or an error and never panic; a refused value is named
//! by its field. Case counts are fixed, so the suite's time is bounded.

#![allow(clippy::unwrap_used)]

use std::path::Path;

use crate::common::replace_value;
use kilotouch_rig::config::{RigConfig, default_config_text};
use kilotouch_study::export::trials::parse_trials;
use kilotouch_study::export::{ReadOptions, TRIALS_COLUMNS};
use kilotouch_study::protocol::{PAPER_TOML, Protocol, ProtocolError};
use proptest::prelude::*;

/// Hostile replacement values for one `key = value` line.
fn hostile_value() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<f64>().prop_map(|x| format!("{x:e}")),
        any::<i64>().prop_map(|x| x.to_string()),
        Just("4294967295".to_owned()),
        Just("18446744073709551615".to_owned()),
        Just("1e308".to_owned()),
        Just("-1e308".to_owned()),
        Just("nan".to_owned()),
        Just("inf".to_owned()),
        Just("-inf".to_owned()),
        Just("0".to_owned()),
        Just("\"\\u001b[2J\"".to_owned()),
        Just("[1, 2, 3]".to_owned()),
        "[ -~]{0,40}".prop_map(|s| format!("\"{s}\"")),
        "[ -~]{0,40}",
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    #[test]
    fn any_text_is_a_protocol_or_an_error(text in "(?s).{0,400}") {
        let _ = Protocol::from_toml_str(&text, "<prop>");
    }

    #[test]
    fn a_hostile_value_in_a_protocol_is_refused_by_field(
        line in 0usize..64,
        value in hostile_value(),
    ) {
        let text = replace_value(PAPER_TOML, line, &value);
        match Protocol::from_toml_str(&text, "paper.toml") {
            Ok(p) => {
                // Accepted values are within the plan's bounds.
                prop_assert!(p.participants <= kilotouch_study::protocol::MAX_PARTICIPANTS);
                prop_assert!(
                    p.trials_per_session <= kilotouch_study::protocol::MAX_TRIALS_PER_SESSION
                );
            }
            Err(ProtocolError::Invalid { invalid, .. }) => {
                prop_assert!(!invalid.field.is_empty());
            }
            Err(e) => {
                prop_assert!(e.to_string().contains("paper.toml"), "{e}");
            }
        }
    }

    #[test]
    fn any_text_is_a_rig_file_or_an_error(text in "(?s).{0,400}") {
        let _ = RigConfig::from_toml_str(&text, "<prop>");
    }

    #[test]
    fn a_hostile_value_in_a_rig_file_is_refused_by_field(
        line in 0usize..128,
        value in hostile_value(),
    ) {
        let text = replace_value(default_config_text(), line, &value);
        if let Err(e) = RigConfig::from_toml_str(&text, "rig.toml") {
            prop_assert!(e.to_string().contains("rig.toml"), "{e}");
        }
    }

    #[test]
    fn any_bytes_are_trials_or_an_error(
        body in prop::collection::vec(any::<u8>(), 0..2000),
        with_header in any::<bool>(),
    ) {
        let mut bytes = Vec::new();
        if with_header {
            bytes.extend_from_slice(TRIALS_COLUMNS.join(",").as_bytes());
            bytes.push(b'\n');
        }
        bytes.extend_from_slice(&body);
        let _ = parse_trials(Path::new("trials.csv"), &bytes, ReadOptions::default());
        let _ = parse_trials(
            Path::new("trials.csv"),
            &bytes,
            ReadOptions { verify_checksums: false },
        );
    }
}
