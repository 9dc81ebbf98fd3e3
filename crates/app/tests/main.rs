//! Integration tests of the kilotouch app: CLI, GUI (egui_kittest), the engine and hardware in the loop.
//!
//! Every file in this directory is a module of this one test binary
//! (`autotests = false` in Cargo.toml): one link instead of one per file.
//! Run one file's tests with `cargo test -p kilotouch --test integration FILE::`.
//! The workspace test `every_test_file_is_compiled` (tests/workspace.rs)
//! fails if a file here is not declared below.

mod calibrate_cli;
mod cli;
mod closed_loop_cli;
mod engine_core;
mod engine_live;
mod engine_live_tweezer;
mod engine_paced;
mod fidelity_cli;
mod firmware_qemu;
mod gui_app;
mod gui_busy;
mod gui_calibration;
mod gui_explore;
mod gui_participant;
mod gui_plan_study;
mod gui_plots;
mod gui_results;
mod gui_rig;
mod gui_study;
mod gui_tweezer;
mod gui_tweezer_live;
mod hil_sitting;
mod hil_tweezer_sitting;
#[cfg(feature = "lsl")]
mod lsl_gui_sitting;
#[cfg(feature = "lsl")]
mod lsl_outlets;
mod paper_cli;
mod refusals_cli;
mod rig_check_cli;
mod rig_cli;
mod serial_acceptance;
mod serial_cli;
mod serial_watchdog_cli;
mod session_thread;
mod stats_cli;
mod study_cli;
mod study_folder_cli;
mod study_guard_cli;
mod study_merge_cli;
mod study_power_cli;
mod tweezer_calibrate_cli;
mod tweezer_record_live;
mod tweezer_sim;
