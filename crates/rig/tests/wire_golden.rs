//! The host's frames are byte-identical to those of the implementation
//! before the wire moved into the `kilotouch-proto` crate: every message
//! type, sample and command blocks of each item type (full, partial, over
//! long), strings cut at 255 bytes, against `data/wire_golden.hex`, which
//! the previous implementation wrote with this same test
//! (`KILOTOUCH_WRITE_GOLDEN=1`).

#![allow(clippy::unwrap_used)]

use kilotouch_rig::serial::frame::{
    self, Caps, DaqCaps, DaqCommand, DaqSample, DeviceState, FaultReport, Hello, Status,
    TrapCommand, TweezerCaps, TweezerWireSample, ty,
};

fn frames() -> Vec<u8> {
    let mut out = Vec::new();
    frame::write_frame(&mut out, ty::START, |_| {});
    frame::write_frame(&mut out, ty::HELLO_REQ, |o| {
        o.extend_from_slice(&2u16.to_le_bytes())
    });
    frame::write_frame(&mut out, ty::HEARTBEAT, |o| {
        o.extend_from_slice(&77u32.to_le_bytes())
    });
    // Payload longer than the limit: truncated to a valid frame.
    frame::write_frame(&mut out, 0x7E, |o| o.extend((0..1100u32).map(|i| i as u8)));
    let daq = Hello {
        version: 2,
        sample_rate_hz: 10_000,
        watchdog_ms: 100,
        batch: 10,
        caps: Caps::Daq(DaqCaps {
            encoder_counts_per_m: 1e7,
            accel_m_s2_per_code: 1.4528e-2,
            accel_range_m_s2: 58.8399,
            force_max_n: 5.0,
            drive_max_v: -0.0,
        }),
        name: "rig é ✓".into(),
        serial: "x".repeat(254) + "é",
        firmware: String::new(),
    };
    frame::write_hello(&mut out, &daq);
    let tw = Hello {
        caps: Caps::Tweezer(TweezerCaps {
            stiffness_n_per_m: 2.5e-5,
        }),
        name: "ü".repeat(200),
        ..daq.clone()
    };
    frame::write_hello(&mut out, &tw);
    for state in [
        DeviceState::Idle,
        DeviceState::Running,
        DeviceState::Tripped,
    ] {
        frame::write_status(
            &mut out,
            &Status {
                next_seq: 0xFFFF_FFF0,
                state,
                host_frames: 1,
                host_crc_errors: 2,
                late_commands: 0x0102_0304,
            },
        );
    }
    frame::write_fault(
        &mut out,
        &FaultReport {
            code: frame::fault::OVERFLOW,
            seq: 123_456,
        },
    );
    let cmds: Vec<DaqCommand> = (0..200)
        .map(|i| DaqCommand {
            force: [i * 160 - 16000, -32768 + i],
            drive: i * 37,
        })
        .collect();
    for n in [0, 1, 32, 200] {
        frame::write_block(&mut out, ty::COMMANDS, 0x0102_0304 + n as u32, &cmds[..n]);
    }
    let samples: Vec<DaqSample> = (0..80)
        .map(|i| DaqSample {
            enc: [i * 1000 - 40_000, -i * 77],
            acc: [i as i16, -(i as i16) * 400, 32767],
            flags: (i as u8) & 0x7E,
        })
        .collect();
    for n in [1, 10, 80] {
        frame::write_block(&mut out, ty::SAMPLES, 99, &samples[..n]);
    }
    let traps: Vec<TrapCommand> = (0..3)
        .map(|i| TrapCommand {
            trap_m: [1e-6 * f64::from(i), -2.5e-7],
        })
        .collect();
    frame::write_block(&mut out, ty::TRAP, 5, &traps);
    frame::write_frame(&mut out, ty::RESET, |o| {
        o.extend_from_slice(&1e-6f64.to_le_bytes());
        o.extend_from_slice(&(-1e-6f64).to_le_bytes());
    });
    let tws: Vec<TweezerWireSample> = (0..40)
        .map(|i| TweezerWireSample {
            bead_m: [1e-8 * f64::from(i), f64::NAN],
            sum_v: 0.5,
            detector_v: [f32::from(i as u8) * 0.01, -1.0],
            status: i as u8 & 0x7F,
        })
        .collect();
    frame::write_block(&mut out, ty::TWEEZER_SAMPLES, u32::MAX, &tws);
    out
}

fn hex(b: &[u8]) -> String {
    let mut s = String::new();
    for line in b.chunks(32) {
        for x in line {
            s.push_str(&format!("{x:02x}"));
        }
        s.push('\n');
    }
    s
}

#[test]
fn frames_are_byte_identical_to_the_previous_implementation() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/wire_golden.hex");
    let got = hex(&frames());
    if std::env::var_os("KILOTOUCH_WRITE_GOLDEN").is_some() {
        std::fs::write(path, &got).unwrap();
    }
    let want = std::fs::read_to_string(path).unwrap();
    assert_eq!(got.len(), want.len(), "stream length differs");
    for (i, (g, w)) in got.lines().zip(want.lines()).enumerate() {
        assert_eq!(g, w, "bytes {}..{} differ", 32 * i, 32 * i + 32);
    }
}
