//! Journal line format, checksums and crash handling; CRC-32 / SHA-256
//! against their published check values.

use std::fs;

use kilotouch_study::export::ExportError;
use kilotouch_study::export::checksum::{Crc32, Sha256, crc32, sha256_hex};
use kilotouch_study::export::session::{
    CalibrationRef, DeviceRecord, OrderRow, SittingTiming, TweezerDeviceRecord,
};
use kilotouch_study::export::utc::UtcTime;
use kilotouch_study::journal::{
    Entry, Journal, Record, RecoveryRecord, SessionStart, decode_line, encode_line, parse_journal,
    read_journal,
};
use kilotouch_study::protocol::Condition;
use kilotouch_study::seeds::{Phase, TrialKey};

#[test]
fn crc32_check_values() {
    // CRC-32/ISO-HDLC check value (Williams' catalogue, "123456789").
    assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    assert_eq!(crc32(b""), 0);
    assert_eq!(
        crc32(b"The quick brown fox jumps over the lazy dog"),
        0x414F_A339
    );
    // Detects any single-bit error in a line.
    let line = b"P01,1,VPD,V,test,1,circling,1,,12.5".to_vec();
    let c = crc32(&line);
    for i in 0..line.len() * 8 {
        let mut l = line.clone();
        l[i / 8] ^= 1 << (i % 8);
        assert_ne!(crc32(&l), c, "bit {i}");
    }
    // Piece by piece (a raw file read in chunks) equals the whole.
    let text = b"The quick brown fox jumps over the lazy dog";
    for cut in [0, 1, 17, text.len()] {
        let mut d = Crc32::new();
        d.update(&text[..cut]);
        d.update(&text[cut..]);
        assert_eq!(d.finish(), 0x414F_A339, "cut at {cut}");
    }
}

#[test]
fn sha256_fips_180_vectors() {
    // FIPS 180-4 examples (NIST CSRC "SHA256.pdf").
    assert_eq!(
        sha256_hex(b"abc"),
        "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
    );
    assert_eq!(
        sha256_hex(b""),
        "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
    );
    assert_eq!(
        sha256_hex(b"abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"),
        "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1"
    );
    // One million 'a', fed in uneven pieces (streaming across blocks).
    let mut h = Sha256::new();
    let chunk = vec![b'a'; 997];
    let mut left = 1_000_000;
    while left > 0 {
        let n = left.min(chunk.len());
        h.update(&chunk[..n]);
        left -= n;
    }
    let digest: String = h.finish().iter().map(|b| format!("{b:02x}")).collect();
    assert_eq!(
        digest,
        "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0"
    );
    // Padding boundary: 55 and 56 bytes (one vs two final blocks).
    assert_eq!(
        sha256_hex(&[b'a'; 55]),
        "9f4390f8d30c2dd92ec9f095b65e2b9ae9b0a925a5258e241c9f1e910f734318"
    );
    assert_eq!(
        sha256_hex(&[b'a'; 56]),
        "b35439a4ac6f0948b6d6f9e3c6af0f5f590ce20f1bde7090ef7970686ec6738a"
    );
}

fn key(t: u32) -> TrialKey {
    TrialKey::new(1, Condition::P, Phase::Test, t)
}

fn all_records() -> Vec<Record> {
    vec![
        Record::SessionStarted(SessionStart {
            protocol_name: "paper-circling".into(),
            protocol_sha256: "ab".repeat(32),
            software_version: "0.1.0".into(),
            study_seed: (1 << 63) - 1,
            rig: "simulated \"rig\" #1".into(),
            calibration: Some(CalibrationRef {
                path: "/tmp/cal.toml".into(),
                sha256: "cd".repeat(32),
            }),
            orders: vec![OrderRow {
                participant: "P01".into(),
                index: 0,
                row: 2,
                sessions: vec![Condition::D, Condition::V, Condition::P],
            }],
            resumed: false,
            device: Some(DeviceRecord {
                spec: "serial:/dev/ttyACM0".into(),
                kind: "serial DAQ".into(),
                name: "kilotouch-daq".into(),
                serial: "KT-0001".into(),
                firmware: "0.1.0".into(),
                sample_rate_hz: 10_000.0,
                block_samples: 10,
                loop_delay_samples: 31,
                loop_delay_ms: 3.1,
                extra_latency_ms: 3.0,
                round_trip_ms: Some(0.8),
                tweezer: Some(TweezerDeviceRecord {
                    spec: "serial:/dev/ttyACM1".into(),
                    name: "kilotouch-tweezer".into(),
                    serial: "KT-T-0001".into(),
                    firmware: "0.1.0".into(),
                    lead_samples: 10,
                    lead_ms: 1.0,
                    round_trip_ms: Some(0.4),
                }),
            }),
        }),
        Record::Recovered(RecoveryRecord {
            journal_torn_bytes: 17,
            trials_torn_bytes: 0,
            adopted: vec![key(3)],
            interrupted: vec![key(4)],
        }),
        Record::TrialStarted {
            trial: key(1),
            seed: "0x0123456789abcdef".into(),
            started_utc: UtcTime::from_unix_millis(1_767_225_600_123),
        },
        Record::TrialCompleted {
            trial: key(1),
            row_crc32: "deadbeef".into(),
            adopted: false,
        },
        Record::TrialAborted {
            trial: key(2),
            reason: "participant asked to stop,\nthen continued".into(),
        },
        Record::Note {
            text: "µ-bead drifted; ünïcode ✓".into(),
        },
        Record::Paused {
            reason: String::new(),
        },
        Record::Resumed,
        Record::SessionDone {
            completed: 30,
            planned: 240,
            timing: Some(SittingTiming::judge(
                300_000, 30_000, 4, 0.0031, 2, 10, 1e-3,
            )),
        },
    ]
}

#[test]
fn every_record_round_trips_through_a_checksummed_json_line() {
    for (seq, record) in all_records().into_iter().enumerate() {
        let entry = Entry {
            seq: seq as u64,
            utc: UtcTime::from_unix_millis(1_767_225_600_000 + seq as i64),
            record,
        };
        let line = encode_line(&entry).unwrap();
        assert!(
            line.ends_with("\"}\n") && line.matches('\n').count() == 1,
            "{line}"
        );
        // Each line is a JSON object with seq, utc, type and crc32.
        let v: serde_json::Value = serde_json::from_str(&line).unwrap();
        assert_eq!(v["seq"], seq);
        assert!(v["type"].is_string());
        assert_eq!(v["utc"], entry.utc.to_string());
        // crc32 = CRC-32 of the object without its crc32 member, i.e. of
        // the serialised entry.
        let mut without = v.clone();
        let stored = without.as_object_mut().unwrap().remove("crc32").unwrap();
        let expected = format!(
            "{:08x}",
            crc32(serde_json::to_string(&entry).unwrap().as_bytes())
        );
        assert_eq!(stored, expected.as_str());
        assert_eq!(without, serde_json::to_value(&entry).unwrap());
        let text = line.trim_end_matches('\n');
        assert_eq!(decode_line(text.as_bytes()).unwrap(), entry);
        // Any changed character is caught.
        let mut bytes = text.as_bytes().to_vec();
        let i = bytes.len() / 2;
        bytes[i] = if bytes[i] == b'x' { b'y' } else { b'x' };
        assert!(decode_line(&bytes).is_err());
    }
    let line = encode_line(&Entry {
        seq: 0,
        utc: UtcTime::from_unix_millis(0),
        record: Record::Resumed,
    })
    .unwrap();
    assert_eq!(
        &line[..line.len() - 21],
        "{\"seq\":0,\"utc\":\"1970-01-01T00:00:00.000Z\",\"type\":\"resumed\""
    );
}

fn write_journal(path: &std::path::Path, n: usize) -> Vec<u8> {
    let rec = tempfile::tempdir().expect("test setup");
    let (mut j, read) = Journal::open(path, rec.path()).expect("test setup");
    assert!(read.entries.is_empty() && read.torn.is_none());
    for (i, r) in all_records().into_iter().cycle().take(n).enumerate() {
        let e = j.append(r).expect("test setup");
        assert_eq!(e.seq, i as u64);
    }
    fs::read(path).expect("test setup")
}

#[test]
fn torn_last_line_is_ignored_reported_and_cut() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("journal.jsonl");
    let good = write_journal(&path, 6);
    let good_lines = good.iter().filter(|&&b| b == b'\n').count();
    let next = encode_line(&Entry {
        seq: 6,
        utc: UtcTime::from_unix_millis(5),
        record: Record::Note {
            text: "x".repeat(80),
        },
    })
    .unwrap();
    // Every proper prefix of the next record, including one that stops just
    // before its newline, and a prefix followed by zero bytes (power loss
    // with delayed allocation).
    let cases: Vec<Vec<u8>> = (1..next.len())
        .map(|k| next.as_bytes()[..k].to_vec())
        .chain([
            [&next.as_bytes()[..40], &[0_u8; 300][..]].concat(),
            vec![0_u8; 4096],
            b"\n".to_vec(),
            // Complete line, wrong checksum.
            next.replace("xxxx", "xxxy").into_bytes(),
        ])
        .collect();
    for tail in cases {
        let bytes = [good.clone(), tail.clone()].concat();
        let read = parse_journal(&path, &bytes).unwrap();
        assert_eq!(read.entries.len(), 6);
        let torn = read.torn.expect("torn tail reported");
        assert_eq!(torn.offset, good.len() as u64);
        assert_eq!(torn.len, tail.len() as u64);
        assert_eq!(torn.line, good_lines as u64 + 1);
    }
    // Journal::open cuts it, keeps a copy, and appends after the last valid
    // record.
    fs::write(
        &path,
        [good.clone(), next.as_bytes()[..33].to_vec()].concat(),
    )
    .unwrap();
    let rec = dir.path().join("recovery");
    let (mut j, read) = Journal::open(&path, &rec).unwrap();
    let torn = read.torn.unwrap();
    let saved = torn.saved_to.unwrap();
    assert_eq!(fs::read(&saved).unwrap(), next.as_bytes()[..33].to_vec());
    assert_eq!(fs::read(&path).unwrap(), good);
    assert_eq!(j.next_seq(), 6);
    j.append(Record::Resumed).unwrap();
    let read = read_journal(&path).unwrap();
    assert_eq!(read.entries.len(), 7);
    assert!(read.torn.is_none());
}

#[test]
fn damage_before_valid_lines_is_an_error_not_a_torn_tail() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("journal.jsonl");
    let good = write_journal(&path, 5);
    let text = String::from_utf8(good).unwrap();
    let lines: Vec<&str> = text.lines().collect();

    // A changed byte in line 3.
    let mut damaged = lines.clone();
    let l3 = lines[2].replacen("trial", "trail", 1);
    damaged[2] = &l3;
    let bytes = format!("{}\n", damaged.join("\n"));
    let err = parse_journal(&path, bytes.as_bytes()).unwrap_err();
    assert!(
        matches!(&err, ExportError::Format { at, .. } if at.line == 3),
        "{err}"
    );
    assert!(err.to_string().contains("line 3"), "{err}");
    // The file is not touched by a failed open.
    fs::write(&path, &bytes).unwrap();
    assert!(Journal::open(&path, &dir.path().join("rec")).is_err());
    assert_eq!(fs::read(&path).unwrap(), bytes.as_bytes());

    // A removed line: sequence gap.
    let mut gap = lines.clone();
    gap.remove(1);
    let bytes = format!("{}\n", gap.join("\n"));
    let err = parse_journal(&path, bytes.as_bytes()).unwrap_err();
    assert!(matches!(err, ExportError::Inconsistent { .. }), "{err}");
    assert!(
        err.to_string().contains("sequence number 2 where 1"),
        "{err}"
    );
}

/// The study seed is written as a decimal string (a double-based reader
/// such as pandas would round 2⁶⁴ − 1 to 2⁶⁴); journals written before,
/// with a JSON number, still read.
#[test]
fn study_seed_is_text_and_old_numeric_seeds_still_read() {
    let Record::SessionStarted(mut start) = all_records().remove(0) else {
        panic!("first record is session_started")
    };
    start.study_seed = u64::MAX;
    let entry = Entry {
        seq: 0,
        utc: UtcTime::from_unix_millis(1_767_225_600_000),
        record: Record::SessionStarted(start),
    };
    let line = encode_line(&entry).unwrap();
    assert!(
        line.contains("\"study_seed\":\"18446744073709551615\""),
        "{line}"
    );
    assert_eq!(decode_line(line.trim_end().as_bytes()).unwrap(), entry);
    // The same record as an older version wrote it: a JSON number, with
    // its own checksum.
    let body = line.trim_end();
    let body = &body[..body.len() - 20];
    let old_json = format!("{body}}}").replace(
        "\"study_seed\":\"18446744073709551615\"",
        "\"study_seed\":18446744073709551615",
    );
    let crc = crc32(old_json.as_bytes());
    let old_line = format!(
        "{},\"crc32\":\"{crc:08x}\"}}",
        old_json.strip_suffix('}').unwrap()
    );
    assert_eq!(decode_line(old_line.as_bytes()).unwrap(), entry);
    // A seed that is no number is refused as an invalid record.
    let bad_json = format!("{body}}}").replace("18446744073709551615", "seventeen");
    let crc = crc32(bad_json.as_bytes());
    let bad_line = format!(
        "{},\"crc32\":\"{crc:08x}\"}}",
        bad_json.strip_suffix('}').unwrap()
    );
    assert!(decode_line(bad_line.as_bytes()).is_err());
}
