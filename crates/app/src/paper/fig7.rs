//! Fig. 7: the tip acceleration at the third-octave centres 63–1000 Hz
//! through the calibrated chain — the compensated sum is the calibration's
//! verification ([`kilotouch_rig::calibration::verify`]), each channel alone
//! is the same stepped-sine measurement with the other output silent
//! ([`measure_band_paths`]), on the same simulated rig right after the
//! calibration. Magnitudes in dB re the target K_sys·A.

use super::style::{self, Figure, Frame, err, legend, legend_line};
use super::{Claim, PaperError, write_csv};
use kilotouch_rig::calibration::verify::{Paths, measure_band_paths, sensor_gain};
use kilotouch_rig::calibration::{CalibrationConfig, CalibrationOutcome, CalibrationRig};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// The data of Fig. 7.
#[derive(Debug, Clone, PartialEq)]
pub struct Fig7 {
    /// Nominal band labels.
    pub nominal: Vec<String>,
    /// Frequencies played, Hz.
    pub f_hz: Vec<f64>,
    /// Low path alone, dB re target.
    pub low_db: Vec<f64>,
    /// High path alone, dB re target.
    pub high_db: Vec<f64>,
    /// Both (the verification), dB re target.
    pub sum_db: Vec<f64>,
    /// Crossover alone (no compensation), dB re target.
    pub uncompensated_db: Vec<f64>,
    /// Crossover frequency of the calibrated chain, Hz.
    pub crossover_hz: f64,
    /// Verification tolerance, dB.
    pub tolerance_db: f64,
}

impl Fig7 {
    /// Measure each channel alone on `rig` (the rig the calibration ran on)
    /// through the calibrated chain, at the verification's frequencies.
    ///
    /// # Errors
    /// Rig and chain errors.
    pub fn measure<R: CalibrationRig + ?Sized>(
        rig: &mut R,
        o: &CalibrationOutcome,
        progress: &mut dyn FnMut(f64, &str),
    ) -> Result<Self, PaperError> {
        let v = &o.verification;
        let cfg: &CalibrationConfig = &o.config;
        let coeffs = o.design.chain_coefficients(&o.crossover)?;
        let target = v.target_m_s2;
        let bands: Vec<_> = v.bands.iter().filter(|b| !b.extended).collect();
        let mut out = Self {
            nominal: Vec::new(),
            f_hz: Vec::new(),
            low_db: Vec::new(),
            high_db: Vec::new(),
            sum_db: Vec::new(),
            uncompensated_db: Vec::new(),
            crossover_hz: o.crossover.crossover_hz,
            tolerance_db: v.tolerance_db,
        };
        for (k, b) in bands.iter().enumerate() {
            let mut one = |paths: Paths, what: &str| -> Result<f64, PaperError> {
                let (f, a, _) = measure_band_paths(
                    rig,
                    &coeffs,
                    b.centre_hz,
                    cfg,
                    format!("fig7 {} Hz {what}", b.nominal),
                    paths,
                )?;
                let s = if v.sensor_corrected {
                    sensor_gain(rig, f).unwrap_or(1.0)
                } else {
                    1.0
                };
                Ok(20.0 * (a / s / target).log10())
            };
            let l = one(Paths::LowOnly, "low alone")?;
            let h = one(Paths::HighOnly, "high alone")?;
            out.nominal.push(b.nominal.clone());
            out.f_hz.push(b.f_hz);
            out.low_db.push(l);
            out.high_db.push(h);
            out.sum_db.push(b.db);
            out.uncompensated_db.push(b.uncompensated_db);
            progress(
                (k + 1) as f64 / bands.len() as f64,
                &format!("{} Hz", b.nominal),
            );
        }
        Ok(out)
    }

    /// The paper's statements about Fig. 7, checked.
    pub fn claims(&self) -> Vec<Claim> {
        let max = |v: &[f64]| v.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
        let dev = max(&self.sum_db);
        let unc = max(&self.uncompensated_db);
        let first = |v: &[f64]| v.first().copied().unwrap_or(f64::NAN);
        let last = |v: &[f64]| v.last().copied().unwrap_or(f64::NAN);
        let lo_margin = first(&self.low_db) - first(&self.high_db);
        let hi_margin = last(&self.high_db) - last(&self.low_db);
        vec![
            Claim::new(
                "7",
                "compensated sum flat over the third octaves 63–1000 Hz: largest |deviation|",
                "the system's response was indeed flat within a few dB from DC to 1000 Hz (§3.4)",
                dev,
                "dB",
                "≤ 1 dB",
                dev <= 1.0 && !self.sum_db.is_empty(),
            ),
            Claim::new(
                "7",
                "the compensation is needed: crossover alone, largest |deviation|",
                "the channels had to be frequency and amplitude compensated in their respective bands (§3.3)",
                unc,
                "dB",
                "larger than the compensated sum's",
                unc > dev,
            ),
            Claim::new(
                "7",
                &format!(
                    "low channel carries the signal at {} Hz: low − high",
                    self.nominal.first().map_or("?", String::as_str)
                ),
                "the Pantograph supplies the largest portion of the force at low frequencies (§2)",
                lo_margin,
                "dB",
                "≥ 10 dB",
                lo_margin >= 10.0,
            ),
            Claim::new(
                "7",
                &format!(
                    "high channel carries the signal at {} Hz: high − low",
                    self.nominal.last().map_or("?", String::as_str)
                ),
                "the vibration transducer is responsible for the high frequencies (§2)",
                hi_margin,
                "dB",
                "≥ 10 dB",
                hi_margin >= 10.0,
            ),
        ]
    }

    /// Write `fig7.csv` (`f_hz,low_db,high_db,sum_db,uncompensated_db`).
    ///
    /// # Errors
    /// File errors.
    pub fn write_csv(&self, path: &Path) -> Result<(), PaperError> {
        write_csv(
            path,
            &["f_hz", "low_db", "high_db", "sum_db", "uncompensated_db"],
            &[
                &self.f_hz,
                &self.low_db,
                &self.high_db,
                &self.sum_db,
                &self.uncompensated_db,
            ],
        )
    }
}

impl Figure for Fig7 {
    fn size(&self) -> (u32, u32) {
        style::SIZE_SINGLE
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let all = self
            .low_db
            .iter()
            .chain(&self.high_db)
            .chain(&self.sum_db)
            .chain(&self.uncompensated_db)
            .copied();
        let (lo, _) = style::bounds(all, 0.05).unwrap_or((-40.0, 5.0));
        // Room under the curves for the legend.
        let lo = (lo - 18.0).max(-75.0);
        let title = format!(
            "Fig. 7 — Magnitude response of the combined interface (f_c = {:.0} Hz)",
            self.crossover_hz
        );
        let frame = Frame::FIGURE;
        let mut chart = frame.chart(root, title, (50.0_f64..1250.0).log_scale(), lo..8.0)?;
        frame
            .mesh(
                &mut chart,
                "Third-octave centre frequency (Hz)",
                "Tip acceleration (dB re K_sys·A)",
            )
            .x_label_formatter(&style::log_label)
            .draw()
            .map_err(err)?;
        let tol = self.tolerance_db.max(1.0);
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(50.0, -tol), (1250.0, tol)],
                style::SUM.mix(0.08).filled(),
            )))
            .map_err(err)?
            .label(format!("±{tol} dB"))
            .legend(|(x, y)| {
                Rectangle::new([(x, y - 6), (x + 24, y + 6)], style::SUM.mix(0.15).filled())
            });
        let series = [
            ("low channel alone", &self.low_db, style::LOW, 2),
            ("high channel alone", &self.high_db, style::HIGH, 2),
            ("combined (compensated)", &self.sum_db, style::SUM, 3),
        ];
        for (name, ys, c, w) in series {
            let pts: Vec<(f64, f64)> = self
                .f_hz
                .iter()
                .zip(ys.iter())
                .map(|(&f, &y)| (f, y.max(lo)))
                .collect();
            chart
                .draw_series(LineSeries::new(pts.clone(), c.stroke_width(w)))
                .map_err(err)?
                .label(name)
                .legend(legend_line(c, w));
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 5, c.filled())))
                .map_err(err)?;
        }
        let pts: Vec<(f64, f64)> = self
            .f_hz
            .iter()
            .zip(&self.uncompensated_db)
            .map(|(&f, &y)| (f, y.max(lo)))
            .collect();
        chart
            .draw_series(DashedLineSeries::new(
                pts,
                6,
                4,
                style::GREY.stroke_width(2),
            ))
            .map_err(err)?
            .label("crossover alone (uncompensated)")
            .legend(legend_line(style::GREY, 2));
        legend(&mut chart, SeriesLabelPosition::LowerRight)
    }
}
