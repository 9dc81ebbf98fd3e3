//! Fig. 4: magnitude of the Linkwitz–Riley crossover's channels, low, high
//! and their sum — the digital filters the loop's chain runs (order, f_c and
//! f_s of the as-designed chain of the rig file,
//! [`kilotouch_rig::coupling::model_chain_design`]), evaluated exactly on
//! the unit circle ([`LinkwitzRiley::response`]).

use super::style::{self, Figure, Frame, err, legend, legend_line, log_grid};
use super::{Claim, PaperError, write_csv};
use kilotouch_dsp::crossover::LinkwitzRiley;
use kilotouch_rig::config::RigConfig;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// Lowest frequency drawn, Hz.
pub const F_LO: f64 = 10.0;
/// Highest frequency drawn, Hz.
pub const F_HI: f64 = 4000.0;
/// Points of the frequency grid (log-spaced, `F_LO`..=`F_HI`).
pub const N_POINTS: usize = 401;

/// The data of Fig. 4.
#[derive(Debug, Clone, PartialEq)]
pub struct Fig4 {
    /// Crossover frequency, Hz.
    pub crossover_hz: f64,
    /// Sample rate, Hz.
    pub fs_hz: f64,
    /// Linkwitz–Riley order.
    pub order: usize,
    /// Frequencies, Hz.
    pub f_hz: Vec<f64>,
    /// |L|, dB.
    pub low_db: Vec<f64>,
    /// |H|, dB.
    pub high_db: Vec<f64>,
    /// |L + H|, dB.
    pub sum_db: Vec<f64>,
}

fn db(x: f64) -> f64 {
    20.0 * x.log10()
}

impl Fig4 {
    /// The crossover of `cfg`'s as-designed chain on the log grid.
    ///
    /// # Errors
    /// An invalid rig file or crossover.
    pub fn compute(cfg: &RigConfig) -> Result<Self, PaperError> {
        let design = kilotouch_rig::coupling::model_chain_design(cfg)?;
        Self::for_crossover(design.crossover_order, design.crossover_hz, design.fs)
    }

    /// An LR crossover of `order` at `crossover_hz`, sampled at `fs_hz`.
    ///
    /// # Errors
    /// An invalid crossover.
    pub fn for_crossover(order: usize, crossover_hz: f64, fs_hz: f64) -> Result<Self, PaperError> {
        let xo = LinkwitzRiley::new(order, crossover_hz, fs_hz)?;
        let f_hz = log_grid(F_LO, F_HI, N_POINTS);
        let (mut low_db, mut high_db, mut sum_db) = (Vec::new(), Vec::new(), Vec::new());
        for &f in &f_hz {
            let (l, h) = xo.response(f);
            low_db.push(db(l.norm()));
            high_db.push(db(h.norm()));
            sum_db.push(db((l + h).norm()));
        }
        Ok(Self {
            crossover_hz,
            fs_hz,
            order,
            f_hz,
            low_db,
            high_db,
            sum_db,
        })
    }

    /// Magnitudes at one frequency (dB): low, high, sum.
    fn at(&self, f: f64) -> Result<(f64, f64, f64), PaperError> {
        let xo = LinkwitzRiley::new(self.order, self.crossover_hz, self.fs_hz)?;
        let (l, h) = xo.response(f);
        Ok((db(l.norm()), db(h.norm()), db((l + h).norm())))
    }

    /// The paper's statements about Fig. 4, checked.
    ///
    /// # Errors
    /// An invalid crossover.
    pub fn claims(&self) -> Result<Vec<Claim>, PaperError> {
        let fc = self.crossover_hz;
        let (l_fc, h_fc, _) = self.at(fc)?;
        let expected = db(0.5);
        let sum_dev = self.sum_db.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        // Slopes over one octave well inside the stop bands.
        let (l4, _, _) = self.at(2.0 * fc)?;
        let (l8, _, _) = self.at(4.0 * fc)?;
        let (_, h8, _) = self.at(fc / 8.0)?;
        let (_, h4, _) = self.at(fc / 4.0)?;
        let low_slope = l8 - l4;
        let high_slope = h4 - h8;
        let mut v = vec![
            Claim::new(
                "4",
                &format!("low channel at f_c = {fc} Hz is −6.02 dB"),
                "−6 dB gain at the cut-off frequency (§3.1)",
                l_fc,
                "dB",
                "within 0.01 dB of 20·log10(1/2)",
                (l_fc - expected).abs() <= 0.01,
            ),
            Claim::new(
                "4",
                &format!("high channel at f_c = {fc} Hz is −6.02 dB"),
                "−6 dB gain at the cut-off frequency (§3.1)",
                h_fc,
                "dB",
                "within 0.01 dB of 20·log10(1/2)",
                (h_fc - expected).abs() <= 0.01,
            ),
            Claim::new(
                "4",
                "L + H is all-pass: largest |sum| over 10 Hz–4 kHz",
                "the whole system should behave like an all-pass, unity filter (§3.1)",
                sum_dev,
                "dB",
                "≤ 0.01 dB",
                sum_dev <= 0.01,
            ),
        ];
        let slope_ok = |s: f64| (s.abs() - 6.0 * self.order as f64).abs() <= 1.0;
        v.push(Claim::new(
            "4",
            &format!(
                "low-pass slope from 2 f_c to 4 f_c ({} dB/octave)",
                -6 * self.order as i64
            ),
            "slopes of 80 dB/decade (24 dB/octave) for the fourth order (§3.1)",
            low_slope,
            "dB/octave",
            "within 1 dB/octave of −6·order (higher up, bilinear warping steepens it towards f_s/2)",
            low_slope < 0.0 && slope_ok(low_slope),
        ));
        v.push(Claim::new(
            "4",
            &format!(
                "high-pass slope from f_c/8 to f_c/4 (+{} dB/octave)",
                6 * self.order
            ),
            "slopes of 80 dB/decade (24 dB/octave) for the fourth order (§3.1)",
            high_slope,
            "dB/octave",
            "within 1 dB/octave of +6·order",
            high_slope > 0.0 && slope_ok(high_slope),
        ));
        Ok(v)
    }

    /// Write `fig4.csv` (`f_hz,low_db,high_db,sum_db`).
    ///
    /// # Errors
    /// File errors.
    pub fn write_csv(&self, path: &Path) -> Result<(), PaperError> {
        write_csv(
            path,
            &["f_hz", "low_db", "high_db", "sum_db"],
            &[&self.f_hz, &self.low_db, &self.high_db, &self.sum_db],
        )
    }
}

impl Figure for Fig4 {
    fn size(&self) -> (u32, u32) {
        style::SIZE_SINGLE
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let title = format!(
            "Fig. 4 — LR{} crossover, f_c = {} Hz, f_s = {} kHz",
            self.order,
            self.crossover_hz,
            self.fs_hz / 1e3
        );
        let frame = Frame::FIGURE;
        let mut chart = frame.chart(root, title, (F_LO..F_HI).log_scale(), -80.0_f64..6.0)?;
        frame
            .mesh(&mut chart, "Frequency (Hz)", "Magnitude (dB)")
            .x_label_formatter(&style::log_label)
            .y_labels(10)
            .draw()
            .map_err(err)?;
        let clip = |v: f64| v.max(-80.0);
        let series = [
            ("low-pass L", &self.low_db, style::LOW),
            ("high-pass H", &self.high_db, style::HIGH),
            ("sum L + H", &self.sum_db, style::SUM),
        ];
        for (name, ys, c) in series {
            chart
                .draw_series(LineSeries::new(
                    self.f_hz.iter().zip(ys.iter()).map(|(&f, &y)| (f, clip(y))),
                    c.stroke_width(3),
                ))
                .map_err(err)?
                .label(name)
                .legend(legend_line(c, 3));
        }
        let m6 = db(0.5);
        chart
            .draw_series(DashedLineSeries::new(
                vec![(F_LO, m6), (F_HI, m6)],
                6,
                4,
                style::GREY.stroke_width(1),
            ))
            .map_err(err)?
            .label("−6.02 dB")
            .legend(legend_line(style::GREY, 1));
        chart
            .draw_series(DashedLineSeries::new(
                vec![(self.crossover_hz, -80.0), (self.crossover_hz, 6.0)],
                6,
                4,
                style::GREY.stroke_width(1),
            ))
            .map_err(err)?;
        legend(&mut chart, SeriesLabelPosition::LowerLeft)
    }
}
