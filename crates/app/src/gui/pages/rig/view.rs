//! The Rig page's view pieces that need no page state: the run controls,
//! the last error, the connected rig's status, and the stability-margin
//! table (also on the Calibration page).

use crate::engine::{EngineHandle, SafetyState};
use crate::gui::env::{PageEnv, ShellRequest};
use crate::gui::plot::format_si;
use egui::{Color32, RichText};
use kilotouch_rig::stability::StabilityReport;
use kilotouch_rig::units::to_pn_per_um;

/// Disconnect, and Pause/Resume or Reconnect after a fault.
pub(super) fn run_controls_ui(
    ui: &mut egui::Ui,
    engine: Option<&EngineHandle>,
    requests: &mut Vec<ShellRequest>,
) {
    ui.horizontal(|ui| match engine {
        None => {
            ui.label("Disconnected.");
        }
        Some(h) => {
            if ui
                .add(egui::Button::new("Disconnect").min_size(egui::vec2(110.0, 28.0)))
                .clicked()
            {
                requests.push(ShellRequest::Disconnect);
            }
            let running = h.health().is_none_or(|x| x.running);
            let faulted = h.last_error().is_some()
                || h.health().is_some_and(|x| x.safety == SafetyState::Fault);
            if faulted {
                if ui
                    .add(
                        egui::Button::new(RichText::new("Reconnect").strong())
                            .min_size(egui::vec2(110.0, 28.0)),
                    )
                    .on_hover_text(
                        "reopen the device and resume (outputs ramp on again through \
                         the safety layer)",
                    )
                    .clicked()
                {
                    requests.push(ShellRequest::Reconnect);
                }
            } else if running {
                if ui.button("Pause").clicked() {
                    requests.push(ShellRequest::StopEngine);
                }
            } else if ui.button("Resume").clicked() {
                requests.push(ShellRequest::StartEngine);
            }
        }
    });
}

/// The connected rig's last error: outputs at zero, the loop stopped.
pub(super) fn error_ui(ui: &mut egui::Ui, h: &EngineHandle) {
    if let Some(e) = h.last_error() {
        ui.group(|ui| {
            ui.colored_label(
                Color32::from_rgb(235, 80, 70),
                RichText::new(format!("Rig error: {e}")).strong(),
            );
            ui.label(
                "Outputs were commanded to zero and the loop stopped. Check the cable \
                 or the device, then press Reconnect (or edit the rig field and \
                 Connect).",
            );
        });
        ui.add_space(6.0);
    }
}

/// The connected rig: its identity, health and loop margins.
pub(super) fn status_ui(ui: &mut egui::Ui, env: &PageEnv<'_>, h: &EngineHandle) {
    ui.columns(2, |cols| {
        cols[0].group(|ui| {
            ui.label(RichText::new("Identity").strong());
            let id = h.identity();
            egui::Grid::new("rig-identity")
                .striped(true)
                .show(ui, |ui| {
                    let rows = [
                        ("name", id.name.clone()),
                        ("kind", format!("{:?}", id.kind)),
                        ("rig", h.spec().describe()),
                        ("serial", id.serial.clone()),
                        ("firmware", id.firmware.clone()),
                        ("sample rate", format!("{:.0} Hz", id.sample_rate_hz)),
                        ("Pantograph force limit", format!("±{} N", id.force_max_n)),
                        (
                            "Haptuator drive limit",
                            format!("±{} V", id.haptuator_max_v),
                        ),
                        (
                            "accelerometer range",
                            format!("±{:.1} m/s²", id.accel_range_m_s2),
                        ),
                    ];
                    for (k, v) in rows {
                        ui.label(k);
                        ui.label(v);
                        ui.end_row();
                    }
                });
        });
        cols[1].group(|ui| {
            ui.label(RichText::new("Status").strong());
            match h.health() {
                None => {
                    ui.label("waiting for the engine…");
                }
                Some(x) => {
                    let col = match x.safety {
                        SafetyState::EStop | SafetyState::Fault => Color32::RED,
                        SafetyState::Enabled => Color32::from_rgb(60, 200, 90),
                        _ => ui.visuals().text_color(),
                    };
                    ui.colored_label(col, format!("safety: {}", x.status_label()));
                    egui::Grid::new("rig-status").striped(true).show(ui, |ui| {
                        let r = &x.rig;
                        let rows = [
                            ("state", format!("{:?}", r.state)),
                            ("loop rate", format!("{:.0} Hz", x.loop_rate_hz)),
                            ("load", format!("{:.2} %", 100.0 * x.load)),
                            ("deadline misses", x.deadline_misses.to_string()),
                            (
                                "worst lateness (window)",
                                format!("{:.2} ms", 1e3 * x.worst_lateness_s.max(0.0)),
                            ),
                            ("stalls (re-anchored)", x.overruns.to_string()),
                            ("frames", r.frames.to_string()),
                            ("lost frames", r.lost_frames.to_string()),
                            ("accelerometer clipped", r.clipped_frames.to_string()),
                            ("commands limited", r.limited_frames.to_string()),
                            ("Haptuator end stop", r.end_stop_frames.to_string()),
                            ("non-finite commands", r.nonfinite_commands.to_string()),
                            (
                                "passivity controller active",
                                x.coupling.passivity_active.to_string(),
                            ),
                            (
                                "trap at workspace edge",
                                x.coupling.workspace_clamped.to_string(),
                            ),
                            ("telemetry dropped", x.telemetry_dropped.to_string()),
                            (
                                "frames zeroed (e-stop, fault)",
                                x.estop_zeroed_frames.to_string(),
                            ),
                        ];
                        for (k, v) in rows {
                            ui.label(k);
                            ui.label(v);
                            ui.end_row();
                        }
                    });
                    if let Some(o) = h.last_swap() {
                        ui.label(crate::gui::app::swap_words(o));
                    }
                }
            }
        });
    });
    // Full width: the margins table has long rows that a half-width
    // column would let run into the Status box.
    ui.add_space(6.0);
    ui.group(|ui| {
        ui.set_width(ui.available_width());
        ui.label(RichText::new("Closed-loop stability").strong());
        ui.label(format!("D chain: {}", h.chain_source().describe()));
        match h.stability() {
            Some(r) => margins_ui(
                ui,
                r,
                "rig-margins",
                env.trap_applied.map(|t| t.kappa_n_per_m),
            ),
            None => {
                ui.label("not analysed (the loop was armed without the analysis)");
            }
        }
    });
}

/// A factor in scientific notation with a superscript exponent, e.g.
/// 1.0·10¹¹.
fn sci(x: f64) -> String {
    if !(x.is_finite() && x > 0.0) {
        return if x.is_infinite() {
            "∞".into()
        } else {
            format!("{x}")
        };
    }
    let e = x.log10().floor() as i32;
    let m = x / 10f64.powi(e);
    if e < 0 {
        // egui's font has the superscript digits but no superscript minus.
        return format!("{m:.1}e{e}");
    }
    let sup: String = e
        .to_string()
        .chars()
        .map(|d| {
            ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'][d.to_digit(10).unwrap_or(0) as usize]
        })
        .collect();
    format!("{m:.1}·10{sup}")
}

/// Green/red for a margin against its minimum.
fn verdict_color(ok: bool) -> Color32 {
    if ok {
        Color32::from_rgb(60, 200, 90)
    } else {
        Color32::from_rgb(235, 80, 70)
    }
}

fn fmt_or_inf(x: f64, unit: &str) -> String {
    if x.is_finite() && unit.is_empty() {
        format!("{x:.1}")
    } else if x.is_finite() {
        format!("{x:.1} {unit}")
    } else {
        "∞".to_owned()
    }
}

/// The stability report as a table: per condition the worst-case gain and
/// phase margins over the hand range and the free/pressed states, the
/// verdict, and the critical values (Rig and Calibration pages).
///
/// `applied_kappa_n_per_m`: the trap stiffness of an applied trap
/// calibration (N/m), shown instead of the rig file's.
pub fn margins_ui(
    ui: &mut egui::Ui,
    r: &StabilityReport,
    id: &str,
    applied_kappa_n_per_m: Option<f64>,
) {
    egui::Grid::new(id).striped(true).show(ui, |ui| {
        for h in ["", "gain margin", "phase margin", "verdict", "worst at"] {
            ui.label(RichText::new(h).strong());
        }
        ui.end_row();
        for c in &r.conditions {
            ui.label(RichText::new(c.condition.code()).strong());
            ui.colored_label(
                verdict_color(c.gain_margin_db >= r.min_gain_margin_db),
                fmt_or_inf(c.gain_margin_db, "dB"),
            );
            ui.colored_label(
                verdict_color(c.phase_margin_deg >= r.min_phase_margin_deg),
                fmt_or_inf(c.phase_margin_deg, "°"),
            );
            let v = if !c.stable {
                "UNSTABLE"
            } else if c.meets_minimum {
                "safe"
            } else {
                "below the minimum"
            };
            ui.colored_label(verdict_color(c.meets_minimum), v);
            let w = &c.worst_phase_case;
            let axis = match w.axis {
                kilotouch_rig::Axis::X => "x",
                kilotouch_rig::Axis::Y => "y",
            };
            let state = match w.state {
                kilotouch_rig::stability::LoopState::Free => "free",
                kilotouch_rig::stability::LoopState::Pressed => "pressed",
            };
            ui.label(format!("{axis}, {state}")).on_hover_text(format!(
                "finger {:.0} N/m, {:.1} N·s/m",
                w.hand.stiffness_n_per_m, w.hand.damping_n_s_per_m
            ));
            ui.end_row();
        }
    });
    ui.add_space(4.0);
    egui::Grid::new(format!("{id}-critical")).show(ui, |ui| {
        let rows = [
            (
                "required",
                format!(
                    "≥ {} dB and ≥ {}°",
                    r.min_gain_margin_db, r.min_phase_margin_deg
                ),
            ),
            (
                "trap stiffness",
                match applied_kappa_n_per_m {
                    Some(k) => format!(
                        "{:.2} pN/µm from the applied trap calibration (the margins are for \
                         the rig file's {:.2}; unstable above {})",
                        to_pn_per_um(k),
                        to_pn_per_um(r.trap_stiffness_n_per_m),
                        fmt_or_inf(to_pn_per_um(r.critical_trap_stiffness_n_per_m), "pN/µm")
                    ),
                    None => format!(
                        "{:.2} pN/µm, the rig file's (unstable above {})",
                        to_pn_per_um(r.trap_stiffness_n_per_m),
                        fmt_or_inf(to_pn_per_um(r.critical_trap_stiffness_n_per_m), "pN/µm")
                    ),
                },
            ),
            (
                "force scale",
                format!(
                    "1 pN on the bead is felt as {} at the hand (×{})",
                    format_si(1e-12 * r.force_scale, "N"),
                    sci(r.force_scale)
                ),
            ),
            (
                "largest safe force scale",
                format!(
                    "1 pN felt as {} (×{}); the loop is unstable from 1 pN felt as {} (×{})",
                    format_si(1e-12 * r.max_force_scale, "N"),
                    sci(r.max_force_scale),
                    format_si(1e-12 * r.critical_force_scale, "N"),
                    sci(r.critical_force_scale)
                ),
            ),
            (
                "pressed stiffness at the handle",
                format!("{:.0} N/m", r.pressed_stiffness_n_per_m),
            ),
            (
                "Haptuator full scale",
                format!(
                    "{:.2} N (high band at g_H = {:.3}; largest safe g_H {})",
                    r.high_band_force_full_scale_n,
                    r.high_band_gain,
                    fmt_or_inf(r.max_high_band_gain, "")
                ),
            ),
            ("P renders", r.p_mode.describe()),
        ];
        for (k, v) in rows {
            ui.label(k);
            ui.label(v);
            ui.end_row();
        }
    });
    if let Some(why) = r.refusal() {
        ui.colored_label(verdict_color(false), why);
    }
}
