//! The Results page's view code: the folder summary, the bar charts, the
//! statistics table and the export buttons, drawn from the study crate's
//! results model ([`kilotouch_study::results`]).

use crate::gui::charts::{self, BarSeries, FAIL_COLOR, condition_color};
use kilotouch_study::export::regenerate_summaries;
use kilotouch_study::results::{
    ConditionBars, ParticipantBars, ResultMetric, StatsTable, StudyResults,
};

/// What the folder holds: counts, the sittings' timing verdicts and the
/// data dictionary.
pub(super) fn folder_summary_ui(ui: &mut egui::Ui, d: &StudyResults) {
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
}

/// The per-participant bar chart (Fig. 11) of `metric`, labelled `label`,
/// with the sentence saying what the bars are.
pub(super) fn participants_chart(
    ui: &mut egui::Ui,
    bars: &ParticipantBars,
    metric: ResultMetric,
    label: &str,
) {
    let series: Vec<BarSeries> = bars
        .conditions
        .iter()
        .zip(&bars.values)
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
        &bars.participants,
        &series,
        label,
        220.0,
    );
    ui.label(match metric {
        ResultMetric::SuccessCount => "bars: the participant's number of successful test trials",
        ResultMetric::Column(_) => {
            "bars: mean over the participant's successful test trials; whiskers: ±1 SD"
        }
    });
}

/// The per-condition bar chart (Fig. 12), labelled `label`, with its means
/// ± SD in words.
pub(super) fn conditions_chart(ui: &mut egui::Ui, bars: &ConditionBars, label: &str) {
    let series = vec![BarSeries {
        name: "all participants".into(),
        color: condition_color(""),
        values: bars.values.clone(),
        group_colors: bars.conditions.iter().map(|c| condition_color(c)).collect(),
    }];
    charts::bars_with_whiskers(
        ui,
        "res-conditions",
        &bars.conditions,
        &series,
        label,
        200.0,
    );
    let parts: Vec<String> = bars
        .conditions
        .iter()
        .zip(&bars.values)
        .zip(&bars.n)
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
}

/// The **Export statistics** and **Regenerate summaries** buttons; returns
/// what each clicked one did (the message to show, or the error).
pub(super) fn export_buttons_ui(
    ui: &mut egui::Ui,
    d: &StudyResults,
) -> Vec<Result<String, String>> {
    let mut out = Vec::new();
    ui.horizontal(|ui| {
        if ui
            .button("Export statistics (stats.csv, stats.json)")
            .clicked()
        {
            match d.export_stats() {
                Ok((c, j)) => out.push(Ok(format!("wrote {} and {}", c.display(), j.display()))),
                Err(e) => out.push(Err(e.to_string())),
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
                    out.push(Ok(m));
                }
                Err(e) => out.push(Err(e.to_string())),
            }
        }
    });
    out
}

/// Format a number for the table (4 significant decimals, empty for none).
fn fmt(v: Option<f64>) -> String {
    match v {
        Some(x) if x != 0.0 && (x.abs() < 1e-3 || x.abs() >= 1e5) => format!("{x:.3e}"),
        Some(x) => format!("{x:.4}"),
        None => String::new(),
    }
}

pub(super) fn stats_ui(ui: &mut egui::Ui, t: &StatsTable) {
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
