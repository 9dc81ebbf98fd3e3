//! The pages of the app. Each page is a struct with `new()` and
//! `ui(&mut self, ui, env)` (see [`super::env::PageEnv`]); the Rig and
//! Explore pages also get the engine handle.

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
