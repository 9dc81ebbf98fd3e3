//! Calibration of the dual-stage rig: the paper's §3 as one procedure.
//!
//! The same code serves the GUI wizard (step by step) and the command line
//! (`kilotouch calibrate`, all at once through [`calibrate`]), on the
//! simulated rig and on a live one: all it needs from a rig is
//! [`CalibrationRig`].
//!
//! 1. **Check** ([`check::check`]): sensor alive and in range, rig
//!    responding, safety armed.
//! 2. **Identify the low channel** ([`identify::identify_low`]): MLS on the
//!    Pantograph, H1 with coherence, G0_L and the flat band.
//! 3. **Identify the high channel** ([`identify::identify_high`]): MLS on the
//!    Haptuator with back-off on saturation, reliable band, fit of Ĝ_H.
//! 4. **Choose the crossover** ([`crossover::choose_crossover`]).
//! 5. **Design** C_L, C_H and K_sys ([`design::design`]).
//! 6. **Verify** with stepped sines at third-octave centres
//!    ([`verify::verify`]), compensated and with the crossover alone.
//! 7. **Save** the calibration file ([`file::CalibrationFile`]).
//!
//! Every step reports progress ([`Progress`]), checks the cancel flag before
//! each rig run, and keeps its raw records (`raw` fields). Theory, units and
//! the crossover rule: `docs/theory/calibration.md`.

pub mod bands;
pub mod check;
pub mod config;
pub mod crossover;
pub mod design;
pub mod error;
pub mod file;
pub mod hash;
pub mod identify;
pub mod interface;
pub mod measure;
pub mod prediction;
pub mod progress;
pub mod report;
pub mod sim;
#[cfg(feature = "testing")]
pub mod standin;
pub mod step;
pub mod verify;

pub use check::CheckResult;
pub use config::CalibrationConfig;
pub use crossover::CrossoverChoice;
pub use design::CompensatorDesign;
pub use error::{CalibrationError, Result};
pub use file::CalibrationFile;
pub use identify::{HighChannelId, LowChannelId};
pub use interface::{ActuatorLimits, CalibrationRig, Channel, CheckReport, RigRecord, RunStats};
pub use progress::{NoProgress, Progress, Step, StepContext};
pub use report::CalibrationReport;
pub use sim::{RigAdapter, calibrate_sim, rig_config_hash};
#[cfg(feature = "testing")]
pub use standin::{StandInConfig, StandInRig};
pub use verify::Verification;

use std::path::Path;
use std::sync::atomic::AtomicBool;

/// Everything a calibration produced (steps 1–6).
#[derive(Debug, Clone)]
pub struct CalibrationOutcome {
    /// The rig's record (name, serial, configuration hash, rate).
    pub rig: RigRecord,
    /// Sample rate, Hz.
    pub fs: f64,
    /// Rig limits.
    pub limits: ActuatorLimits,
    /// Settings used.
    pub config: CalibrationConfig,
    /// Step 1.
    pub check: CheckResult,
    /// Step 2.
    pub low: LowChannelId,
    /// Step 3.
    pub high: HighChannelId,
    /// Step 4.
    pub crossover: CrossoverChoice,
    /// Step 5.
    pub design: CompensatorDesign,
    /// Step 6.
    pub verification: Verification,
}

impl CalibrationOutcome {
    /// The command-line report.
    pub fn report(&self) -> CalibrationReport {
        CalibrationReport::from_outcome(self)
    }

    /// The calibration file, stamped with the current UTC time.
    pub fn file(&self) -> Result<CalibrationFile> {
        CalibrationFile::new(self, hash::utc_now_rfc3339())
    }

    /// Step 7: write the calibration file to `path` and return it.
    pub fn save(&self, path: &Path, ctx: &mut StepContext<'_>) -> Result<CalibrationFile> {
        ctx.begin(Step::Save, &format!("writing {}", path.display()))?;
        let f = self.file()?;
        f.save(path)?;
        ctx.report(Step::Save, 1.0, &format!("saved {}", path.display()));
        Ok(f)
    }
}

/// Run steps 1–6 on `rig` (and step 7 when `out` is given), reporting to
/// `progress` and stopping with [`CalibrationError::Cancelled`] once
/// `cancel` is raised.
pub fn calibrate<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    cfg: &CalibrationConfig,
    out: Option<&Path>,
    progress: &mut dyn Progress,
    cancel: &AtomicBool,
) -> Result<CalibrationOutcome> {
    let mut ctx = StepContext::new(progress, cancel);
    let fs = rig.sample_rate();
    cfg.validate(fs)?;
    let check = check::check(rig, cfg, &mut ctx)?;
    let low = identify::identify_low(rig, cfg, &mut ctx)?;
    let high = identify::identify_high(rig, cfg, &mut ctx)?;
    let crossover = crossover::choose_crossover(fs, &low, &high, cfg, &mut ctx)?;
    let limits = rig.limits();
    let design = design::design(fs, &limits, &low, &high, &crossover, cfg, &mut ctx)?;
    let verification = verify::verify(rig, &design, &crossover, &low, cfg, &mut ctx)?;
    let outcome = CalibrationOutcome {
        rig: rig.record(),
        fs,
        limits,
        config: cfg.clone(),
        check,
        low,
        high,
        crossover,
        design,
        verification,
    };
    match out {
        Some(path) => {
            outcome.save(path, &mut ctx)?;
        }
        None => ctx.report(Step::Save, 1.0, "not saved (no output file)"),
    }
    Ok(outcome)
}
