//! One module per headless command.

pub mod bench;
pub mod bench_fidelity;
pub mod bench_hil;
pub mod calibrate;
pub mod crossover;
pub mod emulate;
pub mod firmware;
pub mod frf;
pub mod paper;
pub mod progress;
pub mod protocol_arg;
pub mod psd;
pub mod rig;
pub mod sim;
pub mod stats;
pub mod study;
pub mod study_power;
pub mod study_run;
pub mod tfest;
pub mod tweezer;
