//! The pages of the app. Each page is a struct with `new()` that
//! implements [`Page`]; everything a page needs from the shell, and every
//! request it makes of it, goes through [`super::env::PageEnv`].

pub mod calibration;
pub mod explore;
pub mod plan_study;
pub mod results;
pub mod rig;
pub mod rig_tweezer;
pub mod study;
pub mod study_size;

pub use calibration::CalibrationPage;
pub use explore::ExplorePage;
pub use results::ResultsPage;
pub use rig::RigPage;
pub use study::StudyPage;

use super::env::PageEnv;

/// A page of the app, as the shell sees it.
pub trait Page {
    /// Draw the page (the shell's central panel), once per frame while it is shown.
    fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>);

    /// Work done every frame whatever page is shown (after the shown page's
    /// `ui` and the requests it made): none by default.
    fn background(&mut self, _ctx: &egui::Context, _env: &mut PageEnv<'_>) {}
}
