//! The shell: tabs, the always-visible emergency stop, the status bar with
//! the engine's health, messages, settings, and the rig/engine life cycle.
//!
//! **Emergency stop.** The red button at the top right of every page, or the
//! **Esc** key (anywhere, also while typing in a field), zeroes all outputs
//! at the engine's next block (≤ 1 ms) and latches. Releasing it takes two
//! deliberate steps in a dialog (tick "the rig is safe", then click
//! "Re-enable outputs"); no key does it, and a stop pressed meanwhile wins.

use super::env::AppliedCalibration;
use super::env::{PageEnv, ShellRequest};
use super::pages::study::ProtocolSource;
use super::pages::{self, CalibrationPage, ExplorePage, ResultsPage, RigPage, StudyPage};
use super::settings::{Page, Settings};
use crate::engine::{EngineEvent, EngineHandle, EngineOptions, SafetyState};
use egui::{Color32, RichText};
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::{RigSpec, TweezerSpec};
use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::mpsc;
use std::time::Instant;

/// Options from the command line.
#[derive(Debug, Clone)]
pub struct AppOptions {
    /// Page to open (else the one shown last).
    pub page: Option<Page>,
    /// Rig file (else the one used last, else the built-in default).
    pub rig_config: Option<PathBuf>,
    /// Ignore the persisted settings (screenshots, tests).
    pub fresh_settings: bool,
    /// Connect the simulated rig at start.
    pub connect: bool,
    /// Engine options.
    pub engine: EngineOptions,
    /// Study output folder (Study and Results pages).
    pub study_dir: Option<PathBuf>,
    /// Start a simulated real-time sitting on the Study page.
    pub simulate_sitting: bool,
    /// Record and calibrate the simulated tweezer at start (Rig page).
    pub calibrate_tweezer: bool,
    /// The rig to connect at start (`sim`, `serial:PATH[,…]`; else the one
    /// used last, else the simulated rig).
    pub rig: Option<String>,
    /// The tweezer to connect at start (`sim`, `serial:PATH[,…]`; else the
    /// one used last, else the simulated tweezer).
    pub tweezer: Option<String>,
}

impl Default for AppOptions {
    fn default() -> Self {
        Self {
            page: None,
            rig_config: None,
            fresh_settings: false,
            connect: true,
            engine: EngineOptions::default(),
            study_dir: None,
            simulate_sitting: false,
            calibrate_tweezer: false,
            rig: None,
            tweezer: None,
        }
    }
}

/// A message shown in the status line (errors stay until dismissed).
#[derive(Debug, Clone)]
struct Notice {
    text: String,
    error: bool,
    at: Instant,
    /// How many times the same text was notified (shown as "×N").
    count: u32,
}

/// Screenshot-and-quit plan (`kilotouch gui --screenshot FILE --quit-after S`).
#[derive(Debug)]
pub struct ScreenshotPlan {
    /// Where to save the PNG (`None`: just quit).
    pub path: Option<PathBuf>,
    /// Seconds after start.
    pub after_s: f64,
    /// Exit code for `main` (0 ok, 1 blank or unwritable image).
    pub exit_code: Arc<AtomicI32>,
    /// Bits per channel kept in the PNG.
    pub bits: u8,
    start: Instant,
    requested: bool,
    tx: mpsc::Sender<Arc<egui::ColorImage>>,
    rx: mpsc::Receiver<Arc<egui::ColorImage>>,
}

impl ScreenshotPlan {
    /// New plan.
    pub fn new(path: Option<PathBuf>, after_s: f64, exit_code: Arc<AtomicI32>, bits: u8) -> Self {
        let (tx, rx) = mpsc::channel();
        Self {
            path,
            after_s,
            exit_code,
            bits,
            start: Instant::now(),
            requested: false,
            tx,
            rx,
        }
    }
}

/// The app.
#[derive(Debug)]
pub struct KilotouchApp {
    /// Persisted settings.
    pub settings: Settings,
    /// Rig configuration in use.
    pub rig_config: RigConfig,
    rig_config_path: Option<PathBuf>,
    config_error: Option<String>,
    /// The engine (None = disconnected).
    pub engine: Option<EngineHandle>,
    engine_opts: EngineOptions,
    /// Current page.
    pub page: Page,
    rig_page: RigPage,
    calibration: CalibrationPage,
    /// Explore page.
    pub explore: ExplorePage,
    /// Study page (its session owns the rig while it runs).
    pub study: StudyPage,
    results: ResultsPage,
    requests: Vec<ShellRequest>,
    /// The calibration the engine runs (None: the as-designed chain).
    applied: Option<AppliedCalibration>,
    /// The trap calibration the engine's tweezer uses (None: the
    /// simulated bead and stiffness).
    trap_applied: Option<kilotouch_rig::tweezer::TrapCalibrationRecord>,
    notices: VecDeque<Notice>,
    reset_dialog: Option<bool>,
    /// Screenshot plan, if any.
    pub screenshot: Option<ScreenshotPlan>,
    gpu_status: String,
    fresh: bool,
    connecting: Option<PendingConnect>,
}

/// A live rig being opened on a worker thread (its handshake may take up to
/// the device timeout; the GUI keeps drawing meanwhile).
#[derive(Debug)]
struct PendingConnect {
    label: String,
    rx: mpsc::Receiver<Result<EngineHandle, crate::engine::EngineError>>,
}

/// The [`PageEnv`] of a frame, from the shell's fields (a macro, not a
/// method, so that the pages stay borrowable beside it).
macro_rules! page_env {
    ($app:ident) => {
        PageEnv {
            rig_config: &$app.rig_config,
            rig_config_path: $app.rig_config_path.as_deref(),
            output_dir: $app.settings.output_dir.as_deref(),
            requests: &mut $app.requests,
            applied: $app.applied.as_ref(),
            trap_applied: $app.trap_applied.as_ref(),
            engine: $app.engine.as_mut(),
            config_error: $app.config_error.as_deref(),
        }
    };
}

impl KilotouchApp {
    /// Build the app. `wgpu`: eframe's render state (None: painter fallback).
    pub fn new(
        opts: AppOptions,
        storage: Option<&dyn eframe::Storage>,
        wgpu: Option<&eframe::egui_wgpu::RenderState>,
    ) -> Self {
        let mut settings = if opts.fresh_settings {
            Settings::default()
        } else {
            Settings::load(storage)
        };
        if let Some(p) = opts.page {
            settings.page = p;
        }
        if let Some(d) = &opts.study_dir {
            settings.output_dir = Some(d.clone());
        }
        let mut notices = VecDeque::new();
        let path = opts
            .rig_config
            .clone()
            .or_else(|| settings.rig_file.clone());
        let (rig_config, rig_config_path, config_error) = match &path {
            None => (RigConfig::default(), None, None),
            Some(p) => match RigConfig::load(p) {
                Ok(c) => (c, Some(p.clone()), None),
                Err(e) => (RigConfig::default(), None, Some(e.to_string())),
            },
        };
        if let Some(e) = &config_error {
            notices.push_back(Notice {
                text: format!("rig file not loaded, using the built-in default: {e}"),
                error: true,
                at: Instant::now(),
                count: 1,
            });
        }
        let (gpu, gpu_status) = match wgpu {
            None => (false, "egui painter (no wgpu render state)".to_owned()),
            Some(rs) => match super::scene_wgpu::install(rs) {
                Ok(()) => (true, "wgpu".to_owned()),
                Err(e) => {
                    notices.push_back(Notice {
                        text: format!("microscope scene falls back to the egui painter: {e}"),
                        error: false,
                        at: Instant::now(),
                        count: 1,
                    });
                    (false, format!("egui painter ({e})"))
                }
            },
        };
        let mut explore = ExplorePage::new(&rig_config, settings.camera);
        explore.gpu = gpu;
        explore.trace_seconds = settings.trace_seconds;
        let mut rig_page = RigPage::new();
        rig_page.path_text = rig_config_path
            .as_ref()
            .map(|p| p.display().to_string())
            .unwrap_or_default();
        if let Some(r) = opts.rig.as_ref().or(settings.rig_spec.as_ref()) {
            rig_page.rig_text = r.clone();
        }
        if let Some(t) = opts.tweezer.as_ref().or(settings.tweezer_spec.as_ref()) {
            rig_page.tweezer_text = t.clone();
        }
        let mut study = StudyPage::with_gpu(gpu);
        match settings.protocol_source.as_deref() {
            Some("blind") => study.form.source = ProtocolSource::Blind,
            Some("file") => {
                study.form.source = ProtocolSource::File;
                if let Some(f) = &settings.protocol_file {
                    study.form.protocol_file = f.display().to_string();
                }
            }
            _ => {}
        }
        if opts.simulate_sitting {
            study.simulate_sitting();
        }
        if opts.calibrate_tweezer {
            rig_page.tweezer.start(&rig_config);
        }
        let mut app = Self {
            page: settings.page,
            settings,
            rig_config,
            rig_config_path,
            config_error,
            engine: None,
            engine_opts: opts.engine,
            rig_page,
            calibration: CalibrationPage::new(),
            explore,
            study,
            results: ResultsPage::new(),
            requests: Vec::new(),
            applied: None,
            trap_applied: None,
            notices,
            reset_dialog: None,
            screenshot: None,
            gpu_status,
            fresh: opts.fresh_settings,
            connecting: None,
        };
        if opts.connect {
            app.connect();
        }
        app
    }

    /// The notices on screen (the newest last), their texts.
    pub fn notices(&self) -> impl Iterator<Item = &str> {
        self.notices.iter().map(|n| n.text.as_str())
    }

    /// Show a message; the same text again counts up ("×N") and refreshes
    /// the existing notice instead of stacking copies.
    fn notify(&mut self, text: impl Into<String>, error: bool) {
        let text = text.into();
        if let Some(i) = self.notices.iter().position(|n| n.text == text) {
            if let Some(mut n) = self.notices.remove(i) {
                n.count = n.count.saturating_add(1);
                n.at = Instant::now();
                n.error |= error;
                self.notices.push_back(n);
            }
            return;
        }
        self.notices.push_back(Notice {
            text,
            error,
            at: Instant::now(),
            count: 1,
        });
        while self.notices.len() > 20 {
            self.notices.pop_front();
        }
    }

    /// Start the engine on the current rig configuration. The simulated rig
    /// starts at once; a live rig is opened on a worker thread (a serial
    /// handshake may block up to its timeout) and joins when ready
    /// ([`KilotouchApp::is_connecting`]).
    pub fn connect(&mut self) {
        self.engine = None;
        self.connecting = None;
        let specs = self
            .rig_page
            .spec()
            .and_then(|r| Ok((r, self.rig_page.tweezer_spec()?)));
        let (spec, tweezer) = match specs {
            Ok(s) => s,
            Err(e) => {
                self.notify(format!("cannot start the engine: {e}"), true);
                return;
            }
        };
        if spec == RigSpec::Sim && tweezer == TweezerSpec::Sim {
            let spawned = EngineHandle::spawn_spec(&self.rig_config, &spec, self.engine_opts);
            self.engine_ready(spawned);
            return;
        }
        let (tx, rx) = mpsc::channel();
        let mut label = self.rig_page.rig_text.trim().to_owned();
        if tweezer != TweezerSpec::Sim {
            label = format!("{label} + tweezer {}", tweezer.describe());
        }
        let (cfg, opts) = (self.rig_config.clone(), self.engine_opts);
        let worker = std::thread::Builder::new()
            .name("kilotouch-connect".into())
            .spawn(move || {
                // If the GUI gave up meanwhile, the handle drops here and
                // its engine stops.
                let _ = tx.send(EngineHandle::spawn_devices(&cfg, &spec, &tweezer, opts));
            });
        match worker {
            Ok(_) => self.connecting = Some(PendingConnect { label, rx }),
            Err(e) => self.notify(format!("cannot start the engine: {e}"), true),
        }
    }

    /// The Rig page.
    pub fn rig_page(&self) -> &RigPage {
        &self.rig_page
    }

    /// The Rig page, to change its fields.
    pub fn rig_page_mut(&mut self) -> &mut RigPage {
        &mut self.rig_page
    }

    /// The trap calibration the engine's tweezer uses, if one was applied.
    pub fn trap_calibration(&self) -> Option<&kilotouch_rig::tweezer::TrapCalibrationRecord> {
        self.trap_applied.as_ref()
    }

    /// Is a live rig being opened?
    pub fn is_connecting(&self) -> bool {
        self.connecting.is_some()
    }

    fn engine_ready(&mut self, spawned: Result<EngineHandle, crate::engine::EngineError>) {
        match spawned {
            Ok(mut h) => {
                h.set_condition(self.settings.condition);
                self.explore.reset(&self.rig_config);
                // A calibration applied before keeps being used when the
                // engine restarts (after a study sitting, a reconnect).
                if let Some(a) = &self.applied
                    && let Err(e) = h.apply_chain(&a.chain, &a.clearance)
                {
                    self.notify(format!("calibration not re-applied: {e}"), true);
                    self.applied = None;
                }
                if let Some(t) = &self.trap_applied
                    && let Err(e) = h.check_trap_calibration(t).and_then(|()| {
                        h.apply_trap_calibration(Some(t.applied()))
                            .map_err(|e| e.to_string())
                    })
                {
                    self.notify(format!("trap calibration not re-applied: {e}"), true);
                    self.trap_applied = None;
                }
                self.engine = Some(h);
            }
            Err(e) => self.notify(format!("cannot start the engine: {e}"), true),
        }
    }

    /// Collect a finished background connect.
    fn poll_connect(&mut self) {
        let Some(p) = &self.connecting else {
            return;
        };
        match p.rx.try_recv() {
            Ok(spawned) => {
                self.connecting = None;
                self.engine_ready(spawned);
            }
            Err(mpsc::TryRecvError::Empty) => {}
            Err(mpsc::TryRecvError::Disconnected) => {
                let label = p.label.clone();
                self.connecting = None;
                self.notify(
                    format!("cannot start the engine on {label}: the connecting thread ended"),
                    true,
                );
            }
        }
    }

    /// THE emergency stop of the GUI (button and Esc): never blocks.
    pub fn emergency_stop(&mut self) {
        let sitting = self.study.emergency_stop();
        match &self.engine {
            Some(e) => {
                e.emergency_stop();
                if let Some(what) = sitting {
                    self.notify(
                        format!(
                            "emergency stop: {what}; the sitting is paused and the outputs held \
                             at zero until the stop is reset"
                        ),
                        true,
                    );
                }
            }
            None => self.notify(
                "emergency stop: no rig connected (outputs already off)",
                false,
            ),
        }
        self.reset_dialog = None;
    }

    /// Is an emergency stop latched, the engine's or a study sitting's?
    pub fn any_estop_latched(&self) -> bool {
        self.estop_latched() || self.study.estop_latched()
    }

    /// Is the engine's emergency stop latched (per the last health report)?
    pub fn estop_latched(&self) -> bool {
        self.engine.as_ref().is_some_and(|e| {
            e.health().is_some_and(|h| h.safety == SafetyState::EStop)
                || e.estop_count() > 0 && e.health().is_none()
        })
    }

    /// Switch to the rig file `cfg` (read from `path`; `None`: the built-in
    /// rig): the applied calibration is dropped (it belongs to the rig file
    /// it was cleared for), the Explore scene reset, and a running engine
    /// restarted on the new rig.
    fn use_rig_file(&mut self, cfg: RigConfig, path: Option<PathBuf>) {
        self.rig_config = cfg;
        self.applied = None;
        self.trap_applied = None;
        self.rig_config_path = path.clone();
        self.settings.rig_file = path;
        self.config_error = None;
        let was = self.engine.is_some();
        self.engine = None;
        self.explore.reset(&self.rig_config);
        if was {
            self.connect();
        }
    }

    fn handle_requests(&mut self) {
        for r in std::mem::take(&mut self.requests) {
            match r {
                ShellRequest::Notify(s) => self.notify(s, false),
                ShellRequest::ShowRigPage => self.page = Page::Rig,
                ShellRequest::EmergencyStop => self.emergency_stop(),
                ShellRequest::LoadRigFile(p) => {
                    let path = PathBuf::from(&p);
                    match RigConfig::load(&path) {
                        Ok(c) => {
                            self.use_rig_file(c, Some(path));
                            self.notify(format!("rig file loaded: {p}"), false);
                        }
                        Err(e) => self.config_error = Some(e.to_string()),
                    }
                }
                ShellRequest::UseDefaultRig => self.use_rig_file(RigConfig::default(), None),
                ShellRequest::Connect => self.connect(),
                ShellRequest::Reconnect => {
                    if let (Some(e), Ok(spec)) = (&mut self.engine, self.rig_page.spec()) {
                        let other = (spec != *e.spec()).then_some(spec);
                        e.reconnect(other);
                    }
                }
                ShellRequest::Disconnect => {
                    if let Some(e) = self.engine.take() {
                        e.shutdown();
                    }
                }
                ShellRequest::StartEngine => {
                    if let Some(e) = &mut self.engine {
                        let _ = e.send(crate::engine::Command::Start);
                    }
                }
                ShellRequest::StopEngine => {
                    if let Some(e) = &mut self.engine {
                        let _ = e.send(crate::engine::Command::Stop);
                    }
                }
                ShellRequest::ConnectRig(spec) => {
                    if self.study.is_running() {
                        self.notify("the rig cannot change while a sitting runs", true);
                    } else {
                        self.rig_page.rig_text = spec.describe();
                        self.connect();
                    }
                }
                ShellRequest::SetOutputDir(p) => self.settings.output_dir = Some(p),
                ShellRequest::ApplyTrapCalibration(t) => match (&mut self.engine, t) {
                    (None, _) => {
                        self.notify("trap calibration not applied: no rig connected", true)
                    }
                    (Some(h), None) => match h.apply_trap_calibration(None) {
                        Ok(()) => self.trap_applied = None,
                        Err(e) => self.notify(format!("trap calibration not removed: {e}"), true),
                    },
                    (Some(h), Some(t)) => {
                        let r = h.check_trap_calibration(&t).and_then(|()| {
                            h.apply_trap_calibration(Some(t.applied()))
                                .map_err(|e| e.to_string())
                        });
                        match r {
                            Ok(()) => {
                                self.trap_applied = Some(*t);
                                self.notify("trap calibration applied to the tweezer", false);
                            }
                            Err(e) => {
                                self.notify(format!("trap calibration not applied: {e}"), true)
                            }
                        }
                    }
                },
                ShellRequest::ApplyCalibration(a) => {
                    let fs = self.rig_config.rig.sample_rate_hz;
                    let c = &a.chain.coefficients;
                    match &mut self.engine {
                        _ if c.fs() != fs => self.notify(
                            format!(
                                "calibration not applied: it is for {} Hz, the rig runs at {fs} Hz",
                                c.fs()
                            ),
                            true,
                        ),
                        None => self.notify("calibration not applied: no rig connected", true),
                        Some(h) => match h.apply_chain(&a.chain, &a.clearance) {
                            Ok(()) => self.applied = Some(*a),
                            Err(e) => self.notify(format!("calibration not applied: {e}"), true),
                        },
                    }
                }
            }
        }
    }

    fn poll_engine(&mut self) {
        let Some(e) = &mut self.engine else {
            return;
        };
        self.explore.ingest(e);
        let mut msgs = Vec::new();
        for ev in e.poll_events() {
            match ev {
                EngineEvent::ChainSwapped(o) => msgs.push((swap_words(o).to_owned(), false)),
                EngineEvent::RigError(err) => msgs.push((format!("rig stopped: {err}"), true)),
                EngineEvent::Reconnected(id) => {
                    msgs.push((format!("rig reconnected: {}", id.name), false))
                }
                EngineEvent::RigFault(f) => msgs.push((format!("rig: {}", f.describe()), false)),
                EngineEvent::Refused(why) => msgs.push((why.to_owned(), true)),
                EngineEvent::Health(_) | EngineEvent::Garbage(_) => {}
            }
        }
        let dead = !e.is_alive();
        for (m, err) in msgs {
            self.notify(m, err);
        }
        if dead {
            self.engine = None;
            self.notify(
                "the engine thread ended unexpectedly; reconnect on the Rig page",
                true,
            );
        }
    }

    fn top_bar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            ui.label(RichText::new("kilotouch").strong().size(18.0));
            ui.separator();
            for p in Page::ALL {
                let r = ui.selectable_label(self.page == p, RichText::new(p.title()).size(15.0));
                if r.clicked() {
                    self.page = p;
                }
            }
            ui.with_layout(egui::Layout::right_to_left(egui::Align::Center), |ui| {
                let stop = egui::Button::new(
                    RichText::new("EMERGENCY STOP  [Esc]")
                        .size(17.0)
                        .strong()
                        .color(Color32::WHITE),
                )
                .fill(Color32::from_rgb(200, 20, 20))
                .min_size(egui::vec2(250.0, 34.0));
                if ui
                    .add(stop)
                    .on_hover_text("zero all outputs now (key: Esc)")
                    .clicked()
                {
                    self.emergency_stop();
                }
                if self.any_estop_latched() {
                    if ui
                        .add(
                            egui::Button::new("Reset emergency stop…")
                                .min_size(egui::vec2(0.0, 34.0)),
                        )
                        .clicked()
                    {
                        self.reset_dialog = Some(false);
                    }
                    ui.label(
                        RichText::new("OUTPUTS HELD AT ZERO")
                            .color(Color32::RED)
                            .strong(),
                    );
                }
            });
        });
    }

    fn status_bar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            match &self.engine {
                None => match (&self.connecting, self.study.status_line()) {
                    (Some(p), _) => {
                        ui.spinner();
                        ui.label(format!("connecting to {}…", p.label));
                    }
                    (None, Some(line)) => {
                        if self.study.estop_latched() {
                            ui.colored_label(Color32::RED, "EMERGENCY STOP");
                            ui.separator();
                        }
                        ui.label(line);
                    }
                    (None, None) => {
                        ui.colored_label(Color32::GRAY, "disconnected");
                    }
                },
                Some(e) => match e.health() {
                    None => {
                        ui.label(format!("{}: starting…", e.identity().name));
                    }
                    Some(h) => {
                        let col = match h.safety {
                            SafetyState::EStop | SafetyState::Fault => Color32::RED,
                            SafetyState::Enabled => Color32::from_rgb(60, 200, 90),
                            _ => Color32::from_rgb(230, 180, 40),
                        };
                        ui.colored_label(col, h.status_label().to_owned());
                        ui.separator();
                        ui.label(format!(
                            "{} · {}",
                            h.condition.code(),
                            if h.running { "running" } else { "paused" }
                        ));
                        ui.separator();
                        ui.label(format!("loop {:.0} Hz", h.loop_rate_hz));
                        ui.label(format!("load {:.1} %", 100.0 * h.load));
                        deadline_ui(ui, h);
                        if h.telemetry_dropped > 0 {
                            ui.label(format!("telemetry dropped {}", h.telemetry_dropped));
                        }
                    }
                },
            }
            if self.engine.is_some()
                && let Some(line) = self.study.status_line()
            {
                ui.separator();
                ui.label(line);
            }
            ui.separator();
            ui.weak(format!("scene: {}", self.gpu_status));
        });
        // Messages: errors stay until dismissed, others fade after 8 s. One
        // line of fixed height (the newest, the others behind "+N more"),
        // so messages coming and going never move the page above.
        let now = Instant::now();
        self.notices
            .retain(|n| n.error || now.duration_since(n.at).as_secs_f64() < 8.0);
        let mut dismiss = None;
        let line_h = ui.text_style_height(&egui::TextStyle::Body) + 6.0;
        let width = ui.available_width();
        ui.allocate_ui_with_layout(
            egui::vec2(width, line_h),
            egui::Layout::left_to_right(egui::Align::Center),
            |ui| {
                ui.set_min_size(egui::vec2(width, line_h));
                let newest = self.notices.len().checked_sub(1);
                if let Some(i) = newest {
                    notice_ui(ui, &self.notices[i], i, &mut dismiss, true);
                }
                if self.notices.len() > 1 {
                    let label = format!("+{} more", self.notices.len() - 1);
                    ui.menu_button(label, |ui| {
                        for (i, n) in self.notices.iter().enumerate().rev().skip(1) {
                            ui.horizontal(|ui| notice_ui(ui, n, i, &mut dismiss, false));
                        }
                    });
                }
            },
        );
        if let Some(i) = dismiss {
            self.notices.remove(i);
        }
    }

    fn reset_dialog_ui(&mut self, ctx: &egui::Context) {
        let Some(mut confirmed) = self.reset_dialog else {
            return;
        };
        let mut close = false;
        let mut release = false;
        egui::Modal::new(egui::Id::unique("estop-reset")).show(ctx, |ui| {
            ui.heading("Reset emergency stop");
            ui.label("All outputs are held at zero. Before re-enabling them:");
            ui.label("• the handle is free or held by the operator,\n• nothing touches the moving parts,\n• the cause of the stop is understood.");
            ui.checkbox(&mut confirmed, "I have checked that the rig is safe");
            ui.horizontal(|ui| {
                if ui
                    .add_enabled(confirmed, egui::Button::new("Re-enable outputs (ramped)"))
                    .clicked()
                {
                    release = true;
                }
                if ui.button("Cancel").clicked() {
                    close = true;
                }
            });
        });
        self.reset_dialog = Some(confirmed);
        if release {
            // The stop's notices are history once it is reset.
            self.notices
                .retain(|n| !n.text.starts_with("emergency stop"));
            if let Some(e) = &mut self.engine
                && !e.reset_emergency_stop()
            {
                self.notify("reset not sent (command queue full), try again", true);
            }
            if self.study.estop_latched() {
                self.study.release_emergency_stop();
                self.notify(
                    "emergency stop reset: press Resume on the Study page to go on",
                    false,
                );
            }
            close = true;
        }
        if close {
            self.reset_dialog = None;
        }
    }

    /// The whole UI (also used by the tests without eframe).
    pub fn ui_root(&mut self, ui: &mut egui::Ui) {
        let ctx = ui.ctx().clone();
        if ctx.input_mut(|i| i.consume_key(egui::Modifiers::NONE, egui::Key::Escape)) {
            self.emergency_stop();
        }
        self.poll_connect();
        if self.connecting.is_some() {
            ctx.request_repaint_after(std::time::Duration::from_millis(50));
        }
        self.poll_engine();
        // A sitting opened while the Rig page streams to Lab Streaming
        // Layer sends its markers there.
        #[cfg(feature = "lsl")]
        self.study
            .set_lsl(self.rig_page.lsl().map(crate::lsl::LslPublisher::markers));
        egui::Panel::top("kilotouch-top").show(ui, |ui| self.top_bar(ui));
        egui::Panel::bottom("kilotouch-status").show(ui, |ui| self.status_bar(ui));
        egui::CentralPanel::default().show(ui, |ui| {
            let mut env = page_env!(self);
            let page: &mut dyn pages::Page = match self.page {
                Page::Rig => &mut self.rig_page,
                Page::Calibration => &mut self.calibration,
                Page::Explore => &mut self.explore,
                Page::Study => &mut self.study,
                Page::Results => &mut self.results,
            };
            page.ui(ui, &mut env);
        });
        self.handle_requests();
        // Every page's background work (Study sittings: drain events, the
        // participant window).
        {
            let mut env = page_env!(self);
            let all: [&mut dyn pages::Page; 5] = [
                &mut self.rig_page,
                &mut self.calibration,
                &mut self.explore,
                &mut self.study,
                &mut self.results,
            ];
            for page in all {
                page.background(&ctx, &mut env);
            }
        }
        self.handle_requests();
        self.reset_dialog_ui(&ctx);
        self.settings.page = self.page;
        self.settings.camera = self.explore.camera.model;
        self.settings.trace_seconds = self.explore.trace_seconds;
        if let Some(e) = &self.engine {
            self.settings.condition = e.condition();
        }
        // Live pages repaint at 30 fps (the camera's rate; rendering faster
        // only takes CPU from the engine), others often enough to drain
        // the telemetry queue.
        if self.page == Page::Explore || self.page == Page::Rig {
            ctx.request_repaint_after(std::time::Duration::from_millis(33));
        } else {
            ctx.request_repaint_after(std::time::Duration::from_millis(100));
        }
    }

    fn screenshot_step(&mut self, ctx: &egui::Context) {
        let Some(plan) = &mut self.screenshot else {
            return;
        };
        ctx.request_repaint_after(std::time::Duration::from_millis(33));
        if !plan.requested && plan.start.elapsed().as_secs_f64() >= plan.after_s {
            plan.requested = true;
            match &plan.path {
                None => ctx.send_viewport_cmd(egui::ViewportCommand::Close),
                Some(_) => {
                    let tx = plan.tx.clone();
                    ctx.request_screenshot(move |img| {
                        let _ = tx.send(img);
                    });
                }
            }
        }
        if let Ok(img) = plan.rx.try_recv() {
            let code = match &plan.path {
                Some(p) => match super::save_png(&img, p, plan.bits) {
                    Ok(()) if super::image_is_blank(&img) => {
                        eprintln!("kilotouch: screenshot {} is blank", p.display());
                        1
                    }
                    Ok(()) => {
                        eprintln!(
                            "kilotouch: screenshot saved to {} ({}×{})",
                            p.display(),
                            img.width(),
                            img.height()
                        );
                        0
                    }
                    Err(e) => {
                        eprintln!("kilotouch: cannot save screenshot {}: {e}", p.display());
                        1
                    }
                },
                None => 0,
            };
            plan.exit_code.store(code, Ordering::SeqCst);
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
    }
}

/// What a chain swap did, in words.
pub fn swap_words(o: crate::engine::splitter::SwapOutcome) -> &'static str {
    use crate::engine::splitter::SwapOutcome;
    match o {
        SwapOutcome::Faded => {
            "calibration applied to the engine: the forces cross-faded to the new compensation"
        }
        SwapOutcome::Replaced => {
            "calibration applied to the engine: its filters took over, starting from rest"
        }
        SwapOutcome::WrongSampleRate => {
            "calibration refused by the engine: it was made for another sample rate"
        }
    }
}

/// One notice: red with a dismiss button for an error, its repeat count.
fn notice_ui(ui: &mut egui::Ui, n: &Notice, i: usize, dismiss: &mut Option<usize>, truncate: bool) {
    let text = if n.count > 1 {
        format!("{} (×{})", n.text, n.count)
    } else {
        n.text.clone()
    };
    let color = if n.error {
        Color32::from_rgb(235, 80, 70)
    } else {
        ui.visuals().text_color()
    };
    if n.error && ui.small_button("dismiss").clicked() {
        *dismiss = Some(i);
    }
    let label = egui::Label::new(RichText::new(text.clone()).color(color));
    let label = if truncate { label.truncate() } else { label };
    ui.add(label).on_hover_text(text);
}

/// Deadline misses in the status bar: the count, their share of the blocks
/// and the worst lateness, coloured by what they mean, with the
/// explanation and the check to run on hover.
fn deadline_ui(ui: &mut egui::Ui, h: &crate::engine::Health) {
    let share = if h.blocks > 0 {
        h.deadline_misses as f64 / h.blocks as f64
    } else {
        0.0
    };
    let worst_ms = 1e3 * h.worst_lateness_total_s.max(0.0);
    let col = match deadline_verdict(share, worst_ms) {
        TimingVerdict::Clean => ui.visuals().text_color(),
        TimingVerdict::MachineFloor => Color32::from_rgb(230, 150, 40),
        TimingVerdict::Degraded => Color32::from_rgb(235, 80, 70),
    };
    ui.colored_label(
        col,
        format!(
            "deadline misses {} ({:.1} ‰, worst {worst_ms:.0} ms) [?]",
            h.deadline_misses,
            1e3 * share
        ),
    )
    .on_hover_text(DEADLINE_HELP);
    ui.label(format!(
        "worst late {:.2} ms",
        1e3 * h.worst_lateness_s.max(0.0)
    ))
    .on_hover_text(
        "largest lateness of a block past its deadline in the last 100 ms (0 = all on time)",
    );
}

/// How the deadline misses of the running engine read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum TimingVerdict {
    /// No block was late.
    Clean,
    /// Under 1 ‰ of the blocks late and none by more than 10 ms: the late
    /// wake-ups of a busy or virtual machine.
    MachineFloor,
    /// More, or a block later than 10 ms: the forces were felt late.
    Degraded,
}

fn deadline_verdict(share: f64, worst_ms: f64) -> TimingVerdict {
    if share <= 0.0 {
        TimingVerdict::Clean
    } else if share < 1e-3 && worst_ms <= 10.0 {
        TimingVerdict::MachineFloor
    } else {
        TimingVerdict::Degraded
    }
}

/// The status bar's explanation of deadline misses (docs/GUI.md, "Deadline
/// misses: what to do").
const DEADLINE_HELP: &str = "A deadline miss is a 1 ms block of the loop that finished more \
than 2 ms after its deadline. The simulation never skips a sample (a late block is caught up), \
so the recorded samples are complete; what a miss changes is *when* the force reached the \
hand: up to the worst lateness shown, late.\n\n\
• none (grey): the timing is clean.\n\
• orange: under 1 ‰ of the blocks, none later than 10 ms: the late wake-ups of a busy or \
virtual machine; fine for exploring and dry runs.\n\
• red: more, or a block later than 10 ms: the finger felt forces late. Do not run \
participants on this machine as it is.\n\n\
To qualify a lab PC, close other programs and run in a terminal:\n\
    kilotouch bench --paced 60\n\
It runs the engine for 60 s beside an idle reference thread; a machine fit for a study shows \
(almost) no misses and no more than the reference. See docs/GUI.md, \"Deadline misses\".";

impl eframe::App for KilotouchApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        self.screenshot_step(&ctx);
        self.ui_root(ui);
    }

    fn save(&mut self, storage: &mut dyn eframe::Storage) {
        if !self.fresh {
            let rig = self.rig_page.rig_text.trim();
            self.settings.rig_spec = (!rig.is_empty()).then(|| rig.to_owned());
            let tw = self.rig_page.tweezer_text.trim();
            self.settings.tweezer_spec = (!tw.is_empty() && tw != "sim").then(|| tw.to_owned());
            self.settings.protocol_source = Some(
                match self.study.form.source {
                    ProtocolSource::Paper => "paper",
                    ProtocolSource::Blind => "blind",
                    ProtocolSource::File => "file",
                }
                .to_owned(),
            );
            let file = self.study.form.protocol_file.trim();
            self.settings.protocol_file = (!file.is_empty()).then(|| PathBuf::from(file));
            self.settings.save(storage);
        }
    }

    fn on_exit(&mut self) {
        if let Some(e) = self.engine.take() {
            e.emergency_stop();
            e.shutdown();
        }
    }
}
