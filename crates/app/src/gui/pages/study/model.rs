//! The Study page's model of a sitting: what the session's events change
//! (runner state, current trial, live metrics, health, rows, progress, the
//! event log, the error and how the sitting ended) and how each event
//! changes it. No GUI toolkit here: the page (`mod.rs`) drains the session's
//! events into [`SittingModel::apply`] and tells the participant's screen
//! what the returned [`ScreenNote`] says; the views (`running.rs`,
//! `setup.rs`) read the model.

use kilotouch_study::export::{SittingTiming, TrialRow};
use kilotouch_study::runner::RunnerState;
use kilotouch_study::seeds::TrialKey;
use kilotouch_study::task::Scene;
use kilotouch_study::task::station::HandMapping;

use crate::session::{FinishReason, SessionEvent, SessionHealth, Telemetry};

/// Lines of the event log kept (the newest).
pub const LOG_CAPACITY: usize = 200;

/// What the participant's screen must be told after an event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScreenNote {
    /// The runner's state changed.
    State(RunnerState),
    /// The running trial ended.
    TrialEnded(TrialKey),
    /// The sitting ended: the end screen stays (`keep_end_screen`: the
    /// participant or the study is done), else the screen closes (stopped
    /// or failed).
    Finished {
        /// Show the end screen rather than close the participant's window.
        keep_end_screen: bool,
    },
}

/// The state of the sitting the page shows (the running one, or the last
/// one until it is cleared).
#[derive(Debug, Clone, Default)]
pub struct SittingModel {
    state: Option<RunnerState>,
    current: Option<(TrialKey, Scene)>,
    telemetry: Option<Telemetry>,
    health: SessionHealth,
    timing: Option<SittingTiming>,
    rows: Vec<TrialRow>,
    committed: usize,
    planned: usize,
    log: Vec<String>,
    error: Option<String>,
    finished: Option<FinishReason>,
    recovery_text: Option<String>,
    /// Where the participant's drags put the trap, m (sample plane).
    trap_target_m: [f64; 2],
    /// The participant's hand to send to the engine, m (handle plane).
    pending_hand: Option<[f64; 2]>,
}

impl SittingModel {
    /// Applies one session event; `mapping` (the sitting's hand mapping)
    /// gives the hand of a trial's start position. Returns what the
    /// participant's screen must be told, if anything.
    pub fn apply(&mut self, e: SessionEvent, mapping: &HandMapping) -> Option<ScreenNote> {
        match e {
            SessionEvent::State(st) => {
                self.state = Some(st);
                return Some(ScreenNote::State(st));
            }
            SessionEvent::TrialStarted { key, scene } => {
                self.current = Some((key, scene));
                self.telemetry = None;
                self.trap_target_m = scene.start_m;
                self.pending_hand = Some(mapping.to_hand(scene.start_m));
                self.push_log(format!("started {key}"));
            }
            SessionEvent::TrialEnded(k, e) => {
                self.push_log(format!("ended {k}: {e:?}"));
                return Some(ScreenNote::TrialEnded(k));
            }
            SessionEvent::Committed(row) => {
                self.committed += 1;
                self.rows.push(*row);
            }
            SessionEvent::Replanned(n) => {
                self.planned = n;
                self.push_log(format!(
                    "an unsuccessful practice trial earned an extra one ({n} trials planned)"
                ));
            }
            SessionEvent::Telemetry(t) => self.telemetry = Some(t),
            SessionEvent::Noted(n) => self.push_log(format!("note: {n}")),
            SessionEvent::Error(m) => {
                self.push_log(format!("error: {m}"));
                self.error = Some(m);
            }
            SessionEvent::Finished(r) => {
                if let FinishReason::Failed(m) = &r {
                    self.error = Some(m.clone());
                }
                let keep_end_screen = matches!(
                    r,
                    FinishReason::StudyDone | FinishReason::ParticipantDone(_)
                );
                self.finished = Some(r);
                self.current = None;
                return Some(ScreenNote::Finished { keep_end_screen });
            }
        }
        None
    }

    /// Forgets what the last sitting showed (after switching participant
    /// or folder): rows, metrics, state, messages, progress. The timing
    /// verdict, the trap target and a pending hand stay (the next sitting
    /// replaces them).
    pub fn clear(&mut self) {
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
    }

    /// A sitting opened: this participant's rows so far, the trials
    /// committed and planned in the study, what opening the folder
    /// recovered; the runner is idle, the log and health start afresh.
    pub fn opened(
        &mut self,
        rows: Vec<TrialRow>,
        committed: usize,
        planned: usize,
        recovery_text: String,
    ) {
        self.rows = rows;
        self.committed = committed;
        self.planned = planned;
        self.recovery_text = Some(recovery_text);
        self.state = Some(RunnerState::Idle);
        self.log.clear();
        self.health = SessionHealth::default();
    }

    /// Appends a line to the event log (the newest [`LOG_CAPACITY`] are kept).
    pub fn push_log(&mut self, line: String) {
        self.log.push(line);
        if self.log.len() > LOG_CAPACITY {
            let cut = self.log.len() - LOG_CAPACITY;
            self.log.drain(..cut);
        }
    }

    /// Shows an error (not logged).
    pub fn set_error(&mut self, message: String) {
        self.error = Some(message);
    }

    /// Clears the error shown.
    pub fn clear_error(&mut self) {
        self.error = None;
    }

    /// Forgets how the last sitting ended (a new one is being opened).
    pub fn clear_finished(&mut self) {
        self.finished = None;
    }

    /// The session thread's health, as last read.
    pub fn set_health(&mut self, health: SessionHealth) {
        self.health = health;
    }

    /// The sitting's timing verdict so far, as last read.
    pub fn set_timing(&mut self, timing: SittingTiming) {
        self.timing = Some(timing);
    }

    /// The participant dragged the trap by `delta_m` (m, sample plane):
    /// the hand that puts it there waits to be sent.
    pub fn drag_trap(&mut self, delta_m: [f64; 2], mapping: &HandMapping) {
        self.trap_target_m[0] += delta_m[0];
        self.trap_target_m[1] += delta_m[1];
        self.pending_hand = Some(mapping.to_hand(self.trap_target_m));
    }

    /// The hand waiting to be sent to the engine, m.
    pub fn pending_hand(&self) -> Option<[f64; 2]> {
        self.pending_hand
    }

    /// The engine took the pending hand.
    pub fn hand_sent(&mut self) {
        self.pending_hand = None;
    }

    /// The runner state last reported.
    pub fn runner_state(&self) -> Option<RunnerState> {
        self.state
    }

    /// The runner state last reported, idle before any.
    pub fn state_or_idle(&self) -> RunnerState {
        self.state.unwrap_or(RunnerState::Idle)
    }

    /// The trial the engine has begun and its scene.
    pub fn current(&self) -> Option<(TrialKey, Scene)> {
        self.current
    }

    /// The trial the engine has begun (its `TrialStarted` arrived), if any.
    pub fn trial_started(&self) -> Option<TrialKey> {
        self.current.map(|(k, _)| k)
    }

    /// The last telemetry of the current trial.
    pub fn telemetry(&self) -> Option<&Telemetry> {
        self.telemetry.as_ref()
    }

    /// The session thread's health.
    pub fn health(&self) -> SessionHealth {
        self.health
    }

    /// The sitting's timing verdict so far.
    pub fn timing(&self) -> Option<&SittingTiming> {
        self.timing.as_ref()
    }

    /// Rows shown in the table (this participant's, from `trials.csv` and
    /// the rows committed in this sitting).
    pub fn rows(&self) -> &[TrialRow] {
        &self.rows
    }

    /// Trials committed in the study.
    pub fn committed(&self) -> usize {
        self.committed
    }

    /// Trials in the study's plan as the sitting last reported it.
    pub fn planned(&self) -> usize {
        self.planned
    }

    /// The event log, oldest first.
    pub fn log(&self) -> &[String] {
        &self.log
    }

    /// The last error shown.
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    /// How the last sitting ended.
    pub fn finished(&self) -> Option<&FinishReason> {
        self.finished.as_ref()
    }

    /// What opening the folder found and recovered.
    pub fn recovery_text(&self) -> Option<&str> {
        self.recovery_text.as_deref()
    }

    /// Where the participant's drags put the trap, m.
    pub fn trap_target_m(&self) -> [f64; 2] {
        self.trap_target_m
    }

    /// "committed 3 of 40 trials (study)".
    pub fn progress_text(&self) -> String {
        format!(
            "committed {} of {} trials (study)",
            self.committed, self.planned
        )
    }

    /// What an emergency stop does to the sitting in its current state:
    /// which trial it aborts, or that none runs.
    pub fn estop_effect(&self) -> String {
        match self.state {
            Some(
                RunnerState::Training(k) | RunnerState::Trial(k) | RunnerState::Paused(Some(k)),
            ) => {
                format!("trial {k} was aborted (its row is kept as `aborted`)")
            }
            _ => "no trial was running, none was aborted".to_owned(),
        }
    }

    /// How the last sitting ended, in one sentence.
    pub fn finish_text(&self) -> Option<String> {
        Some(match self.finished.as_ref()? {
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
        })
    }

    /// "current: P01/V/test/3 (V — …)".
    pub fn current_text(&self) -> Option<String> {
        let (key, _) = self.current.as_ref()?;
        Some(format!(
            "current: {key} ({} — {})",
            key.condition.code(),
            key.condition.description()
        ))
    }

    /// The current trial's live metrics in one line.
    pub fn live_text(&self) -> Option<String> {
        let l = self.telemetry.as_ref()?.live;
        let f =
            |v: Option<f64>, d: usize| v.map(|x| format!("{x:.d$}")).unwrap_or_else(|| "—".into());
        Some(format!(
            "time {:.1} s · contact fraction {} · mean handle force {} N (peak {:.3}) · disp. error {} µm",
            l.t_s,
            f(l.contact_fraction, 2),
            f(l.force_mean_n, 3),
            l.force_peak_n,
            f(l.disp_err_mean_um, 2)
        ))
    }

    /// The session thread's health in one line.
    pub fn health_text(&self) -> String {
        let h = self.health;
        format!(
            "session thread: load {:.1} % · deadline misses {} · overruns {} · telemetry dropped {} · simulated {:.1} s",
            100.0 * h.load,
            h.deadline_misses,
            h.overruns,
            h.telemetry_dropped,
            h.simulated_s
        )
    }
}

#[cfg(test)]
mod tests {
    use kilotouch_rig::RigConfig;
    use kilotouch_study::export::{PlannedTrial, TaskKind, UtcTime};
    use kilotouch_study::protocol::Condition;
    use kilotouch_study::seeds::Phase;
    use kilotouch_study::task::{Geometry, TrialEnd};

    use super::*;

    fn mapping() -> HandMapping {
        HandMapping::from_config(&RigConfig::default().coupling)
    }

    fn key(trial: u32) -> TrialKey {
        TrialKey::new(0, Condition::V, Phase::Test, trial)
    }

    fn row(trial: u32) -> TrialRow {
        PlannedTrial {
            key: key(trial),
            participant: "P01".into(),
            session_index: 1,
            session_order: "VPD".into(),
            seed: 7,
        }
        .blank_row(
            TaskKind::Circling,
            UtcTime::from_unix_millis(0),
            String::new(),
        )
    }

    fn scene() -> Scene {
        Scene {
            geometry: Geometry {
                obstacle_m: [0.0, 0.0],
                obstacle_radius_m: 2e-6,
                bead_radius_m: 1e-6,
            },
            start_m: [4e-6, -1e-6],
            heading: [-1.0, 0.0],
        }
    }

    #[test]
    fn committed_rows_and_replanning_count() {
        let mut m = SittingModel::default();
        m.opened(vec![row(1)], 5, 40, "clean".into());
        assert_eq!(m.runner_state(), Some(RunnerState::Idle));
        for t in 2..=3 {
            assert_eq!(
                m.apply(SessionEvent::Committed(Box::new(row(t))), &mapping()),
                None
            );
        }
        assert_eq!(m.rows().len(), 3);
        assert_eq!(m.rows()[2].trial, 3);
        assert_eq!(m.committed(), 7);
        assert_eq!(m.apply(SessionEvent::Replanned(41), &mapping()), None);
        assert_eq!(m.planned(), 41);
        assert_eq!(m.progress_text(), "committed 7 of 41 trials (study)");
        assert!(m.log().last().unwrap().contains("41 trials planned"));
    }

    #[test]
    fn log_keeps_the_newest_lines() {
        let mut m = SittingModel::default();
        for i in 0..500 {
            m.apply(SessionEvent::Noted(format!("n{i}")), &mapping());
        }
        assert_eq!(m.log().len(), LOG_CAPACITY);
        assert_eq!(m.log().first().unwrap(), "note: n300");
        assert_eq!(m.log().last().unwrap(), "note: n499");
        m.push_log("last".into());
        assert_eq!(m.log().len(), LOG_CAPACITY);
        assert_eq!(m.log().last().unwrap(), "last");
    }

    #[test]
    fn an_error_is_shown_and_logged() {
        let mut m = SittingModel::default();
        m.apply(SessionEvent::Error("refused".into()), &mapping());
        assert_eq!(m.error(), Some("refused"));
        assert_eq!(m.log(), ["error: refused"]);
        assert!(m.finished().is_none());
    }

    #[test]
    fn a_failed_sitting_sets_the_error_and_closes_the_screen() {
        let mut m = SittingModel::default();
        m.apply(
            SessionEvent::TrialStarted {
                key: key(1),
                scene: scene(),
            },
            &mapping(),
        );
        let note = m.apply(
            SessionEvent::Finished(FinishReason::Failed("disk full".into())),
            &mapping(),
        );
        assert_eq!(
            note,
            Some(ScreenNote::Finished {
                keep_end_screen: false
            })
        );
        assert_eq!(m.error(), Some("disk full"));
        assert_eq!(
            m.finished(),
            Some(&FinishReason::Failed("disk full".into()))
        );
        assert_eq!(m.finish_text().unwrap(), "session failed: disk full");
        assert_eq!(m.trial_started(), None);
    }

    #[test]
    fn a_finished_participant_keeps_the_end_screen() {
        let mut m = SittingModel::default();
        let note = m.apply(
            SessionEvent::Finished(FinishReason::ParticipantDone("P01".into())),
            &mapping(),
        );
        assert_eq!(
            note,
            Some(ScreenNote::Finished {
                keep_end_screen: true
            })
        );
        assert_eq!(m.error(), None);
    }

    #[test]
    fn a_started_trial_sets_the_trap_and_the_hand() {
        let mapping = mapping();
        let mut m = SittingModel::default();
        let st = RunnerState::Trial(key(2));
        assert_eq!(
            m.apply(SessionEvent::State(st), &mapping),
            Some(ScreenNote::State(st))
        );
        assert_eq!(
            m.estop_effect(),
            format!(
                "trial {} was aborted (its row is kept as `aborted`)",
                key(2)
            )
        );
        let sc = scene();
        m.apply(
            SessionEvent::TrialStarted {
                key: key(2),
                scene: sc,
            },
            &mapping,
        );
        assert_eq!(m.trial_started(), Some(key(2)));
        assert_eq!(m.current().unwrap().1, sc);
        assert_eq!(m.trap_target_m(), sc.start_m);
        assert_eq!(m.pending_hand(), Some(mapping.to_hand(sc.start_m)));
        assert!(m.telemetry().is_none());
        assert_eq!(m.log(), [format!("started {}", key(2))]);
        m.hand_sent();
        m.drag_trap([1e-6, 0.0], &mapping);
        let moved = [sc.start_m[0] + 1e-6, sc.start_m[1]];
        assert_eq!(m.trap_target_m(), moved);
        assert_eq!(m.pending_hand(), Some(mapping.to_hand(moved)));
        assert_eq!(
            m.apply(
                SessionEvent::TrialEnded(key(2), TrialEnd::Completed),
                &mapping
            ),
            Some(ScreenNote::TrialEnded(key(2)))
        );
        assert_eq!(
            m.log().last().unwrap(),
            &format!("ended {}: Completed", key(2))
        );
    }

    #[test]
    fn clear_forgets_the_sitting() {
        let mut m = SittingModel::default();
        m.opened(vec![row(1)], 3, 40, "recovered".into());
        m.apply(
            SessionEvent::TrialStarted {
                key: key(1),
                scene: scene(),
            },
            &mapping(),
        );
        m.apply(SessionEvent::Error("x".into()), &mapping());
        m.apply(SessionEvent::Finished(FinishReason::Stopped), &mapping());
        m.clear();
        assert!(m.rows().is_empty());
        assert!(m.log().is_empty());
        assert_eq!(m.runner_state(), None);
        assert_eq!(m.trial_started(), None);
        assert_eq!(m.error(), None);
        assert_eq!(m.finished(), None);
        assert_eq!(m.recovery_text(), None);
        assert_eq!((m.committed(), m.planned()), (0, 0));
        assert_eq!(m.health(), SessionHealth::default());
        assert_eq!(m.estop_effect(), "no trial was running, none was aborted");
    }
}
