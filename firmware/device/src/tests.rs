//! Host tests of the device logic against the protocol document.

use crate::device::{Config, Device, Frontend, LatePolicy, Outbox, STATUS_PERIOD_TICKS};
use crate::plant::PlantFrontend;
use crate::ring::RING;
use kilotouch_proto::testing::{self, Ack, PlantSensors, Section};
use kilotouch_proto::{
    DaqCaps, DaqCommand, DaqSample, Decoder, DeviceState, FaultReport, Hello, Status, WireItem,
    block_header, block_item, fault, flag, ty,
};
use std::vec::Vec;

#[derive(Debug, Default)]
struct VecOut(Vec<u8>);

impl Outbox for VecOut {
    fn free(&self) -> usize {
        1 << 20
    }
    fn write(&mut self, bytes: &[u8]) {
        self.0.extend_from_slice(bytes);
    }
}

/// A frontend that reports the command it holds in the encoder counts.
#[derive(Debug, Default)]
struct Echo {
    cmd: DaqCommand,
    safe_calls: u32,
}

impl Frontend for Echo {
    fn apply(&mut self, c: &DaqCommand) {
        self.cmd = *c;
    }
    fn read(&mut self) -> DaqSample {
        DaqSample {
            enc: [i32::from(self.cmd.force[0]), i32::from(self.cmd.drive)],
            acc: [0; 3],
            flags: 0,
        }
    }
    fn safe(&mut self) {
        self.cmd = DaqCommand::default();
        self.safe_calls += 1;
    }
    fn outputs(&self) -> DaqCommand {
        self.cmd
    }
    fn caps(&self) -> DaqCaps {
        DaqCaps {
            encoder_counts_per_m: 1e7,
            accel_m_s2_per_code: 1e-2,
            accel_range_m_s2: 50.0,
            force_max_n: 5.0,
            drive_max_v: 10.0,
        }
    }
}

fn cfg(policy: LatePolicy) -> Config {
    Config {
        sample_rate_hz: 10_000,
        watchdog_ms: 100,
        batch: 10,
        policy,
        max_code: 32767,
        test_frames: true,
        name: "test",
        firmware: "fw 0",
    }
}

fn device(policy: LatePolicy) -> Device<Echo, VecOut> {
    Device::new(cfg(policy), b"ABC", Echo::default(), VecOut::default())
}

/// Frames the device queued since the last call.
fn drain<F: Frontend>(d: &mut Device<F, VecOut>) -> Vec<(u8, Vec<u8>)> {
    let bytes = core::mem::take(&mut d.outbox().0);
    let mut dec = Decoder::new();
    let mut out = Vec::new();
    for chunk in bytes.chunks(1000) {
        dec.push(chunk);
        while let Some(f) = dec.next_frame() {
            out.push((f.ty, f.payload.to_vec()));
        }
    }
    out
}

fn samples(frames: &[(u8, Vec<u8>)]) -> Vec<(u64, DaqSample)> {
    let mut v = Vec::new();
    for (t, p) in frames {
        if *t == ty::SAMPLES {
            let (s, n) = block_header::<DaqSample>(p).unwrap();
            for i in 0..n {
                v.push((u64::from(s) + i as u64, block_item(p, i)));
            }
        }
    }
    v
}

fn faults(frames: &[(u8, Vec<u8>)]) -> Vec<u8> {
    frames
        .iter()
        .filter(|(t, _)| *t == ty::FAULT)
        .map(|(_, p)| FaultReport::parse(p).unwrap().code)
        .collect()
}

fn commands(first: u32, cmds: &[DaqCommand]) -> Vec<u8> {
    let mut p = Vec::new();
    p.extend_from_slice(&first.to_le_bytes());
    p.push(cmds.len() as u8);
    for c in cmds {
        let mut b = [0u8; 6];
        c.encode(&mut b);
        p.extend_from_slice(&b);
    }
    p
}

fn cmd(k: i16) -> DaqCommand {
    DaqCommand {
        force: [k, 0],
        drive: -k,
    }
}

#[test]
fn hello_answers_the_version_and_identity() {
    let mut d = device(LatePolicy::Hold);
    d.handle(ty::HELLO_REQ, &2u16.to_le_bytes());
    let f = drain(&mut d);
    assert_eq!(f.len(), 1);
    let h = Hello::parse(&f[0].1).unwrap();
    assert_eq!(
        (h.version, h.sample_rate_hz, h.watchdog_ms, h.batch),
        (2, 10_000, 100, 10)
    );
    assert_eq!(
        (h.name, h.serial, h.firmware),
        (&b"test"[..], &b"ABC"[..], &b"fw 0"[..])
    );
    d.handle(ty::HELLO_REQ, &1u16.to_le_bytes());
    let f = drain(&mut d);
    assert_eq!(faults(&f), [fault::VERSION]);
    assert_eq!(f[1].0, ty::HELLO);
}

/// Wait policy: the emulator's semantics, tick by tick.
#[test]
fn waiting_device_runs_due_samples_batches_and_reports_while_waiting() {
    let mut d = device(LatePolicy::Wait);
    d.handle(ty::START, &[]);
    let st = Status::parse(&drain(&mut d)[0].1).unwrap();
    assert_eq!((st.state, st.next_seq), (DeviceState::Running, 0));
    let cmds: Vec<DaqCommand> = (0..25).map(|k| cmd(k as i16 + 1)).collect();
    d.handle(ty::COMMANDS, &commands(0, &cmds));
    for _ in 0..20 {
        d.tick();
    }
    // 20 samples due and executed, two full frames of 10.
    let f = drain(&mut d);
    assert_eq!(f.iter().filter(|(t, _)| *t == ty::SAMPLES).count(), 2);
    let s = samples(&f);
    assert_eq!(s.len(), 20);
    assert!(
        s.iter()
            .all(|(q, x)| x.enc[0] == *q as i32 + 1 && x.flags == 0)
    );
    // Out of commands at sample 25: partial frame of 5, then STATUS.
    for _ in 0..10 {
        d.tick();
    }
    let f = drain(&mut d);
    assert_eq!(samples(&f).len(), 5);
    assert_eq!(f.last().unwrap().0, ty::STATUS);
    assert_eq!(Status::parse(&f.last().unwrap().1).unwrap().next_seq, 25);
    // STATUS repeats every 10 ms while waiting.
    for _ in 0..STATUS_PERIOD_TICKS {
        d.tick();
    }
    assert_eq!(drain(&mut d).len(), 1);
    // Late commands run at once (catch-up), none flagged late.
    d.handle(ty::COMMANDS, &commands(25, &cmds[..10]));
    d.tick();
    assert_eq!(d.next_seq(), 35);
    assert_eq!(d.counters().late_commands, 0);
}

#[test]
fn holding_device_flags_late_samples_and_keeps_the_clock() {
    let mut d = device(LatePolicy::Hold);
    d.handle(ty::START, &[]);
    drain(&mut d);
    // START began the period of sample 0 without a command.
    d.handle(ty::COMMANDS, &commands(1, &[cmd(5), cmd(6)]));
    for _ in 0..10 {
        d.tick();
    }
    let s = samples(&drain(&mut d));
    assert_eq!(s.len(), 10);
    let late: Vec<bool> = s
        .iter()
        .map(|(_, x)| x.flags & flag::CMD_LATE != 0)
        .collect();
    assert_eq!(late[..4], [true, false, false, true]);
    assert!(late[3..].iter().all(|l| *l));
    // Held: the last command stays applied through the late samples.
    assert_eq!(s[1].1.enc[0], 5);
    assert_eq!(s[2].1.enc[0], 6);
    assert!(s[3..].iter().all(|(_, x)| x.enc[0] == 6));
    assert_eq!(d.counters().late_commands, 1 + 8);
    // A command for the period in progress is late: dropped, FAULT LATE.
    d.handle(ty::COMMANDS, &commands(10, &[cmd(1)]));
    assert_eq!(faults(&drain(&mut d)), [fault::LATE]);
}

#[test]
fn the_watchdog_zeroes_the_outputs_when_the_host_goes_silent() {
    for policy in [LatePolicy::Hold, LatePolicy::Wait] {
        let mut d = device(policy);
        d.handle(ty::START, &[]);
        d.handle(ty::COMMANDS, &commands(0, &[cmd(100); 50]));
        // Commands run out at sample 50; the window is 1000 ticks from then
        // (the last host frame came earlier).
        for _ in 0..1049 {
            d.tick();
        }
        assert_eq!(d.state(), DeviceState::Running, "{policy:?}");
        assert_eq!(d.applied(), cmd(100), "held while waiting");
        drain(&mut d);
        for _ in 0..3 {
            d.tick();
        }
        assert_eq!(d.state(), DeviceState::Tripped, "{policy:?}");
        assert_eq!(d.applied(), DaqCommand::default());
        assert_eq!(d.frontend().cmd, DaqCommand::default());
        assert!(d.frontend().safe_calls >= 1);
        let f = drain(&mut d);
        assert_eq!(faults(&f), [fault::WATCHDOG]);
        let st = Status::parse(&f.last().unwrap().1).unwrap();
        assert_eq!(st.state, DeviceState::Tripped);
        // Refused until START.
        d.handle(ty::COMMANDS, &commands(2000, &[cmd(1)]));
        assert_eq!(faults(&drain(&mut d)), [fault::NOT_RUNNING]);
        // Heartbeats alone keep a device without commands alive.
        d.handle(ty::START, &[]);
        for _ in 0..20 {
            for _ in 0..500 {
                d.tick();
            }
            d.handle(ty::HEARTBEAT, &[0; 4]);
        }
        assert_eq!(d.state(), DeviceState::Running, "{policy:?}");
    }
}

#[test]
fn codes_are_clamped_and_flagged_limited() {
    let mut c = cfg(LatePolicy::Wait);
    c.max_code = 30_000;
    let mut d = Device::new(c, b"", Echo::default(), VecOut::default());
    d.handle(ty::START, &[]);
    let cmds = [
        DaqCommand {
            force: [i16::MIN, 0],
            drive: 0,
        },
        DaqCommand {
            force: [29_999, 0],
            drive: -30_000,
        },
        DaqCommand {
            force: [0, 0],
            drive: 31_000,
        },
    ];
    d.handle(ty::COMMANDS, &commands(0, &cmds));
    for _ in 0..3 {
        d.tick();
    }
    d.handle(ty::STOP, &[]);
    let s = samples(&drain(&mut d));
    assert_eq!(s[0].1.enc[0], -30_000);
    assert_eq!(s[2].1.enc[1], 30_000);
    let lim: Vec<bool> = s
        .iter()
        .map(|(_, x)| x.flags & flag::LIMITED != 0)
        .collect();
    assert_eq!(lim, [true, false, true]);
}

#[test]
fn malformed_stale_and_far_commands_are_refused() {
    let mut d = device(LatePolicy::Wait);
    d.handle(ty::COMMANDS, &commands(0, &[cmd(1)]));
    d.handle(0x30, &[]);
    d.handle(ty::COMMANDS, &[1, 2, 3]);
    d.handle(ty::RESET, &[0; 5]);
    d.handle(ty::RESET, &[0; 6]);
    d.handle(ty::INFO, &[2]);
    let f = drain(&mut d);
    assert_eq!(
        faults(&f),
        [
            fault::NOT_RUNNING,
            fault::BAD_FRAME,
            fault::BAD_FRAME,
            fault::BAD_FRAME
        ]
    );
    d.handle(ty::START, &[]);
    d.handle(ty::COMMANDS, &commands(0, &[cmd(1); 3]));
    for _ in 0..3 {
        d.tick();
    }
    drain(&mut d);
    d.handle(ty::COMMANDS, &commands(2, &[cmd(1); 2]));
    d.handle(ty::COMMANDS, &commands(3 + RING as u32 - 1, &[cmd(1); 2]));
    assert_eq!(faults(&drain(&mut d)), [fault::LATE, fault::OVERFLOW]);
}

#[test]
fn the_emergency_stop_zeroes_trips_and_refuses_start() {
    let mut d = device(LatePolicy::Hold);
    d.handle(ty::START, &[]);
    d.handle(ty::COMMANDS, &commands(1, &[cmd(9); 100]));
    for _ in 0..5 {
        d.tick();
    }
    assert_eq!(d.frontend().cmd, cmd(9));
    drain(&mut d);
    d.set_estop(true);
    assert_eq!(d.frontend().cmd, DaqCommand::default());
    assert_eq!(d.state(), DeviceState::Tripped);
    let f = drain(&mut d);
    assert_eq!(faults(&f), [fault::ESTOP]);
    d.handle(ty::START, &[]);
    let f = drain(&mut d);
    assert_eq!(faults(&f), [fault::ESTOP]);
    assert_eq!(Status::parse(&f[1].1).unwrap().state, DeviceState::Tripped);
    d.set_estop(false);
    d.handle(ty::START, &[]);
    assert_eq!(d.state(), DeviceState::Running);
}

fn test_frame(op: u8, args: &[u8]) -> Vec<u8> {
    let mut p = Vec::from([op]);
    p.extend_from_slice(args);
    p
}

fn acks(frames: &[(u8, Vec<u8>)]) -> Vec<(u8, u8, u32)> {
    frames
        .iter()
        .filter(|(t, _)| *t == ty::TEST_ACK)
        .map(|(_, p)| {
            let (a, _) = Ack::parse(p).unwrap();
            (a.op, a.result, a.value)
        })
        .collect()
}

#[test]
fn test_frames_switch_the_policy_and_inject_faults_or_are_refused() {
    let mut c = cfg(LatePolicy::Wait);
    c.test_frames = false;
    let mut d = Device::new(c, b"", Echo::default(), VecOut::default());
    d.handle(ty::TEST, &test_frame(testing::op::MODE, &[1]));
    assert_eq!(faults(&drain(&mut d)), [fault::BAD_FRAME]);
    let mut d = device(LatePolicy::Wait);
    d.handle(ty::TEST, &test_frame(testing::op::MODE, &[1]));
    d.handle(ty::TEST, &test_frame(testing::op::MODE, &[7]));
    d.handle(ty::TEST, &test_frame(testing::op::PLANT_COMMIT, &[]));
    let ok = testing::result::OK;
    assert_eq!(
        acks(&drain(&mut d)),
        [
            (testing::op::MODE, ok, 1),
            (testing::op::MODE, testing::result::BAD_ARGUMENT, 0),
            (testing::op::PLANT_COMMIT, testing::result::UNSUPPORTED, 0)
        ]
    );
    assert_eq!(d.policy(), LatePolicy::Hold);
    // Every byte corrupted: the host decoder sees no valid frame.
    let mut args = Vec::new();
    for v in [1_000_000u32, 0, 7] {
        args.extend_from_slice(&v.to_le_bytes());
    }
    d.handle(ty::TEST, &test_frame(testing::op::FAULTS, &args));
    drain(&mut d);
    d.handle(ty::HELLO_REQ, &2u16.to_le_bytes());
    assert!(drain(&mut d).is_empty());
}

fn sensors() -> PlantSensors {
    PlantSensors {
        accel_alpha: [0.5, 0.5, 0.5],
        accel_offset_m_s2: [0.0, 0.0, 9.80665],
        accel_range_m_s2: 50.0,
        accel_m_s2_per_code: 0.01,
        encoder_counts_per_m: 1e6,
        force_max_n: 5.0,
        drive_max_v: 10.0,
    }
}

fn no_clock() -> u32 {
    0
}

/// The plant model: a first-order section y[n] = 0.5 y[n−1] + 0.5 x[n]
/// from force x to acceleration x, then the accelerometer's pole
/// (α = 0.5): the step response of the two poles in cascade, analytically
/// Σₖ₌₀ⁿ (k + 1)/2^(k+2) = 1 − (n + 3)/2^(n+2) for the n-th sample (n from
/// 0), scaled by the force.
#[test]
fn the_plant_model_matches_its_analytic_step_response() {
    let fe = PlantFrontend::new(sensors(), no_clock);
    let mut d = Device::new(cfg(LatePolicy::Wait), b"", fe, VecOut::default());
    let sec = Section {
        input: testing::input::FORCE_X,
        output: testing::output::ACCEL_X,
        b: [0.5, 0.0, 0.0],
        a: [-0.5, 0.0],
    };
    let unstable = Section {
        a: [-2.5, 1.0],
        ..sec
    };
    for (op, args) in [
        (testing::op::PLANT_CLEAR, Vec::new()),
        (testing::op::PLANT_SENSORS, sensors().encode().to_vec()),
        (testing::op::PLANT_SECTION, sec.encode().to_vec()),
        (testing::op::PLANT_COMMIT, Vec::new()),
        (testing::op::PLANT_SECTION, unstable.encode().to_vec()),
        (testing::op::PLANT_COMMIT, Vec::new()),
        (testing::op::PLANT_SENSORS, [0u8; 3].to_vec()),
    ] {
        d.handle(ty::TEST, &test_frame(op, &args));
    }
    let ok = testing::result::OK;
    assert_eq!(
        acks(&drain(&mut d)),
        [
            (testing::op::PLANT_CLEAR, ok, 0),
            (testing::op::PLANT_SENSORS, ok, 0),
            (testing::op::PLANT_SECTION, ok, 1),
            (testing::op::PLANT_COMMIT, ok, 1),
            (testing::op::PLANT_SECTION, ok, 2),
            (testing::op::PLANT_COMMIT, testing::result::UNSTABLE, 0),
            (testing::op::PLANT_SENSORS, testing::result::BAD_ARGUMENT, 0),
        ]
    );
    d.handle(ty::TEST, &test_frame(testing::op::PLANT_CLEAR, &[]));
    d.handle(
        ty::TEST,
        &test_frame(testing::op::PLANT_SECTION, &sec.encode()),
    );
    d.handle(ty::START, &[]);
    // 4 N = code 26214 (of 5 N at 32767): 4.00006… N.
    let c = DaqCommand {
        force: [26_214, 0],
        drive: 0,
    };
    d.handle(ty::COMMANDS, &commands(0, &[c; 20]));
    d.handle(
        ty::TEST,
        &test_frame(testing::op::PLANT_SENSORS, &sensors().encode()),
    );
    assert_eq!(
        acks(&drain(&mut d)).last().unwrap().1,
        testing::result::BUSY
    );
    for _ in 0..20 {
        d.tick();
    }
    let s = samples(&drain(&mut d));
    let f = 26_214.0 * 5.0 / 32767.0;
    for (n, (_, x)) in s.iter().enumerate() {
        let want = f * (1.0 - (n as f64 + 3.0) / 2f64.powi(n as i32 + 2));
        let got = f64::from(x.acc[0]) * 0.01;
        assert!(
            (got - want).abs() <= 0.005 + 1e-12,
            "n {n}: {got} vs {want}"
        );
        assert_eq!(x.acc[2], 981);
        assert_eq!(x.flags, 0);
    }
}

#[test]
fn the_plant_model_clips_and_resets_on_non_finite_outputs() {
    let mut fe = PlantFrontend::new(sensors(), no_clock);
    let big = Section {
        input: testing::input::DRIVE,
        output: testing::output::ACCEL_Y,
        b: [100.0, 0.0, 0.0],
        a: [0.0, 0.0],
    };
    assert_eq!(
        fe.test(testing::op::PLANT_SECTION, &big.encode(), true),
        Ok(1)
    );
    fe.apply(&DaqCommand {
        force: [0; 2],
        drive: 32767,
    });
    // 1000 m/s² through the pole: clipped at 50 within two samples.
    fe.read();
    let s = fe.read();
    assert_eq!(s.acc[1], 5000);
    assert_eq!(s.flags, flag::CLIPPED);
    let inf = Section {
        b: [f64::MAX, 0.0, 0.0],
        ..big
    };
    assert_eq!(
        fe.test(testing::op::PLANT_SECTION, &inf.encode(), true),
        Ok(2)
    );
    let s = fe.read();
    assert_eq!(s.flags & flag::NONFINITE, flag::NONFINITE);
    assert!(s.enc == [0, 0]);
}

/// An outbox with a settable amount of room.
#[derive(Debug, Default)]
struct Tight {
    bytes: Vec<u8>,
    room: usize,
}

impl Outbox for Tight {
    fn free(&self) -> usize {
        self.room
    }
    fn write(&mut self, b: &[u8]) {
        self.bytes.extend_from_slice(b);
        self.room = self.room.saturating_sub(b.len());
    }
}

/// A waiting device whose link is behind does not run samples (and so
/// drops no frame) until the transmit queue has room again.
#[test]
fn a_waiting_device_stands_still_while_its_link_is_behind() {
    let out = Tight {
        bytes: Vec::new(),
        room: 1 << 20,
    };
    let mut d = Device::new(cfg(LatePolicy::Wait), b"", Echo::default(), out);
    d.handle(ty::START, &[]);
    d.handle(ty::COMMANDS, &commands(0, &[cmd(1); 30]));
    d.outbox().room = 100;
    for _ in 0..20 {
        d.tick();
    }
    assert_eq!(d.next_seq(), 0);
    assert_eq!(d.counters().tx_dropped, 0);
    d.outbox().room = 1 << 20;
    d.tick();
    assert_eq!(d.next_seq(), 21, "caught up");
}
