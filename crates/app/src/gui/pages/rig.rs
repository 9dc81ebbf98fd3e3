//! Rig page: which rig (simulated, serial DAQ, audio interface — the
//! `--rig` syntax of [`RigSpec`]), which rig file, connect/disconnect,
//! reconnect after a device fault, identity, status and counters, and the
//! closed loop's stability margins with the chain the engine runs, and the
//! tweezer's trap calibration ([`super::rig_tweezer`]).

use super::rig_tweezer::TweezerSection;
use crate::engine::{EngineHandle, SafetyState};
use crate::gui::env::{PageEnv, ShellRequest};
use crate::gui::path_field::{PathField, PathKind, TOML};
use crate::gui::plot::format_si;
use egui::{Color32, RichText};
use kilotouch_rig::device::{RigSpec, TweezerSpec};
use kilotouch_rig::stability::StabilityReport;
use kilotouch_rig::units::to_pn_per_um;

/// Hint shown under the rig field.
pub const RIG_HINT: &str = "sim  ·  serial:/dev/ttyACM0[,baud=N][,timeout-ms=N]  ·  audio[:DEVICE]  \
     (a device emulator: `kilotouch emulate daq --pty` prints its port)";

/// The Rig page.
#[derive(Debug)]
pub struct RigPage {
    /// Text of the rig field (`sim`, `serial:PATH…`, `audio[:DEVICE]`).
    pub rig_text: String,
    /// Text of the tweezer field (`sim`, `serial:PATH…`).
    pub tweezer_text: String,
    /// Text of the rig-file field.
    pub path_text: String,
    /// The Tweezer section (trap calibration).
    pub tweezer: TweezerSection,
    rig_file_field: PathField,
    /// The Lab Streaming Layer outlets of the connected engine, while on.
    #[cfg(feature = "lsl")]
    lsl: Option<crate::lsl::LslPublisher>,
    /// Why the outlets could not start.
    #[cfg(feature = "lsl")]
    lsl_error: Option<String>,
}

impl Default for RigPage {
    fn default() -> Self {
        Self::new()
    }
}

impl RigPage {
    /// New page.
    pub fn new() -> Self {
        Self {
            rig_text: "sim".to_owned(),
            tweezer_text: "sim".to_owned(),
            path_text: String::new(),
            tweezer: TweezerSection::new(),
            rig_file_field: PathField::default(),
            #[cfg(feature = "lsl")]
            lsl: None,
            #[cfg(feature = "lsl")]
            lsl_error: None,
        }
    }

    /// The rig the rig field names (empty = `sim`).
    pub fn spec(&self) -> Result<RigSpec, kilotouch_rig::RigError> {
        let t = self.rig_text.trim();
        if t.is_empty() {
            Ok(RigSpec::Sim)
        } else {
            t.parse()
        }
    }

    /// The tweezer the tweezer field names (empty = `sim`).
    pub fn tweezer_spec(&self) -> Result<TweezerSpec, kilotouch_rig::RigError> {
        let t = self.tweezer_text.trim();
        if t.is_empty() {
            Ok(TweezerSpec::Sim)
        } else {
            t.parse()
        }
    }

    /// The tweezer row of the Device group: simulated or live, the field,
    /// and what the running engine has.
    fn tweezer_row(
        &mut self,
        ui: &mut egui::Ui,
        engine: Option<&EngineHandle>,
        requests: &mut Vec<ShellRequest>,
    ) {
        let spec = self.tweezer_spec();
        ui.horizontal(|ui| {
            for (label, text) in [
                ("Simulated tweezer", "sim"),
                ("Serial tweezer", "serial:/dev/ttyACM1"),
            ] {
                let on = matches!(
                    (&spec, text),
                    (Ok(TweezerSpec::Sim), "sim")
                        | (Ok(TweezerSpec::Serial(_)), "serial:/dev/ttyACM1")
                );
                if ui.add(egui::Button::selectable(on, label)).clicked() && !on {
                    self.tweezer_text = text.to_owned();
                }
            }
        });
        ui.horizontal(|ui| {
            let label = ui.label("Tweezer:");
            let edit = ui
                .add(
                    egui::TextEdit::singleline(&mut self.tweezer_text)
                        .hint_text("sim")
                        .desired_width(360.0),
                )
                .labelled_by(label.id);
            if edit.lost_focus()
                && ui.input(|i| i.key_pressed(egui::Key::Enter))
                && self.tweezer_spec().is_ok()
            {
                requests.push(ShellRequest::Connect);
            }
        });
        match spec {
            Err(e) => {
                ui.colored_label(Color32::from_rgb(230, 70, 60), e.to_string());
            }
            Ok(TweezerSpec::Sim) => {
                ui.weak("Simulated tweezer: the rig file's bead, trap and obstacles.");
            }
            Ok(TweezerSpec::Serial(_)) => {
                ui.label(
                    "Live tweezer: trap set-points and bead samples are exchanged in blocks at \
                     the rig's rate; its command lead adds to the loop delay the stability \
                     check is made with. An applied trap calibration sets the κ and the \
                     detector sensitivity the optical force is computed with. Connect to use it.",
                );
            }
        }
        if let Some(t) = engine.and_then(|e| e.live_tweezer()) {
            ui.label(format!(
                "Connected tweezer: {} (firmware {}), command lead {} samples{}",
                t.name,
                t.firmware,
                t.lead_samples,
                t.round_trip_s
                    .map(|r| format!(", round trip {:.2} ms", r * 1e3))
                    .unwrap_or_default()
            ));
        }
    }

    /// The Lab Streaming Layer publisher while streaming is on (the shell
    /// hands its markers to the Study page's sittings).
    #[cfg(feature = "lsl")]
    pub fn lsl(&self) -> Option<&crate::lsl::LslPublisher> {
        self.lsl.as_ref()
    }

    /// Is an audio-interface rig available in this build?
    pub fn audio_built() -> bool {
        cfg!(feature = "audio")
    }

    /// Draw the page with the engine taken out of `env` (so that `env`
    /// stays free for the sections); what the user asks of the shell goes
    /// to `env.requests`.
    fn draw(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>, engine: Option<&EngineHandle>) {
        let mut requests = Vec::new();
        egui::ScrollArea::vertical().show(ui, |ui| {
            ui.heading("Rig");
            self.device_ui(ui, engine, &mut requests);
            ui.add_space(6.0);
            self.rig_file_ui(ui, env, &mut requests);
            ui.add_space(6.0);
            self.tweezer.engine_tweezer = engine
                .and_then(|e| e.live_tweezer())
                .map(|t| t.spec.describe());
            self.tweezer.ui(ui, env, engine.is_some());
            ui.add_space(6.0);
            run_controls_ui(ui, engine, &mut requests);
            ui.add_space(6.0);
            #[cfg(feature = "lsl")]
            self.lsl_ui(ui, engine);
            if let Some(h) = engine {
                error_ui(ui, h);
                status_ui(ui, env, h);
            }
        });
        env.requests.extend(requests);
    }

    /// The Lab Streaming Layer switch: on, the connected engine's samples
    /// and events go to the `kilotouch-markers` and `kilotouch-signals`
    /// outlets (docs/LSL.md); the stream names and whether a consumer
    /// (LabRecorder) is connected. Off when the engine disconnects.
    #[cfg(feature = "lsl")]
    fn lsl_ui(&mut self, ui: &mut egui::Ui, engine: Option<&EngineHandle>) {
        use crate::lsl::{LslIdentity, MARKER_STREAM, SIGNAL_STREAM};
        let Some(h) = engine else {
            self.lsl = None;
            return;
        };
        ui.group(|ui| {
            let mut on = self.lsl.is_some();
            if ui
                .checkbox(&mut on, "Stream to Lab Streaming Layer (1 kHz)")
                .on_hover_text("markers and haptic signals for LabRecorder (docs/LSL.md)")
                .changed()
            {
                if on {
                    let id = LslIdentity {
                        study: "explore".to_owned(),
                        participant: String::new(),
                        id_width: 2,
                    };
                    match h.start_lsl(1000.0, id) {
                        Ok(p) => {
                            self.lsl = Some(p);
                            self.lsl_error = None;
                        }
                        Err(e) => self.lsl_error = Some(e.to_string()),
                    }
                } else if let Some(p) = self.lsl.take() {
                    p.stop();
                }
            }
            if let Some(p) = &self.lsl {
                let (m, s) = p.consumers();
                let state = |c: bool| {
                    if c {
                        "consumer connected"
                    } else {
                        "no consumer"
                    }
                };
                ui.label(format!("{MARKER_STREAM}: {}", state(m)));
                ui.label(format!(
                    "{SIGNAL_STREAM} ({} Hz): {}",
                    p.signal_rate_hz,
                    state(s)
                ));
                if p.dropped() > 0 {
                    ui.colored_label(
                        Color32::from_rgb(200, 120, 0),
                        format!("{} records dropped", p.dropped()),
                    );
                }
                ui.ctx()
                    .request_repaint_after(std::time::Duration::from_millis(500));
            }
            if let Some(e) = &self.lsl_error {
                ui.colored_label(Color32::from_rgb(200, 0, 0), e);
            }
        });
    }

    /// The device: kind, rig text, Connect, what the rig is, the tweezer row.
    fn device_ui(
        &mut self,
        ui: &mut egui::Ui,
        engine: Option<&EngineHandle>,
        requests: &mut Vec<ShellRequest>,
    ) {
        let spec = self.spec();
        ui.group(|ui| {
            ui.label(RichText::new("Device").strong());
            ui.horizontal(|ui| {
                for (label, text) in [
                    ("Simulated", "sim"),
                    ("Serial DAQ", "serial:/dev/ttyACM0"),
                    ("Audio interface", "audio"),
                ] {
                    let on = matches!(
                        (&spec, text),
                        (Ok(RigSpec::Sim), "sim")
                            | (Ok(RigSpec::Serial(_)), "serial:/dev/ttyACM0")
                            | (Ok(RigSpec::Audio(_)), "audio")
                    );
                    let enabled = text != "audio" || Self::audio_built();
                    let b = ui.add_enabled(enabled, egui::Button::selectable(on, label));
                    let b = b.on_disabled_hover_text(
                        "not in this build (cargo feature `audio`, needs libasound2-dev)",
                    );
                    if b.clicked() && !on {
                        self.rig_text = text.to_owned();
                    }
                }
            });
            ui.horizontal(|ui| {
                let label = ui.label("Rig:");
                let edit = ui
                    .add(
                        egui::TextEdit::singleline(&mut self.rig_text)
                            .hint_text("sim")
                            .desired_width(360.0),
                    )
                    .labelled_by(label.id);
                let enter = edit.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
                let ok = self.spec().is_ok();
                let label = if engine.is_some() {
                    "Connect (restart)"
                } else {
                    "Connect"
                };
                if ui
                    .add_enabled(
                        ok,
                        egui::Button::new(RichText::new(label).strong())
                            .min_size(egui::vec2(110.0, 24.0)),
                    )
                    .clicked()
                    || (enter && ok)
                {
                    requests.push(ShellRequest::Connect);
                }
            });
            ui.weak(RIG_HINT);
            match self.spec() {
                Err(e) => {
                    ui.colored_label(Color32::from_rgb(230, 70, 60), e.to_string());
                }
                Ok(RigSpec::Sim) => {
                    ui.weak("Simulated rig: the hand follows the mouse on the Explore page.");
                }
                Ok(_) => {
                    ui.label(
                        "Live rig: the hand is the real handle (encoders); mouse input on the \
                         Explore page is ignored. The engine exchanges blocks of frames with \
                         the device (loop delay one block, 1 ms by default).",
                    );
                }
            }
            ui.add_space(4.0);
            self.tweezer_row(ui, engine, requests);
        });
    }

    /// The rig file: load one, or the built-in default; the one in use.
    fn rig_file_ui(
        &mut self,
        ui: &mut egui::Ui,
        env: &PageEnv<'_>,
        requests: &mut Vec<ShellRequest>,
    ) {
        ui.group(|ui| {
            ui.label(RichText::new("Rig file").strong());
            ui.horizontal(|ui| {
                let r = self.rig_file_field.ui(
                    ui,
                    "Rig file:",
                    &mut self.path_text,
                    PathKind::Open(TOML.0, TOML.1),
                    "built-in default (assets/rigs/default.toml)",
                    420.0,
                );
                if ui.button("Load").clicked() || r.submitted || r.picked {
                    if self.path_text.trim().is_empty() {
                        requests.push(ShellRequest::UseDefaultRig);
                    } else {
                        requests.push(ShellRequest::LoadRigFile(self.path_text.trim().to_owned()));
                    }
                }
                if ui.button("Use built-in default").clicked() {
                    self.path_text.clear();
                    requests.push(ShellRequest::UseDefaultRig);
                }
            });
            match env.rig_config_path {
                Some(p) => ui.label(format!("In use: {}", p.display())),
                None => ui.label("In use: built-in default"),
            };
            if let Some(e) = env.config_error {
                ui.colored_label(Color32::from_rgb(230, 70, 60), e.to_owned());
            }
        });
    }
}

impl super::Page for RigPage {
    fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        let engine = env.engine.take();
        self.draw(ui, env, engine.as_deref());
        env.engine = engine;
    }
}

/// Disconnect, and Pause/Resume or Reconnect after a fault.
fn run_controls_ui(
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
fn error_ui(ui: &mut egui::Ui, h: &EngineHandle) {
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
fn status_ui(ui: &mut egui::Ui, env: &PageEnv<'_>, h: &EngineHandle) {
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
