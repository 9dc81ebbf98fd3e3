//! The report of a calibration for the command line: a serde struct whose
//! JSON form is the contract of `kilotouch calibrate --json`, and a
//! human-readable table.

use super::CalibrationOutcome;
use super::crossover::CrossoverRule;
use super::interface::RigRecord;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;

/// A rational model, descending powers of s (rad/s).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelReport {
    /// Numerator coefficients.
    pub num: Vec<f64>,
    /// Denominator coefficients.
    pub den: Vec<f64>,
}

/// One verification band.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BandReport {
    /// Third-octave centre frequency, Hz.
    pub f: f64,
    /// Nominal label, e.g. "63".
    pub nominal: String,
    /// Deviation from the target with compensation, dB.
    pub db: f64,
    /// Deviation with the crossover alone, dB.
    pub uncompensated_db: f64,
    /// |db| within tolerance.
    pub within: bool,
    /// Band added below the main range (inside the low channel's flat band).
    pub extended: bool,
}

/// What `kilotouch calibrate --json` prints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationReport {
    /// Crossover frequency, Hz.
    pub crossover_hz: f64,
    /// Static gain of the low channel G0_L used in C_L = K_sys/G0_L (over
    /// the flat band below the crossover), (m/s²)/N.
    pub low_gain: f64,
    /// G0_L identified over the whole flat band (step 2), (m/s²)/N.
    pub low_gain_flat_band: f64,
    /// Identified high-channel model Ĝ_H(s).
    pub high_model: ModelReport,
    /// Verification table.
    pub bands: Vec<BandReport>,
    /// max |db| over the bands.
    pub max_abs_dev_db: f64,
    /// max |uncompensated_db| over the bands.
    pub uncompensated_max_abs_dev_db: f64,
    /// Group delay of the chain at low frequency, ms.
    pub group_delay_ms: f64,
    /// Every band within tolerance, none saturated.
    pub passed: bool,
    /// Tolerance, dB.
    pub tolerance_db: f64,
    /// Overall gain K_sys, (m/s²) per unit haptic signal.
    pub k_sys: f64,
    /// C_L = K_sys/G0_L, N per unit.
    pub c_l: f64,
    /// Flat band of the low channel, Hz.
    pub low_flat_band_hz: [f64; 2],
    /// Band over which Ĝ_H was fitted, Hz.
    pub high_reliable_band_hz: [f64; 2],
    /// True when the crossover was set by the configuration.
    pub crossover_overridden: bool,
    /// True when no crossover frequency met the predicted-deviation budget.
    pub crossover_over_budget: bool,
    /// True when the accelerometer response was divided out.
    pub sensor_corrected: bool,
    /// The rig.
    pub rig: RigRecord,
}

impl CalibrationReport {
    /// Report of a finished calibration.
    pub fn from_outcome(o: &CalibrationOutcome) -> Self {
        let v = &o.verification;
        Self {
            crossover_hz: o.crossover.crossover_hz,
            low_gain: o.design.g0_l,
            low_gain_flat_band: o.low.g0,
            high_model: ModelReport {
                num: o.high.model.num.clone(),
                den: o.high.model.den.clone(),
            },
            bands: v
                .bands
                .iter()
                .map(|b| BandReport {
                    f: b.centre_hz,
                    nominal: b.nominal.clone(),
                    db: b.db,
                    uncompensated_db: b.uncompensated_db,
                    within: b.within,
                    extended: b.extended,
                })
                .collect(),
            max_abs_dev_db: v.max_abs_dev_db,
            uncompensated_max_abs_dev_db: v.uncompensated_max_abs_dev_db,
            group_delay_ms: v.group_delay_ms,
            passed: v.passed,
            tolerance_db: v.tolerance_db,
            k_sys: o.design.k_sys,
            c_l: o.design.c_l,
            low_flat_band_hz: o.low.flat_band_hz,
            high_reliable_band_hz: o.high.reliable_band_hz,
            crossover_overridden: o.crossover.rule == CrossoverRule::Override,
            crossover_over_budget: o.crossover.over_budget,
            sensor_corrected: v.sensor_corrected,
            rig: o.rig.clone(),
        }
    }

    /// Human-readable summary and table (what the command prints without
    /// `--json`).
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "Calibration of rig {}", self.rig);
        let _ = writeln!(
            s,
            "  low channel   G0_L = {:.5} (m/s²)/N over the flat band {:.1}–{:.1} Hz; \
             C_L uses G0_L = {:.5} (m/s²)/N (flat band below the crossover)",
            self.low_gain_flat_band,
            self.low_flat_band_hz[0],
            self.low_flat_band_hz[1],
            self.low_gain
        );
        let _ = writeln!(
            s,
            "  high channel  Ĝ_H(s) = [{}] / [{}], fitted {:.1}–{:.1} Hz",
            join(&self.high_model.num),
            join(&self.high_model.den),
            self.high_reliable_band_hz[0],
            self.high_reliable_band_hz[1]
        );
        let _ = writeln!(
            s,
            "  crossover     {:.1} Hz{}{}, group delay {:.3} ms",
            self.crossover_hz,
            if self.crossover_overridden {
                " (set)"
            } else {
                ""
            },
            if self.crossover_over_budget {
                " (over the predicted-deviation budget)"
            } else {
                ""
            },
            self.group_delay_ms
        );
        let _ = writeln!(
            s,
            "  K_sys         {:.5} (m/s²)/unit, C_L = {:.5} N/unit{}",
            self.k_sys,
            self.c_l,
            if self.sensor_corrected {
                ""
            } else {
                ", sensor response NOT corrected"
            }
        );
        let _ = writeln!(s);
        let _ = writeln!(s, "  band (Hz)   compensated (dB)   crossover alone (dB)");
        for b in &self.bands {
            let _ = writeln!(
                s,
                "  {:>7}{}   {:>+10.2} {}      {:>+10.2}",
                b.nominal,
                if b.extended { "*" } else { " " },
                b.db,
                if b.within { " " } else { "!" },
                b.uncompensated_db
            );
        }
        let _ = writeln!(s);
        let _ = writeln!(
            s,
            "  max |deviation| {:.2} dB (crossover alone {:.2} dB), tolerance ±{} dB: {}",
            self.max_abs_dev_db,
            self.uncompensated_max_abs_dev_db,
            self.tolerance_db,
            if self.passed { "PASS" } else { "FAIL" }
        );
        if self.bands.iter().any(|b| b.extended) {
            let _ = writeln!(
                s,
                "  * band below the main range, inside the low channel's flat band"
            );
        }
        s
    }
}

fn join(v: &[f64]) -> String {
    v.iter()
        .map(|c| format!("{c:.6e}"))
        .collect::<Vec<_>>()
        .join(", ")
}
