//! Rig page: which rig (simulated, serial DAQ, audio interface — the
//! `--rig` syntax of [`RigSpec`]), which rig file, connect/disconnect,
//! reconnect after a device fault, identity, status and counters, and the
//! closed loop's stability margins with the chain the engine runs, and the
//! tweezer's trap calibration ([`super::rig_tweezer`]).

mod view;

pub use view::margins_ui;
use view::{error_ui, run_controls_ui, status_ui};

use super::rig_tweezer::{TweezerSection, spec_or_sim};
use crate::engine::EngineHandle;
use crate::gui::env::{PageEnv, ShellRequest};
use crate::gui::path_field::{PathField, PathKind, TOML, labelled_line};
use egui::{Color32, RichText};
use kilotouch_rig::device::{RigSpec, TweezerSpec};

/// Hint shown under the rig field.
pub const RIG_HINT: &str = "sim  ·  serial:/dev/ttyACM0[,baud=N][,timeout-ms=N]  ·  audio[:DEVICE]  \
     (a device emulator: `kilotouch emulate daq --pty` prints its port)";

/// The Rig page.
#[derive(Debug)]
pub struct RigPage {
    /// Text of the rig field (`sim`, `serial:PATH…`, `audio[:DEVICE]`).
    pub rig_text: String,
    /// Text of the tweezer field (`sim`, `serial:PATH…`).
    pub tweezer_text: String,
    /// Text of the rig-file field.
    pub path_text: String,
    /// The Tweezer section (trap calibration).
    pub tweezer: TweezerSection,
    rig_file_field: PathField,
    /// The Lab Streaming Layer outlets of the connected engine, while on.
    #[cfg(feature = "lsl")]
    lsl: Option<crate::lsl::LslPublisher>,
    /// Why the outlets could not start.
    #[cfg(feature = "lsl")]
    lsl_error: Option<String>,
}

impl Default for RigPage {
    fn default() -> Self {
        Self::new()
    }
}

impl RigPage {
    /// New page.
    pub fn new() -> Self {
        Self {
            rig_text: "sim".to_owned(),
            tweezer_text: "sim".to_owned(),
            path_text: String::new(),
            tweezer: TweezerSection::new(),
            rig_file_field: PathField::default(),
            #[cfg(feature = "lsl")]
            lsl: None,
            #[cfg(feature = "lsl")]
            lsl_error: None,
        }
    }

    /// The rig the rig field names (empty = `sim`).
    pub fn spec(&self) -> Result<RigSpec, kilotouch_rig::RigError> {
        spec_or_sim(&self.rig_text, RigSpec::Sim)
    }

    /// The tweezer the tweezer field names (empty = `sim`).
    pub fn tweezer_spec(&self) -> Result<TweezerSpec, kilotouch_rig::RigError> {
        spec_or_sim(&self.tweezer_text, TweezerSpec::Sim)
    }

    /// The tweezer row of the Device group: simulated or live, the field,
    /// and what the running engine has.
    fn tweezer_row(
        &mut self,
        ui: &mut egui::Ui,
        engine: Option<&EngineHandle>,
        requests: &mut Vec<ShellRequest>,
    ) {
        let spec = self.tweezer_spec();
        ui.horizontal(|ui| {
            for (label, text) in [
                ("Simulated tweezer", "sim"),
                ("Serial tweezer", "serial:/dev/ttyACM1"),
            ] {
                let on = matches!(
                    (&spec, text),
                    (Ok(TweezerSpec::Sim), "sim")
                        | (Ok(TweezerSpec::Serial(_)), "serial:/dev/ttyACM1")
                );
                if ui.add(egui::Button::selectable(on, label)).clicked() && !on {
                    self.tweezer_text = text.to_owned();
                }
            }
        });
        ui.horizontal(|ui| {
            if spec_field(ui, "Tweezer:", &mut self.tweezer_text) && self.tweezer_spec().is_ok() {
                requests.push(ShellRequest::Connect);
            }
        });
        match spec {
            Err(e) => {
                ui.colored_label(Color32::from_rgb(230, 70, 60), e.to_string());
            }
            Ok(TweezerSpec::Sim) => {
                ui.weak("Simulated tweezer: the rig file's bead, trap and obstacles.");
            }
            Ok(TweezerSpec::Serial(_)) => {
                ui.label(
                    "Live tweezer: trap set-points and bead samples are exchanged in blocks at \
                     the rig's rate; its command lead adds to the loop delay the stability \
                     check is made with. An applied trap calibration sets the κ and the \
                     detector sensitivity the optical force is computed with. Connect to use it.",
                );
            }
        }
        if let Some(t) = engine.and_then(|e| e.live_tweezer()) {
            ui.label(format!(
                "Connected tweezer: {} (firmware {}), command lead {} samples{}",
                t.name,
                t.firmware,
                t.lead_samples,
                t.round_trip_s
                    .map(|r| format!(", round trip {:.2} ms", r * 1e3))
                    .unwrap_or_default()
            ));
        }
    }

    /// The Lab Streaming Layer publisher while streaming is on (the shell
    /// hands its markers to the Study page's sittings).
    #[cfg(feature = "lsl")]
    pub fn lsl(&self) -> Option<&crate::lsl::LslPublisher> {
        self.lsl.as_ref()
    }

    /// Is an audio-interface rig available in this build?
    pub fn audio_built() -> bool {
        cfg!(feature = "audio")
    }

    /// Draw the page with the engine taken out of `env` (so that `env`
    /// stays free for the sections); what the user asks of the shell goes
    /// to `env.requests`.
    fn draw(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>, engine: Option<&EngineHandle>) {
        let mut requests = Vec::new();
        egui::ScrollArea::vertical().show(ui, |ui| {
            ui.heading("Rig");
            self.device_ui(ui, engine, &mut requests);
            ui.add_space(6.0);
            self.rig_file_ui(ui, env, &mut requests);
            ui.add_space(6.0);
            self.tweezer.engine_tweezer = engine
                .and_then(|e| e.live_tweezer())
                .map(|t| t.spec.describe());
            self.tweezer.ui(ui, env, engine.is_some());
            ui.add_space(6.0);
            run_controls_ui(ui, engine, &mut requests);
            ui.add_space(6.0);
            #[cfg(feature = "lsl")]
            self.lsl_ui(ui, engine);
            if let Some(h) = engine {
                error_ui(ui, h);
                status_ui(ui, env, h);
            }
        });
        env.requests.extend(requests);
    }

    /// The Lab Streaming Layer switch: on, the connected engine's samples
    /// and events go to the `kilotouch-markers` and `kilotouch-signals`
    /// outlets (docs/LSL.md); the stream names and whether a consumer
    /// (LabRecorder) is connected. Off when the engine disconnects.
    #[cfg(feature = "lsl")]
    fn lsl_ui(&mut self, ui: &mut egui::Ui, engine: Option<&EngineHandle>) {
        use crate::lsl::{LslIdentity, MARKER_STREAM, SIGNAL_STREAM};
        let Some(h) = engine else {
            self.lsl = None;
            return;
        };
        ui.group(|ui| {
            let mut on = self.lsl.is_some();
            if ui
                .checkbox(&mut on, "Stream to Lab Streaming Layer (1 kHz)")
                .on_hover_text("markers and haptic signals for LabRecorder (docs/LSL.md)")
                .changed()
            {
                if on {
                    let id = LslIdentity {
                        study: "explore".to_owned(),
                        participant: String::new(),
                        id_width: 2,
                    };
                    match h.start_lsl(1000.0, id) {
                        Ok(p) => {
                            self.lsl = Some(p);
                            self.lsl_error = None;
                        }
                        Err(e) => self.lsl_error = Some(e.to_string()),
                    }
                } else if let Some(p) = self.lsl.take() {
                    p.stop();
                }
            }
            if let Some(p) = &self.lsl {
                let (m, s) = p.consumers();
                let state = |c: bool| {
                    if c {
                        "consumer connected"
                    } else {
                        "no consumer"
                    }
                };
                ui.label(format!("{MARKER_STREAM}: {}", state(m)));
                ui.label(format!(
                    "{SIGNAL_STREAM} ({} Hz): {}",
                    p.signal_rate_hz,
                    state(s)
                ));
                if p.dropped() > 0 {
                    ui.colored_label(
                        Color32::from_rgb(200, 120, 0),
                        format!("{} records dropped", p.dropped()),
                    );
                }
                ui.ctx()
                    .request_repaint_after(std::time::Duration::from_millis(500));
            }
            if let Some(e) = &self.lsl_error {
                ui.colored_label(Color32::from_rgb(200, 0, 0), e);
            }
        });
    }

    /// The device: kind, rig text, Connect, what the rig is, the tweezer row.
    fn device_ui(
        &mut self,
        ui: &mut egui::Ui,
        engine: Option<&EngineHandle>,
        requests: &mut Vec<ShellRequest>,
    ) {
        let spec = self.spec();
        ui.group(|ui| {
            ui.label(RichText::new("Device").strong());
            ui.horizontal(|ui| {
                for (label, text) in [
                    ("Simulated", "sim"),
                    ("Serial DAQ", "serial:/dev/ttyACM0"),
                    ("Audio interface", "audio"),
                ] {
                    let on = matches!(
                        (&spec, text),
                        (Ok(RigSpec::Sim), "sim")
                            | (Ok(RigSpec::Serial(_)), "serial:/dev/ttyACM0")
                            | (Ok(RigSpec::Audio(_)), "audio")
                    );
                    let enabled = text != "audio" || Self::audio_built();
                    let b = ui.add_enabled(enabled, egui::Button::selectable(on, label));
                    let b = b.on_disabled_hover_text(
                        "not in this build (cargo feature `audio`, needs libasound2-dev)",
                    );
                    if b.clicked() && !on {
                        self.rig_text = text.to_owned();
                    }
                }
            });
            ui.horizontal(|ui| {
                let enter = spec_field(ui, "Rig:", &mut self.rig_text);
                let ok = self.spec().is_ok();
                let label = if engine.is_some() {
                    "Connect (restart)"
                } else {
                    "Connect"
                };
                if ui
                    .add_enabled(
                        ok,
                        egui::Button::new(RichText::new(label).strong())
                            .min_size(egui::vec2(110.0, 24.0)),
                    )
                    .clicked()
                    || (enter && ok)
                {
                    requests.push(ShellRequest::Connect);
                }
            });
            ui.weak(RIG_HINT);
            match self.spec() {
                Err(e) => {
                    ui.colored_label(Color32::from_rgb(230, 70, 60), e.to_string());
                }
                Ok(RigSpec::Sim) => {
                    ui.weak("Simulated rig: the hand follows the mouse on the Explore page.");
                }
                Ok(_) => {
                    ui.label(
                        "Live rig: the hand is the real handle (encoders); mouse input on the \
                         Explore page is ignored. The engine exchanges blocks of frames with \
                         the device (loop delay one block, 1 ms by default).",
                    );
                }
            }
            ui.add_space(4.0);
            self.tweezer_row(ui, engine, requests);
        });
    }

    /// The rig file: load one, or the built-in default; the one in use.
    fn rig_file_ui(
        &mut self,
        ui: &mut egui::Ui,
        env: &PageEnv<'_>,
        requests: &mut Vec<ShellRequest>,
    ) {
        ui.group(|ui| {
            ui.label(RichText::new("Rig file").strong());
            ui.horizontal(|ui| {
                let r = self.rig_file_field.ui(
                    ui,
                    "Rig file:",
                    &mut self.path_text,
                    PathKind::Open(TOML.0, TOML.1),
                    "built-in default (assets/rigs/default.toml)",
                    420.0,
                );
                if ui.button("Load").clicked() || r.submitted || r.picked {
                    if self.path_text.trim().is_empty() {
                        requests.push(ShellRequest::UseDefaultRig);
                    } else {
                        requests.push(ShellRequest::LoadRigFile(self.path_text.trim().to_owned()));
                    }
                }
                if ui.button("Use built-in default").clicked() {
                    self.path_text.clear();
                    requests.push(ShellRequest::UseDefaultRig);
                }
            });
            match env.rig_config_path {
                Some(p) => ui.label(format!("In use: {}", p.display())),
                None => ui.label("In use: built-in default"),
            };
            if let Some(e) = env.config_error {
                ui.colored_label(Color32::from_rgb(230, 70, 60), e.to_owned());
            }
        });
    }
}

/// A one-line `--rig`/`--tweezer` spec field after `label` (hint `sim`,
/// 360 points wide); true when the user pressed Enter in it.
fn spec_field(ui: &mut egui::Ui, label: &str, text: &mut String) -> bool {
    let edit = labelled_line(ui, label, text, "sim", 360.0);
    edit.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter))
}

impl super::Page for RigPage {
    fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        let engine = env.engine.take();
        self.draw(ui, env, engine.as_deref());
        env.engine = engine;
    }
}
