//! Rig page: which rig, which rig file, connect/disconnect, identity,
//! status and counters.

use crate::engine::{EngineHandle, SafetyState};
use crate::gui::env::PageEnv;
use egui::{Color32, RichText};

/// What the user asked the shell to do.
#[derive(Debug, Clone, PartialEq)]
pub enum RigAction {
    /// Parse this rig file and (re)connect with it.
    LoadConfig(String),
    /// Go back to the built-in default rig.
    UseDefault,
    /// Start the engine (simulated rig).
    Connect,
    /// Stop the engine thread.
    Disconnect,
    /// Resume exchanging frames.
    Start,
    /// Pause exchanging frames (outputs zero).
    Stop,
}

/// Kind of rig offered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Simulated,
    SerialDaq,
    Audio,
}

/// The Rig page.
#[derive(Debug)]
pub struct RigPage {
    kind: Kind,
    /// Text of the rig-file field.
    pub path_text: String,
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
            kind: Kind::Simulated,
            path_text: String::new(),
        }
    }

    /// Draw the page; returns the actions requested.
    pub fn ui(
        &mut self,
        ui: &mut egui::Ui,
        env: &mut PageEnv<'_>,
        engine: Option<&EngineHandle>,
        config_error: Option<&str>,
    ) -> Vec<RigAction> {
        let mut actions = Vec::new();
        egui::ScrollArea::vertical().show(ui, |ui| {
            ui.heading("Rig");
            ui.horizontal(|ui| {
                ui.selectable_value(&mut self.kind, Kind::Simulated, "Simulated rig");
                for (k, name) in [
                    (Kind::SerialDaq, "Serial DAQ"),
                    (Kind::Audio, "Audio interface"),
                ] {
                    ui.add_enabled(false, egui::Button::selectable(self.kind == k, name))
                        .on_disabled_hover_text("not in this build");
                }
                ui.weak("(live rigs: not in this build)");
            });
            ui.add_space(6.0);
            ui.group(|ui| {
                ui.label(RichText::new("Rig file").strong());
                ui.horizontal(|ui| {
                    let edit = ui.add(
                        egui::TextEdit::singleline(&mut self.path_text)
                            .hint_text("built-in default (assets/rigs/default.toml)")
                            .desired_width(420.0),
                    );
                    let enter = edit.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
                    if ui.button("Load").clicked() || enter {
                        if self.path_text.trim().is_empty() {
                            actions.push(RigAction::UseDefault);
                        } else {
                            actions.push(RigAction::LoadConfig(self.path_text.trim().to_owned()));
                        }
                    }
                    if ui.button("Use built-in default").clicked() {
                        self.path_text.clear();
                        actions.push(RigAction::UseDefault);
                    }
                });
                match env.rig_config_path {
                    Some(p) => ui.label(format!("In use: {}", p.display())),
                    None => ui.label("In use: built-in default"),
                };
                if let Some(e) = config_error {
                    ui.colored_label(Color32::from_rgb(230, 70, 60), e.to_owned());
                }
            });
            ui.add_space(6.0);
            ui.horizontal(|ui| match engine {
                None => {
                    if ui
                        .add(
                            egui::Button::new(RichText::new("Connect").strong())
                                .min_size(egui::vec2(110.0, 28.0)),
                        )
                        .clicked()
                    {
                        actions.push(RigAction::Connect);
                    }
                    ui.label("Disconnected.");
                }
                Some(h) => {
                    if ui
                        .add(egui::Button::new("Disconnect").min_size(egui::vec2(110.0, 28.0)))
                        .clicked()
                    {
                        actions.push(RigAction::Disconnect);
                    }
                    let running = h.health().is_none_or(|x| x.running);
                    if running {
                        if ui.button("Pause").clicked() {
                            actions.push(RigAction::Stop);
                        }
                    } else if ui.button("Resume").clicked() {
                        actions.push(RigAction::Start);
                    }
                }
            });
            ui.add_space(6.0);
            let Some(h) = engine else {
                return;
            };
            ui.columns(2, |cols| {
                cols[0].group(|ui| {
                    ui.label(RichText::new("Identity").strong());
                    let id = h.identity();
                    egui::Grid::new("rig-identity")
                        .striped(true)
                        .show(ui, |ui| {
                            let rows = [
                                ("name", id.name.clone()),
                                ("kind", format!("{:?}", id.kind)),
                                ("serial", id.serial.clone()),
                                ("firmware", id.firmware.clone()),
                                ("sample rate", format!("{:.0} Hz", id.sample_rate_hz)),
                                ("Pantograph force limit", format!("±{} N", id.force_max_n)),
                                (
                                    "Haptuator drive limit",
                                    format!("±{} V", id.haptuator_max_v),
                                ),
                                (
                                    "accelerometer range",
                                    format!("±{:.1} m/s²", id.accel_range_m_s2),
                                ),
                            ];
                            for (k, v) in rows {
                                ui.label(k);
                                ui.label(v);
                                ui.end_row();
                            }
                        });
                });
                cols[1].group(|ui| {
                    ui.label(RichText::new("Status").strong());
                    match h.health() {
                        None => {
                            ui.label("waiting for the engine…");
                        }
                        Some(x) => {
                            let col = match x.safety {
                                SafetyState::EmergencyStop | SafetyState::Fault => Color32::RED,
                                SafetyState::Armed => Color32::from_rgb(60, 200, 90),
                                _ => ui.visuals().text_color(),
                            };
                            ui.colored_label(col, format!("safety: {}", x.safety.label()));
                            egui::Grid::new("rig-status").striped(true).show(ui, |ui| {
                                let r = &x.rig;
                                let rows = [
                                    ("state", format!("{:?}", r.state)),
                                    ("loop rate", format!("{:.0} Hz", x.loop_rate_hz)),
                                    ("load", format!("{:.2} %", 100.0 * x.load)),
                                    ("deadline misses", x.deadline_misses.to_string()),
                                    (
                                        "worst lateness (window)",
                                        format!("{:.2} ms", 1e3 * x.worst_lateness_s),
                                    ),
                                    ("stalls (re-anchored)", x.overruns.to_string()),
                                    ("frames", r.frames.to_string()),
                                    ("lost frames", r.lost_frames.to_string()),
                                    ("accelerometer clipped", r.clipped_frames.to_string()),
                                    ("commands limited", r.limited_frames.to_string()),
                                    ("Haptuator end stop", r.end_stop_frames.to_string()),
                                    ("non-finite commands", r.nonfinite_commands.to_string()),
                                    ("coupling clamps", x.coupling.clamped.to_string()),
                                    (
                                        "trap at workspace edge",
                                        x.coupling.workspace_clamped.to_string(),
                                    ),
                                    ("telemetry dropped", x.telemetry_dropped.to_string()),
                                    ("frames zeroed by e-stop", x.estop_zeroed_frames.to_string()),
                                ];
                                for (k, v) in rows {
                                    ui.label(k);
                                    ui.label(v);
                                    ui.end_row();
                                }
                            });
                            let chain = match h.last_swap() {
                                None => "as designed from the rig model (no calibration loaded)"
                                    .to_owned(),
                                Some(o) => format!("calibration loaded ({o:?})"),
                            };
                            ui.label(format!("D-mode chain: {chain}"));
                        }
                    }
                });
            });
        });
        actions
    }
}
