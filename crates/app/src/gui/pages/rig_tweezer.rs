//! The Rig page's **Tweezer** section: record a few seconds of the
//! position detector's signals with the trap held still, calibrate both
//! axes by their power spectra (Berg-Sørensen & Flyvbjerg 2004, pylake's
//! formulation: `kilotouch_rig::tweezer::calibration`), show the spectra
//! with the fitted models and the values with their standard errors, and
//! apply κ and the detector's sensitivity R_d to the engine's tweezer.
//!
//! The record comes from the tweezer the section's field names — `sim`
//! (default: the rig file's simulated tweezer behind its simulated
//! detector) or `serial:PATH` (a live tweezer, or `kilotouch emulate
//! tweezer --pty`) — through the recording path of `kilotouch tweezer
//! record` ([`kilotouch_rig::tweezer::record::record`]), on a background thread
//! ([`crate::gui::work::trap_calibration`]). The simulated trap is recorded
//! in free solution, away from the scene's obstacles, whose drag the
//! calibration does not model (as one calibrates a real trap away from
//! surfaces other than the coverslip).
//!
//! **Apply** sends the calibration to the shell
//! ([`ShellRequest::ApplyTrapCalibration`]), which refuses a bad fit
//! ([`TrapCalibrationRecord::check`]), a record of another tweezer than the
//! engine's, and a κ that would take the loop beyond the margins it was
//! cleared for ([`kilotouch_rig::tweezer::check_loop_gain`]). The applied
//! calibration is recorded in a study's `session.json`.

use crate::gui::charts::{self, Series};
use crate::gui::env::{PageEnv, ShellRequest};
use crate::gui::path_field::labelled_line;
use crate::gui::work::trap_calibration::{TrapCalibrationDone, TrapCalibrationRun};
use egui::{Color32, RichText};
use egui_plot::{PlotPoints, Points};
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::RigSpec;
use kilotouch_rig::tweezer::TrapCalibrationRecord;
use kilotouch_rig::tweezer::calibration::{
    DEFAULT_BEAD_DENSITY_KG_M3, DEFAULT_FLUID_DENSITY_KG_M3, TrapCalibration,
    TrapCalibrationSettings,
};
use kilotouch_rig::units::{to_pn_per_um, to_pn_per_v, to_um_per_v};

/// Colours of the x and y axes' spectra.
const AXIS_COLORS: [Color32; 2] = [charts::LOW_COLOR, charts::HIGH_COLOR];
/// Colours of their fitted models (light, drawn over the points).
const FIT_COLORS: [Color32; 2] = [
    Color32::from_rgb(0x9e, 0xf0, 0xff),
    Color32::from_rgb(0xff, 0xee, 0x58),
];

/// The Tweezer section's state.
#[derive(Debug)]
pub struct TweezerSection {
    /// The tweezer field (`sim` or `serial:PATH…`).
    pub source_text: String,
    /// Record length, s.
    pub duration_s: f64,
    /// Trap position held during the record, µm.
    pub trap_um: [f64; 2],
    /// Bead radius, µm.
    pub radius_um: f64,
    /// Viscosity, mPa·s.
    pub viscosity_mpa_s: f64,
    /// Temperature, K.
    pub temperature_k: f64,
    /// Fit range, Hz.
    pub fit_range_hz: [f64; 2],
    /// Periodogram bins per block.
    pub points_per_block: usize,
    /// Fit the aliased Lorentzian (point-sampled record).
    pub aliased: bool,
    /// Fit the hydrodynamically correct spectrum.
    pub hydro: bool,
    /// Fit the photodiode filter.
    pub diode: bool,
    /// The bead is near the coverslip (Faxén).
    pub near_surface: bool,
    /// Bead-centre to coverslip distance, µm.
    pub distance_um: f64,
    /// The live tweezer the engine holds (`serial:PATH`), set by the Rig
    /// page each frame: recording from its port while the loop runs would
    /// share the port's bytes between two readers.
    pub engine_tweezer: Option<String>,
    seeded_for: Option<u64>,
    run: Option<TrapCalibrationRun>,
    done: Option<Box<TrapCalibrationDone>>,
    error: Option<String>,
}

impl Default for TweezerSection {
    fn default() -> Self {
        Self::new()
    }
}

impl TweezerSection {
    /// A section with the settings of the built-in rig.
    pub fn new() -> Self {
        let mut s = Self {
            source_text: "sim".to_owned(),
            duration_s: 10.0,
            trap_um: [0.0; 2],
            radius_um: 0.0,
            viscosity_mpa_s: 0.0,
            temperature_k: 0.0,
            fit_range_hz: [0.0; 2],
            points_per_block: kilotouch_rig::tweezer::record::DEFAULT_POINTS_PER_BLOCK,
            aliased: true,
            hydro: false,
            diode: false,
            near_surface: false,
            distance_um: 5.0,
            engine_tweezer: None,
            seeded_for: None,
            run: None,
            done: None,
            error: None,
        };
        s.seed_from(&RigConfig::default());
        s
    }

    /// Settings from a rig file's tweezer
    /// ([`kilotouch_rig::tweezer::record::default_settings`]).
    pub fn seed_from(&mut self, rc: &RigConfig) {
        let s = kilotouch_rig::tweezer::record::default_settings(rc);
        self.radius_um = s.radius_m * 1e6;
        self.viscosity_mpa_s = s.viscosity_pa_s * 1e3;
        self.temperature_k = s.temperature_k;
        self.fit_range_hz = [s.fit_range_hz.0, s.fit_range_hz.1];
        self.points_per_block = s.points_per_block;
        self.diode = s.diode;
        self.aliased = s.aliased;
        self.hydro = s.hydro;
        self.near_surface = s.distance_to_surface_m.is_some();
        if let Some(h) = s.distance_to_surface_m {
            self.distance_um = h * 1e6;
        }
        self.seeded_for = Some(rig_key(rc));
    }

    /// The calibration settings in SI units (the sample rate is the
    /// record's, filled in by the calibration).
    pub fn settings(&self) -> TrapCalibrationSettings {
        TrapCalibrationSettings {
            fs_hz: 2.0 * self.fit_range_hz[1].max(1.0),
            radius_m: self.radius_um * 1e-6,
            viscosity_pa_s: self.viscosity_mpa_s * 1e-3,
            temperature_k: self.temperature_k,
            fit_range_hz: (self.fit_range_hz[0], self.fit_range_hz[1]),
            points_per_block: self.points_per_block,
            hydro: self.hydro,
            diode: self.diode,
            aliased: self.aliased,
            fluid_density_kg_m3: DEFAULT_FLUID_DENSITY_KG_M3,
            bead_density_kg_m3: DEFAULT_BEAD_DENSITY_KG_M3,
            distance_to_surface_m: self.near_surface.then_some(self.distance_um * 1e-6),
        }
    }

    /// The tweezer the field names (empty = `sim`).
    pub fn spec(&self) -> Result<RigSpec, kilotouch_rig::RigError> {
        spec_or_sim(&self.source_text, RigSpec::Sim)
    }

    /// Is a record or calibration running?
    pub fn is_busy(&self) -> bool {
        self.run.is_some()
    }

    /// The last calibration, if one finished.
    pub fn result(&self) -> Option<&TrapCalibrationRecord> {
        self.done.as_ref().map(|d| &d.record)
    }

    /// The last error, if the last run failed.
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    /// Start recording and calibrating in the background.
    pub fn start(&mut self, rc: &RigConfig) {
        self.error = None;
        let spec = match self.spec() {
            Ok(s) => s,
            Err(e) => {
                self.error = Some(e.to_string());
                return;
            }
        };
        if let (RigSpec::Serial(_), Some(held)) = (&spec, &self.engine_tweezer)
            && spec.describe() == *held
        {
            self.error = Some(format!(
                "the engine's loop runs the tweezer on {held}: disconnect the engine (Rig page), \
                 record and calibrate, then connect again — the applied calibration is re-applied \
                 on connection"
            ));
            return;
        }
        // Check the settings before recording (the sample rate is the
        // record's: the check uses the loop rate of the rig file).
        let mut s = self.settings();
        s.fs_hz = rc.rig.sample_rate_hz;
        if let (RigSpec::Sim, Err(e)) = (&spec, s.validate()) {
            self.error = Some(e.to_string());
            return;
        }
        let mut rc = rc.clone();
        if spec == RigSpec::Sim {
            // Calibrate in free solution, away from the scene's obstacles.
            rc.tweezer.obstacles.clear();
        }
        let trap = [self.trap_um[0] * 1e-6, self.trap_um[1] * 1e-6];
        match TrapCalibrationRun::start(spec, rc, self.duration_s, trap, s) {
            Ok(r) => self.run = Some(r),
            Err(e) => self.error = Some(e),
        }
    }

    /// Collect a finished run (called every frame).
    pub fn poll(&mut self, ctx: &egui::Context) {
        let Some(run) = &mut self.run else {
            return;
        };
        match run.poll() {
            None => ctx.request_repaint_after(std::time::Duration::from_millis(50)),
            Some(Ok(d)) => {
                self.run = None;
                self.done = Some(d);
            }
            Some(Err(e)) => {
                self.run = None;
                self.error = Some(e);
            }
        }
    }

    /// Draw the section.
    pub fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>, engine_connected: bool) {
        if self.seeded_for != Some(rig_key(env.rig_config)) {
            self.seed_from(env.rig_config);
        }
        self.poll(ui.ctx());
        ui.group(|ui| {
            ui.label(RichText::new("Tweezer: trap calibration").strong());
            ui.label(
                "Records the position detector with the trap held still and fits the power \
                 spectrum of each axis (Lorentzian, pylake's method): corner frequency f_c, \
                 diffusion D, stiffness κ and sensitivity R_d with their standard errors.",
            );
            self.settings_ui(ui, env.rig_config);
            ui.add_space(4.0);
            self.run_ui(ui, env.rig_config);
            if let Some(e) = &self.error {
                ui.colored_label(charts::FAIL_COLOR, e.clone());
            }
            if let Some(d) = &self.done {
                ui.add_space(4.0);
                result_ui(ui, d, env, engine_connected);
            }
            ui.add_space(4.0);
            active_ui(ui, env);
        });
    }

    fn settings_ui(&mut self, ui: &mut egui::Ui, rc: &RigConfig) {
        let busy = self.is_busy();
        ui.add_enabled_ui(!busy, |ui| {
            ui.horizontal(|ui| {
                labelled_line(ui, "Tweezer:", &mut self.source_text, "sim", 220.0);
                ui.weak("sim  ·  serial:/dev/ttyACM1  (`kilotouch emulate tweezer --pty`)");
            });
            match self.spec() {
                Ok(RigSpec::Sim) => {
                    ui.weak(format!(
                        "simulated trap of the rig file: κ = {:.3} pN/µm, detector {:.3} V/µm \
                         (R_d = {:.4} µm/V); recorded in free solution, away from the obstacles",
                        to_pn_per_um(rc.tweezer.stiffness_n_per_m),
                        rc.tweezer.detector.sensitivity_v_per_m * 1e-6,
                        to_um_per_v(1.0 / rc.tweezer.detector.sensitivity_v_per_m)
                    ));
                }
                Ok(RigSpec::Audio(_)) => {
                    ui.colored_label(charts::FAIL_COLOR, "an audio interface has no tweezer");
                }
                Ok(RigSpec::Serial(_)) => {}
                Err(e) => {
                    ui.colored_label(charts::FAIL_COLOR, e.to_string());
                }
            }
            egui::Grid::new("tweezer-cal-settings")
                .num_columns(6)
                .spacing([10.0, 4.0])
                .show(ui, |ui| {
                    let num =
                        |ui: &mut egui::Ui, label: &str, v: &mut f64, speed: f64, unit: &str| {
                            let l = ui.label(label);
                            ui.add(
                                egui::DragValue::new(v)
                                    .speed(speed)
                                    .range(0.0..=f64::MAX)
                                    .suffix(unit),
                            )
                            .labelled_by(l.id);
                        };
                    num(ui, "record", &mut self.duration_s, 0.1, " s");
                    let l = ui.label("trap at");
                    ui.horizontal(|ui| {
                        for (k, v) in self.trap_um.iter_mut().enumerate() {
                            ui.add(
                                egui::DragValue::new(v)
                                    .speed(0.1)
                                    .prefix(if k == 0 { "x " } else { "y " })
                                    .suffix(" µm"),
                            )
                            .labelled_by(l.id);
                        }
                    });
                    num(ui, "bead radius", &mut self.radius_um, 0.01, " µm");
                    ui.end_row();
                    num(ui, "viscosity", &mut self.viscosity_mpa_s, 0.001, " mPa·s");
                    num(ui, "temperature", &mut self.temperature_k, 0.1, " K");
                    let l = ui.label("fit range");
                    ui.horizontal(|ui| {
                        ui.add(
                            egui::DragValue::new(&mut self.fit_range_hz[0])
                                .speed(1.0)
                                .range(0.0..=f64::MAX)
                                .suffix(" Hz"),
                        )
                        .labelled_by(l.id);
                        ui.label("–");
                        ui.add(
                            egui::DragValue::new(&mut self.fit_range_hz[1])
                                .speed(10.0)
                                .range(0.0..=f64::MAX)
                                .suffix(" Hz"),
                        )
                        .labelled_by(l.id);
                    });
                    ui.end_row();
                    let l = ui.label("points per block");
                    ui.add(egui::DragValue::new(&mut self.points_per_block).range(1..=100_000))
                        .labelled_by(l.id);
                    ui.checkbox(&mut self.aliased, "aliased").on_hover_text(
                        "point-sampled record without an anti-aliasing filter (the simulated \
                         detector): fit the aliased Lorentzian; not with hydro or diode",
                    );
                    ui.horizontal(|ui| {
                        ui.checkbox(&mut self.hydro, "hydro").on_hover_text(
                            "hydrodynamically correct spectrum (large beads, high frequencies)",
                        );
                        ui.checkbox(&mut self.diode, "diode")
                            .on_hover_text("fit the slow photodiode's filter (f_diode, α)");
                    });
                    ui.checkbox(&mut self.near_surface, "coverslip at")
                        .on_hover_text("Faxén's drag correction at this bead-centre height");
                    ui.add_enabled(
                        self.near_surface,
                        egui::DragValue::new(&mut self.distance_um)
                            .speed(0.1)
                            .range(0.0..=f64::MAX)
                            .suffix(" µm"),
                    );
                    ui.end_row();
                });
        });
    }

    fn run_ui(&mut self, ui: &mut egui::Ui, rc: &RigConfig) {
        ui.horizontal(|ui| {
            let ok = self.spec().is_ok_and(|s| !matches!(s, RigSpec::Audio(_)));
            if ui
                .add_enabled(
                    ok && !self.is_busy(),
                    egui::Button::new(RichText::new("Record and calibrate").strong())
                        .min_size(egui::vec2(170.0, 26.0)),
                )
                .clicked()
            {
                self.start(rc);
            }
            if ui.button("Settings from the rig file").clicked() {
                self.seed_from(rc);
            }
            if let Some(r) = &self.run {
                let f = r.progress();
                ui.add(
                    egui::ProgressBar::new(f as f32)
                        .desired_width(260.0)
                        .text(if f < 1.0 {
                            format!("recording {:.0} %", 100.0 * f)
                        } else {
                            "calibrating…".to_owned()
                        }),
                );
                ui.spinner();
            }
        });
    }
}

/// A key that changes when the rig file's tweezer or rate does.
fn rig_key(rc: &RigConfig) -> u64 {
    let t = &rc.tweezer;
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for v in [
        t.radius_m,
        t.viscosity_pa_s,
        t.temperature_k,
        t.wall_distance_m.unwrap_or(-1.0),
        t.detector.diode_hz.unwrap_or(-1.0),
        rc.rig.sample_rate_hz,
    ] {
        h = (h ^ v.to_bits()).wrapping_mul(0x1000_0000_01b3);
    }
    h
}

fn pm(v: f64, se: f64, prec: usize) -> String {
    format!("{v:.prec$} ± {se:.prec$}")
}

/// The value rows of one axis' calibration.
fn rows(c: &TrapCalibration) -> Vec<(&'static str, String)> {
    let mut r = vec![
        ("f_c (Hz)", pm(c.corner_hz, c.corner_se_hz, 2)),
        (
            "D (V²/s)",
            format!("{:.4e} ± {:.1e}", c.diffusion_v2_s, c.diffusion_se_v2_s),
        ),
        (
            "κ (pN/µm)",
            pm(
                to_pn_per_um(c.kappa_n_per_m),
                to_pn_per_um(c.kappa_se_n_per_m),
                3,
            ),
        ),
        (
            "R_d (µm/V)",
            pm(to_um_per_v(c.rd_m_per_v), to_um_per_v(c.rd_se_m_per_v), 4),
        ),
        ("R_f (pN/V)", format!("{:.3}", to_pn_per_v(c.rf_n_per_v))),
    ];
    if let (Some(fd), Some(al)) = (c.f_diode_hz, c.alpha) {
        r.push((
            "f_diode (Hz)",
            pm(fd, c.f_diode_se_hz.unwrap_or(f64::NAN), 0),
        ));
        r.push(("α", pm(al, c.alpha_se.unwrap_or(f64::NAN), 3)));
    }
    r.push(("χ²/dof [?]", format!("{:.3}", c.chi2_per_dof)));
    r.push(("fit backing (%) [?]", format!("{:.1}", c.backing_pct)));
    r.push(("points fitted", c.n_points.to_string()));
    r
}

/// What a value row means, for the rows a non-specialist cannot read.
fn row_help(name: &str) -> Option<&'static str> {
    if name.starts_with("fit backing") {
        Some(
            "Statistical backing of the fit (pylake's): the probability, in %, that a spectrum \
             following the model exactly would fit it this badly or worse (χ² test on the \
             blocked periodogram). It varies from record to record like any p-value: x and y \
             at 46 % and 96 % both mean the model fits. Below 0.1 % the model does not \
             describe the spectrum (a wrong fit range, a surface nearby, a noisy detector) and \
             the calibration is refused.",
        )
    } else if name.starts_with("χ²/dof") {
        Some(
            "χ² per degree of freedom of the fit: about 1 when the model fits the spectrum to \
             within its statistical scatter; accepted between 0.5 and 2.",
        )
    } else {
        None
    }
}

fn result_ui(
    ui: &mut egui::Ui,
    d: &TrapCalibrationDone,
    env: &mut PageEnv<'_>,
    engine_connected: bool,
) {
    let r = &d.record;
    ui.label(format!(
        "{} samples per axis from {}; {}",
        r.n_samples,
        r.source,
        kilotouch_rig::tweezer::record::model_name(&r.settings)
    ));
    ui.columns(2, |cols| {
        psd_chart(&mut cols[0], d);
        let ui = &mut cols[1];
        egui::Grid::new("tweezer-cal-values")
            .striped(true)
            .show(ui, |ui| {
                for h in ["", "x", "y"] {
                    ui.label(RichText::new(h).strong());
                }
                ui.end_row();
                for ((name, vx), (_, vy)) in rows(&r.x).into_iter().zip(rows(&r.y)) {
                    let l = ui.label(name);
                    if let Some(help) = row_help(name) {
                        l.on_hover_text(help);
                    }
                    ui.label(vx);
                    ui.label(vy);
                    ui.end_row();
                }
            });
        ui.add_space(4.0);
        ui.label(
            RichText::new(format!(
                "κ to apply: {} pN/µm (both axes, weighted)",
                pm(
                    to_pn_per_um(r.kappa_n_per_m),
                    to_pn_per_um(r.kappa_se_n_per_m),
                    3
                )
            ))
            .strong(),
        );
        if r.source == "sim" {
            let truth = env.rig_config.tweezer.stiffness_n_per_m;
            ui.label(format!(
                "simulated trap: κ = {:.3} pN/µm ({:+.2} %, {:+.1} SE)",
                to_pn_per_um(truth),
                100.0 * (r.kappa_n_per_m / truth - 1.0),
                (r.kappa_n_per_m - truth) / r.kappa_se_n_per_m
            ));
        }
        let verdict = r.check();
        match &verdict {
            Ok(()) => {
                ui.colored_label(charts::PASS_COLOR, "fit accepted");
            }
            Err(e) => {
                ui.colored_label(charts::FAIL_COLOR, format!("not applicable: {e}"));
            }
        }
        let b = ui
            .horizontal(|ui| {
                ui.add_enabled(
                    verdict.is_ok() && engine_connected,
                    egui::Button::new(RichText::new("Apply").strong())
                        .min_size(egui::vec2(110.0, 26.0)),
                )
            })
            .inner
            .on_hover_text(
                "the engine's tweezer reports the bead at trap + R_d·V and the force \
                 κ (trap − bead) from now on; recorded in a study's session.json",
            )
            .on_disabled_hover_text(if engine_connected {
                "the fit is not applicable (reason shown)"
            } else {
                "no rig connected"
            });
        if b.clicked() {
            env.requests
                .push(ShellRequest::ApplyTrapCalibration(Some(Box::new(
                    r.clone(),
                ))));
        }
    });
}

/// The blocked periodogram of each axis with its fitted model (log–log).
fn psd_chart(ui: &mut egui::Ui, d: &TrapCalibrationDone) {
    let mut series = Vec::new();
    let mut points = Vec::new();
    for (k, fit) in d.fits.iter().enumerate() {
        let axis = ["x", "y"][k];
        let spec = &fit.spectrum;
        let log_p: Vec<f64> = spec.p.iter().map(|p| p.log10()).collect();
        points.push((
            format!("{axis}: blocked periodogram"),
            charts::log_points(&spec.f, &log_p),
            AXIS_COLORS[k],
        ));
        let (f0, f1) = (
            spec.f.first().copied().unwrap_or(1.0),
            spec.f.last().copied().unwrap_or(10.0),
        );
        let model: Vec<[f64; 2]> = (0..=200)
            .filter_map(|i| {
                let f = f0 * (f1 / f0).powf(f64::from(i) / 200.0);
                let m = fit.model_at(f);
                (f > 0.0 && m > 0.0 && m.is_finite()).then(|| [f.log10(), m.log10()])
            })
            .collect();
        series.push(Series::solid(format!("{axis}: fit"), model, FIT_COLORS[k]));
    }
    charts::freq_chart(
        ui,
        "tweezer-psd",
        "log₁₀ PSD (V²/Hz)",
        260.0,
        &series,
        |p| {
            for (name, pts, color) in points {
                p.points(
                    Points::new(name, PlotPoints::new(pts))
                        .radius(1.8)
                        .color(color.gamma_multiply(0.75)),
                );
            }
        },
    );
}

/// The calibration in force and the button that removes it.
fn active_ui(ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
    ui.horizontal(|ui| match env.trap_applied {
        Some(t) => {
            ui.colored_label(
                charts::PASS_COLOR,
                format!(
                    "Active trap calibration: κ = {} pN/µm, R_d = {:.4} / {:.4} µm/V ({})",
                    pm(
                        to_pn_per_um(t.kappa_n_per_m),
                        to_pn_per_um(t.kappa_se_n_per_m),
                        3
                    ),
                    to_um_per_v(t.rd_m_per_v[0]),
                    to_um_per_v(t.rd_m_per_v[1]),
                    t.source
                ),
            );
            if ui.small_button("Remove").clicked() {
                env.requests.push(ShellRequest::ApplyTrapCalibration(None));
            }
        }
        None => {
            ui.weak("Active trap calibration: none (the tweezer reports the simulated bead and κ)");
        }
    });
}

/// The device a spec field names (`--rig`/`--tweezer` syntax), `sim` when
/// the field is empty or blank.
///
/// # Errors
/// The spec's parse error.
pub(super) fn spec_or_sim<T>(text: &str, sim: T) -> Result<T, kilotouch_rig::RigError>
where
    T: std::str::FromStr<Err = kilotouch_rig::RigError>,
{
    let t = text.trim();
    if t.is_empty() { Ok(sim) } else { t.parse() }
}
