//! A trap calibration in force: what the loop's tweezer uses instead of the
//! instrument's own bead position and stiffness, the check a fit must pass
//! before it is applied, and the record a study keeps of it.
//!
//! **In the loop** ([`AppliedTrap`]): the bead is placed at
//! trap + R_d·V from the detector signals V (volts) and the optical force is
//! κ_cal (trap − bead) (paper §4.1, eq. 4, with the calibrated κ). The live
//! tweezer link ([`crate::serial::LinkTweezer`]) and the simulated tweezer
//! behind its detector ([`super::DetectedTweezer`]) both use
//! [`AppliedTrap::bead_and_force`].
//!
//! **Before** ([`check_applicable`]): a calibration is refused when any
//! value is not finite or not positive, when the model does not describe
//! the spectrum (statistical backing below [`MIN_BACKING_PCT`] %, or χ² per
//! degree of freedom outside [`CHI2_PER_DOF_RANGE`]), or when κ is too
//! imprecise (relative standard error above [`MAX_KAPPA_REL_SE`]).
//!
//! **After** ([`TrapCalibrationRecord`]): the settings, both axes' results
//! and the values applied, as `session.json` records them.

use super::calibration::{TrapCalibration, TrapCalibrationSettings};
use crate::error::RigError;
use crate::units::{to_pn_per_um, to_um_per_v};
use serde::{Deserialize, Serialize};

/// Lowest statistical backing P(χ² ≥ observed) a fit may have to be
/// applied, %. A correct model gives a uniform backing, so this refuses one
/// good fit in a thousand.
pub const MIN_BACKING_PCT: f64 = 0.1;

/// χ² per degree of freedom a fit must lie in to be applied (a correct
/// model gives 1 ± √(2/dof)).
pub const CHI2_PER_DOF_RANGE: (f64, f64) = (0.5, 2.0);

/// Largest relative standard error of κ a fit may have to be applied.
pub const MAX_KAPPA_REL_SE: f64 = 0.2;

/// A trap calibration as the loop uses it (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AppliedTrap {
    /// Trap stiffness κ, N/m.
    pub stiffness_n_per_m: f64,
    /// Displacement sensitivity R_d per axis (x, y), m/V.
    pub rd_m_per_v: [f64; 2],
}

impl AppliedTrap {
    /// Refuse a non-finite or non-positive κ and a non-finite or zero R_d.
    pub fn validate(&self) -> Result<(), RigError> {
        let valid = self.stiffness_n_per_m.is_finite()
            && self.stiffness_n_per_m > 0.0
            && self.rd_m_per_v.iter().all(|r| r.is_finite() && *r != 0.0);
        if valid {
            Ok(())
        } else {
            Err(RigError::InvalidInput(format!(
                "trap calibration {self:?}: κ must be finite and > 0, R_d finite and non-zero"
            )))
        }
    }

    /// The bead, trap + R_d·V (m), and the optical force κ (trap − bead)
    /// (N) for the trap at `trap_m` (m) and detector signals `v` (V).
    #[inline]
    pub fn bead_and_force(&self, trap_m: [f64; 2], v: [f64; 2]) -> ([f64; 2], [f64; 2]) {
        let bead = [
            trap_m[0] + self.rd_m_per_v[0] * v[0],
            trap_m[1] + self.rd_m_per_v[1] * v[1],
        ];
        let k = self.stiffness_n_per_m;
        (bead, [k * (trap_m[0] - bead[0]), k * (trap_m[1] - bead[1])])
    }
}

/// Why `c` must not be applied (module docs), in a researcher's words; `Ok`
/// when it may.
pub fn check_applicable(c: &TrapCalibration) -> Result<(), String> {
    let values = [
        ("f_c", c.corner_hz),
        ("its standard error", c.corner_se_hz),
        ("κ", c.kappa_n_per_m),
        ("κ's standard error", c.kappa_se_n_per_m),
        ("R_d", c.rd_m_per_v),
        ("χ²/dof", c.chi2_per_dof),
        ("the backing", c.backing_pct),
    ];
    if let Some((name, v)) = values.iter().find(|(_, v)| !v.is_finite()) {
        return Err(format!("the fit failed: {name} is {v}"));
    }
    if !(c.corner_hz > 0.0 && c.kappa_n_per_m > 0.0 && c.rd_m_per_v > 0.0) {
        return Err(format!(
            "the fit failed: f_c {:.4} Hz, κ {:.4} pN/µm and R_d {:.4} µm/V must be > 0",
            c.corner_hz,
            to_pn_per_um(c.kappa_n_per_m),
            to_um_per_v(c.rd_m_per_v)
        ));
    }
    if c.backing_pct < MIN_BACKING_PCT {
        return Err(format!(
            "the model does not describe the spectrum: backing {:.2e} % < {MIN_BACKING_PCT} % \
             (check the fit range, the diode and aliasing options, and that the bead is \
             trapped alone and far from obstacles)",
            c.backing_pct
        ));
    }
    let (lo, hi) = CHI2_PER_DOF_RANGE;
    if !(lo..=hi).contains(&c.chi2_per_dof) {
        return Err(format!(
            "χ²/dof = {:.3} is outside [{lo}, {hi}]: the model does not describe the spectrum",
            c.chi2_per_dof
        ));
    }
    let rel = c.kappa_se_n_per_m / c.kappa_n_per_m;
    if rel > MAX_KAPPA_REL_SE {
        return Err(format!(
            "κ is too imprecise: ±{:.0} % (at most {:.0} %); record longer",
            100.0 * rel,
            100.0 * MAX_KAPPA_REL_SE
        ));
    }
    Ok(())
}

/// Whether the closed loop analysed in `report` stays within its margins
/// when the tweezer's force is rendered with the calibrated stiffness
/// `kappa_n_per_m` instead of the analysed one. The haptic image is
/// g·κ(bead − trap) with the force scale g, so rendering with κ_cal scales
/// the loop gain as the force scale g·κ_cal/κ would: it is safe when that
/// scale is at most the analysis' largest safe force scale.
pub fn check_loop_gain(
    report: &crate::stability::StabilityReport,
    kappa_n_per_m: f64,
) -> Result<(), String> {
    let analysed = report.trap_stiffness_n_per_m;
    let scale = report.force_scale * kappa_n_per_m / analysed;
    if scale.is_finite() && scale <= report.max_force_scale {
        Ok(())
    } else {
        Err(format!(
            "the loop was cleared for κ = {:.3} pN/µm at force scale {:.3e} N/N; κ = {:.3} pN/µm \
             renders like force scale {scale:.3e} N/N, above the largest safe {:.3e} N/N",
            to_pn_per_um(report.trap_stiffness_n_per_m),
            report.force_scale,
            to_pn_per_um(kappa_n_per_m),
            report.max_force_scale
        ))
    }
}

/// A trap calibration of both detector axes and what it applies: the
/// inverse-variance weighted κ of the two axes and each axis' R_d (the
/// `trap_calibration` of `session.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrapCalibrationRecord {
    /// Where the record came from (`sim`, `serial:PATH`).
    pub source: String,
    /// Samples per axis of the record.
    pub n_samples: usize,
    /// The settings of both fits.
    pub settings: TrapCalibrationSettings,
    /// The x axis' calibration.
    pub x: TrapCalibration,
    /// The y axis' calibration.
    pub y: TrapCalibration,
    /// κ applied: inverse-variance weighted mean of the axes, N/m (JSON key
    /// `kappa_pn_um`, pN/µm).
    #[serde(rename = "kappa_pn_um", with = "crate::units::pn_per_um")]
    pub kappa_n_per_m: f64,
    /// Its standard error, N/m (JSON key `kappa_se_pn_um`, pN/µm).
    #[serde(rename = "kappa_se_pn_um", with = "crate::units::pn_per_um")]
    pub kappa_se_n_per_m: f64,
    /// R_d applied per axis (x, y), m/V (JSON key `rd_um_per_v`, µm/V).
    #[serde(rename = "rd_um_per_v", with = "crate::units::um_per_v")]
    pub rd_m_per_v: [f64; 2],
}

impl TrapCalibrationRecord {
    /// Combine the two axes' calibrations (κ weighted by 1/SE²).
    pub fn new(
        source: &str,
        n_samples: usize,
        settings: TrapCalibrationSettings,
        x: TrapCalibration,
        y: TrapCalibration,
    ) -> Self {
        let (wx, wy) = (x.kappa_se_n_per_m.powi(-2), y.kappa_se_n_per_m.powi(-2));
        let (kappa, se) = if wx.is_finite() && wy.is_finite() && wx + wy > 0.0 {
            (
                (wx * x.kappa_n_per_m + wy * y.kappa_n_per_m) / (wx + wy),
                (wx + wy).sqrt().recip(),
            )
        } else {
            (
                0.5 * (x.kappa_n_per_m + y.kappa_n_per_m),
                0.5 * x.kappa_se_n_per_m.hypot(y.kappa_se_n_per_m),
            )
        };
        Self {
            source: source.to_owned(),
            n_samples,
            settings,
            rd_m_per_v: [x.rd_m_per_v, y.rd_m_per_v],
            x,
            y,
            kappa_n_per_m: kappa,
            kappa_se_n_per_m: se,
        }
    }

    /// Why this record must not be applied (both axes checked, [`check_applicable`]).
    pub fn check(&self) -> Result<(), String> {
        check_applicable(&self.x).map_err(|e| format!("x axis: {e}"))?;
        check_applicable(&self.y).map_err(|e| format!("y axis: {e}"))?;
        self.applied()
            .validate()
            .map_err(|e| e.to_string())
            .map(|_| ())
    }

    /// What the loop uses.
    pub fn applied(&self) -> AppliedTrap {
        AppliedTrap {
            stiffness_n_per_m: self.kappa_n_per_m,
            rd_m_per_v: self.rd_m_per_v,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// κ ± SE in N/m, R_d 2 µm/V.
    fn cal(kappa: f64, se: f64) -> TrapCalibration {
        TrapCalibration {
            corner_hz: 100.0,
            corner_se_hz: 100.0 * se / kappa,
            diffusion_v2_s: 0.03,
            diffusion_se_v2_s: 1e-4,
            kappa_n_per_m: kappa,
            kappa_se_n_per_m: se,
            rd_m_per_v: 2e-6,
            rd_se_m_per_v: 0.01e-6,
            rf_n_per_v: 2e-6 * kappa,
            chi2_per_dof: 1.02,
            backing_pct: 35.0,
            f_diode_hz: None,
            f_diode_se_hz: None,
            alpha: None,
            alpha_se: None,
            drag_n_s_m: 2.8e-8,
            n_points: 500,
            iterations: 5,
        }
    }

    #[test]
    fn bad_fits_are_refused_with_the_reason() {
        assert!(check_applicable(&cal(20e-6, 0.4e-6)).is_ok());
        let mut c = cal(20e-6, 0.4e-6);
        c.kappa_n_per_m = f64::NAN;
        assert!(check_applicable(&c).unwrap_err().contains("κ is NaN"));
        let mut c = cal(20e-6, 0.4e-6);
        c.backing_pct = 1e-5;
        assert!(check_applicable(&c).unwrap_err().contains("backing"));
        let mut c = cal(20e-6, 0.4e-6);
        c.chi2_per_dof = 3.1;
        assert!(check_applicable(&c).unwrap_err().contains("χ²/dof = 3.100"));
        assert!(
            check_applicable(&cal(20e-6, 5e-6))
                .unwrap_err()
                .contains("imprecise")
        );
        let mut c = cal(20e-6, 0.4e-6);
        c.rd_m_per_v = -1e-6;
        assert!(check_applicable(&c).is_err());
    }

    #[test]
    fn axes_combine_by_inverse_variance_and_the_loop_sees_si_units() {
        let s = TrapCalibrationSettings {
            fs_hz: 1e4,
            radius_m: 1.5e-6,
            viscosity_pa_s: 1.0016e-3,
            temperature_k: 293.15,
            fit_range_hz: (10.0, 5e3),
            points_per_block: 50,
            hydro: false,
            diode: false,
            aliased: true,
            fluid_density_kg_m3: 997.0,
            bead_density_kg_m3: 1060.0,
            distance_to_surface_m: None,
        };
        let r = TrapCalibrationRecord::new("sim", 1000, s, cal(20e-6, 1e-6), cal(22e-6, 2e-6));
        // (20/1 + 22/4)/(1 + 1/4) = 20.4 pN/µm, SE 1/√1.25 pN/µm.
        assert!((r.kappa_n_per_m - 20.4e-6).abs() < 1e-18);
        assert!((r.kappa_se_n_per_m - 1e-6 / 1.25f64.sqrt()).abs() < 1e-18);
        let a = r.applied();
        assert!((a.stiffness_n_per_m - 20.4e-6).abs() < 1e-18);
        assert_eq!(a.rd_m_per_v, [2e-6, 2e-6]);
        assert!(r.check().is_ok());
        // Bead at trap + R_d·V, force κ (trap − bead).
        let (b, f) = a.bead_and_force([1e-6, 0.0], [0.5, -0.25]);
        assert!((b[0] - 2e-6).abs() < 1e-18 && (b[1] + 0.5e-6).abs() < 1e-18);
        assert!((f[0] + 20.4e-6 * 1e-6).abs() < 1e-20 && (f[1] - 20.4e-6 * 0.5e-6).abs() < 1e-20);
        assert!(
            AppliedTrap {
                stiffness_n_per_m: 0.0,
                rd_m_per_v: [1.0; 2]
            }
            .validate()
            .is_err()
        );
    }

    #[test]
    fn a_record_written_in_pn_per_um_loads_and_is_written_back_identically() {
        // Written by `kilotouch tweezer record --calibration-out` when the
        // record held pN/µm and µm/V.
        let text = include_str!("../../tests/data/trap_calibration_record.json");
        let r: TrapCalibrationRecord = serde_json::from_str(text).unwrap();
        let file: serde_json::Value = serde_json::from_str(text).unwrap();
        let num = |v: &serde_json::Value| v.as_f64().unwrap();
        let ulps = |a: f64, b: f64| a.to_bits().abs_diff(b.to_bits());
        // The loop gets what it got from the file before: pN/µm × 1e-6
        // (within one unit in the last place: now the correctly rounded
        // pN/µm ÷ 10⁶).
        let a = r.applied();
        assert!(ulps(a.stiffness_n_per_m, num(&file["kappa_pn_um"]) * 1e-6) <= 1);
        for k in 0..2 {
            assert!(ulps(a.rd_m_per_v[k], num(&file["rd_um_per_v"][k]) * 1e-6) <= 1);
        }
        assert!(ulps(r.x.rf_n_per_v, num(&file["x"]["rf_pn_per_v"]) * 1e-12) <= 1);
        assert!((r.kappa_n_per_m - 20.19e-6).abs() < 0.01e-6, "{r:?}");
        // Keys and units as they were, every number within a unit in the
        // last place (exactly with an exact float parser: the study crate's
        // tests, serde_json's `float_roundtrip`).
        fn same(a: &serde_json::Value, b: &serde_json::Value) -> bool {
            use serde_json::Value::{Array, Number, Object};
            match (a, b) {
                (Number(x), Number(y)) if x.is_f64() || y.is_f64() => {
                    let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
                    x.to_bits().abs_diff(y.to_bits()) <= 1
                }
                (Array(x), Array(y)) => {
                    x.len() == y.len() && x.iter().zip(y).all(|(x, y)| same(x, y))
                }
                (Object(x), Object(y)) => {
                    x.len() == y.len()
                        && x.iter().all(|(k, v)| y.get(k).is_some_and(|w| same(v, w)))
                }
                _ => a == b,
            }
        }
        let back = serde_json::to_value(&r).unwrap();
        assert!(same(&back, &file), "{back}");
    }
}
