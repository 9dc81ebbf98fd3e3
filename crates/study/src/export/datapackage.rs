//! `datapackage.json`: the study folder as a Frictionless **Tabular Data
//! Package** (<https://specs.frictionlessdata.io/tabular-data-package/>),
//! the machine-readable data dictionary of `trials.csv`, `cells_long.csv`
//! and `cells_wide.csv`.
//!
//! Every field has its Table Schema `type`, a `description` that states its
//! unit, `constraints` (required, ranges, enumerations, patterns), and the
//! schemas declare `missingValues` (`""`: NA is an empty cell) and a
//! `primaryKey`. The file is written by [`super::regenerate_summaries`] —
//! whenever the summaries are, so at the end of every session
//! (`StudyStore::close`), by `kilotouch study simulate` and by the Results
//! page — from the same summary as the CSV headers
//! ([`super::Summary::value_columns`]), so the two cannot disagree. `frictionless validate datapackage.json` checks a folder
//! against it (CI does so on a simulated study).

use std::path::Path;

use serde_json::{Map, Value, json};

use super::trials::{Metric, TRIALS_COLUMNS, TRIALS_FILE};
use crate::protocol::Condition;
use crate::storage::error::Result;
use crate::storage::fsutil::write_atomic;

/// File name of the data package descriptor.
pub const DATAPACKAGE_FILE: &str = "datapackage.json";

/// Table Schema `missingValues` of every resource: an empty cell is NA.
const MISSING: [&str; 1] = [""];

fn field(name: &str, ty: &str, description: &str, constraints: Value) -> Value {
    let mut f = Map::new();
    f.insert("name".into(), name.into());
    f.insert("type".into(), ty.into());
    f.insert("description".into(), description.into());
    if constraints.as_object().is_some_and(|c| !c.is_empty()) {
        f.insert("constraints".into(), constraints);
    }
    Value::Object(f)
}

fn boolean(name: &str, description: &str, required: bool) -> Value {
    let mut f = field(
        name,
        "boolean",
        description,
        if required {
            json!({"required": true})
        } else {
            json!({})
        },
    );
    f["trueValues"] = json!(["1"]);
    f["falseValues"] = json!(["0"]);
    f
}

/// Description and range of a metric (the unit is in the description).
fn metric_field(name: &str, m: Metric, what: &str) -> Value {
    let unit = match m.unit() {
        "1" => "dimensionless, 0–1".to_owned(),
        u => format!("unit: {u}"),
    };
    let meaning = match m {
        Metric::TimeS => "manipulation time",
        Metric::ForceMeanPn => "mean magnitude of the optical force on the bead",
        Metric::ForceMeanN => "mean magnitude of the force rendered at the hand",
        Metric::DispErrMeanUm => {
            "mean displacement error from the task's reference trajectory (circling: \
             mean |gap| to the contact circle)"
        }
        Metric::ContactFraction => "fraction of the trajectory with bead and obstacle in contact",
        Metric::TimeToCollisionS => "blind navigation: time to the first contact",
        Metric::PeakForcePn => "blind navigation: peak optical force at the collision",
        Metric::RetreatAngleErrDeg => {
            "blind navigation: angle between the retreat direction and the surface normal"
        }
    };
    let constraints = match m {
        Metric::ContactFraction => json!({"minimum": 0, "maximum": 1}),
        Metric::RetreatAngleErrDeg => json!({"minimum": 0, "maximum": 180}),
        _ => json!({"minimum": 0}),
    };
    field(
        name,
        "number",
        &format!("{meaning} ({unit}){what}; empty = NA (not defined)"),
        constraints,
    )
}

/// The field descriptor of `trials.csv` column `name`.
fn trials_field(name: &str) -> Value {
    if let Some(m) = Metric::from_column(name) {
        return metric_field(name, m, "");
    }
    let req = json!({"required": true});
    match name {
        "participant" => field(
            name,
            "string",
            "participant id (P01, P02, …)",
            json!({"required": true, "pattern": "[^,\\s]+"}),
        ),
        "session_index" => field(
            name,
            "integer",
            "1-based position of this condition's session in the participant's order; 0 for \
             practice trials (count, no unit)",
            json!({"required": true, "minimum": 0}),
        ),
        "session_order" => field(
            name,
            "string",
            "the participant's condition order, e.g. VDP",
            json!({"required": true, "pattern": "[VPD]+"}),
        ),
        "condition" => field(
            name,
            "string",
            "V = vision only, P = + Pantograph, D = + dual-stage (paper §4.3)",
            json!({"required": true, "enum": ["V", "P", "D"]}),
        ),
        "phase" => field(
            name,
            "string",
            "practice = training trial (not analysed by default), test = measured trial",
            json!({"required": true, "enum": ["practice", "test"]}),
        ),
        "trial" => field(
            name,
            "integer",
            "1-based trial number within (participant, condition, phase)",
            json!({"required": true, "minimum": 1}),
        ),
        "task" => field(
            name,
            "string",
            "task of the protocol",
            json!({"required": true, "enum": ["circling", "blind_navigation"]}),
        ),
        "success" => boolean(
            name,
            "1 = trial not rejected, 0 = rejected (see reject_reason); analyses use success = 1 \
             by default",
            true,
        ),
        "reject_reason" => field(
            name,
            "string",
            "empty when success = 1; otherwise why the trial was rejected (escaped, \
             low_contact, timeout, no_collision, retreat_angle)",
            json!({}),
        ),
        "seed" => field(
            name,
            "string",
            "trial seed, 0x + 16 hexadecimal digits (text, so no reader rounds it)",
            json!({"required": true, "pattern": "0x[0-9a-f]{16}"}),
        ),
        "started_utc" => field(
            name,
            "string",
            "start of the trial, UTC, ISO 8601 with milliseconds (YYYY-MM-DDTHH:MM:SS.mmmZ)",
            json!({"required": true,
                   "pattern": "[0-9]{4}-[0-9]{2}-[0-9]{2}T[0-9]{2}:[0-9]{2}:[0-9]{2}\\.[0-9]{3}Z"}),
        ),
        "escaped" => boolean(
            name,
            "circling: 1 = the bead left the trap; empty for blind navigation",
            false,
        ),
        "raw_file" => field(
            name,
            "string",
            "raw-signal file (NPY + JSON sidecar naming channels and units), relative to the \
             folder: `raw/…npy`; `recovery/quarantine/<time>-…npy` when the file failed its \
             check (size, header, CRC-32) on a resume and was moved there — its signals are not \
             to be trusted; empty if none was recorded, or if it was missing on a resume (the \
             journal's `raw_quarantined` record names it)",
            json!({"pattern": "(raw|recovery/quarantine)/[^/]+\\.npy"}),
        ),
        "row_crc32" => field(
            name,
            "string",
            "CRC-32 of the line up to its last comma (integrity check; ignore in analyses)",
            json!({"required": true, "pattern": "[0-9a-f]{8}"}),
        ),
        _ => field(name, "any", "", req),
    }
}

/// Descriptor of a value column of the summaries (`cells_long.csv` name;
/// `suffix` tells the wide file's condition).
fn cell_field(name: &str, column: &str, suffix: &str) -> Value {
    if let Some(m) = Metric::from_column(column) {
        return metric_field(
            name,
            m,
            &format!("; mean over the cell's successful test trials{suffix}"),
        );
    }
    match column {
        "session_index" => field(
            name,
            "integer",
            &format!("position of the condition's session for the participant{suffix}"),
            json!({"minimum": 1}),
        ),
        "n_trials" => field(
            name,
            "integer",
            &format!("test trials in the cell (count){suffix}"),
            json!({"minimum": 0}),
        ),
        "n_success" => field(
            name,
            "integer",
            &format!("successful test trials (count){suffix}"),
            json!({"minimum": 0}),
        ),
        "success_rate" => field(
            name,
            "number",
            &format!("n_success / n_trials (dimensionless, 0–1){suffix}"),
            json!({"minimum": 0, "maximum": 1}),
        ),
        "n_escaped" => field(
            name,
            "integer",
            &format!("test trials with escaped = 1 (count); empty = NA{suffix}"),
            json!({"minimum": 0}),
        ),
        _ => field(name, "any", suffix, json!({})),
    }
}

fn participant_field() -> Value {
    field(
        "participant",
        "string",
        "participant id",
        json!({"required": true}),
    )
}

fn resource(name: &str, path: &str, description: &str, fields: Vec<Value>, key: &[&str]) -> Value {
    json!({
        "name": name,
        "path": path,
        "profile": "tabular-data-resource",
        "format": "csv",
        "mediatype": "text/csv",
        "encoding": "utf-8",
        "description": description,
        "dialect": {"delimiter": ",", "lineTerminator": "\n", "header": true},
        "schema": {
            "fields": fields,
            "missingValues": MISSING,
            "primaryKey": key,
        },
    })
}

/// What the summary tables hold: their file names, value columns (after
/// `participant`, `condition`) and conditions (the wide file's suffixes),
/// as [`super::Summary`] writes them.
#[derive(Debug, Clone, Copy)]
pub struct SummaryLayout<'a> {
    /// File name of the long summary.
    pub long_file: &'a str,
    /// File name of the wide summary.
    pub wide_file: &'a str,
    /// Value columns of the long file, in order.
    pub value_columns: &'a [String],
    /// Conditions, in the wide file's order.
    pub conditions: &'a [Condition],
}

/// The descriptor of a study folder whose summaries have `layout`.
pub fn descriptor(layout: SummaryLayout<'_>, title: &str) -> Value {
    let trials = resource(
        "trials",
        TRIALS_FILE,
        "one row per finished trial (practice and test, successful and rejected)",
        TRIALS_COLUMNS.iter().map(|c| trials_field(c)).collect(),
        &["participant", "condition", "phase", "trial"],
    );
    let mut long_fields = vec![
        participant_field(),
        field(
            "condition",
            "string",
            "V, P or D",
            json!({"required": true, "enum": ["V", "P", "D"]}),
        ),
    ];
    long_fields.extend(layout.value_columns.iter().map(|c| cell_field(c, c, "")));
    let long = resource(
        "cells_long",
        layout.long_file,
        "participant × condition means of the test trials (metrics over successful ones)",
        long_fields,
        &["participant", "condition"],
    );
    let mut wide_fields = vec![participant_field()];
    for col in layout.value_columns {
        for c in layout.conditions {
            wide_fields.push(cell_field(
                &format!("{col}_{c}"),
                col,
                &format!(" (condition {c})"),
            ));
        }
    }
    let wide = resource(
        "cells_wide",
        layout.wide_file,
        "one row per participant, one column per value × condition (JASP layout)",
        wide_fields,
        &["participant"],
    );
    json!({
        "profile": "tabular-data-package",
        "name": "kilotouch-study",
        "title": title,
        "description": "A kilotouch study folder (docs/STUDY.md). Raw per-trial signals are in \
                        raw/ as NPY files with JSON sidecars naming channels and units.",
        "resources": [trials, long, wide],
    })
}

/// Writes `dir/datapackage.json` (atomically) for summaries of `layout`.
///
/// # Errors
/// I/O errors.
pub fn write_datapackage(dir: &Path, layout: SummaryLayout<'_>, title: &str) -> Result<()> {
    let mut text = serde_json::to_string_pretty(&descriptor(layout, title)).unwrap_or_default();
    text.push('\n');
    write_atomic(&dir.join(DATAPACKAGE_FILE), text.as_bytes())
}
