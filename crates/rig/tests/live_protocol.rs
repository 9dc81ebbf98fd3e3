//! Serial protocol without a transport: the decoder under arbitrary byte
//! streams (proptest), and the device emulator's logic (pacing, batching,
//! waiting for commands, catch-up, watchdog, fault injection).

#![allow(clippy::unwrap_used)]

use kilotouch_rig::config::RigConfig;
use kilotouch_rig::device::{ActuatorFrame, Rig, SensorFrame};
use kilotouch_rig::serial::emulator::{
    DaqInstrument, Emulator, EmulatorConfig, FaultInjection, Next, code_to_value, value_to_code,
};
use kilotouch_rig::serial::frame::{self, DaqCommand, DaqSample, Decoder, DeviceState, ty};
use kilotouch_rig::sim::SimRig;
use proptest::prelude::*;
use proptest::test_runner::RngSeed;
use std::time::Duration;

// ---------------------------------------------------------------- decoder

fn encode(frames: &[(u8, Vec<u8>)]) -> (Vec<u8>, Vec<std::ops::Range<usize>>) {
    let mut out = Vec::new();
    let mut spans = Vec::new();
    for (t, p) in frames {
        let a = out.len();
        frame::write_frame(&mut out, *t, |o| o.extend_from_slice(p));
        spans.push(a..out.len());
    }
    (out, spans)
}

/// Feed `bytes` in chunks of the given sizes (cycled); collect frames.
fn decode(bytes: &[u8], chunks: &[usize], dec: &mut Decoder) -> Vec<(u8, Vec<u8>)> {
    let mut got = Vec::new();
    let mut rest = bytes;
    let mut k = 0;
    while !rest.is_empty() {
        let want = chunks[k % chunks.len()].max(1).min(rest.len());
        k += 1;
        let mut chunk = &rest[..want];
        rest = &rest[want..];
        while !chunk.is_empty() {
            let n = dec.push(chunk);
            chunk = &chunk[n..];
            assert!(dec.buffered() <= Decoder::CAPACITY);
            while let Some(f) = dec.next_frame() {
                got.push((f.ty, f.payload.to_vec()));
            }
            // After next_frame returned None a whole frame always fits.
            assert!(Decoder::CAPACITY - dec.buffered() >= frame::MAX_FRAME);
        }
    }
    got
}

fn frames_strategy() -> impl Strategy<Value = Vec<(u8, Vec<u8>)>> {
    prop::collection::vec(
        (
            any::<u8>(),
            prop_oneof![
                4 => prop::collection::vec(any::<u8>(), 0..64),
                1 => prop::collection::vec(any::<u8>(), 0..=frame::MAX_PAYLOAD),
                // Payloads full of sync bytes.
                1 => prop::collection::vec(prop_oneof![Just(0xA5u8), Just(0x5A)], 0..40),
            ],
        ),
        1..30,
    )
}

#[derive(Debug, Clone)]
enum Damage {
    Flip(usize, u8),
    Drop(usize),
    Insert(usize, u8),
}

fn damage_strategy() -> impl Strategy<Value = Vec<Damage>> {
    prop::collection::vec(
        prop_oneof![
            (any::<usize>(), 1..=255u8).prop_map(|(p, x)| Damage::Flip(p, x)),
            any::<usize>().prop_map(Damage::Drop),
            (any::<usize>(), any::<u8>()).prop_map(|(p, b)| Damage::Insert(p, b)),
        ],
        0..8,
    )
}

fn config() -> ProptestConfig {
    // Fixed seed: a CRC-16 collision (probability 2⁻¹⁶ per damaged frame)
    // would otherwise make the exact-match property flaky.
    ProptestConfig {
        cases: 192,
        rng_seed: RngSeed::Fixed(0x6b69_6c6f),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

proptest! {
    #![proptest_config(config())]

    /// Any byte stream: no panic, bounded buffer, and whatever is decoded
    /// passes its CRC.
    #[test]
    fn random_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..6000),
                                chunks in prop::collection::vec(1usize..700, 1..8)) {
        let mut d = Decoder::new();
        for (t, p) in decode(&bytes, &chunks, &mut d) {
            // Re-encode: a frame the decoder accepted is a valid frame.
            let (enc, _) = encode(&[(t, p.clone())]);
            let mut d2 = Decoder::new();
            d2.push(&enc);
            let f = d2.next_frame().unwrap();
            prop_assert_eq!((f.ty, f.payload), (t, &p[..]));
        }
    }

    /// A valid stream split at arbitrary chunk boundaries decodes exactly.
    #[test]
    fn valid_streams_decode_exactly_at_any_split(frames in frames_strategy(),
                                                 chunks in prop::collection::vec(1usize..300, 1..10)) {
        let (bytes, _) = encode(&frames);
        let mut d = Decoder::new();
        let got = decode(&bytes, &chunks, &mut d);
        prop_assert_eq!(&got, &frames);
        prop_assert_eq!(d.stats().crc_errors, 0);
        prop_assert_eq!(d.stats().bytes_skipped, 0);
    }

    /// Corrupted, dropped and inserted bytes: every frame the damage did
    /// not touch is decoded, in order, and nothing else (resync on the next
    /// valid frame); damaged frames are counted as CRC errors or skipped.
    #[test]
    fn damaged_streams_resync_on_the_next_valid_frame(frames in frames_strategy(),
                                                      damage in damage_strategy(),
                                                      chunks in prop::collection::vec(1usize..300, 1..10),
                                                      garbage in prop::collection::vec(any::<u8>(), 0..50)) {
        let (bytes, spans) = encode(&frames);
        let n = bytes.len();
        let mut touched = vec![false; frames.len()];
        let mut flip = vec![0u8; n];
        let mut drop = vec![false; n];
        let mut insert: Vec<Vec<u8>> = vec![Vec::new(); n + 1];
        for d in &damage {
            let (p, kind) = match d {
                Damage::Flip(p, x) => { let p = p % n; flip[p] ^= x; (p, 0) }
                Damage::Drop(p) => { let p = p % n; drop[p] = true; (p, 1) }
                Damage::Insert(p, b) => { let p = p % (n + 1); insert[p].push(*b); (p, 2) }
            };
            for (i, s) in spans.iter().enumerate() {
                let inside = if kind == 2 { p > s.start && p < s.end } else { s.contains(&p) };
                if inside { touched[i] = true; }
            }
        }
        // Two flips of one byte may cancel: then the frame is intact.
        for (i, s) in spans.iter().enumerate() {
            if touched[i] && damage.iter().all(|d| matches!(d, Damage::Flip(..)))
                && s.clone().all(|p| flip[p] == 0) {
                touched[i] = false;
            }
        }
        let mut stream = garbage.clone();
        for p in 0..n {
            stream.extend_from_slice(&insert[p]);
            if !drop[p] { stream.push(bytes[p] ^ flip[p]); }
        }
        stream.extend_from_slice(&insert[n]);
        let intact: Vec<(u8, Vec<u8>)> = frames.iter().zip(&touched)
            .filter(|(_, t)| !**t).map(|(f, _)| f.clone()).collect();
        let mut d = Decoder::new();
        let got = decode(&stream, &chunks, &mut d);
        // The garbage prefix may by chance end in a valid-looking prefix of
        // nothing: it can never produce a frame (CRC), so equality holds.
        prop_assert_eq!(&got, &intact);
    }
}

// ---------------------------------------------------------------- emulator

fn cfg() -> EmulatorConfig {
    EmulatorConfig {
        watchdog: Duration::from_secs(1),
        ..EmulatorConfig::default()
    }
}

fn emulator(c: EmulatorConfig) -> Emulator<DaqInstrument> {
    let inst = DaqInstrument::new(&RigConfig::default()).unwrap();
    Emulator::new(inst, c, Duration::ZERO).unwrap()
}

fn ms(x: f64) -> Duration {
    Duration::from_secs_f64(x * 1e-3)
}

/// Decode everything the emulator has queued.
fn drain(emu: &mut Emulator<DaqInstrument>) -> Vec<(u8, Vec<u8>)> {
    let bytes = emu.output().to_vec();
    emu.consume_output(bytes.len());
    let mut d = Decoder::new();
    decode(&bytes, &[4096], &mut d)
}

fn host(ty_: u8, body: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut v = Vec::new();
    frame::write_frame(&mut v, ty_, body);
    v
}

fn commands(first: u32, cmds: &[DaqCommand]) -> Vec<u8> {
    let mut v = Vec::new();
    for (k, c) in cmds.chunks(32).enumerate() {
        frame::write_block(&mut v, ty::COMMANDS, first + 32 * k as u32, c);
    }
    v
}

fn samples(frames: &[(u8, Vec<u8>)]) -> Vec<(u64, DaqSample)> {
    let mut out = Vec::new();
    for (t, p) in frames {
        if *t == ty::SAMPLES {
            let (s, n) = frame::block_header::<DaqSample>(p).unwrap();
            for i in 0..n {
                out.push((u64::from(s) + i as u64, frame::block_item(p, i)));
            }
        }
    }
    out
}

#[test]
fn emulator_paces_by_the_clock_waits_for_commands_and_batches() {
    let mut e = emulator(cfg());
    e.receive(&host(ty::START, |_| {}), Duration::ZERO);
    let f = drain(&mut e);
    let st = frame::parse_status(&f.last().unwrap().1).unwrap();
    assert_eq!((st.state, st.next_seq), (DeviceState::Running, 0));
    // Commands for 1000 samples (100 ms at 10 kHz).
    let cmds = vec![DaqCommand::default(); 1000];
    e.receive(&commands(0, &cmds), Duration::ZERO);
    // Sample t is due at (t + 1)/fs: at 25.05 ms, 250 samples are due.
    e.advance(ms(25.05));
    assert_eq!(e.next_seq(), 250);
    let out = drain(&mut e);
    let s = samples(&out);
    assert_eq!(s.len(), 250);
    assert!(s.iter().enumerate().all(|(i, (q, _))| *q == i as u64));
    // Full frames of 10 samples only (no partial frame while commands remain).
    assert!(
        out.iter()
            .filter(|(t, _)| *t == ty::SAMPLES)
            .all(|(_, p)| frame::block_header::<DaqSample>(p).unwrap().1 == 10)
    );
    // The next wake-up is when the next frame is full: sample 259 due at 26 ms.
    match e.advance(ms(25.05)) {
        Next::WakeAt(t) => assert!((t.as_secs_f64() - 26e-3).abs() < 1e-9, "{t:?}"),
        Next::Disconnect => panic!(),
    }
    // A stall of 60 ms: everything due is caught up at once, and the device
    // then waits for commands (partial frame + STATUS with next_seq).
    e.advance(ms(95.0));
    assert_eq!(e.next_seq(), 950);
    e.advance(ms(150.0));
    assert_eq!(e.next_seq(), 1000, "no command → no sample");
    let out = drain(&mut e);
    let (t, p) = out.last().unwrap();
    assert_eq!(*t, ty::STATUS);
    assert_eq!(frame::parse_status(p).unwrap().next_seq, 1000);
    assert_eq!(samples(&out).len(), 750);
    // Late commands are executed as soon as they arrive (simulated time
    // waited), and the device catches up with the clock.
    e.receive(&commands(1000, &cmds[..300]), ms(151.0));
    e.advance(ms(151.0));
    assert_eq!(e.next_seq(), 1300);
    assert_eq!(e.stats().late_commands, 0);
}

/// `speed` scales the emulator's clock: at 4, sample t is due at
/// (t + 1)/(4·fs) of wall time, the HELLO still announcing fs.
#[test]
fn a_faster_clock_serves_samples_at_speed_times_the_rate() {
    let mut e = emulator(EmulatorConfig {
        speed: 4.0,
        ..cfg()
    });
    e.receive(&host(ty::START, |_| {}), Duration::ZERO);
    drain(&mut e);
    let cmds = vec![DaqCommand::default(); 1000];
    e.receive(&commands(0, &cmds), Duration::ZERO);
    // 25.05 ms of wall time: 4 × 250 = 1000 samples due.
    e.advance(ms(6.2625));
    assert_eq!(e.next_seq(), 250);
    e.advance(ms(25.05));
    assert_eq!(e.next_seq(), 1000);
    assert_eq!(samples(&drain(&mut e)).len(), 1000);
    assert!(
        EmulatorConfig {
            speed: 0.0,
            ..cfg()
        }
        .validate()
        .is_err(),
        "a stopped clock is refused"
    );
    assert!(
        EmulatorConfig {
            speed: 50.0,
            ..cfg()
        }
        .validate()
        .is_err()
    );
}

#[test]
fn emulator_output_equals_the_simulated_rig_sample_for_sample() {
    // Reference: the simulated rig driven directly with the same commands.
    let rc = RigConfig::default();
    let mut reference = SimRig::new(&rc).unwrap();
    reference.start().unwrap();
    let (fmax, vmax) = (
        rc.limits.pantograph_force_max_n,
        rc.limits.haptuator_drive_max_v,
    );
    let n = 2000;
    let cmds: Vec<DaqCommand> = (0..n)
        .map(|i| {
            let t = i as f64 / 1e4;
            DaqCommand {
                force: [
                    value_to_code(
                        0.4 * fmax * (2.0 * std::f64::consts::PI * 40.0 * t).sin(),
                        fmax,
                    )
                    .0,
                    value_to_code(-0.1 * fmax, fmax).0,
                ],
                drive: value_to_code(
                    0.5 * vmax * (2.0 * std::f64::consts::PI * 300.0 * t).sin(),
                    vmax,
                )
                .0,
            }
        })
        .collect();
    let frames_in: Vec<ActuatorFrame> = cmds
        .iter()
        .map(|c| ActuatorFrame {
            force_n: c.force.map(|k| code_to_value(k, fmax)),
            haptuator_v: code_to_value(c.drive, vmax),
        })
        .collect();
    let mut want = vec![SensorFrame::default(); n];
    reference.process_block(&frames_in, &mut want).unwrap();

    let mut e = emulator(cfg());
    e.receive(&host(ty::START, |_| {}), Duration::ZERO);
    e.receive(&commands(0, &cmds), Duration::ZERO);
    e.advance(ms(250.0));
    let got = samples(&drain(&mut e));
    assert_eq!(got.len(), n);
    let caps = e.instrument().caps();
    let mut moved = 0.0f64;
    for ((q, s), w) in got.iter().zip(&want) {
        assert_eq!(*q, w.seq);
        for k in 0..3 {
            assert_eq!(
                f64::from(s.acc[k]) * caps.accel_m_s2_per_code,
                w.accel_m_s2[k],
                "seq {q}"
            );
        }
        for k in 0..2 {
            let h = f64::from(s.enc[k]) / caps.encoder_counts_per_m;
            assert!(
                (h - w.handle_m[k]).abs() <= 1e-12,
                "seq {q}: {h} vs {}",
                w.handle_m[k]
            );
            moved = moved.max(w.handle_m[k].abs());
        }
        assert_eq!(s.flags & 0x1E, w.flags.0 & 0x1E);
    }
    assert!(
        moved > 0.0,
        "the drive must move the handle for the test to mean anything"
    );
}

#[test]
fn watchdog_zeroes_the_outputs_when_the_host_goes_silent() {
    let c = EmulatorConfig {
        watchdog: Duration::from_millis(50),
        ..cfg()
    };
    let mut e = emulator(c);
    e.receive(&host(ty::START, |_| {}), Duration::ZERO);
    let on = DaqCommand {
        force: [20_000, -20_000],
        drive: 10_000,
    };
    e.receive(&commands(0, &[on; 100]), ms(1.0));
    e.advance(ms(20.0));
    assert_eq!(*e.applied(), on);
    assert_eq!(e.state(), DeviceState::Running);
    drain(&mut e);
    // Silent host: the commands run out when sample 100 is due (10.1 ms);
    // still running just inside the window from then …
    e.advance(ms(60.05));
    assert_eq!(e.state(), DeviceState::Running);
    assert_eq!(*e.applied(), on, "held while waiting");
    // … tripped once the window has passed: outputs zero, FAULT + STATUS.
    e.advance(ms(60.15));
    assert_eq!(e.state(), DeviceState::Tripped);
    assert_eq!(*e.applied(), DaqCommand::default());
    assert_eq!(e.stats().watchdog_trips, 1);
    let out = drain(&mut e);
    let f = out.iter().find(|(t, _)| *t == ty::FAULT).unwrap();
    assert_eq!(
        frame::parse_fault(&f.1).unwrap().code,
        frame::fault::WATCHDOG
    );
    let (t, p) = out.last().unwrap();
    assert_eq!(*t, ty::STATUS);
    assert_eq!(frame::parse_status(p).unwrap().state, DeviceState::Tripped);
    // Tripped: commands are refused and nothing runs until START.
    e.receive(&commands(100, &[on; 10]), ms(60.0));
    e.advance(ms(80.0));
    assert_eq!(e.next_seq(), 100);
    assert_eq!(*e.applied(), DaqCommand::default());
    let out = drain(&mut e);
    assert!(out.iter().any(|(t, p)| *t == ty::FAULT
        && frame::parse_fault(p).unwrap().code == frame::fault::NOT_RUNNING));
    // Heartbeats alone keep a waiting device from tripping.
    e.receive(&host(ty::START, |_| {}), ms(100.0));
    for k in 1..10 {
        e.receive(
            &host(ty::HEARTBEAT, |o| {
                o.extend_from_slice(&(k as u32).to_le_bytes())
            }),
            ms(100.0 + 30.0 * f64::from(k)),
        );
        e.advance(ms(100.0 + 30.0 * f64::from(k) + 1.0));
        assert_eq!(e.state(), DeviceState::Running);
    }
}

#[test]
fn fault_injection_damages_the_stream_at_the_requested_rates() {
    let c = EmulatorConfig {
        faults: FaultInjection {
            corrupt_rate: 1e-3,
            drop_rate: 5e-4,
            seed: 7,
            ..FaultInjection::default()
        },
        ..cfg()
    };
    let mut e = emulator(c);
    e.receive(&host(ty::START, |_| {}), Duration::ZERO);
    let cmds = vec![DaqCommand::default(); 5000];
    e.receive(&commands(0, &cmds), Duration::ZERO);
    e.advance(ms(600.0));
    let st = e.stats();
    let bytes = e.output().len() as u64;
    let sent = bytes + st.bytes_dropped;
    // Binomial counts: within 5 standard deviations of the rates.
    let check = |count: u64, n: u64, p: f64| {
        let (m, sd) = (n as f64 * p, (n as f64 * p * (1.0 - p)).sqrt());
        assert!((count as f64 - m).abs() < 5.0 * sd, "{count} vs {m} ± {sd}");
    };
    check(st.bytes_dropped, sent, 5e-4);
    check(st.bytes_corrupted, sent - st.bytes_dropped, 1e-3);
    // The decoder survives and keeps the frames that were not hit: a
    // 162-byte frame of 10 samples survives with probability
    // (1 − 1.5e-3)^162 ≈ 0.78.
    let out = drain(&mut e);
    let got = samples(&out);
    let frac = got.len() as f64 / 5000.0;
    assert!((0.65..0.9).contains(&frac), "{}", got.len());
    assert!(got.windows(2).all(|w| w[0].0 < w[1].0));
}

#[test]
fn injected_stall_and_disconnect() {
    let c = EmulatorConfig {
        faults: FaultInjection {
            stall_after: Some(ms(10.05)),
            stall_for: Some(ms(20.0)),
            disconnect_after: Some(ms(100.0)),
            ..FaultInjection::default()
        },
        ..cfg()
    };
    let mut e = emulator(c);
    e.receive(&host(ty::START, |_| {}), Duration::ZERO);
    e.receive(
        &commands(0, &vec![DaqCommand::default(); 1000]),
        Duration::ZERO,
    );
    e.advance(ms(10.0));
    let n0 = e.next_seq();
    assert_eq!(n0, 100);
    e.advance(ms(25.0));
    assert_eq!(e.next_seq(), n0, "stalled");
    let before = e.stats().host_frames;
    e.receive(
        &host(ty::HEARTBEAT, |o| o.extend_from_slice(&[0; 4])),
        ms(25.0),
    );
    assert_eq!(
        e.stats().host_frames,
        before,
        "input during the stall is lost"
    );
    e.advance(ms(31.0));
    assert_eq!(e.next_seq(), 310, "resumed and caught up");
    assert_eq!(e.advance(ms(100.0)), Next::Disconnect);
}

/// A host that exchanges blocks of 10 samples (1 ms) with a device whose
/// every outgoing byte is corrupted with probability 1 % (about 80 % of
/// the sample frames lost), in simulated time: each block is accounted
/// for — received, or reported executed by the STATUS the waiting device
/// repeats every 10 ms — long before the device's 100 ms watchdog, over
/// 20 s of blocks. A corrupted LEN that claimed more bytes than the device
/// sends before it waits for the host would stall the exchange until the
/// watchdog tripped.
#[test]
fn a_heavily_corrupted_link_keeps_exchanging_blocks() {
    let c = EmulatorConfig {
        faults: FaultInjection {
            corrupt_rate: 1e-2,
            seed: 11,
            ..FaultInjection::default()
        },
        ..EmulatorConfig::default()
    };
    let watchdog = c.watchdog;
    let mut e = emulator(c);
    let mut dec = Decoder::new();
    let step = ms(0.1);
    let mut now = Duration::ZERO;
    e.receive(&host(ty::START, |_| {}), now);
    let (mut received, mut lost, mut worst) = (0u64, 0u64, Duration::ZERO);
    let block = [DaqCommand::default(); 10];
    for k in 0..20_000u32 {
        let (first, end) = (10 * k, 10 * u64::from(k) + 10);
        let sent = now;
        e.receive(&commands(first, &block), now);
        let mut accounted = u64::from(first);
        while accounted < end {
            now += step;
            assert!(now - sent < watchdog, "block {k} waited {:?}", now - sent);
            e.advance(now);
            let mut bytes = e.output();
            let n = bytes.len();
            while !bytes.is_empty() {
                let took = dec.push(bytes);
                bytes = &bytes[took..];
                while let Some(f) = dec.next_frame() {
                    let last = match f.ty {
                        ty::SAMPLES => {
                            let (s, m) = frame::block_header::<DaqSample>(f.payload).unwrap();
                            let s = u64::from(s);
                            if s >= accounted && s < end {
                                lost += s - accounted;
                                received += m as u64;
                            }
                            s + m as u64
                        }
                        ty::STATUS => u64::from(frame::parse_status(f.payload).unwrap().next_seq),
                        ty::FAULT => panic!("device fault at block {k}"),
                        _ => 0,
                    };
                    if last > accounted && last <= end {
                        lost += if f.ty == ty::STATUS {
                            last - accounted
                        } else {
                            0
                        };
                        accounted = last;
                    }
                }
            }
            e.consume_output(n);
        }
        worst = worst.max(now - sent);
    }
    assert_eq!(e.stats().watchdog_trips, 0);
    assert_eq!(e.state(), DeviceState::Running);
    assert_eq!(received + lost, 200_000);
    // The damage was heavy: most sample frames were lost.
    assert!(lost > 100_000, "lost {lost} of 200000");
    eprintln!("received {received}, lost {lost}, longest wait {worst:?}");
}
