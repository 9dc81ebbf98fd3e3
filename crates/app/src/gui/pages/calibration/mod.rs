//! The Calibration wizard page: the paper's §3 procedure step by step on
//! the rig of the Rig page (the simulated rig of `env.rig_config`).
//!
//! * Settings that matter, from [`CalibrationConfig`] with its defaults:
//!   the noise seed, the MLS excitation of each channel (amplitude as a
//!   fraction of the channel's limit, order n → period 2ⁿ − 1 samples,
//!   periods analysed), the crossover rule (automatic: the highest f_c whose
//!   predicted deviation is within budget; or a fixed f_c) and order, and
//!   the verification tolerance.
//! * Start runs steps 1–6 on a background thread
//!   ([`crate::gui::work::calibration`]); a progress bar per step, the
//!   current step's message and Cancel (the procedure's cancel flag).
//! * Results as plots: each channel's measured frequency response
//!   (magnitude, phase) with coherence and the identified model overlaid on
//!   log-frequency axes (Fig. 5); the crossover L, H and L + H; the
//!   compensators C_L and C_H; the third-octave verification before and
//!   after compensation against the tolerance band (Fig. 7), with PASS/FAIL.
//! * Save (step 7) and load of calibration files with the file's checks
//!   (syntax, checksum, contents, rig identity) shown as errors.
//! * The closed loop with the calibration: its force-normalised chain
//!   (C_L = 1, so the rendered force does not change) and the stability
//!   margins of P and D with it ([`kilotouch_rig::stability`]). "Apply to
//!   engine" sends [`ShellRequest::ApplyCalibration`] only when the margins
//!   meet the rig file's minimum; otherwise the page says which margin fails
//!   and the largest safe force scale.

use std::path::{Path, PathBuf};
use std::time::Duration;

use kilotouch_rig::RigConfig;
use kilotouch_rig::calibration::{CalibrationConfig, CalibrationFile, RigAdapter, RigRecord, Step};
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::haptic_loop::Clearance;
use kilotouch_rig::stability::{self, StabilityReport};

use crate::gui::charts::FAIL_COLOR;
use crate::gui::env::{AppliedCalibration, PageEnv, ShellRequest};
use crate::gui::path_field::{PathField, PathKind, TOML};
use crate::gui::work::calibration::{CalibrationRun, RunEnd, StepProgress};

mod form;
mod plots;
mod results;

use plots::{Plots, build_plots};

/// Crossover rule offered by the wizard.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CrossoverRuleChoice {
    /// Highest f_c within the deviation budget (paper §3.1 made an algorithm).
    Automatic,
    /// The f_c typed in.
    Fixed,
}

/// Where the result shown comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum ResultSource {
    /// A wizard run finished in this session.
    Wizard,
    /// A calibration file loaded from this path.
    Loaded(PathBuf),
}

/// A message shown under the controls.
#[derive(Debug, Clone, PartialEq)]
pub enum Status {
    /// Information.
    Info(String),
    /// An error (red).
    Error(String),
}

/// A calibration on display: the file (with the FRFs in memory after a
/// wizard run) and its curves.
#[derive(Debug, Clone)]
struct Shown {
    file: CalibrationFile,
    source: ResultSource,
    plots: Plots,
    saved_to: Option<PathBuf>,
    /// The closed loop with this calibration (or why it cannot be built).
    closed_loop: Result<LoopCheck, String>,
}

/// The closed loop with a calibration: its chain, the analysis, and the
/// clearance when the margins meet the minimum.
#[derive(Debug, Clone)]
struct LoopCheck {
    chain: LoopChain,
    report: StabilityReport,
    clearance: Option<Clearance>,
}

/// Build the calibration's force-normalised chain for `cfg` and analyse the
/// closed loop with it (a few hundred ms the first time, memoized).
fn loop_check(file: &CalibrationFile, label: &str, cfg: &RigConfig) -> Result<LoopCheck, String> {
    let chain = LoopChain::from_calibration(file, label, cfg.rig.sample_rate_hz)
        .map_err(|e| e.to_string())?;
    let report = stability::analyse(cfg, &chain.coefficients).map_err(|e| e.to_string())?;
    let clearance = Clearance::check(cfg, &chain).ok();
    Ok(LoopCheck {
        chain,
        report,
        clearance,
    })
}

/// The record of the simulated rig of `cfg` (what a calibration file must
/// have been made for).
pub fn sim_record(cfg: &RigConfig) -> Result<RigRecord, String> {
    use kilotouch_rig::calibration::CalibrationRig;
    let rig = RigAdapter::sim(cfg, None).map_err(|e| format!("rig configuration: {e}"))?;
    Ok(rig.record())
}

/// The Calibration wizard page (module documentation).
#[derive(Debug)]
pub struct CalibrationPage {
    /// Base settings; the fields below override parts of it.
    config: CalibrationConfig,
    seed_text: String,
    rule: CrossoverRuleChoice,
    fixed_crossover_hz: f64,
    run: Option<CalibrationRun>,
    progress: StepProgress,
    last_elapsed: Option<Duration>,
    shown: Option<Shown>,
    status: Option<Status>,
    save_path: String,
    load_path: String,
    save_field: PathField,
    load_field: PathField,
    overwrite: bool,
    apply_despite_fail: bool,
}

/// Where calibrations are saved unless the user chooses: the app's data
/// folder (`~/.local/share/kilotouch/calibrations/` on Linux, the
/// platform's application-data folder elsewhere, as eframe stores the
/// settings), not the folder the app happened to be started from.
pub fn default_calibration_path() -> PathBuf {
    eframe::storage_dir("kilotouch")
        .map(|d| d.join("calibrations"))
        .unwrap_or_else(|| PathBuf::from("calibrations"))
        .join("calibration.toml")
}

impl Default for CalibrationPage {
    fn default() -> Self {
        Self::new()
    }
}

impl CalibrationPage {
    /// A page with the default settings ([`CalibrationConfig::default`],
    /// seed 1).
    pub fn new() -> Self {
        Self {
            config: CalibrationConfig::default(),
            seed_text: "1".into(),
            rule: CrossoverRuleChoice::Automatic,
            fixed_crossover_hz: 200.0,
            run: None,
            progress: StepProgress::default(),
            last_elapsed: None,
            shown: None,
            status: None,
            save_path: default_calibration_path().display().to_string(),
            load_path: default_calibration_path().display().to_string(),
            save_field: PathField::default(),
            load_field: PathField::default(),
            overwrite: false,
            apply_despite_fail: false,
        }
    }

    /// True while a calibration runs.
    pub fn is_running(&self) -> bool {
        self.run.as_ref().is_some_and(CalibrationRun::is_running)
    }

    /// Verification verdict of the calibration on display.
    pub fn verification_passed(&self) -> Option<bool> {
        self.shown.as_ref().map(|s| s.file.verification.passed)
    }

    /// The calibration on display.
    pub fn calibration(&self) -> Option<&CalibrationFile> {
        self.shown.as_ref().map(|s| &s.file)
    }

    /// Progress of the steps (of the running or last run; Save is set when
    /// the user saves).
    pub fn progress(&self) -> &StepProgress {
        &self.progress
    }

    /// The message under the controls.
    pub fn status(&self) -> Option<&Status> {
        self.status.as_ref()
    }

    /// Path in the Save field.
    pub fn set_save_path(&mut self, p: &Path) {
        self.save_path = p.display().to_string();
    }

    /// Path in the Load field.
    pub fn set_load_path(&mut self, p: &Path) {
        self.load_path = p.display().to_string();
    }

    /// The base settings (the page's fields override the seed and the
    /// crossover rule), e.g. to set fields the page does not expose.
    pub fn config_mut(&mut self) -> &mut CalibrationConfig {
        &mut self.config
    }

    fn start(&mut self, ctx: &egui::Context, rig: &RigConfig) {
        let (cfg, seed) = match self.effective_config() {
            Ok(v) => v,
            Err(e) => {
                self.status = Some(Status::Error(e));
                return;
            }
        };
        let fs = rig.rig.sample_rate_hz;
        if let Err(e) = cfg.validate(fs) {
            self.status = Some(Status::Error(e.to_string()));
            return;
        }
        self.progress = StepProgress::default();
        self.status = Some(Status::Info("calibrating…".into()));
        self.apply_despite_fail = false;
        self.run = Some(CalibrationRun::start(
            rig,
            Some(seed),
            cfg,
            Some(ctx.clone()),
        ));
    }

    fn poll(&mut self, cfg: &RigConfig) {
        let Some(run) = self.run.as_mut() else {
            return;
        };
        let end = run.poll();
        self.progress = run.progress().clone();
        self.last_elapsed = Some(run.elapsed());
        let Some(end) = end else { return };
        self.run = None;
        match end {
            RunEnd::Finished(outcome) => match outcome.file() {
                Ok(file) => {
                    let passed = file.verification.passed;
                    self.status = Some(Status::Info(format!(
                        "calibration finished: verification {}; save it (step 7) and apply it",
                        if passed { "passed" } else { "FAILED" }
                    )));
                    let plots = build_plots(&file);
                    let closed_loop = loop_check(&file, "this session's calibration", cfg);
                    self.shown = Some(Shown {
                        file,
                        source: ResultSource::Wizard,
                        plots,
                        saved_to: None,
                        closed_loop,
                    });
                }
                Err(e) => self.status = Some(Status::Error(e.to_string())),
            },
            RunEnd::Cancelled(step) => {
                self.status = Some(Status::Error(format!(
                    "calibration cancelled during step `{}`",
                    step.name()
                )));
            }
            RunEnd::Failed(m) => self.status = Some(Status::Error(m)),
        }
    }

    fn save(&mut self, env: &mut PageEnv<'_>) {
        let Some(shown) = self.shown.as_mut() else {
            return;
        };
        let typed = PathBuf::from(self.save_path.trim());
        if typed.as_os_str().is_empty() {
            self.status = Some(Status::Error("type a file name to save to".into()));
            return;
        }
        // Messages name the full path (a bare name lands in the working
        // directory, which the user may not know).
        let path = std::path::absolute(&typed).unwrap_or(typed);
        if path.exists() && !self.overwrite {
            self.status = Some(Status::Error(format!(
                "{} exists; tick \"overwrite\" to replace it",
                path.display()
            )));
            return;
        }
        if let Some(dir) = path.parent()
            && !dir.as_os_str().is_empty()
            && let Err(e) = std::fs::create_dir_all(dir)
        {
            self.status = Some(Status::Error(format!("cannot make {}: {e}", dir.display())));
            return;
        }
        match shown.file.save(&path) {
            Ok(()) => {
                let msg = format!("calibration saved to {}", path.display());
                self.progress.apply(Step::Save, 1.0, &msg);
                env.requests.push(ShellRequest::Notify(msg.clone()));
                self.status = Some(Status::Info(msg));
                shown.saved_to = Some(path);
            }
            Err(e) => self.status = Some(Status::Error(e.to_string())),
        }
    }

    fn load(&mut self, rig: &RigConfig) {
        let path = PathBuf::from(self.load_path.trim());
        let result = sim_record(rig)
            .and_then(|id| CalibrationFile::load_for(&path, &id).map_err(|e| e.to_string()));
        match result {
            Ok(file) => {
                self.status = Some(Status::Info(format!(
                    "loaded {} (made {}, verification {})",
                    path.display(),
                    file.created,
                    if file.verification.passed {
                        "passed"
                    } else {
                        "FAILED"
                    }
                )));
                let plots = build_plots(&file);
                self.apply_despite_fail = false;
                let closed_loop = loop_check(&file, &path.display().to_string(), rig);
                self.shown = Some(Shown {
                    file,
                    source: ResultSource::Loaded(path),
                    plots,
                    saved_to: None,
                    closed_loop,
                });
            }
            Err(e) => self.status = Some(Status::Error(e)),
        }
    }

    fn apply(&mut self, env: &mut PageEnv<'_>) {
        let Some(shown) = self.shown.as_ref() else {
            return;
        };
        // The rig may have changed since the calibration was made.
        let check = sim_record(env.rig_config).and_then(|id| {
            shown
                .file
                .check_rig(&id, "the calibration on display")
                .map_err(|e| e.to_string())
        });
        if let Err(e) = check {
            self.status = Some(Status::Error(e));
            return;
        }
        let lc = match &shown.closed_loop {
            Ok(lc) => lc,
            Err(e) => {
                self.status = Some(Status::Error(format!("calibration not applied: {e}")));
                return;
            }
        };
        let Some(clearance) = lc.clearance.clone() else {
            self.status = Some(Status::Error(format!(
                "calibration not applied: {}",
                lc.report.refusal().unwrap_or_default()
            )));
            return;
        };
        let path = shown.saved_to.clone().or_else(|| match &shown.source {
            ResultSource::Loaded(p) => Some(p.clone()),
            ResultSource::Wizard => None,
        });
        let chain = match &path {
            Some(p) => LoopChain::from_calibration(
                &shown.file,
                &p.display().to_string(),
                env.rig_config.rig.sample_rate_hz,
            )
            .unwrap_or_else(|_| lc.chain.clone()),
            None => lc.chain.clone(),
        };
        let clearance = if chain.source == *clearance.source() {
            clearance
        } else {
            match Clearance::check(env.rig_config, &chain) {
                Ok(c) => c,
                Err(e) => {
                    self.status = Some(Status::Error(format!("calibration not applied: {e}")));
                    return;
                }
            }
        };
        env.requests.push(ShellRequest::ApplyCalibration(Box::new(
            AppliedCalibration {
                chain,
                clearance,
                path,
            },
        )));
        self.status = Some(Status::Info(
            "calibration sent to the engine (force-normalised chain: the rendered force is unchanged)"
                .into(),
        ));
    }

    fn controls_ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        ui.horizontal(|ui| {
            let running = self.is_running();
            if ui
                .add_enabled(!running, egui::Button::new("Start calibration"))
                .clicked()
            {
                let ctx = ui.ctx().clone();
                self.start(&ctx, env.rig_config);
            }
            let cancelling = self
                .run
                .as_ref()
                .is_some_and(CalibrationRun::cancel_requested);
            if ui
                .add_enabled(running && !cancelling, egui::Button::new("Cancel"))
                .clicked()
                && let Some(r) = &self.run
            {
                r.cancel();
                self.status = Some(Status::Info("cancelling…".into()));
            }
            if let Some(t) = self.last_elapsed {
                ui.label(format!("{:.1} s", t.as_secs_f64()));
            }
        });
    }

    fn progress_ui(&self, ui: &mut egui::Ui) {
        egui::Grid::new("cal-progress")
            .num_columns(2)
            .spacing([12.0, 2.0])
            .show(ui, |ui| {
                for step in Step::ALL {
                    let f = self.progress.fractions[step.index()];
                    let current = self.progress.current == Some(step) && self.is_running();
                    let name = format!("{}. {}", step.index() + 1, step_title(step));
                    if current {
                        ui.strong(name);
                    } else {
                        ui.label(name);
                    }
                    ui.add(
                        egui::ProgressBar::new(f as f32)
                            .desired_width(260.0)
                            .text(format!("{:.0} %", 100.0 * f)),
                    );
                    ui.end_row();
                }
            });
        if let Some(step) = self.progress.current
            && !self.progress.message.is_empty()
        {
            ui.label(format!("{}: {}", step_title(step), self.progress.message));
        }
    }

    fn files_ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        let have = self.shown.is_some();
        ui.horizontal(|ui| {
            self.save_field.ui(
                ui,
                "Save to",
                &mut self.save_path,
                PathKind::Save(TOML.0, TOML.1),
                "calibration file (.toml)",
                420.0,
            );
            ui.checkbox(&mut self.overwrite, "overwrite");
            if ui
                .add_enabled(have, egui::Button::new("Save calibration"))
                .clicked()
            {
                self.save(env);
            }
        });
        ui.horizontal(|ui| {
            self.load_field.ui(
                ui,
                "Load from",
                &mut self.load_path,
                PathKind::Open(TOML.0, TOML.1),
                "calibration file (.toml)",
                420.0,
            );
            if ui
                .add_enabled(!self.is_running(), egui::Button::new("Load calibration"))
                .clicked()
            {
                self.load(env.rig_config);
            }
        });
        let passed = self.verification_passed();
        let safe = self
            .shown
            .as_ref()
            .is_some_and(|s| s.closed_loop.as_ref().is_ok_and(|c| c.clearance.is_some()));
        ui.horizontal(|ui| {
            if passed == Some(false) {
                ui.checkbox(
                    &mut self.apply_despite_fail,
                    "apply although the verification failed",
                );
            }
            let enabled = safe
                && (passed == Some(true) || (passed == Some(false) && self.apply_despite_fail));
            let b = ui.add_enabled(enabled, egui::Button::new("Apply to engine"));
            let b = if !safe && self.shown.is_some() {
                b.on_disabled_hover_text(
                    "the closed loop with this calibration does not meet the minimum margins (below)",
                )
            } else {
                b
            };
            if b.clicked() {
                self.apply(env);
            }
            if let Some(a) = env.applied {
                ui.label(format!("engine runs: {}", a.chain.source.describe()));
            }
        });
    }
}

/// Title of a step in the wizard.
pub fn step_title(step: Step) -> &'static str {
    match step {
        Step::Check => "Check the rig",
        Step::IdentifyLow => "Identify the low channel",
        Step::IdentifyHigh => "Identify the high channel",
        Step::Crossover => "Choose the crossover",
        Step::Design => "Design the compensators",
        Step::Verify => "Verify (third-octave bands)",
        Step::Save => "Save",
    }
}

impl super::Page for CalibrationPage {
    /// Draw the page.
    fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        self.poll(env.rig_config);
        if self.is_running() {
            // The worker repaints on progress; this keeps the clock moving.
            ui.ctx().request_repaint_after(Duration::from_millis(250));
        }
        egui::ScrollArea::vertical()
            .auto_shrink([false, false])
            .show(ui, |ui| {
                ui.heading("Calibration wizard");
                let rig_name = match env.rig_config_path {
                    Some(p) => p.display().to_string(),
                    None => "built-in default rig".into(),
                };
                ui.label(format!(
                    "Simulated rig `{}` ({rig_name}), fs = {} Hz",
                    env.rig_config.rig.name, env.rig_config.rig.sample_rate_hz
                ));
                self.settings_ui(ui, env.rig_config.rig.sample_rate_hz);
                self.controls_ui(ui, env);
                self.progress_ui(ui);
                match &self.status {
                    Some(Status::Info(m)) => {
                        ui.label(m.as_str());
                    }
                    Some(Status::Error(m)) => {
                        ui.colored_label(FAIL_COLOR, format!("Error: {m}"));
                    }
                    None => {}
                }
                ui.separator();
                self.files_ui(ui, env);
                ui.separator();
                self.results_ui(ui);
            });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_seed_is_an_error_not_a_panic() {
        let mut p = CalibrationPage::new();
        p.seed_text = "12x".into();
        let e = p.effective_config().unwrap_err();
        assert!(e.contains("12x"), "{e}");
        p.seed_text = " 18446744073709551615 ".into();
        assert_eq!(p.effective_config().unwrap().1, u64::MAX);
        p.rule = CrossoverRuleChoice::Fixed;
        p.fixed_crossover_hz = 180.0;
        assert_eq!(
            p.effective_config().unwrap().0.crossover.crossover_hz,
            Some(180.0)
        );
    }
}
