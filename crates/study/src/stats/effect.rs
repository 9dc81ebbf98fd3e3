//! Confidence intervals of effect sizes.
//!
//! * η² and partial η² of an F test: the noncentral-F interval (Steiger
//!   2004, "Beyond the F test", Psychol. Methods 9:164). The noncentrality
//!   λ whose F(df1, df2, λ) puts the observed F at its 97.5 % and 2.5 %
//!   quantiles bounds λ; each bound converts to η²_p = λ / (λ + df1 + df2 + 1)
//!   (as R's `effectsize::F_to_eta2`, `alternative = "two.sided"`). The
//!   noncentral F CDF is the Poisson mixture of regularised incomplete beta
//!   functions (Johnson, Kotz & Balakrishnan 1995, eq. 30.5), summed outward
//!   from the Poisson mode so that large λ do not underflow.
//! * Kendall's W: percentile bootstrap over participants (rows of the cell
//!   matrix resampled with replacement, [`BOOTSTRAP_RESAMPLES`] resamples,
//!   fixed seed [`BOOTSTRAP_SEED`], so a result is reproducible).
//! * Cohen's d_z: the large-sample normal interval
//!   d_z ± z₀.₉₇₅ √(1/n + d_z²/(2n)) (Hedges & Olkin 1985, ch. 5).

use statrs::function::{beta, gamma};

use super::error::{Result, StatsError};

/// Coverage of every interval of this module.
pub const CONFIDENCE: f64 = 0.95;
/// Bootstrap resamples of Kendall's W interval ([`super::Friedman::kendall_w_ci`]).
pub const BOOTSTRAP_RESAMPLES: usize = 2000;
/// Seed of the bootstrap generator (ChaCha8).
pub const BOOTSTRAP_SEED: u64 = 0x6b69_6c6f_746f_7563;
/// z₀.₉₇₅ of the standard normal distribution.
const Z975: f64 = 1.959_963_984_540_054;

fn numerical(what: &'static str, detail: String) -> StatsError {
    StatsError::Numerical { what, detail }
}

/// CDF P(F' ≤ f) of the noncentral F distribution F'(d1, d2, λ).
///
/// # Errors
/// Non-positive degrees of freedom, negative or non-finite λ, NaN f.
pub fn ncf_cdf(f: f64, d1: f64, d2: f64, lambda: f64) -> Result<f64> {
    const WHAT: &str = "noncentral F distribution";
    if !(d1 > 0.0 && d2 > 0.0 && d1.is_finite() && d2.is_finite()) {
        return Err(numerical(WHAT, format!("degrees of freedom {d1}, {d2}")));
    }
    if !(lambda >= 0.0 && lambda.is_finite()) || f.is_nan() {
        return Err(numerical(WHAT, format!("λ = {lambda}, F = {f}")));
    }
    if f <= 0.0 {
        return Ok(0.0);
    }
    if f.is_infinite() {
        return Ok(1.0);
    }
    let x = d1 * f / (d1 * f + d2);
    let half = lambda / 2.0;
    let term = |j: f64| -> Result<f64> {
        let lw = if half > 0.0 {
            -half + j * half.ln() - gamma::ln_gamma(j + 1.0)
        } else if j == 0.0 {
            0.0
        } else {
            return Ok(0.0);
        };
        let ib = beta::checked_beta_reg(d1 / 2.0 + j, d2 / 2.0, x)
            .map_err(|e| numerical(WHAT, e.to_string()))?;
        Ok(lw.exp() * ib)
    };
    // Poisson weights summed from the mode outward; 1e6 terms bound the
    // work (λ up to ~1e11 would need more: reported, not truncated).
    const MAX_TERMS: usize = 1_000_000;
    let mode = half.floor();
    let mut sum = term(mode)?;
    let mut weight_seen = 0.0_f64;
    let pois = |j: f64| {
        if half > 0.0 {
            (-half + j * half.ln() - gamma::ln_gamma(j + 1.0)).exp()
        } else if j == 0.0 {
            1.0
        } else {
            0.0
        }
    };
    weight_seen += pois(mode);
    let mut j = mode + 1.0;
    let mut down = mode - 1.0;
    for _ in 0..MAX_TERMS {
        let mut progressed = false;
        let wu = pois(j);
        if wu > 1e-18 {
            sum += term(j)?;
            weight_seen += wu;
            j += 1.0;
            progressed = true;
        }
        if down >= 0.0 {
            let wd = pois(down);
            if wd > 1e-18 {
                sum += term(down)?;
                weight_seen += wd;
                down -= 1.0;
                progressed = true;
            } else {
                down = -1.0;
            }
        }
        if !progressed || weight_seen >= 1.0 - 1e-15 {
            return Ok(sum.clamp(0.0, 1.0));
        }
    }
    Err(numerical(
        WHAT,
        format!("λ = {lambda} needs more than {MAX_TERMS} terms"),
    ))
}

/// λ with P(F' ≤ `f_obs` | λ) = `target` (the CDF falls as λ grows); 0
/// when even λ = 0 leaves the CDF below `target`.
fn solve_lambda(f_obs: f64, d1: f64, d2: f64, target: f64) -> Result<f64> {
    let g = |l: f64| ncf_cdf(f_obs, d1, d2, l).map(|c| c - target);
    if g(0.0)? <= 0.0 {
        return Ok(0.0);
    }
    let mut hi = (f_obs * d1).max(1.0);
    let mut tries = 0;
    while g(hi)? > 0.0 {
        hi *= 2.0;
        tries += 1;
        if tries > 60 {
            return Err(numerical(
                "η² confidence interval",
                format!("no noncentrality bracket for F = {f_obs}"),
            ));
        }
    }
    let mut lo = 0.0_f64;
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if g(mid)? > 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo <= 1e-12 * hi.max(1.0) {
            break;
        }
    }
    Ok(0.5 * (lo + hi))
}

/// Two-sided [`CONFIDENCE`] interval of (partial) η² from an observed F
/// with (`df1`, `df2`) degrees of freedom (module documentation).
///
/// # Errors
/// Non-finite or negative F, bad degrees of freedom.
pub fn eta2_ci_from_f(f: f64, df1: f64, df2: f64) -> Result<[f64; 2]> {
    if !(f.is_finite() && f >= 0.0) {
        return Err(numerical(
            "η² confidence interval",
            format!("F = {f} is not a finite non-negative number"),
        ));
    }
    let alpha = 1.0 - CONFIDENCE;
    let l_lo = solve_lambda(f, df1, df2, 1.0 - alpha / 2.0)?;
    let l_hi = solve_lambda(f, df1, df2, alpha / 2.0)?;
    let eta = |l: f64| l / (l + df1 + df2 + 1.0);
    Ok([eta(l_lo), eta(l_hi)])
}

/// [`CONFIDENCE`] interval of Cohen's d_z from n pairs (module
/// documentation).
pub fn dz_ci(dz: f64, n: usize) -> [f64; 2] {
    let nf = n as f64;
    let se = (1.0 / nf + dz * dz / (2.0 * nf)).sqrt();
    [dz - Z975 * se, dz + Z975 * se]
}

/// Linear-interpolation quantile of sorted data (type 7, numpy's and
/// pandas' default).
pub(crate) fn quantile_sorted(sorted: &[f64], q: f64) -> f64 {
    let n = sorted.len();
    if n == 0 {
        return f64::NAN;
    }
    let h = (n - 1) as f64 * q;
    let lo = h.floor() as usize;
    let hi = h.ceil() as usize;
    sorted[lo] + (h - lo as f64) * (sorted[hi.min(n - 1)] - sorted[lo])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn central_limit_is_the_f_distribution() {
        // λ = 0: the noncentral F is Fisher's F.
        for &(f, d1, d2) in &[(0.5, 2.0, 8.0), (2.15, 2.0, 8.0), (10.0, 3.0, 30.0)] {
            let c = ncf_cdf(f, d1, d2, 0.0).unwrap();
            let sf = super::super::dist::f_sf(f, d1, d2).unwrap();
            assert!((c + sf - 1.0).abs() < 1e-13, "{c} {sf}");
        }
        assert_eq!(ncf_cdf(0.0, 2.0, 3.0, 5.0).unwrap(), 0.0);
        assert!(ncf_cdf(1.0, 2.0, 3.0, -1.0).is_err());
        // The CDF falls with λ; a huge λ still sums (no underflow).
        let a = ncf_cdf(3.0, 2.0, 20.0, 1.0).unwrap();
        let b = ncf_cdf(3.0, 2.0, 20.0, 10.0).unwrap();
        assert!(a > b);
        let c = ncf_cdf(500.0, 2.0, 2000.0, 1000.0).unwrap();
        assert!(c > 0.0 && c < 1.0, "{c}");
    }

    #[test]
    fn quantiles_interpolate_linearly() {
        let s = [1.0, 2.0, 4.0, 8.0];
        assert_eq!(quantile_sorted(&s, 0.0), 1.0);
        assert_eq!(quantile_sorted(&s, 1.0), 8.0);
        assert!((quantile_sorted(&s, 0.25) - 1.75).abs() < 1e-15);
        assert!((quantile_sorted(&s, 0.5) - 3.0).abs() < 1e-15);
    }
}
