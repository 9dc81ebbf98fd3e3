//! kilotouch application library: the headless command-line interface (and,
//! in a later milestone, the egui/wgpu GUI).
//!
//! The binary `kilotouch` is a thin wrapper around [`cli::main_entry`].

pub mod cli;
pub mod commands;
pub mod csvio;
pub mod gui;
pub mod output;
