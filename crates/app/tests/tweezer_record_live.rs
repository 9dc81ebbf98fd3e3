//! `kilotouch tweezer record` over the block tweezer link, through the real
//! executable against `kilotouch emulate tweezer --pty` (its default
//! watchdog): records at 10 kHz hold while two CPU-bound processes run
//! alongside on the machine, and a link that fails mid-record (the
//! emulator gone, or hung) ends the record as a failure of the tweezer
//! link — not as an escape — with nothing written.
#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::{Emulator, kilotouch as run};
use std::process::{Child, Command, Stdio};

/// Processes that spin on the CPU until dropped.
struct Busy(Vec<Child>);

impl Busy {
    fn spawn(n: usize) -> Self {
        Self(
            (0..n)
                .map(|_| {
                    Command::new("sh")
                        .args(["-c", "while :; do :; done"])
                        .stdout(Stdio::null())
                        .spawn()
                        .expect("spawn a busy loop")
                })
                .collect(),
        )
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// Data rows of a record CSV (after its `#` comments and header).
/// `tweezer record` from `emu` for `seconds` into `out`, with `extra`.
fn record(
    emu: &Emulator,
    seconds: &str,
    out: &std::path::Path,
    extra: &[&str],
) -> std::process::Output {
    let rig = emu.rig();
    let mut args = vec![
        "tweezer",
        "record",
        "--rig",
        &rig,
        "--duration-s",
        seconds,
        "--out",
    ];
    args.push(out.to_str().unwrap());
    args.extend_from_slice(extra);
    run(&args)
}

fn rows(path: &std::path::Path) -> usize {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("t_s"))
        .count()
}

#[test]
fn records_at_10_khz_hold_with_two_cpu_bound_processes_alongside() {
    let _busy = Busy::spawn(2);
    let dir = tempfile::tempdir().unwrap();
    for i in 0..3 {
        let emu = Emulator::spawn("tweezer", &[]);
        let out = dir.path().join(format!("rec{i}.csv"));
        let o = record(&emu, "3", &out, &["--json"]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "record {i} failed under load: {err}");
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["n_samples"].as_u64(), Some(30_000), "{v}");
        assert_eq!(v["fs_hz"].as_f64(), Some(10_000.0), "{v}");
        // Blocks of 10 with the automatic lead (≥ one block), the round
        // trip measured at connection.
        assert_eq!(v["link"]["block_samples"].as_u64(), Some(10), "{v}");
        assert!(v["link"]["lead_samples"].as_u64().unwrap() >= 10, "{v}");
        assert!(v["link"]["round_trip_ms"].as_f64().unwrap() > 0.0, "{v}");
        assert_eq!(rows(&out), 30_000);
    }
}

/// The emulator disconnects (its pty closed, as when it is killed) or hangs
/// 1 s into a 5 s record: non-zero exit, an error naming the tweezer link
/// and the port, no escape reported, no file written.
#[test]
fn a_link_failure_mid_record_is_reported_as_a_link_failure() {
    let dir = tempfile::tempdir().unwrap();
    for (fault, said) in [
        ("--disconnect-after-s", "vanished"),
        ("--stall-after-s", "did not advance"),
    ] {
        let emu = Emulator::spawn("tweezer", &[fault, "1"]);
        let out = dir.path().join("rec.csv");
        let o = record(&emu, "5", &out, &[]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{fault}: the record must fail");
        assert!(
            err.contains("the tweezer link failed at sample"),
            "{fault}: {err}"
        );
        assert!(err.contains("the record is incomplete"), "{fault}: {err}");
        assert!(
            err.contains(&emu.path) && err.contains(said),
            "{fault}: {err}"
        );
        assert!(!err.contains("not trapped"), "{fault}: {err}");
        assert!(!err.contains("panicked"), "{fault}: {err}");
        assert!(!out.exists(), "{fault}: partial data written");
    }
}
