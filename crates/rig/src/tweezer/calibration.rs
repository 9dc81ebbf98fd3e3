//! Passive power-spectral calibration of a trap (Berg-Sørensen & Flyvbjerg
//! 2004; pylake's formulation, `kilotouch_dsp::trap_psd`): a record of the
//! position detector's output (volts) with the trap held still →
//! corner frequency f_c and diffusion coefficient D (V²/s) → trap stiffness
//! κ = 2πγ f_c, displacement sensitivity R_d = √(k_BT/(γ D)) and force
//! sensitivity R_f = R_d κ, with standard errors by Gaussian propagation
//! (the drag γ taken as exact, as pylake does).
//!
//! The drag γ is Stokes' 6πηR, times Faxén's parallel factor when a
//! distance to the coverslip is given ([`super::faxen_parallel`]); the
//! hydrodynamically correct spectrum carries the wall in its frequency-
//! dependent drag instead, and its f_c and D refer to the bulk drag γ₀.

use super::{BOLTZMANN, faxen_parallel, stokes_drag};
use crate::error::RigError;
use kilotouch_dsp::trap_psd::{
    Hydrodynamics, Periodogram, PsdFit, PsdFitOptions, PsdModel, SpectrumShape, fit_power_spectrum,
};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Fluid density used when none is given, kg/m³ (water; pylake's default).
pub const DEFAULT_FLUID_DENSITY_KG_M3: f64 = 997.0;
/// Bead density used when none is given, kg/m³ (polystyrene; pylake's
/// default).
pub const DEFAULT_BEAD_DENSITY_KG_M3: f64 = 1060.0;

/// What a trap calibration assumes (SI units).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrapCalibrationSettings {
    /// Sample rate of the record, Hz.
    pub fs_hz: f64,
    /// Bead radius R, m.
    pub radius_m: f64,
    /// Viscosity η, Pa·s.
    pub viscosity_pa_s: f64,
    /// Temperature T, K.
    pub temperature_k: f64,
    /// Fit range (low, high], Hz.
    pub fit_range_hz: (f64, f64),
    /// Periodogram bins per block.
    pub points_per_block: usize,
    /// Fit the hydrodynamically correct spectrum.
    pub hydro: bool,
    /// Fit the slow-photodiode filter (f_diode, α).
    pub diode: bool,
    /// Fit the aliased Lorentzian of a point-sampled record.
    pub aliased: bool,
    /// Fluid density, kg/m³ (hydrodynamic model).
    pub fluid_density_kg_m3: f64,
    /// Bead density, kg/m³ (hydrodynamic model).
    pub bead_density_kg_m3: f64,
    /// Bead-centre to coverslip distance, m (None: far from it).
    pub distance_to_surface_m: Option<f64>,
}

/// Result of a trap calibration (SI units in the names; the JSON of
/// `kilotouch tweezer calibrate`, whose keys and units differ where noted).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrapCalibration {
    /// Corner frequency f_c, Hz (JSON key `fc_hz`).
    #[serde(rename = "fc_hz")]
    pub corner_hz: f64,
    /// Its standard error, Hz (JSON key `fc_se_hz`).
    #[serde(rename = "fc_se_hz")]
    pub corner_se_hz: f64,
    /// Diffusion coefficient of the detector signal, V²/s.
    pub diffusion_v2_s: f64,
    /// Its standard error, V²/s.
    pub diffusion_se_v2_s: f64,
    /// Trap stiffness κ, N/m (JSON key `kappa_pn_um`, pN/µm).
    #[serde(rename = "kappa_pn_um", with = "crate::units::pn_per_um")]
    pub kappa_n_per_m: f64,
    /// Its standard error, N/m (JSON key `kappa_se_pn_um`, pN/µm).
    #[serde(rename = "kappa_se_pn_um", with = "crate::units::pn_per_um")]
    pub kappa_se_n_per_m: f64,
    /// Displacement sensitivity R_d, m/V (JSON key `rd_um_per_v`, µm/V).
    #[serde(rename = "rd_um_per_v", with = "crate::units::um_per_v")]
    pub rd_m_per_v: f64,
    /// Its standard error, m/V (JSON key `rd_se_um_per_v`, µm/V).
    #[serde(rename = "rd_se_um_per_v", with = "crate::units::um_per_v")]
    pub rd_se_m_per_v: f64,
    /// Force sensitivity R_f = R_d κ, N/V (JSON key `rf_pn_per_v`, pN/V).
    #[serde(rename = "rf_pn_per_v", with = "crate::units::pn_per_v")]
    pub rf_n_per_v: f64,
    /// χ² per degree of freedom of the fit (≈ 1 for a good fit).
    pub chi2_per_dof: f64,
    /// Statistical backing P(χ² ≥ observed), %.
    pub backing_pct: f64,
    /// Diode roll-off frequency, Hz (with the diode filter).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub f_diode_hz: Option<f64>,
    /// Its standard error, Hz.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub f_diode_se_hz: Option<f64>,
    /// Diode relaxation factor α (with the diode filter).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alpha: Option<f64>,
    /// Its standard error.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alpha_se: Option<f64>,
    /// Drag used for κ and R_d, N·s/m.
    pub drag_n_s_m: f64,
    /// Blocked points fitted.
    pub n_points: usize,
    /// Fit iterations.
    pub iterations: usize,
}

impl TrapCalibrationSettings {
    /// Check every setting (errors name the option as the CLI spells it).
    pub fn validate(&self) -> Result<(), RigError> {
        let pos = RigError::require_positive;
        pos("fs", self.fs_hz)?;
        pos("radius", self.radius_m)?;
        pos("viscosity", self.viscosity_pa_s)?;
        pos("temperature", self.temperature_k)?;
        pos("fluid-density", self.fluid_density_kg_m3)?;
        pos("bead-density", self.bead_density_kg_m3)?;
        if let Some(h) = self.distance_to_surface_m
            && !(h.is_finite() && h > self.radius_m)
        {
            return Err(RigError::InvalidParameter {
                name: "distance-to-surface",
                value: h,
                reason: format!(
                    "the bead centre must be farther from the surface than its radius {} m",
                    self.radius_m
                ),
            });
        }
        if self.aliased && (self.hydro || self.diode) {
            return Err(RigError::InvalidInput(
                "--aliased fits the aliased Lorentzian of a point-sampled record and cannot be \
                 combined with --hydro or --diode (those assume an anti-aliased record)"
                    .into(),
            ));
        }
        let (lo, hi) = self.fit_range_hz;
        if !(lo.is_finite() && hi.is_finite() && lo >= 0.0 && hi > lo) {
            return Err(RigError::InvalidInput(format!(
                "fit range {lo},{hi} Hz: need 0 ≤ LO < HI"
            )));
        }
        if hi > 0.5 * self.fs_hz * (1.0 + 1e-12) {
            return Err(RigError::InvalidInput(format!(
                "fit range ends at {hi} Hz, above the Nyquist frequency {} Hz",
                0.5 * self.fs_hz
            )));
        }
        if self.points_per_block == 0 {
            return Err(RigError::InvalidInput(
                "points per block must be ≥ 1".into(),
            ));
        }
        Ok(())
    }

    /// Bulk Stokes drag γ₀, N·s/m.
    pub fn gamma0(&self) -> f64 {
        stokes_drag(self.viscosity_pa_s, self.radius_m)
    }

    /// Drag that converts f_c and D: γ₀ with the hydrodynamic model, else γ₀
    /// times Faxén's factor at the given distance, N·s/m.
    pub fn drag(&self) -> f64 {
        match (self.hydro, self.distance_to_surface_m) {
            (false, Some(h)) => self.gamma0() * faxen_parallel(self.radius_m / h),
            _ => self.gamma0(),
        }
    }

    /// The spectrum model these settings fit.
    pub fn model(&self) -> PsdModel {
        let shape = if self.hydro {
            SpectrumShape::Hydrodynamic(Hydrodynamics {
                gamma0_n_s_m: self.gamma0(),
                radius_m: self.radius_m,
                fluid_density_kg_m3: self.fluid_density_kg_m3,
                bead_density_kg_m3: self.bead_density_kg_m3,
                distance_to_surface_m: self.distance_to_surface_m,
            })
        } else if self.aliased {
            SpectrumShape::AliasedLorentzian { fs_hz: self.fs_hz }
        } else {
            SpectrumShape::Lorentzian
        };
        PsdModel {
            shape,
            diode: self.diode,
        }
    }
}

/// Calibrate from a detector record `volts` (V, trap held still): the fit
/// and the calibration it gives.
pub fn calibrate_trap(
    volts: &[f64],
    s: &TrapCalibrationSettings,
) -> Result<(TrapCalibration, PsdFit), RigError> {
    s.validate()?;
    let pg = Periodogram::new(volts, s.fs_hz)?;
    calibrate_periodogram(&pg, s)
}

/// [`calibrate_trap`] from a periodogram already computed.
pub fn calibrate_periodogram(
    pg: &Periodogram,
    s: &TrapCalibrationSettings,
) -> Result<(TrapCalibration, PsdFit), RigError> {
    s.validate()?;
    let fit = fit_power_spectrum(
        pg,
        s.fit_range_hz.0,
        s.fit_range_hz.1,
        s.points_per_block,
        &s.model(),
        &PsdFitOptions::default(),
    )?;
    Ok((from_fit(&fit, s), fit))
}

/// κ, R_d and R_f from a fit (module docs).
pub fn from_fit(fit: &PsdFit, s: &TrapCalibrationSettings) -> TrapCalibration {
    let gamma = s.drag();
    let kt = BOLTZMANN * s.temperature_k;
    let (corner_hz, d) = (fit.theta[0], fit.theta[1]);
    let (corner_se_hz, d_se) = (fit.se[0], fit.se[1]);
    let kappa = 2.0 * PI * gamma * corner_hz;
    let rd = (kt / (gamma * d)).sqrt();
    TrapCalibration {
        corner_hz,
        corner_se_hz,
        diffusion_v2_s: d,
        diffusion_se_v2_s: d_se,
        kappa_n_per_m: kappa,
        kappa_se_n_per_m: kappa / corner_hz * corner_se_hz,
        rd_m_per_v: rd,
        rd_se_m_per_v: rd / (2.0 * d) * d_se,
        rf_n_per_v: rd * kappa,
        chi2_per_dof: fit.chi2_per_dof(),
        backing_pct: fit.backing_pct,
        f_diode_hz: s.diode.then(|| fit.theta[2]),
        f_diode_se_hz: s.diode.then(|| fit.se[2]),
        alpha: s.diode.then(|| fit.theta[3]),
        alpha_se: s.diode.then(|| fit.se[3]),
        drag_n_s_m: gamma,
        n_points: fit.spectrum.f.len(),
        iterations: fit.iterations,
    }
}

/// Largest record [`record_detector`] takes, samples per axis (10⁸: 100 s
/// at 1 MHz, 1.6 GB for both axes).
pub const MAX_RECORD_SAMPLES: usize = 100_000_000;

/// Samples per block of a detector record: one exchange of a live
/// tweezer link ([`super::Tweezer::step_block`]).
pub const RECORD_BLOCK: usize = 10;

/// Record `n` samples of a tweezer's detector signals (V, x and y) with the
/// trap held at `trap_m` (m), after `settle` samples of settling that are
/// not kept, in blocks of [`RECORD_BLOCK`] samples; `progress` is called
/// with the samples done every 10⁴ samples. Fails if the tweezer reports no
/// detector signals, the bead escapes (the tweezer reports it untrapped:
/// "the bead was not trapped at sample i"), its link fails (naming the
/// tweezer link; nothing of the incomplete record is returned), or the
/// size is out of bounds.
pub fn record_detector(
    tw: &mut dyn super::Tweezer,
    trap_m: [f64; 2],
    settle: usize,
    n: usize,
    progress: &mut dyn FnMut(usize),
) -> Result<[Vec<f64>; 2], RigError> {
    if !(16..=MAX_RECORD_SAMPLES).contains(&n) {
        return Err(RigError::InvalidInput(format!(
            "a detector record of {n} samples; need between 16 and {MAX_RECORD_SAMPLES}"
        )));
    }
    let traps = [trap_m; RECORD_BLOCK];
    let mut out = [super::TweezerSample::default(); RECORD_BLOCK];
    let mut v = [[0.0; 2]; RECORD_BLOCK];
    let (mut x, mut y) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let total = settle + n;
    let mut i = 0;
    while i < total {
        let k = (total - i).min(RECORD_BLOCK);
        if !tw.step_block_detected(&traps[..k], &mut out[..k], &mut v[..k]) {
            return Err(RigError::Device(
                "this tweezer reports no position-detector signals".into(),
            ));
        }
        if let Some(e) = tw.link_error() {
            return Err(RigError::Disconnected(format!(
                "the tweezer link failed at sample {} of {n} ({}); the record is incomplete \
                 and was not kept",
                i.saturating_sub(settle),
                link_failure_words(e)
            )));
        }
        for j in 0..k {
            let Some(r) = (i + j).checked_sub(settle) else {
                continue;
            };
            if !out[j].trapped {
                return Err(RigError::Device(format!(
                    "the bead was not trapped at sample {r}: a calibration needs a trapped bead"
                )));
            }
            x.push(v[j][0]);
            y.push(v[j][1]);
            if (r + 1) % 10_000 == 0 {
                progress(r + 1);
            }
        }
        i += k;
    }
    Ok([x, y])
}

/// What a tweezer link failure of kind `k` means, in a researcher's words.
pub fn link_failure_words(k: crate::device::LinkErrorKind) -> &'static str {
    use crate::device::LinkErrorKind as K;
    match k {
        K::Disconnected => "no answer from the tweezer, or its port closed",
        K::Watchdog => "the tweezer's watchdog tripped: it waited too long for trap set-points",
        K::EmergencyStop => "the tweezer's emergency stop was engaged",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::DetectorConfig;
    use crate::tweezer::{DetectedTweezer, Tweezer, TweezerParams};

    fn settings(fs: f64) -> TrapCalibrationSettings {
        TrapCalibrationSettings {
            fs_hz: fs,
            radius_m: 1.5e-6,
            viscosity_pa_s: 1.0016e-3,
            temperature_k: 293.15,
            fit_range_hz: (20.0, 0.5 * fs),
            points_per_block: 50,
            hydro: false,
            diode: false,
            aliased: true,
            fluid_density_kg_m3: DEFAULT_FLUID_DENSITY_KG_M3,
            bead_density_kg_m3: DEFAULT_BEAD_DENSITY_KG_M3,
            distance_to_surface_m: Some(5e-6),
        }
    }

    #[test]
    fn simulated_detector_calibrates_to_the_simulated_trap() {
        // The simulated tweezer at 5 µm from the coverslip, point-sampled at
        // 10 kHz behind a detector of 0.5 V/µm: κ, R_d and f_c within 3.5 SE.
        let fs = 10e3;
        let p = TweezerParams {
            wall_distance_m: Some(5e-6),
            stiffness_n_per_m: 5e-5,
            seed: 4,
            ..TweezerParams::paper_default()
        };
        let det = DetectorConfig::default();
        let mut tw = DetectedTweezer::new(p.clone(), &det, fs).unwrap();
        tw.start_stationary();
        let [x, _] = record_detector(&mut tw, [0.0; 2], 0, 200_000, &mut |_| {}).unwrap();
        let (c, _) = calibrate_trap(&x, &settings(fs)).unwrap();
        let kappa = p.stiffness_n_per_m;
        assert!(
            (c.kappa_n_per_m - kappa).abs() < 3.5 * c.kappa_se_n_per_m,
            "{c:?} vs κ {kappa}"
        );
        assert!(
            (c.corner_hz - p.corner_hz()).abs() < 3.5 * c.corner_se_hz,
            "{c:?}"
        );
        let rd = 1.0 / det.sensitivity_v_per_m;
        assert!(
            (c.rd_m_per_v - rd).abs() < 3.5 * c.rd_se_m_per_v,
            "{c:?} vs {rd}"
        );
        assert!(c.kappa_se_n_per_m / c.kappa_n_per_m < 0.03, "{c:?}");
    }

    /// A tweezer whose link fails, or whose bead escapes, at sample `at`.
    struct Failing {
        at: usize,
        n: usize,
        escape: bool,
    }

    impl Tweezer for Failing {
        fn sample_rate_hz(&self) -> f64 {
            1e4
        }
        fn stiffness_n_per_m(&self) -> f64 {
            1e-5
        }
        fn step(&mut self, trap_m: [f64; 2]) -> crate::tweezer::TweezerSample {
            self.n += 1;
            crate::tweezer::TweezerSample {
                trap_m,
                trapped: !(self.escape && self.n > self.at),
                ..Default::default()
            }
        }
        fn reset(&mut self, _trap_m: [f64; 2]) {}
        fn detector_v(&self) -> Option<[f64; 2]> {
            Some([0.0; 2])
        }
        fn link_error(&self) -> Option<crate::device::LinkErrorKind> {
            (!self.escape && self.n > self.at).then_some(crate::device::LinkErrorKind::Watchdog)
        }
    }

    /// The error of a 100-sample record (5 settling) on a tweezer that
    /// fails at its 25th sample: by the link, or by an `escape`.
    fn record_failing_at_25(escape: bool) -> String {
        let mut tw = Failing {
            at: 25,
            n: 0,
            escape,
        };
        record_detector(&mut tw, [0.0; 2], 5, 100, &mut |_| {})
            .unwrap_err()
            .to_string()
    }

    /// A failed link is reported as the tweezer link's failure, an escape
    /// as an escape; neither returns a partial record.
    #[test]
    fn a_link_failure_is_not_an_escape() {
        let e = record_failing_at_25(false);
        assert!(
            e.contains("the tweezer link failed at sample 15 of 100"),
            "{e}"
        );
        assert!(
            e.contains("watchdog tripped") && !e.contains("not trapped"),
            "{e}"
        );
        let e = record_failing_at_25(true);
        assert!(e.contains("the bead was not trapped at sample 20"), "{e}");
    }

    #[test]
    fn settings_are_checked() {
        let mut s = settings(1e4);
        s.diode = true;
        assert!(s.validate().is_err(), "--aliased with --diode");
        let mut s = settings(1e4);
        s.fit_range_hz = (10.0, 6e3);
        assert!(s.validate().unwrap_err().to_string().contains("Nyquist"));
        let mut s = settings(1e4);
        s.distance_to_surface_m = Some(1e-6);
        assert!(s.validate().is_err());
        let mut tw = crate::tweezer::SimTweezer::new(TweezerParams::paper_default(), 1e4).unwrap();
        assert!(record_detector(&mut tw, [0.0; 2], 0, 100, &mut |_| {}).is_err());
        assert!(tw.detector_v().is_none());
    }
}
