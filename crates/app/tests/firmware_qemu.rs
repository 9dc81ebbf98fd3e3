//! The DAQ firmware's QEMU build (`firmware/`, feature `qemu`,
//! docs/FIRMWARE.md) in `qemu-system-arm -M netduinoplus2` with its USART on
//! a pty, driven by the real `kilotouch` executable: the link check, the
//! calibration through the in-firmware plant (and its agreement with the
//! emulator's), the fault tests of the emulator (corrupted bytes, stall,
//! vanished device), the device watchdog zeroing the outputs, late
//! commands on a free-running device, the emergency stop, and a recorded
//! session whose frames the emulator and the firmware must agree on.
//!
//! These tests need the firmware's ELF in `KILOTOUCH_FIRMWARE_ELF` and
//! `qemu-system-arm` on the path (CI's firmware step, `.ci/run`, provides
//! both); without the variable each test says so and returns. Every wait
//! is on an event (a line, a frame) with a deadline.

use kilotouch_testkit as common;

use common::{Emulator, json_ok, kilotouch as run};
use kilotouch_rig::device::{ActuatorFrame, Rig, SensorFrame};
use kilotouch_rig::error::RigError;
use kilotouch_rig::serial::frame::{
    self, DaqCommand, DaqSample, Decoder, DeviceState, FaultReport, Status, WireItem, fault, flag,
    ty,
};
use kilotouch_rig::serial::{SerialConfig, SerialRig};
use serde_json::Value;
use std::io::{BufRead, BufReader, ErrorKind, Read, Write};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// The firmware ELF, or `None` when `KILOTOUCH_FIRMWARE_ELF` is unset (the
/// test is skipped, and says so). Set to a missing file, the test fails.
fn elf(test: &str) -> Option<String> {
    let Some(v) = std::env::var_os("KILOTOUCH_FIRMWARE_ELF") else {
        eprintln!(
            "{test}: SKIPPED: KILOTOUCH_FIRMWARE_ELF is not set (the firmware's QEMU build, \
             docs/FIRMWARE.md; CI sets it)"
        );
        return None;
    };
    let v = v.to_string_lossy().into_owned();
    assert!(
        std::path::Path::new(&v).is_file(),
        "KILOTOUCH_FIRMWARE_ELF={v}: no such file (build it with `cd firmware && cargo build \
         --release --no-default-features --features qemu`)"
    );
    Some(v)
}

/// QEMU running the firmware, its USART2 on a pty, the plant loaded.
struct Qemu {
    child: Child,
    path: String,
}

impl Qemu {
    fn boot(elf: &str) -> Self {
        let mut child = Command::new("qemu-system-arm")
            .args([
                "-M",
                "netduinoplus2",
                "-display",
                "none",
                "-monitor",
                "none",
            ])
            // Instruction-counted virtual time (1 ns per instruction): the
            // firmware gets its CPU time per sample whatever the host's
            // load, so its sample interrupt never starves its link (in
            // real time, a loaded host left it no time to read or send).
            .args(["-icount", "shift=0,align=off,sleep=on"])
            .args(["-serial", "null", "-serial", "pty", "-kernel", elf])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("qemu-system-arm on the path");
        let (tx, rx) = mpsc::channel();
        for out in [
            Box::new(child.stdout.take().expect("stdout")) as Box<dyn Read + Send>,
            Box::new(child.stderr.take().expect("stderr")),
        ] {
            let tx = tx.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(out).lines().map_while(Result::ok) {
                    let _ = tx.send(line);
                }
            });
        }
        // "char device redirected to /dev/pts/N (label serial1)"
        let deadline = Instant::now() + Duration::from_secs(30);
        let path = loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let line = rx.recv_timeout(left).expect("QEMU printed its pty");
            if line.contains("serial1")
                && let Some(p) = line.split_whitespace().find(|w| w.starts_with("/dev/pts/"))
            {
                break p.to_owned();
            }
        };
        let q = Self { child, path };
        let v = json_ok(&["firmware", "load-plant", "--rig", &q.rig(), "--json"]);
        assert!(v["sections"].as_u64().unwrap_or(0) > 10, "{v}");
        q
    }

    /// `serial:PATH,min-rate=0,timeout-ms=30000`: QEMU's clock is not real
    /// time, so the host's rate check (≥ 10 % of 10 kHz) is off; its
    /// progress check stays, with a window the slowest input of a loaded
    /// machine does not reach (no test here is about it).
    fn rig(&self) -> String {
        format!("serial:{},min-rate=0,timeout-ms=30000", self.path)
    }

    /// The settings of [`Qemu::rig`] for `SerialRig` in the test, with a
    /// progress window of [`STALL_WINDOW`] (the stall tests measure how
    /// promptly a stall is reported) and answers to HELLO and START waited
    /// for 30 s.
    fn config(&self) -> SerialConfig {
        let mut cfg = SerialConfig::new(self.path.clone());
        cfg.min_rate_fraction = 0.0;
        cfg.timeout = STALL_WINDOW;
        cfg.handshake_timeout = Duration::from_secs(30);
        cfg
    }

    fn signal(&self, sig: &str) {
        let ok = Command::new("kill")
            .args([sig, &self.child.id().to_string()])
            .status()
            .expect("kill")
            .success();
        assert!(ok, "kill {sig}");
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        // Best effort: QEMU may already be gone.
        let _ = Command::new("kill")
            .args(["-CONT", &self.child.id().to_string()])
            .status();
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn rig_check_streams_10000_blocks_without_loss() {
    let Some(elf) = elf("rig_check") else { return };
    let q = Qemu::boot(&elf);
    let rig = q.rig();
    let v = json_ok(&[
        "rig",
        "check",
        "--rig",
        &rig,
        "--block",
        "10",
        "--blocks",
        "10000",
        "--duration",
        "600",
        // QEMU's clock is not real time: no rate is judged.
        "--rate-tolerance",
        "1",
        "--json",
    ]);
    eprintln!("rig check through the firmware: {v}");
    assert_eq!(v["blocks"].as_u64(), Some(10_000), "{v}");
    assert_eq!(v["lost"].as_u64(), Some(0), "{v}");
    assert_eq!(v["crc_errors"].as_u64(), Some(0), "{v}");
    assert_eq!(v["passed"].as_bool(), Some(true));
    assert!(
        v["firmware"]
            .as_str()
            .unwrap_or("")
            .starts_with("kilotouch-firmware")
    );
}

/// Third-octave bands 63 Hz – 1 kHz of a calibration's verification.
fn bands(v: &Value) -> Vec<(f64, f64)> {
    v["bands"]
        .as_array()
        .expect("bands")
        .iter()
        .map(|b| {
            (
                b["f"].as_f64().unwrap_or(0.0),
                b["db"].as_f64().unwrap_or(f64::NAN),
            )
        })
        .filter(|(f, _)| (63.0..=1001.0).contains(f))
        .collect()
}

#[test]
fn calibration_through_the_firmware_plant_agrees_with_the_emulator() {
    let Some(elf) = elf("calibration") else {
        return;
    };
    let q = Qemu::boot(&elf);
    let fw = json_ok(&["calibrate", "--rig", &q.rig(), "--json"]);
    drop(q);
    let emu = Emulator::spawn("daq", &[]);
    let em = json_ok(&[
        "calibrate",
        "--rig",
        &format!("{},timeout-ms=1000", emu.rig()),
        "--json",
    ]);
    let (bf, be) = (bands(&fw), bands(&em));
    assert_eq!(bf.len(), 13);
    assert_eq!(fw["passed"].as_bool(), Some(true), "{fw}");
    let worst = bf.iter().map(|(_, d)| d.abs()).fold(0.0, f64::max);
    assert!(worst <= 1.0, "firmware plant: worst band {worst} dB");
    let mut diff = 0.0f64;
    for ((f1, d1), (f2, d2)) in bf.iter().zip(&be) {
        assert_eq!(f1, f2);
        diff = diff.max((d1 - d2).abs());
        assert!(
            (d1 - d2).abs() <= 0.5,
            "{f1} Hz: firmware {d1} dB, emulator {d2} dB"
        );
    }
    eprintln!(
        "calibration: firmware worst band {worst:.3} dB; largest difference to the emulator {diff:.3} dB"
    );
}

#[test]
fn corrupted_and_dropped_bytes_are_counted_and_survived() {
    let Some(elf) = elf("faults") else { return };
    let q = Qemu::boot(&elf);
    // Block-synchronous, as the emulator's test of the same faults
    // (crates/rig/tests/live_serial.rs): with the automatic command lead
    // the loss was 28–68 % instead of the ≈ 6 % below (an open finding).
    let rig = format!("{},lead=0", q.rig());
    let out = run(&[
        "firmware",
        "set",
        "--rig",
        &rig,
        "--corrupt-rate",
        "2e-4",
        "--drop-rate",
        "2e-4",
        "--seed",
        "3",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v = json_ok(&[
        "rig",
        "check",
        "--rig",
        &rig,
        "--block",
        "100",
        "--blocks",
        "300",
        "--duration",
        "120",
        // QEMU's clock is not real time: no rate is judged.
        "--rate-tolerance",
        "1",
        "--max-loss",
        "0.25",
        "--max-crc-errors",
        "0.25",
        "--json",
    ]);
    common::assert_corruption_counted(&v);
}

/// The host's progress window in the stall tests: no new sample for this
/// long is a stall (wide enough for a frame of 10 commands through a loaded
/// machine's QEMU).
const STALL_WINDOW: Duration = Duration::from_secs(3);
/// How much later than [`STALL_WINDOW`] a stall may be reported.
const STALL_SLACK: Duration = Duration::from_secs(3);

/// Stream blocks of 10 samples from the firmware through `SerialRig` (the
/// host backend `rig check` uses), do `act` once five blocks came back,
/// and return how long the failing block took and its error.
fn stream_then(q: &Qemu, act: impl FnOnce()) -> (Duration, RigError) {
    let mut rig = SerialRig::open(&q.config()).expect("open the firmware");
    rig.start().expect("start");
    let cmds = vec![ActuatorFrame::default(); 10];
    let mut sens = vec![SensorFrame::default(); 10];
    for _ in 0..5 {
        rig.process_block(&cmds, &mut sens).expect("a block");
    }
    act();
    let t = Instant::now();
    loop {
        match rig.process_block(&cmds, &mut sens) {
            Ok(_) => assert!(t.elapsed() < Duration::from_secs(10), "still streaming"),
            Err(e) => return (t.elapsed(), e),
        }
    }
}

#[test]
fn a_stalled_firmware_is_reported_promptly() {
    let Some(elf) = elf("stall") else { return };
    let q = Qemu::boot(&elf);
    let (waited, err) = stream_then(&q, || q.signal("-STOP"));
    assert!(waited < STALL_WINDOW + STALL_SLACK, "took {waited:?}");
    let msg = err.to_string();
    assert!(
        matches!(err, RigError::Disconnected(_)) && msg.contains("did not advance"),
        "{msg}"
    );
}

#[test]
fn a_vanished_firmware_is_reported_promptly() {
    let Some(elf) = elf("vanish") else { return };
    let mut q = Qemu::boot(&elf);
    let pid = q.child.id().to_string();
    let (waited, err) = stream_then(&q, || {
        let _ = Command::new("kill").args(["-KILL", &pid]).status();
    });
    let _ = q.child.wait();
    assert!(waited < STALL_WINDOW + STALL_SLACK, "took {waited:?}");
    assert!(matches!(err, RigError::Disconnected(_)), "{err}");
}

/// Device frames in arrival order: type and payload.
type Frames = Vec<(u8, Vec<u8>)>;

/// A raw host session on a port: frames out, every device frame in.
struct Raw {
    port: Box<dyn serialport::SerialPort>,
    dec: Decoder,
    got: Frames,
}

impl Raw {
    fn open(path: &str) -> Self {
        let port = serialport::new(path, 2_000_000)
            .timeout(Duration::from_millis(10))
            .open()
            .expect("open the port");
        Self {
            port,
            dec: Decoder::new(),
            got: Vec::new(),
        }
    }

    fn send(&mut self, t: u8, payload: &[u8]) {
        let mut v = Vec::new();
        frame::write_frame(&mut v, t, |o| o.extend_from_slice(payload));
        self.port.write_all(&v).expect("write");
    }

    fn commands(&mut self, first: u64, cmds: &[DaqCommand]) {
        let mut v = Vec::new();
        for (k, c) in cmds.chunks(32).enumerate() {
            frame::write_block(&mut v, ty::COMMANDS, (first + 32 * k as u64) as u32, c);
        }
        self.port.write_all(&v).expect("write");
    }

    /// Read until `done` holds for the frames received so far (deadline
    /// 60 s: a loaded machine's QEMU may take in only a few hundred bytes
    /// per second).
    fn until(&mut self, what: &str, mut done: impl FnMut(&[(u8, Vec<u8>)]) -> bool) {
        let deadline = Instant::now() + Duration::from_secs(60);
        let mut buf = [0u8; 4096];
        while !done(&self.got) {
            if Instant::now() >= deadline {
                let tail: Vec<String> = self
                    .got
                    .iter()
                    .rev()
                    .filter(|(t, _)| *t != ty::SAMPLES)
                    .take(8)
                    .map(|(t, p)| format!("{t:#04x}:{p:02x?}"))
                    .collect();
                let smp = samples(&self.got);
                panic!(
                    "no {what} within 60 s; {} frames, last samples {:?}, last others {tail:?}",
                    self.got.len(),
                    smp.last().map(|(q, x)| (*q, x.flags))
                );
            }
            match self.port.read(&mut buf) {
                Ok(n) => {
                    // The decoder holds two frames: feed it piecewise,
                    // taking the frames out as they complete.
                    let mut rest = &buf[..n];
                    while !rest.is_empty() {
                        let k = self.dec.push(rest);
                        rest = &rest[k..];
                        while let Some(f) = self.dec.next_frame() {
                            self.got.push((f.ty, f.payload.to_vec()));
                        }
                    }
                }
                Err(e) if e.kind() == ErrorKind::TimedOut => {}
                Err(e) => panic!("read: {e}"),
            }
        }
    }

    fn test(&mut self, op: u8, args: &[u8]) -> Vec<u8> {
        let mut p = vec![op];
        p.extend_from_slice(args);
        let from = self.got.len();
        self.send(ty::TEST, &p);
        self.until("test ack", |g| {
            g[from..].iter().any(|(t, _)| *t == ty::TEST_ACK)
        });
        let (_, p) = self.got[from..]
            .iter()
            .find(|(t, _)| *t == ty::TEST_ACK)
            .expect("ack");
        assert_eq!(p[1], 0, "test op {op} refused");
        p[6..].to_vec()
    }

    fn outputs(&mut self) -> DaqCommand {
        DaqCommand::decode(&self.test(frame::testing::op::OUTPUTS, &[]))
    }
}

fn has_fault(g: &[(u8, Vec<u8>)], code: u8) -> bool {
    g.iter()
        .any(|(t, p)| *t == ty::FAULT && FaultReport::parse(p).is_some_and(|f| f.code == code))
}

fn samples(g: &[(u8, Vec<u8>)]) -> Vec<(u64, DaqSample)> {
    let mut v = Vec::new();
    for (t, p) in g {
        if *t == ty::SAMPLES
            && let Some((s, n)) = frame::block_header::<DaqSample>(p)
        {
            for i in 0..n {
                v.push((u64::from(s) + i as u64, frame::block_item(p, i)));
            }
        }
    }
    v
}

fn start(r: &mut Raw) -> u64 {
    let from = r.got.len();
    r.send(ty::START, &[]);
    r.until("STATUS running", |g| {
        g[from..].iter().any(|(t, p)| {
            *t == ty::STATUS && Status::parse(p).is_some_and(|s| s.state == DeviceState::Running)
        })
    });
    r.got[from..]
        .iter()
        .find_map(|(t, p)| (*t == ty::STATUS).then(|| Status::parse(p)).flatten())
        .map(|s| u64::from(s.next_seq))
        .unwrap_or(0)
}

#[test]
fn the_device_watchdog_zeroes_both_outputs_when_the_host_goes_silent() {
    let Some(elf) = elf("watchdog") else { return };
    let q = Qemu::boot(&elf);
    let mut r = Raw::open(&q.path);
    let s = start(&mut r);
    let on = DaqCommand {
        force: [20_000, -20_000],
        drive: 10_000,
    };
    r.commands(s, &[on; 100]);
    r.until("100 samples", |g| samples(g).len() >= 100);
    // Waiting for commands, the last one held.
    assert_eq!(r.outputs(), on);
    // Silence: FAULT WATCHDOG, STATUS tripped.
    let from = r.got.len();
    r.until("watchdog trip", |g| has_fault(&g[from..], fault::WATCHDOG));
    r.until("STATUS tripped", |g| {
        g[from..].iter().any(|(t, p)| {
            *t == ty::STATUS && Status::parse(p).is_some_and(|s| s.state == DeviceState::Tripped)
        })
    });
    assert_eq!(
        r.outputs(),
        DaqCommand::default(),
        "Pantograph and Haptuator at zero"
    );
}

/// Samples ahead of START the hold-mode test's commands are for: within
/// the command buffer (2048) and the QEMU build's 5 s watchdog window, far
/// beyond the time QEMU usually takes to read them (about 2 bytes of host
/// frames per sample interrupt, docs/FIRMWARE.md; the commands are ≈ 130
/// bytes).
const HOLD_LEAD: u64 = 1500;
/// Commands of one hold-mode attempt.
const HOLD_COMMANDS: usize = 16;
/// Attempts at a hold-mode run whose commands arrive in time, and at an
/// emergency stop of a running device (each attempt checks the device's
/// answers whatever the timing).
const ATTEMPTS: usize = 5;

/// The device's answers in `g` that end a COMMANDS frame's handling:
/// FAULT `LATE` (stale commands) or `NOT_RUNNING` (it tripped first), with
/// their sequence numbers.
fn command_faults(g: &[(u8, Vec<u8>)]) -> Vec<(u8, u64)> {
    g.iter()
        .filter(|(t, _)| *t == ty::FAULT)
        .filter_map(|(_, p)| FaultReport::parse(p))
        .filter(|f| f.code == fault::LATE || f.code == fault::NOT_RUNNING)
        .map(|f| (f.code, u64::from(f.seq)))
        .collect()
}

/// One hold-mode run: START, then in one write a command for the period
/// START began (always stale: FAULT `LATE`) and [`HOLD_COMMANDS`] commands
/// for [`HOLD_LEAD`] samples on. Checks every sample's `CMD_LATE` flag
/// against the device's answers: a sample is on time exactly when its
/// command is one of those and arrived before its period began (a FAULT
/// `LATE` carries the sample in progress when stale commands arrived;
/// `NOT_RUNNING`, that they came after a trip). Returns whether all the
/// commands were on time; the device is left running or tripped.
fn hold_attempt(r: &mut Raw) -> bool {
    let from = r.got.len();
    let s = start(r);
    let n = s + HOLD_LEAD;
    let end = n + HOLD_COMMANDS as u64;
    let at = r.got.len();
    let mut v = Vec::new();
    frame::write_block(&mut v, ty::COMMANDS, s as u32, &[DaqCommand::default()]);
    frame::write_block(
        &mut v,
        ty::COMMANDS,
        n as u32,
        &[DaqCommand::default(); HOLD_COMMANDS],
    );
    r.port.write_all(&v).expect("write");
    // The samples past the commands, and the stale command's answer.
    r.until("samples past the commands and FAULT LATE", |g| {
        samples(&g[from..]).iter().any(|(q, _)| *q >= end + 10)
            && !command_faults(&g[at..]).is_empty()
    });
    let window_late = |g: &[(u8, Vec<u8>)]| {
        samples(&g[from..])
            .iter()
            .any(|(q, x)| (n..end).contains(q) && x.flags & flag::CMD_LATE != 0)
    };
    // Late commands in the window: wait for the second frame's answer.
    if window_late(&r.got) {
        r.until("the answer to the late commands", |g| {
            command_faults(&g[at..]).len() >= 2
        });
    }
    let answers = command_faults(&r.got[at..]);
    let stale_until = match answers.get(1) {
        Some((c, _)) if *c == fault::NOT_RUNNING => Some(u64::MAX),
        Some((_, f)) => Some(*f),
        None => None,
    };
    let got = samples(&r.got[from..]);
    for (q, x) in got.iter().filter(|(q, _)| *q <= end + 10) {
        let want = (n..end).contains(q) && stale_until.is_none_or(|f| *q > f);
        assert_eq!(
            x.flags & flag::CMD_LATE == 0,
            want,
            "sample {q} (start {s}, commands {n}..{end}, answers {answers:?}): flags {:#04x}",
            x.flags
        );
    }
    stale_until.is_none()
}

/// Wait for STATUS `state` among the frames after `from`.
fn until_state(r: &mut Raw, from: usize, state: DeviceState) {
    r.until(&format!("STATUS {state:?}"), |g| {
        g[from..]
            .iter()
            .any(|(t, p)| *t == ty::STATUS && Status::parse(p).is_some_and(|s| s.state == state))
    });
}

#[test]
fn a_free_running_firmware_flags_late_commands_and_the_estop_trips_it() {
    let Some(elf) = elf("late") else { return };
    let q = Qemu::boot(&elf);
    let mut r = Raw::open(&q.path);
    r.test(frame::testing::op::MODE, &[1]);
    // A free-running device: samples without a command run anyway, flagged
    // CMD_LATE; commands that arrive in time are applied without the flag.
    // Whether they do arrive in time depends on the machine's load, so a
    // run whose commands came late (checked all the same) is repeated.
    let mut attempts = 1;
    while !hold_attempt(&mut r) {
        assert!(
            attempts < ATTEMPTS,
            "commands {HOLD_LEAD} samples ahead were late {attempts} times"
        );
        attempts += 1;
        let from = r.got.len();
        r.send(ty::STOP, &[]);
        until_state(&mut r, from, DeviceState::Idle);
    }
    eprintln!("hold mode: commands on time at attempt {attempts}");
    // Emergency stop while running: START and the stop in one write.
    // Outputs zero at once, FAULT ESTOP, STATUS tripped. Should QEMU hold
    // the stop's bytes past the watchdog window, the watchdog trips first
    // and the stop finds the device tripped (no FAULT ESTOP): repeated.
    let mut attempts = 0;
    let from = loop {
        attempts += 1;
        let from = r.got.len();
        r.send(ty::STOP, &[]);
        until_state(&mut r, from, DeviceState::Idle);
        r.test(frame::testing::op::ESTOP, &[0]);
        let from = r.got.len();
        let mut v = Vec::new();
        frame::write_frame(&mut v, ty::START, |_| {});
        frame::write_frame(&mut v, ty::TEST, |o| {
            o.extend_from_slice(&[frame::testing::op::ESTOP, 1])
        });
        r.port.write_all(&v).expect("write");
        r.until("FAULT ESTOP or WATCHDOG", |g| {
            has_fault(&g[from..], fault::ESTOP) || has_fault(&g[from..], fault::WATCHDOG)
        });
        if has_fault(&r.got[from..], fault::ESTOP) {
            break from;
        }
        assert!(
            attempts < ATTEMPTS,
            "the watchdog tripped before the stop {attempts} times"
        );
    };
    eprintln!("emergency stop: tripped the running device at attempt {attempts}");
    until_state(&mut r, from, DeviceState::Tripped);
    assert_eq!(r.outputs(), DaqCommand::default());
    // START is refused while the stop is engaged, and the host says so.
    let from = r.got.len();
    r.send(ty::START, &[]);
    r.until("START refused", |g| has_fault(&g[from..], fault::ESTOP));
    drop(r);
    let mut rig = SerialRig::open(&q.config()).expect("open the firmware");
    let err = rig.start().expect_err("START refused").to_string();
    assert!(err.contains("emergency stop is engaged"), "{err}");
    drop(rig);
    // Released: it starts again.
    let mut r = Raw::open(&q.path);
    r.test(frame::testing::op::ESTOP, &[0]);
    start(&mut r);
}

/// One event of a session as both devices must produce it.
#[derive(Debug, Clone, PartialEq)]
enum Event {
    Hello {
        version: u16,
        rate: u32,
        watchdog_ms: u16,
        batch: u8,
    },
    Fault(u8),
    Status(DeviceState, u64),
    Samples(Vec<(u64, u8)>),
}

/// The normalised events of a session: sequence numbers relative to
/// `base`, consecutive SAMPLES merged, STATUS "running, nothing owed"
/// dropped (how often a waiting device repeats it depends on timing).
fn events(g: &[(u8, Vec<u8>)], base: u64) -> Vec<Event> {
    let mut out: Vec<Event> = Vec::new();
    let mut next = 0u64; // relative sequence number after the last sample
    for (t, p) in g {
        let e = match *t {
            ty::HELLO => {
                let h = frame::parse_hello(p).expect("HELLO");
                Event::Hello {
                    version: h.version,
                    rate: h.sample_rate_hz,
                    watchdog_ms: h.watchdog_ms,
                    batch: h.batch,
                }
            }
            ty::FAULT => Event::Fault(FaultReport::parse(p).expect("FAULT").code),
            ty::STATUS => {
                let s = Status::parse(p).expect("STATUS");
                let rel = u64::from(s.next_seq).wrapping_sub(base);
                // "Running, every sample up to here sent": the answer to
                // START (checked by the session itself) or a report while
                // waiting, repeated every 10 ms — timing, not behaviour.
                if s.state == DeviceState::Running && rel == next {
                    continue;
                }
                Event::Status(s.state, rel)
            }
            ty::SAMPLES => {
                let (s, n) = frame::block_header::<DaqSample>(p).expect("SAMPLES");
                let v: Vec<(u64, u8)> = (0..n)
                    .map(|i| {
                        let x: DaqSample = frame::block_item(p, i);
                        (u64::from(s) + i as u64 - base, x.flags)
                    })
                    .collect();
                next = v.last().map_or(next, |(q, _)| q + 1);
                if let Some(Event::Samples(prev)) = out.last_mut() {
                    prev.extend(v);
                    continue;
                }
                Event::Samples(v)
            }
            _ => continue,
        };
        out.push(e);
    }
    out
}

/// The scripted session (every step waits for its answer): handshake,
/// version mismatch, commands while idle, unknown and malformed frames,
/// START, 300 commands (one of them −32768: LIMITED), a stale and a far
/// command, silence until the watchdog trips, commands while tripped,
/// START, 50 more samples, STOP. Returns the frames and the base sequence.
fn session(path: &str) -> (Frames, u64, Vec<(u64, DaqSample)>) {
    let mut r = Raw::open(path);
    let count = |t: u8| move |g: &[(u8, Vec<u8>)]| g.iter().filter(|(x, _)| *x == t).count();
    r.send(ty::HELLO_REQ, &2u16.to_le_bytes());
    r.until("HELLO", |g| count(ty::HELLO)(g) == 1);
    r.send(ty::HELLO_REQ, &1u16.to_le_bytes());
    r.until("second HELLO", |g| count(ty::HELLO)(g) == 2);
    r.commands(0, &[DaqCommand::default(); 3]);
    r.until("NOT_RUNNING", |g| has_fault(g, fault::NOT_RUNNING));
    let faults = |g: &[(u8, Vec<u8>)]| count(ty::FAULT)(g);
    let f0 = faults(&r.got);
    r.send(0x30, b"?");
    r.send(ty::RESET, &[0; 5]);
    r.send(ty::RESET, &[0; 6]);
    r.send(ty::HEARTBEAT, &[0; 4]);
    r.until("two BAD_FRAME", |g| faults(g) == f0 + 2);
    let s = start(&mut r);
    let cmds: Vec<DaqCommand> = (0..300)
        .map(|i| {
            let x = (i as f64 * 0.05).sin();
            DaqCommand {
                force: [(6000.0 * x) as i16, if i == 123 { i16::MIN } else { -1000 }],
                drive: (3000.0 * (i as f64 * 0.9).sin()) as i16,
            }
        })
        .collect();
    r.commands(s, &cmds);
    r.until("300 samples", |g| samples(g).len() >= 300);
    let f1 = faults(&r.got);
    r.commands(s + 5, &cmds[..2]);
    r.until("LATE", |g| faults(g) == f1 + 1);
    r.commands(s + 300 + 100_000, &cmds[..2]);
    r.until("OVERFLOW", |g| faults(g) == f1 + 2);
    r.until("watchdog", |g| has_fault(g, fault::WATCHDOG));
    r.until("STATUS tripped", |g| {
        g.iter().any(|(t, p)| {
            *t == ty::STATUS && Status::parse(p).is_some_and(|x| x.state == DeviceState::Tripped)
        })
    });
    let f2 = faults(&r.got);
    r.commands(s + 300, &cmds[..2]);
    r.until("NOT_RUNNING", |g| faults(g) == f2 + 1);
    let s2 = start(&mut r);
    r.commands(s2, &cmds[..50]);
    r.until("50 more samples", |g| samples(g).len() >= 350);
    r.send(ty::STOP, &[]);
    r.until("STATUS idle", |g| {
        g.iter().rev().take(3).any(|(t, p)| {
            *t == ty::STATUS && Status::parse(p).is_some_and(|x| x.state == DeviceState::Idle)
        })
    });
    let smp = samples(&r.got);
    (r.got, s, smp)
}

#[test]
fn the_emulator_and_the_firmware_agree_on_every_frame_of_a_recorded_session() {
    let Some(elf) = elf("session") else { return };
    let q = Qemu::boot(&elf);
    let (fw, fw_base, fw_s) = session(&q.path);
    // The QEMU build's watchdog window (HELLO): 5 s.
    let emu = Emulator::spawn("daq", &["--watchdog-ms", "5000"]);
    let (em, em_base, em_s) = session(&emu.path);
    let (a, b) = (events(&fw, fw_base), events(&em, em_base));
    assert_eq!(a.len(), b.len(), "firmware {a:?}\nemulator {b:?}");
    for (i, (x, y)) in a.iter().zip(&b).enumerate() {
        assert_eq!(x, y, "event {i}");
    }
    // The flags include LIMITED on the −32768 command and nothing else.
    let limited: Vec<u64> = fw_s
        .iter()
        .filter(|(_, x)| x.flags & flag::LIMITED != 0)
        .map(|(q, _)| q - fw_base)
        .collect();
    assert_eq!(limited, [123]);
    // The same plant behind both: encoder counts within 2, accelerations
    // within the emulator's sensor noise.
    let (mut enc, mut acc, mut sig) = (0i64, 0.0f64, 0.0f64);
    for ((_, x), (_, y)) in fw_s.iter().zip(&em_s) {
        for k in 0..2 {
            enc = enc.max(i64::from(x.enc[k] - y.enc[k]).abs());
        }
        acc += f64::from(x.acc[0] - y.acc[0]).powi(2);
        sig += f64::from(y.acc[0]).powi(2);
    }
    let n = fw_s.len().min(em_s.len()) as f64;
    let (acc, sig) = ((acc / n).sqrt(), (sig / n).sqrt());
    eprintln!(
        "session: {} events; |Δenc| ≤ {enc}; accel x RMS difference {acc:.1} codes of {sig:.1}",
        a.len()
    );
    assert!(enc <= 2, "encoder counts differ by {enc}");
    assert!(
        acc < 0.2 * sig,
        "accelerations differ: RMS {acc} of {sig} codes"
    );
}
