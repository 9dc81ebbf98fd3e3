//! Fixtures shared by the app's integration tests (`use kilotouch_testkit as
//! common;` in each test file): the app under egui_kittest, stepping it until
//! a condition holds, the device emulator on a pty, running the executable.
//!
//! A library of its own (a dev-dependency only, never published) rather than
//! a `tests/common` module: each test file is its own crate and uses only some
//! of these, which as a module would be dead code in most of them.

use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use kilotouch::gui::pages::study::ProtocolSource;
use kilotouch::gui::{AppOptions, KilotouchApp, Page};
use kilotouch_rig::device::RigSpec;
use kilotouch_study::export::{TRIALS_FILE, TrialRow, UtcTime, read_trials};
use serde_json::Value;
use std::collections::HashSet;
use std::ffi::OsStr;
use std::fmt::Debug;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// How long a test waits for an event before it calls it lost (s): a bound
/// on a hang, not a speed claim. A passing test never waits this long; a
/// loaded 2-core machine (CI builds alongside, fsync on a busy disk) may
/// stretch an event that takes milliseconds to seconds. Speed claims are
/// in the benchmarks, latency bounds in the tests that state them.
pub const WAIT_S: f64 = 120.0;

/// The emulators' device watchdog window in the tests, ms
/// ([`Emulator::spawn`]); the watchdog's own tests set theirs.
pub const TEST_WATCHDOG_MS: u64 = 1000;

/// The host's stall timeout for a serial rig in the tests that run whole
/// trials on an emulator (a `--rig` option, appended to `serial:PATH`): the
/// default 100 ms is a USB link's bound, and a loaded 2-core machine may
/// deschedule the emulator process for longer. The tests of stall detection
/// set their own.
pub const TEST_HOST_TIMEOUT: &str = ",timeout-ms=1000";

/// The executable under test: the path cargo gives the tests in
/// `CARGO_BIN_EXE_kilotouch` at run time, else `kilotouch` beside the
/// directory of the running test binary (`target/<profile>/deps/…`).
pub fn bin_path() -> PathBuf {
    if let Some(p) = std::env::var_os("CARGO_BIN_EXE_kilotouch") {
        return PathBuf::from(p);
    }
    let exe = std::env::current_exe().expect("the test binary's path");
    let profile_dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("the test binary lies in target/<profile>/deps");
    profile_dir.join(format!("kilotouch{}", std::env::consts::EXE_SUFFIX))
}

/// The app with fresh settings (nothing remembered from earlier runs),
/// opening on `page` (the app's default page with `None`).
pub fn fresh_app(page: Option<Page>) -> KilotouchApp {
    KilotouchApp::new(
        AppOptions {
            fresh_settings: true,
            page,
            ..Default::default()
        },
        None,
        None,
    )
}

/// A kittest harness of `width` × `height` points around the app's root UI;
/// `max_steps` overrides the harness's limit of steps per `run` (kittest's
/// default with `None`).
pub fn app_harness(
    app: KilotouchApp,
    width: f32,
    height: f32,
    max_steps: Option<u64>,
) -> Harness<'static, KilotouchApp> {
    let mut builder = Harness::builder().with_size(egui::vec2(width, height));
    if let Some(n) = max_steps {
        builder = builder.with_max_steps(n);
    }
    builder.build_ui_state(|ui, app: &mut KilotouchApp| app.ui_root(ui), app)
}

/// Step the UI until `done` or `secs` seconds have passed (the engine runs
/// in real time), sleeping 10 ms between steps; whether `done` held.
pub fn step_until(
    h: &mut Harness<'_, KilotouchApp>,
    secs: f64,
    done: impl FnMut(&KilotouchApp) -> bool,
) -> bool {
    step_until_every(h, Duration::from_millis(10), secs, done)
}

/// [`step_until`], sleeping `pause` between steps.
pub fn step_until_every(
    h: &mut Harness<'_, KilotouchApp>,
    pause: Duration,
    secs: f64,
    mut done: impl FnMut(&KilotouchApp) -> bool,
) -> bool {
    let t0 = Instant::now();
    while t0.elapsed().as_secs_f64() < secs {
        h.step();
        if done(h.state()) {
            return true;
        }
        std::thread::sleep(pause);
    }
    false
}

/// [`step_until_every`] (≤ [`WAIT_S`]) until the app's engine reports.
pub fn until_engine_reporting(h: &mut Harness<'_, KilotouchApp>, pause: Duration) -> bool {
    step_until_every(h, pause, WAIT_S, engine_reporting)
}

/// [`step_until_every`] (≤ [`WAIT_S`]) until the Study page's sitting finished.
pub fn until_study_finished(h: &mut Harness<'_, KilotouchApp>, pause: Duration) -> bool {
    step_until_every(h, pause, WAIT_S, |a| a.study.finished().is_some())
}

/// Step until the Study page's sitting opened (after its size check,
/// which runs on a thread of its own) or the page shows an error; whether
/// it opened.
pub fn until_sitting_opened(h: &mut Harness<'_, KilotouchApp>) -> bool {
    step_until(h, WAIT_S, |a| {
        a.study.is_running() || a.study.error().is_some()
    }) && h.state().study.is_running()
}

/// The app under a kittest harness.
pub type AppHarness = Harness<'static, KilotouchApp>;

/// The app on the Study page, 1100 × `height` points, with the protocol
/// file `proto`, participant `participant`, output folder `out` and the
/// inline participant view.
pub fn study_page(proto: &Path, participant: &str, out: &Path, height: f32) -> AppHarness {
    let app = fresh_app(Some(Page::Study));
    let mut h = app_harness(app, 1100.0, height, None);
    let s = &mut h.state_mut().study;
    s.form.source = ProtocolSource::File;
    s.form.protocol_file = proto.display().to_string();
    s.form.participant_text = participant.into();
    s.form.out_text = out.display().to_string();
    s.separate_window = false;
    h
}

/// Click the Study page's "Open session" and check that the session opened
/// (the page's error shown if not).
pub fn open_session(h: &mut AppHarness) {
    h.get_by_label("Open session").click();
    assert!(until_sitting_opened(h), "{:?}", h.state().study.error());
    h.step();
}

/// The health the app's engine last reported, if it is up and has.
pub fn engine_health(a: &KilotouchApp) -> Option<&kilotouch::engine::Health> {
    a.engine.as_ref().and_then(|e| e.health())
}

/// Spawn on `engine` the sitting of the first participant (P01) of
/// `protocol`, its participant at the handle, writing to `out`, and start it.
pub fn start_p01_at_the_handle(
    protocol: kilotouch_study::protocol::Protocol,
    out: &Path,
    rig: kilotouch_rig::RigConfig,
    engine: &mut kilotouch::engine::EngineHandle,
) -> kilotouch::session::SessionHandle {
    use kilotouch::session::{ParticipantKind, SessionCommand, SessionHandle, SessionOptions};
    let mut opts = SessionOptions::new(out, Some(protocol), rig);
    opts.participant = ParticipantKind::Handle;
    opts.only_participant = Some(0);
    let mut s = SessionHandle::spawn(opts, engine).expect("spawn the sitting");
    assert!(s.send(SessionCommand::Start));
    s
}

/// Poll `engine`'s events (≤ `secs`) until it reports its loop stopped.
pub fn until_engine_stopped(engine: &mut kilotouch::engine::EngineHandle, secs: f64) {
    let t0 = Instant::now();
    while t0.elapsed().as_secs_f64() < secs {
        let _ = engine.poll_events();
        if engine.health().is_some_and(|h| !h.running) {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// A `rig check --json` report of a link that corrupts and drops bytes at
/// 2e-4 each: ≈ 1 − (1 − 4e-4)^162 ≈ 6 % of the frames of 10 samples are
/// hit, every frame is received or lost, and CRC errors are counted.
pub fn assert_corruption_counted(v: &Value) {
    let (frames, lost) = (
        v["frames"].as_u64().expect("frames"),
        v["lost"].as_u64().expect("lost"),
    );
    assert!(lost > 100 && lost < frames / 4, "{v}");
    assert!(v["crc_errors"].as_u64().expect("crc_errors") > 5, "{v}");
    assert_eq!(v["received"].as_u64().expect("received") + lost, frames);
}

/// Click the Rig page's "Record and calibrate" and step (≤ [`WAIT_S`])
/// until the tweezer panel is no longer busy.
pub fn record_and_calibrate(h: &mut AppHarness) {
    h.get_by_label("Record and calibrate").click();
    h.step();
    assert!(step_until(h, WAIT_S, |a| !a.rig_page().tweezer.is_busy()));
    h.step();
}

/// Whether the app's engine is up and has reported its health.
pub fn engine_reporting(a: &KilotouchApp) -> bool {
    a.engine.as_ref().is_some_and(|e| e.health().is_some())
}

/// Uniform noise in [−0.5, 0.5): successive states of the 32-bit xorshift
/// generator (13, 17, 5) from `seed`, scaled by 1/(2³² − 1).
pub fn xorshift_noise(seed: u32) -> impl Iterator<Item = f64> {
    let mut s = seed;
    std::iter::repeat_with(move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        f64::from(s) / f64::from(u32::MAX) - 0.5
    })
}

/// Root mean square of `x` (0 for no values).
pub fn rms(x: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for v in x {
        s += v * v;
        n += 1;
    }
    (s / n.max(1) as f64).sqrt()
}

/// A running device emulator (`kilotouch emulate KIND --pty`); killed on
/// drop.
#[derive(Debug)]
pub struct Emulator {
    pub child: Child,
    /// The pty's path (`/dev/pts/N`).
    pub path: String,
}

impl Emulator {
    /// The DAQ emulator with its default options.
    pub fn start() -> Self {
        Self::spawn("daq", &[])
    }

    /// The `kind` emulator with the `extra` options; waits for the pty path
    /// it prints on its first line. Unless `extra` sets `--watchdog-ms`, the
    /// device's watchdog window is [`TEST_WATCHDOG_MS`]: a test of something
    /// else must not fail because a loaded machine held the host back for
    /// the device's default 100 ms.
    pub fn spawn(kind: &str, extra: &[&str]) -> Self {
        let window = TEST_WATCHDOG_MS.to_string();
        let watchdog: &[&str] = if extra.contains(&"--watchdog-ms") {
            &[]
        } else {
            &["--watchdog-ms", &window]
        };
        let mut child = bin()
            .args(["emulate", kind, "--pty"])
            .args(watchdog)
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("spawn the emulator");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("stdout"))
            .read_line(&mut line)
            .expect("pty path on the first line");
        let path = line.trim().to_owned();
        assert!(path.starts_with("/dev/"), "first line: {line:?}");
        Self { child, path }
    }

    /// The rig spec `serial:PATH` followed by `opts` (`,key=value…`).
    pub fn spec(&self, opts: &str) -> RigSpec {
        format!("serial:{}{opts}", self.path)
            .parse()
            .expect("a serial rig spec")
    }

    /// The `--rig` argument for this emulator: `serial:PATH`.
    pub fn rig(&self) -> String {
        format!("serial:{}", self.path)
    }

    /// Kill the emulator and reap it (errors ignored: it may be gone).
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        self.kill();
    }
}

/// A command running the executable under test ([`bin_path`]).
pub fn bin() -> Command {
    Command::new(bin_path())
}

/// Run the executable with `args` and wait for it.
pub fn kilotouch<S: AsRef<OsStr>>(args: &[S]) -> Output {
    bin().args(args).output().expect("run kilotouch")
}

/// Run `study simulate --protocol PROTOCOL --out OUT` with `extra` flags
/// and wait for it (`out` as given, so it may be any path).
pub fn simulate_study(protocol: &str, out: &Path, extra: &[&str]) -> Output {
    bin()
        .args(["study", "simulate", "--protocol", protocol, "--out"])
        .arg(out)
        .args(extra)
        .output()
        .expect("run kilotouch")
}

/// The arguments of `rig check --rig RIG --duration SECONDS --json`.
pub fn rig_check_args<'a>(rig: &'a str, seconds: &'a str) -> [&'a str; 7] {
    [
        "rig",
        "check",
        "--rig",
        rig,
        "--duration",
        seconds,
        "--json",
    ]
}

/// Run `study run --protocol PROTOCOL --rig RIG --participant P01 --out OUT
/// --json` (with `--resume` if `resume`) and `extra`, and wait for it.
pub fn study_run_p01(
    protocol: &str,
    rig: &str,
    out: &Path,
    resume: bool,
    extra: &[&str],
) -> Output {
    let out_s = out.to_str().expect("utf-8 out");
    let mut args = vec![
        "study",
        "run",
        "--protocol",
        protocol,
        "--rig",
        rig,
        "--participant",
        "P01",
        "--out",
        out_s,
        "--json",
    ];
    if resume {
        args.push("--resume");
    }
    args.extend_from_slice(extra);
    kilotouch(&args)
}

/// Run the executable with `args`; it must succeed (its stderr shown if
/// not).
pub fn ok<S: AsRef<OsStr> + Debug>(args: &[S]) {
    let o = kilotouch(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Run the executable with `args`; it must fail with `why` in its stderr.
pub fn refused<S: AsRef<OsStr> + Debug>(args: &[S], why: &str) {
    let o = kilotouch(args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{args:?} succeeded");
    assert!(err.contains(why), "{args:?}: `{why}` not in: {err}");
}

/// The rows of the study folder `dir`'s trials file without the wall-clock
/// start time (which a rerun cannot equal: set to the epoch).
pub fn rows_without_start_time(dir: &Path) -> Vec<TrialRow> {
    read_trials(&dir.join(TRIALS_FILE))
        .expect("a readable trials file")
        .rows
        .into_iter()
        .map(|mut r| {
            r.started_utc = UtcTime::from_unix_millis(0);
            r
        })
        .collect()
}

/// Checks a `study run --resume` after an interrupted sitting: `run`
/// succeeded, and the study folder `out` then holds `total` rows, no two of
/// one trial, beginning with the rows `committed` before the interruption.
pub fn assert_resumed(run: &Output, out: &Path, committed: &[TrialRow], total: usize) {
    assert!(
        run.status.success(),
        "resume failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let all = rows_so_far(out);
    assert_eq!(all.len(), total, "{all:?}");
    let keys: HashSet<_> = all
        .iter()
        .map(|r| (r.phase, r.condition, r.trial))
        .collect();
    assert_eq!(keys.len(), total, "a duplicate row: {all:?}");
    assert_eq!(&all[..committed.len()], committed);
}

/// The rows of the study folder `dir`'s trials file so far (none while it
/// cannot be read yet: a sitting still starting).
pub fn rows_so_far(dir: &Path) -> Vec<TrialRow> {
    read_trials(&dir.join(TRIALS_FILE))
        .map(|r| r.rows)
        .unwrap_or_default()
}

/// Run the executable with `args`; it must succeed and print one JSON
/// document, which is returned.
pub fn json_ok(args: &[&str]) -> Value {
    let out = kilotouch(args);
    assert!(
        out.status.success(),
        "kilotouch {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("stdout is one JSON document")
}

/// One page shown alone, with the bare environment the shell would give it
/// (the default rig, no calibration applied, shell requests collected).
#[derive(Debug)]
pub struct PageState<P> {
    pub page: P,
    pub rig: kilotouch_rig::RigConfig,
    pub output_dir: Option<std::path::PathBuf>,
    pub requests: Vec<kilotouch::gui::env::ShellRequest>,
}

impl<P> PageState<P> {
    /// `page` with the default rig and no output folder.
    pub fn new(page: P) -> Self {
        Self {
            page,
            rig: kilotouch_rig::RigConfig::default(),
            output_dir: None,
            requests: Vec::new(),
        }
    }
}

/// A harness 1400 px wide and `height` px tall drawing the page of `state`
/// (its [`Page::ui`](kilotouch::gui::pages::Page::ui)) every frame, with no
/// engine.
pub fn page_harness<P: kilotouch::gui::pages::Page + 'static>(
    state: PageState<P>,
    height: f32,
) -> Harness<'static, PageState<P>> {
    Harness::builder()
        .with_size(egui::vec2(1400.0, height))
        .build_ui_state(
            move |ui, s: &mut PageState<P>| {
                let mut env = kilotouch::gui::env::PageEnv {
                    rig_config: &s.rig,
                    rig_config_path: None,
                    output_dir: s.output_dir.as_deref(),
                    requests: &mut s.requests,
                    applied: None,
                    trap_applied: None,
                    engine: None,
                    config_error: None,
                };
                s.page.ui(ui, &mut env);
            },
            state,
        )
}

/// Poll the sitting `s` on `engine` until its `n`-th trial has begun
/// (≤ [`WAIT_S`]); the rows committed meanwhile. Panics if the sitting finishes
/// first.
pub fn until_trials_started(
    engine: &mut kilotouch::engine::EngineHandle,
    s: &mut kilotouch::session::SessionHandle,
    n: usize,
) -> Vec<kilotouch_study::export::TrialRow> {
    use kilotouch::session::SessionEvent;
    let t0 = Instant::now();
    let (mut committed, mut started) = (Vec::new(), 0);
    while started < n && t0.elapsed().as_secs_f64() < WAIT_S {
        let _ = engine.poll_events();
        for e in s.poll() {
            match e {
                SessionEvent::TrialStarted { .. } => started += 1,
                SessionEvent::Committed(r) => committed.push(*r),
                SessionEvent::Finished(r) => panic!("finished early: {r:?}"),
                _ => {}
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(started, n, "trial {n} never began");
    committed
}

/// Poll the sitting `s` on `engine` until it finishes (≤ 10 s after
/// `since`, when a device was killed), adding the rows it commits to
/// `committed`; how it finished and the seconds since `since`.
pub fn until_finished(
    engine: &mut kilotouch::engine::EngineHandle,
    s: &mut kilotouch::session::SessionHandle,
    committed: &mut Vec<kilotouch_study::export::TrialRow>,
    since: Instant,
) -> (kilotouch::session::FinishReason, f64) {
    use kilotouch::session::SessionEvent;
    let reason = loop {
        assert!(
            since.elapsed() < Duration::from_secs(10),
            "the sitting did not end"
        );
        let _ = engine.poll_events();
        if let Some(r) = s.poll().into_iter().find_map(|e| match e {
            SessionEvent::Committed(r) => {
                committed.push(*r);
                None
            }
            SessionEvent::Finished(r) => Some(r),
            _ => None,
        }) {
            break r;
        }
        std::thread::sleep(Duration::from_millis(2));
    };
    (reason, since.elapsed().as_secs_f64())
}

/// Writes a circling protocol of one participant over V, P and D
/// (`trials` test and `practice` practice trials per session, 20 s timeout,
/// study seed `seed`) to `dir/proto.toml`; returns its path.
pub fn write_circling_protocol(
    dir: &Path,
    name: &str,
    trials: u32,
    practice: u32,
    seed: u64,
) -> String {
    write_circling_protocol_timeout(dir, name, trials, practice, seed, 20.0)
}

/// [`write_circling_protocol`] with a trial time-out of `timeout_s` (a
/// longer one lets P and D succeed, so every participant has the cells a
/// power analysis needs).
pub fn write_circling_protocol_timeout(
    dir: &Path,
    name: &str,
    trials: u32,
    practice: u32,
    seed: u64,
    timeout_s: f64,
) -> String {
    let p = dir.join("proto.toml");
    std::fs::write(
        &p,
        format!(
            "name = \"{name}\"\nparticipants = 1\nconditions = [\"V\", \"P\", \"D\"]\n\
             trials_per_session = {trials}\n[training]\npractice_trials = {practice}\n\
             [task.circling]\ntimeout_s = {timeout_s:?}\n[seeds]\nstudy = {seed}\n"
        ),
    )
    .expect("test setup: write the protocol");
    p.to_string_lossy().into_owned()
}

/// A process's standard error as text.
pub fn stderr_text(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `kilotouch stats FILE --dv DV --within condition --subject participant
/// --test TEST`, as arguments (the layout of a study's `trials.csv`).
pub fn stats_args<'a>(path: &'a str, dv: &'a str, test: &'a str) -> Vec<&'a str> {
    vec![
        "stats",
        path,
        "--dv",
        dv,
        "--within",
        "condition",
        "--subject",
        "participant",
        "--test",
        test,
    ]
}

/// A PNG that decodes, is at least 600 × 400 px, is not one colour and has
/// ink on ≥ 2 % of it (a figure was drawn, not an empty canvas).
pub fn assert_non_blank_png(path: &Path) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(
        bytes.starts_with(b"\x89PNG\r\n\x1a\n"),
        "{} is not a PNG",
        path.display()
    );
    let img = image::load_from_memory(&bytes)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgb8();
    let (w, h) = img.dimensions();
    assert!(w >= 600 && h >= 400, "{}: {w}×{h}", path.display());
    let ink = img.pixels().filter(|p| p.0 != [255, 255, 255]).count();
    let colours: HashSet<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    assert!(
        ink as f64 > 0.02 * f64::from(w * h) && colours.len() > 8,
        "{} looks blank: {ink} ink pixels, {} colours",
        path.display(),
        colours.len()
    );
}
