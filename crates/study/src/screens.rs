//! The participant's screens of a sitting, as a PsychoPy Builder flow of
//! routines: **instructions** → **ready** (start on a key or click) →
//! **trial** (with a counter) → **inter-trial interval** → … → **break**
//! between sessions → instructions → ready → … → **end**.
//!
//! The texts and timings come from the protocol file's optional
//! `[screens]` table ([`Screens`], every key has a default); which routine
//! comes between two trials is decided here once ([`gate`]), for the
//! session thread (which holds the next trial until the participant is
//! ready) and for the GUI (which draws the screens).
//!
//! ```toml
//! [screens]
//! instructions = "Move the handle to bring the small bead against the large one …"
//! practice = "The first trials are practice."
//! ready = "Press SPACE or click to start."
//! break = "Take a short break. Press SPACE or click when you are ready to go on."
//! end = "Thank you! The experiment is over."
//! iti_s = 1.0          # inter-trial interval, s (0–60)
//! break_min_s = 5.0    # shortest break before it can be ended, s (0–600)
//! show_progress = true # trial counter and progress bar during a trial
//! [screens.condition_instructions]
//! D = "In this session you feel the contact through the handle."
//! ```

use crate::protocol::{Condition, Invalid, Task};
pub use crate::screen_texts::{
    BLIND_INSTRUCTIONS, CIRCLING_INSTRUCTIONS, MAX_BREAK_MIN_S, MAX_ITI_S, MAX_TEXT_CHARS, Screens,
};
use crate::seeds::{Phase, TrialKey};

impl Screens {
    /// Checks texts and timings against `conditions` (first problem found,
    /// field paths under `screens.`).
    ///
    /// # Errors
    /// [`Invalid`]: interval or break outside its range, a text longer
    /// than [`MAX_TEXT_CHARS`], condition instructions for a condition the
    /// protocol does not run.
    pub fn validate(&self, conditions: &[Condition]) -> Result<(), Invalid> {
        let bad = |field: &str, message: String| Invalid {
            field: format!("screens.{field}"),
            message,
        };
        if !(self.iti_s.is_finite() && (0.0..=MAX_ITI_S).contains(&self.iti_s)) {
            return Err(bad(
                "iti_s",
                format!(
                    "the inter-trial interval must be between 0 and {MAX_ITI_S} seconds, got {}",
                    self.iti_s
                ),
            ));
        }
        if !(self.break_min_s.is_finite() && (0.0..=MAX_BREAK_MIN_S).contains(&self.break_min_s)) {
            return Err(bad(
                "break_min_s",
                format!(
                    "the shortest break must be between 0 and {MAX_BREAK_MIN_S} seconds, got {}",
                    self.break_min_s
                ),
            ));
        }
        for (field, text) in [
            ("instructions", &self.instructions),
            ("practice", &self.practice),
            ("ready", &self.ready),
            ("break", &self.break_text),
            ("end", &self.end),
        ] {
            if text.chars().count() > MAX_TEXT_CHARS {
                return Err(bad(
                    field,
                    format!("is longer than {MAX_TEXT_CHARS} characters (one screen)"),
                ));
            }
        }
        for (code, text) in &self.condition_instructions {
            let field = format!("condition_instructions.{code}");
            if !conditions.iter().any(|c| c.code() == code) {
                let codes: Vec<&str> = conditions.iter().map(|c| c.code()).collect();
                return Err(bad(
                    &field,
                    format!(
                        "`{code}` is not a condition of this protocol (it runs {})",
                        codes.join(", ")
                    ),
                ));
            }
            if text.chars().count() > MAX_TEXT_CHARS {
                return Err(bad(
                    &field,
                    format!("is longer than {MAX_TEXT_CHARS} characters (one screen)"),
                ));
            }
        }
        Ok(())
    }

    /// The instructions shown before the block that `next` begins: the
    /// general text (or the task's default), the condition's text where
    /// given, and the practice note before practice trials.
    pub fn instructions_for(&self, task: &Task, next: TrialKey) -> String {
        let general = if self.instructions.trim().is_empty() {
            match task {
                Task::Circling(_) => CIRCLING_INSTRUCTIONS,
                Task::BlindNavigation(_) => BLIND_INSTRUCTIONS,
            }
        } else {
            self.instructions.trim()
        };
        let mut out = general.to_owned();
        if let Some(t) = self
            .condition_instructions
            .get(next.condition.code())
            .map(|t| t.trim())
            .filter(|t| !t.is_empty())
        {
            out.push_str("\n\n");
            out.push_str(t);
        }
        if next.phase == Phase::Practice && !self.practice.trim().is_empty() {
            out.push_str("\n\n");
            out.push_str(self.practice.trim());
        }
        out
    }
}

/// What runs between the trial just finished and the next one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Gate {
    /// Same block: the inter-trial interval, then the next trial begins by
    /// itself.
    Iti,
    /// A new block begins: (break →) instructions → ready; the participant
    /// starts the trial.
    NewBlock {
        /// A break screen comes first (after a session, and after the
        /// training block).
        break_first: bool,
    },
}

/// The routine between `prev` (the trial just finished; `None` at the start
/// of a sitting) and `next`. A block is a run of trials with the same
/// participant, phase and condition.
pub fn gate(prev: Option<TrialKey>, next: TrialKey) -> Gate {
    match prev {
        None => Gate::NewBlock { break_first: false },
        Some(p) if p.participant != next.participant => Gate::NewBlock { break_first: false },
        Some(p) if p.phase == next.phase && p.condition == next.condition => Gate::Iti,
        Some(p) => Gate::NewBlock {
            // After a measured session, and between training and test.
            break_first: p.phase == Phase::Test || next.phase == Phase::Test,
        },
    }
}

/// Where `key` stands in its block, for the participant's counter:
/// (trial number, trials in the block, session number, sessions) — the
/// session number is 0 for practice trials. `order` is the participant's
/// condition order.
pub fn position(
    key: TrialKey,
    order: &[Condition],
    trials_per_session: u32,
    practice_trials: u32,
) -> (u32, u32, usize, usize) {
    let session = order
        .iter()
        .position(|&c| c == key.condition)
        .map_or(0, |i| i + 1);
    match key.phase {
        Phase::Practice => (key.trial, practice_trials, 0, order.len()),
        Phase::Test => (key.trial, trials_per_session, session, order.len()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::CirclingTask;

    fn key(phase: Phase, c: Condition, trial: u32) -> TrialKey {
        TrialKey::new(0, c, phase, trial)
    }

    #[test]
    fn gates_follow_the_blocks() {
        use Condition::{D, V};
        let (pr, te) = (Phase::Practice, Phase::Test);
        assert_eq!(
            gate(None, key(pr, V, 1)),
            Gate::NewBlock { break_first: false }
        );
        assert_eq!(gate(Some(key(te, V, 1)), key(te, V, 2)), Gate::Iti);
        // Training: next condition's instructions without a break.
        assert_eq!(
            gate(Some(key(pr, V, 1)), key(pr, D, 1)),
            Gate::NewBlock { break_first: false }
        );
        // Training → test and session → session: a break first.
        assert_eq!(
            gate(Some(key(pr, D, 1)), key(te, V, 1)),
            Gate::NewBlock { break_first: true }
        );
        assert_eq!(
            gate(Some(key(te, V, 10)), key(te, D, 1)),
            Gate::NewBlock { break_first: true }
        );
    }

    #[test]
    fn instructions_combine_task_condition_and_practice() {
        let mut s = Screens::default();
        let task = Task::Circling(CirclingTask::default());
        let t = s.instructions_for(&task, key(Phase::Test, Condition::D, 1));
        assert_eq!(t, CIRCLING_INSTRUCTIONS);
        s.condition_instructions
            .insert("D".into(), "You feel the contact.".into());
        s.instructions = "Go around.".into();
        let t = s.instructions_for(&task, key(Phase::Practice, Condition::D, 1));
        assert!(t.starts_with("Go around.\n\nYou feel the contact.\n\nThe first trials"));
        let t = s.instructions_for(&task, key(Phase::Test, Condition::V, 1));
        assert_eq!(t, "Go around.");
    }

    #[test]
    fn validation_bounds() {
        let conds = [Condition::V, Condition::D];
        assert!(Screens::default().validate(&conds).is_ok());
        let mut s = Screens {
            iti_s: -1.0,
            ..Screens::default()
        };
        assert_eq!(s.validate(&conds).unwrap_err().field, "screens.iti_s");
        s.iti_s = f64::NAN;
        assert!(s.validate(&conds).is_err());
        s.iti_s = MAX_ITI_S;
        s.break_min_s = 1e9;
        assert_eq!(s.validate(&conds).unwrap_err().field, "screens.break_min_s");
        s.break_min_s = 0.0;
        s.condition_instructions.insert("P".into(), "x".into());
        let e = s.validate(&conds).unwrap_err();
        assert_eq!(e.field, "screens.condition_instructions.P");
        assert!(e.message.contains("runs V, D"), "{}", e.message);
    }

    #[test]
    fn counter_positions() {
        use Condition::{D, P, V};
        let order = [P, D, V];
        assert_eq!(
            position(key(Phase::Test, D, 4), &order, 10, 3),
            (4, 10, 2, 3)
        );
        assert_eq!(
            position(key(Phase::Practice, V, 2), &order, 10, 3),
            (2, 3, 0, 3)
        );
    }
}
