//! The Results page's **Plan the next study** panel: `kilotouch study
//! power` on the open folder. The panel keeps its own state in egui's
//! memory (one self-contained function, [`plan_panel`]); the simulation
//! runs on a background thread with a progress bar and a Cancel button,
//! and the same numerics as the CLI (`kilotouch_study::power`).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{self, Receiver, TryRecvError};
use std::sync::{Arc, Mutex};

use egui_plot::{HLine, Legend, Line, Plot, PlotPoints, Points};
use kilotouch_study::power::{
    EffectSpec, PowerOptions, PowerReport, PowerTest, parse_sample_sizes, power_from_path,
};

use crate::gui::charts::FAIL_COLOR;

/// DV columns offered (trials.csv metrics and the outcome itself).
const DVS: [&str; 6] = [
    "disp_err_mean_um",
    "time_s",
    "force_mean_pn",
    "force_mean_n",
    "contact_fraction",
    "success",
];

/// How the assumed effect is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum EffectMode {
    Pilot,
    Absolute,
    Scale,
}

/// A running simulation.
#[derive(Debug)]
struct Job {
    rx: Receiver<Result<PowerReport, String>>,
    done: Arc<AtomicUsize>,
    total: Arc<AtomicUsize>,
    cancel: Arc<AtomicBool>,
}

/// The panel's state (kept in egui memory between frames).
#[derive(Debug)]
struct PlanState {
    dv: String,
    rm: bool,
    a: String,
    b: String,
    ns: String,
    trials: u32,
    effect_mode: EffectMode,
    effect: f64,
    alpha: f64,
    target: f64,
    replications: u32,
    seed: u64,
    job: Option<Job>,
    result: Option<PowerReport>,
    error: Option<String>,
    folder: PathBuf,
}

impl Default for PlanState {
    fn default() -> Self {
        Self {
            dv: "disp_err_mean_um".into(),
            rm: false,
            a: "P".into(),
            b: "D".into(),
            ns: "4:40:4".into(),
            trials: 0,
            effect_mode: EffectMode::Pilot,
            effect: 0.0,
            alpha: 0.05,
            target: 0.8,
            replications: 1000,
            seed: 1,
            job: None,
            result: None,
            error: None,
            folder: PathBuf::new(),
        }
    }
}

impl PlanState {
    fn options(&self) -> Result<PowerOptions, String> {
        let test = if self.rm {
            PowerTest::Rm
        } else {
            PowerTest::Contrast {
                a: self.a.trim().to_owned(),
                b: self.b.trim().to_owned(),
            }
        };
        let ns = parse_sample_sizes(&self.ns).map_err(|e| e.to_string())?;
        let mut o = PowerOptions::new(&self.dv, test, ns);
        o.trials = (self.trials > 0).then_some(self.trials);
        o.effect = match self.effect_mode {
            EffectMode::Pilot => EffectSpec::Pilot,
            EffectMode::Absolute => EffectSpec::Absolute(self.effect),
            EffectMode::Scale => EffectSpec::Scale(self.effect),
        };
        o.alpha = self.alpha;
        o.target = self.target;
        o.replications = self.replications;
        o.seed = self.seed;
        o.threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        Ok(o)
    }

    fn start(&mut self, dir: &Path) {
        let opts = match self.options() {
            Ok(o) => o,
            Err(e) => {
                self.error = Some(e);
                return;
            }
        };
        let (tx, rx) = mpsc::channel();
        let done = Arc::new(AtomicUsize::new(0));
        let total = Arc::new(AtomicUsize::new(1));
        let cancel = Arc::new(AtomicBool::new(false));
        let (d, t, c) = (done.clone(), total.clone(), cancel.clone());
        let dir = dir.to_path_buf();
        let spawned = std::thread::Builder::new()
            .name("kilotouch-power".into())
            .stack_size(kilotouch_rig::realtime::THREAD_STACK_BYTES)
            .spawn(move || {
                let r = power_from_path(&dir, &opts, &|k, n| {
                    d.store(k, Ordering::Relaxed);
                    t.store(n.max(1), Ordering::Relaxed);
                    !c.load(Ordering::Relaxed)
                })
                .map_err(|e| e.to_string());
                let _ = tx.send(r);
            });
        match spawned {
            Ok(_) => {
                self.error = None;
                self.job = Some(Job {
                    rx,
                    done,
                    total,
                    cancel,
                });
            }
            Err(e) => self.error = Some(format!("cannot start the simulation thread: {e}")),
        }
    }

    fn poll(&mut self) {
        let Some(job) = &self.job else { return };
        match job.rx.try_recv() {
            Ok(Ok(r)) => {
                self.result = Some(r);
                self.job = None;
            }
            Ok(Err(e)) => {
                self.error = Some(e);
                self.job = None;
            }
            Err(TryRecvError::Empty) => {}
            Err(TryRecvError::Disconnected) => {
                self.error = Some("the simulation thread stopped without a result".into());
                self.job = None;
            }
        }
    }

    /// The panel's form: the options of the power analysis.
    fn form_ui(&mut self, ui: &mut egui::Ui) {
        egui::Grid::new("plan-grid").num_columns(2).show(ui, |ui| {
            ui.label("Dependent variable");
            egui::ComboBox::from_id_salt("plan-dv")
                .selected_text(self.dv.clone())
                .show_ui(ui, |ui| {
                    for dv in DVS {
                        ui.selectable_value(&mut self.dv, dv.to_owned(), dv);
                    }
                });
            ui.end_row();
            ui.label("Test");
            ui.horizontal(|ui| {
                ui.radio_value(&mut self.rm, false, "paired t of");
                ui.add(egui::TextEdit::singleline(&mut self.a).desired_width(30.0));
                ui.label("−");
                ui.add(egui::TextEdit::singleline(&mut self.b).desired_width(30.0));
                ui.radio_value(&mut self.rm, true, "RM-ANOVA (GG)");
            });
            ui.end_row();
            let label = ui.label("Participants (n)");
            ui.add(egui::TextEdit::singleline(&mut self.ns).desired_width(160.0))
                .labelled_by(label.id)
                .on_hover_text("comma list and/or FROM:TO:STEP, e.g. 4:40:4");
            ui.end_row();
            ui.label("Trials per condition");
            ui.add(egui::DragValue::new(&mut self.trials).range(0..=1000))
                .on_hover_text("0 = as in the pilot");
            ui.end_row();
            ui.label("Effect");
            ui.horizontal(|ui| {
                ui.radio_value(&mut self.effect_mode, EffectMode::Pilot, "pilot's");
                ui.radio_value(&mut self.effect_mode, EffectMode::Absolute, "difference");
                ui.radio_value(&mut self.effect_mode, EffectMode::Scale, "× pilot's");
                if self.effect_mode != EffectMode::Pilot {
                    ui.add(egui::DragValue::new(&mut self.effect).speed(0.01));
                }
            });
            ui.end_row();
            ui.label("α, target power");
            ui.horizontal(|ui| {
                ui.add(
                    egui::DragValue::new(&mut self.alpha)
                        .range(0.001..=0.5)
                        .speed(0.001),
                );
                ui.add(
                    egui::DragValue::new(&mut self.target)
                        .range(0.05..=0.99)
                        .speed(0.01),
                );
            });
            ui.end_row();
            ui.label("Simulated studies per n, seed");
            ui.horizontal(|ui| {
                ui.add(egui::DragValue::new(&mut self.replications).range(10..=100_000));
                ui.add(egui::DragValue::new(&mut self.seed));
            });
            ui.end_row();
        });
    }

    /// The progress bar and Cancel button of a running simulation, or the
    /// button that starts one on the folder `dir`.
    fn progress_ui(&mut self, ui: &mut egui::Ui, dir: &Path) {
        if let Some(job) = &self.job {
            let (d, t) = (
                job.done.load(Ordering::Relaxed),
                job.total.load(Ordering::Relaxed),
            );
            ui.horizontal(|ui| {
                ui.add(
                    egui::ProgressBar::new(d as f32 / t.max(1) as f32)
                        .text(format!("{d}/{t} simulated studies"))
                        .desired_width(300.0),
                );
                if ui.button("Cancel").clicked() {
                    job.cancel.store(true, Ordering::Relaxed);
                }
            });
            ui.ctx()
                .request_repaint_after(std::time::Duration::from_millis(100));
        } else if ui.button("Simulate power").clicked() {
            self.start(dir);
        }
    }
}

/// The power curve with its 95 % intervals, the target and α.
fn curve(ui: &mut egui::Ui, r: &PowerReport) {
    let color = egui::Color32::from_rgb(31, 119, 180);
    Plot::new("plan-power-curve")
        .height(220.0)
        .include_y(0.0)
        .include_y(1.0)
        .legend(Legend::default())
        .x_axis_label("participants (n)")
        .y_axis_label("power")
        .show(ui, |p| {
            for pt in &r.points {
                let x = f64::from(pt.n);
                p.line(
                    Line::new("", PlotPoints::new(vec![[x, pt.ci[0]], [x, pt.ci[1]]]))
                        .color(color)
                        .width(1.5),
                );
            }
            let pts: Vec<[f64; 2]> = r.points.iter().map(|q| [f64::from(q.n), q.power]).collect();
            p.line(
                Line::new("power (95 % CI)", PlotPoints::new(pts.clone()))
                    .color(color)
                    .width(2.5),
            );
            p.points(
                Points::new("", PlotPoints::new(pts))
                    .color(color)
                    .radius(3.5),
            );
            p.hline(
                HLine::new(format!("target {}", r.target), r.target).color(egui::Color32::GRAY),
            );
            p.hline(
                HLine::new(format!("α = {}", r.alpha), r.alpha).color(egui::Color32::DARK_GRAY),
            );
        });
}

/// The result of a power analysis: the curve, the n that reaches the
/// target, the assumed effect, the pilot caution and the table.
fn report_ui(ui: &mut egui::Ui, r: &PowerReport) {
    curve(ui, r);
    ui.label(match r.n_for_target {
        Some(n) => format!("n for power ≥ {}: {n} participants", r.target),
        None => format!("power {} is not reached at any n tried", r.target),
    });
    ui.label(format!(
        "assumed effect {:.4}; SD of the participants' differences {:.4} (pilot), {:.4} (model, {} trials per condition)",
        r.effect, r.sd_diff, r.sd_diff_model, r.trials_per_condition
    ));
    ui.label(r.pilot_warning());
    egui::Grid::new("plan-table").striped(true).show(ui, |ui| {
        ui.strong("n");
        ui.strong("power");
        ui.strong("95 % CI");
        ui.strong("dropped / study");
        ui.end_row();
        for p in &r.points {
            ui.label(p.n.to_string());
            ui.label(format!("{:.3}", p.power));
            ui.label(format!("[{:.3}, {:.3}]", p.ci[0], p.ci[1]));
            ui.label(format!("{:.2}", p.mean_dropped));
            ui.end_row();
        }
    });
}

/// The **Plan the next study** panel for the study folder `dir` (call it
/// once per frame from the Results page).
pub fn plan_panel(ui: &mut egui::Ui, dir: &Path) {
    let id = ui.make_persistent_id("plan-next-study");
    let state: Arc<Mutex<PlanState>> = ui.data_mut(|d| {
        d.get_temp_mut_or_default::<Arc<Mutex<PlanState>>>(id)
            .clone()
    });
    let Ok(mut s) = state.lock() else { return };
    if s.folder != dir {
        s.folder = dir.to_path_buf();
        s.result = None;
        s.error = None;
    }
    s.poll();
    egui::CollapsingHeader::new("Plan the next study")
        .default_open(false)
        .show(ui, |ui| {
            ui.label(
                "How many participants does the next study need? This folder is the pilot: its \
                 test trials give the spread between and within participants and the success \
                 rates; many studies are simulated at each number of participants and analysed \
                 as the statistics above are.",
            );
            s.form_ui(ui);
            s.progress_ui(ui, dir);
            if let Some(e) = &s.error {
                ui.colored_label(FAIL_COLOR, format!("Error: {e}"));
            }
            if let Some(r) = &s.result {
                report_ui(ui, r);
            }
        });
}
