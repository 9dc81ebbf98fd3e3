//! The Study page before a sitting opens: protocol, participant, output
//! folder, who is at the handle, D's chain, the participant's window and
//! the actions.

use std::path::PathBuf;

use egui::{Color32, RichText};
use kilotouch_rig::units::{to_pn_per_um, to_um_per_v};

use crate::engine::EngineHandle;
use crate::gui::env::{PageEnv, ShellRequest};
use crate::gui::path_field::{PathKind, TOML};
use crate::session::{FolderStatus, ParticipantKind, Speed, validate_participant_id};

use super::{CalibrationChoice, Monitor, ProtocolSource, StudyPage};

impl StudyPage {
    /// Draw the page with the engine taken out of `env`.
    pub(super) fn draw(
        &mut self,
        ui: &mut egui::Ui,
        env: &mut PageEnv<'_>,
        mut engine: Option<&mut EngineHandle>,
    ) {
        if !self.out_seeded {
            self.out_seeded = true;
            if self.form.out_text.is_empty()
                && let Some(d) = env.output_dir
            {
                self.form.out_text = d.display().to_string();
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
            self.form.participant_text = match next {
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
                            self.participant_view(ui, false, env.requests)
                        });
                    } else {
                        ui.label(RichText::new("Participant view (inline)").strong());
                        let side = ui.available_width().min(420.0);
                        ui.allocate_ui(egui::vec2(side, side), |ui| {
                            self.participant_view(ui, true, env.requests)
                        });
                    }
                }
                ui.separator();
                self.rows_ui(ui);
            });
        self.flush_hand(engine);
    }

    pub(super) fn setup_ui(
        &mut self,
        ui: &mut egui::Ui,
        env: &mut PageEnv<'_>,
        mut engine: Option<&mut EngineHandle>,
    ) {
        self.rig_ui(ui, env, engine.as_deref());
        self.protocol_ui(ui);
        let pid_ok = self.participant_ui(ui);
        let status = self.folder_ui(ui, env);
        let live = engine.as_deref().is_some_and(EngineHandle::is_live);
        self.kind_ui(ui, live);
        self.calibration_ui(ui, env);
        self.window_ui(ui);
        self.actions_ui(ui, env, engine.as_deref_mut(), pid_ok, status.as_ref());
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

    /// The protocol source and the loaded protocol's summary.
    fn protocol_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            ui.label("Protocol:");
            ui.radio_value(
                &mut self.form.source,
                ProtocolSource::Paper,
                "paper (built-in)",
            );
            ui.radio_value(
                &mut self.form.source,
                ProtocolSource::Blind,
                "blind (built-in)",
            );
            ui.radio_value(&mut self.form.source, ProtocolSource::File, "file");
            if self.form.source == ProtocolSource::File {
                let r = self.protocol_field.ui(
                    ui,
                    "Protocol file:",
                    &mut self.form.protocol_file,
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
    }

    /// The participant ID and their counterbalanced order; whether the ID
    /// is valid for the loaded protocol.
    fn participant_ui(&mut self, ui: &mut egui::Ui) -> bool {
        ui.horizontal(|ui| {
            let l = ui.label("Participant ID:");
            ui.add(egui::TextEdit::singleline(&mut self.form.participant_text).hint_text("P01"))
                .labelled_by(l.id);
        });
        let pid = self
            .table
            .as_ref()
            .map(|t| validate_participant_id(&self.form.participant_text, t));
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
            (Some(Err(e)), _) if !self.form.participant_text.trim().is_empty() => {
                ui.colored_label(Color32::from_rgb(235, 80, 70), e);
            }
            _ => {}
        }
        matches!(pid, Some(Ok(_)))
    }

    /// The output folder and one line on what it holds (a change of
    /// participant or folder clears what the last sitting showed).
    fn folder_ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) -> Option<FolderStatus> {
        ui.horizontal(|ui| {
            let r = self.out_field.ui(
                ui,
                "Output folder:",
                &mut self.form.out_text,
                PathKind::Folder,
                "study folder",
                380.0,
            );
            if (r.edit.lost_focus() || r.picked) && !self.form.out_text.trim().is_empty() {
                env.requests.push(ShellRequest::SetOutputDir(PathBuf::from(
                    self.form.out_text.trim(),
                )));
            }
        });
        let status = self.folder_status().cloned();
        // What the last sitting showed belongs to its participant and
        // folder: switching either clears it.
        let now = (
            self.form.participant_text.trim().to_owned(),
            self.form.out_text.trim().to_owned(),
        );
        if self.shown_for.as_ref().is_some_and(|s| *s != now) {
            self.clear_sitting_state();
        }
        self.shown_for = Some(now);
        // One line, whatever the folder holds (the controls below never move).
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
        status
    }

    /// Who is at the handle and the pacing (`live`: a live rig is connected).
    fn kind_ui(&mut self, ui: &mut egui::Ui, live: bool) {
        ui.horizontal(|ui| {
            ui.label("At the handle:");
            if live {
                self.form.kind = ParticipantKind::Handle;
                ui.radio_value(
                    &mut self.form.kind,
                    ParticipantKind::Handle,
                    "the participant at the live rig's handle",
                );
            } else {
                if self.form.kind == ParticipantKind::Handle {
                    self.form.kind = ParticipantKind::Mouse;
                }
                ui.radio_value(
                    &mut self.form.kind,
                    ParticipantKind::Mouse,
                    "person (mouse)",
                );
                ui.radio_value(
                    &mut self.form.kind,
                    ParticipantKind::Simulated,
                    "simulated participant",
                );
            }
            ui.separator();
            let fast_ok = self.form.kind == ParticipantKind::Simulated;
            if !fast_ok {
                self.form.speed = Speed::RealTime;
            }
            ui.radio_value(&mut self.form.speed, Speed::RealTime, "real time");
            ui.add_enabled_ui(fast_ok, |ui| {
                ui.radio_value(&mut self.form.speed, Speed::Fast, "as fast as possible")
                    .on_disabled_hover_text("for the simulated participant only");
            });
        });
    }

    /// Where the participant's view opens.
    fn window_ui(&mut self, ui: &mut egui::Ui) {
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
    }

    /// The actions, always in this order and place: open, resume, run all.
    fn actions_ui(
        &mut self,
        ui: &mut egui::Ui,
        env: &mut PageEnv<'_>,
        mut engine: Option<&mut EngineHandle>,
        pid_ok: bool,
        status: Option<&FolderStatus>,
    ) {
        let next = match status {
            Some(FolderStatus::Study { next, .. }) => next.clone(),
            _ => None,
        };
        let mut resume = false;
        let mut run_all = false;
        ui.horizontal(|ui| {
            let can = self.protocol.is_some() && pid_ok;
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
            let sim = self.form.kind == ParticipantKind::Simulated;
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
                self.form.participant_text = first.id.clone();
            }
            self.open_session(env, engine, resume, true);
        }
    }

    /// Which rig the sitting runs on: the simulated rig, or the live rig
    /// the Rig page connects (the engine switches rigs).
    pub(super) fn rig_ui(
        &mut self,
        ui: &mut egui::Ui,
        env: &mut PageEnv<'_>,
        engine: Option<&EngineHandle>,
    ) {
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

    pub(super) fn calibration_ui(&mut self, ui: &mut egui::Ui, env: &PageEnv<'_>) {
        ui.horizontal(|ui| {
            ui.label("D's chain:");
            let applied = match env.applied {
                Some(a) => format!("applied: {}", a.chain.source.describe()),
                None => "applied (none: as designed)".into(),
            };
            ui.radio_value(
                &mut self.form.calibration,
                CalibrationChoice::Applied,
                applied,
            )
            .on_hover_text("the calibration applied on the Calibration page");
            ui.radio_value(
                &mut self.form.calibration,
                CalibrationChoice::AsDesigned,
                "as designed (uncalibrated)",
            );
            ui.radio_value(&mut self.form.calibration, CalibrationChoice::File, "file:");
            if self.form.calibration == CalibrationChoice::File {
                self.calibration_field.ui(
                    ui,
                    "calibration file",
                    &mut self.form.calibration_file,
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
                to_pn_per_um(t.kappa_n_per_m),
                to_pn_per_um(t.kappa_se_n_per_m),
                to_um_per_v(t.rd_m_per_v[0]),
                to_um_per_v(t.rd_m_per_v[1])
            ),
            None => "no trap calibration applied (the Rig page's Tweezer section)".to_owned(),
        };
        ui.label(RichText::new(trap).weak());
    }

    pub(super) fn messages_ui(&mut self, ui: &mut egui::Ui) {
        if let Some(e) = self.model.error() {
            ui.colored_label(Color32::from_rgb(235, 80, 70), e.to_owned());
        }
        if let Some(text) = self.model.finish_text() {
            ui.label(RichText::new(text).strong());
        }
    }
}
