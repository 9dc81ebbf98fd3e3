//! The plan of a study: every trial of a protocol in run order
//! ([`PlannedTrial`], [`plan`]) and where each trial's raw file goes.

use super::session::OrderRow;
use super::trials::{TaskKind, TrialRow};
use crate::protocol::Protocol;
use crate::rawsig::RawLayout;
use crate::seeds::{Phase, TrialKey, format_seed};
use crate::storage::utc::UtcTime;

/// Folder of the raw-signal files.
pub const RAW_DIR: &str = "raw";

/// One trial of the protocol's plan, with the identity columns of its row.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlannedTrial {
    /// Identity.
    pub key: TrialKey,
    /// Participant id (`P01`).
    pub participant: String,
    /// `session_index` column (0 for practice).
    pub session_index: u32,
    /// `session_order` column.
    pub session_order: String,
    /// Trial seed.
    pub seed: u64,
}

impl PlannedTrial {
    /// A row with the identity columns filled (participant, session, order,
    /// condition, phase, trial, task, seed, start time, raw file) and every
    /// result empty: `success = false`, metrics NA.
    pub fn blank_row(&self, task: TaskKind, started_utc: UtcTime, raw_file: String) -> TrialRow {
        TrialRow {
            participant: self.participant.clone(),
            session_index: self.session_index,
            session_order: self.session_order.clone(),
            condition: self.key.condition,
            phase: self.key.phase,
            trial: self.key.trial,
            task,
            success: false,
            reject_reason: String::new(),
            time_s: None,
            force_mean_pn: None,
            force_mean_n: None,
            disp_err_mean_um: None,
            contact_fraction: None,
            seed: self.seed,
            started_utc,
            escaped: None,
            time_to_collision_s: None,
            peak_force_pn: None,
            retreat_angle_err_deg: None,
            raw_file,
        }
    }
}

/// Plan of a protocol: for each participant in index order, the practice
/// block (each condition in the participant's order, `training.practice_trials`
/// trials each), then the test sessions in the participant's order
/// (`trials_per_session` trials each).
pub fn plan(protocol: &Protocol, orders: &[OrderRow]) -> Vec<PlannedTrial> {
    let seed = protocol.seeds.study;
    let mut out = Vec::new();
    for o in orders {
        let order = o.order_string();
        let mut push = |key: TrialKey, session_index: u32| {
            out.push(PlannedTrial {
                key,
                participant: o.participant.clone(),
                session_index,
                session_order: order.clone(),
                seed: key.seed(seed),
            });
        };
        for &c in &o.sessions {
            for t in 1..=protocol.training.practice_trials {
                push(TrialKey::new(o.index, c, Phase::Practice, t), 0);
            }
        }
        for (i, &c) in o.sessions.iter().enumerate() {
            for t in 1..=protocol.trials_per_session {
                push(
                    TrialKey::new(o.index, c, Phase::Test, t),
                    u32::try_from(i + 1).unwrap_or(u32::MAX),
                );
            }
        }
    }
    out
}

/// The extra practice trial a practice row that is not a success earns
/// (`training.practice_retries`, [`crate::protocol::Training`]): where it
/// goes in `plan` (right after the last practice trial of the same
/// participant and condition, so the participant practises that condition
/// again before the next block) and the trial, numbered after the cell's
/// last practice trial, with its own seed. `None` when `failed` is not a
/// practice trial of `plan` or its condition's extra trials are used up.
///
/// Applying this once per unsuccessful practice row, in any order, gives
/// the same plan: a resumed folder rebuilds its extra trials from the rows
/// of `trials.csv`.
pub fn practice_retry(
    protocol: &Protocol,
    plan: &[PlannedTrial],
    failed: TrialKey,
) -> Option<(usize, PlannedTrial)> {
    if failed.phase != Phase::Practice {
        return None;
    }
    let same_cell = |p: &PlannedTrial| {
        p.key.participant == failed.participant
            && p.key.condition == failed.condition
            && p.key.phase == Phase::Practice
    };
    let last = plan.iter().rposition(same_cell)?;
    let in_cell = plan.iter().filter(|p| same_cell(p)).count();
    let extra = u32::try_from(in_cell)
        .ok()?
        .saturating_sub(protocol.training.practice_trials);
    if extra >= protocol.training.practice_retries {
        return None;
    }
    let template = &plan[last];
    let key = TrialKey::new(
        failed.participant,
        failed.condition,
        Phase::Practice,
        template.key.trial.checked_add(1)?,
    );
    Some((
        last + 1,
        PlannedTrial {
            key,
            seed: key.seed(protocol.seeds.study),
            ..template.clone()
        },
    ))
}

/// [`plan`] as a folder whose `trials.csv` holds `rows` has it: with the
/// extra practice trials its unsuccessful practice rows earned
/// ([`extend_with_rows`]). The one way to know a folder's plan (the store,
/// the GUI's folder check and the size estimates use it).
pub fn plan_with_rows(
    protocol: &Protocol,
    orders: &[OrderRow],
    rows: &[TrialRow],
) -> Vec<PlannedTrial> {
    let mut out = plan(protocol, orders);
    extend_with_rows(protocol, orders, &mut out, rows);
    out
}

/// Adds to `plan` the extra practice trials that the unsuccessful practice
/// rows of `rows` earned, as [`super::StudyStore::commit_trial`] added them
/// when those rows were committed ([`practice_retry`]). Rows of unknown
/// participants are left to the reconciliation, which names them.
pub fn extend_with_rows(
    protocol: &Protocol,
    orders: &[OrderRow],
    plan: &mut Vec<PlannedTrial>,
    rows: &[TrialRow],
) {
    if protocol.training.practice_retries == 0 {
        return;
    }
    for row in rows.iter().filter(|r| !r.success) {
        let Some(o) = orders.iter().find(|o| o.participant == row.participant) else {
            continue;
        };
        if let Some((at, extra)) = practice_retry(protocol, plan, row.key(o.index)) {
            plan.insert(at, extra);
        }
    }
}

/// Relative path (with `/`) of a trial's raw file.
pub fn raw_file_name(planned: &PlannedTrial) -> String {
    format!(
        "{RAW_DIR}/{}_{}_{}_{:03}.npy",
        planned.participant, planned.key.condition, planned.key.phase, planned.key.trial
    )
}

/// `layout` with the trial identity added to its attributes (participant,
/// condition, phase, trial, session_index, seed, started_utc), as
/// [`super::StudyStore::raw_writer`] writes it.
pub fn raw_layout_for(
    planned: &PlannedTrial,
    started_utc: UtcTime,
    layout: RawLayout,
) -> RawLayout {
    let mut layout = layout;
    let p = planned;
    let attrs = [
        (
            "participant",
            serde_json::Value::from(p.participant.clone()),
        ),
        ("condition", p.key.condition.code().into()),
        ("phase", p.key.phase.as_str().into()),
        ("trial", p.key.trial.into()),
        ("session_index", p.session_index.into()),
        ("seed", format_seed(p.seed).into()),
        ("started_utc", started_utc.to_string().into()),
    ];
    for (k, v) in attrs {
        layout.attrs.insert(k.to_owned(), v);
    }
    layout
}

impl TrialRow {
    /// Whether the row names raw signals that passed their checks: a file
    /// under [`RAW_DIR`] (not empty, not one moved to
    /// `recovery/quarantine/` because it was damaged).
    pub fn has_trusted_raw(&self) -> bool {
        self.raw_file
            .strip_prefix(RAW_DIR)
            .is_some_and(|rest| rest.starts_with('/'))
    }
}
