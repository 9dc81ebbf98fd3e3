//! Errors of the power analysis.

use std::path::PathBuf;

use thiserror::Error;

use crate::csvio::CsvError;
use crate::stats::StatsError;

/// Why a power analysis could not run.
#[derive(Debug, Error)]
pub enum PowerError {
    /// The pilot file could not be read, or a cell is malformed (file,
    /// line and column named).
    #[error(transparent)]
    Csv(#[from] CsvError),
    /// A column the analysis needs is not in the header.
    #[error("{}: no {what} column `{column}` (the file has: {})", path.display(), available.join(", "))]
    MissingColumn {
        /// The file.
        path: PathBuf,
        /// Its role.
        what: &'static str,
        /// The name asked for.
        column: String,
        /// The header's names.
        available: Vec<String>,
    },
    /// A condition of the contrast is not in the pilot's analysed rows.
    #[error("condition `{label}` has no analysable test rows in the pilot (conditions in the file: {})", available.join(", "))]
    UnknownCondition {
        /// The label asked for.
        label: String,
        /// The labels in the file.
        available: Vec<String>,
    },
    /// A malformed `--contrast`.
    #[error(
        "--contrast `{0}`: expected two condition labels joined by `-`, e.g. `P-D` (conditions in the pilot: {1})"
    )]
    BadContrast(String, String),
    /// Too few complete participants to estimate the between-participant
    /// variability.
    #[error(
        "the pilot has {got} participant(s) with every analysed condition; at least 2 are needed to estimate how participants vary"
    )]
    TooFewParticipants {
        /// Complete participants.
        got: usize,
    },
    /// An option out of its range.
    #[error("{0}")]
    InvalidOption(String),
    /// The pilot's means show no difference to scale.
    #[error(
        "the pilot's condition means are all equal, so there is no effect to scale; give the assumed effect with --effect"
    )]
    NoPilotEffect,
    /// A statistics error on the pilot.
    #[error(transparent)]
    Stats(#[from] StatsError),
}
