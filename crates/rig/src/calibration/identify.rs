//! Steps 2 and 3: identification of the low (Pantograph) and high
//! (Haptuator) channels, paper §3.2.
//!
//! * Low channel: G0_L and the flat band — the widest band (in octaves) of
//!   contiguous bins, after fractional-octave smoothing, whose coherence is
//!   ≥ γ²_min and whose magnitude stays within ±tol dB of one gain. G0_L is
//!   that gain: the geometric midpoint of the largest and smallest smoothed
//!   magnitude in the band (so every bin is within ±tol of it), with the sign
//!   of the mean in-band phasor (a channel measured in antiphase has a
//!   negative G0_L).
//! * High channel: the reliable band — the widest contiguous run of bins up
//!   to `fit_max_hz` whose smoothed coherence is ≥ γ²_min; its lower edge is
//!   where the paper's "not reliable below 100 Hz" falls (saturation and a
//!   weak response both lower the coherence). Ĝ_H(s) is fitted there
//!   (Levy + Sanathanan–Koerner, [`kilotouch_dsp::fit::fit_tf`]) with
//!   weights γ²/(1 − γ²) (inverse relative variance of H1).

use super::config::CalibrationConfig;
use super::error::{CalibrationError, Result};
use super::interface::{CalibrationRig, Channel};
use super::measure::{ChannelFrf, ExcitationSummary, RawRecord, measure_channel, smoothed};
use super::progress::{Step, StepContext};
use kilotouch_dsp::compensator::minimum_phase;
use kilotouch_dsp::fit::{CoherenceWeighting, FitOptions, Mode, coherence_weights, fit_tf};
use kilotouch_dsp::{C64, Tf};
use serde::{Deserialize, Serialize};

/// Result of step 2.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LowChannelId {
    /// Static gain G0_L of the low channel, (m/s²)/N, signed.
    pub g0: f64,
    /// Flat band [f_lo, f_hi], Hz: within ±`flat_tol_db` of |G0_L| with
    /// coherence ≥ the configured minimum.
    pub flat_band_hz: [f64; 2],
    /// Half-width of the flat band criterion, dB.
    pub flat_tol_db: f64,
    /// Largest |deviation| from |G0_L| inside the flat band (smoothed), dB.
    pub max_dev_db: f64,
    /// Smallest smoothed coherence inside the flat band.
    pub min_coherence: f64,
    /// How the channel was excited.
    pub excitation: ExcitationSummary,
    /// The FRF estimate (not stored in the calibration file).
    #[serde(skip)]
    pub frf: ChannelFrf,
    /// Raw records (not stored in the calibration file).
    #[serde(skip)]
    pub raw: Vec<RawRecord>,
}

/// Diagnostics of the Ĝ_H fit.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitDiagnostics {
    /// RMS relative error over the fitted points.
    pub rms_rel_error: f64,
    /// Worst magnitude mismatch over the fitted points, dB.
    pub max_mag_dev_db: f64,
    /// Condition number of the final least-squares matrix.
    pub condition_number: f64,
    /// Sanathanan–Koerner iterations.
    pub iterations: usize,
    /// True when the iterations converged.
    pub converged: bool,
    /// Points used.
    pub n_points: usize,
    /// Right-half-plane poles reflected into the left half plane.
    pub reflected_poles: usize,
    /// Right-half-plane zeros reflected (minimum-phase model, same magnitude).
    pub reflected_zeros: usize,
    /// Resonances of the model (pole pairs).
    pub modes: Vec<Mode>,
    /// Antiresonances of the model (zero pairs).
    pub zero_modes: Vec<Mode>,
}

/// Result of step 3.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HighChannelId {
    /// Fitted model Ĝ_H(s), (m/s²) per drive unit, s in rad/s.
    pub model: Tf,
    /// Band [f_lo, f_hi] (Hz) over which the model was fitted; below f_lo the
    /// estimate is unreliable.
    pub reliable_band_hz: [f64; 2],
    /// Fraction of the bins in the reliable band with coherence ≥ the minimum.
    pub coherent_fraction: f64,
    /// Fit diagnostics.
    pub fit: FitDiagnostics,
    /// How the channel was excited.
    pub excitation: ExcitationSummary,
    /// The FRF estimate (not stored in the calibration file).
    #[serde(skip)]
    pub frf: ChannelFrf,
    /// Raw records (not stored in the calibration file).
    #[serde(skip)]
    pub raw: Vec<RawRecord>,
}

/// Widest (in octaves) run of consecutive indices in `range` where `ok(i)`
/// holds and `vals` spans at most `spread`; ties go to the higher band.
/// Returns inclusive index bounds.
fn widest_run(
    f: &[f64],
    range: std::ops::Range<usize>,
    vals: &[f64],
    spread: f64,
    ok: impl Fn(usize) -> bool,
) -> Option<(usize, usize)> {
    let mut best: Option<(usize, usize, f64)> = None;
    for l in range.clone() {
        if !ok(l) {
            continue;
        }
        let (mut lo, mut hi) = (vals[l], vals[l]);
        let mut r = l;
        while r + 1 < range.end && ok(r + 1) {
            let v = vals[r + 1];
            if v.max(hi) - v.min(lo) > spread {
                break;
            }
            lo = lo.min(v);
            hi = hi.max(v);
            r += 1;
        }
        let width = (f[r] / f[l]).log2();
        if best.is_none_or(|(_, _, w)| width >= w) {
            best = Some((l, r, width));
        }
    }
    best.map(|(l, r, _)| (l, r))
}

/// Flat band of a low-channel estimate: `(i_lo, i_hi, |G0_L| in dB, max
/// deviation in dB)`, see the module documentation.
pub fn flat_band(frf: &ChannelFrf, cfg: &CalibrationConfig) -> Option<(usize, usize, f64, f64)> {
    let a = &cfg.analysis;
    let (db, coh) = smoothed(frf, a.smoothing_octaves);
    let range = frf.range(a.f_min_hz, a.f_max_hz);
    let (l, r) = widest_run(&frf.f_hz, range, &db, 2.0 * a.flat_tol_db, |i| {
        coh[i] >= a.coherence_min
    })?;
    let (lo, hi) = db[l..=r]
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    let mid = 0.5 * (lo + hi);
    Some((l, r, mid, 0.5 * (hi - lo)))
}

/// Step 2: identify the low channel (Pantograph on, Haptuator off).
pub fn identify_low<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    cfg: &CalibrationConfig,
    ctx: &mut StepContext<'_>,
) -> Result<LowChannelId> {
    let step = Step::IdentifyLow;
    ctx.check_cancel(step)?;
    ctx.report(step, 0.0, "low channel: MLS excitation, Pantograph only");
    let m = measure_channel(rig, Channel::Low, cfg, step, ctx)?;
    let id = low_from_frf(m.frf, m.excitation, m.raw, cfg)?;
    ctx.report(
        step,
        1.0,
        &format!(
            "G0_L = {:.4} (m/s²)/N, flat {:.0}–{:.0} Hz",
            id.g0, id.flat_band_hz[0], id.flat_band_hz[1]
        ),
    );
    Ok(id)
}

/// Step 2's analysis of a measured low-channel FRF.
pub fn low_from_frf(
    frf: ChannelFrf,
    excitation: ExcitationSummary,
    raw: Vec<RawRecord>,
    cfg: &CalibrationConfig,
) -> Result<LowChannelId> {
    let step = Step::IdentifyLow;
    let (l, r, mid_db, max_dev_db) = flat_band(&frf, cfg).ok_or_else(|| {
        CalibrationError::measurement(
            step,
            format!(
                "no bin between {} and {} Hz reached coherence {}: is the Pantograph driven \
                 and the accelerometer attached?",
                cfg.analysis.f_min_hz, cfg.analysis.f_max_hz, cfg.analysis.coherence_min
            ),
        )
    })?;
    let (f_lo, f_hi) = (frf.f_hz[l], frf.f_hz[r]);
    if (f_hi / f_lo).log2() < 1.0 / 3.0 {
        return Err(CalibrationError::measurement(
            step,
            format!(
                "the widest band within ±{} dB with coherence ≥ {} is only {f_lo:.1}–{f_hi:.1} Hz \
                 (less than a third of an octave): no flat band to identify a static gain",
                cfg.analysis.flat_tol_db, cfg.analysis.coherence_min
            ),
        ));
    }
    let phasor: C64 = frf.h[l..=r]
        .iter()
        .filter(|h| h.norm() > 0.0)
        .map(|h| h / h.norm())
        .sum();
    let sign = if phasor.re < 0.0 { -1.0 } else { 1.0 };
    let (_, coh) = smoothed(&frf, cfg.analysis.smoothing_octaves);
    let min_coherence = coh[l..=r].iter().copied().fold(1.0, f64::min);
    Ok(LowChannelId {
        g0: sign * 10f64.powf(mid_db / 20.0),
        flat_band_hz: [f_lo, f_hi],
        flat_tol_db: cfg.analysis.flat_tol_db,
        max_dev_db,
        min_coherence,
        excitation,
        frf,
        raw,
    })
}

/// Step 3: identify the high channel (Pantograph off, Haptuator on).
pub fn identify_high<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    cfg: &CalibrationConfig,
    ctx: &mut StepContext<'_>,
) -> Result<HighChannelId> {
    let step = Step::IdentifyHigh;
    ctx.check_cancel(step)?;
    ctx.report(step, 0.0, "high channel: MLS excitation, Haptuator only");
    let m = measure_channel(rig, Channel::High, cfg, step, ctx)?;
    let id = high_from_frf(m.frf, m.excitation, m.raw, cfg)?;
    ctx.report(
        step,
        1.0,
        &format!(
            "Ĝ_H fitted over {:.0}–{:.0} Hz, worst mismatch {:.2} dB",
            id.reliable_band_hz[0], id.reliable_band_hz[1], id.fit.max_mag_dev_db
        ),
    );
    Ok(id)
}

/// Step 3's analysis of a measured high-channel FRF: reliable band and fit.
pub fn high_from_frf(
    frf: ChannelFrf,
    excitation: ExcitationSummary,
    raw: Vec<RawRecord>,
    cfg: &CalibrationConfig,
) -> Result<HighChannelId> {
    let step = Step::IdentifyHigh;
    let a = &cfg.analysis;
    let h = &cfg.high_fit;
    let (_, coh) = smoothed(&frf, a.smoothing_octaves);
    let range = frf.range(a.f_min_hz, h.fit_max_hz);
    let (l, r) = widest_run(&frf.f_hz, range.clone(), &coh, f64::INFINITY, |i| {
        coh[i] >= a.coherence_min
    })
    .ok_or_else(|| {
        CalibrationError::measurement(
            step,
            format!(
                "no bin between {} and {} Hz reached coherence {}: is the Haptuator driven?",
                a.f_min_hz, h.fit_max_hz, a.coherence_min
            ),
        )
    })?;
    let mut f_lo = frf.f_hz[l];
    if let Some(m) = h.min_reliable_hz {
        f_lo = f_lo.max(m);
    }
    let f_hi = h.fit_max_hz;
    if frf.f_hz[r] / f_lo < 2f64.sqrt() {
        return Err(CalibrationError::measurement(
            step,
            format!(
                "the coherent band {:.1}–{:.1} Hz is narrower than half an octave: not enough \
                 to fit Ĝ_H (raise the high-channel amplitude or the number of periods)",
                f_lo, frf.f_hz[r]
            ),
        ));
    }
    let band = frf.range(f_lo, f_hi);
    let coherent = band
        .clone()
        .filter(|&i| frf.coherence[i] >= a.coherence_min)
        .count();
    let coherent_fraction = coherent as f64 / band.len().max(1) as f64;
    let w = coherence_weights(&frf.coherence, CoherenceWeighting::SignalToNoise)
        .map_err(|e| CalibrationError::dsp("coherence weights", e))?;
    let opts = FitOptions {
        fmin_hz: Some(f_lo),
        fmax_hz: Some(f_hi),
        enforce_stability: true,
        ..FitOptions::default()
    };
    let fit = fit_tf(&frf.f_hz, &frf.h, Some(&w), h.num_order, h.den_order, &opts)
        .map_err(|e| CalibrationError::dsp("fit of Ĝ_H", e))?;
    let reflected_zeros = fit.zeros.iter().filter(|z| z.re > 0.0).count();
    let model = if reflected_zeros > 0 {
        minimum_phase(&fit.tf).map_err(|e| CalibrationError::dsp("minimum-phase Ĝ_H", e))?
    } else {
        fit.tf.clone()
    };
    Ok(HighChannelId {
        model,
        reliable_band_hz: [f_lo, f_hi],
        coherent_fraction,
        fit: FitDiagnostics {
            rms_rel_error: fit.rms_rel_error,
            max_mag_dev_db: fit.max_mag_dev_db,
            condition_number: fit.condition_number,
            iterations: fit.iterations,
            converged: fit.converged,
            n_points: fit.n_points,
            reflected_poles: fit.reflected_poles,
            reflected_zeros,
            modes: fit.modes,
            zero_modes: fit.zero_modes,
        },
        excitation,
        frf,
        raw,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frf_of(f: &[f64], g: impl Fn(f64) -> C64, coh: impl Fn(f64) -> f64) -> ChannelFrf {
        ChannelFrf {
            f_hz: f.to_vec(),
            h: f.iter().map(|&x| g(x)).collect(),
            coherence: f.iter().map(|&x| coh(x)).collect(),
            n_segments: 30,
            sensor_corrected: true,
        }
    }

    fn grid() -> Vec<f64> {
        (1..=400).map(|k| k as f64 * 10_000.0 / 2048.0).collect()
    }

    /// A channel that is exactly G0 between 40 and 250 Hz and jumps by
    /// 20 dB from bin to bin outside: the flat band and gain are recovered to
    /// the bin.
    #[test]
    fn flat_band_of_a_plateau() {
        let f = grid();
        let df = 10_000.0 / 2048.0;
        let g = |x: f64| {
            if (40.0..=250.0).contains(&x) {
                C64::new(-3.0, 0.0)
            } else if (x / df).round() as i64 % 2 == 0 {
                C64::new(0.3, 0.0)
            } else {
                C64::new(3.0, 0.0)
            }
        };
        let mut cfg = CalibrationConfig::default();
        cfg.analysis.smoothing_octaves = 0.0;
        let id = low_from_frf(frf_of(&f, g, |_| 0.99), Default::default(), vec![], &cfg).unwrap();
        assert_eq!(id.g0, -3.0);
        assert!((id.flat_band_hz[0] - 40.0).abs() < df);
        assert!((id.flat_band_hz[1] - 250.0).abs() < df);
        assert_eq!(id.max_dev_db, 0.0);
    }

    /// A slope of s dB/octave stays within ±1 dB over 2/s octaves: the band
    /// found is that wide (to one bin) and G0 is the midpoint.
    #[test]
    fn flat_band_of_a_slope_has_analytic_width() {
        let f = grid();
        let slope = 3.0; // dB per octave
        let g = |x: f64| C64::new(10f64.powf(slope * (x / 100.0).log2() / 20.0), 0.0);
        let mut cfg = CalibrationConfig::default();
        cfg.analysis.smoothing_octaves = 0.0;
        cfg.analysis.f_min_hz = 50.0;
        cfg.analysis.f_max_hz = 400.0;
        let id = low_from_frf(frf_of(&f, g, |_| 0.95), Default::default(), vec![], &cfg).unwrap();
        let width = (id.flat_band_hz[1] / id.flat_band_hz[0]).log2();
        let want = 2.0 * cfg.analysis.flat_tol_db / slope;
        assert!(
            width <= want + 1e-12 && width > want - 0.05,
            "{width} vs {want}"
        );
        // Every bin in the band is within ±1 dB of G0.
        for (x, h) in f.iter().zip(g_vals(&f, g)) {
            if (id.flat_band_hz[0]..=id.flat_band_hz[1]).contains(x) {
                assert!((20.0 * (h / id.g0).log10()).abs() <= 1.0 + 1e-12);
            }
        }
    }

    fn g_vals(f: &[f64], g: impl Fn(f64) -> C64) -> Vec<f64> {
        f.iter().map(|&x| g(x).norm()).collect()
    }

    /// Coherence below the minimum splits the band.
    #[test]
    fn incoherent_bins_end_the_flat_band() {
        let f = grid();
        let mut cfg = CalibrationConfig::default();
        cfg.analysis.smoothing_octaves = 0.0;
        cfg.analysis.f_max_hz = 1000.0;
        let coh = |x: f64| {
            if (150.0..160.0).contains(&x) {
                0.5
            } else {
                0.99
            }
        };
        let id = low_from_frf(
            frf_of(&f, |_| C64::new(2.0, 0.0), coh),
            Default::default(),
            vec![],
            &cfg,
        )
        .unwrap();
        // 14.6–146 Hz is 3.3 octaves, 161–1000 Hz is 2.6.
        assert!(id.flat_band_hz[0] < 15.0, "{:?}", id.flat_band_hz);
        assert!(
            (id.flat_band_hz[1] - 146.5).abs() < 1.0,
            "{:?}",
            id.flat_band_hz
        );
    }

    #[test]
    fn no_coherent_bin_is_a_clear_error() {
        let f = grid();
        let cfg = CalibrationConfig::default();
        let e = low_from_frf(
            frf_of(&f, |_| C64::new(1.0, 0.0), |_| 0.2),
            Default::default(),
            vec![],
            &cfg,
        )
        .unwrap_err();
        assert!(e.to_string().contains("coherence"), "{e}");
    }

    /// The paper's Ĝ_H (eq. 2) sampled exactly with coherence 1 above 100 Hz
    /// and 0.3 below: the reliable band starts at the first coherent bin and
    /// the fit recovers eq. 2 (REFERENCE-VALUES.md: ω_n = 2135.42 rad/s,
    /// ζ = 0.4999, zero at −2560 rad/s).
    #[test]
    fn high_fit_recovers_paper_model_above_unreliable_band() {
        let f = grid();
        let g = kilotouch_dsp::compensator::paper_g_h();
        let coh = |x: f64| if x < 100.0 { 0.3 } else { 0.999 };
        let cfg = CalibrationConfig::default();
        let id = high_from_frf(
            frf_of(&f, |x| g.response_hz(x), coh),
            Default::default(),
            vec![],
            &cfg,
        )
        .unwrap();
        assert!((id.reliable_band_hz[0] - 100.0).abs() < 10_000.0 / 2048.0);
        let mode = id.fit.modes[0];
        assert!(
            (mode.wn_rad_s - 4.56e6f64.sqrt()).abs() < 1e-6 * 2135.42,
            "{mode:?}"
        );
        assert!((mode.zeta - 2135.0 / (2.0 * 4.56e6f64.sqrt())).abs() < 1e-8);
        let z = id.model.zeros().unwrap();
        assert!((z[0].re + 2560.0).abs() < 1e-6 && z[0].im.abs() < 1e-9);
        assert!((id.model.dc_gain() - 0.140351).abs() < 1e-6);
        assert_eq!(id.coherent_fraction, 1.0);
    }

    /// A non-minimum-phase channel is replaced by its minimum-phase
    /// reflection (same magnitude) so that C_H can invert it.
    #[test]
    fn rhp_zero_is_reflected() {
        let f = grid();
        let g = Tf::new(vec![-250.0, 6.4e5], vec![1.0, 2135.0, 4.56e6]).unwrap();
        let cfg = CalibrationConfig::default();
        let id = high_from_frf(
            frf_of(&f, |x| g.response_hz(x), |_| 0.999),
            Default::default(),
            vec![],
            &cfg,
        )
        .unwrap();
        assert_eq!(id.fit.reflected_zeros, 1);
        let z = id.model.zeros().unwrap();
        assert!(z[0].re < 0.0);
        for x in [100.0, 400.0, 1000.0] {
            let r = id.model.response_hz(x).norm() / g.response_hz(x).norm();
            assert!((r - 1.0).abs() < 1e-6);
        }
    }
}
