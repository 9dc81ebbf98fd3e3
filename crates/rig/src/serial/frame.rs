//! The wire format of the live-rig protocol (`docs/PROTOCOL.md`) on the
//! host: the definitions of the `kilotouch-proto` crate (framing, CRC,
//! items, the resynchronising [`Decoder`], sequence extension), which the
//! firmware shares, with the host's conveniences around them: frames
//! appended to a `Vec<u8>` and an owned [`Hello`].

use crate::condition::Condition;
use crate::coupling::mapping::HandMapping;
use crate::device::{HostInfo, PhaseCode, TaskCode, TrialInfo, VisualFrame};
use kilotouch_proto::info::{Info, TrialBegin, View};

pub use kilotouch_proto::{
    CRC16, Caps, DaqCaps, DaqCommand, DaqSample, Decoder, DecoderStats, DeviceKind, DeviceState,
    FaultReport, FrameRef, HEADER, MAX_FRAME, MAX_PAYLOAD, MAX_SCENE_OBSTACLES, PROTOCOL_VERSION,
    SYNC, Scene, SceneObstacle, Status, TRAILER, TrapCommand, TweezerCaps, TweezerWireSample,
    WireItem, block_header, block_item, fault, flag, max_items, testing, tweezer_status, ty,
    unwrap_seq,
};

/// Handshake answer (device → host, [`ty::HELLO`]): the owned form of
/// [`kilotouch_proto::Hello`], whose identity strings borrow.
#[derive(Debug, Clone, PartialEq)]
pub struct Hello {
    /// Protocol version of the device.
    pub version: u16,
    /// Sample rate, Hz.
    pub sample_rate_hz: u32,
    /// Watchdog window, ms.
    pub watchdog_ms: u16,
    /// Samples per device frame at most.
    pub batch: u8,
    /// Capabilities (the kind follows from the variant).
    pub caps: Caps,
    /// Device name (UTF-8, ≤ 255 bytes on the wire).
    pub name: String,
    /// Serial number.
    pub serial: String,
    /// Firmware version.
    pub firmware: String,
}

impl Hello {
    /// The handshake of one of kilotouch's own emulators (current protocol
    /// version, no device watchdog, no batching): `tool` names it in the
    /// firmware string (`kilotouch emulate daq 0.1.0`).
    pub fn emulator(sample_rate_hz: u32, caps: Caps, name: &str, serial: &str, tool: &str) -> Self {
        Self {
            version: PROTOCOL_VERSION,
            sample_rate_hz,
            watchdog_ms: 0,
            batch: 0,
            caps,
            name: name.to_owned(),
            serial: serial.to_owned(),
            firmware: format!("kilotouch emulate {tool} {}", env!("CARGO_PKG_VERSION")),
        }
    }

    /// Device kind.
    pub fn kind(&self) -> DeviceKind {
        self.caps.kind()
    }

    /// The wire form, borrowing the strings.
    pub fn wire(&self) -> kilotouch_proto::Hello<'_> {
        kilotouch_proto::Hello {
            version: self.version,
            sample_rate_hz: self.sample_rate_hz,
            watchdog_ms: self.watchdog_ms,
            batch: self.batch,
            caps: self.caps,
            name: self.name.as_bytes(),
            serial: self.serial.as_bytes(),
            firmware: self.firmware.as_bytes(),
        }
    }

    /// The owned form of a parsed HELLO (invalid UTF-8 replaced by U+FFFD).
    pub fn from_wire(h: &kilotouch_proto::Hello<'_>) -> Self {
        let s = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
        Self {
            version: h.version,
            sample_rate_hz: h.sample_rate_hz,
            watchdog_ms: h.watchdog_ms,
            batch: h.batch,
            caps: h.caps,
            name: s(h.name),
            serial: s(h.serial),
            firmware: s(h.firmware),
        }
    }
}

/// Append one frame of type `ty` whose payload is written by `body`
/// (which must append at most [`MAX_PAYLOAD`] bytes; more is truncated to
/// keep the frame valid). Allocation-free when `out` has the capacity.
pub fn write_frame(out: &mut Vec<u8>, ty: u8, body: impl FnOnce(&mut Vec<u8>)) {
    let start = out.len();
    out.extend_from_slice(&[0; HEADER]);
    body(out);
    let plen = (out.len() - start - HEADER).min(MAX_PAYLOAD);
    out.truncate(start + HEADER + plen);
    out.extend_from_slice(&[0; TRAILER]);
    // The length is within MAX_PAYLOAD, so sealing cannot fail.
    let _ = kilotouch_proto::frame::seal(&mut out[start..], ty);
}

/// Append the encoding of one item.
pub fn put_item<T: WireItem>(out: &mut Vec<u8>, item: &T) {
    let at = out.len();
    out.resize(at + T::SIZE, 0);
    item.encode(&mut out[at..]);
}

/// Append a block frame `seq u32, n u8, n × item` (at most
/// [`max_items`]`::<T>()` items are written).
pub fn write_block<T: WireItem>(out: &mut Vec<u8>, ty: u8, seq: u32, items: &[T]) {
    let n = items.len().min(max_items::<T>());
    let start = out.len();
    out.resize(start + kilotouch_proto::block_len::<T>(n), 0);
    // Sized for `n` items above, so encoding cannot fail.
    let _ = kilotouch_proto::encode_block(&mut out[start..], ty, seq, &items[..n]);
}

/// Append a HELLO frame.
pub fn write_hello(out: &mut Vec<u8>, h: &Hello) {
    let w = h.wire();
    write_frame(out, ty::HELLO, |o| {
        let at = o.len();
        o.resize(at + w.size(), 0);
        let _ = w.encode(&mut o[at..]);
    });
}

/// Parse a HELLO payload.
pub fn parse_hello(payload: &[u8]) -> Option<Hello> {
    kilotouch_proto::Hello::parse(payload).map(|h| Hello::from_wire(&h))
}

/// Append a STATUS frame.
pub fn write_status(out: &mut Vec<u8>, s: &Status) {
    write_frame(out, ty::STATUS, |o| o.extend_from_slice(&s.encode()));
}

/// Parse a STATUS payload.
pub fn parse_status(payload: &[u8]) -> Option<Status> {
    Status::parse(payload)
}

/// Append a FAULT frame.
pub fn write_fault(out: &mut Vec<u8>, f: &FaultReport) {
    write_frame(out, ty::FAULT, |o| o.extend_from_slice(&f.encode()));
}

/// Parse a FAULT payload.
pub fn parse_fault(payload: &[u8]) -> Option<FaultReport> {
    FaultReport::parse(payload)
}

/// Append a SCENE frame (a tweezer's bead radius and obstacles).
pub fn write_scene(out: &mut Vec<u8>, s: &Scene) {
    write_frame(out, ty::SCENE, |o| {
        let at = o.len();
        o.resize(at + s.size(), 0);
        let _ = s.encode(&mut o[at..]);
    });
}

/// Parse a SCENE payload.
pub fn parse_scene(payload: &[u8]) -> Option<Scene> {
    Scene::parse(payload)
}

/// Append an INFO frame: what the host tells the device about the
/// experiment ([`HostInfo`], `docs/PROTOCOL.md` §5.5).
pub fn write_info(out: &mut Vec<u8>, info: &HostInfo) {
    let w = info_to_wire(info);
    write_frame(out, ty::INFO, |o| {
        let at = o.len();
        o.resize(at + w.size(), 0);
        let _ = w.encode(&mut o[at..]);
    });
}

/// Parse an INFO payload (`None`: unknown kind, wrong length, or a code out
/// of range).
pub fn parse_info(payload: &[u8]) -> Option<HostInfo> {
    match Info::parse(payload)? {
        Info::TrialEnd => Some(HostInfo::TrialEnd),
        Info::View(v) => Some(HostInfo::View(VisualFrame {
            seq: u64::from(v.seq),
            captured_s: v.captured_s,
            bead_m: v.bead_m,
            trap_m: v.trap_m,
            obstacle_m: v.obstacle_m,
            obstacle_radius_m: v.obstacle_radius_m,
            bead_radius_m: v.bead_radius_m,
        })),
        Info::TrialBegin(t) => {
            let m = t.mapping;
            Some(HostInfo::TrialBegin(TrialInfo {
                participant: t.participant,
                condition: match t.condition {
                    0 => Condition::V,
                    1 => Condition::P,
                    2 => Condition::D,
                    _ => return None,
                },
                phase: match t.phase {
                    0 => PhaseCode::Practice,
                    1 => PhaseCode::Test,
                    _ => return None,
                },
                index: t.index,
                task: match t.task {
                    0 => TaskCode::Circling,
                    1 => TaskCode::BlindNavigation,
                    _ => return None,
                },
                mapping: HandMapping {
                    scale: m[0],
                    handle_origin_m: [m[1], m[2]],
                    trap_offset_m: [m[3], m[4]],
                    trap_min_m: [m[5], m[6]],
                    trap_max_m: [m[7], m[8]],
                    force_scale: m[9],
                },
                start_trap_m: t.start_trap_m,
                heading: t.heading,
                retreat_distance_m: t.retreat_m,
                first_seq: u64::from(t.first_seq),
            }))
        }
    }
}

fn info_to_wire(info: &HostInfo) -> Info {
    match info {
        HostInfo::TrialEnd => Info::TrialEnd,
        HostInfo::View(v) => Info::View(View {
            seq: v.seq as u32,
            captured_s: v.captured_s,
            bead_m: v.bead_m,
            trap_m: v.trap_m,
            obstacle_m: v.obstacle_m,
            obstacle_radius_m: v.obstacle_radius_m,
            bead_radius_m: v.bead_radius_m,
        }),
        HostInfo::TrialBegin(t) => {
            let m = &t.mapping;
            Info::TrialBegin(TrialBegin {
                participant: t.participant,
                condition: match t.condition {
                    Condition::V => 0,
                    Condition::P => 1,
                    Condition::D => 2,
                },
                phase: match t.phase {
                    PhaseCode::Practice => 0,
                    PhaseCode::Test => 1,
                },
                index: t.index,
                task: match t.task {
                    TaskCode::Circling => 0,
                    TaskCode::BlindNavigation => 1,
                },
                mapping: [
                    m.scale,
                    m.handle_origin_m[0],
                    m.handle_origin_m[1],
                    m.trap_offset_m[0],
                    m.trap_offset_m[1],
                    m.trap_min_m[0],
                    m.trap_min_m[1],
                    m.trap_max_m[0],
                    m.trap_max_m[1],
                    m.force_scale,
                ],
                start_trap_m: t.start_trap_m,
                heading: t.heading,
                retreat_m: t.retreat_distance_m,
                first_seq: t.first_seq as u32,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn worked_example_of_the_protocol_document() {
        // docs/PROTOCOL.md, "Worked example": START, then one COMMANDS frame
        // (seq 0x01020304; +2.5 N, −2.5 N on a 5 N Pantograph; +1 V of 10 V).
        let mut out = Vec::new();
        write_frame(&mut out, ty::START, |_| {});
        assert_eq!(out, [0xA5, 0x5A, 0x00, 0x00, 0x02, 0xDE, 0xEC]);
        out.clear();
        let cmd = DaqCommand {
            force: [
                super::super::emulator::value_to_code(2.5, 5.0).0,
                super::super::emulator::value_to_code(-2.5, 5.0).0,
            ],
            drive: super::super::emulator::value_to_code(1.0, 10.0).0,
        };
        // 2.5/5·32767 = 16383.5 → 16384 (half away from zero); 1/10·32767 → 3277.
        assert_eq!(cmd.force, [16384, -16384]);
        assert_eq!(cmd.drive, 3277);
        write_block(&mut out, ty::COMMANDS, 0x0102_0304, &[cmd]);
        let hex: Vec<String> = out.iter().map(|b| format!("{b:02X}")).collect();
        assert_eq!(
            hex.join(" "),
            "A5 5A 0B 00 04 04 03 02 01 01 00 40 00 C0 CD 0C 30 8D"
        );
        let mut d = Decoder::new();
        d.push(&out);
        let f = d.next_frame().unwrap();
        assert_eq!(f.ty, ty::COMMANDS);
        let (seq, n) = block_header::<DaqCommand>(f.payload).unwrap();
        assert_eq!((seq, n), (0x0102_0304, 1));
        assert_eq!(block_item::<DaqCommand>(f.payload, 0), cmd);
    }

    #[test]
    fn messages_round_trip() {
        let h = Hello {
            version: PROTOCOL_VERSION,
            sample_rate_hz: 10_000,
            watchdog_ms: 100,
            batch: 10,
            caps: Caps::Daq(DaqCaps {
                encoder_counts_per_m: 1e5,
                accel_m_s2_per_code: 1.4528e-2,
                accel_range_m_s2: 58.8399,
                force_max_n: 5.0,
                drive_max_v: 10.0,
            }),
            name: "rig é".into(),
            serial: "0001".into(),
            firmware: "emu 1".into(),
        };
        let st = Status {
            next_seq: 77,
            state: DeviceState::Tripped,
            host_frames: 5,
            host_crc_errors: 2,
            late_commands: 1,
        };
        let fr = FaultReport {
            code: fault::WATCHDOG,
            seq: 9,
        };
        let s = DaqSample {
            enc: [-5, 123_456],
            acc: [-4050, 675, 1],
            flags: flag::CLIPPED,
        };
        let t = TweezerWireSample {
            bead_m: [1e-8, -3.5e-7],
            sum_v: 0.75,
            detector_v: [0.125, -2.5],
            status: tweezer_status::TRAPPED,
        };
        let mut out = Vec::new();
        write_hello(&mut out, &h);
        write_status(&mut out, &st);
        write_fault(&mut out, &fr);
        write_block(&mut out, ty::SAMPLES, 3, &[s, s]);
        write_block(&mut out, ty::TWEEZER_SAMPLES, 4, &[t]);
        let mut d = Decoder::new();
        d.push(&out);
        assert_eq!(parse_hello(d.next_frame().unwrap().payload).unwrap(), h);
        assert_eq!(parse_status(d.next_frame().unwrap().payload).unwrap(), st);
        assert_eq!(parse_fault(d.next_frame().unwrap().payload).unwrap(), fr);
        let f = d.next_frame().unwrap();
        assert_eq!(block_header::<DaqSample>(f.payload), Some((3, 2)));
        assert_eq!(block_item::<DaqSample>(f.payload, 1), s);
        let f = d.next_frame().unwrap();
        assert_eq!(block_item::<TweezerWireSample>(f.payload, 0), t);
        assert!(d.next_frame().is_none());
        assert_eq!(d.stats().frames, 5);
        assert_eq!(d.stats().crc_errors, 0);
    }

    /// A genuine long frame whose payload is full of sync markers, arriving
    /// a byte at a time, is decoded whole: partial frames are not abandoned
    /// for lack of a later valid frame.
    #[test]
    fn a_long_frame_full_of_sync_markers_arrives_whole() {
        let payload: Vec<u8> = (0..1000).map(|i| SYNC[i % 2]).collect();
        let mut stream = Vec::new();
        write_frame(&mut stream, ty::HEARTBEAT, |o| {
            o.extend_from_slice(&payload)
        });
        let mut d = Decoder::new();
        for (i, b) in stream.iter().enumerate() {
            d.push(std::slice::from_ref(b));
            match d.next_frame() {
                Some(f) => {
                    assert_eq!(i, stream.len() - 1, "decoded early");
                    assert_eq!(f.payload, &payload[..]);
                }
                None => assert!(i < stream.len() - 1, "not decoded"),
            }
        }
        assert_eq!(d.stats().frames, 1);
        assert_eq!(d.stats().bad_lengths + d.stats().crc_errors, 0);
    }
}
