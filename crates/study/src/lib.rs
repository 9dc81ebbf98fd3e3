//! # kilotouch-study
//!
//! Psychophysics study logic for the dual-stage haptic interface of Ji,
//! Vézien, Hayward et al. (§4 of the paper): the statistics used to compare
//! the V / P / D conditions ([`stats`]), counterbalancing of session orders
//! ([`counterbalance`]), study protocol files ([`protocol`]) and the
//! crash-safe storage of a study's results: the output folder with
//! `trials.csv`, summaries and `session.json` ([`export`]), the session
//! journal ([`journal`]), raw signals as NPY ([`rawsig`]) and the per-trial
//! seed derivation ([`seeds`]).
//!
//! Equations, references and the protocol format are documented in
//! `docs/THEORY.md`; the output folder and its formats in
//! `docs/STUDY.md`.

pub mod counterbalance;
mod error;
pub mod export;
pub mod operator;
pub mod protocol;
pub mod rawsig;
pub mod runner;
pub mod seeds;
pub mod simulate;
pub mod stats;
mod storage;
pub mod task;

pub use export::journal;
