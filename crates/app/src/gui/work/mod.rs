//! Work done off the UI thread or outside the widgets: the background
//! calibration run and the study-results model (loading, statistics,
//! export), kept free of egui so they can be tested directly.

pub mod calibration;
pub mod results;
pub mod trap_calibration;
