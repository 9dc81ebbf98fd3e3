//! The pages of the desktop app.

pub mod calibration;
pub mod results;

pub use calibration::CalibrationPage;
pub use results::ResultsPage;
