//! Text formats: UTC timestamps against an independent calendar count, and
//! the `trials.csv` row encoding (NA, booleans, quoting, exact numbers,
//! checksums, errors naming line and column).

use std::path::Path;
use std::time::{Duration, UNIX_EPOCH};

use kilotouch_study::export::checksum::crc32;
use kilotouch_study::export::trials::{header_line, parse_trials};
use kilotouch_study::export::{
    ExportError, ReadOptions, TRIALS_COLUMNS, TaskKind, TrialRow, UtcTime,
};
use kilotouch_study::protocol::Condition;
use kilotouch_study::seeds::{Phase, TrialKey};

#[test]
fn utc_known_instants() {
    let cases = [
        (0_i64, "1970-01-01T00:00:00.000Z"),
        (-1, "1969-12-31T23:59:59.999Z"),
        (951_782_400_000, "2000-02-29T00:00:00.000Z"),
        (1_000_000_000_000, "2001-09-09T01:46:40.000Z"),
        (1_767_225_599_999, "2025-12-31T23:59:59.999Z"),
        (4_107_542_400_000, "2100-03-01T00:00:00.000Z"),
        (-62_135_596_800_000, "0001-01-01T00:00:00.000Z"),
        (253_402_300_799_999, "9999-12-31T23:59:59.999Z"),
    ];
    for (ms, text) in cases {
        let t = UtcTime::from_unix_millis(ms);
        assert_eq!(t.to_string(), text);
        assert_eq!(UtcTime::parse(text).unwrap(), t);
    }
    // Clamped beyond year 9999.
    assert_eq!(
        UtcTime::from_unix_millis(i64::MAX).to_string(),
        "9999-12-31T23:59:59.999Z"
    );
    // SystemTime conversion truncates toward the past, also before 1970.
    let t = UNIX_EPOCH + Duration::from_micros(1_500);
    assert_eq!(UtcTime::from_system_time(t).unix_millis(), 1);
    let t = UNIX_EPOCH - Duration::from_micros(1_500);
    assert_eq!(UtcTime::from_system_time(t).unix_millis(), -2);
    let now = UtcTime::now();
    assert!(now.unix_millis() > 1_700_000_000_000);
    assert_eq!(UtcTime::from_system_time(now.to_system_time()), now);
}

/// Day-by-day calendar count (independent of the library's closed form).
fn naive_days(mut days: i64) -> (i64, u32, u32) {
    let leap = |y: i64| (y % 4 == 0 && y % 100 != 0) || y % 400 == 0;
    let len = |y: i64, m: u32| match m {
        2 if leap(y) => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    };
    let (mut y, mut m, mut d) = (1970_i64, 1_u32, 1_u32);
    while days > 0 {
        d += 1;
        if d > len(y, m) {
            d = 1;
            m += 1;
            if m > 12 {
                m = 1;
                y += 1;
            }
        }
        days -= 1;
    }
    while days < 0 {
        if d > 1 {
            d -= 1;
        } else {
            if m > 1 {
                m -= 1;
            } else {
                m = 12;
                y -= 1;
            }
            d = len(y, m);
        }
        days += 1;
    }
    (y, m, d)
}

#[test]
fn utc_dates_agree_with_a_day_by_day_calendar() {
    // 1770–2170: covers 1800, 1900 (not leap), 2000 (leap), 2100.
    let first = -73_000_i64;
    let (mut y, mut m, mut d) = naive_days(first);
    assert_eq!((y, m, d), (1770, 2, 18)); // Python datetime
    for days in first..73_000 {
        if days > first {
            (y, m, d) = naive_days_step(y, m, d);
        }
        let ms = days * 86_400_000 + 45_296_789; // 12:34:56.789
        let text = UtcTime::from_unix_millis(ms).to_string();
        assert_eq!(
            text,
            format!("{y:04}-{m:02}-{d:02}T12:34:56.789Z"),
            "day {days}"
        );
        assert_eq!(UtcTime::parse(&text).unwrap().unix_millis(), ms);
    }
    assert_eq!((y, m, d), (2169, 11, 12)); // Python datetime
}

fn naive_days_step(y: i64, m: u32, d: u32) -> (i64, u32, u32) {
    let leap = (y % 4 == 0 && y % 100 != 0) || y % 400 == 0;
    let len = match m {
        2 if leap => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    };
    if d < len {
        (y, m, d + 1)
    } else if m < 12 {
        (y, m + 1, 1)
    } else {
        (y + 1, 1, 1)
    }
}

#[test]
fn utc_rejects_what_is_not_a_utc_timestamp() {
    for bad in [
        "",
        "2026-02-29T00:00:00Z",
        "1900-02-29T00:00:00.000Z",
        "2026-13-01T00:00:00Z",
        "2026-04-31T00:00:00Z",
        "2026-01-01T24:00:00Z",
        "2026-01-01T00:60:00Z",
        "2026-01-01T00:00:60Z",
        "2026-01-01T00:00:00",
        "2026-01-01T00:00:00+01:00",
        "2026-01-01 00:00:00Z",
        "2026-01-01T00:00:00.Z",
        "2026-01-01T00:00:00.1234567890Z",
        "+2026-01-01T00:00:00Z",
    ] {
        assert!(UtcTime::parse(bad).is_err(), "{bad}");
    }
    assert!(UtcTime::parse("2024-02-29T00:00:00Z").is_ok());
    // Sub-millisecond digits are truncated.
    assert_eq!(
        UtcTime::parse("2026-01-01T00:00:00.123999Z")
            .unwrap()
            .unix_millis()
            % 1000,
        123
    );
    assert_eq!(
        UtcTime::parse("2026-01-01T00:00:00.5Z")
            .unwrap()
            .unix_millis()
            % 1000,
        500
    );
}

fn sample_row() -> TrialRow {
    TrialRow {
        participant: "P03".into(),
        session_index: 2,
        session_order: "DVP".into(),
        condition: Condition::V,
        phase: Phase::Test,
        trial: 7,
        task: TaskKind::BlindNavigation,
        success: false,
        reject_reason: "said \"stop\", then left".into(),
        time_s: Some(0.1 + 0.2),
        force_mean_pn: None,
        force_mean_n: Some(5e-324),
        disp_err_mean_um: Some(-0.0),
        contact_fraction: Some(1.0),
        seed: 0xfedc_ba98_7654_3210,
        started_utc: UtcTime::from_unix_millis(1_767_225_600_123),
        escaped: None,
        time_to_collision_s: Some(1.7976931348623157e308),
        peak_force_pn: Some(123.456),
        retreat_angle_err_deg: Some(-12.5),
        raw_file: "raw/P03_V_test_007.npy".into(),
    }
}

#[test]
fn row_encoding_na_booleans_quoting_and_checksum() {
    let row = sample_row();
    let key = TrialKey::new(2, Condition::V, Phase::Test, 7);
    row.validate(key).unwrap();
    let (line, crc) = row.encode().unwrap();
    assert!(line.ends_with('\n') && line.matches('\n').count() == 1);
    let text = line.trim_end();
    let (content, crc_text) = text.rsplit_once(',').unwrap();
    assert_eq!(crc_text, format!("{:08x}", crc32(content.as_bytes())));
    assert_eq!(crc, crc32(content.as_bytes()));
    // RFC 4180: a cell with a comma or quote is quoted, quotes doubled.
    assert!(
        content.contains(",\"said \"\"stop\"\", then left\","),
        "{content}"
    );
    let mut r = csv::ReaderBuilder::new()
        .has_headers(false)
        .from_reader(text.as_bytes());
    let rec = r.records().next().unwrap().unwrap();
    assert_eq!(rec.len(), TRIALS_COLUMNS.len());
    let cell = |name: &str| {
        rec.get(TRIALS_COLUMNS.iter().position(|c| *c == name).unwrap())
            .unwrap()
            .to_owned()
    };
    assert_eq!(cell("participant"), "P03");
    assert_eq!(cell("phase"), "test");
    assert_eq!(cell("task"), "blind_navigation");
    assert_eq!(cell("success"), "0");
    assert_eq!(cell("force_mean_pn"), "", "NA is an empty cell");
    assert_eq!(cell("escaped"), "");
    assert_eq!(cell("seed"), "0xfedcba9876543210");
    assert_eq!(cell("started_utc"), "2026-01-01T00:00:00.123Z");
    assert_eq!(cell("time_s"), "0.30000000000000004", "shortest round-trip");
    assert!(
        !cell("time_to_collision_s").contains('e'),
        "no exponent notation"
    );

    // Read back: identical values, bit for bit.
    let file = format!("{}{}", header_line(), line);
    let read = parse_trials(Path::new("t.csv"), file.as_bytes(), ReadOptions::default()).unwrap();
    assert_eq!(read.rows, vec![row.clone()]);
    let back = &read.rows[0];
    assert_eq!(back.force_mean_n.unwrap().to_bits(), 5e-324_f64.to_bits());
    assert!(back.disp_err_mean_um.unwrap().is_sign_negative());
    assert_eq!(read.crcs, vec![crc]);
    assert_eq!(read.lines, vec![2]);
}

#[test]
fn parse_errors_name_line_and_column() {
    let (line, _) = sample_row().encode().unwrap();
    let mut other = sample_row();
    other.trial = 8;
    let (line2, _) = other.encode().unwrap();
    let with_crc = |content: &str| format!("{content},{:08x}\n", crc32(content.as_bytes()));
    let path = Path::new("trials.csv");
    let cases = [
        ("time_s", "abc"),
        ("time_s", "NaN"),
        ("time_s", "inf"),
        ("success", "yes"),
        ("condition", "X"),
        ("phase", "warmup"),
        ("trial", "-1"),
        ("seed", "0xZZ"),
        ("started_utc", "2026-01-01"),
        ("task", "juggling"),
        ("escaped", "2"),
    ];
    for (column, bad) in cases {
        let j = TRIALS_COLUMNS.iter().position(|c| *c == column).unwrap();
        let (content, _) = line.trim_end().rsplit_once(',').unwrap();
        let mut rdr = csv::ReaderBuilder::new()
            .has_headers(false)
            .from_reader(content.as_bytes());
        let rec = rdr.records().next().unwrap().unwrap();
        let mut cells: Vec<String> = rec.iter().map(str::to_owned).collect();
        cells[j] = bad.to_owned();
        let mut w = csv::WriterBuilder::new().from_writer(Vec::new());
        w.write_record(&cells).unwrap();
        let edited = String::from_utf8(w.into_inner().unwrap()).unwrap();
        let file = format!("{}{}{}", header_line(), with_crc(edited.trim_end()), line2);
        let err = parse_trials(path, file.as_bytes(), ReadOptions::default()).unwrap_err();
        assert!(
            matches!(&err, ExportError::Format { at, .. } if at.line == 2 && at.column.as_deref() == Some(column)),
            "{column}={bad}: {err}"
        );
        assert!(
            err.to_string()
                .contains(&format!("line 2, column `{column}`")),
            "{err}"
        );
    }
    // Wrong number of fields.
    let file = format!("{}{}{}", header_line(), with_crc("a,b,c"), line2);
    let err = parse_trials(path, file.as_bytes(), ReadOptions::default()).unwrap_err();
    assert!(
        err.to_string().contains("4 field(s), the header has 22"),
        "{err}"
    );
    // Empty file.
    let err = parse_trials(path, b"", ReadOptions::default()).unwrap_err();
    assert!(err.to_string().contains("header line is missing"), "{err}");
    // Checksums can be switched off for a deliberately edited file.
    let edited = line.replacen("P03", "P04", 1);
    let file = format!("{}{}", header_line(), edited);
    assert!(
        parse_trials(path, file.as_bytes(), ReadOptions::default())
            .is_ok_and(|r| r.rows.is_empty() && r.torn.is_some())
    );
    let r = parse_trials(
        path,
        file.as_bytes(),
        ReadOptions {
            verify_checksums: false,
        },
    )
    .unwrap();
    assert_eq!(r.rows[0].participant, "P04");
}

#[test]
fn invalid_rows_are_refused_before_writing() {
    let key = TrialKey::new(2, Condition::V, Phase::Test, 7);
    type Edit = fn(&mut TrialRow);
    let cases: [(&str, Edit); 7] = [
        ("time_s", |r| r.time_s = Some(f64::NAN)),
        ("peak_force_pn", |r| {
            r.peak_force_pn = Some(f64::NEG_INFINITY)
        }),
        ("reject_reason", |r| r.reject_reason.clear()),
        ("reject_reason", |r| r.success = true),
        ("session_index", |r| r.phase = Phase::Practice),
        ("raw_file", |r| r.raw_file = "C:\\raw\\x.npy".into()),
        ("participant", |r| r.participant = "P\t1".into()),
    ];
    for (column, edit) in cases {
        let mut row = sample_row();
        edit(&mut row);
        let err = row.validate(key).unwrap_err();
        assert!(
            matches!(&err, ExportError::InvalidRow { column: c, .. } if *c == column),
            "{column}: {err}"
        );
    }
}
