//! The Results page: a study output folder as the paper's figures and
//! tables.
//!
//! * Open a folder (default: the shell's output folder; another one is sent
//!   back with [`ShellRequest::SetOutputDir`]), reload.
//! * For a chosen metric (successful trials, manipulation time, mean force,
//!   mean displacement error, …): bars with SD whiskers per participant and
//!   condition (Fig. 11) and per condition over participants (Fig. 12).
//! * Bead trajectories of one participant × condition from the raw files
//!   the trial rows reference (Fig. 10), read on a background thread.
//! * The statistics table (RM ANOVA with GG/HF, Friedman with Kendall's W,
//!   one-way ANOVA, post-hoc paired t / Wilcoxon with Holm) on the cell
//!   means of the test trials, and export (`stats.csv`, `stats.json`,
//!   regenerated `cells_long.csv` / `cells_wide.csv`).
//!
//! The computations live in [`kilotouch_study::results`]; the drawing of
//! the charts and the table in `view`; malformed files
//! give the study crate's file:line errors on the page, never a panic.

use crate::gui::charts::{self, FAIL_COLOR, Trace};
use crate::gui::env::{PageEnv, ShellRequest};
use crate::gui::path_field::{PathField, PathKind};
use kilotouch_study::results::{
    ConditionBars, ParticipantBars, ResultMetric, StatsTable, StudyResults, Trajectory,
    read_trajectory,
};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Receiver, TryRecvError};

mod view;

/// Points per trajectory drawn.
const TRAJECTORY_POINTS: usize = 4000;
/// Trials per participant × condition drawn (the paper's Fig. 10 shows 5).
const TRAJECTORY_TRIALS: usize = 5;

/// Charts and table of the selected metric (recomputed when it changes).
#[derive(Debug, Clone)]
struct View {
    metric: ResultMetric,
    participants: ParticipantBars,
    conditions: ConditionBars,
    stats: StatsTable,
}

/// Trajectory loading state.
#[derive(Debug)]
enum Traj {
    None,
    Loading(Receiver<Result<Vec<Trajectory>, String>>),
    Loaded(Vec<Trajectory>),
    Failed(String),
}

/// The Results page (module documentation).
#[derive(Debug)]
pub struct ResultsPage {
    dir_text: String,
    initialised: bool,
    data: Option<StudyResults>,
    metric: ResultMetric,
    view: Option<View>,
    error: Option<String>,
    info: Option<String>,
    traj_participant: String,
    traj_condition: String,
    traj: Traj,
    folder_field: PathField,
}

impl Default for ResultsPage {
    fn default() -> Self {
        Self::new()
    }
}

impl ResultsPage {
    /// An empty page (it fills the folder from the shell on first draw).
    pub fn new() -> Self {
        Self {
            dir_text: String::new(),
            initialised: false,
            data: None,
            metric: ResultMetric::Column(kilotouch_study::export::Metric::TimeS),
            view: None,
            error: None,
            info: None,
            traj_participant: String::new(),
            traj_condition: String::new(),
            traj: Traj::None,
            folder_field: PathField::default(),
        }
    }

    /// The folder field.
    pub fn set_folder(&mut self, dir: &Path) {
        self.dir_text = dir.display().to_string();
        self.initialised = true;
    }

    /// The data on display.
    pub fn results(&self) -> Option<&StudyResults> {
        self.data.as_ref()
    }

    /// The statistics on display.
    pub fn stats(&self) -> Option<&StatsTable> {
        self.view.as_ref().map(|v| &v.stats)
    }

    /// The last error.
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    /// Trajectories loaded (Fig. 10), when they are.
    pub fn trajectories(&self) -> Option<&[Trajectory]> {
        match &self.traj {
            Traj::Loaded(t) => Some(t),
            _ => None,
        }
    }

    /// Why the trajectories could not be shown.
    pub fn trajectory_error(&self) -> Option<&str> {
        match &self.traj {
            Traj::Failed(e) => Some(e),
            _ => None,
        }
    }

    /// Participant and condition whose trajectories are loaded next.
    pub fn set_trajectory_selection(&mut self, participant: &str, condition: &str) {
        participant.clone_into(&mut self.traj_participant);
        condition.clone_into(&mut self.traj_condition);
    }

    /// Select the metric shown.
    pub fn set_metric(&mut self, m: ResultMetric) {
        self.metric = m;
        self.refresh_view();
    }

    fn refresh_view(&mut self) {
        self.view = self.data.as_ref().map(|d| {
            let metric = if d.metrics().contains(&self.metric) {
                self.metric
            } else {
                ResultMetric::SuccessCount
            };
            View {
                metric,
                participants: d.per_participant(metric),
                conditions: d.per_condition(metric),
                stats: d.stats(metric),
            }
        });
    }

    fn open(&mut self, env: &mut PageEnv<'_>) {
        let dir = PathBuf::from(self.dir_text.trim());
        self.info = None;
        self.traj = Traj::None;
        if dir.as_os_str().is_empty() {
            self.error = Some("type the study output folder".into());
            return;
        }
        match StudyResults::load(&dir) {
            Ok(d) => {
                self.error = None;
                if let Some(t) = &d.torn {
                    self.info = Some(format!(
                        "ignored an incomplete last line of trials.csv ({} bytes at offset {}): \
                         a session was interrupted while writing",
                        t.len, t.offset
                    ));
                }
                if let Some(p) = d.summary.participants.first()
                    && self.traj_participant.is_empty()
                {
                    self.traj_participant = p.clone();
                }
                if let Some(c) = d.summary.conditions.first()
                    && self.traj_condition.is_empty()
                {
                    self.traj_condition = c.code().to_owned();
                }
                if env.output_dir != Some(dir.as_path()) {
                    env.requests.push(ShellRequest::SetOutputDir(dir.clone()));
                }
                self.data = Some(d);
                self.refresh_view();
            }
            Err(e) => {
                self.error = Some(e.to_string());
                self.data = None;
                self.view = None;
            }
        }
    }

    fn start_trajectories(&mut self) {
        let Some(d) = &self.data else { return };
        let files: Vec<(u32, bool, PathBuf)> = d
            .raw_trials(&self.traj_participant, &self.traj_condition)
            .into_iter()
            .take(TRAJECTORY_TRIALS)
            .collect();
        if files.is_empty() {
            self.traj = Traj::Failed(format!(
                "the test trials of {} in condition {} reference no raw-signal file \
                 (raw_file column empty): trajectories need the raw NPY files with the \
                 bead_x/bead_y channels",
                self.traj_participant, self.traj_condition
            ));
            return;
        }
        let (tx, rx) = mpsc::channel();
        let spawned = std::thread::Builder::new()
            .name("kilotouch-trajectories".into())
            .spawn(move || {
                let r: Result<Vec<Trajectory>, String> = files
                    .iter()
                    .map(|(t, ok, p)| {
                        read_trajectory(p, *t, *ok, TRAJECTORY_POINTS).map_err(|e| e.to_string())
                    })
                    .collect();
                let _ = tx.send(r);
            });
        self.traj = match spawned {
            Ok(_) => Traj::Loading(rx),
            Err(e) => Traj::Failed(format!("cannot start the reader thread: {e}")),
        };
    }

    fn poll_trajectories(&mut self) {
        if let Traj::Loading(rx) = &self.traj {
            self.traj = match rx.try_recv() {
                Ok(Ok(t)) => Traj::Loaded(t),
                Ok(Err(e)) => Traj::Failed(e),
                Err(TryRecvError::Empty) => return,
                Err(TryRecvError::Disconnected) => {
                    Traj::Failed("the reader thread stopped without a result".into())
                }
            };
        }
    }

    /// **Export figures**: the selected metric's bar charts (and the
    /// selected cell's trajectories), PNG and SVG, drawn by the code of
    /// `kilotouch paper` ([`crate::paper::study_figs::export_results_figures`]).
    pub fn export_figures(&mut self) {
        let Some(d) = &self.data else { return };
        let metric = self.view.as_ref().map_or(self.metric, |v| v.metric);
        let cell = (!self.traj_participant.is_empty() && !self.traj_condition.is_empty())
            .then_some((self.traj_participant.as_str(), self.traj_condition.as_str()));
        match crate::paper::study_figs::export_results_figures(d, metric, cell) {
            Ok(files) => {
                self.info = Some(format!(
                    "exported {} files to {}",
                    files.len(),
                    d.dir.join("figures").display()
                ));
            }
            Err(e) => self.error = Some(format!("export figures: {e}")),
        }
    }

    fn data_ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        let Some(d) = &self.data else { return };
        view::folder_summary_ui(ui, d);
        self.metric_row_ui(ui);
        let Some(d) = &self.data else { return };
        let Some(v) = &self.view else { return };
        let label = v.metric.label();
        egui::CollapsingHeader::new("Per participant (Fig. 11)")
            .default_open(true)
            .show(ui, |ui| {
                view::participants_chart(ui, &v.participants, v.metric, &label);
            });
        egui::CollapsingHeader::new("Per condition (Fig. 12)")
            .default_open(true)
            .show(ui, |ui| view::conditions_chart(ui, &v.conditions, &label));
        egui::CollapsingHeader::new("Statistics")
            .default_open(true)
            .show(ui, |ui| view::stats_ui(ui, &v.stats));
        super::plan_study::plan_panel(ui, &d.dir);
        for outcome in view::export_buttons_ui(ui, d) {
            match outcome {
                Ok(m) => {
                    env.requests.push(ShellRequest::Notify(m.clone()));
                    self.info = Some(m);
                }
                Err(e) => self.error = Some(e),
            }
        }
        self.trajectories_ui(ui);
    }

    /// The metric selector and the **Export figures** button.
    fn metric_row_ui(&mut self, ui: &mut egui::Ui) {
        let Some(d) = &self.data else { return };
        let metrics = d.metrics();
        let mut metric = self.view.as_ref().map_or(self.metric, |v| v.metric);
        let before = metric;
        let mut export = false;
        ui.horizontal(|ui| {
            let l = ui.label("Metric");
            egui::ComboBox::from_id_salt("res-metric")
                .selected_text(metric.label())
                .show_ui(ui, |ui| {
                    for m in &metrics {
                        ui.selectable_value(&mut metric, *m, m.label());
                    }
                })
                .response
                .labelled_by(l.id);
            if ui
                .button("Export figures")
                .on_hover_text(
                    "PNG and SVG of the bar charts (and the selected trajectories) into figures/",
                )
                .clicked()
            {
                export = true;
            }
        });
        if metric != before {
            self.set_metric(metric);
        }
        if export {
            self.export_figures();
        }
    }

    fn trajectories_ui(&mut self, ui: &mut egui::Ui) {
        let Some(d) = &self.data else { return };
        let participants = d.summary.participants.clone();
        let conditions: Vec<String> = d
            .summary
            .conditions
            .iter()
            .map(|c| c.code().to_owned())
            .collect();
        let mut load = false;
        egui::CollapsingHeader::new("Trajectories (Fig. 10)")
            .default_open(false)
            .show(ui, |ui| {
                ui.horizontal(|ui| {
                    pick_one(
                        ui,
                        "Participant",
                        "res-traj-p",
                        &mut self.traj_participant,
                        &participants,
                    );
                    pick_one(
                        ui,
                        "Condition",
                        "res-traj-c",
                        &mut self.traj_condition,
                        &conditions,
                    );
                    load = ui
                        .add_enabled(
                            !matches!(self.traj, Traj::Loading(_)),
                            egui::Button::new("Load trajectories"),
                        )
                        .clicked();
                });
                match &self.traj {
                    Traj::None => {
                        ui.label(format!(
                            "bead trajectories of up to {TRAJECTORY_TRIALS} test trials, from \
                             their raw files"
                        ));
                    }
                    Traj::Loading(_) => {
                        ui.spinner();
                    }
                    Traj::Failed(e) => {
                        ui.colored_label(FAIL_COLOR, e.as_str());
                    }
                    Traj::Loaded(ts) => {
                        let traces: Vec<Trace> = ts
                            .iter()
                            .enumerate()
                            .map(|(i, t)| Trace {
                                name: format!(
                                    "trial {}{}",
                                    t.trial,
                                    if t.success { "" } else { " (rejected)" }
                                ),
                                points: t.bead_um.clone(),
                                color: trace_color(i),
                            })
                            .collect();
                        charts::trajectories(ui, "res-traj", &traces, 320.0);
                    }
                }
            });
        if load {
            self.start_trajectories();
        }
    }
}

fn trace_color(i: usize) -> egui::Color32 {
    const C: [egui::Color32; 5] = [
        egui::Color32::from_rgb(0x42, 0x85, 0xf4),
        egui::Color32::from_rgb(0xe6, 0x7c, 0x22),
        egui::Color32::from_rgb(0x4c, 0xaf, 0x50),
        egui::Color32::from_rgb(0xab, 0x47, 0xbc),
        egui::Color32::from_rgb(0xef, 0x53, 0x50),
    ];
    C[i % C.len()]
}

impl super::Page for ResultsPage {
    /// Draw the page.
    fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
        if !self.initialised {
            self.initialised = true;
            if let Some(d) = env.output_dir {
                self.dir_text = d.display().to_string();
                if d.join(kilotouch_study::export::TRIALS_FILE).is_file() {
                    self.open(env);
                }
            }
        }
        self.poll_trajectories();
        if matches!(self.traj, Traj::Loading(_)) {
            ui.ctx()
                .request_repaint_after(std::time::Duration::from_millis(100));
        }
        egui::ScrollArea::vertical()
            .auto_shrink([false, false])
            .show(ui, |ui| {
                ui.heading("Results");
                ui.horizontal(|ui| {
                    let r = self.folder_field.ui(
                        ui,
                        "Study folder",
                        &mut self.dir_text,
                        PathKind::Folder,
                        "study output folder",
                        380.0,
                    );
                    if ui.button("Open").clicked() || r.submitted || r.picked {
                        self.open(env);
                    }
                    if ui
                        .add_enabled(self.data.is_some(), egui::Button::new("Reload"))
                        .clicked()
                    {
                        self.open(env);
                    }
                });
                if let Some(e) = &self.error {
                    ui.colored_label(FAIL_COLOR, format!("Error: {e}"));
                }
                if let Some(i) = &self.info {
                    ui.label(i.as_str());
                }
                if self.data.is_some() {
                    self.data_ui(ui, env);
                } else {
                    ui.label("Open a study output folder (with trials.csv) to see its results.");
                }
            });
    }
}

/// `label`, then a drop-down (egui id `id`) that sets `selected` to one of
/// `options`.
fn pick_one(ui: &mut egui::Ui, label: &str, id: &str, selected: &mut String, options: &[String]) {
    let l = ui.label(label);
    egui::ComboBox::from_id_salt(id)
        .selected_text(selected.clone())
        .show_ui(ui, |ui| {
            for o in options {
                ui.selectable_value(selected, o.clone(), o);
            }
        })
        .response
        .labelled_by(l.id);
}
