//! Fig. 9: what the fingertip feels in free space, at a collision and
//! pressed against an obstacle — one record of the closed loop
//! ([`simulate_press_after_rest`], the scenario of `kilotouch sim press`
//! with the hand at rest first), condition D, the as-designed chain.
//!
//! The felt acceleration is the tip acceleration along the pressing
//! direction in the band [`FELT_LO_HZ`]–[`FELT_HI_HZ`] (second-order
//! Butterworth high- and low-pass, applied forward once): the hand's slow
//! movement and the loop's low-frequency modes are left out, and what
//! remains is the Brownian agitation the Haptuator carries in D (the band of
//! `docs/theory/coupling-and-stability.md`'s closed-loop test). Both the true
//! tip acceleration (the plant's output) and the accelerometer's reading are
//! analysed. The sensor
//! adds its noise floor, which is above the simulated agitation: through the
//! sensor the narrowing almost vanishes (`docs/PAPER.md`).

use super::style::{self, Figure, Frame, err, legend, legend_line};
use super::{Claim, PaperError, write_csv};
use kilotouch_dsp::design::{FilterKind, Prewarp, butter};
use kilotouch_dsp::filter::Sos;
use kilotouch_rig::Condition;
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::haptic_loop::Clearance;
use kilotouch_rig::press::{APPROACH_S, PressOptions, SETTLE_S, simulate_press_after_rest};
use kilotouch_study::vibrotactile::PacinianCurve;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// Lower edge of the felt band, Hz.
pub const FELT_LO_HZ: f64 = 400.0;
/// Upper edge of the felt band, Hz.
pub const FELT_HI_HZ: f64 = 1000.0;
/// Histogram bins.
const BINS: usize = 60;
/// Samples skipped at the start of the rest (filter and loop warm-up), s.
const WARMUP_S: f64 = 0.1;
/// The set-up of each of the four panels: [`Frame::PANEL`] with room on
/// the right for the last time label.
const PANEL: Frame = Frame {
    margin_right: 30,
    ..Frame::PANEL
};

/// Summary statistics of one window.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Moments {
    /// Samples.
    pub n: usize,
    /// Mean.
    pub mean: f64,
    /// Standard deviation.
    pub sd: f64,
    /// Skewness.
    pub skew: f64,
    /// Excess kurtosis.
    pub ex_kurt: f64,
}

impl Moments {
    /// Sample moments of `x`.
    pub fn of(x: &[f64]) -> Self {
        let n = x.len();
        if n < 2 {
            return Self::default();
        }
        let nf = n as f64;
        let mean = x.iter().sum::<f64>() / nf;
        let (mut m2, mut m3, mut m4) = (0.0, 0.0, 0.0);
        for v in x {
            let d = v - mean;
            m2 += d * d;
            m3 += d * d * d;
            m4 += d * d * d * d;
        }
        m2 /= nf;
        m3 /= nf;
        m4 /= nf;
        Self {
            n,
            mean,
            sd: (m2 * nf / (nf - 1.0)).sqrt(),
            skew: m3 / m2.powf(1.5),
            ex_kurt: m4 / (m2 * m2) - 3.0,
        }
    }
}

/// The data of Fig. 9.
#[derive(Debug, Clone, PartialEq)]
pub struct Fig9 {
    /// Time, s.
    pub t_s: Vec<f64>,
    /// True tip acceleration along the pressing direction, m/s².
    pub accel: Vec<f64>,
    /// Accelerometer reading along it, m/s².
    pub sensor: Vec<f64>,
    /// `accel` high-passed (felt), m/s².
    pub accel_felt: Vec<f64>,
    /// `sensor` high-passed, m/s².
    pub sensor_felt: Vec<f64>,
    /// Surface gap bead–obstacle, µm.
    pub gap_um: Vec<f64>,
    /// Phase: 0 rest (free), 1 approach, 2 settling, 3 pressed.
    pub phase: Vec<f64>,
    /// Time of the first contact, s (NaN: none).
    pub contact_s: f64,
    /// End of the rest, s.
    pub rest_s: f64,
    /// Moments free / pressed, true tip.
    pub tip: [Moments; 2],
    /// Moments free / pressed, sensor.
    pub meas: [Moments; 2],
    /// Largest |felt tip acceleration| within 20 ms after contact, m/s².
    pub spike: f64,
    /// Time of that peak, s.
    pub spike_s: f64,
    /// The bead stayed trapped and the press was stable.
    pub stable: bool,
    /// RMS of the true tip acceleration through the Pacinian weighting
    /// ([`PacinianCurve`]), free / pressed, m/s² (both axes of the press
    /// direction only, as recorded).
    pub pacinian_rms: [f64; 2],
    /// The median participant's Pacinian threshold, m/s² RMS.
    pub pacinian_threshold: f64,
}

fn highpass(x: &[f64], fs: f64) -> Result<Vec<f64>, PaperError> {
    let mut sections = butter(2, FELT_LO_HZ, fs, FilterKind::Highpass, Prewarp::AtCutoff)?;
    sections.extend(butter(
        2,
        FELT_HI_HZ,
        fs,
        FilterKind::Lowpass,
        Prewarp::AtCutoff,
    )?);
    let mut f = Sos::new(sections)?;
    Ok(x.iter().map(|&v| f.process(v)).collect())
}

impl Fig9 {
    /// Simulate the record (quick: 1 s rest, 2.5 s press; full: 3 s, 6 s).
    ///
    /// # Errors
    /// Rig, chain and filter errors.
    pub fn simulate(cfg: &RigConfig, quick: bool, seed: u64) -> Result<Self, PaperError> {
        let (rest_s, dur_s) = if quick { (1.0, 2.5) } else { (3.0, 6.0) };
        let mut cfg = cfg.clone();
        cfg.coupling.mode = Condition::D;
        let chain = LoopChain::as_designed(&cfg)?;
        let clearance = Clearance::check(&cfg, &chain)?;
        let opts = PressOptions {
            condition: Condition::D,
            duration_s: dur_s,
            seed,
            ..PressOptions::default()
        };
        let (report, tr) = simulate_press_after_rest(&cfg, &chain, clearance, &opts, rest_s)?;
        let fs = cfg.rig.sample_rate_hz;
        let accel_felt = highpass(&tr.accel_m_s2, fs)?;
        let curve = PacinianCurve::default();
        let mut weighting = Sos::new(curve.sections(fs)?)?;
        let weighted: Vec<f64> = tr
            .accel_m_s2
            .iter()
            .map(|&v| weighting.process(v))
            .collect();
        let sensor_felt = highpass(&tr.accel_sensor_m_s2, fs)?;
        let t_press = rest_s + APPROACH_S + SETTLE_S;
        let phase: Vec<f64> = tr
            .t_s
            .iter()
            .map(|&t| {
                if t < rest_s {
                    0.0
                } else if t < rest_s + APPROACH_S {
                    1.0
                } else if t < t_press {
                    2.0
                } else {
                    3.0
                }
            })
            .collect();
        let window = |v: &[f64], p: f64| -> Vec<f64> {
            (0..v.len())
                .filter(|&i| phase[i] == p && tr.t_s[i] >= WARMUP_S)
                .map(|i| v[i])
                .collect()
        };
        // Contact as the tweezer defines its start: surface gap below δ.
        let delta = cfg.tweezer.contact_range_m;
        let contact = tr.gap_m.iter().position(|&g| g < delta);
        let contact_s = contact.map_or(f64::NAN, |i| tr.t_s[i]);
        let (mut spike, mut spike_s) = (0.0_f64, f64::NAN);
        if let Some(c) = contact {
            let end = (c + (0.02 * fs) as usize).min(accel_felt.len());
            for (i, v) in accel_felt.iter().enumerate().take(end).skip(c) {
                if v.abs() > spike {
                    spike = v.abs();
                    spike_s = tr.t_s[i];
                }
            }
        }
        let rms =
            |v: Vec<f64>| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
        let pacinian_rms = [rms(window(&weighted, 0.0)), rms(window(&weighted, 3.0))];
        Ok(Self {
            pacinian_rms,
            pacinian_threshold: curve.threshold_m_s2,
            tip: [
                Moments::of(&window(&accel_felt, 0.0)),
                Moments::of(&window(&accel_felt, 3.0)),
            ],
            meas: [
                Moments::of(&window(&sensor_felt, 0.0)),
                Moments::of(&window(&sensor_felt, 3.0)),
            ],
            gap_um: tr.gap_m.iter().map(|g| g * 1e6).collect(),
            t_s: tr.t_s,
            accel: tr.accel_m_s2,
            sensor: tr.accel_sensor_m_s2,
            accel_felt,
            sensor_felt,
            phase,
            contact_s,
            rest_s,
            spike,
            spike_s,
            stable: report.stable && !report.escaped,
        })
    }

    /// The paper's statements about Fig. 9, checked.
    pub fn claims(&self) -> Vec<Claim> {
        let [tf, tp] = self.tip;
        let [sf, sp] = self.meas;
        let gauss = tf.ex_kurt.abs().max(tf.skew.abs());
        let ratio_tip = tf.sd / tp.sd;
        let ratio_sensor = sf.sd / sp.sd;
        let felt_over_threshold = self.pacinian_rms[0] / self.pacinian_threshold;
        let spike_ratio = self.spike / tf.sd;
        vec![
            Claim::new(
                "9",
                "free space: felt tip acceleration is Gaussian, max(|skewness|, |excess kurtosis|)",
                "the particle displacement and its derivatives obey a Gaussian distribution with zero mean (§4.1, Fig. 9c, e)",
                gauss,
                "",
                &format!(
                    "≤ 0.2 (skewness {:.3}, excess kurtosis {:.3}, {} samples)",
                    tf.skew, tf.ex_kurt, tf.n
                ),
                gauss <= 0.2,
            ),
            Claim::new(
                "9",
                "collision: peak felt acceleration within 20 ms of contact ÷ free-space SD",
                "this collision was felt as an acceleration spike (§4.1, Fig. 9d)",
                spike_ratio,
                "×",
                &format!(
                    "≥ 5 (peak {:.3} m/s² at {:.1} ms after contact)",
                    self.spike,
                    (self.spike_s - self.contact_s) * 1e3
                ),
                spike_ratio >= 5.0,
            ),
            Claim::new(
                "9",
                "pressing sharpens the distribution: SD free ÷ SD pressed, true tip acceleration",
                "the distribution of acceleration due to molecular impacts became dramatically sharper (§4.1, Fig. 9f–g)",
                ratio_tip,
                "×",
                &format!(
                    "≥ 2 (SD {:.4} → {:.4} m/s²; the bead stayed pressed: {})",
                    tf.sd, tp.sd, self.stable
                ),
                ratio_tip >= 2.0 && self.stable,
            ),
            Claim::new(
                "9",
                "the same through the accelerometer: SD free ÷ SD pressed, sensor reading",
                "Fig. 9e, g: histograms read from the accelerometer on the handle",
                ratio_sensor,
                "×",
                &format!(
                    "≥ 2 through the sensor's own noise floor (SD {:.4} → {:.4} m/s²; high-band gain g_H renders the agitation above it)",
                    sf.sd, sp.sd
                ),
                ratio_sensor >= 2.0,
            ),
            Claim::new(
                "9",
                "free space: the agitation at the fingertip, Pacinian-weighted RMS ÷ the median participant's threshold",
                "users feel the Brownian motion of the bead (§4.1–4.2: a magnified representation through the Haptuator)",
                felt_over_threshold,
                "×",
                &format!(
                    "≥ 1 ({:.3} m/s² free, {:.3} m/s² pressed; threshold {:.2} m/s² RMS, flat 40–300 Hz)",
                    self.pacinian_rms[0], self.pacinian_rms[1], self.pacinian_threshold
                ),
                felt_over_threshold >= 1.0,
            ),
        ]
    }

    /// Write `fig9.csv`.
    ///
    /// # Errors
    /// File errors.
    pub fn write_csv(&self, path: &Path) -> Result<(), PaperError> {
        write_csv(
            path,
            &[
                "t_s",
                "accel_m_s2",
                "accel_sensor_m_s2",
                "felt_m_s2",
                "felt_sensor_m_s2",
                "gap_um",
                "phase",
            ],
            &[
                &self.t_s,
                &self.accel,
                &self.sensor,
                &self.accel_felt,
                &self.sensor_felt,
                &self.gap_um,
                &self.phase,
            ],
        )
    }

    fn trace_panel<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        zoom: bool,
    ) -> Result<(), String> {
        let (t0, t1, scale, unit) = if zoom && self.contact_s.is_finite() {
            (self.contact_s - 0.03, self.contact_s + 0.06, 1e3, "ms")
        } else {
            (0.0, self.t_s.last().copied().unwrap_or(1.0), 1.0, "s")
        };
        let idx: Vec<usize> = (0..self.t_s.len())
            .filter(|&i| self.t_s[i] >= t0 && self.t_s[i] <= t1 && self.t_s[i] >= WARMUP_S)
            .collect();
        let origin = if zoom { self.contact_s } else { 0.0 };
        let ys = idx
            .iter()
            .flat_map(|&i| [self.accel_felt[i], self.sensor_felt[i]]);
        let (lo, hi) = style::bounds(ys, 0.05).unwrap_or((-1.0, 1.0));
        let m = lo.abs().max(hi.abs());
        let title = if zoom {
            "(b) collision: felt acceleration around the contact"
        } else {
            "(a) rest (free) → approach → pressed"
        };
        let x_desc = if zoom {
            "Time from contact (ms)".to_owned()
        } else {
            format!("Time ({unit})")
        };
        let x = (t0 - origin) * scale..(t1 - origin) * scale;
        let mut chart = PANEL.chart(area, title, x, -m..m)?;
        PANEL
            .mesh(&mut chart, x_desc, "Felt acceleration (m/s²)")
            .x_label_formatter(&style::lin_label)
            .y_label_formatter(&style::lin_label)
            .draw()
            .map_err(err)?;
        // Decimate the long view to at most ~4000 points per series.
        let step = if zoom { 1 } else { (idx.len() / 4000).max(1) };
        let pick = |v: &Vec<f64>| -> Vec<(f64, f64)> {
            idx.iter()
                .step_by(step)
                .map(|&i| ((self.t_s[i] - origin) * scale, v[i]))
                .collect()
        };
        chart
            .draw_series(LineSeries::new(
                pick(&self.sensor_felt),
                style::GREY.stroke_width(1),
            ))
            .map_err(err)?
            .label("accelerometer reading")
            .legend(legend_line(style::GREY, 2));
        chart
            .draw_series(LineSeries::new(
                pick(&self.accel_felt),
                style::HIGH.stroke_width(1),
            ))
            .map_err(err)?
            .label("true tip acceleration")
            .legend(legend_line(style::HIGH, 2));
        if self.contact_s.is_finite() {
            let x = (self.contact_s - origin) * scale;
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(x, -m), (x, m)],
                    5,
                    4,
                    style::SUM.stroke_width(1),
                ))
                .map_err(err)?
                .label("contact")
                .legend(legend_line(style::SUM, 1));
        }
        legend(&mut chart, SeriesLabelPosition::UpperRight)
    }

    fn hist_panel<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        sensor: bool,
    ) -> Result<(), String> {
        let (v, mo) = if sensor {
            (&self.sensor_felt, &self.meas)
        } else {
            (&self.accel_felt, &self.tip)
        };
        let win = |p: f64| -> Vec<f64> {
            (0..v.len())
                .filter(|&i| self.phase[i] == p && self.t_s[i] >= WARMUP_S)
                .map(|i| v[i])
                .collect()
        };
        let (free, pressed) = (win(0.0), win(3.0));
        let half = 4.0 * mo[0].sd.max(mo[1].sd);
        let half = if half.is_finite() && half > 0.0 {
            half
        } else {
            1.0
        };
        let width = 2.0 * half / BINS as f64;
        let density = |x: &[f64]| -> Vec<f64> {
            let mut h = vec![0.0; BINS];
            for &s in x {
                let b = ((s + half) / width).floor();
                if b >= 0.0 && (b as usize) < BINS {
                    h[b as usize] += 1.0;
                }
            }
            let n = x.len().max(1) as f64;
            h.iter().map(|c| c / (n * width)).collect()
        };
        let (df, dp) = (density(&free), density(&pressed));
        let top = df.iter().chain(&dp).fold(0.0_f64, |m, v| m.max(*v)) * 1.08;
        let title = if sensor {
            "(d) distribution, accelerometer reading"
        } else {
            "(c) distribution, true tip acceleration"
        };
        let mut chart = PANEL.chart(area, title, -half..half, 0.0..top.max(1e-12))?;
        PANEL
            .mesh(
                &mut chart,
                "Felt acceleration (m/s²)",
                "Probability density (s²/m)",
            )
            .x_label_formatter(&style::lin_label)
            .y_label_formatter(&style::lin_label)
            .draw()
            .map_err(err)?;
        for (d, c, name, m) in [
            (&df, style::FREE, "free space", mo[0]),
            (&dp, style::PRESSED, "pressed", mo[1]),
        ] {
            chart
                .draw_series(d.iter().enumerate().map(|(i, &y)| {
                    let x0 = -half + i as f64 * width;
                    Rectangle::new([(x0, 0.0), (x0 + width, y)], c.mix(0.45).filled())
                }))
                .map_err(err)?
                .label(format!("{name} (SD {:.3} m/s²)", m.sd))
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 6), (x + 24, y + 6)], c.mix(0.6).filled())
                });
            // The Gaussian of the same mean and SD.
            let g: Vec<(f64, f64)> = (0..=200)
                .map(|k| {
                    let x = -half + 2.0 * half * k as f64 / 200.0;
                    let z = (x - m.mean) / m.sd;
                    (
                        x,
                        (-0.5 * z * z).exp() / (m.sd * (2.0 * std::f64::consts::PI).sqrt()),
                    )
                })
                .filter(|p| p.1.is_finite() && p.1 <= top)
                .collect();
            chart
                .draw_series(LineSeries::new(g, c.stroke_width(2)))
                .map_err(err)?;
        }
        legend(&mut chart, SeriesLabelPosition::UpperRight)
    }
}

impl Figure for Fig9 {
    fn size(&self) -> (u32, u32) {
        style::SIZE_GRID
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        let root = style::titled(
            root,
            &format!(
                "Fig. 9 — Free space and contact, felt through the interface (D, {FELT_LO_HZ:.0}–{FELT_HI_HZ:.0} Hz)"
            ),
        )?;
        let p = root.split_evenly((2, 2));
        self.trace_panel(&p[0], false)?;
        self.trace_panel(&p[1], true)?;
        self.hist_panel(&p[2], false)?;
        self.hist_panel(&p[3], true)
    }
}
