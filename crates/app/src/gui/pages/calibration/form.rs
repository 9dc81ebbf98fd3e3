//! The wizard's settings: the text fields and choices, and the
//! [`CalibrationConfig`] they make (validated).

use crate::gui::path_field::labelled_line;
use kilotouch_rig::calibration::CalibrationConfig;

use super::{CalibrationPage, CrossoverRuleChoice};

impl CalibrationPage {
    /// The settings the next run uses (the base configuration with the
    /// page's overrides), or the reason they are invalid.
    pub fn effective_config(&self) -> Result<(CalibrationConfig, u64), String> {
        let seed: u64 = self.seed_text.trim().parse().map_err(|_| {
            format!(
                "seed `{}` is not a whole number in 0..=18446744073709551615",
                self.seed_text.trim()
            )
        })?;
        let mut cfg = self.config.clone();
        cfg.crossover.crossover_hz = match self.rule {
            CrossoverRuleChoice::Automatic => None,
            CrossoverRuleChoice::Fixed => Some(self.fixed_crossover_hz),
        };
        Ok((cfg, seed))
    }

    pub(super) fn settings_ui(&mut self, ui: &mut egui::Ui, fs: f64) {
        let running = self.is_running();
        egui::CollapsingHeader::new("Settings")
            .default_open(true)
            .show(ui, |ui| {
                ui.add_enabled_ui(!running, |ui| {
                    egui::Grid::new("cal-settings")
                        .num_columns(3)
                        .spacing([12.0, 4.0])
                        .show(ui, |ui| {
                            labelled_line(ui, "Noise seed", &mut self.seed_text, "seed", 120.0);
                            ui.label("seed of the simulated sensor noise");
                            ui.end_row();
                            for (name, exc) in [
                                ("Low channel (Pantograph)", &mut self.config.low),
                                ("High channel (Haptuator)", &mut self.config.high),
                            ] {
                                let l = ui.label(format!("{name}: level"));
                                ui.add(
                                    egui::DragValue::new(&mut exc.amplitude_fraction)
                                        .range(0.01..=1.0)
                                        .speed(0.01),
                                )
                                .labelled_by(l.id);
                                ui.label("MLS amplitude, fraction of the channel's limit");
                                ui.end_row();
                                let l = ui.label(format!("{name}: MLS order"));
                                ui.add(egui::DragValue::new(&mut exc.order).range(10..=18))
                                    .labelled_by(l.id);
                                let period = (1u64 << exc.order) - 1;
                                ui.label(format!(
                                    "period {period} samples = {:.2} s; {} periods analysed",
                                    period as f64 * f64::from(exc.hold) / fs,
                                    exc.periods
                                ));
                                ui.end_row();
                                let l = ui.label(format!("{name}: periods"));
                                ui.add(egui::DragValue::new(&mut exc.periods).range(1..=32))
                                    .labelled_by(l.id);
                                ui.label("periods averaged (record length)");
                                ui.end_row();
                            }
                            let l = ui.label("Crossover rule");
                            egui::ComboBox::from_id_salt("cal-xo-rule")
                                .selected_text(match self.rule {
                                    CrossoverRuleChoice::Automatic => "automatic",
                                    CrossoverRuleChoice::Fixed => "fixed frequency",
                                })
                                .show_ui(ui, |ui| {
                                    ui.selectable_value(
                                        &mut self.rule,
                                        CrossoverRuleChoice::Automatic,
                                        "automatic",
                                    );
                                    ui.selectable_value(
                                        &mut self.rule,
                                        CrossoverRuleChoice::Fixed,
                                        "fixed frequency",
                                    );
                                })
                                .response
                                .labelled_by(l.id);
                            ui.label(
                                "automatic: highest f_c whose predicted deviation is within \
                                 the budget",
                            );
                            ui.end_row();
                            let l = ui.label("Crossover frequency (Hz)");
                            ui.add_enabled(
                                self.rule == CrossoverRuleChoice::Fixed,
                                egui::DragValue::new(&mut self.fixed_crossover_hz)
                                    .range(10.0..=(0.45 * fs).max(20.0))
                                    .speed(1.0),
                            )
                            .labelled_by(l.id);
                            ui.label("used with the fixed rule");
                            ui.end_row();
                            let l = ui.label("Crossover order");
                            egui::ComboBox::from_id_salt("cal-xo-order")
                                .selected_text(format!("LR{}", self.config.crossover.order))
                                .show_ui(ui, |ui| {
                                    for o in [2usize, 4, 8] {
                                        ui.selectable_value(
                                            &mut self.config.crossover.order,
                                            o,
                                            format!("LR{o}"),
                                        );
                                    }
                                })
                                .response
                                .labelled_by(l.id);
                            ui.label("Linkwitz–Riley order (paper: 4)");
                            ui.end_row();
                            let l = ui.label("Verification tolerance (dB)");
                            ui.add(
                                egui::DragValue::new(&mut self.config.verify.tolerance_db)
                                    .range(0.1..=10.0)
                                    .speed(0.05),
                            )
                            .labelled_by(l.id);
                            ui.label("pass when every third-octave band is within ±tolerance");
                            ui.end_row();
                        });
                    if ui.button("Reset settings to defaults").clicked() {
                        self.config = CalibrationConfig::default();
                        self.seed_text = "1".into();
                        self.rule = CrossoverRuleChoice::Automatic;
                        self.fixed_crossover_hz = 200.0;
                    }
                });
            });
    }
}
