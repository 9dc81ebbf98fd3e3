//! Continuous-time rational model fitting to frequency-response data.
//!
//! Fits G(s) = B(s)/A(s) with
//!
//! ```text
//! B(s) = b_nb s^nb + … + b_1 s + b_0,
//! A(s) = s^na + a_(na−1) s^(na−1) + … + a_0        (A monic)
//! ```
//!
//! to measured pairs (f_i in Hz, H_i complex) with optional non-negative
//! weights w_i, minimising approximately Σ w_i |B(jω_i)/A(jω_i) − H_i|²,
//! ω_i = 2π f_i (rad/s).
//!
//! Algorithm (see `docs/theory/model-fitting.md`):
//!
//! 1. **Levy (1959)** linearisation: multiply the error by A, giving the linear
//!    least-squares problem Σ w_i |B(jω_i) − H_i A(jω_i)|² in the unknown
//!    coefficients.
//! 2. **Sanathanan–Koerner (1963)** iterations: re-solve with each equation
//!    divided by |A_(k−1)(jω_i)|, the previous denominator, so that at the
//!    fixed point the residual is the true output error B/A − H.
//! 3. **Frequency scaling**: the fit is done in σ = s/ω0 with ω0 the geometric
//!    mean of the band's positive angular frequencies (default), then the
//!    coefficients are unscaled: a_k = α_k ω0^(na−k), b_k = β_k ω0^(na−k).
//! 4. Each complex equation is stacked as two real rows (Re, Im); the real
//!    least-squares problem is column-equilibrated (each column divided by its
//!    2-norm) and solved by SVD (nalgebra). Normal equations are never formed:
//!    they would square the condition number.
//!
//! The reported condition number is σ_max/σ_min of the final, scaled LS matrix.

use crate::{C64, DspError, Result, Tf, poly};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// How the angular-frequency scale ω0 (rad/s) of the fit variable σ = s/ω0 is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum FrequencyScaling {
    /// ω0 = geometric mean of the positive angular frequencies used in the fit
    /// (centres the band on |σ| = 1 in a logarithmic sense). Default.
    GeometricMean,
    /// ω0 = largest angular frequency used in the fit (|σ| ≤ 1).
    Max,
    /// A fixed ω0 in rad/s (must be finite and > 0).
    Fixed(f64),
    /// No frequency scaling, ω0 = 1 rad/s. Only for comparison: powers of
    /// ω reach ω^n and the problem becomes badly scaled.
    None,
}

/// Options of [`fit_tf`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitOptions {
    /// Maximum number of Sanathanan–Koerner iterations after the Levy
    /// initialisation (default 50). 0 returns the plain Levy estimate.
    pub max_iter: usize,
    /// Convergence tolerance on the relative change of the (frequency-scaled)
    /// coefficient vector, ‖θ_k − θ_(k−1)‖₂ ≤ tol·‖θ_k‖₂ (default 1e-10).
    pub tol: f64,
    /// Lower edge of the fitted band in Hz (inclusive); `None` = no lower limit.
    pub fmin_hz: Option<f64>,
    /// Upper edge of the fitted band in Hz (inclusive); `None` = no upper limit.
    pub fmax_hz: Option<f64>,
    /// Choice of the frequency scale ω0 (default: geometric mean).
    pub frequency_scaling: FrequencyScaling,
    /// Divide each LS column by its 2-norm before solving (default true).
    pub column_scaling: bool,
    /// Reflect right-half-plane poles into the left half plane (p → −p̄,
    /// i.e. Re p → −Re p) after the fit (default false). |A(jω)| and hence
    /// the magnitude response are unchanged (the change is an allpass
    /// factor); the phase is not. The number reflected is reported.
    pub enforce_stability: bool,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            max_iter: 50,
            tol: 1e-10,
            fmin_hz: None,
            fmax_hz: None,
            frequency_scaling: FrequencyScaling::GeometricMean,
            column_scaling: true,
            enforce_stability: false,
        }
    }
}

/// A complex-conjugate pair of poles (a resonance) or zeros (an antiresonance),
/// described by its natural frequency and damping ratio:
/// (s − p)(s − p̄) = s² + 2ζω_n s + ω_n².
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Mode {
    /// Natural frequency ω_n = |p| in rad/s.
    pub wn_rad_s: f64,
    /// Natural frequency f_n = ω_n/(2π) in Hz.
    pub wn_hz: f64,
    /// Damping ratio ζ = −Re(p)/|p| (negative for a right-half-plane pair).
    pub zeta: f64,
}

/// Result of [`fit_tf`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitResult {
    /// Fitted model, descending powers of s (rad/s), monic denominator.
    pub tf: Tf,
    /// Poles in rad/s, sorted by real then imaginary part.
    pub poles: Vec<C64>,
    /// Zeros in rad/s, sorted by real then imaginary part.
    pub zeros: Vec<C64>,
    /// Complex pole pairs (resonances), sorted by natural frequency.
    pub modes: Vec<Mode>,
    /// Complex zero pairs (antiresonances), sorted by natural frequency.
    pub zero_modes: Vec<Mode>,
    /// Static gain G(0) = b_0/a_0 (±∞ when the model has a pole at s = 0).
    pub dc_gain: f64,
    /// RMS relative error √(mean |G(jω_i) − H_i|²/|H_i|²) over the points used
    /// in the fit (in band, w_i > 0, H_i ≠ 0); dimensionless.
    pub rms_rel_error: f64,
    /// Maximum relative error max |G(jω_i) − H_i|/|H_i| over the same points.
    pub max_rel_error: f64,
    /// 20·log10(`max_rel_error`): the worst error-to-data ratio in dB
    /// (e.g. −40 dB for 1 %).
    pub max_rel_error_db: f64,
    /// Worst magnitude mismatch max |20·log10(|G(jω_i)|/|H_i|)| in dB.
    pub max_mag_dev_db: f64,
    /// 2-norm condition number σ_max/σ_min of the final least-squares matrix
    /// as solved (after frequency and column scaling, with the SK weights).
    pub condition_number: f64,
    /// Frequency scale ω0 in rad/s used for σ = s/ω0.
    pub omega0_rad_s: f64,
    /// Number of Sanathanan–Koerner iterations performed after the Levy
    /// initialisation.
    pub iterations: usize,
    /// True when the relative coefficient change fell below `tol` within
    /// `max_iter` iterations (always true for na = 0, where the problem is
    /// linear; false for a plain Levy fit, `max_iter = 0`). When false, the
    /// last iterate is returned.
    pub converged: bool,
    /// Number of right-half-plane poles reflected when `enforce_stability` is set.
    pub reflected_poles: usize,
    /// Number of data points used (in band and with positive weight).
    pub n_points: usize,
}

/// Weighting derived from the magnitude-squared coherence γ², for [`coherence_weights`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum CoherenceWeighting {
    /// w = γ²/(1 − γ²): inverse of the relative variance of the H1 estimate,
    /// var(|Ĥ|)/|H|² ≈ (1 − γ²)/(2 n_d γ²) for n_d averages (Bendat &
    /// Piersol, *Random Data*, 4th ed. 2010, random errors of frequency
    /// response estimates). Coherences within 1e-12 of 1 are clamped
    /// (w ≤ ≈1e12).
    SignalToNoise,
    /// w = γ²: a bounded, more conservative weighting.
    Coherence,
}

/// Fit weights from a magnitude-squared coherence γ² ∈ [0, 1].
///
/// Values slightly above 1 from rounding (≤ 1 + 1e-9) are clamped to 1.
/// Errors on non-finite values or values outside [0, 1 + 1e-9].
pub fn coherence_weights(gamma2: &[f64], kind: CoherenceWeighting) -> Result<Vec<f64>> {
    const MAX_GAMMA2: f64 = 1.0 - 1e-12;
    gamma2
        .iter()
        .map(|&g| {
            if !g.is_finite() || !(0.0..=1.0 + 1e-9).contains(&g) {
                return Err(DspError::InvalidParameter {
                    name: "coherence",
                    value: g,
                    reason: "magnitude-squared coherence must be finite and in [0, 1]".into(),
                });
            }
            let g = g.min(1.0);
            Ok(match kind {
                CoherenceWeighting::Coherence => g,
                CoherenceWeighting::SignalToNoise => {
                    let g = g.min(MAX_GAMMA2);
                    g / (1.0 - g)
                }
            })
        })
        .collect()
}

/// One data point prepared for the fit: σ_i = jω_i/ω0, H_i, √w_i.
#[derive(Debug, Clone, Copy)]
struct Point {
    sigma: C64,
    h: C64,
    sqrt_w: f64,
}

/// Solution of one least-squares problem.
#[derive(Debug)]
struct LsSolution {
    x: Vec<f64>,
    cond: f64,
}

/// Fit a continuous-time model B(s)/A(s) of numerator order `nb` and
/// denominator order `na` (A monic) to frequency-response data.
///
/// * `f_hz` — frequencies in Hz (finite, ≥ 0);
/// * `h` — complex response at those frequencies (finite);
/// * `weights` — optional non-negative weights w_i (e.g. from
///   [`coherence_weights`]); points with w_i = 0 are ignored;
/// * `nb ≤ na` (proper model); `na = 0` fits a polynomial B (`nb = na = 0`:
///   a static gain, the weighted mean of Re H).
///
/// Levy (1959) initialisation, Sanathanan–Koerner (1963) iterations, frequency
/// and column scaling, SVD least squares; see the module documentation.
///
/// Errors: mismatched lengths, empty or non-finite data, negative or
/// non-finite weights, negative frequencies, `nb > na`, an empty band, fewer
/// real equations (2 per point) than unknowns (nb + 1 + na), a rank-deficient
/// problem (model order too high for the data: pole–zero cancellation) or a
/// denominator vanishing at a data frequency.
pub fn fit_tf(
    f_hz: &[f64],
    h: &[C64],
    weights: Option<&[f64]>,
    nb: usize,
    na: usize,
    opts: &FitOptions,
) -> Result<FitResult> {
    let points = prepare(f_hz, h, weights, nb, na, opts)?;
    let (omega0, points) = scale_frequencies(points, opts.frequency_scaling);

    let ones = vec![1.0; points.len()];

    // Levy (1959): unweighted by A.
    let mut sol = solve_linearised(&points, &ones, nb, na, opts.column_scaling)?;
    let mut iterations = 0;
    let mut converged = na == 0;

    // Sanathanan–Koerner (1963): divide by |A_(k−1)(σ_i)|.
    if na > 0 {
        for _ in 0..opts.max_iter {
            let a_prev = monic_den(&sol.x[nb + 1..]);
            let inv_a: Vec<f64> = points
                .iter()
                .map(|p| 1.0 / poly::polyval(&a_prev, p.sigma).norm())
                .collect();
            if inv_a.iter().any(|v| !v.is_finite()) {
                return Err(DspError::Numerical(
                    "Sanathanan–Koerner weight is infinite: the denominator estimate vanishes \
                     at a data frequency (pole on the jω axis)"
                        .into(),
                ));
            }
            let next = solve_linearised(&points, &inv_a, nb, na, opts.column_scaling)?;
            iterations += 1;
            let diff = next
                .x
                .iter()
                .zip(&sol.x)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                .sqrt();
            let norm = next.x.iter().map(|a| a * a).sum::<f64>().sqrt();
            sol = next;
            if diff <= opts.tol * norm {
                converged = true;
                break;
            }
        }
    }
    let theta = &sol.x;

    // Scaled coefficients, descending powers of σ.
    let beta: Vec<f64> = theta[..=nb].iter().rev().copied().collect();
    let mut alpha = monic_den(&theta[nb + 1..]);

    let mut reflected_poles = 0;
    if opts.enforce_stability && na > 0 {
        let mut p = poly::roots(&alpha)?;
        for z in p.iter_mut() {
            if z.re > 0.0 {
                z.re = -z.re;
                reflected_poles += 1;
            }
        }
        if reflected_poles > 0 {
            // A_refl/A is allpass on s = jω: |G| is unchanged, only the phase moves.
            alpha = poly::poly_from_roots(&p, 1.0);
        }
    }

    finish(
        &points,
        &beta,
        &alpha,
        omega0,
        FitMeta {
            cond: sol.cond,
            iterations,
            converged,
            reflected_poles,
        },
    )
}

/// Bookkeeping passed to [`finish`].
#[derive(Debug, Clone, Copy)]
struct FitMeta {
    cond: f64,
    iterations: usize,
    converged: bool,
    reflected_poles: usize,
}

/// Validate the inputs and select the points of the band with positive weight.
/// Returned points carry σ = jω (not yet scaled).
fn prepare(
    f_hz: &[f64],
    h: &[C64],
    weights: Option<&[f64]>,
    nb: usize,
    na: usize,
    opts: &FitOptions,
) -> Result<Vec<Point>> {
    check_data(f_hz, h, weights, nb, na)?;
    let band = check_options(opts)?;
    select_points(f_hz, h, weights, nb, na, band)
}

/// The data checks of [`fit_tf`]: lengths, non-empty data, a proper model,
/// finite non-negative frequencies, finite responses and weights.
fn check_data(
    f_hz: &[f64],
    h: &[C64],
    weights: Option<&[f64]>,
    nb: usize,
    na: usize,
) -> Result<()> {
    if f_hz.len() != h.len() {
        return Err(DspError::InvalidInput(format!(
            "frequency and response lengths differ ({} vs {})",
            f_hz.len(),
            h.len()
        )));
    }
    if let Some(w) = weights
        && w.len() != f_hz.len()
    {
        return Err(DspError::InvalidInput(format!(
            "weights length {} differs from data length {}",
            w.len(),
            f_hz.len()
        )));
    }
    if f_hz.is_empty() {
        return Err(DspError::InvalidInput(
            "no frequency-response data to fit".into(),
        ));
    }
    if nb > na {
        return Err(DspError::NotProper {
            num_degree: nb,
            den_degree: na,
        });
    }
    if let Some(i) = f_hz.iter().position(|f| !f.is_finite() || *f < 0.0) {
        return Err(DspError::InvalidInput(format!(
            "frequency #{i} = {} Hz is not a finite non-negative number",
            f_hz[i]
        )));
    }
    if let Some(i) = h.iter().position(|z| !z.is_finite()) {
        return Err(DspError::InvalidInput(format!(
            "response #{i} = {} is not finite",
            h[i]
        )));
    }
    if let Some(w) = weights
        && let Some(i) = w.iter().position(|v| !v.is_finite() || *v < 0.0)
    {
        return Err(DspError::InvalidParameter {
            name: "weights",
            value: w[i],
            reason: format!("weight #{i} must be finite and non-negative"),
        });
    }
    Ok(())
}

/// The option checks of [`fit_tf`]; returns the band [fmin, fmax] in Hz.
fn check_options(opts: &FitOptions) -> Result<(f64, f64)> {
    if !opts.tol.is_finite() || opts.tol < 0.0 {
        return Err(DspError::InvalidParameter {
            name: "tol",
            value: opts.tol,
            reason: "must be finite and non-negative".into(),
        });
    }
    if let FrequencyScaling::Fixed(w0) = opts.frequency_scaling
        && (!w0.is_finite() || w0 <= 0.0)
    {
        return Err(DspError::InvalidParameter {
            name: "omega0",
            value: w0,
            reason: "fixed frequency scale must be finite and > 0 rad/s".into(),
        });
    }
    let fmin = opts.fmin_hz.unwrap_or(0.0);
    let fmax = opts.fmax_hz.unwrap_or(f64::INFINITY);
    if fmin.is_nan() || fmin < 0.0 || fmin.is_infinite() {
        return Err(DspError::InvalidParameter {
            name: "fmin_hz",
            value: fmin,
            reason: "must be finite and non-negative".into(),
        });
    }
    if fmax.is_nan() || fmax < fmin {
        return Err(DspError::InvalidParameter {
            name: "fmax_hz",
            value: fmax,
            reason: format!("must be ≥ fmin_hz = {fmin}"),
        });
    }
    Ok((fmin, fmax))
}

/// The points in `band` = (fmin, fmax) Hz with positive weight, as σ = jω;
/// errors when the band holds no such point, gives fewer real equations
/// (2 per point) than the nb + 1 + na unknowns, or the response vanishes in
/// it.
fn select_points(
    f_hz: &[f64],
    h: &[C64],
    weights: Option<&[f64]>,
    nb: usize,
    na: usize,
    (fmin, fmax): (f64, f64),
) -> Result<Vec<Point>> {
    let in_band = f_hz.iter().filter(|&&f| f >= fmin && f <= fmax).count();
    if in_band == 0 {
        return Err(DspError::InvalidInput(format!(
            "empty band: no data point lies in [{fmin}, {fmax}] Hz (data span {} … {} Hz)",
            f_hz.iter().copied().fold(f64::INFINITY, f64::min),
            f_hz.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        )));
    }
    let points: Vec<Point> = f_hz
        .iter()
        .zip(h)
        .enumerate()
        .filter(|&(_, (&f, _))| f >= fmin && f <= fmax)
        .filter_map(|(i, (&f, &hi))| {
            let w = weights.map_or(1.0, |w| w[i]);
            (w > 0.0).then(|| Point {
                sigma: C64::new(0.0, 2.0 * PI * f),
                h: hi,
                sqrt_w: w.sqrt(),
            })
        })
        .collect();
    let n_unknowns = nb + 1 + na;
    if points.is_empty() {
        return Err(DspError::InvalidInput(format!(
            "all {in_band} points in [{fmin}, {fmax}] Hz have zero weight"
        )));
    }
    // Repeated frequencies add no equation: each distinct frequency gives
    // two real equations (one at DC, where a real-coefficient model is
    // real), so fewer than the unknowns cannot determine the model.
    let mut distinct: Vec<f64> = points.iter().map(|p| p.sigma.im).collect();
    distinct.sort_by(f64::total_cmp);
    distinct.dedup();
    let equations: usize = distinct.iter().map(|&w| if w == 0.0 { 1 } else { 2 }).sum();
    if equations < n_unknowns {
        return Err(DspError::InvalidInput(format!(
            "too few distinct frequencies: {} weighted points in band at {} distinct \
             frequencies give {equations} independent real equations for {n_unknowns} unknowns \
             (nb + 1 + na with nb = {nb}, na = {na}); measure at more frequencies or lower the \
             orders",
            points.len(),
            distinct.len(),
        )));
    }
    if points.iter().all(|p| p.h.norm() == 0.0) {
        return Err(DspError::Degenerate(
            "the response is identically zero in the band".into(),
        ));
    }
    Ok(points)
}

/// Choose ω0 and replace σ = jω by σ = jω/ω0.
fn scale_frequencies(mut points: Vec<Point>, how: FrequencyScaling) -> (f64, Vec<Point>) {
    let positive: Vec<f64> = points
        .iter()
        .map(|p| p.sigma.im)
        .filter(|&w| w > 0.0)
        .collect();
    let omega0 = match how {
        FrequencyScaling::None => 1.0,
        FrequencyScaling::Fixed(w0) => w0,
        FrequencyScaling::Max => positive.iter().copied().fold(0.0, f64::max),
        FrequencyScaling::GeometricMean => {
            if positive.is_empty() {
                0.0
            } else {
                (positive.iter().map(|w| w.ln()).sum::<f64>() / positive.len() as f64).exp()
            }
        }
    };
    // Only DC points: nothing to scale.
    let omega0 = if omega0 > 0.0 && omega0.is_finite() {
        omega0
    } else {
        1.0
    };
    for p in points.iter_mut() {
        p.sigma /= omega0;
    }
    (omega0, points)
}

/// Monic denominator (descending powers) from the ascending free coefficients
/// [α_0, …, α_(na−1)].
fn monic_den(alpha_asc: &[f64]) -> Vec<f64> {
    std::iter::once(1.0)
        .chain(alpha_asc.iter().rev().copied())
        .collect()
}

/// Powers σ^0 … σ^n.
fn powers(sigma: C64, n: usize) -> Vec<C64> {
    let mut out = Vec::with_capacity(n + 1);
    let mut p = C64::new(1.0, 0.0);
    for _ in 0..=n {
        out.push(p);
        p *= sigma;
    }
    out
}

/// Build and solve the linearised (Levy / SK) problem
/// r_i √w_i [Σ_k β_k σ_i^k − H_i Σ_(k<na) α_k σ_i^k − H_i σ_i^na] ≈ 0
/// with extra row factors `r_i` (1 for Levy, 1/|A_(k−1)(σ_i)| for SK).
/// Unknowns θ = [β_0 … β_nb, α_0 … α_(na−1)] (ascending powers).
fn solve_linearised(
    points: &[Point],
    row_factor: &[f64],
    nb: usize,
    na: usize,
    column_scaling: bool,
) -> Result<LsSolution> {
    let n = nb + 1 + na;
    let m = 2 * points.len();
    let mut a = DMatrix::<f64>::zeros(m, n);
    let mut b = DVector::<f64>::zeros(m);
    for (i, (p, &r)) in points.iter().zip(row_factor).enumerate() {
        let g = p.sqrt_w * r;
        let pw = powers(p.sigma, na.max(nb));
        for k in 0..=nb {
            let c = pw[k] * g;
            a[(2 * i, k)] = c.re;
            a[(2 * i + 1, k)] = c.im;
        }
        for k in 0..na {
            let c = -p.h * pw[k] * g;
            a[(2 * i, nb + 1 + k)] = c.re;
            a[(2 * i + 1, nb + 1 + k)] = c.im;
        }
        let rhs = p.h * pw[na] * g;
        b[2 * i] = rhs.re;
        b[2 * i + 1] = rhs.im;
    }
    solve_ls(a, &b, column_scaling)
}

/// Solve min ‖A x − b‖₂ by SVD after (optional) column equilibration
/// D = diag(1/‖a_j‖₂): x = D y, y = argmin ‖(A D) y − b‖₂.
/// Returns the 2-norm condition number of A D.
fn solve_ls(mut a: DMatrix<f64>, b: &DVector<f64>, column_scaling: bool) -> Result<LsSolution> {
    let (m, n) = a.shape();
    let mut d = vec![1.0; n];
    for (j, dj) in d.iter_mut().enumerate() {
        let norm = a.column(j).norm();
        if norm == 0.0 || !norm.is_finite() {
            return Err(DspError::Numerical(format!(
                "least-squares column {j} is {}: the data cannot determine this coefficient",
                if norm == 0.0 { "zero" } else { "not finite" }
            )));
        }
        if column_scaling {
            *dj = 1.0 / norm;
        }
    }
    if column_scaling {
        for (j, &dj) in d.iter().enumerate() {
            a.column_mut(j).scale_mut(dj);
        }
    }
    let svd = nalgebra::SVD::try_new(a, true, true, f64::EPSILON, 10_000).ok_or_else(|| {
        DspError::Numerical("SVD of the least-squares matrix did not converge".into())
    })?;
    let sv = &svd.singular_values;
    let smax = sv.iter().copied().fold(0.0, f64::max);
    let smin = sv.iter().copied().fold(f64::INFINITY, f64::min);
    let threshold = smax * f64::EPSILON * (m.max(n) as f64);
    if smin <= threshold {
        return Err(DspError::Numerical(format!(
            "rank-deficient least-squares problem (condition number {:.3e}): the model order is \
             too high for the data (pole–zero cancellation) or there are too few distinct frequencies",
            smax / smin
        )));
    }
    let y = svd
        .solve(b, threshold)
        .map_err(|e| DspError::Numerical(format!("SVD solve failed: {e}")))?;
    let x: Vec<f64> = y.iter().zip(&d).map(|(yi, di)| yi * di).collect();
    if x.iter().any(|v| !v.is_finite()) {
        return Err(DspError::Numerical(
            "least-squares solution is not finite".into(),
        ));
    }
    Ok(LsSolution {
        x,
        cond: smax / smin,
    })
}

/// Unscale, compute roots, modes and error metrics.
fn finish(
    points: &[Point],
    beta: &[f64],
    alpha: &[f64],
    omega0: f64,
    meta: FitMeta,
) -> Result<FitResult> {
    let na = alpha.len() - 1;
    // beta and alpha are descending: index i has power (len−1−i).
    // b_k = β_k ω0^(na−k), a_k = α_k ω0^(na−k).
    let unscale = |c: &[f64]| -> Vec<f64> {
        let deg = c.len() - 1;
        c.iter()
            .enumerate()
            .map(|(i, &v)| {
                let k = deg - i;
                v * omega0.powi((na - k) as i32)
            })
            .collect()
    };
    let tf = Tf::new(unscale(beta), unscale(alpha))?;

    // Roots in the well-scaled variable σ, then s = ω0 σ.
    let scale_roots = |c: &[f64]| -> Result<Vec<C64>> {
        if poly::degree(c).unwrap_or(0) == 0 {
            return Ok(Vec::new());
        }
        let mut r: Vec<C64> = poly::roots(c)?.into_iter().map(|z| z * omega0).collect();
        poly::sort_roots(&mut r);
        Ok(r)
    };
    let poles = scale_roots(alpha)?;
    let zeros = scale_roots(beta)?;

    // Relative errors evaluated in σ (better scaled than s).
    let mut sum2 = 0.0;
    let mut count = 0usize;
    let mut max_rel: f64 = 0.0;
    let mut max_db: f64 = 0.0;
    for p in points {
        let hn = p.h.norm();
        if hn == 0.0 {
            continue;
        }
        let g = poly::polyval(beta, p.sigma) / poly::polyval(alpha, p.sigma);
        let e = (g - p.h).norm() / hn;
        sum2 += e * e;
        count += 1;
        max_rel = max_rel.max(e);
        max_db = max_db.max((20.0 * (g.norm() / hn).log10()).abs());
    }
    let rms = if count > 0 {
        (sum2 / count as f64).sqrt()
    } else {
        f64::NAN
    };

    Ok(FitResult {
        dc_gain: tf.dc_gain(),
        tf,
        modes: modes(&poles),
        zero_modes: modes(&zeros),
        poles,
        zeros,
        rms_rel_error: rms,
        max_rel_error: max_rel,
        max_rel_error_db: 20.0 * max_rel.log10(),
        max_mag_dev_db: max_db,
        condition_number: meta.cond,
        omega0_rad_s: omega0,
        iterations: meta.iterations,
        converged: meta.converged,
        reflected_poles: meta.reflected_poles,
        n_points: points.len(),
    })
}

/// Natural frequency and damping of the complex roots with Im > 0.
fn modes(roots: &[C64]) -> Vec<Mode> {
    let mut m: Vec<Mode> = roots
        .iter()
        .filter(|z| z.im > 0.0)
        .map(|z| {
            let wn = z.norm();
            Mode {
                wn_rad_s: wn,
                wn_hz: wn / (2.0 * PI),
                zeta: -z.re / wn,
            }
        })
        .collect();
    m.sort_by(|a, b| a.wn_rad_s.total_cmp(&b.wn_rad_s));
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand::rngs::StdRng;
    use rand_distr::{Distribution, Normal};

    /// Paper eq. 2: G_H(s) = (250 s + 6.40e5)/(s² + 2135 s + 4.56e6).
    fn g_h() -> Tf {
        Tf::new(vec![250.0, 6.40e5], vec![1.0, 2135.0, 4.56e6]).unwrap()
    }

    /// The default fit of G_H's exact response at `f` (Hz), order 1/2.
    fn fit_g_h(f: &[f64]) -> FitResult {
        fit_tf(f, &response(&g_h(), f), None, 1, 2, &FitOptions::default()).unwrap()
    }

    fn logspace(f0: f64, f1: f64, n: usize) -> Vec<f64> {
        (0..n)
            .map(|i| f0 * (f1 / f0).powf(i as f64 / (n - 1) as f64))
            .collect()
    }

    fn response(tf: &Tf, f: &[f64]) -> Vec<C64> {
        f.iter().map(|&fi| tf.response_hz(fi)).collect()
    }

    fn rel(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs()
    }

    fn assert_coeffs(got: &Tf, want: &Tf, tol: f64) {
        assert_eq!(got.num.len(), want.num.len(), "{got} vs {want}");
        assert_eq!(got.den.len(), want.den.len(), "{got} vs {want}");
        for (g, w) in got
            .num
            .iter()
            .zip(&want.num)
            .chain(got.den.iter().zip(&want.den))
        {
            assert!(
                rel(*g, *w) <= tol,
                "coefficient {g} vs {w}: {got} vs {want}"
            );
        }
    }

    /// Two-mode 4th-order model like the Pantograph channel (paper Fig. 5):
    /// damped antiresonance just above 200 Hz, damped resonance at 300 Hz,
    /// sharp antiresonance/resonance pair near 800 Hz, DC gain g0.
    fn two_mode(g0: f64) -> Tf {
        let w = |f: f64| 2.0 * PI * f;
        let quad = |f: f64, z: f64| vec![1.0, 2.0 * z * w(f), w(f) * w(f)];
        let mul = |p: &[f64], q: &[f64]| {
            let mut r = vec![0.0; p.len() + q.len() - 1];
            for (i, a) in p.iter().enumerate() {
                for (j, b) in q.iter().enumerate() {
                    r[i + j] += a * b;
                }
            }
            r
        };
        let num = mul(&quad(220.0, 0.15), &quad(780.0, 0.02));
        let den = mul(&quad(300.0, 0.2), &quad(820.0, 0.015));
        // Scale so that G(0) = g0: num(0)/den(0) = (wz1 wz2)²/(wp1 wp2)².
        let k = g0 * den[4] / num[4];
        Tf::new(num.iter().map(|c| c * k).collect(), den).unwrap()
    }

    #[test]
    fn recovers_paper_g_h_from_exact_data() {
        // 200 log-spaced points, 10 Hz – 5 kHz; every coefficient to 1e-6.
        let f = logspace(10.0, 5000.0, 200);
        let h = response(&g_h(), &f);
        let r = fit_tf(&f, &h, None, 1, 2, &FitOptions::default()).unwrap();
        assert!(r.converged);
        assert_coeffs(&r.tf, &g_h(), 1e-6);
        assert_eq!(r.tf.den[0], 1.0, "monic denominator");
        assert!(r.rms_rel_error < 1e-9 && r.max_rel_error < 1e-9);
        assert!(r.max_rel_error_db < -180.0);
        assert!(r.max_mag_dev_db < 1e-7);
        assert_eq!(r.n_points, 200);
        // ω0 = geometric mean of the band: 2π √(10·5000).
        assert!(rel(r.omega0_rad_s, 2.0 * PI * (10.0_f64 * 5000.0).sqrt()) < 1e-12);
    }

    #[test]
    fn g_h_reference_figures() {
        // REFERENCE-VALUES.md: ωn 2135.42 rad/s (339.86 Hz), ζ 0.49990,
        // zero −2560 rad/s (407.44 Hz), DC gain 0.140351.
        let f = logspace(10.0, 5000.0, 200);
        let r = fit_g_h(&f);
        assert_eq!(r.modes.len(), 1);
        let m = r.modes[0];
        assert!((m.wn_rad_s - 2135.42).abs() < 0.005, "{m:?}");
        assert!((m.wn_hz - 339.86).abs() < 0.005, "{m:?}");
        assert!((m.zeta - 0.49990).abs() < 5e-6, "{m:?}");
        // And against the exact formulas ωn = √a0, ζ = a1/(2√a0).
        assert!(rel(m.wn_rad_s, 4.56e6_f64.sqrt()) < 1e-9);
        assert!(rel(m.zeta, 2135.0 / (2.0 * 4.56e6_f64.sqrt())) < 1e-9);
        assert_eq!(r.zeros.len(), 1);
        assert!((r.zeros[0].re + 2560.0).abs() < 1e-6 && r.zeros[0].im == 0.0);
        assert!((r.zeros[0].re.abs() / (2.0 * PI) - 407.44).abs() < 0.005);
        assert!((r.dc_gain - 0.140351).abs() < 5e-7);
        assert!(rel(r.dc_gain, 6.40e5 / 4.56e6) < 1e-9);
        // Poles: the conjugate pair −2135/2 ± j√(4.56e6 − 2135²/4).
        let im = (4.56e6 - 2135.0_f64.powi(2) / 4.0).sqrt();
        assert_eq!(r.poles.len(), 2);
        for p in &r.poles {
            assert!((p.re + 1067.5).abs() < 1e-6 && (p.im.abs() - im).abs() < 1e-6);
        }
    }

    #[test]
    fn recovers_g_h_from_one_percent_noise() {
        // 1 % complex noise: H_i (1 + 0.01 (n1 + j n2)/√2), n ~ N(0, 1).
        let f = logspace(10.0, 5000.0, 200);
        let h0 = response(&g_h(), &f);
        let wn = 4.56e6_f64.sqrt();
        let zeta = 2135.0 / (2.0 * wn);
        let normal = Normal::new(0.0, 0.01 / 2.0_f64.sqrt()).unwrap();
        for seed in [1_u64, 2, 3, 42] {
            let mut rng = StdRng::seed_from_u64(seed);
            let h: Vec<C64> = h0
                .iter()
                .map(|&z| z * C64::new(1.0 + normal.sample(&mut rng), normal.sample(&mut rng)))
                .collect();
            let r = fit_tf(&f, &h, None, 1, 2, &FitOptions::default()).unwrap();
            assert!(r.converged, "seed {seed}");
            assert_coeffs(&r.tf, &g_h(), 0.01);
            let m = r.modes[0];
            assert!(rel(m.wn_rad_s, wn) < 0.01, "seed {seed}: {m:?}");
            assert!(rel(m.zeta, zeta) < 0.01, "seed {seed}: {m:?}");
            assert!(rel(r.dc_gain, 6.40e5 / 4.56e6) < 0.01, "seed {seed}");
            // The residual is the noise: rms ≈ 1 %.
            assert!(
                r.rms_rel_error > 0.007 && r.rms_rel_error < 0.013,
                "{}",
                r.rms_rel_error
            );
        }
    }

    /// The plain Levy matrix in s (rad/s), without frequency or column
    /// scaling: columns s^k (k ≤ nb) and −H s^k (k < na), Re/Im rows.
    fn raw_levy_matrix(f: &[f64], h: &[C64], nb: usize, na: usize) -> DMatrix<f64> {
        let n = nb + 1 + na;
        let mut a = DMatrix::<f64>::zeros(2 * f.len(), n);
        for (i, (&fi, &hi)) in f.iter().zip(h).enumerate() {
            let s = C64::new(0.0, 2.0 * PI * fi);
            for k in 0..=nb {
                let c = s.powu(k as u32);
                a[(2 * i, k)] = c.re;
                a[(2 * i + 1, k)] = c.im;
            }
            for k in 0..na {
                let c = -hi * s.powu(k as u32);
                a[(2 * i, nb + 1 + k)] = c.re;
                a[(2 * i + 1, nb + 1 + k)] = c.im;
            }
        }
        a
    }

    /// Lower bound on the 2-norm condition number that needs no SVD:
    /// σ_max ≥ max_j ‖a_j‖ and σ_min ≤ min_j ‖a_j‖ (a_j = A e_j).
    fn column_norm_ratio(a: &DMatrix<f64>) -> f64 {
        let norms: Vec<f64> = a.column_iter().map(|c| c.norm()).collect();
        norms.iter().copied().fold(0.0, f64::max)
            / norms.iter().copied().fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn wide_band_identification_is_well_conditioned_by_scaling() {
        // 1 Hz – 5 kHz. For exact data the coefficient error is about cond·ε
        // (ε = 2.2e-16), so the 1e-6 requirement needs cond ≲ 4.5e9. We ask
        // for cond < 1e4: at least 12 digits left, and with noise the
        // perturbation is amplified by less than 1e4.
        let f = logspace(1.0, 5000.0, 300);
        let h = response(&g_h(), &f);
        let r = fit_tf(&f, &h, None, 1, 2, &FitOptions::default()).unwrap();
        assert!(r.condition_number.is_finite() && r.condition_number >= 1.0);
        assert!(r.condition_number < 1e4, "cond {}", r.condition_number);
        assert_coeffs(&r.tf, &g_h(), 1e-6);
        // Unscaled Levy matrix in s: columns 1, s, −H, −H s, with |s| up to
        // 3.1e4 rad/s; its condition number is at least the column-norm ratio.
        let raw = raw_levy_matrix(&f, &h, 1, 2);
        let raw_bound = column_norm_ratio(&raw);
        let sv = raw.singular_values();
        let raw_cond = sv.max() / sv.min();
        assert!(raw_cond >= raw_bound * (1.0 - 1e-12));
        assert!(raw_bound > 1e4, "raw bound {raw_bound}");
        assert!(
            raw_cond > 100.0 * r.condition_number,
            "raw {raw_cond} vs {}",
            r.condition_number
        );

        // 4th-order two-mode system over the same band: s^4 reaches 6e17.
        let g = two_mode(1.0);
        let h4 = response(&g, &f);
        let r4 = fit_tf(&f, &h4, None, 4, 4, &FitOptions::default()).unwrap();
        assert!(r4.condition_number < 1e4, "cond {}", r4.condition_number);
        assert_coeffs(&r4.tf, &g, 1e-6);
        let raw4 = raw_levy_matrix(&f, &h4, 4, 4);
        assert!(
            column_norm_ratio(&raw4) > 1e17,
            "{}",
            column_norm_ratio(&raw4)
        );
        // Numerically singular in f64 without scaling: the same fit through
        // the API with both scalings off is rejected as rank-deficient.
        let unscaled = FitOptions {
            frequency_scaling: FrequencyScaling::None,
            column_scaling: false,
            ..Default::default()
        };
        let e = fit_tf(&f, &h4, None, 4, 4, &unscaled).unwrap_err();
        assert!(e.to_string().contains("rank-deficient"), "{e}");
        // Frequency scaling alone already makes it solvable.
        let freq_only = FitOptions {
            column_scaling: false,
            ..Default::default()
        };
        let rf = fit_tf(&f, &h4, None, 4, 4, &freq_only).unwrap();
        assert!(rf.condition_number < 1e8, "{}", rf.condition_number);
        assert_coeffs(&rf.tf, &g, 1e-6);
    }

    #[test]
    fn recovers_fourth_order_two_mode_system() {
        let g = two_mode(0.8);
        let f = logspace(1.0, 5000.0, 400);
        let r = fit_tf(&f, &response(&g, &f), None, 4, 4, &FitOptions::default()).unwrap();
        assert!(r.converged);
        assert_coeffs(&r.tf, &g, 1e-6);
        // Modes (ascending ωn): 300 Hz ζ 0.2, 820 Hz ζ 0.015.
        assert_eq!(r.modes.len(), 2);
        for (m, (fn_, z)) in r.modes.iter().zip([(300.0, 0.2), (820.0, 0.015)]) {
            assert!(rel(m.wn_hz, fn_) < 1e-8 && rel(m.zeta, z) < 1e-7, "{m:?}");
        }
        assert_eq!(r.zero_modes.len(), 2);
        for (m, (fn_, z)) in r.zero_modes.iter().zip([(220.0, 0.15), (780.0, 0.02)]) {
            assert!(rel(m.wn_hz, fn_) < 1e-8 && rel(m.zeta, z) < 1e-7, "{m:?}");
        }
        assert!(rel(r.dc_gain, 0.8) < 1e-9);
    }

    #[test]
    fn sk_iterations_remove_levy_bias() {
        // With noise, plain Levy (max_iter = 0) weights high frequencies by
        // |A|² and is biased; SK reduces the output error.
        let f = logspace(10.0, 5000.0, 200);
        let normal = Normal::new(0.0, 0.02).unwrap();
        let mut rng = StdRng::seed_from_u64(7);
        let h: Vec<C64> = response(&g_h(), &f)
            .iter()
            .map(|&z| z * C64::new(1.0 + normal.sample(&mut rng), normal.sample(&mut rng)))
            .collect();
        let levy = fit_tf(
            &f,
            &h,
            None,
            1,
            2,
            &FitOptions {
                max_iter: 0,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(levy.iterations, 0);
        assert!(!levy.converged);
        let sk = fit_tf(&f, &h, None, 1, 2, &FitOptions::default()).unwrap();
        assert!(sk.converged && sk.iterations >= 2);
        assert!(sk.rms_rel_error < levy.rms_rel_error);
    }

    #[test]
    fn weights_reject_corrupted_points() {
        let f = logspace(10.0, 5000.0, 200);
        let mut h = response(&g_h(), &f);
        // Corrupt 12 points (e.g. mains pick-up, saturation) by a factor 3 and 40° phase.
        let bad: Vec<usize> = (0..12).map(|k| 20 + 13 * k).collect();
        for &i in &bad {
            h[i] *= C64::from_polar(3.0, 40f64.to_radians());
        }
        let unweighted = fit_tf(&f, &h, None, 1, 2, &FitOptions::default()).unwrap();
        let worst = unweighted
            .tf
            .num
            .iter()
            .zip(&g_h().num)
            .chain(unweighted.tf.den.iter().zip(&g_h().den))
            .map(|(a, b)| rel(*a, *b))
            .fold(0.0, f64::max);
        assert!(
            worst > 0.05,
            "corruption should bias the unweighted fit: {worst}"
        );

        // Coherence-derived weights: γ² = 0.999 on good points, 0.01 on bad ones;
        // SNR weighting γ²/(1−γ²) = 999 vs 0.0101.
        let mut gamma2 = vec![0.999; f.len()];
        for &i in &bad {
            gamma2[i] = 0.01;
        }
        let w = coherence_weights(&gamma2, CoherenceWeighting::SignalToNoise).unwrap();
        assert!(rel(w[0], 0.999 / 0.001) < 1e-9 && rel(w[bad[0]], 0.01 / 0.99) < 1e-12);
        let weighted = fit_tf(&f, &h, Some(&w), 1, 2, &FitOptions::default()).unwrap();
        assert_coeffs(&weighted.tf, &g_h(), 2e-3);

        // Zero weight excludes the points entirely: exact recovery.
        let mut w0 = vec![1.0; f.len()];
        for &i in &bad {
            w0[i] = 0.0;
        }
        let excluded = fit_tf(&f, &h, Some(&w0), 1, 2, &FitOptions::default()).unwrap();
        assert_coeffs(&excluded.tf, &g_h(), 1e-6);
        assert_eq!(excluded.n_points, 200 - bad.len());
    }

    #[test]
    fn band_limits_select_the_fitted_points() {
        // Below 100 Hz the paper's Haptuator data were unreliable (saturation):
        // replace them with garbage and fit only 100 Hz – 5 kHz.
        let f = logspace(10.0, 5000.0, 200);
        let mut h = response(&g_h(), &f);
        for (fi, hi) in f.iter().zip(h.iter_mut()) {
            if *fi < 100.0 {
                *hi = C64::new(5.0, -3.0);
            }
        }
        let opts = FitOptions {
            fmin_hz: Some(100.0),
            fmax_hz: Some(5000.0),
            ..Default::default()
        };
        let r = fit_tf(&f, &h, None, 1, 2, &opts).unwrap();
        assert_coeffs(&r.tf, &g_h(), 1e-6);
        assert_eq!(r.n_points, f.iter().filter(|&&x| x >= 100.0).count());
    }

    #[test]
    fn frequency_scaling_variants_agree_on_exact_data() {
        let f = logspace(10.0, 5000.0, 200);
        let h = response(&g_h(), &f);
        for fs in [
            FrequencyScaling::Max,
            FrequencyScaling::Fixed(2000.0),
            FrequencyScaling::None,
        ] {
            let r = fit_tf(
                &f,
                &h,
                None,
                1,
                2,
                &FitOptions {
                    frequency_scaling: fs,
                    ..Default::default()
                },
            )
            .unwrap();
            assert_coeffs(&r.tf, &g_h(), 1e-6);
        }
        let r = fit_tf(
            &f,
            &h,
            None,
            1,
            2,
            &FitOptions {
                frequency_scaling: FrequencyScaling::Max,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(rel(r.omega0_rad_s, 2.0 * PI * 5000.0) < 1e-12);
    }

    #[test]
    fn static_gain_and_polynomial_models() {
        // nb = na = 0: weighted mean of Re H (the paper's Ĝ_L ≈ G0_L).
        let f = logspace(1.0, 200.0, 50);
        let h: Vec<C64> = f
            .iter()
            .enumerate()
            .map(|(i, _)| C64::new(2.0 + if i % 2 == 0 { 0.1 } else { -0.1 }, 0.05))
            .collect();
        let r = fit_tf(&f, &h, None, 0, 0, &FitOptions::default()).unwrap();
        let mean_re = h.iter().map(|z| z.re).sum::<f64>() / h.len() as f64;
        assert!(rel(r.dc_gain, mean_re) < 1e-12);
        assert!(r.converged && r.iterations == 0 && r.poles.is_empty());
    }

    #[test]
    fn first_order_system_recovered() {
        // G(s) = 1/(s/ωc + 1), ωc = 2π·50: monic form ωc/(s + ωc).
        let wc = 2.0 * PI * 50.0;
        let g = Tf::new(vec![wc], vec![1.0, wc]).unwrap();
        let f = logspace(0.1, 1e4, 100);
        let r = fit_tf(&f, &response(&g, &f), None, 0, 1, &FitOptions::default()).unwrap();
        assert_coeffs(&r.tf, &g, 1e-9);
        assert!(r.modes.is_empty());
        assert!(rel(r.poles[0].re, -wc) < 1e-9);
    }

    #[test]
    fn dc_point_and_integrating_model() {
        // Data including f = 0 (excluded from the geometric mean): G_H again.
        let mut f = vec![0.0];
        f.extend(logspace(10.0, 5000.0, 100));
        let r = fit_g_h(&f);
        assert_coeffs(&r.tf, &g_h(), 1e-8);
        assert!(rel(r.omega0_rad_s, 2.0 * PI * (10.0_f64 * 5000.0).sqrt()) < 1e-12);
        // A pole at the origin: G(s) = 1e4/(s (s + 300)), 0.1 Hz – 1 kHz.
        let g = Tf::new(vec![1e4], vec![1.0, 300.0, 0.0]).unwrap();
        let f = logspace(0.1, 1000.0, 150);
        let r = fit_tf(&f, &response(&g, &f), None, 0, 2, &FitOptions::default()).unwrap();
        assert!(rel(r.tf.num[0], 1e4) < 1e-8 && rel(r.tf.den[1], 300.0) < 1e-8);
        // a_0 = 0 to rounding relative to the scale ω0² of the σ problem.
        assert!(
            r.tf.den[2].abs() < 1e-9 * r.omega0_rad_s.powi(2),
            "{}",
            r.tf
        );
        assert!(r.dc_gain.abs() > 1e6);
        assert!(r.poles.iter().any(|p| p.norm() < 1e-6 * r.omega0_rad_s));
    }

    #[test]
    fn enforce_stability_reflects_unstable_poles() {
        // An unstable resonance has the same |G| as its reflection; the fit
        // recovers it as is, and with enforce_stability reports one pair
        // reflected and a stable model.
        let wn = 2.0 * PI * 300.0;
        let g = Tf::new(vec![wn * wn], vec![1.0, -0.2 * wn, wn * wn]).unwrap();
        let f = logspace(10.0, 3000.0, 200);
        let h = response(&g, &f);
        let free = fit_tf(&f, &h, None, 0, 2, &FitOptions::default()).unwrap();
        assert_coeffs(&free.tf, &g, 1e-8);
        assert_eq!(free.reflected_poles, 0);
        assert!(free.modes[0].zeta < 0.0);
        let stable = fit_tf(
            &f,
            &h,
            None,
            0,
            2,
            &FitOptions {
                enforce_stability: true,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(stable.reflected_poles, 2);
        assert!(stable.tf.is_stable().unwrap());
        assert!(rel(stable.tf.den[1], 0.2 * wn) < 1e-8);
        assert!(rel(stable.modes[0].zeta, 0.1) < 1e-8);
        // Same magnitude response: |G(jω)| equal, so the dB mismatch vanishes.
        assert!(stable.max_mag_dev_db < 1e-8);
    }

    #[test]
    fn invalid_inputs_are_rejected_with_clear_errors() {
        let f = logspace(10.0, 5000.0, 20);
        let h = response(&g_h(), &f);
        let o = FitOptions::default();
        // Length mismatch.
        assert!(matches!(
            fit_tf(&f[..5], &h, None, 1, 2, &o),
            Err(DspError::InvalidInput(_))
        ));
        // Empty data.
        assert!(fit_tf(&[], &[], None, 1, 2, &o).is_err());
        // Improper model.
        assert!(matches!(
            fit_tf(&f, &h, None, 3, 2, &o),
            Err(DspError::NotProper { .. })
        ));
        // Non-finite data.
        let mut hn = h.clone();
        hn[3] = C64::new(f64::NAN, 0.0);
        assert!(matches!(
            fit_tf(&f, &hn, None, 1, 2, &o),
            Err(DspError::InvalidInput(_))
        ));
        hn[3] = C64::new(0.0, f64::INFINITY);
        assert!(fit_tf(&f, &hn, None, 1, 2, &o).is_err());
        let mut fnan = f.clone();
        fnan[0] = f64::NAN;
        assert!(fit_tf(&fnan, &h, None, 1, 2, &o).is_err());
        fnan[0] = -1.0;
        assert!(fit_tf(&fnan, &h, None, 1, 2, &o).is_err());
        // Negative or NaN weight.
        let mut w = vec![1.0; f.len()];
        w[2] = -0.5;
        let e = fit_tf(&f, &h, Some(&w), 1, 2, &o).unwrap_err();
        assert!(matches!(
            e,
            DspError::InvalidParameter {
                name: "weights",
                ..
            }
        ));
        assert!(e.to_string().contains("non-negative"));
        w[2] = f64::NAN;
        assert!(fit_tf(&f, &h, Some(&w), 1, 2, &o).is_err());
        assert!(fit_tf(&f, &h, Some(&w[..3]), 1, 2, &o).is_err());
        // All-zero weights.
        assert!(fit_tf(&f, &h, Some(&vec![0.0; f.len()]), 1, 2, &o).is_err());
        // Empty band.
        let band = FitOptions {
            fmin_hz: Some(6000.0),
            fmax_hz: Some(7000.0),
            ..Default::default()
        };
        let e = fit_tf(&f, &h, None, 1, 2, &band).unwrap_err();
        assert!(e.to_string().contains("empty band"), "{e}");
        // fmax < fmin.
        let bad_band = FitOptions {
            fmin_hz: Some(100.0),
            fmax_hz: Some(50.0),
            ..Default::default()
        };
        assert!(fit_tf(&f, &h, None, 1, 2, &bad_band).is_err());
        // Too few points: 1 point = 2 equations for 4 unknowns.
        let e = fit_tf(&f[..1], &h[..1], None, 1, 2, &o).unwrap_err();
        assert!(
            e.to_string().contains("too few distinct frequencies"),
            "{e}"
        );
        // Many points at one frequency are still 2 equations: refused, not
        // a "converged" fit through one point.
        let one_f = vec![f[3]; 50];
        let one_h = vec![h[3]; 50];
        let e = fit_tf(&one_f, &one_h, None, 1, 2, &o).unwrap_err();
        assert!(
            e.to_string()
                .contains("50 weighted points in band at 1 distinct frequencies"),
            "{e}"
        );
        // Two distinct frequencies (4 equations) determine nb = 1, na = 2.
        let two_f: Vec<f64> = (0..40).map(|i| f[3 + 5 * (i % 2)]).collect();
        let two_h: Vec<C64> = (0..40).map(|i| h[3 + 5 * (i % 2)]).collect();
        assert!(fit_tf(&two_f, &two_h, None, 1, 2, &o).is_ok());
        // DC gives one equation only: DC plus one frequency is 3 < 4.
        let dc_f = [0.0, f[3]];
        let dc_h = [C64::new(1.0, 0.0), h[3]];
        let e = fit_tf(&dc_f, &dc_h, None, 1, 2, &o).unwrap_err();
        assert!(
            e.to_string().contains("3 independent real equations"),
            "{e}"
        );
        // Bad options.
        let bad_tol = FitOptions {
            tol: f64::NAN,
            ..Default::default()
        };
        assert!(fit_tf(&f, &h, None, 1, 2, &bad_tol).is_err());
        let bad_w0 = FitOptions {
            frequency_scaling: FrequencyScaling::Fixed(0.0),
            ..Default::default()
        };
        assert!(fit_tf(&f, &h, None, 1, 2, &bad_w0).is_err());
        // Identically zero response.
        let z = vec![C64::new(0.0, 0.0); f.len()];
        assert!(fit_tf(&f, &z, None, 1, 2, &o).is_err());
    }

    #[test]
    fn over_parameterised_exact_fit_is_reported_rank_deficient() {
        // A 2nd-order system fitted with (nb, na) = (2, 3) from exact data has
        // a one-parameter family of solutions (common factor): SVD detects it.
        let f = logspace(10.0, 5000.0, 200);
        let h = response(&g_h(), &f);
        let e = fit_tf(&f, &h, None, 2, 3, &FitOptions::default()).unwrap_err();
        assert!(e.to_string().contains("rank-deficient"), "{e}");
    }

    #[test]
    fn coherence_weights_validate_and_clamp() {
        let w = coherence_weights(&[0.0, 0.5, 1.0], CoherenceWeighting::SignalToNoise).unwrap();
        assert_eq!(w[0], 0.0);
        assert!(rel(w[1], 1.0) < 1e-15);
        assert!(w[2].is_finite() && w[2] > 1e11);
        let c = coherence_weights(&[0.25, 1.0 + 1e-12], CoherenceWeighting::Coherence).unwrap();
        assert_eq!(c, vec![0.25, 1.0]);
        assert!(coherence_weights(&[1.1], CoherenceWeighting::Coherence).is_err());
        assert!(coherence_weights(&[-0.1], CoherenceWeighting::Coherence).is_err());
        assert!(coherence_weights(&[f64::NAN], CoherenceWeighting::SignalToNoise).is_err());
    }
}
