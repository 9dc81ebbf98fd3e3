//! The power curve of `kilotouch study power --plot` (PNG or SVG, by the
//! file's extension): power against the number of participants with the
//! Clopper–Pearson 95 % interval of each point, the target power, α, and
//! the smallest n reaching the target. With a final check (`study power
//! --simulate` at `draft`), the check's curve is drawn beside the search's.
//!
//! Text goes through `ab_glyph` with DejaVu Sans compiled into the binary
//! (`assets/fonts/DejaVuSans.ttf`, licence beside it), so the plot renders
//! the same on a machine without system fonts.

use std::path::Path;

use kilotouch_study::fidelity::Fidelity;
use kilotouch_study::power::PowerReport;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::paper::style::{Frame, GREY, SUM, ensure_font, err, legend_line};
/// Size of the plot, px (PNG) or user units (SVG).
const SIZE: (u32, u32) = (900, 600);
/// Curve colour.
const CURVE: RGBColor = crate::paper::style::LOW;
/// The n reaching the target.
const HIT: RGBColor = crate::paper::style::HIGH;
/// The chart's set-up: one chart with a smaller title and tick labels than
/// the paper's figures.
const FRAME: Frame = Frame {
    caption_px: 24.0,
    x_label_area: 50,
    y_label_area: 64,
    tick_px: 16.0,
    ..Frame::FIGURE
};

/// A second curve: the final check at this fidelity.
pub type Check<'a> = Option<(Fidelity, &'a PowerReport)>;

/// Colour of the final check's curve.
const CHECK: RGBColor = SUM;

/// Draws the curve on any backend.
fn draw<DB: DrawingBackend>(
    r: &PowerReport,
    check: Check<'_>,
    root: &DrawingArea<DB, Shift>,
) -> Result<(), String> {
    root.fill(&WHITE).map_err(err)?;
    let n_max = r.points.iter().map(|p| p.n).max().unwrap_or(2);
    let n_min = r.points.iter().map(|p| p.n).min().unwrap_or(0);
    let x_lo = f64::from(n_min.saturating_sub(1));
    let x_hi = f64::from(n_max) + 1.0;
    let m = &r.model;
    let checked = check.map_or_else(String::new, |(f, c)| format!(" ({f}: {:.4})", c.effect));
    let title = if r.test == "paired_t" {
        format!(
            "{}: {} − {}, effect {:.4}{checked}",
            m.dv, m.conditions[0], m.conditions[1], r.effect
        )
    } else {
        format!("{}: RM-ANOVA (GG), range {:.4}{checked}", m.dv, r.effect)
    };
    let mut chart = FRAME.chart(root, title, x_lo..x_hi, 0.0..1.0)?;
    FRAME
        .mesh(&mut chart, "participants (n)", "power")
        .draw()
        .map_err(err)?;
    let target = r.target;
    chart
        .draw_series(LineSeries::new(
            [(x_lo, target), (x_hi, target)],
            GREY.stroke_width(2),
        ))
        .map_err(err)?
        .label(format!("target {target}"))
        .legend(legend_line(GREY, 2));
    chart
        .draw_series(LineSeries::new(
            [(x_lo, r.alpha), (x_hi, r.alpha)],
            GREY.mix(0.6).stroke_width(1),
        ))
        .map_err(err)?
        .label(format!("α = {}", r.alpha))
        .legend(|(x, y)| {
            PathElement::new(vec![(x, y), (x + 24, y)], GREY.mix(0.6).stroke_width(1))
        });
    chart
        .draw_series(r.points.iter().map(|p| {
            let x = f64::from(p.n);
            PathElement::new(vec![(x, p.ci[0]), (x, p.ci[1])], CURVE.stroke_width(2))
        }))
        .map_err(err)?;
    chart
        .draw_series(LineSeries::new(
            r.points.iter().map(|p| (f64::from(p.n), p.power)),
            CURVE.stroke_width(3),
        ))
        .map_err(err)?
        .label(format!(
            "simulated power ({} studies per n, 95 % CI)",
            r.replications
        ))
        .legend(legend_line(CURVE, 3));
    chart
        .draw_series(
            r.points
                .iter()
                .map(|p| Circle::new((f64::from(p.n), p.power), 5, CURVE.filled())),
        )
        .map_err(err)?;
    if let Some((fidelity, c)) = check {
        chart
            .draw_series(DashedLineSeries::new(
                c.points.iter().map(|p| (f64::from(p.n), p.power)),
                10,
                6,
                CHECK.stroke_width(2),
            ))
            .map_err(err)?
            .label(format!(
                "final check at {fidelity} fidelity{}",
                c.n_for_target
                    .map_or_else(String::new, |n| format!(" (n for target: {n})"))
            ))
            .legend(legend_line(CHECK, 2));
        chart
            .draw_series(
                c.points
                    .iter()
                    .map(|p| Cross::new((f64::from(p.n), p.power), 5, CHECK.stroke_width(2))),
            )
            .map_err(err)?;
    }
    if let Some(n) = r.n_for_target
        && let Some(p) = r.points.iter().find(|p| p.n == n)
    {
        let x = f64::from(n);
        chart
            .draw_series(LineSeries::new(
                [(x, 0.0), (x, p.power)],
                HIT.stroke_width(2),
            ))
            .map_err(err)?
            .label(format!("n for target: {n}"))
            .legend(legend_line(HIT, 2));
    }
    // Two curves leave the middle free more often than the corners.
    let at = if check.is_some() {
        SeriesLabelPosition::MiddleRight
    } else {
        SeriesLabelPosition::LowerRight
    };
    FRAME.legend(&mut chart, at)?;
    root.present().map_err(err)
}

/// Writes the power curve to `path`: SVG for a `.svg` name, PNG otherwise.
///
/// # Errors
/// Drawing or file errors, as text.
pub fn save(r: &PowerReport, check: Check<'_>, path: &Path) -> Result<(), String> {
    ensure_font()?;
    let svg = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("svg"));
    if svg {
        let mut text = String::new();
        {
            let root = SVGBackend::with_string(&mut text, SIZE).into_drawing_area();
            draw(r, check, &root)?;
        }
        std::fs::write(path, text).map_err(|e| e.to_string())
    } else {
        let (w, h) = SIZE;
        let mut buf = vec![255_u8; (w as usize) * (h as usize) * 3];
        {
            let root = BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area();
            draw(r, check, &root)?;
        }
        image::save_buffer(path, &buf, w, h, image::ExtendedColorType::Rgb8)
            .map_err(|e| e.to_string())
    }
}
