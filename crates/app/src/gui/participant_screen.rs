//! The participant's screen of a sitting: the routines of
//! [`kilotouch_study::screens`] (instructions → ready → trial with a
//! counter → inter-trial interval → … → break → … → end), driven by the
//! session's states and the protocol's `[screens]` texts. Only what the
//! participant should see is drawn here: no experimenter controls, no
//! condition codes, no status or error messages.
//!
//! The session thread holds each new block until the participant leaves
//! the ready screen ([`Routine::Ready`] → [`ParticipantScreen::input`]
//! returns `true`: send `SessionCommand::Proceed`); the inter-trial
//! interval elapses on the session thread.

use std::time::Instant;

use egui::{Color32, RichText};
use kilotouch_study::protocol::{Condition, Protocol};
use kilotouch_study::runner::RunnerState;
use kilotouch_study::screens::{Gate, gate, position};
use kilotouch_study::seeds::{Phase, TrialKey};

/// Which screen the participant sees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Routine {
    /// Before the experimenter starts, or while the sitting is paused:
    /// "please wait".
    Wait,
    /// Break between sessions (until `break_min_s` has passed and the
    /// participant presses a key or clicks); then the instructions.
    Break {
        /// The trial after the break.
        next: TrialKey,
        /// When the break began.
        since: Instant,
    },
    /// Instructions of the block `next` begins; a key or click → ready.
    Instructions {
        /// The first trial of the block.
        next: TrialKey,
    },
    /// Ready screen: a key or click begins the trial.
    Ready {
        /// The trial to begin.
        next: TrialKey,
    },
    /// Proceed sent; the trial is about to begin (blank).
    Starting,
    /// A trial runs: the scene, with the counter.
    Trial(TrialKey),
    /// Inter-trial interval (blank).
    Iti,
    /// End screen (stays until the experimenter closes the window).
    End,
}

/// The participant's screen state.
#[derive(Debug, Clone)]
pub struct ParticipantScreen {
    /// Current routine.
    pub routine: Routine,
    protocol: Protocol,
    orders: Vec<Vec<Condition>>,
    last_ended: Option<TrialKey>,
    /// The participant may press/click (a person; the simulated
    /// participant's session proceeds by itself).
    pub person: bool,
}

/// Text size of the screens, points.
const TEXT_PT: f32 = 24.0;
/// Widest text column, points.
const TEXT_WIDTH: f32 = 760.0;

impl ParticipantScreen {
    /// A screen for a sitting of `protocol`; `orders[i]` is participant
    /// i's condition order (the protocol's assignment table).
    pub fn new(protocol: Protocol, orders: Vec<Vec<Condition>>, person: bool) -> Self {
        Self {
            routine: Routine::Wait,
            protocol,
            orders,
            last_ended: None,
            person,
        }
    }

    /// The session's runner changed state.
    pub fn on_state(&mut self, s: RunnerState) {
        if matches!(s, RunnerState::Paused(None)) {
            // The next trial after a pause between trials begins a new
            // block (as the session thread decides).
            self.last_ended = None;
        }
        self.routine = match s {
            RunnerState::Idle | RunnerState::Paused(_) => Routine::Wait,
            RunnerState::Training(k) | RunnerState::Trial(k) => Routine::Trial(k),
            RunnerState::Waiting(next) => match gate(self.last_ended, next) {
                Gate::Iti => Routine::Iti,
                Gate::NewBlock { break_first: true } => Routine::Break {
                    next,
                    since: Instant::now(),
                },
                Gate::NewBlock { break_first: false } => Routine::Instructions { next },
            },
            RunnerState::Done => Routine::End,
        };
    }

    /// A trial ended.
    pub fn on_trial_ended(&mut self, k: TrialKey) {
        self.last_ended = Some(k);
    }

    /// The participant's sitting is over (show the end screen).
    pub fn on_finished(&mut self) {
        self.routine = Routine::End;
    }

    /// A key press or click of the participant: advances break →
    /// instructions → ready; `true` when the ready screen was left (send
    /// `Proceed`).
    pub fn input(&mut self) -> bool {
        if !self.person {
            return false;
        }
        match self.routine {
            Routine::Break { next, since } => {
                if since.elapsed().as_secs_f64() >= self.protocol.screens.break_min_s {
                    self.routine = Routine::Instructions { next };
                }
                false
            }
            Routine::Instructions { next } => {
                self.routine = Routine::Ready { next };
                false
            }
            Routine::Ready { .. } => {
                self.routine = Routine::Starting;
                true
            }
            _ => false,
        }
    }

    /// The counter of trial `k`: "Practice — trial 1 of 3", "Practice —
    /// extra trial 1" (one replacing an unsuccessful practice trial) or
    /// "Session 2 of 3 — trial 4 of 10", and the fraction of the block done.
    pub fn counter(&self, k: TrialKey) -> (String, f32) {
        let order = self
            .orders
            .get(k.participant as usize)
            .map_or(&[][..], |o| &o[..]);
        let (trial, of, session, sessions) = position(
            k,
            order,
            self.protocol.trials_per_session,
            self.protocol.training.practice_trials,
        );
        let text = match k.phase {
            // An extra trial replacing an unsuccessful one
            // (`training.practice_retries`).
            Phase::Practice if trial > of => {
                format!("Practice — extra trial {}", trial - of)
            }
            Phase::Practice => format!("Practice — trial {trial} of {of}"),
            Phase::Test => format!("Session {session} of {sessions} — trial {trial} of {of}"),
        };
        let done = (trial as f32 - 1.0) / of.max(1) as f32;
        (text, done.min(1.0))
    }

    /// The text of the current screen (`None`: blank or the scene).
    pub fn text(&self) -> Option<String> {
        let s = &self.protocol.screens;
        match self.routine {
            Routine::Wait => Some("Please wait.".into()),
            Routine::Break { since, .. } => {
                let left = s.break_min_s - since.elapsed().as_secs_f64();
                if left > 0.0 {
                    Some(format!("{}\n\n({:.0} s)", s.break_text.trim(), left.ceil()))
                } else {
                    Some(s.break_text.trim().to_owned())
                }
            }
            Routine::Instructions { next } => Some(format!(
                "{}\n\n{}",
                s.instructions_for(&self.protocol.task, next),
                "Press SPACE or click to continue."
            )),
            Routine::Ready { .. } => Some(s.ready.trim().to_owned()),
            Routine::End => Some(s.end.trim().to_owned()),
            Routine::Starting | Routine::Trial(_) | Routine::Iti => None,
        }
    }

    /// Draws a text screen (or nothing for the scene / blank routines) into
    /// `rect`; returns `true` when something was drawn. The counter of a
    /// trial is drawn by [`ParticipantScreen::counter_ui`].
    pub fn paint_text(&self, ui: &mut egui::Ui, rect: egui::Rect) -> bool {
        let Some(text) = self.text() else {
            return false;
        };
        ui.painter_at(rect)
            .rect_filled(rect, 0.0, Color32::from_gray(24));
        let width = (rect.width() - 48.0).clamp(100.0, TEXT_WIDTH);
        let size = TEXT_PT.min(rect.height() / 10.0).max(12.0);
        let rich = RichText::new(text)
            .size(size)
            .color(Color32::from_gray(235));
        // A label (readable by screen readers and the UI tests), centred;
        // not selectable, so a click reaches the screen underneath.
        let galley = egui::WidgetText::from(rich.clone()).into_galley(
            ui,
            Some(egui::TextWrapMode::Wrap),
            width,
            egui::TextStyle::Body,
        );
        let inner = egui::Rect::from_center_size(rect.center(), galley.size()).intersect(rect);
        ui.put(
            inner,
            egui::Label::new(rich)
                .wrap()
                .selectable(false)
                .halign(egui::Align::Center),
        );
        true
    }

    /// The trial counter and the block's progress bar at the top of `rect`
    /// (when the protocol shows progress).
    pub fn counter_ui(&self, ui: &mut egui::Ui, rect: egui::Rect) {
        let Routine::Trial(k) = self.routine else {
            return;
        };
        if !self.protocol.screens.show_progress {
            return;
        }
        let (text, frac) = self.counter(k);
        let bar = egui::Rect::from_min_size(
            rect.left_top() + egui::vec2(12.0, 10.0),
            egui::vec2((rect.width() - 24.0).max(10.0), 22.0),
        );
        let mut child = ui.new_child(egui::UiBuilder::new().max_rect(bar));
        child.add(
            egui::ProgressBar::new(frac)
                .desired_width(bar.width())
                .text(RichText::new(text).color(Color32::WHITE)),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn screen() -> ParticipantScreen {
        let mut p = Protocol::builtin("paper").unwrap_or_else(|e| panic!("{e}"));
        p.screens.break_min_s = 0.0;
        ParticipantScreen::new(
            p,
            vec![vec![Condition::P, Condition::D, Condition::V]],
            true,
        )
    }

    #[test]
    fn routines_follow_the_flow() {
        let mut s = screen();
        let k = |ph, c, t| TrialKey::new(0, c, ph, t);
        s.on_state(RunnerState::Waiting(k(Phase::Practice, Condition::P, 1)));
        assert!(matches!(s.routine, Routine::Instructions { .. }));
        assert!(!s.input());
        assert!(matches!(s.routine, Routine::Ready { .. }));
        assert!(s.input(), "leaving the ready screen proceeds");
        s.on_state(RunnerState::Training(k(Phase::Practice, Condition::P, 1)));
        assert_eq!(
            s.counter(k(Phase::Practice, Condition::P, 1)).0,
            "Practice — trial 1 of 3"
        );
        // An extra trial replacing an unsuccessful one: no "4 of 3".
        assert_eq!(
            s.counter(k(Phase::Practice, Condition::P, 4)),
            ("Practice — extra trial 1".to_owned(), 1.0)
        );
        s.on_trial_ended(k(Phase::Practice, Condition::P, 1));
        s.on_state(RunnerState::Waiting(k(Phase::Practice, Condition::P, 2)));
        assert_eq!(s.routine, Routine::Iti);
        assert!(!s.input(), "keys do nothing in the interval");
        s.on_trial_ended(k(Phase::Practice, Condition::V, 3));
        s.on_state(RunnerState::Waiting(k(Phase::Test, Condition::P, 1)));
        assert!(matches!(s.routine, Routine::Break { .. }));
        s.on_state(RunnerState::Trial(k(Phase::Test, Condition::D, 4)));
        assert_eq!(
            s.counter(k(Phase::Test, Condition::D, 4)),
            ("Session 2 of 3 — trial 4 of 10".to_owned(), 0.3)
        );
        s.on_finished();
        assert!(s.text().unwrap_or_default().contains("Thank you"));
    }

    #[test]
    fn the_simulated_participant_presses_nothing() {
        let mut s = screen();
        s.person = false;
        s.on_state(RunnerState::Waiting(TrialKey::new(
            0,
            Condition::P,
            Phase::Practice,
            1,
        )));
        assert!(!s.input());
        assert!(matches!(s.routine, Routine::Instructions { .. }));
    }
}
