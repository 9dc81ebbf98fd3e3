//! The result's summary: the closed loop with it, the verification verdict
//! and the identified models in words.

use kilotouch_rig::calibration::CalibrationFile;

use crate::gui::charts::{FAIL_COLOR, PASS_COLOR};
use crate::gui::pages::rig::margins_ui;

use super::{CalibrationPage, ResultSource};

impl CalibrationPage {
    pub(super) fn results_ui(&self, ui: &mut egui::Ui) {
        let Some(shown) = &self.shown else {
            ui.label("No calibration yet: start one, or load a calibration file.");
            return;
        };
        let f = &shown.file;
        let v = &f.verification;
        let source = match &shown.source {
            ResultSource::Wizard => "this session's run".to_owned(),
            ResultSource::Loaded(p) => p.display().to_string(),
        };
        ui.label(format!(
            "Calibration of `{}` (serial {}) from {source}",
            f.rig.name, f.rig.serial
        ));
        if let Some(p) = &shown.saved_to {
            ui.label(format!("saved to {}", p.display()));
        }
        egui::CollapsingHeader::new("Closed loop with this calibration")
            .default_open(true)
            .show(ui, |ui| match &shown.closed_loop {
                Ok(lc) => {
                    ui.label(
                        "The loop runs the calibration's chain force-normalised (K_sys = G0_L, so \
                         C_L = 1 N/N): the force rendered at low frequency is the same as without \
                         calibration; only the crossover's compensation changes.",
                    );
                    margins_ui(ui, &lc.report, "cal-margins", None);
                }
                Err(e) => {
                    ui.colored_label(FAIL_COLOR, format!("cannot build the closed loop: {e}"));
                }
            });
        let verdict = if v.passed {
            egui::RichText::new(format!(
                "Verification PASS: max |deviation| {:.2} dB within ±{} dB over {} bands \
                 (before compensation {:.1} dB)",
                v.max_abs_dev_db,
                v.tolerance_db,
                v.bands.len(),
                v.uncompensated_max_abs_dev_db
            ))
            .color(PASS_COLOR)
        } else {
            let worst = v
                .bands
                .iter()
                .filter(|b| !b.within || b.saturated)
                .map(|b| b.nominal.as_str())
                .collect::<Vec<_>>()
                .join(", ");
            egui::RichText::new(format!(
                "Verification FAIL: max |deviation| {:.2} dB, tolerance ±{} dB; bands out: {worst}",
                v.max_abs_dev_db, v.tolerance_db
            ))
            .color(FAIL_COLOR)
        };
        ui.label(verdict.strong().size(18.0));
        egui::Grid::new("cal-summary")
            .num_columns(2)
            .spacing([12.0, 2.0])
            .show(ui, |ui| {
                let mut row = |k: &str, val: String| {
                    ui.label(k);
                    ui.label(val);
                    ui.end_row();
                };
                row("crossover", crossover_words(f));
                row(
                    "low channel",
                    format!(
                        "G0_L = {:.5} (m/s²)/N over the flat band {:.0}–{:.0} Hz; C_L uses \
                         G0_L = {:.5} (m/s²)/N, the flat band below the crossover",
                        f.low.g0, f.low.flat_band_hz[0], f.low.flat_band_hz[1], f.compensators.g0_l
                    ),
                );
                row(
                    "high channel",
                    format!(
                        "Ĝ_H(s) num [{}], den [{}] (s in rad/s); reliable {:.0}–{:.0} Hz",
                        coefs(&f.high.model.num),
                        coefs(&f.high.model.den),
                        f.high.reliable_band_hz[0],
                        f.high.reliable_band_hz[1]
                    ),
                );
                row(
                    "overall gain",
                    format!(
                        "K_sys = {:.4} (m/s²)/unit (limited by {})",
                        f.compensators.k_sys, f.compensators.k_sys_limited_by
                    ),
                );
                row(
                    "group delay",
                    format!("{:.3} ms at low frequency", v.group_delay_ms),
                );
            });
        shown.plots.ui(ui, f);
    }
}

/// The crossover row: the frequency, how it was chosen, and the predicted
/// deviation set against the design target — with the measured
/// verification as the verdict, so an over-target prediction beside a
/// passed verification does not read as a contradiction.
fn crossover_words(f: &CalibrationFile) -> String {
    let c = &f.crossover;
    let how = match c.rule {
        kilotouch_rig::calibration::crossover::CrossoverRule::Automatic => "chosen automatically",
        kilotouch_rig::calibration::crossover::CrossoverRule::Override => "fixed by the settings",
    };
    let target = f.settings.crossover.budget_db;
    let prediction = if c.over_budget {
        format!(
            "no frequency met the design target of {target} dB predicted deviation, so the one \
             with the smallest was taken ({:.2} dB)",
            c.predicted_max_abs_dev_db
        )
    } else {
        format!(
            "predicted deviation {:.2} dB (design target {target} dB)",
            c.predicted_max_abs_dev_db
        )
    };
    let v = &f.verification;
    let verdict = format!(
        "the measured verification is the verdict: {:.2} dB against ±{} dB, {}",
        v.max_abs_dev_db,
        v.tolerance_db,
        if v.passed { "passed" } else { "failed" }
    );
    format!(
        "LR{} at {:.1} Hz, {how}; {prediction}; {verdict}",
        c.order, c.crossover_hz
    )
}

/// Polynomial coefficients, 4 significant digits.
fn coefs(c: &[f64]) -> String {
    c.iter()
        .map(|x| format!("{x:.4e}"))
        .collect::<Vec<_>>()
        .join(", ")
}
