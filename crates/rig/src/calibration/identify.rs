//! Steps 2 and 3: identification of the low (Pantograph) and high
//! (Haptuator) channels, paper §3.2.
//!
//! * Low channel: the flat band is the widest (in octaves) run of
//!   contiguous bins, after fractional-octave smoothing, with coherence
//!   ≥ γ²_min and a magnitude spread of at most 2·tol dB, so that one gain
//!   is within ±tol of all of them. G0_L is that gain: the band's plateau
//!   level (the level with the most octaves of bins within ±tol/2 of it,
//!   refined to their octave-weighted mean) kept within [max − tol,
//!   min + tol]; its sign is that of the mean in-band phasor (a channel
//!   measured in antiphase has a negative G0_L).
//! * High channel: the coherent band is the widest contiguous run of bins
//!   up to `fit_max_hz` whose smoothed coherence is ≥ γ²_min (saturation
//!   and a weak response both lower it). Ĝ_H(s) is fitted by
//!   Levy + Sanathanan–Koerner ([`kilotouch_dsp::fit::fit_tf`]) with weights
//!   γ²/(1 − γ²) (inverse relative variance of H1) after removing a pure
//!   delay τ (half-sample grid, best fit of the top two octaves). The
//!   reliable band is where the model holds: its lower edge starts at the
//!   coherent edge and rises in 1/6-octave steps until a model — the
//!   configured orders (default 1/2, paper eq. 2), then orders raised by
//!   one up to `max_order_increase`, each with 0 or 2 zeros imposed at
//!   s = 0 — matches the estimate in magnitude and phase within
//!   `model_tol_db` ([`model_error_db`]). This is the paper's "for
//!   frequencies greater than 100 Hz the response was well approximated by
//!   the following model". Right-half-plane zeros are reflected (C_H must be
//!   stable) and zeros near s = 0 moved to −[`ORIGIN_ZERO_FLOOR`]·ω_lo.

use super::config::CalibrationConfig;
use super::error::{CalibrationError, Result};
use super::interface::{CalibrationRig, Channel};
use super::measure::{
    ChannelFrf, ExcitationSummary, RawRecord, measure_channel, smooth_octave_complex, smoothed,
};
use super::progress::{Step, StepContext};
use kilotouch_dsp::fit::{CoherenceWeighting, FitOptions, Mode, coherence_weights, fit_tf};
use kilotouch_dsp::poly::poly_from_roots;
use kilotouch_dsp::{C64, DspError, Tf};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

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
    /// Zeros moved off the origin to −[`ORIGIN_ZERO_FLOOR`]·ω_lo.
    pub moved_zeros: usize,
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
    /// Lowest frequency of the coherent band (coherence ≥ the minimum), Hz.
    pub coherent_from_hz: f64,
    /// Model magnitude error over the reliable band (smoothed, coherent
    /// bins), dB.
    pub model_error_db: f64,
    /// Fraction of the bins in the reliable band with coherence ≥ the minimum.
    pub coherent_fraction: f64,
    /// Pure delay of the channel beyond the model, s: Ĥ(f) ≈
    /// Ĝ_H(j2πf)·e^{−j2πfτ}. Negative for an advance (a zero-order-hold
    /// simulation read at the end of each step leads by half a sample).
    /// C_H does not invert it; the low channel has the same timing.
    pub delay_s: f64,
    /// Numerator order of the model.
    pub num_order: usize,
    /// Denominator order of the model.
    pub den_order: usize,
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

impl HighChannelId {
    /// Model response including the delay, Ĝ_H(j2πf)·e^{−j2πfτ}, at `f_hz`.
    pub fn response(&self, f_hz: f64) -> C64 {
        self.model.response_hz(f_hz)
            * C64::from_polar(1.0, -2.0 * std::f64::consts::PI * f_hz * self.delay_s)
    }
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
    let tol = a.flat_tol_db;
    let (db, coh) = smoothed(frf, a.smoothing_octaves);
    let range = frf.range(a.f_min_hz, a.f_max_hz);
    let (l, r) = widest_run(&frf.f_hz, range, &db, 2.0 * tol, |i| {
        coh[i] >= a.coherence_min && db[i].is_finite()
    })?;
    let band = &db[l..=r];
    let (lo, hi) = band
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    // Octave width of each bin (the log-frequency measure third-octave
    // bands see).
    let f = &frf.f_hz;
    let width = |i: usize| {
        if i + 1 < f.len() {
            (f[i + 1] / f[i]).log2()
        } else {
            (f[i] / f[i - 1]).log2()
        }
    };
    // Plateau level: the in-band level with the most octaves within ±tol/2
    // of it (refined to their octave-weighted mean), then kept within
    // [hi − tol, lo + tol] so that the whole band stays within ±tol.
    let half = 0.5 * tol;
    let db = &db;
    let near = |g: f64| (l..=r).filter(move |&j| (db[j] - g).abs() <= half);
    let score = |g: f64| near(g).map(width).sum::<f64>();
    let c = (l..=r).max_by(|&x, &y| score(db[x]).total_cmp(&score(db[y])))?;
    let wsum: f64 = near(db[c]).map(width).sum();
    let plateau = near(db[c]).map(|j| width(j) * db[j]).sum::<f64>() / wsum;
    let g0_db = plateau.clamp(hi - tol, lo + tol);
    let dev = band.iter().map(|v| (v - g0_db).abs()).fold(0.0, f64::max);
    Some((l, r, g0_db, dev))
}

/// The low channel's static gain over the part of its flat band at or below
/// `crossover_hz` — where, with a crossover at `crossover_hz`, the low channel carries the
/// signal: the minimax midpoint of the smoothed magnitude over those bins,
/// with the sign of G0_L. Equal to |G0_L|'s band when `crossover_hz` is at or above
/// the flat band's upper edge; G0_L itself when no bin qualifies.
pub fn gain_below(low: &LowChannelId, crossover_hz: f64, cfg: &CalibrationConfig) -> f64 {
    let (db, _) = smoothed(&low.frf, cfg.analysis.smoothing_octaves);
    let [lo, hi] = low.flat_band_hz;
    let r = low.frf.range(lo, hi.min(crossover_hz));
    if r.is_empty() {
        return low.g0;
    }
    let (mn, mx) = db[r]
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    low.g0.signum() * 10f64.powf(0.5 * (mn + mx) / 20.0)
}

/// Step 2: identify the low channel (Pantograph on, Haptuator off).
pub fn identify_low<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    cfg: &CalibrationConfig,
    ctx: &mut StepContext<'_>,
) -> Result<LowChannelId> {
    let step = Step::IdentifyLow;
    ctx.begin(step, "low channel: MLS excitation, Pantograph only")?;
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
    ctx.begin(step, "high channel: MLS excitation, Haptuator only")?;
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

/// Model error of `model` (with delay `delay_s`) against `frf` over
/// `lo..=hi` Hz: the ratio Ĥ/(Ĝ e^{−j2πfτ}) is smoothed (real and imaginary
/// parts, fractional-octave) and 20·log10(1 + max |ratio − 1|) over the bins
/// whose smoothed coherence `coh` reaches the minimum is returned, in dB.
pub fn model_error_db(
    frf: &ChannelFrf,
    model: &Tf,
    delay_s: f64,
    (lo, hi): (f64, f64),
    coh: &[f64],
    cfg: &CalibrationConfig,
) -> f64 {
    let ratio: Vec<C64> = frf
        .f_hz
        .iter()
        .zip(&frf.h)
        .map(|(&f, &h)| h / (model.response_hz(f) * C64::from_polar(1.0, -2.0 * PI * f * delay_s)))
        .collect();
    let w = cfg.analysis.smoothing_octaves;
    let ratio = smooth_octave_complex(&frf.f_hz, &ratio, w);
    let e = frf
        .range(lo, hi)
        .filter(|&i| coh[i] >= cfg.analysis.coherence_min)
        .map(|i| (ratio[i] - 1.0).norm())
        .filter(|e| e.is_finite())
        .fold(0.0, f64::max);
    20.0 * (1.0 + e).log10()
}

/// Zeros of Ĝ_H closer to the origin than this fraction of the lower band
/// edge (as angular frequency) are moved to −that (C_H must invert them):
/// in the band each move changes |Ĝ_H| by at most 10·log10(1 + 1/256) =
/// 0.017 dB and its phase by at most atan(1/16) = 3.6°, decaying as 1/f.
pub const ORIGIN_ZERO_FLOOR: f64 = 1.0 / 16.0;

/// A candidate model of the high channel.
#[derive(Debug, Clone)]
struct Candidate {
    model: Tf,
    /// The model whose error is judged: `model` with the zeros moved to the
    /// floor put back at the origin.
    judged: Tf,
    fit: FitDiagnostics,
}

fn mode_list(r: &[C64]) -> Vec<Mode> {
    let mut m: Vec<Mode> = r
        .iter()
        .filter(|z| z.im > 0.0)
        .map(|z| Mode {
            wn_rad_s: z.norm(),
            wn_hz: z.norm() / (2.0 * PI),
            zeta: -z.re / z.norm(),
        })
        .collect();
    m.sort_by(|a, b| a.wn_rad_s.total_cmp(&b.wn_rad_s));
    m
}

/// Complex fit ([`kilotouch_dsp::fit::fit_tf`]) of (nb, na) over `lo..=hi` Hz
/// of `frf` with the delay `delay_s` removed and `k` zeros at the origin
/// imposed (the data are divided by (j2πf)^k and (nb − k, na) fitted — an
/// inertial actuator's acceleration response has zeros at DC, which a band
/// fit above them cannot place). Right-half-plane zeros are then reflected
/// (same magnitude) and zeros closer to the origin than
/// [`ORIGIN_ZERO_FLOOR`]·ω_lo moved there (C_H must invert them). `Ok(None)`
/// when the data do not determine the model.
fn fit_candidate(
    frf: &ChannelFrf,
    w: &[f64],
    (lo, hi): (f64, f64),
    (nb, na, k): (usize, usize, usize),
    delay_s: f64,
) -> Result<Option<Candidate>> {
    if k > nb {
        return Ok(None);
    }
    let mut data = frf.without_delay(delay_s);
    for (h, &f) in data.h.iter_mut().zip(&frf.f_hz) {
        *h /= C64::new(0.0, 2.0 * PI * f).powu(k as u32);
    }
    let opts = FitOptions {
        fmin_hz: Some(lo),
        fmax_hz: Some(hi),
        enforce_stability: true,
        ..FitOptions::default()
    };
    let fit = match fit_tf(&data.f_hz, &data.h, Some(w), nb - k, na, &opts) {
        Ok(f) => f,
        Err(DspError::Numerical(_) | DspError::InvalidInput(_) | DspError::Degenerate(_)) => {
            return Ok(None);
        }
        Err(e) => return Err(CalibrationError::dsp("fit of Ĝ_H", e)),
    };
    let floor = ORIGIN_ZERO_FLOOR * 2.0 * PI * lo;
    let mut zeros = fit.zeros.clone();
    zeros.extend(std::iter::repeat_n(C64::new(0.0, 0.0), k));
    // `judged`: right-half-plane zeros reflected, zeros near the origin put
    // exactly there; `model`: the same with those zeros at −floor.
    let (mut judged, mut reflected_zeros, mut moved_zeros) = (zeros.clone(), 0, 0);
    for (z, j) in zeros.iter_mut().zip(judged.iter_mut()) {
        if z.norm() < floor {
            *j = C64::new(0.0, 0.0);
            *z = C64::new(-floor, 0.0);
            moved_zeros += 1;
        } else if z.re > 0.0 {
            z.re = -z.re;
            *j = *z;
            reflected_zeros += 1;
        }
    }
    let lead = fit.tf.num[0];
    let model = Tf::new(poly_from_roots(&zeros, lead), fit.tf.den.clone())
        .map_err(|e| CalibrationError::dsp("Ĝ_H", e))?;
    let judged = Tf::new(poly_from_roots(&judged, lead), fit.tf.den.clone())
        .map_err(|e| CalibrationError::dsp("Ĝ_H", e))?;
    Ok(Some(Candidate {
        judged,
        model,
        fit: FitDiagnostics {
            rms_rel_error: fit.rms_rel_error,
            max_mag_dev_db: fit.max_mag_dev_db,
            condition_number: fit.condition_number,
            iterations: fit.iterations,
            converged: fit.converged,
            n_points: fit.n_points,
            reflected_poles: fit.reflected_poles,
            reflected_zeros,
            moved_zeros,
            modes: fit.modes,
            zero_modes: mode_list(&zeros),
        },
    }))
}

/// Step 3's analysis of a measured high-channel FRF: reliable band and fit.
///
/// The lower edge of the fitted band starts at the coherent edge and rises in
/// 1/6-octave steps (keeping at least two octaves); at each edge the
/// configured orders (nb, na), then (nb + 1, na + 1), … up to
/// `max_order_increase` are fitted, and the first model whose error
/// ([`model_error_db`]) is within `model_tol_db` is taken; failing that,
/// the candidate with the smallest error.
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
    let mut f_coh = frf.f_hz[l];
    if let Some(m) = h.min_reliable_hz {
        f_coh = f_coh.max(m);
    }
    let f_hi = h.fit_max_hz;
    if frf.f_hz[r] / f_coh < 2f64.sqrt() {
        return Err(CalibrationError::measurement(
            step,
            format!(
                "the coherent band {:.1}–{:.1} Hz is narrower than half an octave: not enough \
                 to fit Ĝ_H (raise the high-channel amplitude or the number of periods)",
                f_coh, frf.f_hz[r]
            ),
        ));
    }
    let w = coherence_weights(&frf.coherence, CoherenceWeighting::SignalToNoise)
        .map_err(|e| CalibrationError::dsp("coherence weights", e))?;
    // Delay first: the configured orders fitted over the top two octaves with
    // τ on a half-sample grid from −2 to +4 samples, then ±¼ sample around
    // the best; the τ whose fit has the smallest RMS relative error is kept
    // (a rational model cannot absorb a delay).
    let top = ((f_hi / 4.0).max(f_coh), f_hi);
    let err_at = |tau: f64| -> Result<f64> {
        Ok(
            match fit_candidate(&frf, &w, top, (h.num_order, h.den_order, 0), tau)? {
                Some(c) if c.fit.rms_rel_error.is_finite() => c.fit.rms_rel_error,
                _ => f64::INFINITY,
            },
        )
    };
    let ts = 1.0 / frf.fs;
    let mut delay = (0.0, err_at(0.0)?);
    for k in -4..=8 {
        let tau = 0.5 * f64::from(k) * ts;
        let e = err_at(tau)?;
        if e < delay.1 {
            delay = (tau, e);
        }
    }
    for d in [-0.25, 0.25] {
        let tau = delay.0 + d * ts;
        let e = err_at(tau)?;
        if e < delay.1 {
            delay = (tau, e);
        }
    }
    let delay_s = delay.0;
    let mut best: Option<(f64, Candidate, f64)> = None;
    let mut step_k = 0;
    'edges: loop {
        let f_lo = f_coh * 2f64.powf(f64::from(step_k) / 6.0);
        if step_k > 0 && f_lo > f_hi / 4.0 {
            break;
        }
        step_k += 1;
        for extra in 0..=h.max_order_increase {
            let (nb, na) = (h.num_order + extra, h.den_order + extra);
            for &k in &h.origin_zeros {
                let Some(cand) = fit_candidate(&frf, &w, (f_lo, f_hi), (nb, na, k), delay_s)?
                else {
                    continue;
                };
                let err = model_error_db(&frf, &cand.judged, delay_s, (f_lo, f_hi), &coh, cfg);
                if best.as_ref().is_none_or(|b| err < b.2) {
                    best = Some((f_lo, cand, err));
                }
                if err <= h.model_tol_db {
                    break 'edges;
                }
            }
        }
    }
    let (f_lo, cand, model_error_db) =
        best.ok_or_else(|| CalibrationError::measurement(step, "no model of Ĝ_H could be fitted"))?;
    let band = frf.range(f_lo, f_hi);
    let coherent = band
        .clone()
        .filter(|&i| frf.coherence[i] >= a.coherence_min)
        .count();
    let coherent_fraction = coherent as f64 / band.len().max(1) as f64;
    Ok(HighChannelId {
        num_order: cand.model.num_degree(),
        den_order: cand.model.den_degree(),
        model: cand.model,
        reliable_band_hz: [f_lo, f_hi],
        delay_s,
        coherent_from_hz: f_coh,
        model_error_db,
        coherent_fraction,
        fit: cand.fit,
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
            fs: 10_000.0,
        }
    }

    fn grid() -> Vec<f64> {
        (1..=400).map(|k| k as f64 * 10_000.0 / 2048.0).collect()
    }

    /// A channel that is exactly G0 between 40 and 250 Hz and jumps by
    /// 40 dB from bin to bin outside: the flat band and gain are recovered to
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
                C64::new(30.0, 0.0)
            }
        };
        let mut cfg = CalibrationConfig::default();
        cfg.analysis.smoothing_octaves = 0.0;
        let id = low_from_frf(frf_of(&f, g, |_| 0.99), Default::default(), vec![], &cfg).unwrap();
        assert!((id.g0 + 3.0).abs() < 1e-12, "{}", id.g0);
        assert!((id.flat_band_hz[0] - 40.0).abs() < df);
        assert!((id.flat_band_hz[1] - 250.0).abs() < df);
        assert!(id.max_dev_db < 1e-12);
    }

    /// A slope of s dB/octave stays within ±1 dB of a level over 2/s octaves
    /// at most: the band found is that wide (to one bin) and every bin in it
    /// is within ±1 dB of G0.
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

    /// The gain below a crossover is the minimax midpoint of the flat band's
    /// magnitude up to f_c: for a slope of s dB/octave from f_lo, the
    /// magnitude at the geometric mean of f_lo and f_c (to a bin), with the
    /// sign of G0_L; the whole flat band's value for f_c above it.
    #[test]
    fn gain_below_a_crossover_is_the_minimax_midpoint() {
        let f = grid();
        let slope = -1.0;
        let g = |x: f64| C64::new(-10f64.powf(slope * (x / 100.0).log2() / 20.0), 0.0);
        let mut cfg = CalibrationConfig::default();
        cfg.analysis.smoothing_octaves = 0.0;
        cfg.analysis.f_min_hz = 50.0;
        cfg.analysis.f_max_hz = 200.0;
        let id = low_from_frf(frf_of(&f, g, |_| 0.99), Default::default(), vec![], &cfg).unwrap();
        assert!(id.g0 < 0.0);
        let [lo, _] = id.flat_band_hz;
        let fc = 120.0;
        let top = f[f.partition_point(|&x| x <= fc) - 1];
        let want = -10f64.powf(slope * ((lo * top).sqrt() / 100.0).log2() / 20.0);
        let got = gain_below(&id, fc, &cfg);
        assert!((got / want - 1.0).abs() < 1e-12, "{got} vs {want}");
        assert!((gain_below(&id, 1e4, &cfg) / id.g0 - 1.0).abs() < 0.02);
        assert_eq!(gain_below(&id, 1.0, &cfg), id.g0);
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
        cfg.analysis.f_min_hz = 10.0;
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
    /// the fit recovers eq. 2 (docs/REFERENCE-VALUES.md: ω_n = 2135.42 rad/s,
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

    /// A non-minimum-phase channel (eq. 2 with its zero mirrored to
    /// +2560 rad/s), fitted with the paper's orders only: the model is its
    /// minimum-phase reflection (same magnitude) so that C_H can invert it,
    /// and the phase mismatch is reported: at f the two differ by
    /// 2·atan(2πf/2560), |e^{jφ} − 1| = 9.2 dB at 1.2 kHz (a little less after
    /// the 1/12-octave smoothing of the ratio).
    #[test]
    fn rhp_zero_is_reflected() {
        let f = grid();
        let g = Tf::new(vec![-250.0, 6.4e5], vec![1.0, 2135.0, 4.56e6]).unwrap();
        let mut cfg = CalibrationConfig::default();
        cfg.high_fit.max_order_increase = 0;
        cfg.high_fit.origin_zeros = vec![0];
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
        let top = f[f.partition_point(|&x| x <= 1200.0) - 1];
        let phi = 2.0 * (2.0 * PI * top / 2560.0).atan();
        let want = 20.0 * (1.0 + (C64::from_polar(1.0, phi) - 1.0).norm()).log10();
        assert!(
            id.model_error_db > 0.8 * want && id.model_error_db <= want,
            "{} vs {want}",
            id.model_error_db
        );
    }
}
