//! The serial link's soak, alone in its binary because it takes a minute:
//! `kilotouch rig check` over the emulator's pty streams 10 kHz for 60 s
//! with no lost frame.

use kilotouch_testkit as common;

use common::{Emulator, json_ok};

#[test]
fn rig_check_streams_10_khz_for_60_s_with_no_lost_frame() {
    // Generous watchdog and host timeout: a shared CI machine may
    // deschedule either process for tens of ms; what is under test is
    // the stream (rate, lost frames), not the fault timing.
    let emu = Emulator::spawn("daq", &["--watchdog-ms", "1000"]);
    let rig = format!("{},timeout-ms=1000", emu.rig());
    let v = json_ok(&["rig", "check", "--rig", &rig, "--duration", "60", "--json"]);
    drop(emu);
    eprintln!("60 s acceptance: {v}");
    assert_eq!(v["lost"].as_u64(), Some(0), "{v}");
    assert_eq!(v["crc_errors"].as_u64(), Some(0), "{v}");
    let rate = v["rate_hz"].as_f64().unwrap();
    assert!((rate - 10_000.0).abs() < 0.005 * 10_000.0, "rate {rate}");
    assert!(v["frames"].as_u64().unwrap() >= 600_000, "{v}");
}
