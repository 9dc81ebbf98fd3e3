//! Work done off the UI thread or outside the widgets: the background
//! haptic and trap calibration runs, kept free of egui so they can be
//! tested directly. The study-results model is [`kilotouch_study::results`].

pub mod calibration;
pub mod trap_calibration;
