//! The host side of the protocol's test frames (`docs/PROTOCOL.md` §13):
//! configuring a test build of the firmware (`firmware/`, feature `qemu`)
//! — its plant model from a rig file, the late-command policy, a simulated
//! emergency stop, fault injection — and reading its interrupt's cost
//! counters. Used by `kilotouch firmware …` and the QEMU tests.
//!
//! The plant is the rig file's plant as parallel second-order sections
//! ([`crate::plant::sections`]), its accelerometer (pole, static offset,
//! range, step; no noise) and the output scales of the emulator's DAQ
//! ([`super::emulator::DaqInstrument`]), so that the firmware announces
//! the same capabilities as `kilotouch emulate daq` with that rig file.

use super::emulator::DaqInstrument;
use super::frame::{self, Decoder, MAX_FRAME, ty};
use crate::accel::Accelerometer;
use crate::config::RigConfig;
use crate::error::RigError;
use crate::plant::Axis;
use crate::plant::sections::{ChannelInput, ChannelOutput, plant_sections};
use kilotouch_proto::testing::{self, Ack, PlantSensors, Profile, Section, input, output};
use serialport::SerialPort;
use std::io::{ErrorKind, Read, Write};
use std::time::{Duration, Instant};

/// How long to wait for each TEST_ACK (QEMU can hold the host's bytes up
/// for seconds on a loaded machine).
pub const ACK_TIMEOUT: Duration = Duration::from_secs(20);

/// A port to a device that takes test frames.
pub struct TestLink {
    path: String,
    port: Box<dyn SerialPort>,
    decoder: Decoder,
    tx: Vec<u8>,
}

impl std::fmt::Debug for TestLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TestLink")
            .field("path", &self.path)
            .finish()
    }
}

/// What [`TestLink::load_plant`] loaded.
#[derive(Debug, Clone, PartialEq)]
pub struct PlantLoad {
    /// Sections per channel, in the order x force → accel, x force →
    /// handle, x drive → accel, x drive → handle, y force → accel, y force
    /// → handle.
    pub sections_per_channel: Vec<usize>,
    /// Sections in the device after the commit.
    pub total: u32,
    /// The sensors and scales sent.
    pub sensors: PlantSensors,
}

/// Late-command policy of a test build.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Policy {
    /// Wait for late commands (emulator semantics).
    Wait,
    /// Hold the previous command and flag CMD_LATE (a free-running device).
    Hold,
}

impl TestLink {
    /// Open `path` (any baud: the test build ignores it).
    pub fn open(path: &str) -> Result<Self, RigError> {
        let port = serialport::new(path, 2_000_000)
            .timeout(Duration::from_millis(20))
            .open()
            .map_err(|e| RigError::Disconnected(format!("cannot open serial port {path}: {e}")))?;
        let _ = port.clear(serialport::ClearBuffer::Input);
        let mut link = Self {
            path: path.to_owned(),
            port,
            decoder: Decoder::new(),
            tx: Vec::with_capacity(MAX_FRAME),
        };
        link.hello()?;
        Ok(link)
    }

    /// Repeat HELLO_REQ every 250 ms until a HELLO comes back (a device
    /// that is still booting — QEMU creates the pty before the firmware
    /// runs — loses what it is sent before its USART is on), at most
    /// [`ACK_TIMEOUT`].
    fn hello(&mut self) -> Result<(), RigError> {
        let deadline = Instant::now() + ACK_TIMEOUT;
        let mut buf = [0u8; 1024];
        while Instant::now() < deadline {
            self.tx.clear();
            frame::write_frame(&mut self.tx, ty::HELLO_REQ, |o| {
                o.extend_from_slice(&frame::PROTOCOL_VERSION.to_le_bytes())
            });
            self.port
                .write_all(&self.tx)
                .map_err(|e| RigError::Disconnected(format!("{}: write failed: {e}", self.path)))?;
            let step = Instant::now() + Duration::from_millis(250);
            while Instant::now() < step {
                match self.port.read(&mut buf) {
                    Ok(n) if n > 0 => {
                        self.decoder.push(&buf[..n]);
                    }
                    Ok(_) => {}
                    Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock) => {}
                    Err(e) => return Err(RigError::Disconnected(format!("{}: {e}", self.path))),
                }
                while let Some(f) = self.decoder.next_frame() {
                    if f.ty == ty::HELLO {
                        return Ok(());
                    }
                }
            }
        }
        Err(RigError::Disconnected(format!(
            "{}: no HELLO within {} s (is the firmware running?)",
            self.path,
            ACK_TIMEOUT.as_secs()
        )))
    }

    /// Send TEST `op` with `args`; the ack (checked to be OK) and its data.
    pub fn request(&mut self, op: u8, args: &[u8]) -> Result<(Ack, Vec<u8>), RigError> {
        self.tx.clear();
        frame::write_frame(&mut self.tx, ty::TEST, |o| {
            o.push(op);
            o.extend_from_slice(args);
        });
        self.port
            .write_all(&self.tx)
            .map_err(|e| RigError::Disconnected(format!("{}: write failed: {e}", self.path)))?;
        let deadline = Instant::now() + ACK_TIMEOUT;
        let mut buf = [0u8; 1024];
        loop {
            while let Some(f) = self.decoder.next_frame() {
                if f.ty == ty::FAULT
                    && let Some(fr) = frame::parse_fault(f.payload)
                    && fr.code == frame::fault::BAD_FRAME
                {
                    return Err(RigError::Device(format!(
                        "{}: the device refuses test frames (not a test build of the firmware?)",
                        self.path
                    )));
                }
                if f.ty == ty::TEST_ACK
                    && let Some((ack, data)) = Ack::parse(f.payload)
                    && ack.op == op
                {
                    if ack.result != testing::result::OK {
                        return Err(RigError::Device(format!(
                            "{}: test operation {op:#04x} refused: {}",
                            self.path,
                            result_name(ack.result)
                        )));
                    }
                    return Ok((ack, data.to_vec()));
                }
            }
            if Instant::now() >= deadline {
                return Err(RigError::Disconnected(format!(
                    "{}: no answer to test operation {op:#04x} within {} s",
                    self.path,
                    ACK_TIMEOUT.as_secs()
                )));
            }
            match self.port.read(&mut buf) {
                Ok(0) => {
                    return Err(RigError::Disconnected(format!(
                        "{}: end of file on the port",
                        self.path
                    )));
                }
                Ok(n) => {
                    self.decoder.push(&buf[..n]);
                }
                Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock) => {}
                Err(e) => {
                    return Err(RigError::Disconnected(format!("{}: {e}", self.path)));
                }
            }
        }
    }

    /// Load the plant of `cfg` (module docs): clear, sensors, every
    /// section, commit. The device must be idle.
    pub fn load_plant(&mut self, cfg: &RigConfig) -> Result<PlantLoad, RigError> {
        let (sections, sensors, per_channel) = plant_frames(cfg)?;
        self.request(testing::op::PLANT_CLEAR, &[])?;
        self.request(testing::op::PLANT_SENSORS, &sensors.encode())?;
        for s in &sections {
            self.request(testing::op::PLANT_SECTION, &s.encode())?;
        }
        let (ack, _) = self.request(testing::op::PLANT_COMMIT, &[])?;
        Ok(PlantLoad {
            sections_per_channel: per_channel,
            total: ack.value,
            sensors,
        })
    }

    /// Set the late-command policy (idle device).
    pub fn set_policy(&mut self, p: Policy) -> Result<(), RigError> {
        let m = match p {
            Policy::Wait => 0,
            Policy::Hold => 1,
        };
        self.request(testing::op::MODE, &[m]).map(|_| ())
    }

    /// Engage or release the simulated emergency-stop input.
    pub fn set_estop(&mut self, engaged: bool) -> Result<(), RigError> {
        self.request(testing::op::ESTOP, &[u8::from(engaged)])
            .map(|_| ())
    }

    /// Fault injection on the device → host bytes: probabilities per byte
    /// (0 ..= 1, resolved to parts per million) and the generator's seed.
    pub fn set_faults(&mut self, corrupt: f64, drop: f64, seed: u32) -> Result<(), RigError> {
        let ppm = |name: &'static str, p: f64| {
            if (0.0..=1.0).contains(&p) {
                Ok((p * 1e6).round() as u32)
            } else {
                Err(RigError::InvalidParameter {
                    name,
                    value: p,
                    reason: "must be a probability in [0, 1]".into(),
                })
            }
        };
        let mut a = Vec::with_capacity(12);
        a.extend_from_slice(&ppm("corrupt_rate", corrupt)?.to_le_bytes());
        a.extend_from_slice(&ppm("drop_rate", drop)?.to_le_bytes());
        a.extend_from_slice(&seed.to_le_bytes());
        self.request(testing::op::FAULTS, &a).map(|_| ())
    }

    /// The command the device's outputs carry now.
    pub fn outputs(&mut self) -> Result<frame::DaqCommand, RigError> {
        let (_, data) = self.request(testing::op::OUTPUTS, &[])?;
        if data.len() != 6 {
            return Err(RigError::Device(format!(
                "{}: malformed outputs",
                self.path
            )));
        }
        Ok(<frame::DaqCommand as frame::WireItem>::decode(&data))
    }

    /// The sample interrupt's cost counters (reset after reading when
    /// `reset`).
    pub fn profile(&mut self, reset: bool) -> Result<Profile, RigError> {
        let (_, data) = self.request(testing::op::PROFILE, &[u8::from(reset)])?;
        Profile::parse(&data)
            .ok_or_else(|| RigError::Device(format!("{}: malformed profile", self.path)))
    }
}

fn result_name(r: u8) -> &'static str {
    match r {
        testing::result::BAD_ARGUMENT => "bad argument",
        testing::result::FULL => "no room for another plant section",
        testing::result::BUSY => "the device is running (send STOP first)",
        testing::result::UNSTABLE => "unstable plant section",
        testing::result::UNSUPPORTED => "not supported by this build",
        _ => "unknown result",
    }
}

/// The test-frame arguments of `cfg`'s plant: the sections, the sensors,
/// and the number of sections per channel (order of [`PlantLoad`]).
pub fn plant_frames(cfg: &RigConfig) -> Result<(Vec<Section>, PlantSensors, Vec<usize>), RigError> {
    let fs = cfg.rig.sample_rate_hz;
    let caps = DaqInstrument::new(cfg)?.caps();
    let accel = Accelerometer::new(&cfg.accelerometer, fs)?;
    let sensors = PlantSensors {
        accel_alpha: accel.alpha(),
        accel_offset_m_s2: accel.offset_m_s2(),
        accel_range_m_s2: caps.accel_range_m_s2,
        accel_m_s2_per_code: caps.accel_m_s2_per_code,
        encoder_counts_per_m: caps.encoder_counts_per_m,
        force_max_n: caps.force_max_n,
        drive_max_v: caps.drive_max_v,
    };
    let mut sections = Vec::new();
    let mut per_channel = Vec::new();
    for ch in plant_sections(cfg)? {
        let inp = match (ch.axis, ch.input) {
            (Axis::X, ChannelInput::Force) => input::FORCE_X,
            (Axis::Y, ChannelInput::Force) => input::FORCE_Y,
            (_, ChannelInput::Drive) => input::DRIVE,
        };
        let out = match (ch.axis, ch.output) {
            (Axis::X, ChannelOutput::Accel) => output::ACCEL_X,
            (Axis::Y, ChannelOutput::Accel) => output::ACCEL_Y,
            (Axis::X, ChannelOutput::Handle) => output::HANDLE_X,
            (Axis::Y, ChannelOutput::Handle) => output::HANDLE_Y,
        };
        per_channel.push(ch.sections.len());
        sections.extend(ch.sections.iter().map(|c| Section {
            input: inp,
            output: out,
            b: [c.b0, c.b1, c.b2],
            a: [c.a1, c.a2],
        }));
    }
    Ok((sections, sensors, per_channel))
}
