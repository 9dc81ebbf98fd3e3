//! Lab Streaming Layer outlets (the `lsl` feature): the engine's samples
//! and events on the lab's common clock, for LabRecorder next to EEG, eye
//! trackers and cameras (docs/LSL.md).
//!
//! ```text
//!  engine thread                                 LSL publisher thread
//!  ─────────────                                 ────────────────────
//!  Publisher ── LslRecord (rtrb, LSL_RING) ────▶ drains every 2 ms:
//!    every `every`-th sample + its LSL time        signal outlet (float32)
//!    contact / escape / e-stop / trial markers     marker outlet (string)
//!  a full ring drops the record and counts it  ◀── non-real-time markers
//!                                                  (sitting start/end, notes)
//! ```
//!
//! The engine only reads the LSL clock ([`lsl::local_clock`], a clock read)
//! and pushes fixed-size [`LslRecord`]s into a bounded lock-free ring: no
//! allocation, no lock, no network in the loop. Strings are made and the
//! outlets fed on the publisher thread, which owns the outlets (liblsl's
//! handles are not `Send`). Markers from other threads ([`LslMarkers`]:
//! a sitting's start and end, notes — [`LslSitting`], shared by `study run
//! --lsl` and the Study page) are stamped when sent and merged with the
//! engine's records in time order.

/// The liblsl bindings the outlets use (for inlets in tests and tools).
pub use ::lsl as sys;

use kilotouch_rig::LoopSample;
use kilotouch_study::seeds::TrialKey;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, mpsc};
use std::thread::JoinHandle;
use std::time::Duration;

/// Capacity of the engine → publisher ring, records (about 16 s of the
/// signal stream at 1 kHz).
pub const LSL_RING: usize = 1 << 14;

/// Name of the marker stream.
pub const MARKER_STREAM: &str = "kilotouch-markers";
/// Name of the signal stream.
pub const SIGNAL_STREAM: &str = "kilotouch-signals";

/// Channels of the signal stream: label, unit, XDF type.
pub const SIGNAL_CHANNELS: [(&str, &str, &str); 13] = [
    ("handle_x", "m", "Position"),
    ("handle_y", "m", "Position"),
    ("force_x", "N", "Force"),
    ("force_y", "N", "Force"),
    ("haptuator", "V", "Control"),
    ("accel_x", "m/s^2", "Acceleration"),
    ("accel_y", "m/s^2", "Acceleration"),
    ("accel_z", "m/s^2", "Acceleration"),
    ("bead_x", "m", "Position"),
    ("bead_y", "m", "Position"),
    ("trap_x", "m", "Position"),
    ("trap_y", "m", "Position"),
    ("contact", "bool", "Flag"),
];

/// Number of signal channels.
pub const N_SIGNAL: usize = SIGNAL_CHANNELS.len();

/// An event of the engine thread (fixed size; its text is made on the
/// publisher thread).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Marker {
    /// A trial began.
    TrialStart(TrialKey),
    /// A trial ended.
    TrialEnd(TrialKey),
    /// The bead touched the obstacle.
    ContactStart,
    /// The contact ended.
    ContactEnd,
    /// The bead escaped the trap.
    Escape,
    /// The emergency stop latched.
    EmergencyStop,
    /// The running trial was paused.
    Pause,
    /// It was resumed.
    Resume,
}

impl Marker {
    /// The marker's text on the stream (`trial_start participant=P01
    /// condition=V phase=test trial=1`, `contact_start`, …); participant
    /// IDs have `id_width` digits, as the protocol writes them (2 up to 99
    /// participants).
    pub fn text(&self, id_width: usize) -> String {
        let trial = |what: &str, k: &TrialKey| {
            format!(
                "{what} participant=P{:0id_width$} condition={} phase={} trial={}",
                k.participant + 1,
                k.condition,
                k.phase,
                k.trial
            )
        };
        match self {
            Marker::TrialStart(k) => trial("trial_start", k),
            Marker::TrialEnd(k) => trial("trial_end", k),
            Marker::ContactStart => "contact_start".into(),
            Marker::ContactEnd => "contact_end".into(),
            Marker::Escape => "escape".into(),
            Marker::EmergencyStop => "emergency_stop".into(),
            Marker::Pause => "pause".into(),
            Marker::Resume => "resume".into(),
        }
    }
}

/// What the engine hands the publisher: one record, stamped with the LSL
/// clock (s) on the engine thread.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LslRecord {
    /// One decimated sample of the signal stream ([`SIGNAL_CHANNELS`]).
    Sample {
        /// LSL time, s.
        t: f64,
        /// The channels.
        ch: [f32; N_SIGNAL],
    },
    /// An event.
    Marker {
        /// LSL time, s.
        t: f64,
        /// What happened.
        m: Marker,
    },
}

/// Shared lock-free between the engine, its handle and the publisher.
#[derive(Debug)]
pub struct LslShared {
    /// Publishing: the engine pushes records only while set.
    pub on: AtomicBool,
    /// Decimation: every this many engine samples go to the signal stream.
    pub every: AtomicU32,
    /// Records dropped because the ring was full.
    pub dropped: AtomicU64,
    /// The marker outlet has a consumer.
    pub marker_consumer: AtomicBool,
    /// The signal outlet has a consumer.
    pub signal_consumer: AtomicBool,
    /// The ring's reading end, until a publisher takes it (the engine never
    /// touches this lock).
    pub(crate) rx: Mutex<Option<rtrb::Consumer<LslRecord>>>,
}

impl Default for LslShared {
    fn default() -> Self {
        Self {
            on: AtomicBool::new(false),
            every: AtomicU32::new(10),
            dropped: AtomicU64::new(0),
            marker_consumer: AtomicBool::new(false),
            signal_consumer: AtomicBool::new(false),
            rx: Mutex::new(None),
        }
    }
}

/// The engine's end: pushes records into the ring while publishing is on.
#[derive(Debug)]
pub struct LslTap {
    tx: rtrb::Producer<LslRecord>,
    shared: Arc<LslShared>,
    count: u32,
}

impl LslTap {
    /// A tap and its ring; the reading end waits in `shared` for
    /// [`LslPublisher::start`].
    pub fn new(shared: Arc<LslShared>) -> Self {
        let (tx, rx) = rtrb::RingBuffer::new(LSL_RING);
        if let Ok(mut slot) = shared.rx.lock() {
            *slot = Some(rx);
        }
        Self {
            tx,
            shared,
            count: 0,
        }
    }

    #[inline]
    fn push(&mut self, r: LslRecord) {
        if self.tx.push(r).is_err() {
            self.shared.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Publishing is on.
    #[inline]
    pub fn on(&self) -> bool {
        self.shared.on.load(Ordering::Relaxed)
    }

    /// An event now (engine thread; no allocation).
    #[inline]
    pub fn marker(&mut self, m: Marker) {
        if self.on() {
            let t = lsl::local_clock();
            self.push(LslRecord::Marker { t, m });
        }
    }

    /// One engine sample: its contact and escape events, and every
    /// `every`-th sample to the signal stream.
    #[inline]
    pub fn sample(&mut self, l: &LoopSample) {
        if !self.on() {
            return;
        }
        let e = l.tweezer.events;
        if e.contact_start {
            self.marker(Marker::ContactStart);
        }
        if e.contact_end {
            self.marker(Marker::ContactEnd);
        }
        if e.escaped {
            self.marker(Marker::Escape);
        }
        self.count += 1;
        if self.count < self.shared.every.load(Ordering::Relaxed).max(1) {
            return;
        }
        self.count = 0;
        let t = lsl::local_clock();
        let s = &l.tweezer;
        let c = &l.command;
        let a = l.sensors.accel_m_s2;
        let h = l.sensors.handle_m;
        let ch = [
            h[0],
            h[1],
            c.force_n[0],
            c.force_n[1],
            c.haptuator_v,
            a[0],
            a[1],
            a[2],
            s.bead_m[0],
            s.bead_m[1],
            s.trap_m[0],
            s.trap_m[1],
            f64::from(u8::from(s.in_contact)),
        ]
        .map(|v| v as f32);
        self.push(LslRecord::Sample { t, ch });
    }
}

/// Who the streams are about (XDF meta-data).
#[derive(Debug, Clone)]
pub struct LslIdentity {
    /// The study's name.
    pub study: String,
    /// The participant (`P01`).
    pub participant: String,
    /// Digits of the protocol's participant IDs (`P01`: 2).
    pub id_width: usize,
}

/// Why the outlets could not start.
#[derive(Debug, thiserror::Error)]
pub enum LslError {
    /// Another publisher already drains this engine's ring.
    #[error("the engine's LSL ring is already taken")]
    Taken,
    /// The requested signal rate is not within (0, engine rate].
    #[error("--lsl-rate-hz must be > 0 and at most the engine's rate {fs} Hz, got {rate}")]
    Rate {
        /// Requested, Hz.
        rate: f64,
        /// The engine's, Hz.
        fs: f64,
    },
    /// liblsl refused (the stream could not be created).
    #[error("liblsl: {0}")]
    Lsl(String),
}

/// The publisher thread and its outlets.
#[derive(Debug)]
pub struct LslPublisher {
    shared: Arc<LslShared>,
    notes: mpsc::Sender<(f64, String)>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    /// Nominal rate of the signal stream, Hz (the engine's rate over the
    /// decimation).
    pub signal_rate_hz: f64,
}

fn lsl_err(e: lsl::Error) -> LslError {
    LslError::Lsl(e.to_string())
}

fn outlets(
    id: &LslIdentity,
    rate: f64,
) -> Result<(lsl::StreamOutlet, lsl::StreamOutlet), LslError> {
    let source = format!("kilotouch-{}-{}", id.study, id.participant);
    let mut mi = lsl::StreamInfo::new(
        MARKER_STREAM,
        "Markers",
        1,
        lsl::IRREGULAR_RATE,
        lsl::ChannelFormat::String,
        &format!("{source}-markers"),
    )
    .map_err(lsl_err)?;
    let mut si = lsl::StreamInfo::new(
        SIGNAL_STREAM,
        "Haptics",
        N_SIGNAL as u32,
        rate,
        lsl::ChannelFormat::Float32,
        &format!("{source}-signals"),
    )
    .map_err(lsl_err)?;
    for info in [&mut mi, &mut si] {
        let mut d = info.desc();
        d.append_child_value("manufacturer", "kilotouch");
        d.append_child_value("study", &id.study);
        d.append_child_value("participant", &id.participant);
        d.append_child_value("version", env!("CARGO_PKG_VERSION"));
    }
    let mut chans = si.desc().append_child("channels");
    for (label, unit, kind) in SIGNAL_CHANNELS {
        let mut c = chans.append_child("channel");
        c.append_child_value("label", label);
        c.append_child_value("unit", unit);
        c.append_child_value("type", kind);
    }
    let m = lsl::StreamOutlet::new(&mi, 0, 360).map_err(lsl_err)?;
    let s = lsl::StreamOutlet::new(&si, 0, 60).map_err(lsl_err)?;
    Ok((m, s))
}

impl LslPublisher {
    /// Start publishing the engine's ring (`shared`, engine rate `fs` Hz)
    /// at about `rate_hz` on a thread of its own; the outlets exist when
    /// this returns.
    ///
    /// # Errors
    /// [`LslError`].
    pub fn start(
        shared: Arc<LslShared>,
        fs: f64,
        rate_hz: f64,
        id: LslIdentity,
    ) -> Result<Self, LslError> {
        if !(rate_hz.is_finite() && rate_hz > 0.0 && rate_hz <= fs) {
            return Err(LslError::Rate { rate: rate_hz, fs });
        }
        let every = (fs / rate_hz).round().max(1.0) as u32;
        let signal_rate_hz = fs / f64::from(every);
        let mut rx = shared
            .rx
            .lock()
            .ok()
            .and_then(|mut s| s.take())
            .ok_or(LslError::Taken)?;
        // Stale records from an earlier publisher.
        while rx.pop().is_ok() {}
        let (notes, notes_rx) = mpsc::channel::<(f64, String)>();
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = mpsc::channel::<Result<(), LslError>>();
        let th_shared = shared.clone();
        let th_stop = stop.clone();
        let thread = std::thread::Builder::new()
            .name("kilotouch-lsl".into())
            .spawn(move || {
                let (mo, so) = match outlets(&id, signal_rate_hz) {
                    Ok(o) => {
                        let _ = ready_tx.send(Ok(()));
                        o
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                let width = id.id_width.max(1);
                publish_loop(&mo, &so, &mut rx, &notes_rx, &th_shared, &th_stop, width);
                th_shared.on.store(false, Ordering::Release);
                if let Ok(mut slot) = th_shared.rx.lock() {
                    *slot = Some(rx);
                }
            })
            .map_err(|e| LslError::Lsl(e.to_string()))?;
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                let _ = thread.join();
                return Err(e);
            }
            Err(_) => {
                let _ = thread.join();
                return Err(LslError::Lsl("the publisher thread ended".into()));
            }
        }
        shared.every.store(every, Ordering::Relaxed);
        shared.on.store(true, Ordering::Release);
        Ok(Self {
            shared,
            notes,
            stop,
            thread: Some(thread),
            signal_rate_hz,
        })
    }

    /// A handle for markers from non-real-time threads (a sitting's start
    /// and end, notes: [`LslSitting`]) while this publisher runs.
    pub fn markers(&self) -> LslMarkers {
        LslMarkers {
            notes: self.notes.clone(),
            shared: self.shared.clone(),
        }
    }

    /// Records dropped because the ring was full (since the engine
    /// started, over all its publishers).
    pub fn dropped(&self) -> u64 {
        self.shared.dropped.load(Ordering::Relaxed)
    }

    /// Whether (markers, signals) have a consumer (LabRecorder, an inlet).
    pub fn consumers(&self) -> (bool, bool) {
        (
            self.shared.marker_consumer.load(Ordering::Relaxed),
            self.shared.signal_consumer.load(Ordering::Relaxed),
        )
    }

    /// Stop publishing: the engine stops pushing, the ring is drained into
    /// the outlets, the outlets close.
    pub fn stop(mut self) {
        self.finish();
    }

    fn finish(&mut self) {
        self.shared.on.store(false, Ordering::Release);
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for LslPublisher {
    fn drop(&mut self) {
        self.finish();
    }
}

/// A publisher's marker outlet seen from a non-real-time thread
/// ([`LslPublisher::markers`]): markers sent once the publisher has stopped
/// are lost.
#[derive(Debug, Clone)]
pub struct LslMarkers {
    notes: mpsc::Sender<(f64, String)>,
    shared: Arc<LslShared>,
}

impl LslMarkers {
    /// A marker, stamped now with the LSL clock. The publisher sends it
    /// after every engine record stamped before it, and before every one
    /// stamped after it: after the events that led to it, before those it
    /// led to.
    pub fn send(&self, text: &str) {
        let _ = self.notes.send((lsl::local_clock(), text.to_owned()));
    }

    /// Records the engine dropped because the ring was full (since the
    /// engine started).
    pub fn dropped(&self) -> u64 {
        self.shared.dropped.load(Ordering::Relaxed)
    }
}

/// One study sitting on the marker stream, for `study run --lsl` and the
/// Study page alike: `sitting_start` when it begins ([`Self::start`]), a
/// `note` marker for every journal note ([`Self::note`]), `sitting_end` and
/// the sitting's entry in the study folder's [`CLOCK_FILE`] when it ends
/// ([`Self::end`]).
#[derive(Debug)]
pub struct LslSitting {
    markers: LslMarkers,
    out: std::path::PathBuf,
    participant: String,
    study: String,
    start: ClockPair,
    dropped0: u64,
}

impl LslSitting {
    /// The sitting of `participant` (`P01`) in the study `study` (the
    /// protocol's name), folder `out`, begins now: the clocks are read and
    /// `sitting_start participant=P01 study=NAME` is sent.
    pub fn start(
        markers: LslMarkers,
        out: &std::path::Path,
        participant: &str,
        study: &str,
    ) -> Self {
        let start = ClockPair::now();
        let s = Self {
            dropped0: markers.dropped(),
            markers,
            out: out.to_path_buf(),
            participant: participant.to_owned(),
            study: study.to_owned(),
            start,
        };
        s.markers.send(&s.text("sitting_start"));
        s
    }

    /// `sitting_start`/`sitting_end` with the sitting's fields (the study's
    /// name last: it runs to the end of the marker, spaces included).
    fn text(&self, what: &str) -> String {
        format!(
            "{what} participant={} study={}",
            self.participant, self.study
        )
    }

    /// A journal note of the sitting: `note TEXT`.
    pub fn note(&self, text: &str) {
        self.markers.send(&format!("note {text}"));
    }

    /// The sitting has ended: `sitting_end` is sent, the clocks read again,
    /// and the sitting's start and end clocks with the records the engine
    /// dropped during it are appended to `out`'s [`CLOCK_FILE`].
    ///
    /// # Errors
    /// Reading or writing the clock file.
    pub fn end(self) -> std::io::Result<()> {
        self.markers.send(&self.text("sitting_end"));
        let end = ClockPair::now();
        let dropped = self.markers.dropped().saturating_sub(self.dropped0);
        record_clock(&self.out, &self.participant, self.start, end, dropped)
    }
}

fn publish_loop(
    mo: &lsl::StreamOutlet,
    so: &lsl::StreamOutlet,
    rx: &mut rtrb::Consumer<LslRecord>,
    notes: &mpsc::Receiver<(f64, String)>,
    shared: &LslShared,
    stop: &AtomicBool,
    id_width: usize,
) {
    use lsl::ExPushable;
    let mut row: Vec<f32> = vec![0.0; N_SIGNAL];
    let mut text: Vec<String> = vec![String::new()];
    let mut pending: std::collections::VecDeque<(f64, String)> = Default::default();
    loop {
        let stopping = stop.load(Ordering::Acquire);
        // The notes sent so far, then the ring: every record an event that
        // led to a note pushed is in the ring by now. Notes go out in time
        // order with the records.
        pending.extend(notes.try_iter());
        while let Ok(r) = rx.pop() {
            match r {
                LslRecord::Sample { t, ch } => {
                    row.copy_from_slice(&ch);
                    // Sent when the ring is drained (one chunk per pass).
                    let _ = so.push_sample_ex(&row, t, rx.is_empty());
                }
                LslRecord::Marker { t, m } => {
                    push_notes_until(mo, &mut pending, t, &mut text);
                    text[0] = m.text(id_width);
                    let _ = mo.push_sample_ex(&text, t, true);
                }
            }
        }
        push_notes_until(mo, &mut pending, f64::INFINITY, &mut text);
        shared
            .marker_consumer
            .store(mo.have_consumers(), Ordering::Relaxed);
        shared
            .signal_consumer
            .store(so.have_consumers(), Ordering::Relaxed);
        if stopping {
            break;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Push the pending notes stamped at or before `t` (s), oldest first.
fn push_notes_until(
    mo: &lsl::StreamOutlet,
    pending: &mut std::collections::VecDeque<(f64, String)>,
    t: f64,
    text: &mut Vec<String>,
) {
    use lsl::ExPushable;
    while let Some((tn, n)) = pending.pop_front() {
        if tn > t {
            pending.push_front((tn, n));
            break;
        }
        text[0] = n;
        let _ = mo.push_sample_ex(&*text, tn, true);
    }
}

/// The LSL clock and the system's UTC clock read together.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ClockPair {
    /// [`lsl::local_clock`], s.
    pub lsl_s: f64,
    /// UTC, s since the Unix epoch (the clock of `started_utc` in
    /// `trials.csv` and of the journal).
    pub unix_s: f64,
    /// `unix_s − lsl_s`, s: add it to an LSL time to get UTC.
    pub offset_s: f64,
}

impl ClockPair {
    /// Both clocks now (the LSL clock read between two UTC reads, the UTC
    /// time their mean).
    pub fn now() -> Self {
        let unix = || {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64())
        };
        let u0 = unix();
        let lsl_s = lsl::local_clock();
        let unix_s = 0.5 * (u0 + unix());
        Self {
            lsl_s,
            unix_s,
            offset_s: unix_s - lsl_s,
        }
    }
}

/// One sitting's entry in `lsl_clock.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SittingClock {
    /// The participant (`P01`).
    pub participant: String,
    /// The clocks when the sitting began.
    pub start: ClockPair,
    /// The clocks when it ended.
    pub end: ClockPair,
    /// Records the engine dropped because the publisher fell behind.
    pub dropped: u64,
}

/// Name of the clock file in a study folder.
pub const CLOCK_FILE: &str = "lsl_clock.json";

/// Append a sitting's clock pairs to the study folder's [`CLOCK_FILE`]
/// (a JSON array, one entry per sitting streamed to LSL).
///
/// # Errors
/// Reading or writing the file.
pub fn record_clock(
    dir: &std::path::Path,
    participant: &str,
    start: ClockPair,
    end: ClockPair,
    dropped: u64,
) -> std::io::Result<()> {
    let path = dir.join(CLOCK_FILE);
    let mut all: Vec<SittingClock> = match std::fs::read(&path) {
        Ok(b) => serde_json::from_slice(&b).map_err(std::io::Error::other)?,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
        Err(e) => return Err(e),
    };
    all.push(SittingClock {
        participant: participant.to_owned(),
        start,
        end,
        dropped,
    });
    let text = serde_json::to_string_pretty(&all).map_err(std::io::Error::other)?;
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, text + "\n")?;
    std::fs::rename(&tmp, &path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_ring_drops_and_counts() {
        let shared = Arc::new(LslShared::default());
        let mut tap = LslTap::new(shared.clone());
        // Off: nothing is pushed.
        tap.marker(Marker::Pause);
        assert_eq!(shared.dropped.load(Ordering::Relaxed), 0);
        shared.on.store(true, Ordering::Relaxed);
        for _ in 0..LSL_RING + 100 {
            tap.marker(Marker::Resume);
        }
        assert_eq!(shared.dropped.load(Ordering::Relaxed), 100);
    }

    #[test]
    fn trial_markers_name_the_trial() {
        use kilotouch_rig::Condition;
        use kilotouch_study::seeds::Phase;
        let k = TrialKey {
            participant: 0,
            phase: Phase::Test,
            condition: Condition::P,
            trial: 3,
        };
        assert_eq!(
            Marker::TrialStart(k).text(2),
            "trial_start participant=P01 condition=P phase=test trial=3"
        );
    }
}
