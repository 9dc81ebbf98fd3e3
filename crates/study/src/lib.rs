//! # kilotouch-study
//!
//! Psychophysics study logic for the dual-stage haptic interface of Ji,
//! Vézien, Hayward et al. (§4 of the paper):
//!
//! * study protocol files ([`protocol`]), counterbalancing of session
//!   orders ([`counterbalance`]) and the per-trial seed derivation
//!   ([`seeds`]);
//! * the two micro-bead tasks, their metrics and the stations they run on
//!   ([`task`]); the participant interface ([`participant`]) and the
//!   simulated operator ([`operator`]) with its attention lapses ([`lapse`]);
//! * the session runner ([`runner`]) and simulated studies run in parallel
//!   ([`simulate`]) at the fidelity a scene needs ([`fidelity`]; each
//!   level's speed against error measured by [`frontier`]), whole or in
//!   participant shards ([`shard`]) merged afterwards ([`merge`]);
//! * the crash-safe storage of a study's results: the output folder with
//!   `trials.csv`, summaries, `session.json` and the session journal
//!   ([`export`], [`journal`]), raw signals as NPY ([`rawsig`]);
//! * the statistics used to compare the V / P / D conditions ([`stats`])
//!   and the results model of a study folder: per-participant and
//!   per-condition values, the statistics table ([`results`]);
//! * simulation-based power analysis from a pilot ([`power`]);
//! * the bounded CSV reader of the files a researcher hands in ([`csvio`]).
//!
//! Equations, references and the protocol format are documented in
//! `docs/theory/` (index: `docs/THEORY.md`); the output folder and its formats in
//! `docs/STUDY.md`.

pub mod at_device;
pub mod counterbalance;
pub mod csvio;
mod error;
pub mod export;
pub mod fidelity;
pub mod frontier;
pub mod lapse;
pub mod merge;
pub mod operator;
pub mod participant;
pub mod power;
pub mod protocol;
pub mod rawsig;
pub mod results;
pub mod runner;
mod screen_texts;
pub mod screens;
pub mod seeds;
pub mod shard;
pub mod simulate;
pub mod size;
pub mod stats;
mod storage;
pub mod task;
pub mod vibrotactile;

// The journal lives in export/ (it is part of the study folder); this keeps
// `kilotouch_study::journal` working.
pub use export::journal;
