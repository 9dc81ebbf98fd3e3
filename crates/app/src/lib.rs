//! kilotouch application library: the desktop app (egui/wgpu, [`gui`]), its
//! real-time engine ([`engine`], GUI-independent) and the headless
//! command-line interface.
//!
//! The binary `kilotouch` is a thin wrapper around [`cli::main_entry`].

pub mod cli;
pub mod commands;
pub mod engine;
pub mod fidelity_plot;
pub mod gui;
#[cfg(feature = "lsl")]
pub mod lsl;
pub mod output;
pub mod paper;
pub mod power_plot;
pub mod session;
pub mod tweezer_cal;
pub mod tweezer_sim;
