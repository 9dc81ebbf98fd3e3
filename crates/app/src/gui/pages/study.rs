//! Study page (placeholder: the session runner plugs into the engine as a
//! [`crate::engine::BlockDriver`] in a later step).

use crate::gui::env::PageEnv;

/// Study sessions.
#[derive(Debug, Default)]
pub struct StudyPage;

impl StudyPage {
    /// New page.
    pub fn new() -> Self {
        Self
    }

    /// Draw the page.
    pub fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        ui.heading("Study");
        ui.label(
            "Running sessions from the app is not in this build yet; \
             `kilotouch study simulate` runs the protocol headless with the simulated participant.",
        );
        if let Some(d) = env.output_dir {
            ui.label(format!("Output folder: {}", d.display()));
        }
    }
}
