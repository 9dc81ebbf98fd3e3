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

use egui::Color32;
use kilotouch_study::export::TrialRow;
use kilotouch_study::protocol::{AssignmentTable, Protocol};
use kilotouch_study::runner::RunnerState;
use kilotouch_study::seeds::TrialKey;
use kilotouch_study::task::station::HandMapping;

use crate::engine::EngineHandle;
use crate::gui::env::{PageEnv, ShellRequest};
use crate::gui::pages::Page;
use crate::gui::pages::study_size::SizeGate;
use crate::gui::participant_screen::ParticipantScreen;
use crate::gui::path_field::PathField;
pub use form::{CalibrationChoice, ProtocolSource, StudyForm};
pub use model::{LOG_CAPACITY, ScreenNote, SittingModel};

use crate::session::{
    FinishReason, FolderStatus, ParticipantId, ParticipantKind, SessionCommand, SessionHandle,
    Speed, inspect_folder,
};

mod form;
mod model;
mod open;
mod running;
mod setup;

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
    /// What the experimenter typed and chose (validated when a sitting opens).
    pub form: StudyForm,
    /// Participant view in a separate window (else inline on this page;
    /// inline is what the UI tests use).
    pub separate_window: bool,
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
    /// What the sitting's events changed (egui-free).
    model: SittingModel,
    note_text: String,
    /// The rig of the sitting (`sim`, `serial:PATH`), its loop delay.
    rig_used: Option<String>,
    /// What the last emergency stop did to the sitting.
    estop_what: Option<String>,
    /// Where the participant's window opened (screen points).
    participant_at: Option<[f32; 2]>,
    /// The size check before a sitting opens.
    pub size_gate: SizeGate,
    protocol_field: PathField,
    out_field: PathField,
    calibration_field: PathField,
    /// The Rig page's marker outlet while it streams to Lab Streaming
    /// Layer (the shell sets it every frame).
    #[cfg(feature = "lsl")]
    lsl: Option<crate::lsl::LslMarkers>,
    /// The open sitting on the marker stream (it opened while streaming
    /// was on).
    #[cfg(feature = "lsl")]
    lsl_sitting: Option<crate::lsl::LslSitting>,
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
            form: StudyForm::default(),
            separate_window: true,
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
            model: SittingModel::default(),
            note_text: String::new(),
            rig_used: None,
            estop_what: None,
            participant_at: None,
            size_gate: SizeGate::default(),
            protocol_field: PathField::default(),
            out_field: PathField::default(),
            calibration_field: PathField::default(),
            #[cfg(feature = "lsl")]
            lsl: None,
            #[cfg(feature = "lsl")]
            lsl_sitting: None,
        }
    }

    /// The marker outlet a sitting opened from now on sends its sitting
    /// start and end and its notes to (`None`: not streaming).
    #[cfg(feature = "lsl")]
    pub fn set_lsl(&mut self, markers: Option<crate::lsl::LslMarkers>) {
        self.lsl = markers;
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
        self.model.trial_started()
    }

    /// Trials in the study's plan as the sitting last reported it (it grows
    /// when an unsuccessful practice trial earns an extra one).
    pub fn planned(&self) -> usize {
        self.model.planned()
    }

    /// Rows shown in the table (this participant's, from `trials.csv` and
    /// the rows committed in this sitting).
    pub fn rows(&self) -> &[TrialRow] {
        self.model.rows()
    }

    /// The runner state last reported.
    pub fn runner_state(&self) -> Option<RunnerState> {
        self.model.runner_state()
    }

    /// How the last sitting ended.
    pub fn finished(&self) -> Option<&FinishReason> {
        self.model.finished()
    }

    /// The last error shown.
    pub fn error(&self) -> Option<&str> {
        self.model.error()
    }

    /// The sitting's model (what its events changed).
    pub fn model(&self) -> &SittingModel {
        &self.model
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
        let what = self.model.estop_effect();
        self.estop_what = Some(what.clone());
        Some(what)
    }

    /// On the first draw, open a sitting of the folder's next pending
    /// participant (or P01 of a new folder) with the simulated participant
    /// in real time, participant view inline, and start it.
    pub fn simulate_sitting(&mut self) {
        self.form.kind = ParticipantKind::Simulated;
        self.form.speed = Speed::RealTime;
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
        let state = self.model.state_or_idle();
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
        self.model.clear();
        self.screen = None;
    }

    /// Drains the session's events and shows the participant window (when
    /// separate): the page's [`Page::background`], with the engine taken
    /// out of the shell's `PageEnv`.
    fn drain_and_show(
        &mut self,
        ctx: &egui::Context,
        mut engine: Option<&mut EngineHandle>,
        requests: &mut Vec<ShellRequest>,
    ) {
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
                    .show(ui, |ui| self.participant_view(ui, true, requests));
            });
        } else {
            self.participant_at = None;
        }
        self.flush_hand(engine);
    }

    /// The participant's hand (mouse) to the engine.
    fn flush_hand(&mut self, engine: Option<&mut EngineHandle>) {
        if let (Some(h), Some(e)) = (self.model.pending_hand(), engine)
            && e.set_hand(h)
        {
            self.model.hand_sent();
        }
    }

    /// Drains the session's events into the model and tells the
    /// participant's screen; a finished sitting gives the engine back.
    fn poll(&mut self, engine: Option<&mut EngineHandle>) {
        let Some(s) = &mut self.session else {
            return;
        };
        let events = s.poll();
        if let Some(e) = engine.as_deref() {
            self.model.set_health(s.health(e));
        }
        self.model.set_timing(s.timing());
        let mut ended = false;
        for e in events {
            #[cfg(feature = "lsl")]
            if let (Some(l), crate::session::SessionEvent::Noted(n)) = (&self.lsl_sitting, &e) {
                l.note(n);
            }
            if let Some(note) = self.model.apply(e, &self.mapping) {
                ended |= self.tell_screen(note);
            }
        }
        if ended {
            #[cfg(feature = "lsl")]
            if let Some(l) = self.lsl_sitting.take()
                && let Err(e) = l.end()
            {
                self.model
                    .set_error(format!("{}: {e}", crate::lsl::CLOCK_FILE));
            }
            // The engine goes back to free exploration (its driver, pacing
            // and chain as before the sitting).
            if let Some(s) = self.session.take() {
                match engine {
                    Some(e) => drop(s.close(e)),
                    None => drop(s),
                }
            }
            self.folder = None;
            self.run_all = false;
        }
    }

    /// Tells the participant's screen what an event changed; `true` when
    /// the sitting ended.
    fn tell_screen(&mut self, note: ScreenNote) -> bool {
        match (note, &mut self.screen) {
            (ScreenNote::State(st), Some(sc)) => sc.on_state(st),
            (ScreenNote::TrialEnded(k), Some(sc)) => sc.on_trial_ended(k),
            (ScreenNote::State(_) | ScreenNote::TrialEnded(_), None) => {}
            // The end screen stays (participant done, study done); a
            // stopped or failed sitting closes the participant's window.
            (ScreenNote::Finished { keep_end_screen }, screen) => {
                match screen {
                    Some(sc) if keep_end_screen => sc.on_finished(),
                    _ => *screen = None,
                }
                return true;
            }
        }
        false
    }

    fn load_protocol(&mut self) {
        let key = (self.form.source, self.form.protocol_file.trim().to_owned());
        if self.loaded_source.as_ref() == Some(&key) {
            return;
        }
        self.loaded_source = Some(key.clone());
        let r = match self.form.source {
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
        let t = self.form.out_text.trim();
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
}

impl Page for StudyPage {
    fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        let mut engine = env.engine.take();
        self.draw(ui, env, engine.as_deref_mut());
        env.engine = engine;
    }

    fn background(&mut self, ctx: &egui::Context, env: &mut PageEnv<'_>) {
        let mut engine = env.engine.take();
        self.drain_and_show(ctx, engine.as_deref_mut(), env.requests);
        env.engine = engine;
    }
}
