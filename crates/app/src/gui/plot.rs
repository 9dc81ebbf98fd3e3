//! Live, decimating plots: ring buffers of the engine's telemetry,
//! min/max-per-pixel-column decimation, the acceleration histogram and the
//! Welch spectrum on log axes.
//!
//! **Decimation.** A trace of n samples drawn into c pixel columns is split
//! into c consecutive groups, group j holding the samples
//! [⌊j·n/c⌋, ⌊(j+1)·n/c⌋); each group is drawn as a vertical segment from its
//! minimum to its maximum, consecutive segments joined. The drawn envelope
//! therefore contains every sample's value exactly (no sample's extreme is
//! lost, unlike sub-sampling), and the cost of drawing is O(c) whatever n
//! is: a 10 s trace at 10 kHz (10⁵ samples) draws as ~2·width points.

use egui_plot::{GridMark, Line, Plot, PlotPoints};
use kilotouch_dsp::spectral::{Spectrum, WelchConfig, welch};

/// Fixed-capacity ring of samples (the oldest is overwritten).
#[derive(Debug, Clone)]
pub struct Ring {
    buf: Vec<f32>,
    head: usize,
    len: usize,
}

impl Ring {
    /// Ring holding `capacity` (≥ 1) samples.
    pub fn new(capacity: usize) -> Self {
        Self {
            buf: vec![0.0; capacity.max(1)],
            head: 0,
            len: 0,
        }
    }

    /// Capacity.
    pub fn capacity(&self) -> usize {
        self.buf.len()
    }

    /// Samples held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Empty?
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Forget everything.
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }

    /// Append one sample.
    pub fn push(&mut self, v: f32) {
        self.buf[self.head] = v;
        self.head = (self.head + 1) % self.buf.len();
        self.len = (self.len + 1).min(self.buf.len());
    }

    /// The last `n` samples (fewer if not available), oldest first, into `out`.
    pub fn last_into(&self, n: usize, out: &mut Vec<f32>) {
        out.clear();
        let n = n.min(self.len);
        let cap = self.buf.len();
        let start = (self.head + cap - n) % cap;
        if start + n <= cap {
            out.extend_from_slice(&self.buf[start..start + n]);
        } else {
            out.extend_from_slice(&self.buf[start..]);
            out.extend_from_slice(&self.buf[..n - (cap - start)]);
        }
    }
}

/// Min/max of each of `columns` consecutive groups of `samples` (module
/// docs). Non-finite samples are skipped; a group without a finite sample
/// gives `None`. `out` has exactly `columns` entries (0 columns → empty).
pub fn min_max_columns(samples: &[f32], columns: usize, out: &mut Vec<Option<(f32, f32)>>) {
    out.clear();
    let n = samples.len();
    for j in 0..columns {
        let a = j * n / columns;
        let b = (j + 1) * n / columns;
        let mut mm: Option<(f32, f32)> = None;
        for &v in &samples[a..b] {
            if v.is_finite() {
                mm = Some(match mm {
                    None => (v, v),
                    Some((lo, hi)) => (lo.min(v), hi.max(v)),
                });
            }
        }
        out.push(mm);
    }
}

/// Index range of samples in column `j` (as [`min_max_columns`] splits).
pub fn column_range(n: usize, columns: usize, j: usize) -> std::ops::Range<usize> {
    j * n / columns..(j + 1) * n / columns
}

/// The decimated envelope as a polyline: for each non-empty column at
/// x = x0 + (j + ½)·(x1 − x0)/columns, the points (x, min) and (x, max)
/// (alternating order so consecutive columns join at their nearer ends).
pub fn envelope_points(samples: &[f32], columns: usize, x0: f64, x1: f64) -> Vec<[f64; 2]> {
    let mut mm = Vec::with_capacity(columns);
    min_max_columns(samples, columns, &mut mm);
    let mut pts = Vec::with_capacity(2 * columns);
    let dx = (x1 - x0) / columns.max(1) as f64;
    for (j, m) in mm.iter().enumerate() {
        if let Some((lo, hi)) = *m {
            let x = x0 + (j as f64 + 0.5) * dx;
            if j % 2 == 0 {
                pts.push([x, f64::from(lo)]);
                pts.push([x, f64::from(hi)]);
            } else {
                pts.push([x, f64::from(hi)]);
                pts.push([x, f64::from(lo)]);
            }
        }
    }
    pts
}

/// Histogram of the finite `samples` in `bins` equal bins over [lo, hi]
/// (values outside are counted in the end bins).
pub fn histogram(samples: &[f32], lo: f32, hi: f32, bins: usize) -> Vec<u32> {
    let mut h = vec![0u32; bins];
    if bins == 0 || hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return h;
    }
    let w = (hi - lo) / bins as f32;
    for &v in samples {
        if v.is_finite() {
            let k = ((v - lo) / w).floor();
            let k = if k < 0.0 {
                0
            } else {
                (k as usize).min(bins - 1)
            };
            h[k] += 1;
        }
    }
    h
}

/// A "nice" symmetric range ±r with r ≥ `x` from the 1-2-5 series.
pub fn nice_range(x: f32) -> f32 {
    if !(x.is_finite() && x > 0.0) {
        return 1.0;
    }
    let e = x.log10().floor();
    let base = 10f32.powf(e);
    for m in [1.0, 2.0, 5.0, 10.0] {
        if m * base >= x {
            return m * base;
        }
    }
    10.0 * base
}

/// A tick label with as many decimals as the tick spacing needs (egui_plot's
/// default rounds small values such as 0.002 m/s² to "0"): the spacing's
/// leading digit is kept, values below 10⁻³ or above 10⁵ in scientific
/// notation.
pub fn tick_label(mark: egui_plot::GridMark, _range: &std::ops::RangeInclusive<f64>) -> String {
    let v = mark.value;
    let step = mark.step_size.abs();
    if v == 0.0 {
        return "0".into();
    }
    if !(v.is_finite() && step.is_finite() && step > 0.0) {
        return String::new();
    }
    let a = v.abs();
    if !(1e-3..1e5).contains(&a) {
        return format!("{v:.1e}");
    }
    let decimals = (-step.log10().floor()).clamp(0.0, 6.0) as usize;
    format!("{v:.decimals$}")
}

/// An SI prefix and its factor for values up to `peak` in magnitude: the
/// prefix (p … k) whose scaled peak lies in [1, 1000), e.g. 0.0032 N →
/// (1000, "m"): 3.2 mN. Zero, tiny or non-finite peaks give no prefix.
pub fn si_prefix(peak: f64) -> (f64, &'static str) {
    const PREFIXES: [(i32, &str); 7] = [
        (-12, "p"),
        (-9, "n"),
        (-6, "µ"),
        (-3, "m"),
        (0, ""),
        (3, "k"),
        (6, "M"),
    ];
    if !(peak.is_finite() && peak > 1e-15) {
        return (1.0, "");
    }
    let e = (3.0 * (peak.log10() / 3.0).floor()).clamp(-12.0, 6.0) as i32;
    let (e, p) = PREFIXES
        .iter()
        .copied()
        .find(|(x, _)| *x == e)
        .unwrap_or((0, ""));
    (10f64.powi(-e), p)
}

/// A value with an SI prefix and 3 significant digits, e.g.
/// `format_si(0.0312, "m/s²")` = "31.2 mm/s²".
pub fn format_si(v: f64, unit: &str) -> String {
    if !v.is_finite() {
        return format!("– {unit}");
    }
    let (f, p) = si_prefix(v.abs());
    let x = v * f;
    let decimals = if x.abs() >= 100.0 {
        0
    } else if x.abs() >= 10.0 {
        1
    } else {
        2
    };
    format!("{x:.decimals$} {p}{unit}")
}

/// The SI prefix of a live axis, with hysteresis: it changes only when the
/// data's peak leaves [0.5, 2000) of the current unit, so a trace that
/// hovers around 1 mN does not flip between "mN" and "µN" every frame.
#[derive(Debug, Clone, Copy, Default)]
pub struct AxisScale {
    current: Option<(f64, &'static str)>,
}

impl AxisScale {
    /// Update with the data's peak magnitude; the factor to multiply the
    /// values by and the prefix of their unit.
    pub fn update(&mut self, peak: f64) -> (f64, &'static str) {
        let keep = self.current.is_some_and(|(f, _)| {
            !peak.is_finite() || peak <= 0.0 || (0.5..2000.0).contains(&(peak * f))
        });
        if !keep {
            self.current = Some(si_prefix(peak));
        }
        self.current.unwrap_or((1.0, ""))
    }
}

/// Grid marks on the 1-2-(2.5)-5 series spaced at least `min_px` screen points
/// apart (egui_plot's default spacer steps by powers of ten only, so a
/// ±0.5 range got ticks every 0.1 — too close to label — or only "0").
/// When that leaves fewer than three marks in view (a short plot), the next
/// smaller steps are taken down to `floor_px`, the spacing below which
/// egui_plot would not label them. Every mark returned is far enough apart
/// for egui_plot to label it.
pub fn ticks_125(input: egui_plot::GridInput, min_px: f64, floor_px: f64) -> Vec<GridMark> {
    // base_step_size is the value of egui_plot's 8-point minimum grid spacing.
    let per_px = input.base_step_size / 8.0;
    let (lo, hi) = input.bounds;
    let want = per_px * min_px;
    if !(want.is_finite() && want > 0.0 && lo.is_finite() && hi.is_finite() && hi > lo) {
        return Vec::new();
    }
    let e = want.log10().floor();
    let base = 10f64.powf(e);
    // The 1-2-5 series with 2.5 (a short axis then keeps ±250 beside 0).
    let series = [0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 2.5, 5.0, 10.0];
    let Some(mut k) = series.iter().position(|m| m * base >= want * (1.0 - 1e-9)) else {
        return Vec::new();
    };
    let marks = |step: f64| -> Vec<GridMark> {
        let first = (lo / step).ceil() as i64;
        let last = (hi / step).floor() as i64;
        if last < first || last - first > 1000 {
            return Vec::new();
        }
        (first..=last)
            .map(|j| GridMark {
                value: j as f64 * step,
                step_size: step,
            })
            .collect()
    };
    let mut out = marks(series[k] * base);
    while out.len() < 3 && k > 0 && series[k - 1] * base >= per_px * floor_px * (1.0 + 1e-9) {
        k -= 1;
        out = marks(series[k] * base);
    }
    out
}

/// What an axis of a live plot showed: its label and the tick labels
/// (read by the tests; egui_plot paints them as text, not as widgets).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AxisReadout {
    /// The axis label, e.g. "Pantograph force sent (mN)".
    pub label: String,
    /// The tick labels drawn, e.g. ["-2", "0", "2"].
    pub ticks: Vec<String>,
}

/// The tick labels an axis drew, recorded as [`tick_label`] formats them
/// (egui_plot calls the formatter while it paints).
#[derive(Debug, Default)]
struct ShownTicks(std::cell::RefCell<Vec<String>>);

impl ShownTicks {
    /// [`tick_label`], recorded.
    fn label(&self, mark: egui_plot::GridMark, range: &std::ops::RangeInclusive<f64>) -> String {
        let t = tick_label(mark, range);
        self.0.borrow_mut().push(t.clone());
        t
    }

    /// The axis's readout: `label` and the ticks recorded.
    fn readout(self, label: String) -> AxisReadout {
        AxisReadout {
            label,
            ticks: self.0.into_inner(),
        }
    }
}

/// A plot `height` points high that the mouse neither scrolls, drags nor
/// zooms (the live plots follow their data).
fn fixed_plot<'a>(id: &str, height: f32) -> Plot<'a> {
    Plot::new(id.to_owned())
        .height(height)
        .allow_scroll(false)
        .allow_drag(false)
        .allow_zoom(false)
}

/// Spacing of labelled ticks, screen points: wanted, and the least
/// ([`ticks_125`]); egui_plot hides x labels closer than 60 pt and y labels
/// closer than 20 pt.
const X_TICK_PX: (f64, f64) = (80.0, 62.0);
const Y_TICK_PX: (f64, f64) = (32.0, 21.0);

/// Names of the live traces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trace {
    /// Pantograph force sent to the device x (after the condition and the
    /// safety layer: 0 in V and while the outputs are held at zero), N.
    ForceX,
    /// Pantograph force sent y, N.
    ForceY,
    /// Haptuator drive, V.
    Haptuator,
    /// Tip acceleration x, m/s².
    AccelX,
    /// Tip acceleration y, m/s².
    AccelY,
}

impl Trace {
    /// All traces.
    pub const ALL: [Trace; 5] = [
        Trace::ForceX,
        Trace::ForceY,
        Trace::Haptuator,
        Trace::AccelX,
        Trace::AccelY,
    ];
}

/// Ring buffers of the traces the Explore page plots.
#[derive(Debug, Clone)]
pub struct LiveTraces {
    fs: f64,
    rings: [Ring; 5],
    /// Sequence number of the newest sample.
    pub last_seq: u64,
    scratch: Vec<f32>,
}

impl LiveTraces {
    /// Traces of `seconds` at `fs` Hz.
    pub fn new(fs: f64, seconds: f64) -> Self {
        let n = (fs * seconds).ceil().max(1.0) as usize;
        Self {
            fs,
            rings: std::array::from_fn(|_| Ring::new(n)),
            last_seq: 0,
            scratch: Vec::new(),
        }
    }

    /// Sample rate, Hz.
    pub fn fs(&self) -> f64 {
        self.fs
    }

    /// Append one telemetry sample.
    pub fn push(&mut self, s: &crate::engine::TelemetrySample) {
        let v = [
            s.output.force_n[0],
            s.output.force_n[1],
            s.output.haptuator_v,
            s.accel_m_s2[0],
            s.accel_m_s2[1],
        ];
        for (r, x) in self.rings.iter_mut().zip(v) {
            r.push(x as f32);
        }
        self.last_seq = s.seq;
    }

    /// Forget everything.
    pub fn clear(&mut self) {
        for r in &mut self.rings {
            r.clear();
        }
    }

    /// The last `seconds` of a trace, oldest first.
    pub fn last(&mut self, t: Trace, seconds: f64) -> &[f32] {
        let n = (seconds * self.fs) as usize;
        let idx = Trace::ALL.iter().position(|x| *x == t).unwrap_or(0);
        self.rings[idx].last_into(n, &mut self.scratch);
        &self.scratch
    }

    /// Samples held.
    pub fn len(&self) -> usize {
        self.rings[0].len()
    }

    /// Empty?
    pub fn is_empty(&self) -> bool {
        self.rings[0].is_empty()
    }
}

/// Draw decimated traces (time axis: seconds before now) in one plot, the
/// values in `unit` scaled by an SI prefix chosen by `scale` (e.g. N → mN);
/// the y axis is labelled with the unit alone (the legend names the
/// quantities: a long axis label ran into the next plot on a small
/// window); `time_label`: label the time axis. Returns what the y axis
/// showed.
#[allow(clippy::too_many_arguments)]
pub fn trace_plot(
    ui: &mut egui::Ui,
    id: &str,
    height: f32,
    unit: &str,
    scale: &mut AxisScale,
    series: &[(&str, egui::Color32, &[f32])],
    fs: f64,
    time_label: bool,
) -> AxisReadout {
    let columns = (ui.available_width().max(50.0) as usize).min(4000);
    let peak = series
        .iter()
        .flat_map(|(_, _, s)| s.iter())
        .filter(|v| v.is_finite())
        .fold(0f64, |m, v| m.max(f64::from(v.abs())));
    let (factor, prefix) = scale.update(peak);
    // The y range reaches a 1-2-5 value on each side the data reaches, so
    // ±that value and 0 are ticks in view whatever the plot's height (a
    // range just short of a tick value left only "0" labelled).
    let (lo, hi) = series
        .iter()
        .flat_map(|(_, _, s)| s.iter())
        .filter(|v| v.is_finite())
        .fold((0f64, 0f64), |(lo, hi), &v| {
            (lo.min(f64::from(v)), hi.max(f64::from(v)))
        });
    let nice = |x: f64| f64::from(nice_range((x * factor) as f32));
    let y_top = if hi > 0.0 { nice(hi) } else { 0.0 };
    let y_bottom = if lo < 0.0 { -nice(-lo) } else { 0.0 };
    let lines: Vec<Line<'static>> = series
        .iter()
        .map(|(name, color, s)| {
            let t = s.len() as f64 / fs;
            let mut pts = envelope_points(s, columns, -t, 0.0);
            for p in &mut pts {
                p[1] *= factor;
            }
            Line::new(*name, PlotPoints::from(pts))
                .color(*color)
                .width(1.0)
        })
        .collect();
    let label = format!("{prefix}{unit}");
    let shown = ShownTicks::default();
    fixed_plot(id, height)
        .y_axis_label(label.clone())
        .y_grid_spacer(|i| ticks_125(i, Y_TICK_PX.0, Y_TICK_PX.1))
        .y_axis_formatter(|m, r| shown.label(m, r))
        .y_axis_min_width(44.0)
        .x_grid_spacer(|i| ticks_125(i, X_TICK_PX.0, X_TICK_PX.1))
        .x_axis_formatter(tick_label)
        .x_axis_label(if time_label {
            "time before now (s)"
        } else {
            ""
        })
        .include_y(0.0)
        .include_y(y_top)
        .include_y(y_bottom)
        .legend(egui_plot::Legend::default())
        .show(ui, |p| {
            for l in lines {
                p.line(l);
            }
        });
    shown.readout(label)
}

/// Bins of a histogram of a quantised signal: `bins` bins over ±`range`,
/// widened to an odd multiple k of the quantisation step `lsb` (when
/// `lsb` > 0) and centred on its levels, so each bin holds exactly k
/// levels. Equal-width bins that are not a multiple of the step hold one
/// level or two depending on where they fall, which draws spikes that are
/// not in the signal (the 14.5 mm/s² steps of the simulated accelerometer
/// binned at ±0.5 m/s² / 61). Returns (first bin's lower edge, bin width,
/// number of bins).
pub fn quantised_bins(range: f64, bins: usize, lsb: f64) -> (f64, f64, usize) {
    let bins = bins.max(1);
    let w = 2.0 * range / bins as f64;
    if !(lsb.is_finite() && lsb > 0.0 && w.is_finite() && w > 0.0) {
        return (-range, w, bins);
    }
    let mut k = (w / lsb).round().max(1.0) as u64;
    if k.is_multiple_of(2) {
        k += 1;
    }
    let w = k as f64 * lsb;
    // Bins centred on 0, ±w, ±2w … (level j·lsb falls into bin round(j/k);
    // k odd puts no level on an edge).
    let half = (range / w).ceil().max(1.0);
    let n = 2 * half as usize + 1;
    (-(half + 0.5) * w, w, n)
}

/// Standard deviation of the finite samples (population, 1/n), `None`
/// below 2 samples.
pub fn sd(samples: &[f32]) -> Option<f64> {
    let (mut n, mut mean, mut m2) = (0f64, 0f64, 0f64);
    for &v in samples {
        if v.is_finite() {
            // Welford's update.
            n += 1.0;
            let x = f64::from(v);
            let d = x - mean;
            mean += d / n;
            m2 += d * (x - mean);
        }
    }
    (n >= 2.0).then(|| (m2 / n).sqrt())
}

/// Draw a histogram of `samples` (unit `unit`, e.g. "m/s²") over ±`range`
/// as a probability density, bins aligned with the quantisation step `lsb`
/// ([`quantised_bins`]), the x axis with an SI prefix. Returns what the x
/// axis showed.
#[allow(clippy::too_many_arguments)]
pub fn histogram_plot(
    ui: &mut egui::Ui,
    id: &str,
    height: f32,
    quantity: &str,
    unit: &str,
    samples: &[f32],
    range: f32,
    lsb: f64,
) -> AxisReadout {
    let (factor, prefix) = si_prefix(f64::from(range));
    let (lo, w, bins) = quantised_bins(f64::from(range), 61, lsb);
    let h = histogram(samples, lo as f32, (lo + w * bins as f64) as f32, bins);
    let total: u32 = h.iter().sum();
    let wf = w * factor;
    let norm = if total > 0 {
        1.0 / (f64::from(total) * wf)
    } else {
        0.0
    };
    let bars: Vec<egui_plot::Bar> = h
        .iter()
        .enumerate()
        .map(|(k, &c)| {
            egui_plot::Bar::new((lo + (k as f64 + 0.5) * w) * factor, f64::from(c) * norm).width(wf)
        })
        .collect();
    let label = format!("{quantity} ({prefix}{unit})");
    let shown = ShownTicks::default();
    let r = f64::from(range) * factor;
    fixed_plot(id, height)
        .x_axis_label(label.clone())
        .x_grid_spacer(|i| ticks_125(i, X_TICK_PX.0, X_TICK_PX.1))
        .x_axis_formatter(|m, rr| shown.label(m, rr))
        .y_axis_label("density")
        .y_grid_spacer(|i| ticks_125(i, Y_TICK_PX.0, Y_TICK_PX.1))
        .y_axis_formatter(tick_label)
        .y_axis_min_width(44.0)
        .include_x(-r)
        .include_x(r)
        .show(ui, |p| {
            p.bar_chart(
                egui_plot::BarChart::new("histogram", bars).color(egui::Color32::LIGHT_BLUE),
            );
        });
    shown.readout(label)
}

/// Welch PSD of the last samples (periodic Hann, 50 % overlap, one-sided
/// density; `kilotouch_dsp::spectral::welch`), `None` if too short.
pub fn spectrum(samples: &[f32], fs: f64, nperseg: usize) -> Option<Spectrum> {
    if samples.len() < nperseg || nperseg < 8 {
        return None;
    }
    let x: Vec<f64> = samples
        .iter()
        .map(|&v| if v.is_finite() { f64::from(v) } else { 0.0 })
        .collect();
    welch(&x, fs, &WelchConfig::new(nperseg)).ok()
}

/// Draw a PSD on log axes: x = log10 f (ticks in Hz), y = 10 log10 PSD (dB).
pub fn spectrum_plot(ui: &mut egui::Ui, id: &str, height: f32, spec: Option<&Spectrum>) {
    let pts: Vec<[f64; 2]> = spec
        .map(|s| {
            s.f.iter()
                .zip(&s.p)
                .filter(|(f, p)| **f > 0.0 && **p > 0.0 && p.is_finite())
                .map(|(f, p)| [f.log10(), 10.0 * p.log10()])
                .collect()
        })
        .unwrap_or_default();
    fixed_plot(id, height)
        .x_axis_label("frequency (Hz)")
        .y_axis_label("dB")
        .x_grid_spacer(|i| crate::gui::charts::log_freq_marks(i.bounds))
        .x_axis_formatter(|m, _| crate::gui::charts::log_freq_label(m.value))
        .y_grid_spacer(|i| ticks_125(i, Y_TICK_PX.0, Y_TICK_PX.1))
        .y_axis_formatter(tick_label)
        .y_axis_min_width(44.0)
        .show(ui, |p| {
            p.line(Line::new("PSD", PlotPoints::from(pts)).color(egui::Color32::GOLD));
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed | 1;
        (0..n)
            .map(|i| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                let u = (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
                // spikes now and then: the extremes decimation must keep
                if i % 997 == 0 { u * 100.0 } else { u }
            })
            .collect()
    }

    #[test]
    fn envelope_contains_every_sample_and_is_tight() {
        for &(n, cols) in &[
            (100_000usize, 800usize),
            (1000, 1000),
            (999, 7),
            (5, 40),
            (0, 3),
        ] {
            let x = noise(n, n as u64 + cols as u64);
            let mut mm = Vec::new();
            min_max_columns(&x, cols, &mut mm);
            assert_eq!(mm.len(), cols);
            // Every sample lies within its column's [min, max] …
            let mut covered = 0;
            for (j, m) in mm.iter().enumerate() {
                let r = column_range(n, cols, j);
                covered += r.len();
                match *m {
                    None => assert!(r.is_empty()),
                    Some((lo, hi)) => {
                        for &v in &x[r.clone()] {
                            assert!(lo <= v && v <= hi);
                        }
                        // … and the bounds are attained (tight envelope).
                        assert!(x[r.clone()].contains(&lo) && x[r].contains(&hi));
                    }
                }
            }
            assert_eq!(covered, n, "columns partition the samples");
            // The global extremes survive in the polyline.
            let pts = envelope_points(&x, cols, -1.0, 0.0);
            if n > 0 {
                let gmax = x.iter().cloned().fold(f32::MIN, f32::max);
                let gmin = x.iter().cloned().fold(f32::MAX, f32::min);
                assert!(pts.iter().any(|p| p[1] == f64::from(gmax)));
                assert!(pts.iter().any(|p| p[1] == f64::from(gmin)));
                assert!(pts.len() <= 2 * cols);
            }
        }
    }

    #[test]
    fn non_finite_samples_are_skipped() {
        let x = [f32::NAN, 1.0, f32::INFINITY, -2.0, f32::NAN, f32::NAN];
        let mut mm = Vec::new();
        min_max_columns(&x, 3, &mut mm);
        assert_eq!(mm, vec![Some((1.0, 1.0)), Some((-2.0, -2.0)), None]);
    }

    #[test]
    fn ring_keeps_the_newest_in_order() {
        let mut r = Ring::new(5);
        let mut out = Vec::new();
        for i in 0..13 {
            r.push(i as f32);
        }
        r.last_into(3, &mut out);
        assert_eq!(out, vec![10.0, 11.0, 12.0]);
        r.last_into(99, &mut out);
        assert_eq!(out, vec![8.0, 9.0, 10.0, 11.0, 12.0]);
    }

    #[test]
    fn histogram_counts_everything_once() {
        let x = noise(10_000, 3);
        let h = histogram(&x, -0.5, 0.5, 10);
        assert_eq!(h.iter().sum::<u32>(), 10_000);
        // Uniform(-0.5, 0.5) apart from the spikes (clamped to the end bins).
        for &c in &h[1..9] {
            assert!((c as f64 - 1000.0).abs() < 150.0, "{h:?}");
        }
        assert_eq!(nice_range(0.37), 0.5);
        assert_eq!(nice_range(3.0), 5.0);
        assert_eq!(nice_range(f32::NAN), 1.0);
    }

    #[test]
    fn spectrum_of_a_sine_peaks_at_its_frequency() {
        let fs = 10_000.0;
        let f0 = 312.5; // on a bin of nperseg = 1024 (9.77 Hz bins → bin 32)
        let x: Vec<f32> = (0..16_384)
            .map(|i| (2.0 * std::f64::consts::PI * f0 * i as f64 / fs).sin() as f32)
            .collect();
        let s = spectrum(&x, fs, 1024).unwrap();
        let k = (0..s.p.len())
            .max_by(|&a, &b| s.p[a].total_cmp(&s.p[b]))
            .unwrap();
        assert!((s.f[k] - f0).abs() < 1e-9, "{}", s.f[k]);
        // Parseval: ∫ PSD df = variance = 1/2.
        let df = s.f[1] - s.f[0];
        let p: f64 = s.p.iter().sum::<f64>() * df;
        assert!((p - 0.5).abs() < 0.01, "{p}");
        assert!(spectrum(&x[..100], fs, 1024).is_none());
    }

    /// Gaussian samples (Box–Muller on the xorshift of [`noise`]).
    fn gauss(n: usize, sigma: f64, seed: u64) -> Vec<f64> {
        let mut s = seed | 1;
        let mut u = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        (0..n)
            .map(|_| {
                let (a, b) = (u(), u());
                sigma * (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
            })
            .collect()
    }

    /// Largest |count − expected| / √expected over the bins holding more
    /// than 1 % of the samples, for quantised Gaussian noise (σ = 6 LSB,
    /// the simulated accelerometer at rest) binned over ±0.5 (the page's
    /// range) by `edges` = (first edge, width, bins).
    fn worst_z(x: &[f32], sigma: f64, edges: (f64, f64, usize)) -> f64 {
        let (lo, w, n) = edges;
        let h = histogram(x, lo as f32, (lo + w * n as f64) as f32, n);
        let cdf = |v: f64| 0.5 * (1.0 + libm_erf(v / (sigma * std::f64::consts::SQRT_2)));
        let q = 1.4528e-2;
        let mut worst: f64 = 0.0;
        for (k, &c) in h.iter().enumerate() {
            // Expected count: the probability of the quantised levels the
            // bin holds (level j·q collects (j ± ½)·q).
            let (a, b) = (lo + k as f64 * w, lo + (k + 1) as f64 * w);
            let (ja, jb) = ((a / q).ceil() as i64, (b / q).ceil() as i64 - 1);
            let p: f64 = (ja..=jb)
                .filter(|j| (*j as f64) * q >= a && (*j as f64) * q < b)
                .map(|j| cdf((j as f64 + 0.5) * q) - cdf((j as f64 - 0.5) * q))
                .sum();
            let e = p * x.len() as f64;
            if e > 0.01 * x.len() as f64 {
                // Against the smooth density the plot means to show.
                let smooth = (cdf(b) - cdf(a)) * x.len() as f64;
                worst = worst.max((f64::from(c) - smooth).abs() / smooth.sqrt());
            }
        }
        worst
    }

    /// erf by Abramowitz & Stegun 7.1.26 (|error| < 1.5e-7).
    fn libm_erf(x: f64) -> f64 {
        let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
        let y = 1.0
            - (((((1.061_405_429 * t - 1.453_152_027) * t) + 1.421_413_741) * t - 0.284_496_736)
                * t
                + 0.254_829_592)
                * t
                * (-x * x).exp();
        if x < 0.0 { -y } else { y }
    }

    #[test]
    fn quantised_bins_remove_the_spikes_of_equal_width_bins() {
        // The simulated accelerometer: steps of q = 14.5 mm/s², noise
        // σ = 86 mm/s² ≈ 6 q. 61 bins over ±0.5 m/s² are 1.13 q wide: most
        // hold one level, some two, which draws spikes twice as high as
        // their neighbours. Bins of an odd number of levels, centred on a
        // level, follow the smooth density.
        let q = 1.4528e-2;
        let sigma = 0.0858;
        let x: Vec<f32> = gauss(200_000, sigma, 7)
            .iter()
            .map(|v| ((v / q).round() * q) as f32)
            .collect();
        let naive = (-0.5, 1.0 / 61.0, 61);
        let aligned = quantised_bins(0.5, 61, q);
        let (z_naive, z_aligned) = (worst_z(&x, sigma, naive), worst_z(&x, sigma, aligned));
        assert!(z_naive > 20.0, "equal-width bins: worst z {z_naive}");
        assert!(z_aligned < 5.0, "aligned bins: worst z {z_aligned}");
        // The aligned bins: odd multiples of q, centred on 0, covering ±0.5.
        let (lo, w, n) = aligned;
        let k = (w / q).round();
        assert!(
            (w / q - k).abs() < 1e-9 && k % 2.0 == 1.0,
            "{w} = {} q",
            w / q
        );
        assert!(
            (lo + 0.5 * w * n as f64).abs() < 1e-12 && lo <= -0.5,
            "{lo} {n}"
        );
        // Without a step: the plain bins.
        assert_eq!(quantised_bins(0.5, 61, 0.0), (-0.5, 1.0 / 61.0, 61));
    }

    #[test]
    fn si_prefixes_ticks_and_numbers() {
        assert_eq!(si_prefix(0.0032), (1e3, "m"));
        assert_eq!(si_prefix(3.2e-13).1, "p");
        assert_eq!(si_prefix(0.0).1, "");
        assert_eq!(si_prefix(f64::NAN).1, "");
        assert_eq!(format_si(0.0312, "m/s²"), "31.2 mm/s²");
        assert_eq!(format_si(0.1, "N"), "100 mN");
        let mut a = AxisScale::default();
        assert_eq!(a.update(0.002).1, "m");
        // Within [0.5, 2000) of the unit: kept.
        assert_eq!(a.update(0.0009).1, "m");
        assert_eq!(a.update(0.0000009).1, "n");
        // Ticks: 1-2-5 steps at least the spacing apart, all in range.
        let marks = ticks_125(
            egui_plot::GridInput {
                bounds: (-0.5, 0.5),
                // 400 points across: 1/400 per point, ×8.
                base_step_size: 8.0 / 400.0,
            },
            80.0,
            62.0,
        );
        let v: Vec<f64> = marks.iter().map(|m| m.value).collect();
        assert_eq!(v, vec![-0.4, -0.2, 0.0, 0.2, 0.4]);
        let labels: Vec<String> = marks
            .iter()
            .map(|m| tick_label(*m, &(-0.5..=0.5)))
            .collect();
        assert_eq!(labels, ["-0.4", "-0.2", "0", "0.2", "0.4"]);
        // A short axis: ±450 over 130 points wants steps of 500 (only 0 in
        // view); the next smaller steps still ≥ 21 points apart (250) are
        // taken.
        let short = ticks_125(
            egui_plot::GridInput {
                bounds: (-450.0, 450.0),
                base_step_size: 8.0 * 900.0 / 130.0,
            },
            32.0,
            21.0,
        );
        let v: Vec<f64> = short.iter().map(|m| m.value).collect();
        assert_eq!(v, vec![-250.0, 0.0, 250.0]);
        assert!(
            ticks_125(
                egui_plot::GridInput {
                    bounds: (f64::NAN, 1.0),
                    base_step_size: 0.1
                },
                80.0,
                62.0
            )
            .is_empty()
        );
        assert_eq!(sd(&[1.0, 3.0, f32::NAN]), Some(1.0));
        assert_eq!(sd(&[1.0]), None);
    }
}
