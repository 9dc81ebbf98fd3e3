//! Integration tests of the rig crate: plant, tweezer, calibration, stability, safety and the live links.
//!
//! Every file in this directory is a module of this one test binary
//! (`autotests = false` in Cargo.toml): one link instead of one per file.
//! Run one file's tests with `cargo test -p kilotouch-rig --test integration FILE::`.
//! The workspace test `every_test_file_is_compiled` (tests/workspace.rs)
//! fails if a file here is not declared below.

mod audio_null;
mod calibration;
mod calibration_old_files;
mod common;
mod coupling;
mod device_estop;
mod frame_props;
mod gaussian_trap;
mod hello_bounds;
mod live_protocol;
mod live_serial;
mod live_tweezer;
mod plant;
mod plant_sections;
mod rig;
mod safety_layer;
mod safety_props;
mod stability;
mod trap_calibration;
mod tweezer;
mod wire_golden;
