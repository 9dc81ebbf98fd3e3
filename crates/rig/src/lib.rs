//! kilotouch-rig: see README.md. Implemented in a later issue.

pub mod calibration;
