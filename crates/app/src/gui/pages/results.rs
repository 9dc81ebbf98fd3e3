//! Results page (stub until the gui-pages branch merges; that branch owns
//! this file).

use crate::gui::env::PageEnv;

/// Results and statistics.
#[derive(Debug, Default)]
pub struct ResultsPage;

impl ResultsPage {
    /// New page.
    pub fn new() -> Self {
        Self
    }

    /// Draw the page.
    pub fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        ui.heading("Results");
        match env.output_dir {
            Some(d) => ui.label(format!("Output folder: {}", d.display())),
            None => ui.label("No study output folder chosen yet."),
        };
        ui.label("Charts and statistics are not in this build yet; `kilotouch stats` runs them headless.");
    }
}
