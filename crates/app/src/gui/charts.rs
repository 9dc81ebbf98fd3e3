//! Static charts of the Calibration and Results pages (egui_plot): Bode and
//! coherence plots on a logarithmic frequency axis (the paper's Fig. 5),
//! third-octave deviation bars against a tolerance band (Fig. 7), bar charts
//! with standard-deviation whiskers (Figs. 11–12) and trajectories (Fig. 10).
//!
//! # Logarithmic frequency axis
//! egui_plot has linear axes only, so a frequency f (Hz) is plotted at
//! x = log10(f) ([`log_f`]) and the axis is given a custom grid
//! ([`log_freq_marks`]) and tick labels ([`log_freq_label`]): a mark at every
//! m·10^d for m = 1…9, with "importance" (egui_plot's `step_size`, which
//! sets how early a line or label fades out when zooming out) 1 for decades,
//! 0.3 for the 2 and 5 marks (the 1-2-5 series, ≈ 0.3–0.4 decade apart) and
//! 0.05 for the others (the closest pair, 9 and 10, is 0.046 decade apart).
//! Only 1-2-5 marks get a label, in Hz with k/M prefixes ("20", "500",
//! "1k", "2k").
//!
//! # Zoom and pan
//! Plots sit on scrolling pages, so the mouse wheel scrolls the page: a
//! chart zooms with **Ctrl + wheel** (or a pinch) and the right-drag box,
//! and pans with the wheel and a drag only while its "zoom / pan" toggle is
//! on; **Reset view** (or a double-click) restores the automatic bounds.
//! [`nav_bar`] draws that toggle and button once per chart and
//! [`PlotNav::apply`] sets the plot up accordingly — every chart of this
//! module goes through it.
//!
//! The pure parts (mark generation, labels, mapping, whisker geometry, mean
//! and SD) are unit-tested; the drawing functions only hand their output to
//! egui_plot.

use egui::{Color32, Ui};
use egui_plot::{
    Bar, BarChart, Corner, GridInput, GridMark, Legend, Line, LineStyle, Plot, PlotPoints, PlotUi,
    Span,
};
use std::ops::RangeInclusive;

/// Lowest frequency the log axis generates marks for, log10(Hz).
pub const LOG_F_MIN: f64 = -6.0;
/// Highest frequency the log axis generates marks for, log10(Hz).
pub const LOG_F_MAX: f64 = 9.0;

/// Importance (`step_size`) of a decade mark.
pub const DECADE_STEP: f64 = 1.0;
/// Importance of a 2·10^d or 5·10^d mark.
pub const ONE_TWO_FIVE_STEP: f64 = 0.3;
/// Importance of the other marks (3, 4, 6, 7, 8, 9 ·10^d).
pub const MINOR_STEP: f64 = 0.05;

/// Colours of the study conditions V, P, D and of anything else.
pub fn condition_color(code: &str) -> Color32 {
    match code {
        "V" => Color32::from_rgb(0x9e, 0x9e, 0x9e),
        "P" => Color32::from_rgb(0x42, 0x85, 0xf4),
        "D" => Color32::from_rgb(0xe6, 0x7c, 0x22),
        _ => Color32::from_rgb(0x7c, 0xb3, 0x42),
    }
}

/// Low channel / L colour.
pub const LOW_COLOR: Color32 = Color32::from_rgb(0x42, 0x85, 0xf4);
/// High channel / H colour.
pub const HIGH_COLOR: Color32 = Color32::from_rgb(0xe6, 0x7c, 0x22);
/// Sum / model colour.
pub const SUM_COLOR: Color32 = Color32::from_rgb(0x4c, 0xaf, 0x50);
/// Before-compensation colour.
pub const BEFORE_COLOR: Color32 = Color32::from_rgb(0x9e, 0x9e, 0x9e);
/// Pass colour.
pub const PASS_COLOR: Color32 = Color32::from_rgb(0x2e, 0x9d, 0x3a);
/// Fail / error colour.
pub const FAIL_COLOR: Color32 = Color32::from_rgb(0xd3, 0x2f, 0x2f);

/// x coordinate of frequency `f_hz` on a log-frequency plot: log10(f);
/// `None` for f ≤ 0 or non-finite f.
pub fn log_f(f_hz: f64) -> Option<f64> {
    (f_hz.is_finite() && f_hz > 0.0).then(|| f_hz.log10())
}

/// Inverse of [`log_f`]: the frequency (Hz) at plot coordinate `x`.
pub fn f_of_log(x: f64) -> f64 {
    10f64.powf(x)
}

/// 20·log10|x| in dB (−∞ for 0, NaN for non-finite input).
pub fn db(x: f64) -> f64 {
    20.0 * x.abs().log10()
}

/// Points (log10 f, y) of the finite pairs with f > 0 (others are skipped,
/// so a NaN or a DC bin never reaches the plot).
pub fn log_points(f_hz: &[f64], y: &[f64]) -> Vec<[f64; 2]> {
    f_hz.iter()
        .zip(y)
        .filter_map(|(&f, &v)| log_f(f).filter(|_| v.is_finite()).map(|x| [x, v]))
        .collect()
}

/// Grid marks of a log-frequency axis whose visible range is
/// `bounds` = (log10 f_lo, log10 f_hi) (module documentation). Bounds are
/// clamped to [[`LOG_F_MIN`], [`LOG_F_MAX`]]; reversed bounds are accepted;
/// non-finite bounds give no marks.
pub fn log_freq_marks(bounds: (f64, f64)) -> Vec<GridMark> {
    let (a, b) = bounds;
    if !(a.is_finite() && b.is_finite()) {
        return Vec::new();
    }
    let lo = a.min(b).max(LOG_F_MIN);
    let hi = a.max(b).min(LOG_F_MAX);
    if lo > hi {
        return Vec::new();
    }
    let (d0, d1) = (lo.floor() as i32, hi.ceil() as i32);
    let mut out = Vec::new();
    for d in d0..=d1 {
        for m in 1..=9u32 {
            let value = f64::from(d) + f64::from(m).log10();
            if value < lo || value > hi {
                continue;
            }
            let step_size = match m {
                1 => DECADE_STEP,
                2 | 5 => ONE_TWO_FIVE_STEP,
                _ => MINOR_STEP,
            };
            out.push(GridMark { value, step_size });
        }
    }
    out
}

/// Mantissa m ∈ [1, 10) and decade d of 10^x, with m rounded to 6 digits
/// (so that log10(m·10^d) maps back to exactly m).
fn mantissa_decade(x: f64) -> (f64, i32) {
    let mut d = x.floor();
    let mut m = (10f64.powf(x - d) * 1e6).round() / 1e6;
    if m >= 10.0 {
        m /= 10.0;
        d += 1.0;
    }
    (m, d as i32)
}

/// A frequency in Hz as a short tick label: 3 significant digits, k / M
/// prefixes from 1 kHz / 1 MHz, no trailing zeros ("0.05", "20", "1k",
/// "2.5k", "1M"). Empty for non-finite or non-positive input.
pub fn format_hz(f_hz: f64) -> String {
    if !(f_hz.is_finite() && f_hz > 0.0) {
        return String::new();
    }
    let (value, suffix) = if f_hz >= 1e6 {
        (f_hz / 1e6, "M")
    } else if f_hz >= 1e3 {
        (f_hz / 1e3, "k")
    } else {
        (f_hz, "")
    };
    // Round to 3 significant digits.
    let e = value.log10().floor() as i32;
    let scale = 10f64.powi(2 - e);
    let rounded = (value * scale).round() / scale;
    if !rounded.is_finite() {
        // Subnormal input: the scale overflows.
        return format!("{f_hz:.2e}");
    }
    let decimals = usize::try_from((2 - e).max(0)).unwrap_or(0);
    let mut s = format!("{rounded:.decimals$}");
    if s.contains('.') {
        while s.ends_with('0') {
            s.pop();
        }
        if s.ends_with('.') {
            s.pop();
        }
    }
    s + suffix
}

/// Tick label of a log-frequency grid mark at x = log10(f): the frequency
/// ([`format_hz`]) for the 1-2-5 marks, empty for the minor ones.
pub fn log_freq_label(x: f64) -> String {
    if !x.is_finite() {
        return String::new();
    }
    let (m, _) = mantissa_decade(x);
    if [1.0, 2.0, 5.0].iter().any(|k| (m - k).abs() < 1e-6) {
        format_hz(10f64.powf(x))
    } else {
        String::new()
    }
}

/// Phase in degrees, unwrapped: successive differences are brought into
/// (−180°, 180°] by adding multiples of 360°, starting from the first
/// value wrapped into (−180°, 180°]. Non-finite values pass through and do
/// not disturb the running offset.
pub fn unwrap_phase_deg(phase_rad: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(phase_rad.len());
    let mut prev: Option<f64> = None;
    for &p in phase_rad {
        if !p.is_finite() {
            out.push(f64::NAN);
            continue;
        }
        let deg = p.to_degrees();
        let v = match prev {
            None => deg - 360.0 * ((deg + 180.0) / 360.0).ceil() + 360.0,
            Some(q) => {
                let d = deg - q;
                q + d - 360.0 * ((d + 180.0) / 360.0).ceil() + 360.0
            }
        };
        out.push(v);
        prev = Some(v);
    }
    out
}

/// The polyline of an "I"-shaped whisker from `mean − sd` to `mean + sd` at
/// `x`, with caps of half-width `cap`: bottom cap left → right, back to the
/// centre, up the stem, top cap left → right. `None` when a value is not
/// finite or `sd` < 0.
pub fn whisker(x: f64, mean: f64, sd: f64, cap: f64) -> Option<[[f64; 2]; 6]> {
    if !(x.is_finite() && mean.is_finite() && sd.is_finite() && cap.is_finite() && sd >= 0.0) {
        return None;
    }
    let (lo, hi) = (mean - sd, mean + sd);
    Some([
        [x - cap, lo],
        [x + cap, lo],
        [x, lo],
        [x, hi],
        [x - cap, hi],
        [x + cap, hi],
    ])
}

/// x position of member `j` of `n` bars in group `i` (groups at integer x,
/// members spread symmetrically over 80 % of the unit spacing), and the
/// width of one bar.
pub fn grouped_x(i: usize, j: usize, n: usize) -> (f64, f64) {
    let n = n.max(1);
    let width = 0.8 / n as f64;
    let x = i as f64 - 0.4 + width * (j as f64 + 0.5);
    (x, width)
}

/// One curve of a chart.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend name.
    pub name: String,
    /// Points in plot coordinates (x = log10 f on frequency plots).
    pub points: Vec<[f64; 2]>,
    /// Colour.
    pub color: Color32,
    /// Dashed line (models, predictions) instead of solid (measurements).
    pub dashed: bool,
}

impl Series {
    /// A solid curve.
    pub fn solid(name: impl Into<String>, points: Vec<[f64; 2]>, color: Color32) -> Self {
        Self {
            name: name.into(),
            points,
            color,
            dashed: false,
        }
    }

    /// A dashed curve.
    pub fn dashed(name: impl Into<String>, points: Vec<[f64; 2]>, color: Color32) -> Self {
        Self {
            dashed: true,
            ..Self::solid(name, points, color)
        }
    }

    fn line(&self) -> Line<'static> {
        let l = Line::new(self.name.clone(), PlotPoints::new(self.points.clone()))
            .color(self.color)
            .width(1.5);
        if self.dashed {
            l.style(LineStyle::Dashed { length: 6.0 })
        } else {
            l
        }
    }
}

/// How a chart may be moved this frame ([`nav_bar`], module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PlotNav {
    /// The wheel and a drag pan the plot (else the wheel scrolls the page).
    pub free: bool,
    /// Restore the automatic bounds this frame.
    pub reset: bool,
}

impl PlotNav {
    /// The plot `id` with this navigation: Ctrl + wheel zoom, box zoom and
    /// double-click reset always; wheel and drag pan only when `free`. Its
    /// egui id is [`chart_plot_id`]`(id)` wherever it is drawn.
    pub fn apply<'a>(self, plot: Plot<'a>, id: &str) -> Plot<'a> {
        let p = plot
            .id(chart_plot_id(id))
            .allow_zoom(true)
            .allow_boxed_zoom(true)
            .allow_double_click_reset(true)
            .allow_scroll(self.free)
            .allow_drag(self.free);
        if self.reset { p.reset() } else { p }
    }
}

/// The egui id of the chart plot `id` (e.g. `cal-low-mag`): where its
/// bounds live in egui's memory (`egui_plot::PlotMemory::load`).
pub fn chart_plot_id(id: &str) -> egui::Id {
    egui::Id::unique(("kilotouch-chart", id))
}

/// The toggle "zoom / pan" and the "Reset view" button above the chart
/// `id` (the toggle is remembered per chart for the run of the app).
pub fn nav_bar(ui: &mut Ui, id: &str) -> PlotNav {
    let key = egui::Id::unique(("kilotouch-plot-nav", id));
    let mut free = ui.data(|d| d.get_temp::<bool>(key)).unwrap_or(false);
    let mut reset = false;
    ui.horizontal(|ui| {
        ui.checkbox(&mut free, "zoom / pan").on_hover_text(
            "on: the wheel and a drag move this plot; off: the wheel scrolls the page",
        );
        reset = ui
            .small_button("Reset view")
            .on_hover_text("back to the automatic bounds (also: double-click the plot)")
            .clicked();
        ui.weak("Ctrl + wheel: zoom");
    });
    ui.data_mut(|d| d.insert_temp(key, free));
    PlotNav { free, reset }
}

/// A plot with a log-frequency x axis (module documentation): grid, tick
/// labels in Hz, hover label "f Hz, y unit".
pub fn log_freq_plot<'a>(id: &str, y_label: &'a str, height: f32) -> Plot<'a> {
    Plot::new(id.to_owned())
        .height(height)
        .legend(Legend::default().position(Corner::LeftBottom))
        .x_grid_spacer(|input: GridInput| log_freq_marks(input.bounds))
        .x_axis_formatter(|mark: GridMark, _range: &RangeInclusive<f64>| log_freq_label(mark.value))
        .x_axis_label("frequency (Hz)")
        .y_axis_label(y_label)
        .label_formatter(move |pos| {
            let p = match pos {
                egui_plot::HoverPosition::NearDataPoint { position, .. } => position,
                egui_plot::HoverPosition::Elsewhere { position } => position,
            };
            Some(format!(
                "{} Hz\n{:.3} {y_label}",
                format_hz(f_of_log(p.x)),
                p.y
            ))
        })
}

/// Draw `series` on a log-frequency plot; `extra` adds more items (spans,
/// bars) before the curves.
pub fn freq_chart(
    ui: &mut Ui,
    id: &str,
    y_label: &str,
    height: f32,
    series: &[Series],
    extra: impl FnOnce(&mut PlotUi<'_>),
) {
    let nav = nav_bar(ui, id);
    nav.apply(log_freq_plot(id, y_label, height), id)
        .show(ui, |p| {
            extra(p);
            for s in series {
                p.line(s.line());
            }
        });
}

/// Bode plot of frequency responses: magnitude (dB) over phase (deg), and
/// coherence (0–1) when given, with linked frequency axes (Fig. 5).
pub fn bode(ui: &mut Ui, id: &str, magnitude: &[Series], phase: &[Series], coherence: &[Series]) {
    let link = egui::Id::unique((id, "bode-x"));
    let x_link = egui::Vec2b::new(true, false);
    let nav = nav_bar(ui, id);
    nav.apply(
        log_freq_plot(&format!("{id}-mag"), "dB", 180.0),
        &format!("{id}-mag"),
    )
    .link_axis(link, x_link)
    .show(ui, |p| {
        for s in magnitude {
            p.line(s.line());
        }
    });
    nav.apply(
        log_freq_plot(&format!("{id}-phase"), "deg", 120.0),
        &format!("{id}-phase"),
    )
    .link_axis(link, x_link)
    .show(ui, |p| {
        for s in phase {
            p.line(s.line());
        }
    });
    if !coherence.is_empty() {
        nav.apply(
            log_freq_plot(&format!("{id}-coh"), "γ²", 90.0),
            &format!("{id}-coh"),
        )
        .link_axis(link, x_link)
        .include_y(0.0)
        .include_y(1.0)
        .show(ui, |p| {
            for s in coherence {
                p.line(s.line());
            }
        });
    }
}

/// One third-octave band of a verification (Fig. 7).
#[derive(Debug, Clone, PartialEq)]
pub struct BandBars {
    /// Centre frequency, Hz.
    pub centre_hz: f64,
    /// Deviation before compensation (crossover alone), dB.
    pub before_db: f64,
    /// Deviation after compensation, dB.
    pub after_db: f64,
}

/// Half-width of a band's bar pair on the log axis, decades (third-octave
/// centres are 0.1 decade apart).
const BAND_HALF: f64 = 0.04;

/// Bars of the deviation per third-octave band, before (grey) and after
/// (green inside the tolerance, red outside) compensation, over a shaded
/// ±`tolerance_db` band (Fig. 7).
pub fn third_octave_bars(ui: &mut Ui, id: &str, bands: &[BandBars], tolerance_db: f64) {
    let w = BAND_HALF;
    let before: Vec<Bar> = bands
        .iter()
        .filter_map(|b| {
            let x = log_f(b.centre_hz)?;
            b.before_db.is_finite().then(|| {
                Bar::new(x - w / 2.0, b.before_db)
                    .width(w)
                    .fill(BEFORE_COLOR)
                    .name(format!("{} Hz", format_hz(b.centre_hz)))
            })
        })
        .collect();
    let after: Vec<Bar> = bands
        .iter()
        .filter_map(|b| {
            let x = log_f(b.centre_hz)?;
            let ok = b.after_db.abs() <= tolerance_db;
            b.after_db.is_finite().then(|| {
                Bar::new(x + w / 2.0, b.after_db)
                    .width(w)
                    .fill(if ok { PASS_COLOR } else { FAIL_COLOR })
                    .name(format!("{} Hz", format_hz(b.centre_hz)))
            })
        })
        .collect();
    let tol = if tolerance_db.is_finite() && tolerance_db > 0.0 {
        Some(tolerance_db)
    } else {
        None
    };
    let nav = nav_bar(ui, id);
    nav.apply(log_freq_plot(id, "deviation (dB)", 220.0), id)
        .include_y(-3.0)
        .include_y(3.0)
        .show(ui, |p| {
            if let Some(t) = tol {
                p.span(
                    Span::new(format!("tolerance ±{t} dB"), -t..=t)
                        .axis(egui_plot::Axis::Y)
                        .fill(PASS_COLOR.gamma_multiply(0.15)),
                );
            }
            p.bar_chart(BarChart::new("before compensation", before).color(BEFORE_COLOR));
            p.bar_chart(BarChart::new("after compensation", after).color(PASS_COLOR));
        });
}

/// One series of a grouped bar chart: a value per group (mean, optional SD).
#[derive(Debug, Clone)]
pub struct BarSeries {
    /// Legend name (e.g. a condition).
    pub name: String,
    /// Colour.
    pub color: Color32,
    /// (mean, SD) per group; `None` = no data.
    pub values: Vec<Option<(f64, Option<f64>)>>,
    /// Colour of each group's bar (empty: `color` for all).
    pub group_colors: Vec<Color32>,
}

/// Top of the highest bar or whisker (mean + SD) of `series`, for the
/// y range; `None` without finite data.
pub fn bars_top(series: &[BarSeries]) -> Option<f64> {
    series
        .iter()
        .flat_map(|s| s.values.iter().flatten())
        .map(|(m, sd)| m + sd.unwrap_or(0.0).max(0.0))
        .filter(|v| v.is_finite())
        .reduce(f64::max)
}

/// Grouped bar chart with SD whiskers (Figs. 11–12): one group per entry of
/// `groups` (x tick labels), one bar per series within each group.
pub fn bars_with_whiskers(
    ui: &mut Ui,
    id: &str,
    groups: &[String],
    series: &[BarSeries],
    y_label: &str,
    height: f32,
) {
    let n = series.len();
    let labels = groups.to_vec();
    let top = bars_top(series).unwrap_or(0.0);
    let nav = nav_bar(ui, id);
    nav.apply(Plot::new(id.to_owned()), id)
        .height(height)
        // The legend lists the series in the order of the bars.
        .legend(
            Legend::default()
                .position(Corner::RightTop)
                .follow_insertion_order(true),
        )
        .y_axis_label(y_label.to_owned())
        .include_y(0.0)
        .include_y(1.08 * top)
        // The x marks are the group centres, for the labels only: a grid
        // line there would run through the middle bar up to the top of the
        // plot and read as a whisker.
        .show_grid([false, true])
        .x_grid_spacer(move |input: GridInput| {
            let (lo, hi) = input.bounds;
            (0..labels.len())
                .map(|i| i as f64)
                .filter(|x| *x >= lo - 0.5 && *x <= hi + 0.5)
                .map(|value| GridMark {
                    value,
                    step_size: 1.0,
                })
                .collect()
        })
        .x_axis_formatter(move |mark: GridMark, _r: &RangeInclusive<f64>| {
            let i = mark.value.round();
            if (mark.value - i).abs() < 1e-9 && i >= 0.0 {
                groups.get(i as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        })
        .show(ui, |p| {
            // Bars first, whiskers over them: a whisker's lower half lies
            // inside its bar. Each whisker is a dark line under a light
            // one, visible over the bar and over the background.
            let mut whiskers = Vec::new();
            for (j, s) in series.iter().enumerate() {
                let mut bars = Vec::new();
                for (i, v) in s.values.iter().enumerate() {
                    let Some((mean, sd)) = *v else { continue };
                    if !mean.is_finite() {
                        continue;
                    }
                    let (x, width) = grouped_x(i, j, n);
                    let fill = s.group_colors.get(i).copied().unwrap_or(s.color);
                    bars.push(Bar::new(x, mean).width(width * 0.9).fill(fill));
                    if let Some(pts) = sd.and_then(|sd| whisker(x, mean, sd, width * 0.2)) {
                        whiskers.push(pts);
                    }
                }
                p.bar_chart(BarChart::new(s.name.clone(), bars).color(s.color));
            }
            // Three separate segments (bottom cap, stem, top cap): a
            // polyline that doubles back on itself draws spikes at the turns
            // when it is wide.
            for pts in whiskers {
                let segments = [[pts[0], pts[1]], [pts[2], pts[3]], [pts[4], pts[5]]];
                for (color, width) in [(Color32::from_gray(20), 3.0), (ui_text_color(), 1.4)] {
                    for seg in segments {
                        p.line(
                            Line::new("", PlotPoints::new(seg.to_vec()))
                                .color(color)
                                .width(width)
                                .allow_hover(false),
                        );
                    }
                }
            }
        });
}

fn ui_text_color() -> Color32 {
    Color32::from_gray(200)
}

/// One trajectory of Fig. 10 (positions in µm).
#[derive(Debug, Clone)]
pub struct Trace {
    /// Legend name.
    pub name: String,
    /// (x, y) points, µm.
    pub points: Vec<[f64; 2]>,
    /// Colour.
    pub color: Color32,
}

/// Trajectories in the sample plane with equal axis scales (Fig. 10).
pub fn trajectories(ui: &mut Ui, id: &str, traces: &[Trace], height: f32) {
    let nav = nav_bar(ui, id);
    nav.apply(Plot::new(id.to_owned()), id)
        .height(height)
        .data_aspect(1.0)
        .legend(Legend::default().position(Corner::RightTop))
        .x_axis_label("x (µm)")
        .y_axis_label("y (µm)")
        .show(ui, |p| {
            for t in traces {
                p.line(
                    Line::new(t.name.clone(), PlotPoints::new(t.points.clone()))
                        .color(t.color)
                        .width(1.2),
                );
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(marks: &[GridMark]) -> Vec<f64> {
        marks.iter().map(|m| 10f64.powf(m.value)).collect()
    }

    #[test]
    fn marks_cover_1_to_9_per_decade_inside_the_bounds() {
        let (lo, hi) = (20f64.log10(), 2000f64.log10());
        let marks = log_freq_marks((lo, hi));
        // 20..90 (8) + 100..900 (9) + 1000, 2000 (2).
        assert_eq!(marks.len(), 19);
        for m in &marks {
            assert!(m.value >= lo && m.value <= hi);
        }
        let f = values(&marks);
        for want in [20.0, 30.0, 90.0, 100.0, 500.0, 1000.0, 2000.0] {
            assert!(
                f.iter().any(|v| (v / want - 1.0).abs() < 1e-12),
                "{want} missing"
            );
        }
        // Importance: decades 1, 2/5 the middle, the rest minor.
        for m in &marks {
            let (mant, _) = mantissa_decade(m.value);
            let want = match mant.round() as u32 {
                1 => DECADE_STEP,
                2 | 5 => ONE_TWO_FIVE_STEP,
                _ => MINOR_STEP,
            };
            assert_eq!(m.step_size, want, "mark {}", 10f64.powf(m.value));
        }
    }

    #[test]
    fn marks_handle_reversed_nan_and_extreme_bounds() {
        let a = log_freq_marks((3.0, 1.0));
        let b = log_freq_marks((1.0, 3.0));
        assert_eq!(a, b);
        assert!(log_freq_marks((f64::NAN, 2.0)).is_empty());
        assert!(log_freq_marks((0.0, f64::INFINITY)).is_empty());
        // Far outside the clamp window: nothing, not a huge allocation.
        assert!(log_freq_marks((100.0, 200.0)).is_empty());
        let wide = log_freq_marks((-100.0, 100.0));
        assert_eq!(wide.len(), 9 * ((LOG_F_MAX - LOG_F_MIN) as usize) + 1);
        // A range inside one decade still gets its integer-mantissa marks.
        let narrow = log_freq_marks((200f64.log10(), 450f64.log10()));
        assert_eq!(values(&narrow).len(), 3); // 200, 300, 400
    }

    #[test]
    fn labels_are_hz_on_the_1_2_5_series_only() {
        let cases = [
            (20.0, "20"),
            (50.0, "50"),
            (100.0, "100"),
            (1000.0, "1k"),
            (2000.0, "2k"),
            (5000.0, "5k"),
            (0.5, "0.5"),
            (0.01, "0.01"),
            (2e6, "2M"),
            (1.0, "1"),
        ];
        for (f, want) in cases {
            assert_eq!(log_freq_label(f64::log10(f)), want, "f = {f}");
        }
        for f in [30.0, 70.0, 400.0, 9000.0] {
            assert_eq!(log_freq_label(f64::log10(f)), "", "f = {f}");
        }
        assert_eq!(log_freq_label(f64::NAN), "");
        // Every labelled mark of a generated grid reads back its frequency.
        for m in log_freq_marks((-1.0, 4.0)) {
            let s = log_freq_label(m.value);
            if s.is_empty() {
                continue;
            }
            let (num, mult) = match s.strip_suffix('k') {
                Some(n) => (n, 1e3),
                None => (s.as_str(), 1.0),
            };
            let v: f64 = num.parse().unwrap();
            assert!((v * mult / 10f64.powf(m.value) - 1.0).abs() < 1e-9, "{s}");
        }
    }

    #[test]
    fn format_hz_rounds_to_three_significant_digits() {
        assert_eq!(format_hz(63.0957), "63.1");
        assert_eq!(format_hz(1258.9254), "1.26k");
        assert_eq!(format_hz(999.6), "1000");
        assert_eq!(format_hz(12.0), "12");
        assert_eq!(format_hz(0.0), "");
        assert_eq!(format_hz(-5.0), "");
        assert_eq!(format_hz(f64::NAN), "");
        // Far below the axis clamp (hover over a zoomed-out plot).
        assert_eq!(format_hz(1e-310), "1.00e-310");
    }

    #[test]
    fn log_mapping_round_trips_and_rejects_bad_input() {
        for f in [1e-3, 0.37, 1.0, 63.0957, 1000.0, 4999.9] {
            let x = log_f(f).unwrap();
            assert!((f_of_log(x) / f - 1.0).abs() < 1e-14);
        }
        assert_eq!(log_f(0.0), None);
        assert_eq!(log_f(-1.0), None);
        assert_eq!(log_f(f64::NAN), None);
        assert_eq!(log_f(f64::INFINITY), None);
        let pts = log_points(
            &[0.0, 10.0, 100.0, f64::NAN, 1000.0],
            &[1.0, 2.0, f64::NAN, 4.0, 5.0],
        );
        assert_eq!(pts, vec![[1.0, 2.0], [3.0, 5.0]]);
        assert_eq!(db(10.0), 20.0);
        assert_eq!(db(-0.1), -20.0);
    }

    #[test]
    fn phase_unwrapping_recovers_a_pure_delay() {
        // e^{-j2πfτ} with τ = 1.3 ms, sampled every 10 Hz up to 2 kHz:
        // phase steps of 4.68° ≪ 180°, so the unwrapped phase must equal
        // −360·f·τ degrees exactly (up to rounding).
        let tau = 1.3e-3;
        let f: Vec<f64> = (0..=200).map(|k| 10.0 * f64::from(k)).collect();
        let wrapped: Vec<f64> = f
            .iter()
            .map(|&f| {
                let c = kilotouch_dsp::C64::from_polar(1.0, -2.0 * std::f64::consts::PI * f * tau);
                c.arg()
            })
            .collect();
        let un = unwrap_phase_deg(&wrapped);
        for (u, &f) in un.iter().zip(&f) {
            assert!((u + 360.0 * f * tau).abs() < 1e-9, "f = {f}: {u}");
        }
        // A NaN in the middle is passed through and does not break the ramp.
        let mut w2 = wrapped.clone();
        w2[50] = f64::NAN;
        let un2 = unwrap_phase_deg(&w2);
        assert!(un2[50].is_nan());
        assert!((un2[120] - un[120]).abs() < 1e-9);
        // First value wrapped into (−180, 180].
        assert!((unwrap_phase_deg(&[3.0 * std::f64::consts::PI])[0] - 180.0).abs() < 1e-9);
    }

    #[test]
    fn whisker_spans_mean_plus_minus_sd_with_centred_caps() {
        let w = whisker(2.0, 10.0, 3.0, 0.1).unwrap();
        let ys: Vec<f64> = w.iter().map(|p| p[1]).collect();
        assert_eq!(ys.iter().copied().fold(f64::INFINITY, f64::min), 7.0);
        assert_eq!(ys.iter().copied().fold(f64::NEG_INFINITY, f64::max), 13.0);
        // Caps: symmetric about x, half-width 0.1, at the two ends.
        assert_eq!(w[0], [1.9, 7.0]);
        assert_eq!(w[1], [2.1, 7.0]);
        assert_eq!(w[4], [1.9, 13.0]);
        assert_eq!(w[5], [2.1, 13.0]);
        // Stem on x.
        assert_eq!(w[2], [2.0, 7.0]);
        assert_eq!(w[3], [2.0, 13.0]);
        assert!(whisker(0.0, 1.0, -1.0, 0.1).is_none());
        assert!(whisker(0.0, f64::NAN, 1.0, 0.1).is_none());
        // Zero SD: a flat whisker at the mean (still drawable).
        assert!(
            whisker(0.0, 1.0, 0.0, 0.1)
                .unwrap()
                .iter()
                .all(|p| p[1] == 1.0)
        );
    }

    #[test]
    fn bars_top_includes_the_whisker() {
        let s = |values| BarSeries {
            name: String::new(),
            color: Color32::WHITE,
            values,
            group_colors: Vec::new(),
        };
        let a = s(vec![Some((3.0, Some(2.0))), None, Some((4.5, None))]);
        let b = s(vec![Some((f64::NAN, None)), Some((1.0, Some(0.5)))]);
        assert_eq!(bars_top(&[a.clone(), b.clone()]), Some(5.0));
        assert_eq!(bars_top(&[b]), Some(1.5));
        assert_eq!(bars_top(&[s(vec![None])]), None);
        assert_eq!(bars_top(&[]), None);
    }

    #[test]
    fn grouped_bars_tile_each_group_without_overlap() {
        for n in 1..=5 {
            let mut prev_right = f64::NEG_INFINITY;
            for j in 0..n {
                let (x, w) = grouped_x(3, j, n);
                assert!((w - 0.8 / n as f64).abs() < 1e-15);
                assert!(x - w / 2.0 >= prev_right - 1e-12);
                prev_right = x + w / 2.0;
                assert!(x > 2.5 && x < 3.5);
            }
            // Symmetric about the group centre.
            let (first, _) = grouped_x(3, 0, n);
            let (last, _) = grouped_x(3, n - 1, n);
            assert!((first + last - 6.0).abs() < 1e-12);
        }
    }
}
