//! The serial rig over a real pseudo-terminal, with the device emulator
//! served in a thread of the test (the tweezer link: `live_tweezer.rs`): frame-for-frame equality
//! with the simulated rig, lost and corrupted frames, stalls, vanished
//! devices, the device watchdog, reconnects.

#![allow(clippy::unwrap_used)]

use kilotouch_rig::config::RigConfig;
use kilotouch_rig::device::{ActuatorFrame, FrameFlags, Rig, RigFault, RigState, SensorFrame};
use kilotouch_rig::error::RigError;
use kilotouch_rig::serial::emulator::{
    DaqInstrument, EmulatorConfig, FaultInjection, Misbehaviour, code_to_value,
};
use kilotouch_rig::serial::frame::DaqCommand;
use kilotouch_rig::serial::{SerialConfig, SerialRig};
use kilotouch_rig::sim::SimRig;
use std::f64::consts::PI;
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::common;
use common::Device;

fn daq(cfg: EmulatorConfig) -> Device<DaqInstrument> {
    Device::spawn(DaqInstrument::new(&RigConfig::default()).unwrap(), cfg)
}

fn emu_cfg() -> EmulatorConfig {
    EmulatorConfig {
        watchdog: Duration::from_millis(500),
        ..EmulatorConfig::default()
    }
}

/// Commands that are exact output codes (so the device applies exactly
/// what the reference rig gets).
fn commands(n: usize, start: usize) -> Vec<ActuatorFrame> {
    let rc = RigConfig::default();
    let (fmax, vmax) = (
        rc.limits.pantograph_force_max_n,
        rc.limits.haptuator_drive_max_v,
    );
    (start..start + n)
        .map(|i| {
            let t = i as f64 / rc.rig.sample_rate_hz;
            let q = |v: f64, max: f64| {
                code_to_value(
                    kilotouch_rig::serial::emulator::value_to_code(v, max).0,
                    max,
                )
            };
            ActuatorFrame {
                force_n: [q(0.3 * fmax * (2.0 * PI * 30.0 * t).sin(), fmax), 0.0],
                haptuator_v: q(0.4 * vmax * (2.0 * PI * 250.0 * t).sin(), vmax),
            }
        })
        .collect()
}

fn assert_same(got: &SensorFrame, want: &SensorFrame) {
    assert_eq!(got.seq, want.seq);
    assert_eq!(got.accel_m_s2, want.accel_m_s2, "seq {}", got.seq);
    for k in 0..2 {
        assert!(
            (got.handle_m[k] - want.handle_m[k]).abs() <= 1e-12,
            "seq {}: {:?} vs {:?}",
            got.seq,
            got.handle_m,
            want.handle_m
        );
    }
    assert_eq!(got.flags, want.flags, "seq {}", got.seq);
}

#[test]
fn serial_rig_matches_the_simulated_rig_frame_for_frame() {
    let dev = daq(emu_cfg());
    let mut rig = SerialRig::open(&SerialConfig::new(&dev.path)).unwrap();
    let id = rig.identity().clone();
    assert_eq!(id.sample_rate_hz, 10_000.0);
    assert_eq!(
        id.force_max_n,
        RigConfig::default().limits.pantograph_force_max_n
    );
    assert!(id.firmware.contains("emulate daq"));
    let mut reference = SimRig::new(&RigConfig::default()).unwrap();
    reference.start().unwrap();
    rig.start().unwrap();
    let mut at = 0;
    for n in [1usize, 7, 64, 256, 100, 33, 1000] {
        let cmds = commands(n, at);
        let mut got = vec![SensorFrame::default(); n];
        let mut want = vec![SensorFrame::default(); n];
        let r = rig.process_block(&cmds, &mut got).unwrap();
        reference.process_block(&cmds, &mut want).unwrap();
        assert_eq!((r.first_seq, r.frames, r.lost_frames), (at as u64, n, 0));
        for (g, w) in got.iter().zip(&want) {
            assert_same(g, w);
        }
        at += n;
    }
    // Over-limit and non-finite commands are clamped/zeroed and flagged on
    // the host, like the simulated rig does.
    let fmax = id.force_max_n;
    let bad = [
        ActuatorFrame {
            force_n: [2.0 * fmax, -2.0 * fmax],
            haptuator_v: 0.0,
        },
        ActuatorFrame {
            force_n: [f64::NAN, 0.0],
            haptuator_v: f64::INFINITY,
        },
    ];
    let mut got = [SensorFrame::default(); 2];
    let mut want = [SensorFrame::default(); 2];
    rig.process_block(&bad, &mut got).unwrap();
    reference.process_block(&bad, &mut want).unwrap();
    for (g, w) in got.iter().zip(&want) {
        assert_same(g, w);
    }
    assert!(got[0].flags.has(FrameFlags::LIMITED));
    assert!(got[1].flags.has(FrameFlags::NONFINITE_COMMAND));
    let st = rig.status();
    assert_eq!(st.frames, at as u64 + 2);
    assert_eq!(
        (st.lost_frames, st.limited_frames, st.nonfinite_commands),
        (0, 1, 1)
    );
    let ls = rig.link_stats();
    assert_eq!((ls.crc_errors, ls.lost, ls.bytes_skipped), (0, 0, 0));
    rig.stop().unwrap();
    let emu = dev.finish();
    assert_eq!(emu.stats().samples, at as u64 + 2);
    assert_eq!(
        *emu.applied(),
        DaqCommand::default(),
        "STOP zeroes the outputs"
    );
}

#[test]
fn lost_and_corrupted_frames_are_counted_and_survived() {
    let dev = daq(EmulatorConfig {
        faults: FaultInjection {
            corrupt_rate: 3e-4,
            drop_rate: 3e-4,
            seed: 11,
            ..FaultInjection::default()
        },
        ..emu_cfg()
    });
    let mut rig = SerialRig::open(&SerialConfig::new(&dev.path)).unwrap();
    let mut reference = SimRig::new(&RigConfig::default()).unwrap();
    reference.start().unwrap();
    rig.start().unwrap();
    let n = 100;
    let (mut lost, mut total) = (0u64, 0u64);
    let mut last_good: Option<SensorFrame> = None;
    for b in 0..150 {
        let cmds = commands(n, b * n);
        let mut got = vec![SensorFrame::default(); n];
        let mut want = vec![SensorFrame::default(); n];
        let r = rig.process_block(&cmds, &mut got).unwrap();
        reference.process_block(&cmds, &mut want).unwrap();
        assert_eq!(r.first_seq, (b * n) as u64);
        lost += u64::from(r.lost_frames);
        total += n as u64;
        let mut block_lost = 0;
        for (g, w) in got.iter().zip(&want) {
            if g.flags.has(FrameFlags::LOST) {
                block_lost += 1;
                // Placeholder: right sequence number, last good values held.
                assert_eq!(g.seq, w.seq);
                if let Some(l) = last_good {
                    assert_eq!((g.handle_m, g.accel_m_s2), (l.handle_m, l.accel_m_s2));
                }
            } else {
                assert_same(g, w);
                last_good = Some(*g);
            }
        }
        assert_eq!(block_lost, r.lost_frames);
    }
    let ls = rig.link_stats();
    // A 162-byte frame of 10 samples is hit with probability ≈ 1 − (1 − 6e-4)^162
    // ≈ 9 %: about 1 400 of 15 000 samples are lost.
    assert!(lost > 300 && lost < 4000, "lost {lost}");
    assert_eq!(ls.lost, lost);
    assert_eq!(rig.status().lost_frames, lost);
    assert!(ls.crc_errors > 10, "{ls:?}");
    assert_eq!(ls.samples + lost, total);
    let mut lost_faults = 0u64;
    while let Some(f) = rig.pop_fault() {
        if let RigFault::LostFrames { count, .. } = f {
            lost_faults += u64::from(count);
        }
    }
    // The queue may have dropped old entries, never invented any.
    assert!(lost_faults <= lost && lost_faults > 0);
}

#[test]
fn a_stall_is_reported_promptly_and_the_rig_reconnects() {
    let dev = daq(EmulatorConfig {
        watchdog: Duration::from_millis(100),
        faults: FaultInjection {
            stall_after: Some(Duration::from_millis(400)),
            stall_for: Some(Duration::from_millis(500)),
            ..FaultInjection::default()
        },
        ..EmulatorConfig::default()
    });
    let mut cfg = SerialConfig::new(&dev.path);
    cfg.timeout = Duration::from_millis(60);
    let mut rig = SerialRig::open(&cfg).unwrap();
    rig.start().unwrap();
    let cmds = commands(50, 0);
    let mut out = vec![SensorFrame::default(); 50];
    let err = loop {
        let t = Instant::now();
        match rig.process_block(&cmds, &mut out) {
            Ok(_) => assert!(t.elapsed() < Duration::from_millis(60)),
            Err(e) => {
                // A 5 ms block plus the 60 ms timeout, not a hang.
                assert!(
                    t.elapsed() < Duration::from_millis(200),
                    "{:?}",
                    t.elapsed()
                );
                break e;
            }
        }
    };
    assert!(matches!(err, RigError::Disconnected(_)), "{err}");
    assert!(err.to_string().contains("nothing at all"), "{err}");
    assert_eq!(rig.status().state, RigState::Disconnected);
    assert!(matches!(
        rig.process_block(&cmds, &mut out),
        Err(RigError::Disconnected(_))
    ));
    // Once the device answers again, the same rig reopens its port.
    std::thread::sleep(Duration::from_millis(600));
    rig.reconnect().unwrap();
    assert_eq!(rig.status().state, RigState::Idle);
    rig.start().unwrap();
    let r = rig.process_block(&cmds, &mut out).unwrap();
    assert_eq!(r.lost_frames, 0);
    assert!(out.windows(2).all(|w| w[1].seq == w[0].seq + 1));
    assert!(out.iter().all(|f| !f.flags.has(FrameFlags::LOST)));
}

/// A device that keeps sending valid frames which never advance the
/// sample stream is declared stalled by the host's progress watchdog
/// within its timeout, whatever it sends; the error says what it sent, the
/// rig is disconnected (outputs commanded to zero). With a long timeout,
/// the deadline bounds the wait instead.
#[test]
fn valid_frames_that_never_advance_the_stream_end_in_a_stall() {
    for (mode, said) in [
        (Misbehaviour::StatusOnly, "STATUS frame(s) only"),
        (Misbehaviour::UnknownFrames, "of unknown type"),
        (Misbehaviour::StraySequence, "stray sequence numbers"),
    ] {
        let dev = daq(EmulatorConfig {
            faults: FaultInjection {
                misbehave: Some(mode),
                ..FaultInjection::default()
            },
            ..emu_cfg()
        });
        let mut cfg = SerialConfig::new(&dev.path);
        cfg.timeout = Duration::from_millis(100);
        let mut rig = SerialRig::open(&cfg).unwrap();
        rig.start().unwrap();
        let cmds = commands(50, 0);
        let mut out = vec![SensorFrame::default(); 50];
        let t = Instant::now();
        let err = rig.process_block(&cmds, &mut out).unwrap_err();
        let took = t.elapsed();
        assert!(took < Duration::from_millis(400), "{mode:?}: {took:?}");
        let text = err.to_string();
        assert!(matches!(err, RigError::Disconnected(_)), "{text}");
        assert!(
            text.contains("did not advance") && text.contains(said),
            "{mode:?}: {text}"
        );
        assert_eq!(rig.status().state, RigState::Disconnected);

        // A 60 s timeout: the caller's deadline still ends the wait.
        drop(rig);
        cfg.timeout = Duration::from_secs(60);
        let mut rig = SerialRig::open(&cfg).unwrap();
        rig.start().unwrap();
        rig.set_deadline(Some(Instant::now() + Duration::from_millis(300)));
        let t = Instant::now();
        let err = rig.process_block(&cmds, &mut out).unwrap_err();
        let took = t.elapsed();
        // The deadline, or the rate check after 500 ms of waiting.
        assert!(took < Duration::from_millis(700), "{mode:?}: {took:?}");
        assert!(err.to_string().contains(said), "{mode:?}: {err}");
    }
}

#[test]
fn a_vanished_device_is_reported_at_once() {
    let dev = daq(EmulatorConfig {
        faults: FaultInjection {
            disconnect_after: Some(Duration::from_millis(300)),
            ..FaultInjection::default()
        },
        ..emu_cfg()
    });
    let mut cfg = SerialConfig::new(&dev.path);
    cfg.timeout = Duration::from_secs(5); // the hang-up must be seen, not timed out
    let mut rig = SerialRig::open(&cfg).unwrap();
    rig.start().unwrap();
    let cmds = commands(20, 0);
    let mut out = vec![SensorFrame::default(); 20];
    let t0 = Instant::now();
    let err = loop {
        let t = Instant::now();
        if let Err(e) = rig.process_block(&cmds, &mut out) {
            assert!(
                t.elapsed() < Duration::from_millis(300),
                "{:?}",
                t.elapsed()
            );
            break e;
        }
        assert!(t0.elapsed() < Duration::from_secs(3), "no error");
    };
    assert!(matches!(err, RigError::Disconnected(_)), "{err}");
    assert!(err.to_string().contains("vanished"), "{err}");
    assert_eq!(rig.status().state, RigState::Disconnected);
    assert!(rig.reconnect().is_err(), "the pty is gone");
}

/// A device that vanished while the host was between blocks: the next
/// block's write fails first, and the rig reports it as the failed read
/// does: disconnected (so the engine offers Reconnect, not Start).
#[test]
fn a_device_gone_before_the_next_write_leaves_the_rig_disconnected() {
    let dev = daq(emu_cfg());
    let mut rig = SerialRig::open(&SerialConfig::new(&dev.path)).unwrap();
    rig.start().unwrap();
    let cmds = commands(20, 0);
    let mut out = vec![SensorFrame::default(); 20];
    rig.process_block(&cmds, &mut out).unwrap();
    // The device's thread ends and closes the pty (joined: it is gone).
    drop(dev.finish());
    let err = rig.process_block(&cmds, &mut out).unwrap_err();
    assert!(matches!(err, RigError::Disconnected(_)), "{err}");
    assert!(err.to_string().contains("vanished"), "{err}");
    assert_eq!(rig.status().state, RigState::Disconnected);
    assert!(rig.start().is_err(), "start needs a reconnect first");
}

#[test]
fn the_device_watchdog_zeroes_the_outputs_when_the_host_goes_silent() {
    // A window long enough that a loaded machine's scheduling never trips
    // it while the host is talking; the host then goes silent for three.
    let window = Duration::from_millis(250);
    let dev = daq(EmulatorConfig {
        watchdog: window,
        ..EmulatorConfig::default()
    });
    let mut cfg = SerialConfig::new(&dev.path);
    cfg.timeout = Duration::from_secs(2);
    let mut rig = SerialRig::open(&cfg).unwrap();
    rig.start().unwrap();
    let on = [ActuatorFrame {
        force_n: [1.0, -1.0],
        haptuator_v: 0.5,
    }; 30];
    let mut out = [SensorFrame::default(); 30];
    rig.process_block(&on, &mut out).unwrap();
    // The host goes silent for longer than the window.
    std::thread::sleep(3 * window);
    let err = rig.process_block(&on, &mut out).unwrap_err();
    assert!(err.to_string().contains("watchdog"), "{err}");
    assert_eq!(rig.status().state, RigState::Faulted);
    assert!(
        std::iter::from_fn(|| rig.pop_fault())
            .any(|f| matches!(f, RigFault::WatchdogTripped { .. }))
    );
    assert!(matches!(
        rig.process_block(&on, &mut out),
        Err(RigError::NotReady(_))
    ));
    // start() re-arms.
    rig.start().unwrap();
    rig.process_block(&on, &mut out).unwrap();
    rig.stop().unwrap();
    let emu = dev.finish();
    assert_eq!(emu.stats().watchdog_trips, 1);
    assert_eq!(*emu.applied(), DaqCommand::default());
}

#[test]
fn with_rearm_an_idle_trip_is_recovered_inside_process_block() {
    let dev = daq(EmulatorConfig {
        watchdog: Duration::from_millis(40),
        ..EmulatorConfig::default()
    });
    let mut cfg = SerialConfig::new(&dev.path);
    cfg.rearm_after_idle_trip = true;
    let mut rig = SerialRig::open(&cfg).unwrap();
    rig.start().unwrap();
    let cmds = commands(64, 0);
    let mut out = vec![SensorFrame::default(); 64];
    rig.process_block(&cmds, &mut out).unwrap();
    std::thread::sleep(Duration::from_millis(120));
    let r = rig.process_block(&cmds, &mut out).unwrap();
    assert_eq!(r.lost_frames, 0);
    assert_eq!(rig.status().state, RigState::Running);
    assert!(
        std::iter::from_fn(|| rig.pop_fault())
            .any(|f| matches!(f, RigFault::WatchdogTripped { .. }))
    );
    assert_eq!(dev.finish().stats().watchdog_trips, 1);
}

/// Late commands of `blocks` blocks of 10 samples (zero commands) against a
/// free-running emulated device, with a command lead of `lead` blocks.
fn late_commands_with_lead(lead: u32, blocks: usize) -> (u64, u64) {
    let dev = daq(EmulatorConfig {
        free_running: true,
        ..emu_cfg()
    });
    let mut cfg = SerialConfig::new(&dev.path);
    cfg.lead = kilotouch_rig::serial::CommandLead::Blocks(lead);
    let mut rig = SerialRig::open(&cfg).unwrap();
    // The host's loop thread runs real-time too, as the engine's does.
    let _ = kilotouch_rig::realtime::promote_current_thread();
    rig.start().unwrap();
    let cmds = vec![ActuatorFrame::default(); 10];
    let mut out = vec![SensorFrame::default(); 10];
    let mut seqs = Vec::new();
    for _ in 0..blocks {
        rig.process_block(&cmds, &mut out).unwrap();
        seqs.extend(out.iter().map(|f| f.seq));
    }
    // Every sample is accounted for, in order, whatever the lead.
    assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1), "{seqs:?}");
    assert_eq!(
        kilotouch_rig::Rig::loop_delay_samples(&rig, 10),
        10 + 10 * lead
    );
    let late = rig.link_stats().late_commands;
    kilotouch_rig::realtime::demote_current_thread();
    (late, rig.status().late_commands)
}

#[test]
fn a_command_lead_keeps_a_free_running_device_in_commands() {
    // Block-synchronous: the device runs out of commands at the end of
    // every block until the next one arrives (one round trip) and holds
    // the previous command; with a lead of two blocks it always has the
    // next ones. Counted, not timed: the host can be late on a busy
    // machine, but not on nearly every block.
    let (sync, sync_status) = late_commands_with_lead(0, 300);
    let (led, led_status) = late_commands_with_lead(2, 300);
    assert_eq!(sync, sync_status);
    assert_eq!(led, led_status);
    assert!(
        sync >= 150,
        "block-synchronous: only {sync} late commands in 3000 samples"
    );
    assert!(
        led * 10 < sync,
        "with a lead of 2 blocks {led} late commands, block-synchronous {sync}"
    );
}

/// A device whose frames do not line up with the host's blocks (7 samples
/// per frame, blocks of 10) and a command lead of one block: frames carry
/// samples past the block the host waits for; every sample reaches the
/// host, in order, none counted lost.
#[test]
fn frames_across_block_boundaries_lose_nothing_with_a_lead() {
    let dev = daq(EmulatorConfig {
        batch: 7,
        ..emu_cfg()
    });
    let mut cfg = SerialConfig::new(&dev.path);
    cfg.lead = kilotouch_rig::serial::CommandLead::Blocks(1);
    cfg.timeout = Duration::from_secs(2);
    let mut rig = SerialRig::open(&cfg).unwrap();
    rig.start().unwrap();
    let cmds = vec![ActuatorFrame::default(); 10];
    let mut out = vec![SensorFrame::default(); 10];
    let mut seqs = Vec::new();
    for _ in 0..200 {
        rig.process_block(&cmds, &mut out).unwrap();
        seqs.extend(out.iter().map(|f| f.seq));
    }
    assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1), "{seqs:?}");
    let st = rig.link_stats();
    assert_eq!(st.lost, 0, "{st:?}");
    assert_eq!(rig.status().lost_frames, 0);
}

/// A participant at the emulated handle that records what the host told
/// the device and moves the hand along x.
#[derive(Debug, Default)]
struct Recorder {
    infos: Arc<std::sync::Mutex<Vec<kilotouch_rig::device::HostInfo>>>,
    k: u64,
}

impl kilotouch_rig::device::HandAgent for Recorder {
    fn info(&mut self, info: &kilotouch_rig::device::HostInfo) {
        if let Ok(mut v) = self.infos.lock() {
            v.push(*info);
        }
    }
    fn hand(&mut self) -> Option<[f64; 2]> {
        self.k += 1;
        Some([1e-6 * self.k as f64, 0.0])
    }
    fn observe(&mut self, _a: &ActuatorFrame, _s: &SensorFrame) {}
}

#[test]
fn the_host_information_reaches_the_participant_at_the_handle() {
    use kilotouch_rig::device::{HostInfo, PhaseCode, TaskCode, TrialInfo, VisualFrame};
    let infos = Arc::new(std::sync::Mutex::new(Vec::new()));
    let agent = Recorder {
        infos: infos.clone(),
        k: 0,
    };
    let inst = DaqInstrument::new(&RigConfig::default())
        .unwrap()
        .with_agent(Box::new(agent));
    let dev = Device::spawn(inst, emu_cfg());
    // A generous host timeout: what is tested is what reaches the device,
    // not fault timing (a loaded machine may deschedule the device thread
    // for longer than the default 100 ms).
    let mut cfg = SerialConfig::new(&dev.path);
    cfg.timeout = Duration::from_secs(2);
    let mut rig = SerialRig::open(&cfg).unwrap();
    rig.start().unwrap();
    let rc = RigConfig::default();
    let begin = HostInfo::TrialBegin(TrialInfo {
        participant: 3,
        condition: kilotouch_rig::Condition::D,
        phase: PhaseCode::Test,
        index: 7,
        task: TaskCode::BlindNavigation,
        mapping: kilotouch_rig::coupling::HandMapping::from_config(&rc.coupling),
        start_trap_m: [1e-6, -1e-6],
        heading: [0.6, 0.8],
        retreat_distance_m: 2e-6,
        first_seq: 12,
    });
    let view = HostInfo::View(VisualFrame {
        seq: 5,
        captured_s: 0.2,
        bead_m: [1e-6, 2e-6],
        trap_m: [1.5e-6, 2e-6],
        obstacle_m: [5e-6, 0.0],
        obstacle_radius_m: 1.5e-6,
        bead_radius_m: 1.5e-6,
    });
    let cmds = vec![ActuatorFrame::default(); 10];
    let mut out = vec![SensorFrame::default(); 10];
    for info in [begin, view, HostInfo::TrialEnd] {
        rig.send_info(&info).unwrap();
        rig.process_block(&cmds, &mut out).unwrap();
    }
    for _ in 0..20 {
        rig.process_block(&cmds, &mut out).unwrap();
    }
    // The handle follows the participant's hand (1 µm per sample along x,
    // behind the finger's impedance); it rests at 0 without a hand.
    assert!(out[9].handle_m[0] > 10e-6, "{:?}", out[9].handle_m);
    let emu = dev.finish();
    assert_eq!(
        infos.lock().unwrap().as_slice(),
        &[begin, view, HostInfo::TrialEnd]
    );
    assert_eq!(emu.stats().host_frames, emu.stats().host_frames);
}
