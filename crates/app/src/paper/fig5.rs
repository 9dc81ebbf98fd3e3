//! Fig. 5: the two channels' responses, identified as the paper did (MLS
//! excitation, Welch H1 with coherence: the calibration's steps 2 and 3,
//! [`kilotouch_rig::calibration::identify`]) beside the model's analytic
//! response ([`kilotouch_rig::sim::simulate_frf`], what `kilotouch sim frf`
//! prints), the fitted Ĝ_H and the paper's eq. 2 scaled to the rig's drive
//! unit.

use super::style::{self, Figure, Frame, err, legend, legend_line};
use super::{Claim, PaperError, write_csv};
use kilotouch_dsp::C64;
use kilotouch_dsp::compensator::paper_g_h;
use kilotouch_rig::calibration::measure::smooth_octave;
use kilotouch_rig::calibration::{
    CalibrationConfig, CalibrationOutcome, CalibrationRig, Progress, Step, calibrate,
};
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::plant::Channel;
use kilotouch_rig::sim::simulate_frf;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;
use std::sync::atomic::AtomicBool;

/// Lowest frequency drawn and written, Hz.
pub const F_LO: f64 = 10.0;
/// Highest frequency drawn and written, Hz.
pub const F_HI: f64 = 2000.0;
/// Smoothing of the estimate for the claims about its shape, octaves.
const SMOOTH_OCT: f64 = 1.0 / 12.0;
/// The set-up of each of the four panels: a little more room than
/// [`Frame::PANEL`] for the dB labels.
const PANEL: Frame = Frame {
    margin: 14,
    margin_right: 14,
    x_label_area: 52,
    y_label_area: 80,
    ..Frame::PANEL
};

/// Run the calibration procedure (`kilotouch calibrate`'s, default
/// settings) on `rig`, reporting each step's progress as a fraction of the
/// whole procedure.
///
/// # Errors
/// Calibration errors.
pub fn calibrate_rig<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    progress: &mut dyn FnMut(f64, &str),
) -> Result<CalibrationOutcome, PaperError> {
    let cancel = AtomicBool::new(false);
    let mut p = |step: Step, f: f64, msg: &str| progress(step.overall(f), msg);
    let p: &mut dyn Progress = &mut p;
    Ok(calibrate(
        rig,
        &CalibrationConfig::default(),
        None,
        p,
        &cancel,
    )?)
}

/// The data of Fig. 5.
#[derive(Debug, Clone, PartialEq)]
pub struct Fig5 {
    /// Welch bins, Hz.
    pub f_hz: Vec<f64>,
    /// |Ĥ_L| as identified, dB re 1 (m/s²)/N.
    pub low_db: Vec<f64>,
    /// |Ĥ_H| as identified, dB re 1 (m/s²)/drive unit.
    pub high_db: Vec<f64>,
    /// The model's low channel (`sim frf --channel low`), dB.
    pub low_model_db: Vec<f64>,
    /// The model's high channel (`sim frf --channel high`), dB.
    pub high_model_db: Vec<f64>,
    /// The fitted Ĝ_H, dB.
    pub high_fit_db: Vec<f64>,
    /// The paper's eq. 2, scaled by the gain that best matches the
    /// estimate over the reliable band, dB.
    pub high_eq2_db: Vec<f64>,
    /// Coherence of the low estimate.
    pub low_coherence: Vec<f64>,
    /// Coherence of the high estimate.
    pub high_coherence: Vec<f64>,
    /// 1 inside the high channel's reliable band, else 0.
    pub high_reliable: Vec<f64>,
    /// G0_L, (m/s²)/N.
    pub g0_l: f64,
    /// Reliable band of the high estimate, Hz.
    pub reliable_hz: [f64; 2],
    /// Units of the low and high channel.
    pub units: [String; 2],
}

fn db(x: f64) -> f64 {
    20.0 * x.log10()
}

impl Fig5 {
    /// From a calibration of the rig described by `cfg`.
    ///
    /// # Errors
    /// Model errors.
    pub fn from_outcome(cfg: &RigConfig, o: &CalibrationOutcome) -> Result<Self, PaperError> {
        let lf = &o.low.frf;
        let hf = &o.high.frf;
        let idx: Vec<usize> = (0..lf.f_hz.len())
            .filter(|&i| (F_LO..=F_HI).contains(&lf.f_hz[i]))
            .collect();
        let f_hz: Vec<f64> = idx.iter().map(|&i| lf.f_hz[i]).collect();
        let low_db = idx.iter().map(|&i| db(lf.h[i].norm())).collect();
        let low_coherence = idx.iter().map(|&i| lf.coherence[i]).collect();
        let high: Vec<C64> = f_hz.iter().map(|&f| hf.at(f)).collect();
        let high_db: Vec<f64> = high.iter().map(|h| db(h.norm())).collect();
        let high_coherence = f_hz
            .iter()
            .map(|&f| {
                let i = hf.f_hz.partition_point(|&x| x < f).min(hf.f_hz.len() - 1);
                hf.coherence.get(i).copied().unwrap_or(0.0)
            })
            .collect();
        let low_model = simulate_frf(cfg, Channel::Low, &f_hz)?;
        let high_model = simulate_frf(cfg, Channel::High, &f_hz)?;
        let mag = |p: &kilotouch_rig::sim::FrfPoint| db((p.re * p.re + p.im * p.im).sqrt());
        let rb = o.high.reliable_band_hz;
        let high_reliable: Vec<f64> = f_hz
            .iter()
            .map(|f| f64::from(u8::from((rb[0]..=rb[1]).contains(f))))
            .collect();
        let high_fit_db = f_hz
            .iter()
            .map(|&f| db(o.high.model.response_hz(f).norm()))
            .collect();
        // Eq. 2 is in the paper's drive unit: scale it by the mean log ratio
        // over the reliable band (a gain only; the shape is the paper's).
        let eq2 = paper_g_h();
        let ratios: Vec<f64> = f_hz
            .iter()
            .zip(&high_db)
            .zip(&high_reliable)
            .filter(|(_, r)| **r > 0.5)
            .map(|((&f, &h), _)| h - db(eq2.response_hz(f).norm()))
            .collect();
        let k_db = if ratios.is_empty() {
            0.0
        } else {
            ratios.iter().sum::<f64>() / ratios.len() as f64
        };
        let high_eq2_db = f_hz
            .iter()
            .map(|&f| db(eq2.response_hz(f).norm()) + k_db)
            .collect();
        Ok(Self {
            low_model_db: low_model.points.iter().map(mag).collect(),
            high_model_db: high_model.points.iter().map(mag).collect(),
            units: [low_model.units.clone(), high_model.units.clone()],
            f_hz,
            low_db,
            high_db,
            high_fit_db,
            high_eq2_db,
            low_coherence,
            high_coherence,
            high_reliable,
            g0_l: o.low.g0,
            reliable_hz: rb,
        })
    }

    /// Indices of the bins in [lo, hi].
    fn band(&self, lo: f64, hi: f64) -> Vec<usize> {
        (0..self.f_hz.len())
            .filter(|&i| (lo..=hi).contains(&self.f_hz[i]))
            .collect()
    }

    /// The estimate smoothed over 1/12 octave, dB.
    fn smoothed(&self, v: &[f64]) -> Vec<f64> {
        let lin: Vec<f64> = v.iter().map(|d| 10f64.powf(d / 20.0)).collect();
        smooth_octave(&self.f_hz, &lin, SMOOTH_OCT)
            .into_iter()
            .map(db)
            .collect()
    }

    /// The paper's statements about Fig. 5, checked on the identified
    /// (measured) responses.
    pub fn claims(&self) -> Vec<Claim> {
        let low = self.smoothed(&self.low_db);
        let high = self.smoothed(&self.high_db);
        let g0 = db(self.g0_l.abs());
        let mut v = Vec::new();
        // Flat DC–200 Hz: from the lowest coherent bin (≥ 10 Hz) to 200 Hz.
        let flat = self
            .band(F_LO, 200.0)
            .into_iter()
            .filter(|&i| self.low_coherence[i] >= 0.9)
            .fold(0.0_f64, |m, i| m.max((low[i] - g0).abs()));
        v.push(Claim::new(
            "5",
            "low channel flat from 10 Hz to 200 Hz: largest deviation from G0_L",
            "the Pantograph had an acceptably uniform magnitude response from DC to 200 Hz (§3.2)",
            flat,
            "dB",
            "≤ 3 dB (\"within a few dB\")",
            flat <= 3.0,
        ));
        // Antiresonance just above 200 Hz, then a damped resonance near 300 Hz.
        let (amin, amin_db) = self.extremum(&low, 200.0, 300.0, false);
        v.push(Claim::new(
            "5",
            "low channel: antiresonance (minimum) between 200 and 300 Hz, depth below G0_L",
            "a first, nicely damped antiresonance is clearly visible after 200 Hz (§3.2)",
            g0 - amin_db,
            "dB",
            &format!(
                "minimum at {amin:.0} Hz inside (200, 300) Hz, ≥ 3 dB deep and ≤ 30 dB (damped)"
            ),
            amin > 200.0 && amin < 300.0 && (3.0..=30.0).contains(&(g0 - amin_db)),
        ));
        let (rmax, rmax_db) = self.extremum(&low, amin.max(200.0), 450.0, true);
        v.push(Claim::new(
            "5",
            "low channel: damped resonance after the antiresonance, frequency",
            "accompanied by a damped resonance at 300 Hz (§3.2)",
            rmax,
            "Hz",
            &format!(
                "local maximum in 250–400 Hz, ≤ 10 dB above G0_L (damped; {:.1} dB)",
                rmax_db - g0
            ),
            (250.0..=400.0).contains(&rmax) && rmax_db - g0 <= 10.0,
        ));
        // Sharp pair near 800 Hz: the unsmoothed model's peak-to-notch span.
        let (pk, pk_db) = self.extremum(&self.low_model_db, 600.0, 1000.0, true);
        let (nt, nt_db) = self.extremum(&self.low_model_db, 600.0, 1000.0, false);
        let (mpk, mpk_db) = self.extremum(&self.low_db, 600.0, 1000.0, true);
        v.push(Claim::new(
            "5",
            "low channel: sharp resonance–antiresonance pair near 800 Hz, peak-to-notch span (measured)",
            "another resonance-antiresonance pair is seen around 800 Hz, this time with a sharp peak (§3.2)",
            mpk_db - self.extremum(&self.low_db, 600.0, 1000.0, false).1,
            "dB",
            &format!(
                "≥ 10 dB between 600 and 1000 Hz (model: peak {pk:.0} Hz, notch {nt:.0} Hz, {:.1} dB; measured peak at {mpk:.0} Hz)",
                pk_db - nt_db
            ),
            mpk_db - self.extremum(&self.low_db, 600.0, 1000.0, false).1 >= 10.0,
        ));
        // High channel follows eq. 2 above 100 Hz.
        let dev = self
            .band(100.0, 1000.0)
            .into_iter()
            .filter(|&i| self.high_coherence[i] >= 0.9)
            .fold(0.0_f64, |m, i| m.max((high[i] - self.high_eq2_db[i]).abs()));
        v.push(Claim::new(
            "5",
            "high channel follows eq. 2 from 100 Hz to 1 kHz: largest deviation (eq. 2 scaled to the drive unit)",
            "for frequencies greater than 100 Hz the response was well approximated by eq. 2 (§3.2)",
            dev,
            "dB",
            "≤ 3 dB",
            dev <= 3.0,
        ));
        let at = |f: f64| {
            let i = self
                .f_hz
                .partition_point(|&x| x < f)
                .min(self.f_hz.len() - 1);
            high[i]
        };
        let roll = at(300.0) - at(1000.0);
        v.push(Claim::new(
            "5",
            "high channel rolls off past 300 Hz: |Ĥ_H(300 Hz)| − |Ĥ_H(1 kHz)|",
            "the high frequency channel begins to roll-off at 300 Hz (§3.2)",
            roll,
            "dB",
            "≥ 6 dB",
            roll >= 6.0,
        ));
        v
    }

    /// Frequency and value of the largest (`max`) or smallest value of `v`
    /// in [lo, hi].
    fn extremum(&self, v: &[f64], lo: f64, hi: f64, max: bool) -> (f64, f64) {
        let mut best = (
            f64::NAN,
            if max {
                f64::NEG_INFINITY
            } else {
                f64::INFINITY
            },
        );
        for i in self.band(lo, hi) {
            let better = if max { v[i] > best.1 } else { v[i] < best.1 };
            if better && v[i].is_finite() {
                best = (self.f_hz[i], v[i]);
            }
        }
        best
    }

    /// Write `fig5.csv`.
    ///
    /// # Errors
    /// File errors.
    pub fn write_csv(&self, path: &Path) -> Result<(), PaperError> {
        write_csv(
            path,
            &[
                "f_hz",
                "low_db",
                "high_db",
                "low_model_db",
                "high_model_db",
                "high_fit_db",
                "high_eq2_db",
                "low_coherence",
                "high_coherence",
                "high_reliable",
            ],
            &[
                &self.f_hz,
                &self.low_db,
                &self.high_db,
                &self.low_model_db,
                &self.high_model_db,
                &self.high_fit_db,
                &self.high_eq2_db,
                &self.low_coherence,
                &self.high_coherence,
                &self.high_reliable,
            ],
        )
    }

    fn panel<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        high: bool,
    ) -> Result<(), String> {
        let (meas, model) = if high {
            (&self.high_db, &self.high_model_db)
        } else {
            (&self.low_db, &self.low_model_db)
        };
        let all = meas.iter().chain(model.iter()).copied();
        let (lo, hi) = style::bounds(all, 0.08).unwrap_or((-40.0, 20.0));
        let unit = &self.units[usize::from(high)];
        let title = if high {
            "(b) high channel: Haptuator drive → tip acceleration"
        } else {
            "(a) low channel: Pantograph force → tip acceleration"
        };
        let mut chart = PANEL.chart(area, title, (F_LO..F_HI).log_scale(), lo..hi)?;
        PANEL
            .mesh(
                &mut chart,
                "Frequency (Hz)",
                format!("Magnitude (dB re 1 {unit})"),
            )
            .x_label_formatter(&style::log_label)
            .draw()
            .map_err(err)?;
        let c = if high { style::HIGH } else { style::LOW };
        let pts = |ys: &Vec<f64>, keep: &dyn Fn(usize) -> bool| -> Vec<(f64, f64)> {
            (0..self.f_hz.len())
                .filter(|&i| keep(i) && ys[i].is_finite())
                .map(|i| (self.f_hz[i], ys[i]))
                .collect()
        };
        if high {
            // Below the reliable band the estimate is drawn dashed (paper: "not reliable").
            let below = pts(meas, &|i| self.f_hz[i] <= self.reliable_hz[0]);
            let light = RGBColor(235, 150, 150);
            chart
                .draw_series(DashedLineSeries::new(below, 5, 4, light.stroke_width(2)))
                .map_err(err)?
                .label("Welch H1, below the reliable band")
                .legend(legend_line(light, 2));
        }
        let keep_main = |i: usize| !high || self.f_hz[i] >= self.reliable_hz[0];
        chart
            .draw_series(LineSeries::new(pts(meas, &keep_main), c.stroke_width(2)))
            .map_err(err)?
            .label("Welch H1 (MLS, as identified)")
            .legend(legend_line(c, 2));
        chart
            .draw_series(DashedLineSeries::new(
                pts(model, &|_| true),
                8,
                5,
                style::SUM.stroke_width(2),
            ))
            .map_err(err)?
            .label("model (kilotouch sim frf)")
            .legend(legend_line(style::SUM, 2));
        if high {
            chart
                .draw_series(LineSeries::new(
                    pts(&self.high_eq2_db, &|i| self.f_hz[i] >= 100.0),
                    style::GREY.stroke_width(2),
                ))
                .map_err(err)?
                .label("paper eq. 2 (gain matched)")
                .legend(legend_line(style::GREY, 2));
        } else {
            let g0 = db(self.g0_l.abs());
            chart
                .draw_series(LineSeries::new(
                    vec![(F_LO, g0), (F_HI, g0)],
                    style::GREY.stroke_width(1),
                ))
                .map_err(err)?
                .label("G0_L")
                .legend(legend_line(style::GREY, 1));
        }
        let pos = if high {
            SeriesLabelPosition::LowerRight
        } else {
            SeriesLabelPosition::LowerLeft
        };
        legend(&mut chart, pos)
    }
}

impl Figure for Fig5 {
    fn size(&self) -> (u32, u32) {
        (1100, 1100)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let root = style::titled(
            root,
            "Fig. 5 — Magnitude responses from PSD analysis (Welch method)",
        )?;
        let panels = root.split_evenly((2, 1));
        self.panel(&panels[0], false)?;
        self.panel(&panels[1], true)
    }
}
