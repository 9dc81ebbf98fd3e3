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
//! The computations live in [`crate::results`]; malformed files
//! give the study crate's file:line errors on the page, never a panic.

use crate::gui::charts::{self, BarSeries, FAIL_COLOR, Trace, condition_color};
use crate::gui::env::{PageEnv, ShellRequest};
use crate::gui::path_field::{PathField, PathKind};
use kilotouch_study::export::regenerate_summaries;
use kilotouch_study::results::{
    ConditionBars, ParticipantBars, ResultMetric, StatsTable, StudyResults, Trajectory,
    read_trajectory,
};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Receiver, TryRecvError};

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

    /// Draw the page.
    pub fn ui(&mut self, ui: &mut egui::Ui, env: &mut PageEnv<'_>) {
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
        ui.label(format!(
            "{} participants, conditions {}, {} test trials ({} rows)",
            d.summary.participants.len(),
            d.summary
                .conditions
                .iter()
                .map(|c| c.code())
                .collect::<Vec<_>>()
                .join(", "),
            d.n_test_trials(),
            d.rows.len()
        ));
        let late: Vec<_> = d.timing.iter().filter(|(_, t)| t.is_late()).collect();
        if !late.is_empty() {
            for (which, t) in &late {
                ui.colored_label(FAIL_COLOR, format!("Timing: {which}: {}", t.describe()))
                    .on_hover_text(
                        "More of this sitting's samples ran late than the rig file's \
                         sitting_max_late_fraction allows: check its trials (raw files, \
                         deadline misses) before analysis, or run the sitting again \
                         (docs/STUDY.md, timing verdict).",
                    );
            }
        } else if !d.timing.is_empty() {
            ui.label(format!(
                "Timing: all {} sitting(s) on time (worst {:.2} % of samples late)",
                d.timing.len(),
                100.0
                    * d.timing
                        .iter()
                        .map(|(_, t)| t.late_fraction)
                        .fold(0.0, f64::max)
            ));
        }
        let package = d.dir.join(kilotouch_study::export::DATAPACKAGE_FILE);
        ui.label(if package.is_file() {
            format!(
                "data dictionary: {} (Frictionless data package: every column's type, unit and \
                 missing-value code)",
                package.display()
            )
        } else {
            "no datapackage.json yet: Regenerate summaries writes it with cells_long.csv and \
             cells_wide.csv"
                .to_owned()
        });
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
        let Some(d) = &self.data else { return };
        let Some(view) = &self.view else { return };
        let label = view.metric.label();
        egui::CollapsingHeader::new("Per participant (Fig. 11)")
            .default_open(true)
            .show(ui, |ui| {
                let series: Vec<BarSeries> = view
                    .participants
                    .conditions
                    .iter()
                    .zip(&view.participants.values)
                    .map(|(c, v)| BarSeries {
                        name: c.clone(),
                        color: condition_color(c),
                        values: v.clone(),
                        group_colors: Vec::new(),
                    })
                    .collect();
                charts::bars_with_whiskers(
                    ui,
                    "res-participants",
                    &view.participants.participants,
                    &series,
                    &label,
                    220.0,
                );
                ui.label(match view.metric {
                    ResultMetric::SuccessCount => {
                        "bars: the participant's number of successful test trials"
                    }
                    ResultMetric::Column(_) => {
                        "bars: mean over the participant's successful test trials; whiskers: ±1 SD"
                    }
                });
            });
        egui::CollapsingHeader::new("Per condition (Fig. 12)")
            .default_open(true)
            .show(ui, |ui| {
                let series = vec![BarSeries {
                    name: "all participants".into(),
                    color: condition_color(""),
                    values: view.conditions.values.clone(),
                    group_colors: view
                        .conditions
                        .conditions
                        .iter()
                        .map(|c| condition_color(c))
                        .collect(),
                }];
                charts::bars_with_whiskers(
                    ui,
                    "res-conditions",
                    &view.conditions.conditions,
                    &series,
                    &label,
                    200.0,
                );
                let parts: Vec<String> = view
                    .conditions
                    .conditions
                    .iter()
                    .zip(&view.conditions.values)
                    .zip(&view.conditions.n)
                    .map(|((c, v), n)| match v {
                        Some((m, Some(sd))) => format!("{c}: {m:.4} ± {sd:.4} (n = {n})"),
                        Some((m, None)) => format!("{c}: {m:.4} (n = {n})"),
                        None => format!("{c}: no data"),
                    })
                    .collect();
                ui.label(format!(
                    "mean ± SD over participants' cell means — {}",
                    parts.join("; ")
                ));
            });
        egui::CollapsingHeader::new("Statistics")
            .default_open(true)
            .show(ui, |ui| stats_ui(ui, &view.stats));
        super::plan_study::plan_panel(ui, &d.dir);
        ui.horizontal(|ui| {
            if ui
                .button("Export statistics (stats.csv, stats.json)")
                .clicked()
            {
                match d.export_stats() {
                    Ok((c, j)) => {
                        let m = format!("wrote {} and {}", c.display(), j.display());
                        env.requests.push(ShellRequest::Notify(m.clone()));
                        self.info = Some(m);
                    }
                    Err(e) => self.error = Some(e.to_string()),
                }
            }
            if ui.button("Regenerate summaries").clicked() {
                match regenerate_summaries(&d.dir) {
                    Ok(f) => {
                        let m = format!(
                            "wrote {} and {}",
                            f.cells_long.display(),
                            f.cells_wide.display()
                        );
                        env.requests.push(ShellRequest::Notify(m.clone()));
                        self.info = Some(m);
                    }
                    Err(e) => self.error = Some(e.to_string()),
                }
            }
        });
        self.trajectories_ui(ui);
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
                    let l = ui.label("Participant");
                    egui::ComboBox::from_id_salt("res-traj-p")
                        .selected_text(self.traj_participant.clone())
                        .show_ui(ui, |ui| {
                            for p in &participants {
                                ui.selectable_value(&mut self.traj_participant, p.clone(), p);
                            }
                        })
                        .response
                        .labelled_by(l.id);
                    let l = ui.label("Condition");
                    egui::ComboBox::from_id_salt("res-traj-c")
                        .selected_text(self.traj_condition.clone())
                        .show_ui(ui, |ui| {
                            for c in &conditions {
                                ui.selectable_value(&mut self.traj_condition, c.clone(), c);
                            }
                        })
                        .response
                        .labelled_by(l.id);
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

/// Format a number for the table (4 significant decimals, empty for none).
fn fmt(v: Option<f64>) -> String {
    match v {
        Some(x) if x != 0.0 && (x.abs() < 1e-3 || x.abs() >= 1e5) => format!("{x:.3e}"),
        Some(x) => format!("{x:.4}"),
        None => String::new(),
    }
}

fn stats_ui(ui: &mut egui::Ui, t: &StatsTable) {
    ui.label(format!(
        "{} on participant × condition cell means of the test trials; conditions {}; {} \
         participants{}",
        t.metric,
        t.conditions.join(", "),
        t.participants.len(),
        if t.dropped_participants.is_empty() {
            String::new()
        } else {
            format!(
                " ({} dropped from the within-subject tests: missing a condition)",
                t.dropped_participants.join(", ")
            )
        }
    ));
    ui.label(format!(
        "rows of trials.csv: {} — the analysis uses {} (the rule of `kilotouch stats`)",
        t.rows.sentence(),
        t.row_rule.describe()
    ));
    // The table scrolls sideways inside the page's width if it must; the
    // notes, which can be long, are footnotes under it (wrapped to the
    // page), so no column is cut at any window width.
    let notes = egui::ScrollArea::horizontal()
        .id_salt("res-stats-scroll")
        .show(ui, |ui| stats_grid(ui, t))
        .inner;
    for (k, (note, failed)) in notes.iter().enumerate() {
        let text = format!("[{}] {note}", k + 1);
        if *failed {
            ui.colored_label(FAIL_COLOR, text);
        } else {
            ui.label(text);
        }
    }
}

/// The statistics table of [`stats_ui`]; returns its notes (text, and
/// whether it says why a test has no result), numbered [1], [2], … in the
/// note column.
fn stats_grid(ui: &mut egui::Ui, t: &StatsTable) -> Vec<(String, bool)> {
    let mut notes: Vec<(String, bool)> = Vec::new();
    egui::Grid::new("res-stats")
        .striped(true)
        .num_columns(10)
        .spacing([10.0, 2.0])
        .show(ui, |ui| {
            for h in [
                "test",
                "pair",
                "stat",
                "value",
                "df1",
                "df2",
                "p",
                "p (GG / HF / Holm)",
                "effect",
                "note",
            ] {
                ui.strong(h);
            }
            ui.end_row();
            for r in t.rows() {
                ui.label(match r.test.as_str() {
                    "rm_anova" => "RM ANOVA",
                    "friedman" => "Friedman",
                    "oneway_anova" => "one-way ANOVA",
                    "paired_t" => "paired t (Holm)",
                    "wilcoxon" => "Wilcoxon (Holm)",
                    other => other,
                });
                ui.label(r.comparison.as_str());
                ui.label(r.statistic_name.as_str());
                ui.label(fmt(r.statistic));
                ui.label(fmt(r.df1));
                ui.label(fmt(r.df2));
                ui.label(fmt(r.p));
                let corrected = if r.p_holm.is_some() {
                    fmt(r.p_holm)
                } else if r.p_gg.is_some() {
                    format!("{} / {}", fmt(r.p_gg), fmt(r.p_hf))
                } else {
                    String::new()
                };
                ui.label(corrected);
                ui.label(if r.effect.is_some() {
                    format!("{} = {}", r.effect_name, fmt(r.effect))
                } else {
                    String::new()
                });
                if !r.note.is_empty() {
                    let failed = r.statistic.is_none();
                    let k = match notes.iter().position(|(n, _)| *n == r.note) {
                        Some(k) => k,
                        None => {
                            notes.push((r.note.clone(), failed));
                            notes.len() - 1
                        }
                    };
                    let mark = format!("[{}]", k + 1);
                    if failed {
                        ui.colored_label(FAIL_COLOR, mark)
                    } else {
                        ui.label(mark)
                    }
                    .on_hover_text(r.note.as_str());
                } else {
                    ui.label("");
                }
                ui.end_row();
            }
        });
    notes
}
