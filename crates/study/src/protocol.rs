//! Study protocol files (TOML).
//!
//! A protocol fixes everything a session runner needs: the conditions, the
//! number of participants, trials per session, the training block, the task
//! and its parameters, tolerances, counterbalancing and the study seed. Files
//! are parsed with serde (`deny_unknown_fields` everywhere) and validated on
//! load; every error names the file, the line and column (from toml's spans)
//! and the field. The format, with every key, unit and default, is documented
//! in `docs/theory/statistics.md` (protocol files).
//!
//! Built-in protocols are embedded with `include_str!` so the binary needs no
//! files: [`PAPER_TOML`] (the paper's validation experiment, §4.3) and
//! [`BLIND_TOML`] (blind navigation, §4.2).

use std::fmt;
use std::path::Path;

use kilotouch_rig::toml_location::{field_at, line_col, locate, researcher_words};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::counterbalance::{self, BalanceReport, CounterbalanceError};

/// The paper's circling experiment: 8 participants × 3 sessions (V, P, D) ×
/// 10 trials.
pub const PAPER_TOML: &str = include_str!("../../../assets/protocols/paper.toml");

/// Blind navigation (§4.2): 5 participants, dual-stage condition only.
pub const BLIND_TOML: &str = include_str!("../../../assets/protocols/blind.toml");

/// Names of the built-in protocols accepted by [`Protocol::builtin`].
pub const BUILTIN_NAMES: [&str; 2] = ["paper", "blind"];

// ------------------------------------------------------------------ errors

/// Where in a protocol file something went wrong.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    /// File name (or `<builtin:paper>` etc.).
    pub file: String,
    /// 1-based line, when known.
    pub line: Option<usize>,
    /// 1-based column (characters), when known.
    pub column: Option<usize>,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
            if let Some(col) = self.column {
                write!(f, ":{col}")?;
            }
        }
        Ok(())
    }
}

/// A semantic problem found by [`Protocol::validate`].
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("field `{field}`: {message}")]
pub struct Invalid {
    /// Dotted path of the field, e.g. `task.circling.timeout_s` or
    /// `conditions[2]`.
    pub field: String,
    /// What is wrong and what is expected.
    pub message: String,
}

/// Errors of loading a protocol.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum ProtocolError {
    /// The file cannot be read.
    #[error("{file}: cannot read protocol: {source}")]
    Io {
        /// File name.
        file: String,
        /// Underlying I/O error.
        source: std::io::Error,
    },
    /// TOML syntax error or a type / unknown-key error from deserialisation.
    #[error("{location}: {}{message}", field.as_ref().map(|f| format!("field `{f}`: ")).unwrap_or_default())]
    Parse {
        /// Where.
        location: Location,
        /// Field path at the error position, when it can be determined.
        field: Option<String>,
        /// toml's message (e.g. "unknown field `foo`, expected one of …").
        message: String,
    },
    /// The file parses but a value is out of range or inconsistent.
    #[error("{location}: {invalid}")]
    Invalid {
        /// Where (the offending value, or its table when the key is
        /// missing).
        location: Location,
        /// Field and message.
        invalid: Invalid,
    },
    /// Unknown built-in protocol name.
    #[error("unknown built-in protocol `{0}` (expected one of: paper, blind)")]
    UnknownBuiltin(String),
    /// Counterbalancing failed (cannot happen for a validated protocol).
    #[error("counterbalancing: {0}")]
    Counterbalance(#[from] CounterbalanceError),
}

// ------------------------------------------------------------------ types

/// An experimental condition (paper §4.3): the rig crate's, the one type
/// from the protocol file to the actuators.
pub use kilotouch_rig::condition::Condition;

fn default_conditions() -> Vec<Condition> {
    Condition::ALL.to_vec()
}

fn default_trials() -> u32 {
    10
}

/// The training block run before the measured sessions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Training {
    /// Practice trials per condition (0 = no training). Default 3.
    pub practice_trials: u32,
    /// Extra practice trials per condition that may replace practice
    /// trials whose row is not a success (rejected, e.g. `escaped` or
    /// `timeout`, or `aborted` by the emergency stop), so the participant
    /// gets `practice_trials` good ones before the test sessions, as a
    /// PsychoPy loop that repeats failed trials does. Each unsuccessful
    /// practice row adds one extra trial (numbered after the protocol's
    /// practice trials, with its own seed) while fewer than
    /// `practice_retries` were added for that condition. Default 0 (a
    /// protocol file without the key runs exactly `practice_trials`, as
    /// before; the key is then also left out of the protocol's text, so a
    /// study's recorded protocol identity does not change). At most
    /// [`MAX_PRACTICE_TRIALS`].
    #[serde(skip_serializing_if = "is_zero")]
    pub practice_retries: u32,
    /// Upper bound of the training block, minutes (the paper: 10–15 min).
    /// Default 15.
    pub max_duration_min: f64,
}

impl Default for Training {
    fn default() -> Self {
        Self {
            practice_trials: 3,
            practice_retries: 0,
            max_duration_min: 15.0,
        }
    }
}

/// Serde's `skip_serializing_if` for counts whose default is 0.
#[allow(clippy::trivially_copy_pass_by_ref)] // serde passes a reference
fn is_zero(n: &u32) -> bool {
    *n == 0
}

/// Circling task (§4.3): keep the manipulated bead in contact with a fixed
/// spherical obstacle while going around it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CirclingTask {
    /// Obstacle radius, µm. Default 5 (the paper's 10 µm glass beads).
    pub obstacle_radius_um: f64,
    /// Manipulated (trapped) bead radius, µm. Default 1.5 (3 µm bead).
    pub bead_radius_um: f64,
    /// Trial time-out, s. Default 120.
    pub timeout_s: f64,
    /// Minimum fraction of the trajectory in contact for a successful trial
    /// (the paper rejects trials with contact ≤ 50 %). Default 0.5.
    pub min_contact_fraction: f64,
    /// Bead-to-trap-centre distance beyond which the bead has escaped the
    /// trap (trial failed), µm. Default 1.5 (one bead radius).
    pub escape_distance_um: f64,
    /// Revolutions around the obstacle that complete a trial. Default 1.
    pub revolutions: f64,
}

impl Default for CirclingTask {
    fn default() -> Self {
        Self {
            obstacle_radius_um: 5.0,
            bead_radius_um: 1.5,
            timeout_s: 120.0,
            min_contact_fraction: 0.5,
            escape_distance_um: 1.5,
            revolutions: 1.0,
        }
    }
}

/// Blind navigation task (§4.2): without vision, move the bead until it is
/// felt to touch the obstacle, then retreat along the surface normal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BlindNavigationTask {
    /// Obstacle radius, µm. Default 5.
    pub obstacle_radius_um: f64,
    /// Manipulated bead radius, µm. Default 1.5.
    pub bead_radius_um: f64,
    /// Surface-to-surface gap between bead and obstacle at the start, µm.
    /// Default 10.
    pub start_distance_um: f64,
    /// Largest angle between the retreat direction and the surface normal
    /// at contact that counts as success, degrees. Default 30.
    pub success_angle_deg: f64,
    /// Distance moved away from the contact point that ends the trial, µm.
    /// Default 3.
    pub retreat_distance_um: f64,
    /// Trial time-out, s. Default 120.
    pub timeout_s: f64,
    /// Escape distance from the trap centre, µm. Default 1.5.
    pub escape_distance_um: f64,
}

impl Default for BlindNavigationTask {
    fn default() -> Self {
        Self {
            obstacle_radius_um: 5.0,
            bead_radius_um: 1.5,
            start_distance_um: 10.0,
            success_angle_deg: 30.0,
            retreat_distance_um: 3.0,
            timeout_s: 120.0,
            escape_distance_um: 1.5,
        }
    }
}

/// The task of a protocol; in TOML exactly one of the tables
/// `[task.circling]` or `[task.blind_navigation]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Task {
    /// See [`CirclingTask`].
    Circling(CirclingTask),
    /// See [`BlindNavigationTask`].
    BlindNavigation(BlindNavigationTask),
}

impl Task {
    /// `circling` or `blind_navigation`.
    pub fn kind(&self) -> &'static str {
        match self {
            Task::Circling(_) => "circling",
            Task::BlindNavigation(_) => "blind_navigation",
        }
    }
}

/// Measurement tolerances.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Tolerances {
    /// Bead and obstacle count as in contact when their surfaces are closer
    /// than this, µm. Default 0.2.
    pub contact_gap_um: f64,
}

impl Default for Tolerances {
    fn default() -> Self {
        Self {
            contact_gap_um: 0.2,
        }
    }
}

/// Counterbalancing scheme.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Scheme {
    /// Williams balanced Latin square (see [`crate::counterbalance`]).
    #[default]
    Williams,
    /// Every participant runs the conditions in the listed order.
    Fixed,
}

/// How session orders are assigned.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Counterbalancing {
    /// Scheme. Default `williams`.
    pub scheme: Scheme,
    /// Permute the condition labels onto the square's symbols with the study
    /// seed (Williams only). Default true.
    pub permute_labels: bool,
}

impl Default for Counterbalancing {
    fn default() -> Self {
        Self {
            scheme: Scheme::Williams,
            permute_labels: true,
        }
    }
}

/// Seeds recorded with the study.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Seeds {
    /// Study seed: drives the label permutation (and later the simulated
    /// rig's noise). TOML integers are signed 64-bit, so 0 ≤ seed < 2⁶³ in
    /// files. Default 0.
    pub study: u64,
}

/// A complete study protocol.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Protocol {
    /// Short name of the protocol.
    pub name: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// Number of participants (≥ 1).
    pub participants: u32,
    /// Conditions, one session each. Default `["V", "P", "D"]`.
    #[serde(default = "default_conditions")]
    pub conditions: Vec<Condition>,
    /// Measured trials per session (≥ 1). Default 10.
    #[serde(default = "default_trials")]
    pub trials_per_session: u32,
    /// Training block.
    #[serde(default)]
    pub training: Training,
    /// Task and its parameters.
    pub task: Task,
    /// Tolerances.
    #[serde(default)]
    pub tolerances: Tolerances,
    /// Counterbalancing.
    #[serde(default)]
    pub counterbalance: Counterbalancing,
    /// Seeds.
    #[serde(default)]
    pub seeds: Seeds,
    /// The participant's screens: texts and timings (see
    /// [`crate::screens`]).
    #[serde(default)]
    pub screens: crate::screen_texts::Screens,
}

// -------------------------------------------------------------- validation

fn invalid(field: impl Into<String>, message: impl Into<String>) -> Invalid {
    Invalid {
        field: field.into(),
        message: message.into(),
    }
}

/// Finite and > 0.
/// Most participants in one study folder.
pub const MAX_PARTICIPANTS: u32 = 10_000;
/// Most test trials per condition and participant.
pub const MAX_TRIALS_PER_SESSION: u32 = 10_000;
/// Most practice trials per condition.
pub const MAX_PRACTICE_TRIALS: u32 = 1_000;
/// Most trials (practice and test, every participant and condition) in one
/// study plan: its plan, order table and row index stay in memory.
pub const MAX_PLANNED_TRIALS: u64 = 1_000_000;
/// Longest trial time-out, s.
pub const MAX_TIMEOUT_S: f64 = 600.0;
/// Longest training block, minutes.
pub const MAX_TRAINING_MIN: f64 = 24.0 * 60.0;
/// Most revolutions of a circling trial.
pub const MAX_REVOLUTIONS: f64 = 1_000.0;
/// How far from its start a trial may take the bead, µm: the trap's reach
/// in the built-in rig file (`[coupling] trap_min_m`, `trap_max_m` =
/// ±20 µm around the start). A task's geometry must fit within it.
pub const SCENE_REACH_UM: f64 = 20.0;
/// Surface gap between the bead and the obstacle at the start of a
/// circling trial, m (the participant first approaches the obstacle).
pub const CIRCLING_START_GAP_M: f64 = 2.0e-6;

/// A count in `1 ..= max`.
fn count_in(field: &str, v: u32, min: u32, max: u32) -> Result<(), Invalid> {
    if v < min {
        return Err(invalid(field, format!("must be at least {min}, got {v}")));
    }
    if v > max {
        return Err(invalid(field, format!("must be at most {max}, got {v}")));
    }
    Ok(())
}

/// A positive, finite value no larger than `max`.
fn positive_at_most(field: &str, v: f64, max: f64, unit: &str) -> Result<(), Invalid> {
    positive(field, v, unit)?;
    if v > max {
        return Err(invalid(
            field,
            format!("must be at most {max} {unit}, got {v}"),
        ));
    }
    Ok(())
}

fn positive(field: &str, v: f64, unit: &str) -> Result<(), Invalid> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(invalid(
            field,
            format!("must be a positive, finite number of {unit}, got {v}"),
        ))
    }
}

fn check_bead_obstacle(prefix: &str, obstacle: f64, bead: f64, escape: f64) -> Result<(), Invalid> {
    for (field, v) in [
        ("obstacle_radius_um", obstacle),
        ("bead_radius_um", bead),
        ("escape_distance_um", escape),
    ] {
        positive_at_most(&format!("{prefix}.{field}"), v, SCENE_REACH_UM, "µm")?;
    }
    Ok(())
}

/// A task's time limit `timeout_s` (s): positive, at most [`MAX_TIMEOUT_S`];
/// `prefix` is the task's table, e.g. `task.circling`.
fn check_timeout(prefix: &str, timeout_s: f64) -> Result<(), Invalid> {
    positive_at_most(
        &format!("{prefix}.timeout_s"),
        timeout_s,
        MAX_TIMEOUT_S,
        "seconds",
    )
}

/// A task whose bead must go `extent` µm from its start (computed by
/// `how`) fits the scene ([`SCENE_REACH_UM`]); `field` is the value to
/// change.
fn fits_scene(field: String, extent: f64, how: &str) -> Result<(), Invalid> {
    if extent <= SCENE_REACH_UM {
        return Ok(());
    }
    Err(invalid(
        field,
        format!(
            "the bead would have to go {extent} µm from its start ({how}), beyond the scene's \
             reach of {SCENE_REACH_UM} µm (the trap's range)"
        ),
    ))
}

impl Protocol {
    /// Checks ranges and consistency (first problem found).
    ///
    /// # Errors
    /// [`Invalid`] naming the field: empty name, zero participants or
    /// trials, no / duplicate conditions, V in a blind task, non-positive
    /// radii, distances or time-outs, contact fraction outside (0, 1],
    /// success angle outside (0, 90], negative tolerance, a geometry that
    /// does not fit the scene ([`SCENE_REACH_UM`]).
    pub fn validate(&self) -> Result<(), Invalid> {
        if self.name.trim().is_empty() {
            return Err(invalid("name", "must not be empty"));
        }
        count_in("participants", self.participants, 1, MAX_PARTICIPANTS)?;
        count_in(
            "trials_per_session",
            self.trials_per_session,
            1,
            MAX_TRIALS_PER_SESSION,
        )?;
        count_in(
            "training.practice_trials",
            self.training.practice_trials,
            0,
            MAX_PRACTICE_TRIALS,
        )?;
        count_in(
            "training.practice_retries",
            self.training.practice_retries,
            0,
            MAX_PRACTICE_TRIALS,
        )?;
        if self.conditions.is_empty() {
            return Err(invalid(
                "conditions",
                "must list at least one condition (V, P, D)",
            ));
        }
        for (i, c) in self.conditions.iter().enumerate() {
            if self.conditions[..i].contains(c) {
                return Err(invalid(
                    format!("conditions[{i}]"),
                    format!("duplicate condition `{c}`"),
                ));
            }
        }
        let practice =
            u64::from(self.training.practice_trials) + u64::from(self.training.practice_retries);
        let planned = u64::from(self.participants)
            * self.conditions.len() as u64
            * (u64::from(self.trials_per_session) + practice);
        if planned > MAX_PLANNED_TRIALS {
            return Err(invalid(
                "participants",
                format!(
                    "{} participants × {} condition(s) × ({} test + {practice} practice, \
                     extra practice included) trials = {planned} trials, more than the \
                     {MAX_PLANNED_TRIALS} a study may plan",
                    self.participants,
                    self.conditions.len(),
                    self.trials_per_session,
                ),
            ));
        }
        positive_at_most(
            "training.max_duration_min",
            self.training.max_duration_min,
            MAX_TRAINING_MIN,
            "minutes",
        )?;
        self.validate_task()?;
        let gap = self.tolerances.contact_gap_um;
        if !(gap.is_finite() && (0.0..=SCENE_REACH_UM).contains(&gap)) {
            return Err(invalid(
                "tolerances.contact_gap_um",
                format!(
                    "must be a non-negative distance of at most {SCENE_REACH_UM} µm (the \
                     scene's reach), got {gap}"
                ),
            ));
        }
        self.screens.validate(&self.conditions)?;
        Ok(())
    }

    /// The task's values: positive, bounded and fitting the scene
    /// ([`SCENE_REACH_UM`]).
    fn validate_task(&self) -> Result<(), Invalid> {
        let (p, obstacle, bead, escape) = match &self.task {
            Task::Circling(t) => (
                "task.circling",
                t.obstacle_radius_um,
                t.bead_radius_um,
                t.escape_distance_um,
            ),
            Task::BlindNavigation(t) => (
                "task.blind_navigation",
                t.obstacle_radius_um,
                t.bead_radius_um,
                t.escape_distance_um,
            ),
        };
        check_bead_obstacle(p, obstacle, bead, escape)?;
        match &self.task {
            Task::Circling(t) => {
                check_timeout(p, t.timeout_s)?;
                positive_at_most(
                    &format!("{p}.revolutions"),
                    t.revolutions,
                    MAX_REVOLUTIONS,
                    "revolutions",
                )?;
                let rc = t.obstacle_radius_um + t.bead_radius_um;
                let radius = if t.bead_radius_um > t.obstacle_radius_um {
                    "bead_radius_um"
                } else {
                    "obstacle_radius_um"
                };
                fits_scene(
                    format!("{p}.{radius}"),
                    2.0 * rc + CIRCLING_START_GAP_M * 1e6,
                    "twice the contact radius R_o + R_b plus the 2 µm start gap",
                )?;
                if !(t.min_contact_fraction > 0.0 && t.min_contact_fraction <= 1.0) {
                    return Err(invalid(
                        format!("{p}.min_contact_fraction"),
                        format!("must be in (0, 1], got {}", t.min_contact_fraction),
                    ));
                }
            }
            Task::BlindNavigation(t) => {
                positive(&format!("{p}.start_distance_um"), t.start_distance_um, "µm")?;
                positive(
                    &format!("{p}.retreat_distance_um"),
                    t.retreat_distance_um,
                    "µm",
                )?;
                fits_scene(
                    format!("{p}.start_distance_um"),
                    t.start_distance_um + t.retreat_distance_um,
                    "start_distance_um to the contact, then retreat_distance_um",
                )?;
                fits_scene(
                    format!("{p}.start_distance_um"),
                    t.obstacle_radius_um + t.bead_radius_um + t.start_distance_um,
                    "to the obstacle's centre: R_o + R_b + start_distance_um",
                )?;
                check_timeout(p, t.timeout_s)?;
                if !(t.success_angle_deg > 0.0 && t.success_angle_deg <= 90.0) {
                    return Err(invalid(
                        format!("{p}.success_angle_deg"),
                        format!("must be in (0, 90] degrees, got {}", t.success_angle_deg),
                    ));
                }
                if let Some(i) = self.conditions.iter().position(|&c| !c.haptic()) {
                    return Err(invalid(
                        format!("conditions[{i}]"),
                        "condition `V` (vision only) gives no feedback at all in a blind \
                     navigation task; use P and/or D",
                    ));
                }
            }
        }
        Ok(())
    }

    /// Parses and validates a protocol from TOML text; `origin` (file name)
    /// is used in error messages.
    ///
    /// # Errors
    /// [`ProtocolError::Parse`] (syntax, unknown key, wrong type, unknown
    /// condition code, negative integer, …) or [`ProtocolError::Invalid`],
    /// both with file, line, column and field.
    pub fn from_toml_str(src: &str, origin: &str) -> Result<Self, ProtocolError> {
        let protocol: Protocol = match toml::from_str(src) {
            Ok(p) => p,
            Err(e) => {
                let span = e.span();
                let (line, column) = span
                    .as_ref()
                    .map_or((None, None), |s| line_col(src, s.start));
                let field = span.and_then(|s| field_at(src, s.start));
                return Err(ProtocolError::Parse {
                    location: Location {
                        file: origin.to_owned(),
                        line,
                        column,
                    },
                    field,
                    message: researcher_words(e.message()),
                });
            }
        };
        if let Err(inv) = protocol.validate() {
            let (line, column) =
                locate(src, &inv.field).map_or((None, None), |offset| line_col(src, offset));
            return Err(ProtocolError::Invalid {
                location: Location {
                    file: origin.to_owned(),
                    line,
                    column,
                },
                invalid: inv,
            });
        }
        Ok(protocol)
    }

    /// Reads, parses and validates a protocol file.
    ///
    /// # Errors
    /// I/O errors and those of [`Protocol::from_toml_str`].
    pub fn load(path: &Path) -> Result<Self, ProtocolError> {
        let file = path.display().to_string();
        let src =
            kilotouch_rig::input::read_text_capped(path, kilotouch_rig::input::MAX_CONFIG_BYTES)
                .map_err(|source| ProtocolError::Io {
                    file: file.clone(),
                    source,
                })?;
        Self::from_toml_str(&src, &file)
    }

    /// A built-in protocol by name (`paper` or `blind`).
    ///
    /// # Errors
    /// [`ProtocolError::UnknownBuiltin`]; parse errors cannot occur for the
    /// shipped files (tested).
    pub fn builtin(name: &str) -> Result<Self, ProtocolError> {
        match name {
            "paper" => Self::from_toml_str(PAPER_TOML, "<builtin:paper>"),
            "blind" => Self::from_toml_str(BLIND_TOML, "<builtin:blind>"),
            other => Err(ProtocolError::UnknownBuiltin(other.to_owned())),
        }
    }

    /// The paper's protocol ([`PAPER_TOML`]).
    ///
    /// # Errors
    /// None in practice (the embedded file is tested).
    pub fn paper() -> Result<Self, ProtocolError> {
        Self::builtin("paper")
    }

    /// The protocol as TOML (for recording with the session data). Loading
    /// the output gives back an equal protocol.
    ///
    /// # Errors
    /// Serialisation failure (e.g. a non-finite float).
    pub fn to_toml_string(&self) -> Result<String, toml::ser::Error> {
        toml::to_string(self)
    }

    /// Sessions per participant (one per condition).
    pub fn sessions(&self) -> usize {
        self.conditions.len()
    }

    /// Total measured trials: participants × sessions × trials per session.
    pub fn total_trials(&self) -> u64 {
        u64::from(self.participants) * self.sessions() as u64 * u64::from(self.trials_per_session)
    }

    /// Assignment table: participant → session order.
    ///
    /// Williams scheme: square over the listed conditions, labels permuted
    /// with `seeds.study` when `permute_labels`, participant i → row i mod
    /// rows. Fixed scheme: every participant gets the listed order.
    ///
    /// # Errors
    /// Only for an invalid protocol (no condition or participant).
    pub fn assignment(&self) -> Result<AssignmentTable, ProtocolError> {
        let n = self.conditions.len();
        let participants = self.participants as usize;
        let (plan_seed, square, assignments, report) = match self.counterbalance.scheme {
            Scheme::Williams => {
                let seed = self
                    .counterbalance
                    .permute_labels
                    .then_some(self.seeds.study);
                let plan = counterbalance::plan(n, participants, seed)?;
                (seed, plan.square, plan.assignments, plan.report)
            }
            Scheme::Fixed => {
                let square = counterbalance::fixed(n)?;
                if participants == 0 {
                    return Err(CounterbalanceError::NoParticipants.into());
                }
                let assignments: Vec<_> = (0..participants)
                    .map(|i| counterbalance::Assignment {
                        participant: i,
                        row: 0,
                        order: (0..n).collect(),
                    })
                    .collect();
                let report = counterbalance::balance_report(&square, &assignments);
                (None, square, assignments, report)
            }
        };
        let labels: Vec<&str> = self.conditions.iter().map(|c| c.code()).collect();
        let width = participants.to_string().len().max(2);
        let rows = assignments
            .iter()
            .map(|a| ParticipantSessions {
                participant: a.participant,
                id: format!("P{:0width$}", a.participant + 1),
                row: a.row,
                sessions: a.order.iter().map(|&c| self.conditions[c]).collect(),
            })
            .collect();
        Ok(AssignmentTable {
            protocol: self.name.clone(),
            scheme: self.counterbalance.scheme,
            seed: plan_seed,
            conditions: self.conditions.clone(),
            orders: square
                .rows()
                .iter()
                .map(|r| r.iter().map(|&c| self.conditions[c]).collect())
                .collect(),
            summary: report.describe(&labels),
            participants: rows,
            report,
        })
    }
}

/// One participant's session order.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ParticipantSessions {
    /// 0-based participant index.
    pub participant: usize,
    /// Display id, `P01`, `P02`, … (1-based).
    pub id: String,
    /// Row of the counterbalancing square.
    pub row: usize,
    /// Conditions in session order.
    pub sessions: Vec<Condition>,
}

/// Participant → session order table of a protocol.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct AssignmentTable {
    /// Protocol name.
    pub protocol: String,
    /// Scheme used.
    pub scheme: Scheme,
    /// Seed of the label permutation, if one was applied.
    pub seed: Option<u64>,
    /// Conditions as listed in the protocol.
    pub conditions: Vec<Condition>,
    /// All orders (rows) of the square, relabelled.
    pub orders: Vec<Vec<Condition>>,
    /// One row per participant.
    pub participants: Vec<ParticipantSessions>,
    /// Balance report (indices refer to `conditions`).
    pub report: BalanceReport,
    /// Human summary of the balance.
    pub summary: String,
}
