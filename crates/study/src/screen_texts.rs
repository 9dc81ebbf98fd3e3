//! The texts and timings of the participant's screens, as the protocol
//! file's `[screens]` table holds them (a leaf module: the protocol embeds
//! it; what the screens do with it is [`crate::screens`]).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Upper bound of [`Screens::iti_s`], s.
pub const MAX_ITI_S: f64 = 60.0;
/// Upper bound of [`Screens::break_min_s`], s.
pub const MAX_BREAK_MIN_S: f64 = 600.0;
/// Upper bound of each text, characters (a screen, not a document).
pub const MAX_TEXT_CHARS: usize = 4000;

/// Default instructions of the circling task.
pub const CIRCLING_INSTRUCTIONS: &str = "Move the handle to bring the small bead \
against the large sphere, then go once around the sphere while keeping the two \
in contact. Move smoothly: if the bead is pulled too hard it escapes the trap \
and the trial ends.";

/// Default instructions of the blind navigation task.
pub const BLIND_INSTRUCTIONS: &str = "You will not see the bead. Move the handle \
until you feel the bead touch the obstacle, then move straight away from it.";

/// Texts and timings of the participant's screens (`[screens]` of a
/// protocol file). Empty `instructions` means the task's default text.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Screens {
    /// Instructions before the first trial of a block (a session, or a
    /// condition of the training block). Default: the task's
    /// ([`CIRCLING_INSTRUCTIONS`], [`BLIND_INSTRUCTIONS`]).
    pub instructions: String,
    /// Extra instructions per condition code (`V`, `P`, `D`), shown after
    /// the general ones when that condition's block begins. Default none
    /// (participants need not know the condition).
    pub condition_instructions: BTreeMap<String, String>,
    /// Added to the instructions before practice trials.
    pub practice: String,
    /// The ready screen (the trial begins on a key or a click).
    pub ready: String,
    /// The break screen between sessions.
    #[serde(rename = "break")]
    pub break_text: String,
    /// The end screen.
    pub end: String,
    /// Inter-trial interval: a blank screen between two trials of a block,
    /// s. Default 1.
    pub iti_s: f64,
    /// Shortest break between sessions before the participant can end it,
    /// s. Default 0.
    pub break_min_s: f64,
    /// Show the trial counter and the block's progress bar during a trial.
    /// Default true.
    pub show_progress: bool,
}

impl Default for Screens {
    fn default() -> Self {
        Self {
            instructions: String::new(),
            condition_instructions: BTreeMap::new(),
            practice: "The first trials are practice: take your time to get used to the handle."
                .into(),
            ready: "Press SPACE or click to start.".into(),
            break_text: "Take a short break. Press SPACE or click when you are ready to go on."
                .into(),
            end: "Thank you! The experiment is over. Please wait for the experimenter.".into(),
            iti_s: 1.0,
            break_min_s: 0.0,
            show_progress: true,
        }
    }
}
