//! Opening a sitting: the calibration it runs, the size check, the
//! session's worker.

use std::path::PathBuf;

use crate::engine::EngineHandle;
use crate::gui::env::{PageEnv, ShellRequest};
use crate::gui::pages::study_size::{PreparedSitting, Verdict};
use crate::gui::participant_screen::ParticipantScreen;
use crate::session::{
    FolderStatus, ParticipantId, ParticipantKind, SessionCommand, SessionHandle, SessionOptions,
    Speed, validate_participant_id,
};

use super::StudyPage;

impl StudyPage {
    /// The calibration file the sitting runs and records (`None`: the
    /// as-designed chain, recorded as uncalibrated).
    pub(super) fn resolve_calibration(&self, env: &PageEnv<'_>) -> Result<Option<PathBuf>, String> {
        self.form
            .calibration_path(env.applied.map(|a| a.path.as_deref()))
    }

    /// Open a sitting (`resume`: at the folder's next pending trial;
    /// `start`: send Start once it is open) after the size check
    /// ([`SizeGate`]): at once when it writes no raw files, else once the
    /// estimate fits the disk and, above the page's threshold, the
    /// experimenter confirmed.
    pub(super) fn open_session(
        &mut self,
        env: &mut PageEnv<'_>,
        engine: Option<&mut EngineHandle>,
        resume: bool,
        start: bool,
    ) {
        self.model.clear_error();
        if self.size_gate.is_busy() {
            self.model
                .set_error("a sitting is already being checked: confirm or cancel it".into());
            return;
        }
        let Some(engine) = engine else {
            self.model.set_error(
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
    pub(super) fn on_verdict(
        &mut self,
        v: Verdict,
        env: &mut PageEnv<'_>,
        engine: Option<&mut EngineHandle>,
    ) {
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
                self.model
                    .set_error("the rig was disconnected before the sitting opened".into());
            }
            (Verdict::Refused(why), _) => {
                self.run_all = false;
                self.model.set_error(why);
            }
            (Verdict::Cancelled, _) => {
                self.run_all = false;
                self.model
                    .push_log("the sitting was not opened (cancelled)".into());
            }
        }
    }

    /// Validate the page's choices into a sitting's options, or set the
    /// error and return `None`.
    pub(super) fn prepare_session(
        &mut self,
        env: &mut PageEnv<'_>,
        engine: &EngineHandle,
        resume: bool,
        start: bool,
    ) -> Option<PreparedSitting> {
        self.model.clear_finished();
        self.screen = None;
        let out = match self.form.out_folder() {
            Ok(out) => out,
            Err(e) => {
                self.model.set_error(e);
                return None;
            }
        };
        let (protocol, pid) = if resume {
            let next = match self.folder_status() {
                Some(FolderStatus::Study { next: Some(n), .. }) => n.clone(),
                _ => {
                    self.model
                        .set_error("nothing to resume in this folder".into());
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
                self.model.set_error("load a valid protocol first".into());
                return None;
            };
            match validate_participant_id(&self.form.participant_text, t) {
                Ok(id) => (Some(p.clone()), id),
                Err(e) => {
                    self.model.set_error(e);
                    return None;
                }
            }
        };
        let calibration = match self.resolve_calibration(env) {
            Ok(c) => c,
            Err(e) => {
                self.model.set_error(e);
                return None;
            }
        };
        let mut opts = SessionOptions::new(&out, protocol, env.rig_config.clone());
        opts.calibration = calibration;
        opts.trap_calibration = env.trap_applied.cloned();
        let kind = self.form.participant_kind(engine.is_live());
        opts.participant = kind;
        opts.speed = self.form.speed_for(kind);
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
    pub(super) fn spawn_session(
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
                // Streaming: the sitting begins on the marker stream
                // (a run of every remaining participant is named by its
                // first).
                #[cfg(feature = "lsl")]
                {
                    self.lsl_sitting = self.lsl.clone().map(|m| {
                        crate::lsl::LslSitting::start(m, &out, &pid.id, &info.protocol.name)
                    });
                }
                self.mapping = info.mapping;
                self.rig_used = Some(match &info.device {
                    Some(d) => format!(
                        "{} — {} (loop delay {:.1} ms)",
                        info.rig, d.name, d.loop_delay_ms
                    ),
                    None => "the simulated rig".to_owned(),
                });
                let rows = info
                    .rows
                    .iter()
                    .filter(|r| r.participant == pid.id)
                    .cloned()
                    .collect();
                self.model.opened(
                    rows,
                    info.completed,
                    info.planned,
                    info.recovery_text.clone(),
                );
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
                self.form.participant_text = pid.id.clone();
                self.shown_for = Some((pid.id.clone(), self.form.out_text.trim().to_owned()));
                self.sitting_id = Some(pid);
                if resume {
                    h.send(SessionCommand::Note("resumed from the Study page".into()));
                }
                self.session = Some(h);
                env.requests.push(ShellRequest::SetOutputDir(out));
            }
            Err(e) => self.model.set_error(e.to_string()),
        }
    }

    pub(super) fn send(&mut self, cmd: SessionCommand) {
        if let Some(s) = &mut self.session
            && !s.send(cmd)
        {
            self.model
                .set_error("command not sent (queue full); try again".into());
        }
    }
}
