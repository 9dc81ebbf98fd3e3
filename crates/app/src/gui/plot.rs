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
use std::ops::RangeInclusive;

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

/// Draw decimated traces (time axis: seconds before now) in one plot.
pub fn trace_plot(
    ui: &mut egui::Ui,
    id: &str,
    height: f32,
    y_label: &str,
    series: &[(&str, egui::Color32, &[f32])],
    fs: f64,
) {
    let columns = (ui.available_width().max(50.0) as usize).min(4000);
    let lines: Vec<Line<'static>> = series
        .iter()
        .map(|(name, color, s)| {
            let t = s.len() as f64 / fs;
            Line::new(
                *name,
                PlotPoints::from(envelope_points(s, columns, -t, 0.0)),
            )
            .color(*color)
            .width(1.0)
        })
        .collect();
    Plot::new(id.to_owned())
        .height(height)
        .y_axis_label(y_label.to_owned())
        .y_axis_formatter(tick_label)
        .y_axis_min_width(44.0)
        .x_axis_label("time (s)")
        .allow_scroll(false)
        .allow_drag(false)
        .allow_zoom(false)
        .legend(egui_plot::Legend::default())
        .show(ui, |p| {
            for l in lines {
                p.line(l);
            }
        });
}

/// Draw a histogram (counts normalised to a probability density) over ±range.
pub fn histogram_plot(ui: &mut egui::Ui, id: &str, height: f32, samples: &[f32], range: f32) {
    let bins = 61;
    let h = histogram(samples, -range, range, bins);
    let total: u32 = h.iter().sum();
    let w = 2.0 * f64::from(range) / bins as f64;
    let norm = if total > 0 {
        1.0 / (f64::from(total) * w)
    } else {
        0.0
    };
    let bars: Vec<egui_plot::Bar> = h
        .iter()
        .enumerate()
        .map(|(k, &c)| {
            egui_plot::Bar::new(
                -f64::from(range) + (k as f64 + 0.5) * w,
                f64::from(c) * norm,
            )
            .width(w)
        })
        .collect();
    Plot::new(id.to_owned())
        .height(height)
        .x_axis_label("tip acceleration x (m/s²)")
        .x_axis_formatter(tick_label)
        .y_axis_label("density (s²/m)")
        .allow_scroll(false)
        .allow_drag(false)
        .allow_zoom(false)
        .include_x(-f64::from(range))
        .include_x(f64::from(range))
        .show(ui, |p| {
            p.bar_chart(
                egui_plot::BarChart::new("histogram", bars).color(egui::Color32::LIGHT_BLUE),
            );
        });
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

fn log_tick(mark: GridMark, _range: &RangeInclusive<f64>) -> String {
    let f = 10f64.powf(mark.value);
    if f >= 1000.0 {
        format!("{:.0}k", f / 1000.0)
    } else if f >= 1.0 {
        format!("{f:.0}")
    } else {
        format!("{f:.2}")
    }
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
    Plot::new(id.to_owned())
        .height(height)
        .x_axis_label("frequency (Hz, log)")
        .y_axis_label("PSD (dB re 1 (m/s²)²/Hz)")
        .x_axis_formatter(log_tick)
        .allow_scroll(false)
        .allow_drag(false)
        .allow_zoom(false)
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
}
