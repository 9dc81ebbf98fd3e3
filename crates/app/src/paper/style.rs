//! The figures' common look and their output: an embedded font (no system
//! font lookup), colours per channel and condition, and one function that
//! draws a figure twice, to PNG and to SVG, with the same code.
//!
//! Text goes through `ab_glyph` with DejaVu Sans compiled into the binary
//! (`assets/fonts/DejaVuSans.ttf`, Bitstream Vera licence beside it), so the
//! figures render identically on a machine without fontconfig. The SVG
//! names the family "sans-serif"; viewers substitute their own sans font.

use plotters::chart::MeshStyle;
use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;
use std::path::Path;
use std::sync::OnceLock;

/// DejaVu Sans (Bitstream Vera licence: `assets/fonts/DejaVuSans-LICENSE.txt`).
static DEJAVU_SANS: &[u8] = include_bytes!("../../../../assets/fonts/DejaVuSans.ttf");

/// Family every figure uses.
pub const FONT: &str = "sans-serif";

/// Pixel size of a single-panel figure (PNG); the SVG has the same size in
/// user units.
pub const SIZE_SINGLE: (u32, u32) = (960, 640);
/// Pixel size of a figure with a 2 × 2 grid of panels.
pub const SIZE_GRID: (u32, u32) = (1400, 1000);

/// Font sizes, px.
pub const TITLE_PX: f64 = 26.0;
/// Axis descriptions.
pub const LABEL_PX: f64 = 20.0;
/// Tick labels and legends.
pub const TICK_PX: f64 = 17.0;

/// Low channel (Pantograph).
pub const LOW: RGBColor = RGBColor(31, 119, 180);
/// High channel (Haptuator).
pub const HIGH: RGBColor = RGBColor(214, 39, 40);
/// Sum / combined.
pub const SUM: RGBColor = RGBColor(30, 30, 30);
/// Secondary (models, references).
pub const GREY: RGBColor = RGBColor(120, 120, 120);
/// Free space (Fig. 9).
pub const FREE: RGBColor = RGBColor(44, 160, 44);
/// Pressed (Fig. 9).
pub const PRESSED: RGBColor = RGBColor(148, 103, 189);

/// Colour of a study condition (V, P, D), as on the Results page.
pub fn condition_color(code: &str) -> RGBColor {
    match code {
        "V" => RGBColor(127, 127, 127),
        "P" => RGBColor(31, 119, 180),
        "D" => RGBColor(255, 127, 14),
        _ => RGBColor(90, 90, 90),
    }
}

/// A cycle of distinguishable colours (trajectories).
pub fn cycle_color(i: usize) -> RGBColor {
    const C: [RGBColor; 8] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(23, 190, 207),
    ];
    C[i % C.len()]
}

/// Register the embedded font once per process.
///
/// # Errors
/// The embedded file is not a usable TrueType font (a build defect).
pub fn ensure_font() -> Result<(), String> {
    static DONE: OnceLock<Result<(), String>> = OnceLock::new();
    DONE.get_or_init(|| {
        for style in [FontStyle::Normal, FontStyle::Bold] {
            plotters::style::register_font(FONT, style, DEJAVU_SANS)
                .map_err(|_| "the embedded DejaVu Sans font could not be read".to_owned())?;
        }
        Ok(())
    })
    .clone()
}

/// Text style of a given size.
pub fn text(px: f64) -> TextStyle<'static> {
    (FONT, px).into_font().into()
}

/// Text style of a given size and colour.
pub fn text_color(px: f64, c: RGBColor) -> TextStyle<'static> {
    (FONT, px).into_font().color(&c)
}

/// A figure that can draw itself on any plotters backend.
pub trait Figure {
    /// Pixel size.
    fn size(&self) -> (u32, u32);
    /// Draw on `root` (already filled white).
    ///
    /// # Errors
    /// Backend errors, as text.
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>;
}

/// Convert any drawing error to text.
pub fn err<E: std::fmt::Debug>(e: E) -> String {
    format!("drawing failed: {e:?}")
}

/// `root` below a figure title of `title` ([`TITLE_PX`] px).
///
/// # Errors
/// Backend errors, as text.
pub fn titled<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
) -> Result<DrawingArea<DB, Shift>, String> {
    root.titled(title, text(TITLE_PX)).map_err(err)
}

/// Draw `fig` to `png` (RGB, 8 bit) and to `svg`.
///
/// # Errors
/// Drawing or file errors, naming the file.
pub fn save<F: Figure>(fig: &F, png: &Path, svg: &Path) -> Result<(), String> {
    ensure_font()?;
    let (w, h) = fig.size();
    let mut buf = vec![255_u8; (w as usize) * (h as usize) * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        fig.draw(&root)?;
        root.present().map_err(err)?;
    }
    image::save_buffer(png, &buf, w, h, image::ExtendedColorType::Rgb8)
        .map_err(|e| format!("{}: {e}", png.display()))?;
    let mut svg_text = String::new();
    {
        let root = SVGBackend::with_string(&mut svg_text, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        fig.draw(&root)?;
        root.present().map_err(err)?;
    }
    std::fs::write(svg, svg_text).map_err(|e| format!("{}: {e}", svg.display()))?;
    Ok(())
}

/// Log-spaced grid of `n ≥ 2` points from `lo` to `hi` (inclusive).
pub fn log_grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let n = n.max(2);
    (0..n)
        .map(|i| lo * (hi / lo).powf(i as f64 / (n - 1) as f64))
        .collect()
}

/// Lower and upper bound of the finite values in `v`, padded by `pad`
/// of the span (a unit span around a constant); `None` when none is finite.
pub fn bounds(v: impl IntoIterator<Item = f64>, pad: f64) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for x in v.into_iter().filter(|x| x.is_finite()) {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if !lo.is_finite() {
        return None;
    }
    let span = if hi > lo { hi - lo } else { 1.0 };
    Some((lo - pad * span, hi + pad * span))
}

/// The set-up of one chart, shared by every figure: the caption's size, the
/// margins and label areas around the plotting area, the text sizes of the
/// axis descriptions and tick labels, px; the light grid and the legend box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// Caption size, px.
    pub caption_px: f64,
    /// Margin on every side but the right, px.
    pub margin: u32,
    /// Margin on the right (room for the last tick label), px.
    pub margin_right: u32,
    /// Height of the x-axis label area, px.
    pub x_label_area: u32,
    /// Width of the y-axis label area, px.
    pub y_label_area: u32,
    /// Axis descriptions, px.
    pub label_px: f64,
    /// Tick labels and legend entries, px.
    pub tick_px: f64,
}

/// A chart of [`Frame::chart`]: on a `DB` backend over the coordinates `X` × `Y`.
pub type Chart<'a, DB, X, Y> = ChartContext<
    'a,
    DB,
    Cartesian2d<<X as AsRangedCoord>::CoordDescType, <Y as AsRangedCoord>::CoordDescType>,
>;

/// Colour of the minor grid lines.
const LIGHT_GRID: RGBColor = RGBColor(235, 235, 235);

impl Frame {
    /// A single chart filling a figure, under the figure's title.
    pub const FIGURE: Self = Self {
        caption_px: TITLE_PX,
        margin: 16,
        margin_right: 16,
        x_label_area: 56,
        y_label_area: 72,
        label_px: LABEL_PX,
        tick_px: TICK_PX,
    };

    /// One panel of a grid of panels, under the panel's title.
    pub const PANEL: Self = Self {
        caption_px: LABEL_PX + 2.0,
        margin: 12,
        margin_right: 12,
        x_label_area: 50,
        y_label_area: 78,
        label_px: LABEL_PX,
        tick_px: TICK_PX,
    };

    /// A chart on `area` titled `title` over the coordinates `x` × `y`.
    ///
    /// # Errors
    /// Backend errors, as text.
    pub fn chart<'a, DB: DrawingBackend, X: AsRangedCoord, Y: AsRangedCoord>(
        &self,
        area: &'a DrawingArea<DB, Shift>,
        title: impl AsRef<str>,
        x: X,
        y: Y,
    ) -> Result<Chart<'a, DB, X, Y>, String> {
        ChartBuilder::on(area)
            .caption(title, text(self.caption_px))
            .margin(self.margin)
            .margin_right(self.margin_right)
            .x_label_area_size(self.x_label_area)
            .y_label_area_size(self.y_label_area)
            .build_cartesian_2d(x, y)
            .map_err(err)
    }

    /// The mesh of `chart` with the axis descriptions `x_desc` and
    /// `y_desc`, this frame's text sizes and the light grid; the caller
    /// adds what differs (tick formatters, counts) and draws it.
    pub fn mesh<'a, 'b, DB, X, Y>(
        &self,
        chart: &'b mut ChartContext<'a, DB, Cartesian2d<X, Y>>,
        x_desc: impl Into<String>,
        y_desc: impl Into<String>,
    ) -> MeshStyle<'a, 'b, X, Y, DB>
    where
        DB: DrawingBackend,
        X: Ranged + ValueFormatter<X::ValueType>,
        Y: Ranged + ValueFormatter<Y::ValueType>,
    {
        let mut mesh = chart.configure_mesh();
        mesh.x_desc(x_desc)
            .y_desc(y_desc)
            .axis_desc_style(text(self.label_px))
            .label_style(text(self.tick_px))
            .light_line_style(LIGHT_GRID);
        mesh
    }

    /// Draws the legend box of `chart` at `pos`, entries at the tick size.
    ///
    /// # Errors
    /// Backend errors, as text.
    pub fn legend<'a, 'b, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
        &self,
        chart: &'b mut ChartContext<'a, DB, CT>,
        pos: SeriesLabelPosition,
    ) -> Result<(), String> {
        chart
            .configure_series_labels()
            .position(pos)
            .label_font(text(self.tick_px))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(err)
    }
}

/// Legend box style shared by the figures ([`Frame::legend`]).
///
/// # Errors
/// Backend errors, as text.
pub fn legend<'a, 'b, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &'b mut ChartContext<'a, DB, CT>,
    pos: SeriesLabelPosition,
) -> Result<(), String> {
    Frame::FIGURE.legend(chart, pos)
}

/// Short line segment for a legend entry.
pub fn legend_line(c: RGBColor, width: u32) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], c.stroke_width(width))
}

/// Tick label of a logarithmic frequency axis: only 1, 2 and 5 × 10ⁿ are
/// written (the others stay as unlabelled grid lines, so labels never
/// collide).
pub fn log_label(v: &f64) -> String {
    if !(v.is_finite() && *v > 0.0) {
        return String::new();
    }
    let m = v / 10f64.powf(v.log10().floor());
    if [1.0, 2.0, 5.0, 10.0]
        .iter()
        .any(|k| (m - k).abs() < 0.02 * k)
    {
        format!("{v:.0}")
    } else {
        String::new()
    }
}

/// A p-value for a figure: three decimals, scientific below 0.001.
pub fn fmt_p(p: f64) -> String {
    if p < 0.001 {
        format!("{p:.1e}")
    } else {
        format!("{p:.3}")
    }
}

/// Tick label of a linear axis without "-0.0".
pub fn lin_label(v: &f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.').to_owned();
    if s == "-0" { "0".into() } else { s }
}
