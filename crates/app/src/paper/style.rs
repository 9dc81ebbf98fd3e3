//! The figures' common look and their output: an embedded font (no system
//! font lookup), colours per channel and condition, and one function that
//! draws a figure twice, to PNG and to SVG, with the same code.
//!
//! Text goes through `ab_glyph` with DejaVu Sans compiled into the binary
//! (`assets/fonts/DejaVuSans.ttf`, Bitstream Vera licence beside it), so the
//! figures render identically on a machine without fontconfig. The SVG
//! names the family "sans-serif"; viewers substitute their own sans font.

use plotters::coord::Shift;
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

/// Legend box style shared by the figures.
pub fn legend<'a, 'b, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &'b mut ChartContext<'a, DB, CT>,
    pos: SeriesLabelPosition,
) -> Result<(), String> {
    chart
        .configure_series_labels()
        .position(pos)
        .label_font(text(TICK_PX))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(err)
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
