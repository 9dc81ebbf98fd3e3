//! # kilotouch-study
//!
//! Psychophysics study logic for the dual-stage haptic interface of Ji,
//! Vézien, Hayward et al. (§4 of the paper): the statistics used to compare
//! the V / P / D conditions ([`stats`]), counterbalancing of session orders
//! ([`counterbalance`]) and study protocol files ([`protocol`]).
//!
//! Equations, references and the protocol format are documented in
//! `docs/theory/study.md`.

pub mod counterbalance;
pub mod protocol;
pub mod stats;
