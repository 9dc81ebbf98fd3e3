//! The result's curves (Fig. 5 and 7 and the chain's responses), computed once
//! when a calibration arrives, and their drawing.

use kilotouch_dsp::crossover::LinkwitzRiley;
use kilotouch_rig::calibration::CalibrationFile;
use kilotouch_rig::calibration::measure::ChannelFrf;

use crate::gui::charts::{
    self, BandBars, FAIL_COLOR, HIGH_COLOR, LOW_COLOR, PASS_COLOR, SUM_COLOR, Series, db, log_f,
    log_points, unwrap_phase_deg,
};

/// Curves of the result, computed once when the result arrives.
#[derive(Debug, Clone)]
pub(super) struct Plots {
    /// Measured FRFs present (a wizard run; files do not store them).
    measured: bool,
    low_mag: Vec<Series>,
    low_phase: Vec<Series>,
    low_coh: Vec<Series>,
    high_mag: Vec<Series>,
    high_phase: Vec<Series>,
    high_coh: Vec<Series>,
    low_flat_hz: [f64; 2],
    high_reliable_hz: [f64; 2],
    crossover: Vec<Series>,
    comp_mag: Vec<Series>,
    comp_phase: Vec<Series>,
    bands: Vec<BandBars>,
}

/// Logarithmically spaced frequencies from `lo` to `hi` Hz (`n` ≥ 2 points).
fn log_grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let (a, b) = (lo.log10(), hi.log10());
    let n = n.max(2);
    (0..n)
        .map(|k| 10f64.powf(a + (b - a) * k as f64 / (n - 1) as f64))
        .collect()
}

fn mag_db(h: &[kilotouch_dsp::C64]) -> Vec<f64> {
    h.iter().map(|z| db(z.norm())).collect()
}

fn phase_deg(h: &[kilotouch_dsp::C64]) -> Vec<f64> {
    unwrap_phase_deg(&h.iter().map(|z| z.arg()).collect::<Vec<_>>())
}

/// The measured phase unwrapped along the model's, and the model's, in
/// degrees at the bins `f_hz`: the model's phase unwrapped over the bins,
/// plus the measured-minus-model difference wrapped into (−180°, 180°].
/// Unwrapping the measurement on its own carried every 360° slip of its
/// incoherent bins (the Haptuator hardly moves below ~50 Hz, so its phase
/// there is noise) into the band above, where the curve then sat whole
/// turns away from the model it matches within the fit's tolerance.
pub fn phase_along_model(
    f_hz: &[f64],
    h: &[kilotouch_dsp::C64],
    model: impl Fn(f64) -> kilotouch_dsp::C64,
) -> (Vec<f64>, Vec<f64>) {
    let m: Vec<kilotouch_dsp::C64> = f_hz.iter().map(|&f| model(f)).collect();
    let model_deg = phase_deg(&m);
    let meas = h
        .iter()
        .zip(&m)
        .zip(&model_deg)
        .map(|((hi, mi), md)| {
            let d = (hi / mi).arg().to_degrees();
            md + d
        })
        .collect();
    (meas, model_deg)
}

/// Magnitude (dB), unwrapped phase (deg) and coherence curves of a measured
/// FRF (empty for an FRF not in memory, e.g. a loaded file).
fn measured_series(
    frf: &ChannelFrf,
    color: egui::Color32,
) -> (Vec<Series>, Vec<Series>, Vec<Series>) {
    if frf.f_hz.is_empty() {
        return (Vec::new(), Vec::new(), Vec::new());
    }
    let curve = |name: &str, y: &[f64]| vec![Series::solid(name, log_points(&frf.f_hz, y), color)];
    (
        curve("measured H1", &mag_db(&frf.h)),
        curve("measured H1", &phase_deg(&frf.h)),
        curve("coherence γ²", &frf.coherence),
    )
}

pub(super) fn build_plots(f: &CalibrationFile) -> Plots {
    let fs = f.rig.sample_rate_hz;
    let low_frf = &f.low.frf;
    let high_frf = &f.high.frf;
    let measured = !low_frf.f_hz.is_empty() && !high_frf.f_hz.is_empty();
    let (mut low_mag, mut low_phase, low_coh) = measured_series(low_frf, LOW_COLOR);
    let (mut high_mag, mut high_phase, high_coh) = measured_series(high_frf, HIGH_COLOR);
    // Low-channel model: the gain G0_L over its flat band.
    let [fl0, fl1] = f.low.flat_band_hz;
    if let (Some(x0), Some(x1)) = (log_f(fl0), log_f(fl1)) {
        let g = db(f.low.g0);
        low_mag.push(Series::dashed(
            format!("model G0_L = {:.4} (m/s²)/N", f.low.g0),
            vec![[x0, g], [x1, g]],
            SUM_COLOR,
        ));
        let ph = if f.low.g0 < 0.0 { 180.0 } else { 0.0 };
        low_phase.push(Series::dashed(
            "model G0_L",
            vec![[x0, ph], [x1, ph]],
            SUM_COLOR,
        ));
    }
    high_model_series(f, &mut high_mag, &mut high_phase);
    // Crossover L, H and L + H (magnitudes, dB).
    let xo_grid = log_grid(1.0, 0.45 * fs, 300);
    let crossover = crossover_series(f, &xo_grid);
    // Compensators C_L (a gain) and C_H(s) = K_sys·F(s)/Ĝ_H(s).
    let d = &f.compensators;
    let c_h: Vec<kilotouch_dsp::C64> = xo_grid.iter().map(|&fr| d.c_h.response_hz(fr)).collect();
    let c_l = db(d.c_l);
    let comp_mag = vec![
        Series::solid(
            format!("C_L = K_sys/G0_L = {:.4} N/unit", d.c_l),
            log_points(&xo_grid, &vec![c_l; xo_grid.len()]),
            LOW_COLOR,
        ),
        Series::solid(
            "C_H = K_sys·F/Ĝ_H",
            log_points(&xo_grid, &mag_db(&c_h)),
            HIGH_COLOR,
        ),
    ];
    let comp_phase = vec![Series::solid(
        "C_H",
        log_points(&xo_grid, &phase_deg(&c_h)),
        HIGH_COLOR,
    )];
    let bands = f
        .verification
        .bands
        .iter()
        .map(|b| BandBars {
            centre_hz: b.centre_hz,
            before_db: b.uncompensated_db,
            after_db: b.db,
        })
        .collect();
    Plots {
        measured,
        low_mag,
        low_phase,
        low_coh,
        high_mag,
        high_phase,
        high_coh,
        low_flat_hz: f.low.flat_band_hz,
        high_reliable_hz: f.high.reliable_band_hz,
        crossover,
        comp_mag,
        comp_phase,
        bands,
    }
}

/// The high channel's fitted model Ĝ_H(j2πf)·e^{−j2πfτ} over the analysed
/// band, added to its magnitude (dB) and phase (deg) curves; with a
/// measurement, the phase on the measurement's bins, unwrapped along the
/// model ([`phase_along_model`]).
fn high_model_series(
    f: &CalibrationFile,
    high_mag: &mut Vec<Series>,
    high_phase: &mut Vec<Series>,
) {
    let a = &f.settings.analysis;
    let high_frf = &f.high.frf;
    // High-channel model Ĝ_H(j2πf)·e^{−j2πfτ} over the analysed band.
    let grid = log_grid(a.f_min_hz.max(1.0), a.f_max_hz.max(a.f_min_hz * 2.0), 240);
    let model: Vec<kilotouch_dsp::C64> = grid.iter().map(|&fr| f.high.response(fr)).collect();
    high_mag.push(Series::dashed(
        "fitted model Ĝ_H",
        log_points(&grid, &mag_db(&model)),
        SUM_COLOR,
    ));
    if high_frf.f_hz.is_empty() {
        high_phase.push(Series::dashed(
            "fitted model Ĝ_H",
            log_points(&grid, &phase_deg(&model)),
            SUM_COLOR,
        ));
    } else {
        // With a measurement, both phases on the measurement's bins, the
        // measurement unwrapped along the model (phase_along_model).
        let (meas, model_deg) =
            phase_along_model(&high_frf.f_hz, &high_frf.h, |fr| f.high.response(fr));
        let in_band: Vec<usize> = (0..high_frf.f_hz.len())
            .filter(|&i| (a.f_min_hz..=a.f_max_hz).contains(&high_frf.f_hz[i]))
            .collect();
        let pick = |v: &[f64]| -> (Vec<f64>, Vec<f64>) {
            in_band.iter().map(|&i| (high_frf.f_hz[i], v[i])).unzip()
        };
        *high_phase = vec![Series::solid(
            "measured H1",
            log_points(&high_frf.f_hz, &meas),
            HIGH_COLOR,
        )];
        let (fm, pm) = pick(&model_deg);
        high_phase.push(Series::dashed(
            "fitted model Ĝ_H",
            log_points(&fm, &pm),
            SUM_COLOR,
        ));
    }
}

/// The crossover's L, H and L + H magnitudes (dB) on `xo_grid` (Hz); none
/// when the stored crossover cannot be built.
fn crossover_series(f: &CalibrationFile, xo_grid: &[f64]) -> Vec<Series> {
    let fs = f.rig.sample_rate_hz;
    let mut crossover = Vec::new();
    if let Ok(xo) = LinkwitzRiley::new(f.crossover.order, f.crossover.crossover_hz, fs) {
        let (mut l, mut h, mut s) = (Vec::new(), Vec::new(), Vec::new());
        for &fr in xo_grid {
            let (lz, hz) = xo.response(fr);
            l.push(db(lz.norm()));
            h.push(db(hz.norm()));
            s.push(db((lz + hz).norm()));
        }
        crossover.push(Series::solid(
            "L (low-pass)",
            log_points(xo_grid, &l),
            LOW_COLOR,
        ));
        crossover.push(Series::solid(
            "H (high-pass)",
            log_points(xo_grid, &h),
            HIGH_COLOR,
        ));
        crossover.push(Series::dashed("L + H", log_points(xo_grid, &s), SUM_COLOR));
    }
    crossover
}

impl Plots {
    /// Draw the curves of `f` (Fig. 5, the crossover, the compensators, Fig. 7).
    pub(super) fn ui(&self, ui: &mut egui::Ui, f: &CalibrationFile) {
        let p = self;
        let v = &f.verification;
        egui::CollapsingHeader::new("Measured responses and models (Fig. 5)")
            .default_open(true)
            .show(ui, |ui| {
                if !p.measured {
                    ui.label(
                        "Calibration files do not store the measured responses: only the \
                         models are drawn. Run the wizard to see the measurements.",
                    );
                }
                ui.label(format!(
                    "Low channel (Pantograph): flat band {:.0}–{:.0} Hz",
                    p.low_flat_hz[0], p.low_flat_hz[1]
                ));
                charts::bode(ui, "cal-low", &p.low_mag, &p.low_phase, &p.low_coh);
                ui.label(format!(
                    "High channel (Haptuator): model reliable {:.0}–{:.0} Hz",
                    p.high_reliable_hz[0], p.high_reliable_hz[1]
                ));
                charts::bode(ui, "cal-high", &p.high_mag, &p.high_phase, &p.high_coh);
            });
        egui::CollapsingHeader::new("Crossover")
            .default_open(true)
            .show(ui, |ui| {
                let fc = log_f(f.crossover.crossover_hz);
                charts::freq_chart(ui, "cal-xo", "dB", 180.0, &p.crossover, |pl| {
                    if let Some(x) = fc {
                        pl.vline(egui_plot::VLine::new("f_c", x).color(SUM_COLOR));
                    }
                });
            });
        egui::CollapsingHeader::new("Compensators C_L, C_H")
            .default_open(true)
            .show(ui, |ui| {
                charts::freq_chart(ui, "cal-comp-mag", "dB", 160.0, &p.comp_mag, |_| {});
                charts::freq_chart(ui, "cal-comp-phase", "deg", 120.0, &p.comp_phase, |_| {});
            });
        egui::CollapsingHeader::new("Verification, third-octave bands (Fig. 7)")
            .default_open(true)
            .show(ui, |ui| {
                charts::third_octave_bars(ui, "cal-verify", &p.bands, v.tolerance_db);
                egui::Grid::new("cal-bands")
                    .striped(true)
                    .num_columns(5)
                    .show(ui, |ui| {
                        for h in ["band (Hz)", "played (Hz)", "before (dB)", "after (dB)", ""] {
                            ui.strong(h);
                        }
                        ui.end_row();
                        for b in &v.bands {
                            ui.label(format!(
                                "{}{}",
                                b.nominal,
                                if b.extended { " *" } else { "" }
                            ));
                            ui.label(format!("{:.1}", b.f_hz));
                            ui.label(format!("{:+.2}", b.uncompensated_db));
                            ui.label(format!("{:+.2}", b.db));
                            if b.saturated {
                                ui.colored_label(FAIL_COLOR, "saturated");
                            } else if b.within {
                                ui.colored_label(PASS_COLOR, "ok");
                            } else {
                                ui.colored_label(FAIL_COLOR, "out");
                            }
                            ui.end_row();
                        }
                    });
                ui.label("* band below the paper's 63 Hz, inside the low channel's flat band");
            });
    }
}

#[cfg(test)]
mod tests {
    use kilotouch_rig::RigConfig;
    use kilotouch_rig::calibration::{CalibrationConfig, RigAdapter};

    use super::*;

    #[test]
    fn log_grid_is_geometric_with_exact_ends() {
        let g = log_grid(10.0, 1000.0, 5);
        let want = [10.0, 31.622776601683793, 100.0, 316.22776601683796, 1000.0];
        for (a, b) in g.iter().zip(want) {
            assert!((a / b - 1.0).abs() < 1e-12);
        }
        assert_eq!(log_grid(1.0, 2.0, 0).len(), 2);
    }

    #[test]
    fn measured_phase_follows_the_model_through_noisy_low_bins() {
        use kilotouch_dsp::C64;
        // A delay of 0.3 ms measured exactly above 50 Hz and as noise of
        // random phase below: unwrapped alone, its slips below 50 Hz shift
        // the whole curve by turns; along the model it equals the model
        // wherever the measurement does.
        let tau = 3e-4;
        let f: Vec<f64> = (1..=1000).map(|k| f64::from(k) * 2.0).collect();
        let model = |fr: f64| C64::from_polar(1.0, -std::f64::consts::TAU * fr * tau);
        let h: Vec<C64> = f
            .iter()
            .enumerate()
            .map(|(i, &fr)| {
                if fr < 50.0 {
                    // Phases jumping by ±170°: unwrap takes some as slips.
                    C64::from_polar(1e-3, if i % 2 == 0 { 3.0 } else { -3.0 })
                } else {
                    model(fr)
                }
            })
            .collect();
        let (meas, model_deg) = phase_along_model(&f, &h, model);
        let alone = phase_deg(&h);
        for i in (0..f.len()).filter(|&i| f[i] >= 50.0) {
            assert!((meas[i] - model_deg[i]).abs() < 1e-9, "{} Hz", f[i]);
            assert!((model_deg[i] + 360.0 * f[i] * tau).abs() < 1e-9);
        }
        let i = f.len() - 1;
        assert!(
            (alone[i] - model_deg[i]).abs() > 180.0,
            "the plain unwrap slips"
        );
    }

    #[test]
    fn on_the_simulated_rig_the_fit_follows_the_measured_phase_and_the_plain_unwrap_does_not() {
        // The cause of the high-channel phase plot's mismatch: in the
        // reliable band the measurement is within a few degrees of the
        // fitted model once unwrapped along it (the fit is judged in
        // magnitude and phase there), while the measurement unwrapped on its
        // own from the lowest bin sits whole turns away.
        let cfg = RigConfig::default();
        let mut rig = RigAdapter::sim(&cfg, Some(1)).unwrap();
        let flag = std::sync::atomic::AtomicBool::new(false);
        let out = kilotouch_rig::calibration::calibrate(
            &mut rig,
            &CalibrationConfig::default(),
            None,
            &mut kilotouch_rig::calibration::NoProgress,
            &flag,
        )
        .unwrap();
        let file = out.file().unwrap();
        let frf = &file.high.frf;
        let (meas, model) = phase_along_model(&frf.f_hz, &frf.h, |f| file.high.response(f));
        let alone = phase_deg(&frf.h);
        let [lo, hi] = file.high.reliable_band_hz;
        let band: Vec<usize> = (0..frf.f_hz.len())
            .filter(|&i| frf.f_hz[i] >= lo && frf.f_hz[i] <= hi && frf.coherence[i] > 0.9)
            .collect();
        assert!(band.len() > 50, "{} bins in {lo}–{hi} Hz", band.len());
        let worst_along = band
            .iter()
            .map(|&i| (meas[i] - model[i]).abs())
            .fold(0.0, f64::max);
        let worst_alone = band
            .iter()
            .map(|&i| (alone[i] - model[i]).abs())
            .fold(0.0, f64::max);
        assert!(worst_along < 20.0, "along the model: {worst_along}°");
        assert!(worst_alone > 180.0, "unwrapped alone: {worst_alone}°");
    }
}
