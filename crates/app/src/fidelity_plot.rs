//! The frontier of `kilotouch bench fidelity`: each fidelity level's speed
//! against its error. x: the speed-up over `full` (full's CPU time over the
//! level's); y: |level − full| in pooled standard errors, one small marker
//! per condition × metric in the condition's colour and a large one at the
//! level's largest, joined level to level; the bound (3 SE) dashed. Each
//! level is labelled with its name and the power question's answer.
//!
//! Drawn with the figures' shared look and output ([`crate::paper::style`]:
//! the embedded font, [`Frame`], PNG and SVG from the same code).

use std::path::Path;

use kilotouch_study::protocol::Condition;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::paper::style::{
    Figure, Frame, GREY, SIZE_SINGLE, SUM, condition_color, err, legend_line, text, text_color,
};
use kilotouch_study::frontier::FidelityReport;

/// The frontier as a [`Figure`].
struct Frontier<'a>(&'a FidelityReport);

/// Horizontal offset of each condition's markers around the level's x, in
/// units of the x range (so the three conditions do not hide each other).
const JITTER: [f64; 3] = [-0.012, 0.0, 0.012];

impl Figure for Frontier<'_> {
    fn size(&self) -> (u32, u32) {
        SIZE_SINGLE
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let r = self.0;
        let x_max = r
            .levels
            .iter()
            .map(|l| l.speedup_vs_full)
            .filter(|v| v.is_finite())
            .fold(1.0, f64::max);
        // Room on the right for the labels of the fastest level.
        let x_hi = (x_max * 1.3).ceil().max(2.0);
        let z_max = r
            .levels
            .iter()
            .flat_map(|l| l.differences.iter().map(|d| d.z.abs()))
            .filter(|v| v.is_finite())
            .fold(r.bound_se, f64::max);
        let y_hi = (z_max * 1.15).ceil();
        let title = format!(
            "Fidelity: speed against error ({} participant(s) × {} test trials per condition, seed {})",
            r.participants, r.test_trials_per_condition, r.seed
        );
        let mut chart = Frame::FIGURE.chart(root, title, 0.0..x_hi, 0.0..y_hi)?;
        Frame::FIGURE
            .mesh(
                &mut chart,
                "speed-up over full (CPU time of full / CPU time of the level)",
                "|level − full| / pooled SE",
            )
            .draw()
            .map_err(err)?;
        chart
            .draw_series(DashedLineSeries::new(
                [(0.0, r.bound_se), (x_hi, r.bound_se)],
                8,
                6,
                GREY.stroke_width(2),
            ))
            .map_err(err)?
            .label(format!("{} pooled SE", r.bound_se))
            .legend(legend_line(GREY, 2));
        for (k, c) in Condition::ALL.into_iter().enumerate() {
            let colour = condition_color(c.code());
            let dx = JITTER[k] * x_hi;
            chart
                // Full against itself is 0 everywhere: only the other levels.
                .draw_series(r.levels.iter().skip(1).flat_map(|l| {
                    l.differences
                        .iter()
                        .filter(move |d| d.condition == c && d.z.is_finite())
                        .map(move |d| {
                            Circle::new((l.speedup_vs_full + dx, d.z.abs()), 4, colour.filled())
                        })
                }))
                .map_err(err)?
                .label(format!("{c}: one metric"))
                .legend(move |(x, y)| Circle::new((x + 12, y), 4, colour.filled()));
        }
        let mut by_speed: Vec<(f64, f64)> = r
            .levels
            .iter()
            .map(|l| (l.speedup_vs_full, l.max_abs_z))
            .collect();
        by_speed.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart
            .draw_series(LineSeries::new(by_speed, SUM.stroke_width(2)))
            .map_err(err)?
            .label("largest of the level")
            .legend(legend_line(SUM, 2));
        chart
            .draw_series(
                r.levels
                    .iter()
                    .map(|l| Circle::new((l.speedup_vs_full, l.max_abs_z), 8, SUM.stroke_width(3))),
            )
            .map_err(err)?;
        let q = &r.question;
        for l in &r.levels {
            let n = match (l.n_for_target, &l.power_error) {
                (Some(n), _) => format!("n = {n}"),
                (None, Some(_)) => "n: –".into(),
                (None, None) => format!("n > {}", l.power.last().map_or(0, |p| p.n)),
            };
            let label = format!("{} ({:.2}×), {n}", l.fidelity, l.speedup_vs_full);
            chart
                .draw_series(std::iter::once(Text::new(
                    label,
                    // Above the level's marker, clear of its condition markers.
                    (l.speedup_vs_full - 0.03 * x_hi, l.max_abs_z + 0.09 * y_hi),
                    text(Frame::FIGURE.tick_px),
                )))
                .map_err(err)?;
        }
        chart
            .draw_series(std::iter::once(Text::new(
                format!(
                    "n: participants for power ≥ {} ({} {}, {} studies per n)",
                    q.target, q.dv, q.contrast, q.replications
                ),
                (0.02 * x_hi, 0.96 * y_hi),
                text_color(Frame::FIGURE.tick_px, GREY),
            )))
            .map_err(err)?;
        Frame::FIGURE.legend(&mut chart, SeriesLabelPosition::UpperRight)
    }
}

/// Writes the frontier to `png` and `svg`.
///
/// # Errors
/// Drawing or file errors, as text.
pub fn save(r: &FidelityReport, png: &Path, svg: &Path) -> Result<(), String> {
    crate::paper::style::save(&Frontier(r), png, svg)
}
