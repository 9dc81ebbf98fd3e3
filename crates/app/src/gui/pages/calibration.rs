//! Calibration wizard page (stub until the gui-pages branch merges; that
//! branch owns this file).

use crate::gui::env::PageEnv;

/// The calibration wizard.
#[derive(Debug, Default)]
pub struct CalibrationPage;

impl CalibrationPage {
    /// New page.
    pub fn new() -> Self {
        Self
    }

    /// Draw the page.
    pub fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        ui.heading("Calibration");
        ui.label(format!(
            "Rig: {} at {} Hz. The calibration wizard is not in this build yet; \
             `kilotouch calibrate --rig sim --out cal.toml` runs the procedure headless.",
            env.rig_config.rig.name, env.rig_config.rig.sample_rate_hz
        ));
    }
}
