//! Study page: load a protocol, enter a pseudonymous participant ID, see the
//! counterbalanced order, run the training block and the sessions on the
//! real-time engine ([`crate::session`]: the engine the Rig page connected,
//! simulated or live), with an experimenter view (state,
//! trial controls, live metrics, finished rows) and a participant view (the
//! microscope scene through the simulated camera, or a dark screen for the
//! blind task) in a separate viewport or inline.
//!
//! The page never blocks: commands go to the sitting's worker, the hand
//! position to the engine, through queues; events come back the same way
//! and are drained every frame by [`StudyPage::background`] (called by the
//! shell whatever page is shown, so the participant window keeps running).

use std::path::PathBuf;

use egui::{Color32, RichText, Sense};
use kilotouch_rig::tweezer::Obstacle;
use kilotouch_study::export::TrialRow;
use kilotouch_study::protocol::{AssignmentTable, Protocol};
use kilotouch_study::runner::RunnerState;
use kilotouch_study::seeds::TrialKey;
use kilotouch_study::task::Scene;
use kilotouch_study::task::station::HandMapping;

use crate::engine::EngineHandle;
use crate::gui::env::{PageEnv, ShellRequest};
use crate::gui::pages::study_size::{PreparedSitting, SizeGate, Verdict};
use crate::gui::participant_screen::{ParticipantScreen, Routine};
use crate::gui::path_field::{PathField, PathKind, TOML};
use crate::gui::scene::{self, SceneFrame, View};
use crate::gui::scene_wgpu::SceneCallback;
use crate::session::{
    FinishReason, FolderStatus, ParticipantId, ParticipantKind, SessionCommand, SessionEvent,
    SessionHandle, SessionHealth, SessionOptions, Speed, Telemetry, inspect_folder,
    validate_participant_id,
};

/// Where the protocol comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProtocolSource {
    /// Built-in `paper` (circling, V/P/D).
    Paper,
    /// Built-in `blind` (blind navigation).
    Blind,
    /// A TOML file.
    File,
}

/// Which chain D runs in a sitting (recorded in `session.json` and the
/// journal with the file's SHA-256).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CalibrationChoice {
    /// The calibration applied to the engine on the Calibration page (its
    /// file); the as-designed chain when none is applied.
    #[default]
    Applied,
    /// The model's as-designed chain, recorded as uncalibrated.
    AsDesigned,
    /// A calibration file typed in.
    File,
}

/// Where the participant's window opens.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Monitor {
    /// The experimenter's monitor (the window opens over this one).
    #[default]
    Same,
    /// The monitor to the right of the experimenter's (the window is placed
    /// one screen width to the right; full screen then fills that monitor).
    Right,
    /// The monitor to the left.
    Left,
}

/// Study sessions.
#[derive(Debug)]
pub struct StudyPage {
    /// Protocol source.
    pub source: ProtocolSource,
    /// Protocol file path (for [`ProtocolSource::File`]).
    pub protocol_file: String,
    /// Participant ID as typed.
    pub participant_text: String,
    /// Output folder as typed (initialised from the settings).
    pub out_text: String,
    /// Person at the mouse or simulated participant.
    pub kind: ParticipantKind,
    /// Pacing (as fast as possible: simulated participant only).
    pub speed: Speed,
    /// Participant view in a separate window (else inline on this page;
    /// inline is what the UI tests use).
    pub separate_window: bool,
    /// Which chain D runs.
    pub calibration: CalibrationChoice,
    /// Calibration file (for [`CalibrationChoice::File`]).
    pub calibration_file: String,
    /// Draw the scene with wgpu (set by the shell when installed).
    pub gpu: bool,
    /// Monitor of the participant's window.
    pub monitor: Monitor,
    /// Participant's window full screen.
    pub fullscreen: bool,
    screen: Option<ParticipantScreen>,
    estop_latched: bool,
    run_all: bool,
    shown_for: Option<(String, String)>,
    autostart: bool,
    protocol: Option<Protocol>,
    table: Option<AssignmentTable>,
    protocol_error: Option<String>,
    loaded_source: Option<(ProtocolSource, String)>,
    out_seeded: bool,
    folder: Option<(PathBuf, FolderStatus)>,
    session: Option<SessionHandle>,
    sitting_id: Option<ParticipantId>,
    mapping: HandMapping,
    state: Option<RunnerState>,
    current: Option<(TrialKey, Scene)>,
    telemetry: Option<Telemetry>,
    health: SessionHealth,
    /// The running sitting's timing verdict so far.
    timing: Option<kilotouch_study::export::SittingTiming>,
    rows: Vec<TrialRow>,
    committed: usize,
    planned: usize,
    note_text: String,
    log: Vec<String>,
    error: Option<String>,
    finished: Option<FinishReason>,
    recovery_text: Option<String>,
    trap_target_m: [f64; 2],
    /// The participant's hand to send to the engine (mouse drags).
    pending_hand: Option<[f64; 2]>,
    /// The rig of the sitting (`sim`, `serial:PATH`), its loop delay.
    rig_used: Option<String>,
    /// What the last emergency stop did to the sitting.
    estop_what: Option<String>,
    /// Esc in the participant's window, for the shell.
    estop_request: bool,
    /// Where the participant's window opened (screen points).
    participant_at: Option<[f32; 2]>,
    /// The size check before a sitting opens.
    pub size_gate: SizeGate,
    protocol_field: PathField,
    out_field: PathField,
    calibration_field: PathField,
}

impl Default for StudyPage {
    fn default() -> Self {
        Self::new()
    }
}

impl StudyPage {
    /// New page.
    pub fn new() -> Self {
        Self {
            source: ProtocolSource::Paper,
            protocol_file: String::new(),
            participant_text: String::new(),
            out_text: String::new(),
            kind: ParticipantKind::Mouse,
            speed: Speed::RealTime,
            separate_window: true,
            calibration: CalibrationChoice::default(),
            calibration_file: String::new(),
            gpu: false,
            monitor: Monitor::Same,
            fullscreen: false,
            screen: None,
            estop_latched: false,
            run_all: false,
            shown_for: None,
            autostart: false,
            protocol: None,
            table: None,
            protocol_error: None,
            loaded_source: None,
            out_seeded: false,
            folder: None,
            session: None,
            sitting_id: None,
            mapping: HandMapping::from_config(&kilotouch_rig::RigConfig::default().coupling),
            state: None,
            current: None,
            telemetry: None,
            health: SessionHealth::default(),
            timing: None,
            rows: Vec::new(),
            committed: 0,
            planned: 0,
            note_text: String::new(),
            log: Vec::new(),
            error: None,
            finished: None,
            recovery_text: None,
            trap_target_m: [0.0; 2],
            pending_hand: None,
            rig_used: None,
            estop_what: None,
            estop_request: false,
            participant_at: None,
            size_gate: SizeGate::default(),
            protocol_field: PathField::default(),
            out_field: PathField::default(),
            calibration_field: PathField::default(),
        }
    }

    /// New page drawing the scene with wgpu when `gpu` (the shell installed
    /// the scene renderer).
    pub fn with_gpu(gpu: bool) -> Self {
        Self { gpu, ..Self::new() }
    }

    /// A session is open (the rig belongs to it).
    pub fn is_running(&self) -> bool {
        self.session.is_some()
    }

    /// The trial the engine has begun (its `TrialStarted` arrived), if any.
    /// The participant's screen shows a trial as soon as the runner is in
    /// it, a block or so before the engine begins it.
    pub fn trial_started(&self) -> Option<TrialKey> {
        self.current.map(|(k, _)| k)
    }

    /// Trials in the study's plan as the sitting last reported it (it grows
    /// when an unsuccessful practice trial earns an extra one).
    pub fn planned(&self) -> usize {
        self.planned
    }

    /// Rows shown in the table (this participant's, from `trials.csv` and
    /// the rows committed in this sitting).
    pub fn rows(&self) -> &[TrialRow] {
        &self.rows
    }

    /// The runner state last reported.
    pub fn runner_state(&self) -> Option<RunnerState> {
        self.state
    }

    /// How the last sitting ended.
    pub fn finished(&self) -> Option<&FinishReason> {
        self.finished.as_ref()
    }

    /// The last error shown.
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    /// The shell pressed the engine's emergency stop: a running sitting
    /// aborts its trial and pauses (the engine's driver reports it); it
    /// cannot resume until the stop is reset through the shell's
    /// confirmation ([`StudyPage::release_emergency_stop`]).
    ///
    /// Returns what the stop did to the sitting, in one sentence for the
    /// shell's notice (`None`: no sitting runs): which trial was aborted,
    /// or that none was (an instructions, ready or break screen, the
    /// inter-trial interval).
    pub fn emergency_stop(&mut self) -> Option<String> {
        self.session.as_ref()?;
        self.estop_latched = true;
        let what = match self.state {
            Some(
                RunnerState::Training(k) | RunnerState::Trial(k) | RunnerState::Paused(Some(k)),
            ) => {
                format!("trial {k} was aborted (its row is kept as `aborted`)")
            }
            _ => "no trial was running, none was aborted".to_owned(),
        };
        self.estop_what = Some(what.clone());
        Some(what)
    }

    /// Esc was pressed in the participant's window since the last call
    /// (the shell then stops as from its own window).
    pub fn take_estop_request(&mut self) -> bool {
        std::mem::take(&mut self.estop_request)
    }

    /// On the first draw, open a sitting of the folder's next pending
    /// participant (or P01 of a new folder) with the simulated participant
    /// in real time, participant view inline, and start it.
    pub fn simulate_sitting(&mut self) {
        self.kind = ParticipantKind::Simulated;
        self.speed = Speed::RealTime;
        self.separate_window = false;
        self.autostart = true;
    }

    /// An emergency stop of this sitting waits for its reset.
    pub fn estop_latched(&self) -> bool {
        self.estop_latched
    }

    /// The experimenter confirmed that the rig is safe (the shell's reset
    /// dialog): Resume is possible again (it is not pressed for them).
    pub fn release_emergency_stop(&mut self) {
        self.estop_latched = false;
        self.estop_what = None;
    }

    /// One line for the shell's status bar while a sitting owns the rig:
    /// participant and runner state.
    pub fn status_line(&self) -> Option<String> {
        self.session.as_ref()?;
        Some(format!("study sitting: {}", self.heading()))
    }

    /// "P01 · trial P01/V/test/3": whose sitting it is and where the runner
    /// is (a run of every remaining participant says so: the trial's key
    /// names its participant).
    fn heading(&self) -> String {
        let state = self.state.unwrap_or(RunnerState::Idle);
        if self.run_all {
            return format!("all remaining participants · {state}");
        }
        let id = self
            .sitting_id
            .as_ref()
            .map(|p| p.id.clone())
            .unwrap_or_default();
        format!("{id} · {state}")
    }

    /// The participant's screen (while a sitting runs, and its end screen
    /// until closed).
    pub fn participant_screen(&self) -> Option<&ParticipantScreen> {
        self.screen.as_ref()
    }

    /// The participant's key press or click (what the participant window
    /// does on Space, Enter or a click).
    pub fn participant_input(&mut self) {
        if let Some(sc) = &mut self.screen
            && sc.input()
        {
            self.send(SessionCommand::Proceed);
        }
    }

    /// Forget what the last sitting showed (after switching participant or
    /// folder): rows, metrics, messages, the end screen.
    fn clear_sitting_state(&mut self) {
        self.rows.clear();
        self.telemetry = None;
        self.current = None;
        self.state = None;
        self.finished = None;
        self.error = None;
        self.recovery_text = None;
        self.log.clear();
        self.health = SessionHealth::default();
        self.committed = 0;
        self.planned = 0;
        self.screen = None;
    }

    /// Drains the session's events and shows the participant window (when
    /// separate). Call every frame, whatever page is shown.
    pub fn background(&mut self, ctx: &egui::Context, mut engine: Option<&mut EngineHandle>) {
        self.poll(engine.as_deref_mut());
        if self.session.is_some() {
            ctx.request_repaint();
        }
        if (self.session.is_some() || self.screen.is_some()) && self.separate_window {
            let id = egui::ViewportId::from_hash_of("kilotouch-participant");
            let mut builder = egui::ViewportBuilder::default()
                .with_title("kilotouch — participant")
                .with_inner_size([720.0, 720.0])
                .with_fullscreen(self.fullscreen);
            let monitor_w = ctx.input(|i| i.viewport().monitor_size.map_or(1920.0, |m| m.x));
            match self.monitor {
                // Beside the experimenter's window when it fits on the
                // monitor, else over it offset from its corner (never at
                // the screen's origin over the console); where the window
                // was when it opened, so that moving the console does not
                // move the participant's window.
                Monitor::Same => {
                    let main = ctx.input(|i| i.viewport().outer_rect);
                    if self.participant_at.is_none()
                        && let Some(r) = main
                    {
                        let beside = r.max.x + 8.0;
                        self.participant_at = Some(if beside + 720.0 <= monitor_w {
                            [beside, r.min.y]
                        } else {
                            [r.min.x + 40.0, r.min.y + 40.0]
                        });
                    }
                    if let Some(at) = self.participant_at {
                        builder = builder.with_position(at);
                    }
                }
                Monitor::Right => builder = builder.with_position([monitor_w + 40.0, 40.0]),
                Monitor::Left => builder = builder.with_position([-monitor_w + 40.0, 40.0]),
            }
            ctx.show_viewport_immediate(id, builder, |ui, _class| {
                egui::CentralPanel::default()
                    .frame(egui::Frame::NONE.fill(Color32::BLACK))
                    .show(ui, |ui| self.participant_view(ui, true));
            });
        } else {
            self.participant_at = None;
        }
        self.flush_hand(engine);
    }

    /// The participant's hand (mouse) to the engine.
    fn flush_hand(&mut self, engine: Option<&mut EngineHandle>) {
        if let (Some(h), Some(e)) = (self.pending_hand, engine)
            && e.set_hand(h)
        {
            self.pending_hand = None;
        }
    }

    fn poll(&mut self, engine: Option<&mut EngineHandle>) {
        let Some(s) = &mut self.session else {
            return;
        };
        let events = s.poll();
        if let Some(e) = engine.as_deref() {
            self.health = s.health(e);
        }
        self.timing = Some(s.timing());
        let mut end = None;
        for e in events {
            match e {
                SessionEvent::State(st) => {
                    self.state = Some(st);
                    if let Some(sc) = &mut self.screen {
                        sc.on_state(st);
                    }
                }
                SessionEvent::TrialStarted { key, scene } => {
                    self.current = Some((key, scene));
                    self.telemetry = None;
                    self.trap_target_m = scene.start_m;
                    self.pending_hand = Some(self.mapping.to_hand(scene.start_m));
                    self.log.push(format!("started {key}"));
                }
                SessionEvent::TrialEnded(k, e) => {
                    if let Some(sc) = &mut self.screen {
                        sc.on_trial_ended(k);
                    }
                    self.log.push(format!("ended {k}: {e:?}"));
                }
                SessionEvent::Committed(row) => {
                    self.committed += 1;
                    self.rows.push(*row);
                }
                SessionEvent::Replanned(n) => {
                    self.planned = n;
                    self.log.push(format!(
                        "an unsuccessful practice trial earned an extra one ({n} trials planned)"
                    ));
                }
                SessionEvent::Telemetry(t) => self.telemetry = Some(t),
                SessionEvent::Noted(n) => self.log.push(format!("note: {n}")),
                SessionEvent::Error(m) => {
                    self.log.push(format!("error: {m}"));
                    self.error = Some(m);
                }
                SessionEvent::Finished(r) => end = Some(r),
            }
        }
        if self.log.len() > 200 {
            let cut = self.log.len() - 200;
            self.log.drain(..cut);
        }
        if let Some(r) = end {
            if let FinishReason::Failed(m) = &r {
                self.error = Some(m.clone());
            }
            // The end screen stays (participant done, study done); a
            // stopped or failed sitting closes the participant's window.
            match (&r, &mut self.screen) {
                (FinishReason::StudyDone | FinishReason::ParticipantDone(_), Some(sc)) => {
                    sc.on_finished();
                }
                _ => self.screen = None,
            }
            self.finished = Some(r);
            // The engine goes back to free exploration (its driver, pacing
            // and chain as before the sitting).
            if let Some(s) = self.session.take() {
                match engine {
                    Some(e) => drop(s.close(e)),
                    None => drop(s),
                }
            }
            self.current = None;
            self.folder = None;
            self.run_all = false;
        }
    }

    fn load_protocol(&mut self) {
        let key = (self.source, self.protocol_file.trim().to_owned());
        if self.loaded_source.as_ref() == Some(&key) {
            return;
        }
        self.loaded_source = Some(key.clone());
        let r = match self.source {
            ProtocolSource::Paper => Protocol::builtin("paper"),
            ProtocolSource::Blind => Protocol::builtin("blind"),
            ProtocolSource::File if key.1.is_empty() => {
                self.protocol = None;
                self.table = None;
                self.protocol_error = Some("enter the path of a protocol file (TOML)".into());
                return;
            }
            ProtocolSource::File => Protocol::load(std::path::Path::new(&key.1)),
        };
        match r.and_then(|p| p.assignment().map(|t| (p, t))) {
            Ok((p, t)) => {
                self.protocol = Some(p);
                self.table = Some(t);
                self.protocol_error = None;
            }
            Err(e) => {
                self.protocol = None;
                self.table = None;
                self.protocol_error = Some(e.to_string());
            }
        }
    }

    fn folder_status(&mut self) -> Option<&FolderStatus> {
        let t = self.out_text.trim();
        if t.is_empty() {
            return None;
        }
        let p = PathBuf::from(t);
        if self.folder.as_ref().is_none_or(|(q, _)| *q != p) {
            let st = inspect_folder(&p);
            self.folder = Some((p, st));
        }
        self.folder.as_ref().map(|(_, s)| s)
    }

    /// The calibration file the sitting runs and records (`None`: the
    /// as-designed chain, recorded as uncalibrated).
    fn resolve_calibration(&self, env: &PageEnv<'_>) -> Result<Option<PathBuf>, String> {
        match self.calibration {
            CalibrationChoice::AsDesigned => Ok(None),
            CalibrationChoice::Applied => match env.applied {
                None => Ok(None),
                Some(a) => match &a.path {
                    Some(p) => Ok(Some(p.clone())),
                    None => Err(
                        "the applied calibration was not saved: save it on the Calibration page \
                         (a study records the file and its SHA-256), or choose another chain"
                            .into(),
                    ),
                },
            },
            CalibrationChoice::File => {
                let t = self.calibration_file.trim();
                if t.is_empty() {
                    Err("type the calibration file, or choose another chain".into())
                } else {
                    Ok(Some(PathBuf::from(t)))
                }
            }
        }
    }

    fn calibration_ui(&mut self, ui: &mut egui::Ui, env: &PageEnv<'_>) {
        ui.horizontal(|ui| {
            ui.label("D's chain:");
            let applied = match env.applied {
                Some(a) => format!("applied: {}", a.chain.source.describe()),
                None => "applied (none: as designed)".into(),
            };
            ui.radio_value(&mut self.calibration, CalibrationChoice::Applied, applied)
                .on_hover_text("the calibration applied on the Calibration page");
            ui.radio_value(
                &mut self.calibration,
                CalibrationChoice::AsDesigned,
                "as designed (uncalibrated)",
            );
            ui.radio_value(&mut self.calibration, CalibrationChoice::File, "file:");
            if self.calibration == CalibrationChoice::File {
                self.calibration_field.ui(
                    ui,
                    "calibration file",
                    &mut self.calibration_file,
                    PathKind::Open(TOML.0, TOML.1),
                    "calibration file (.toml)",
                    260.0,
                );
            }
        });
        let recorded = match self.resolve_calibration(env) {
            Ok(None) => "recorded as uncalibrated (the model's as-designed chain)".to_owned(),
            Ok(Some(p)) => format!("recorded: {} with its SHA-256", p.display()),
            Err(e) => e,
        };
        ui.label(RichText::new(recorded).weak());
        let trap = match env.trap_applied {
            Some(t) => format!(
                "trap calibration recorded: κ = {:.3} ± {:.3} pN/µm, R_d = {:.4} / {:.4} µm/V \
                 (applied on the Rig page)",
                t.kappa_pn_um, t.kappa_se_pn_um, t.rd_um_per_v[0], t.rd_um_per_v[1]
            ),
            None => "no trap calibration applied (the Rig page's Tweezer section)".to_owned(),
        };
        ui.label(RichText::new(trap).weak());
    }

    /// Open a sitting (`resume`: at the folder's next pending trial;
    /// `start`: send Start once it is open) after the size check
    /// ([`SizeGate`]): at once when it writes no raw files, else once the
    /// estimate fits the disk and, above the page's threshold, the
    /// experimenter confirmed.
    fn open_session(
        &mut self,
        env: &mut PageEnv<'_>,
        engine: Option<&mut EngineHandle>,
        resume: bool,
        start: bool,
    ) {
        self.error = None;
        if self.size_gate.is_busy() {
            self.error = Some("a sitting is already being checked: confirm or cancel it".into());
            return;
        }
        let Some(engine) = engine else {
            self.error = Some(
                "no rig is connected: connect the simulated rig or a live rig on the Rig page"
                    .into(),
            );
            return;
        };
        let Some(prepared) = self.prepare_session(env, engine, resume, start) else {
            return;
        };
        if let Some(v) = self.size_gate.check(prepared) {
            self.on_verdict(v, env, Some(engine));
        }
    }

    /// Act on the size check's verdict.
    fn on_verdict(&mut self, v: Verdict, env: &mut PageEnv<'_>, engine: Option<&mut EngineHandle>) {
        match (v, engine) {
            (Verdict::Open(p), Some(engine)) => {
                let start = p.start;
                self.spawn_session(*p, env, engine);
                if start {
                    if self.session.is_some() {
                        self.send(SessionCommand::Start);
                    } else {
                        self.run_all = false;
                    }
                }
            }
            (Verdict::Open(_), None) => {
                self.run_all = false;
                self.error = Some("the rig was disconnected before the sitting opened".into());
            }
            (Verdict::Refused(why), _) => {
                self.run_all = false;
                self.error = Some(why);
            }
            (Verdict::Cancelled, _) => {
                self.run_all = false;
                self.log
                    .push("the sitting was not opened (cancelled)".into());
            }
        }
    }

    /// Validate the page's choices into a sitting's options, or set the
    /// error and return `None`.
    fn prepare_session(
        &mut self,
        env: &mut PageEnv<'_>,
        engine: &EngineHandle,
        resume: bool,
        start: bool,
    ) -> Option<PreparedSitting> {
        self.finished = None;
        self.screen = None;
        let out = PathBuf::from(self.out_text.trim());
        if self.out_text.trim().is_empty() {
            self.error = Some("choose an output folder".into());
            return None;
        }
        let (protocol, pid) = if resume {
            let next = match self.folder_status() {
                Some(FolderStatus::Study { next: Some(n), .. }) => n.clone(),
                _ => {
                    self.error = Some("nothing to resume in this folder".into());
                    return None;
                }
            };
            (
                None,
                ParticipantId {
                    id: next.participant.clone(),
                    index: next.key.participant,
                },
            )
        } else {
            let (Some(p), Some(t)) = (&self.protocol, &self.table) else {
                self.error = Some("load a valid protocol first".into());
                return None;
            };
            match validate_participant_id(&self.participant_text, t) {
                Ok(id) => (Some(p.clone()), id),
                Err(e) => {
                    self.error = Some(e);
                    return None;
                }
            }
        };
        let calibration = match self.resolve_calibration(env) {
            Ok(c) => c,
            Err(e) => {
                self.error = Some(e);
                return None;
            }
        };
        let mut opts = SessionOptions::new(&out, protocol, env.rig_config.clone());
        opts.calibration = calibration;
        opts.trap_calibration = env.trap_applied.cloned();
        let kind = if engine.is_live() {
            ParticipantKind::Handle
        } else if self.kind == ParticipantKind::Handle {
            ParticipantKind::Mouse
        } else {
            self.kind
        };
        opts.participant = kind;
        opts.speed = if kind == ParticipantKind::Simulated {
            self.speed
        } else {
            Speed::RealTime
        };
        opts.only_participant = (!self.run_all).then_some(pid.index);
        // The participant's screens run in real time (a person, or the
        // simulated participant paced like one); a fast dry run skips them.
        opts.screens = opts.speed == Speed::RealTime;
        Some(PreparedSitting {
            opts,
            pid,
            resume,
            start,
        })
    }

    /// Open the sitting `p` on `engine`.
    fn spawn_session(
        &mut self,
        p: PreparedSitting,
        env: &mut PageEnv<'_>,
        engine: &mut EngineHandle,
    ) {
        let PreparedSitting {
            opts, pid, resume, ..
        } = p;
        let kind = opts.participant;
        let out = opts.out.clone();
        let opts_screens = opts.screens;
        match SessionHandle::spawn(opts, engine) {
            Ok(mut h) => {
                let info = h.info().clone();
                self.mapping = info.mapping;
                self.rig_used = Some(match &info.device {
                    Some(d) => format!(
                        "{} — {} (loop delay {:.1} ms)",
                        info.rig, d.name, d.loop_delay_ms
                    ),
                    None => "the simulated rig".to_owned(),
                });
                self.rows = info
                    .rows
                    .iter()
                    .filter(|r| r.participant == pid.id)
                    .cloned()
                    .collect();
                self.committed = info.completed;
                self.planned = info.planned;
                self.recovery_text = Some(info.recovery_text.clone());
                if let Ok(t) = info.protocol.assignment() {
                    self.table = Some(t);
                }
                if opts_screens {
                    let orders = self
                        .table
                        .as_ref()
                        .map(|t| t.participants.iter().map(|r| r.sessions.clone()).collect())
                        .unwrap_or_default();
                    self.screen = Some(ParticipantScreen::new(
                        info.protocol.clone(),
                        orders,
                        kind != ParticipantKind::Simulated,
                    ));
                }
                self.protocol = Some(info.protocol);
                self.participant_text = pid.id.clone();
                self.shown_for = Some((pid.id.clone(), self.out_text.trim().to_owned()));
                self.sitting_id = Some(pid);
                self.state = Some(RunnerState::Idle);
                self.log.clear();
                self.health = SessionHealth::default();
                if resume {
                    h.send(SessionCommand::Note("resumed from the Study page".into()));
                }
                self.session = Some(h);
                env.requests.push(ShellRequest::SetOutputDir(out));
            }
            Err(e) => self.error = Some(e.to_string()),
        }
    }

    fn send(&mut self, cmd: SessionCommand) {
        if let Some(s) = &mut self.session
            && !s.send(cmd)
        {
            self.error = Some("command not sent (queue full); try again".into());
        }
    }

    /// Draw the page.
    pub fn ui(
        &mut self,
        ui: &mut egui::Ui,
        env: &mut PageEnv<'_>,
        mut engine: Option<&mut EngineHandle>,
    ) {
        if !self.out_seeded {
            self.out_seeded = true;
            if self.out_text.is_empty()
                && let Some(d) = env.output_dir
            {
                self.out_text = d.display().to_string();
            }
        }
        self.poll(engine.as_deref_mut());
        if self.autostart && self.session.is_none() {
            self.load_protocol();
            self.autostart = false;
            let next = match self.folder_status() {
                Some(FolderStatus::Study { next: Some(n), .. }) => Some(n.participant.clone()),
                _ => None,
            };
            let resume = next.is_some();
            self.participant_text = match next {
                Some(n) => n,
                None => self
                    .table
                    .as_ref()
                    .and_then(|t| t.participants.first())
                    .map(|p| p.id.clone())
                    .unwrap_or_default(),
            };
            self.open_session(env, engine.as_deref_mut(), resume, true);
        }
        ui.heading("Study");
        egui::ScrollArea::vertical()
            .id_salt("study-scroll")
            .show(ui, |ui| {
                if self.session.is_none() {
                    self.setup_ui(ui, env, engine.as_deref_mut());
                } else {
                    self.running_ui(ui);
                }
                if self.session.is_some() || self.screen.is_some() {
                    ui.separator();
                    if self.separate_window {
                        // What the participant's window shows, for the
                        // experimenter (not interactive).
                        ui.label(
                            RichText::new("Participant's screen (mirror of their window)").strong(),
                        );
                        let side = ui.available_width().min(300.0);
                        ui.allocate_ui(egui::vec2(side, side), |ui| {
                            self.participant_view(ui, false)
                        });
                    } else {
                        ui.label(RichText::new("Participant view (inline)").strong());
                        let side = ui.available_width().min(420.0);
                        ui.allocate_ui(egui::vec2(side, side), |ui| {
                            self.participant_view(ui, true)
                        });
                    }
                }
                ui.separator();
                self.rows_ui(ui);
            });
        self.flush_hand(engine);
    }

    fn setup_ui(
        &mut self,
        ui: &mut egui::Ui,
        env: &mut PageEnv<'_>,
        mut engine: Option<&mut EngineHandle>,
    ) {
        self.rig_ui(ui, env, engine.as_deref());
        ui.horizontal(|ui| {
            ui.label("Protocol:");
            ui.radio_value(&mut self.source, ProtocolSource::Paper, "paper (built-in)");
            ui.radio_value(&mut self.source, ProtocolSource::Blind, "blind (built-in)");
            ui.radio_value(&mut self.source, ProtocolSource::File, "file");
            if self.source == ProtocolSource::File {
                let r = self.protocol_field.ui(
                    ui,
                    "Protocol file:",
                    &mut self.protocol_file,
                    PathKind::Open(TOML.0, TOML.1),
                    "path/to/protocol.toml",
                    260.0,
                );
                if ui.button("Reload").clicked() || r.picked {
                    self.loaded_source = None;
                }
            }
        });
        self.load_protocol();
        if let Some(e) = &self.protocol_error {
            ui.colored_label(
                Color32::from_rgb(235, 80, 70),
                format!("protocol error: {e}"),
            );
        }
        if let Some(p) = &self.protocol {
            let extra = match p.training.practice_retries {
                0 => String::new(),
                r => format!(" (up to {r} more for unsuccessful ones)"),
            };
            ui.label(format!(
                "{} — {} participants × {} sessions × {} trials, {} practice trials per \
                 condition{extra}; task: {}",
                p.name,
                p.participants,
                p.sessions(),
                p.trials_per_session,
                p.training.practice_trials,
                p.task.kind()
            ));
        }
        ui.horizontal(|ui| {
            let l = ui.label("Participant ID:");
            ui.add(egui::TextEdit::singleline(&mut self.participant_text).hint_text("P01"))
                .labelled_by(l.id);
        });
        let pid = self
            .table
            .as_ref()
            .map(|t| validate_participant_id(&self.participant_text, t));
        match (&pid, &self.table) {
            (Some(Ok(id)), Some(t)) => {
                if let Some(row) = t
                    .participants
                    .iter()
                    .find(|r| r.participant as u32 == id.index)
                {
                    let order: Vec<&str> = row.sessions.iter().map(|c| c.code()).collect();
                    let (practice, extra) = self.protocol.as_ref().map_or((0, 0), |p| {
                        (p.training.practice_trials, p.training.practice_retries)
                    });
                    let extra = match extra {
                        0 => String::new(),
                        r => format!(", up to {r} more for unsuccessful ones"),
                    };
                    ui.label(format!(
                        "{}: order {} (row {} of the square) — training block ({practice} \
                         practice trials per condition{extra}), then sessions {}",
                        id.id,
                        order.join(" > "),
                        row.row + 1,
                        order.join(", ")
                    ));
                    if !t.report.balanced {
                        ui.weak(format!("counterbalancing: {}", t.summary));
                    }
                    if let Some(u) = t.report.repeated.iter().find(|u| u.row == row.row) {
                        ui.weak(format!(
                            "this order is used by {} participants (Williams rows repeat when the \
                             participant count is not a multiple of the rows)",
                            u.count
                        ));
                    }
                }
            }
            (Some(Err(e)), _) if !self.participant_text.trim().is_empty() => {
                ui.colored_label(Color32::from_rgb(235, 80, 70), e);
            }
            _ => {}
        }
        ui.horizontal(|ui| {
            let r = self.out_field.ui(
                ui,
                "Output folder:",
                &mut self.out_text,
                PathKind::Folder,
                "study folder",
                380.0,
            );
            if (r.edit.lost_focus() || r.picked) && !self.out_text.trim().is_empty() {
                env.requests.push(ShellRequest::SetOutputDir(PathBuf::from(
                    self.out_text.trim(),
                )));
            }
        });
        let status = self.folder_status().cloned();
        // What the last sitting showed belongs to its participant and
        // folder: switching either clears it.
        let now = (
            self.participant_text.trim().to_owned(),
            self.out_text.trim().to_owned(),
        );
        if self.shown_for.as_ref().is_some_and(|s| *s != now) {
            self.clear_sitting_state();
        }
        self.shown_for = Some(now);
        // One line, whatever the folder holds (the controls below never move).
        let next = match &status {
            Some(FolderStatus::Study { next, .. }) => next.clone(),
            _ => None,
        };
        match &status {
            Some(FolderStatus::Empty) => {
                ui.weak("new study folder (created when the session opens)");
            }
            Some(FolderStatus::Study {
                protocol,
                completed,
                planned,
                next,
            }) => {
                let tail = match next {
                    Some(n) => format!("next: trial {} ({})", n.key, n.participant),
                    None => "complete".to_owned(),
                };
                ui.label(format!(
                    "this folder holds `{protocol}`: {completed} of {planned} trials done; {tail}"
                ));
            }
            Some(FolderStatus::Unreadable(e)) => {
                ui.colored_label(Color32::from_rgb(235, 80, 70), format!("folder: {e}"));
            }
            None => {
                ui.weak("choose an output folder");
            }
        }
        let live = engine.as_deref().is_some_and(EngineHandle::is_live);
        ui.horizontal(|ui| {
            ui.label("At the handle:");
            if live {
                self.kind = ParticipantKind::Handle;
                ui.radio_value(
                    &mut self.kind,
                    ParticipantKind::Handle,
                    "the participant at the live rig's handle",
                );
            } else {
                if self.kind == ParticipantKind::Handle {
                    self.kind = ParticipantKind::Mouse;
                }
                ui.radio_value(&mut self.kind, ParticipantKind::Mouse, "person (mouse)");
                ui.radio_value(
                    &mut self.kind,
                    ParticipantKind::Simulated,
                    "simulated participant",
                );
            }
            ui.separator();
            let fast_ok = self.kind == ParticipantKind::Simulated;
            if !fast_ok {
                self.speed = Speed::RealTime;
            }
            ui.radio_value(&mut self.speed, Speed::RealTime, "real time");
            ui.add_enabled_ui(fast_ok, |ui| {
                ui.radio_value(&mut self.speed, Speed::Fast, "as fast as possible")
                    .on_disabled_hover_text("for the simulated participant only");
            });
        });
        self.calibration_ui(ui, env);
        ui.horizontal(|ui| {
            ui.checkbox(
                &mut self.separate_window,
                "participant view in a separate window",
            );
            ui.add_enabled_ui(self.separate_window, |ui| {
                let l = ui.label("on");
                egui::ComboBox::from_id_salt("participant-monitor")
                    .selected_text(match self.monitor {
                        Monitor::Same => "this monitor",
                        Monitor::Right => "the monitor to the right",
                        Monitor::Left => "the monitor to the left",
                    })
                    .show_ui(ui, |ui| {
                        ui.selectable_value(&mut self.monitor, Monitor::Same, "this monitor");
                        ui.selectable_value(
                            &mut self.monitor,
                            Monitor::Right,
                            "the monitor to the right",
                        );
                        ui.selectable_value(
                            &mut self.monitor,
                            Monitor::Left,
                            "the monitor to the left",
                        );
                    })
                    .response
                    .labelled_by(l.id);
                ui.checkbox(&mut self.fullscreen, "full screen");
            });
        });
        // The actions, always in this order and place.
        let mut resume = false;
        let mut run_all = false;
        ui.horizontal(|ui| {
            let can = self.protocol.is_some() && matches!(pid, Some(Ok(_)));
            if ui
                .add_enabled(can, egui::Button::new("Open session"))
                .on_hover_text(
                    "open the output folder and wait for Start (the engine runs the sitting's \
                     trials; Explore shows them)",
                )
                .clicked()
            {
                self.open_session(env, engine.as_deref_mut(), false, false);
            }
            let resume_text = match &next {
                Some(n) => format!("Resume at trial {} ({})", n.key, n.participant),
                None => "Resume".to_owned(),
            };
            if ui
                .add_enabled(next.is_some(), egui::Button::new(resume_text))
                .on_hover_text(
                    "reopen the folder at its next pending trial (crash-safe: an interrupted \
                     trial runs again from its seeds)",
                )
                .clicked()
            {
                resume = true;
            }
            let sim = self.kind == ParticipantKind::Simulated;
            let pending = next.is_some() || matches!(status, Some(FolderStatus::Empty));
            if ui
                .add_enabled(
                    sim && pending && self.protocol.is_some(),
                    egui::Button::new("Run all remaining participants"),
                )
                .on_hover_text(
                    "simulated dry run: every pending trial of every participant in one sitting",
                )
                .on_disabled_hover_text("for the simulated participant, with trials pending")
                .clicked()
            {
                run_all = true;
            }
        });
        if resume {
            self.open_session(env, engine.as_deref_mut(), true, false);
        }
        if run_all {
            self.run_all = true;
            let resume = next.is_some();
            if !resume && let Some(first) = self.table.as_ref().and_then(|t| t.participants.first())
            {
                self.participant_text = first.id.clone();
            }
            self.open_session(env, engine.as_deref_mut(), resume, true);
        }
        if let Some(v) = self.size_gate.ui(ui) {
            self.on_verdict(v, env, engine);
        }
        if let Some(last) = &self.size_gate.last {
            ui.label(RichText::new(last).weak());
        }
        if self.screen.is_some() {
            ui.horizontal(|ui| {
                ui.label("The participant's screen shows the end screen.");
                if ui.button("Close participant screen").clicked() {
                    self.screen = None;
                }
            });
        }
        self.messages_ui(ui);
    }

    /// Which rig the sitting runs on: the simulated rig, or the live rig
    /// the Rig page connects (the engine switches rigs).
    fn rig_ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>, engine: Option<&EngineHandle>) {
        ui.horizontal(|ui| {
            let l = ui.label("Rig:");
            let (live, label) = match engine {
                Some(e) if e.is_live() => (
                    true,
                    format!(
                        "{} on {} (loop delay {:.1} ms)",
                        e.identity().name,
                        e.spec().describe(),
                        f64::from(e.loop_delay_samples()) / e.sample_rate_hz() * 1e3
                    ),
                ),
                Some(_) => (false, "the simulated rig".to_owned()),
                None => (false, "none connected".to_owned()),
            };
            ui.label(RichText::new(label).strong()).labelled_by(l.id);
            if live {
                if ui
                    .button("Use the simulated rig")
                    .on_hover_text("disconnect the live rig and run the sitting in simulation")
                    .clicked()
                {
                    env.requests.push(ShellRequest::ConnectRig(
                        kilotouch_rig::device::RigSpec::Sim,
                    ));
                }
            } else if ui
                .button("Use the connected rig…")
                .on_hover_text("choose and connect a live rig on the Rig page")
                .clicked()
            {
                env.requests.push(ShellRequest::ShowRigPage);
            }
        });
    }

    fn messages_ui(&mut self, ui: &mut egui::Ui) {
        if let Some(e) = &self.error {
            ui.colored_label(Color32::from_rgb(235, 80, 70), e.clone());
        }
        if let Some(f) = &self.finished {
            let text = match f {
                FinishReason::StudyDone => {
                    "study complete: every trial has its row; summaries written".to_owned()
                }
                FinishReason::ParticipantDone(id) => format!(
                    "participant {id} finished (session ended paused; the next participant resumes the folder)"
                ),
                FinishReason::Stopped => {
                    "sitting stopped (a trial in progress runs again on resume)".to_owned()
                }
                FinishReason::Failed(m) => format!("session failed: {m}"),
            };
            ui.label(RichText::new(text).strong());
        }
    }

    fn running_ui(&mut self, ui: &mut egui::Ui) {
        let state = self.state.unwrap_or(RunnerState::Idle);
        ui.horizontal(|ui| {
            ui.label(RichText::new(self.heading()).strong().size(16.0));
            ui.separator();
            ui.label(format!(
                "committed {} of {} trials (study)",
                self.committed, self.planned
            ));
        });
        if let Some(r) = &self.rig_used {
            ui.label(format!("rig: {r}"));
        }
        if let Some(r) = &self.recovery_text {
            ui.weak(format!("folder: {r}"));
        }
        if self.run_all {
            ui.weak("running every remaining participant in this sitting (simulated dry run)");
        }
        if self.estop_latched {
            ui.colored_label(
                Color32::from_rgb(235, 80, 70),
                format!(
                    "EMERGENCY STOP: {}; the sitting is paused. Reset the stop (top right) once \
                     the rig is safe, then Resume.",
                    self.estop_what.as_deref().unwrap_or("outputs held at zero")
                ),
            );
        }
        if let Some(sc) = &self.screen {
            let what = match sc.routine {
                Routine::Wait => "please wait".to_owned(),
                Routine::Break { .. } => "break".to_owned(),
                Routine::Instructions { .. } => "instructions".to_owned(),
                Routine::Ready { .. } => "ready screen (waits for the participant)".to_owned(),
                Routine::Starting => "starting".to_owned(),
                Routine::Trial(k) => format!("trial — {}", sc.counter(k).0),
                Routine::Iti => "inter-trial interval".to_owned(),
                Routine::End => "end screen".to_owned(),
            };
            ui.label(format!("participant's screen: {what}"));
        }
        ui.horizontal(|ui| {
            let idle = state == RunnerState::Idle;
            let running = matches!(state, RunnerState::Training(_) | RunnerState::Trial(_));
            let paused = matches!(state, RunnerState::Paused(_));
            if ui.add_enabled(idle, egui::Button::new("Start")).clicked() {
                self.send(SessionCommand::Start);
            }
            if ui
                .add_enabled(running, egui::Button::new("Pause"))
                .clicked()
            {
                self.send(SessionCommand::Pause);
            }
            let latched = self.estop_latched;
            if ui
                .add_enabled(paused && !latched, egui::Button::new("Resume"))
                .on_disabled_hover_text(if latched {
                    "after an emergency stop: reset it first (top right: \"Reset emergency \
                     stop…\", confirm that the rig is safe), then Resume"
                } else {
                    "the sitting is not paused"
                })
                .clicked()
            {
                self.send(SessionCommand::Resume);
            }
            if ui
                .add_enabled(
                    running || matches!(state, RunnerState::Paused(Some(_))),
                    egui::Button::new("Abort trial"),
                )
                .on_hover_text("end the trial now; its row is kept with reject reason `aborted`")
                .clicked()
            {
                self.send(SessionCommand::AbortTrial);
            }
            if ui
                .button("Stop sitting")
                .on_hover_text(
                    "end the sitting; a trial in progress is not recorded and runs again on resume",
                )
                .clicked()
            {
                self.send(SessionCommand::Stop);
            }
        });
        ui.horizontal(|ui| {
            let l = ui.label("Note:");
            ui.add(
                egui::TextEdit::singleline(&mut self.note_text)
                    .hint_text("experimenter note")
                    .desired_width(380.0),
            )
            .labelled_by(l.id);
            if ui.button("Add note").clicked() && !self.note_text.trim().is_empty() {
                let n = std::mem::take(&mut self.note_text);
                self.send(SessionCommand::Note(n));
            }
        });
        if let Some((key, _)) = &self.current {
            ui.label(format!(
                "current: {key} ({} — {})",
                key.condition.code(),
                key.condition.description()
            ));
        }
        if let Some(t) = &self.telemetry {
            let l = t.live;
            let f = |v: Option<f64>, d: usize| {
                v.map(|x| format!("{x:.d$}")).unwrap_or_else(|| "—".into())
            };
            ui.label(format!(
                "time {:.1} s · contact fraction {} · mean handle force {} N (peak {:.3}) · disp. error {} µm",
                l.t_s,
                f(l.contact_fraction, 2),
                f(l.force_mean_n, 3),
                l.force_peak_n,
                f(l.disp_err_mean_um, 2)
            ))
            .on_hover_text(
                "live estimates from the camera frames and the force at the handle (N, what the \
                 participant feels); the row holds the exact time, contact and displacement \
                 error, and the mean optical force on the bead (pN, the paper's force metric)",
            );
        }
        if let Some(t) = &self.timing {
            let text = format!("timing verdict so far: {}", t.describe());
            let hover = "Blocks of the real-time loop that missed their deadline and commands the \
                         device received late, against the rig file's sitting_max_late_fraction; \
                         session.json records the verdict when the sitting ends (docs/STUDY.md, \
                         timing verdict).";
            if t.is_late() {
                ui.colored_label(Color32::from_rgb(230, 140, 40), text)
                    .on_hover_text(hover);
            } else {
                ui.weak(text).on_hover_text(hover);
            }
        }
        let h = self.health;
        ui.weak(format!(
            "session thread: load {:.1} % · deadline misses {} · overruns {} · telemetry dropped {} · simulated {:.1} s",
            100.0 * h.load,
            h.deadline_misses,
            h.overruns,
            h.telemetry_dropped,
            h.simulated_s
        ));
        self.messages_ui(ui);
        egui::CollapsingHeader::new("Event log")
            .id_salt("study-log")
            .show(ui, |ui| {
                for l in self.log.iter().rev().take(30) {
                    ui.monospace(l);
                }
            });
    }

    fn rows_ui(&mut self, ui: &mut egui::Ui) {
        ui.label(RichText::new(format!("Finished trials: {}", self.rows.len())).strong());
        egui::Grid::new("study-rows").striped(true).show(ui, |ui| {
            for h in [
                "participant",
                "phase",
                "cond.",
                "trial",
                "success",
                "reject",
                "time s",
                "contact",
                "bead force pN",
                "disp. µm",
            ] {
                ui.label(RichText::new(h).strong());
            }
            ui.end_row();
            let f = |v: Option<f64>, d: usize| v.map(|x| format!("{x:.d$}")).unwrap_or_default();
            for r in self.rows.iter().rev().take(200) {
                ui.label(&r.participant);
                ui.label(r.phase.to_string());
                ui.label(r.condition.code());
                ui.label(r.trial.to_string());
                ui.label(if r.success { "yes" } else { "no" });
                ui.label(&r.reject_reason);
                ui.label(f(r.time_s, 2));
                ui.label(f(r.contact_fraction, 2));
                ui.label(f(r.force_mean_pn, 2));
                ui.label(f(r.disp_err_mean_um, 2));
                ui.end_row();
            }
        });
    }

    /// The participant's view: the scene as the camera shows it (vision
    /// conditions) or a dark screen (blind task); dragging moves the hand.
    fn participant_view(&mut self, ui: &mut egui::Ui, interactive: bool) {
        let rect = ui.available_rect_before_wrap();
        let sense = if interactive {
            Sense::drag()
        } else {
            Sense::hover()
        };
        let sense = if self.screen.is_some() {
            sense.union(Sense::click())
        } else {
            sense
        };
        let resp = ui.allocate_rect(rect, sense);
        resp.widget_info(|| {
            let label = if interactive {
                "participant screen"
            } else {
                "participant screen (mirror)"
            };
            egui::WidgetInfo::labeled(egui::Role::Button, true, label)
        });
        let painter = ui.painter_at(rect);
        painter.rect_filled(rect, 0.0, Color32::from_gray(8));
        // The emergency stop key works in the participant's window too
        // (it has the keyboard during a trial); the shell stops.
        if interactive && ui.input_mut(|i| i.consume_key(egui::Modifiers::NONE, egui::Key::Escape))
        {
            self.estop_request = true;
        }
        if let Some(sc) = &self.screen {
            // The participant's routines: text screens advance on Space,
            // Enter or a click (keys only while no text field has focus).
            let key = interactive
                && ui.memory(|m| m.focused().is_none())
                && ui.input(|i| i.key_pressed(egui::Key::Space) || i.key_pressed(egui::Key::Enter));
            let text_shown = sc.paint_text(ui, rect);
            let in_trial = matches!(sc.routine, Routine::Trial(_));
            if text_shown && interactive && (key || resp.clicked()) {
                self.participant_input();
            }
            if !in_trial {
                // Text screens, the inter-trial interval and the start of a
                // trial (blank): no scene.
                return;
            }
        }
        let Some((_, scene)) = self.current else {
            painter.text(
                rect.center(),
                egui::Align2::CENTER_CENTER,
                "please wait",
                egui::FontId::proportional(18.0),
                Color32::from_gray(90),
            );
            return;
        };
        let g = scene.geometry;
        let half_um = (3.0 * (g.obstacle_radius_m + g.bead_radius_m) * 1e6).max(10.0);
        let view = View::fit(
            rect,
            [g.obstacle_m[0] * 1e6, g.obstacle_m[1] * 1e6],
            half_um,
        );
        if resp.dragged() {
            let d = resp.drag_delta();
            let k = view.um_per_pt * 1e-6;
            self.trap_target_m[0] += f64::from(d.x) * k;
            self.trap_target_m[1] -= f64::from(d.y) * k;
            self.pending_hand = Some(self.mapping.to_hand(self.trap_target_m));
        }
        let frame = self.telemetry.and_then(|t| t.frame);
        if let Some(f) = frame {
            let sf = SceneFrame {
                view,
                bead_m: f.bead_m,
                bead_radius_m: f.bead_radius_m,
                trap_m: f.trap_m,
                obstacles: vec![Obstacle {
                    centre_m: f.obstacle_m,
                    radius_m: f.obstacle_radius_m,
                }],
                blur_um: 0.3,
                noise: 0.05,
                frame: f.seq,
                estop: false,
            };
            if self.gpu {
                painter.add(SceneCallback::paint_callback(&sf));
            } else {
                scene::paint_fallback(&painter, &sf);
            }
        }
        // Blind task (or before the first frame): the screen stays dark.
        if let Some(sc) = &self.screen {
            sc.counter_ui(ui, rect);
        }
    }
}
