//! What the GUI shell hands every page each frame (contract between the shell and the pages).

use std::path::{Path, PathBuf};

/// Per-frame context given by the shell to a page's `ui` method.
#[derive(Debug)]
pub struct PageEnv<'a> {
    /// The rig file currently selected on the Rig page, parsed (the built-in default when none is chosen).
    pub rig_config: &'a kilotouch_rig::RigConfig,
    /// Path of that rig file (`None` = built-in default).
    pub rig_config_path: Option<&'a Path>,
    /// The study output folder last used (Study and Results pages), if any.
    pub output_dir: Option<&'a Path>,
    /// Requests from the page to the shell, handled by the shell after the frame.
    pub requests: &'a mut Vec<ShellRequest>,
    /// The calibration the engine runs, if one was applied (the Study
    /// page's default).
    pub applied: Option<&'a AppliedCalibration>,
    /// The trap calibration the engine's tweezer uses, if one was applied
    /// (Rig page; recorded in a study's `session.json`).
    pub trap_applied: Option<&'a kilotouch_rig::tweezer::TrapCalibrationRecord>,
    /// The real-time engine, when one runs (the Rig page connects it).
    pub engine: Option<&'a mut crate::engine::EngineHandle>,
    /// Why the rig file last chosen could not be used, if it could not.
    pub config_error: Option<&'a str>,
}

/// A calibration cleared for the closed loop: its force-normalised chain,
/// the stability analysis with it, and the file it came from.
#[derive(Debug, Clone)]
pub struct AppliedCalibration {
    /// The chain and its source.
    pub chain: kilotouch_rig::coupling::LoopChain,
    /// Proof that the margins meet the rig file's minimum.
    pub clearance: kilotouch_rig::haptic_loop::Clearance,
    /// The file, when the calibration was saved or loaded.
    pub path: Option<PathBuf>,
}

/// A page's request to the shell.
#[derive(Debug)]
pub enum ShellRequest {
    /// Load this calibration (a finished wizard run or a loaded file) into
    /// the real-time engine's chain (already cleared by the stability analysis).
    ApplyCalibration(Box<AppliedCalibration>),
    /// Use this trap calibration (κ, R_d) for the engine's tweezer, or
    /// none (`None`); the shell checks the fit and the loop's margins first.
    ApplyTrapCalibration(Option<Box<kilotouch_rig::tweezer::TrapCalibrationRecord>>),
    /// Remember this folder as the study output folder (persisted in the settings).
    SetOutputDir(PathBuf),
    /// Show a short message to the user (status line / toast).
    Notify(String),
    /// Connect the engine to this rig instead (the Study page's rig choice).
    ConnectRig(kilotouch_rig::device::RigSpec),
    /// Show the Rig page (to choose and connect a live rig).
    ShowRigPage,
    /// Parse this rig file and use it (a running engine restarts on it).
    LoadRigFile(String),
    /// Go back to the built-in default rig.
    UseDefaultRig,
    /// Start the engine on the rig of the Rig page's rig field
    /// ([`crate::gui::pages::RigPage::spec`]); restarts it when one runs.
    Connect,
    /// Reopen the device after a fault and resume, without restarting the
    /// engine (the rig field's device when it names another port).
    Reconnect,
    /// Stop the engine thread.
    Disconnect,
    /// Resume exchanging frames.
    StartEngine,
    /// Pause exchanging frames (outputs zero).
    StopEngine,
    /// THE emergency stop (the participant's window has the keyboard
    /// during a trial, so its Esc comes through here).
    EmergencyStop,
}
