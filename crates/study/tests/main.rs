//! Integration tests of the study crate: protocols, runner, export, statistics and the simulated participant.
//!
//! Every file in this directory is a module of this one test binary
//! (`autotests = false` in Cargo.toml): one link instead of one per file.
//! Run one file's tests with `cargo test -p kilotouch-study --test integration FILE::`.
//! The workspace test `every_test_file_is_compiled` (tests/workspace.rs)
//! fails if a file here is not declared below.

mod common;
mod counterbalance;
mod csv_props;
mod export_crash;
mod export_formats;
mod export_store;
mod fidelity;
mod friedman_scipy;
mod journal;
mod loader_props;
mod operator_model;
mod operator_population;
mod power;
mod practice_retries;
mod protocol;
mod rawsig;
mod reader_props;
mod runner_hold;
mod runner_session;
mod seeds;
mod stats_pingouin;
mod stats_props;
mod stats_reference;
mod task_metrics;
