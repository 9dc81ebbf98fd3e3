//! Property test of the CSV reader of the headless commands
//! (`kilotouch_study::csvio`): for tables with repeated column names, missing
//! columns, ragged rows and cells that are not finite numbers, the reader
//! returns exactly what an independent oracle — built from the table's own
//! description, not from the CSV text — says: the right error, or the
//! right numbers (bit for bit). Never a wrong "ok".
//!
//! Cases: `PROPTEST_CASES` (default 256; the closing-note figure was run
//! with 100 000).

#![allow(clippy::unwrap_used)]

use std::path::Path;

use kilotouch_study::csvio::{CsvError, read_table_from};
use proptest::prelude::*;

use crate::common::proptest_config as config;

/// A cell as written, and its value when it is a finite number.
fn cell() -> impl Strategy<Value = (String, Option<f64>)> {
    prop_oneof![
        6 => (-1e6_f64..1e6).prop_map(|x| (format!("{x}"), Some(x))),
        2 => any::<f64>().prop_filter("finite", |x| x.is_finite()).prop_map(|x| (format!("{x:e}"), Some(x))),
        1 => (-100_i64..100).prop_map(|i| (format!(" {i} "), Some(i as f64))),
        1 => prop_oneof![
            Just("NaN".to_owned()),
            Just("inf".to_owned()),
            Just("-inf".to_owned()),
            Just("-".to_owned()),
            Just("abc".to_owned()),
            Just("1e999".to_owned()),
        ]
        .prop_map(|s| (s, None)),
    ]
}

/// Header names from a small alphabet (so repeats happen), rows with an
/// occasional wrong width, and the columns to read.
#[allow(clippy::type_complexity)]
fn table() -> impl Strategy<Value = (Vec<String>, Vec<Vec<(String, Option<f64>)>>, Vec<String>)> {
    let names = prop::collection::vec(prop::sample::select(vec!["a", "b", "c", "x", "y"]), 1..5);
    (names, prop::collection::vec(any::<u8>(), 0..12), 0_usize..3).prop_flat_map(
        |(names, widths, n_req)| {
            let w = names.len();
            let rows: Vec<_> = widths
                .iter()
                .map(|&b| {
                    // 1 row in 16 is ragged.
                    let width = match b % 16 {
                        0 => w + 1,
                        1 => w.saturating_sub(1).max(1),
                        _ => w,
                    };
                    prop::collection::vec(cell(), width)
                })
                .collect();
            let req = prop::collection::vec(
                prop::sample::select(vec!["a", "b", "c", "x", "y", "z"]),
                n_req + 1,
            );
            (
                Just(names.into_iter().map(str::to_owned).collect::<Vec<_>>()),
                rows,
                req.prop_map(|r| r.into_iter().map(str::to_owned).collect::<Vec<_>>()),
            )
        },
    )
}

/// What the reader must answer, from the description alone.
#[derive(Debug, PartialEq)]
enum Expected {
    Duplicate(String),
    Missing(String),
    Ragged(u64),
    NotNumeric(u64, String),
    NoRows,
    Ok(Vec<Vec<f64>>),
}

fn oracle(names: &[String], rows: &[Vec<(String, Option<f64>)>], req: &[String]) -> Expected {
    for (i, n) in names.iter().enumerate() {
        if names[..i].contains(n) {
            return Expected::Duplicate(n.clone());
        }
    }
    let mut idx = Vec::new();
    for r in req {
        match names.iter().position(|n| n == r) {
            Some(i) => idx.push(i),
            None => return Expected::Missing(r.clone()),
        }
    }
    let mut data = vec![Vec::new(); req.len()];
    for (k, row) in rows.iter().enumerate() {
        let line = k as u64 + 2;
        if row.len() != names.len() {
            return Expected::Ragged(line);
        }
        for (j, &i) in idx.iter().enumerate() {
            match row[i].1 {
                Some(v) => data[j].push(v),
                None => return Expected::NotNumeric(line, req[j].clone()),
            }
        }
    }
    if rows.is_empty() {
        return Expected::NoRows;
    }
    Expected::Ok(data)
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn the_reader_answers_what_the_table_holds((names, rows, req) in table()) {
        let mut text = names.join(",") + "\n";
        for r in &rows {
            text += &r.iter().map(|(s, _)| s.as_str()).collect::<Vec<_>>().join(",");
            text.push('\n');
        }
        let req_refs: Vec<&str> = req.iter().map(String::as_str).collect();
        let got = read_table_from(text.as_bytes(), Path::new("t.csv"), &[], &req_refs, &[]);
        let want = oracle(&names, &rows, &req);
        match (&got, &want) {
            (Err(CsvError::DuplicateColumn { name, .. }), Expected::Duplicate(n)) => prop_assert_eq!(name, n),
            (Err(CsvError::MissingColumn { name, .. }), Expected::Missing(n)) => prop_assert_eq!(name, n),
            (Err(CsvError::Ragged { line, .. }), Expected::Ragged(l)) => prop_assert_eq!(line, l),
            (Err(CsvError::NotNumeric { line, column, .. }), Expected::NotNumeric(l, c)) => {
                prop_assert_eq!(line, l);
                prop_assert_eq!(column, c);
            }
            (Err(CsvError::NoRows { .. }), Expected::NoRows) => {}
            (Ok(cols), Expected::Ok(data)) => {
                prop_assert_eq!(cols.data.len(), data.len());
                for (got, want) in cols.data.iter().zip(data) {
                    let g: Vec<u64> = got.iter().map(|v| v.to_bits()).collect();
                    let w: Vec<u64> = want.iter().map(|v| v.to_bits()).collect();
                    prop_assert_eq!(g, w);
                }
            }
            _ => prop_assert!(false, "reader {got:?}, oracle {want:?}\n{text}"),
        }
    }
}
