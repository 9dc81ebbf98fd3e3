//! The Study page while a sitting is open: state, trial controls, live
//! metrics, finished rows and the participant's view.

use egui::{Color32, RichText, Sense};
use kilotouch_rig::tweezer::Obstacle;
use kilotouch_study::runner::RunnerState;

use crate::gui::env::ShellRequest;
use crate::gui::participant_screen::Routine;
use crate::gui::scene::{self, SceneFrame, View};
use crate::gui::scene_wgpu::SceneCallback;
use crate::session::SessionCommand;

use super::StudyPage;

impl StudyPage {
    pub(super) fn running_ui(&mut self, ui: &mut egui::Ui) {
        let state = self.model.state_or_idle();
        self.status_ui(ui);
        self.controls_ui(ui, state);
        self.live_ui(ui);
        self.messages_ui(ui);
        egui::CollapsingHeader::new("Event log")
            .id_salt("study-log")
            .show(ui, |ui| {
                for l in self.model.log().iter().rev().take(30) {
                    ui.monospace(l);
                }
            });
    }

    /// What the sitting is doing: heading, rig, folder, stop, participant's screen.
    fn status_ui(&self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            ui.label(RichText::new(self.heading()).strong().size(16.0));
            ui.separator();
            ui.label(self.model.progress_text());
        });
        if let Some(r) = &self.rig_used {
            ui.label(format!("rig: {r}"));
        }
        if let Some(r) = self.model.recovery_text() {
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
    }

    /// The trial controls and the experimenter's note.
    fn controls_ui(&mut self, ui: &mut egui::Ui, state: RunnerState) {
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
    }

    /// The current trial, live metrics, timing verdict and session thread health.
    fn live_ui(&self, ui: &mut egui::Ui) {
        if let Some(t) = self.model.current_text() {
            ui.label(t);
        }
        if let Some(t) = self.model.live_text() {
            ui.label(t).on_hover_text(
                "live estimates from the camera frames and the force at the handle (N, what the \
                 participant feels); the row holds the exact time, contact and displacement \
                 error, and the mean optical force on the bead (pN, the paper's force metric)",
            );
        }
        if let Some(t) = self.model.timing() {
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
        ui.weak(self.model.health_text());
    }

    pub(super) fn rows_ui(&mut self, ui: &mut egui::Ui) {
        ui.label(RichText::new(format!("Finished trials: {}", self.model.rows().len())).strong());
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
            for r in self.model.rows().iter().rev().take(200) {
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
    pub(super) fn participant_view(
        &mut self,
        ui: &mut egui::Ui,
        interactive: bool,
        requests: &mut Vec<ShellRequest>,
    ) {
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
            requests.push(ShellRequest::EmergencyStop);
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
        let Some((_, scene)) = self.model.current() else {
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
            self.model
                .drag_trap([f64::from(d.x) * k, -f64::from(d.y) * k], &self.mapping);
        }
        let frame = self.model.telemetry().and_then(|t| t.frame);
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
