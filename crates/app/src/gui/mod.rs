//! The desktop app (egui/eframe): pages, charts and background workers.
//!
//! This module list is the gui-pages branch's minimal one; the shell
//! (gui-core) adds its own modules at merge.

pub mod charts;
pub mod env;
pub mod pages;
pub mod work;

pub use env::{PageEnv, ShellRequest};
