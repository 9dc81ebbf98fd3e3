//! Real polynomials in descending powers: evaluation and roots.
//!
//! Coefficients are stored highest power first, as in numpy/scipy:
//! `p = [a_n, …, a_1, a_0]` means a_n xⁿ + … + a_0.
//!
//! Roots are the eigenvalues of the (balanced) companion matrix, computed with
//! nalgebra's real Schur decomposition and polished by Newton steps. This is
//! numpy's `roots` method; it is backward stable for the moderate degrees used
//! here (≤ 16). High-order filters are never represented as expanded
//! polynomials in this crate: they live as second-order sections or zpk.

use crate::{C64, DspError, Result};
use nalgebra::DMatrix;

/// Remove leading zeros (exact zeros only). Returns an empty slice for the zero polynomial.
pub fn trim_leading_zeros(p: &[f64]) -> &[f64] {
    let first = p.iter().position(|&c| c != 0.0).unwrap_or(p.len());
    &p[first..]
}

/// Degree of a polynomial after trimming leading zeros (`None` for the zero polynomial).
pub fn degree(p: &[f64]) -> Option<usize> {
    let t = trim_leading_zeros(p);
    if t.is_empty() {
        None
    } else {
        Some(t.len() - 1)
    }
}

/// Evaluate a real polynomial at a complex point (Horner's rule).
pub fn polyval(p: &[f64], x: C64) -> C64 {
    p.iter().fold(C64::new(0.0, 0.0), |acc, &c| acc * x + c)
}

/// Evaluate a real polynomial at a real point (Horner's rule).
pub fn polyval_real(p: &[f64], x: f64) -> f64 {
    p.iter().fold(0.0, |acc, &c| acc * x + c)
}

/// Real polynomial (descending powers) with the given roots and leading
/// coefficient. Complex roots must come in conjugate pairs; the imaginary
/// residue of the product is discarded.
///
/// Only for low degrees (≤ 4 or so): high-order products are ill-conditioned,
/// which is why filters are kept as sections.
pub fn poly_from_roots(roots: &[C64], leading: f64) -> Vec<f64> {
    let mut c = vec![C64::new(1.0, 0.0)];
    for &r in roots {
        let mut next = vec![C64::new(0.0, 0.0); c.len() + 1];
        for (i, &ci) in c.iter().enumerate() {
            next[i] += ci;
            next[i + 1] -= ci * r;
        }
        c = next;
    }
    c.iter().map(|z| z.re * leading).collect()
}

/// Roots of a real polynomial in descending powers.
///
/// Leading zeros are trimmed; trailing zeros give exact roots at 0. Errors on
/// the zero polynomial or non-finite coefficients.
pub fn roots(p: &[f64]) -> Result<Vec<C64>> {
    if p.iter().any(|c| !c.is_finite()) {
        return Err(DspError::InvalidInput(
            "polynomial has non-finite coefficients".into(),
        ));
    }
    let p = trim_leading_zeros(p);
    if p.is_empty() {
        return Err(DspError::Degenerate("zero polynomial has no roots".into()));
    }
    // Strip trailing zeros: exact roots at the origin.
    let nz = p.iter().rev().take_while(|&&c| c == 0.0).count();
    let core = &p[..p.len() - nz];
    let mut out = vec![C64::new(0.0, 0.0); nz];
    let n = core.len() - 1;
    match n {
        0 => {}
        1 => out.push(C64::new(-core[1] / core[0], 0.0)),
        _ => {
            // Companion matrix of the monic polynomial.
            let a0 = core[0];
            let mut m = DMatrix::<f64>::zeros(n, n);
            for j in 0..n {
                m[(0, j)] = -core[j + 1] / a0;
            }
            for i in 1..n {
                m[(i, i - 1)] = 1.0;
            }
            let (m, _) = balance(&m);
            let ev = m
                .try_schur(f64::EPSILON, 10_000)
                .ok_or_else(|| {
                    DspError::Numerical("companion-matrix eigenvalues did not converge".into())
                })?
                .complex_eigenvalues();
            for &z in ev.iter() {
                out.push(polish(core, z));
            }
        }
    }
    Ok(out)
}

/// Two Newton steps on the original polynomial; keeps the step only when it
/// reduces the residual (guards against multiple roots).
fn polish(p: &[f64], mut z: C64) -> C64 {
    let n = p.len() - 1;
    let dp: Vec<f64> = p[..n]
        .iter()
        .enumerate()
        .map(|(i, &c)| c * (n - i) as f64)
        .collect();
    for _ in 0..2 {
        let f = polyval(p, z);
        let d = polyval(&dp, z);
        if d.norm() == 0.0 || !d.is_finite() {
            break;
        }
        let cand = z - f / d;
        if cand.is_finite() && polyval(p, cand).norm() < f.norm() {
            z = cand;
        } else {
            break;
        }
    }
    // Snap tiny imaginary parts of real roots.
    if z.im.abs() <= 1e-14 * z.re.abs().max(1e-300) {
        z.im = 0.0;
    }
    z
}

/// Balance a square matrix by a diagonal similarity with powers of two
/// (Parlett–Reinsch): returns (D⁻¹ M D, d) with d the diagonal of D.
pub fn balance(m: &DMatrix<f64>) -> (DMatrix<f64>, Vec<f64>) {
    let n = m.nrows();
    let mut a = m.clone();
    let mut d = vec![1.0; n];
    let radix = 2.0_f64;
    for _sweep in 0..100 {
        let mut converged = true;
        for i in 0..n {
            let mut c = 0.0;
            let mut r = 0.0;
            for j in 0..n {
                if j != i {
                    c += a[(j, i)].abs();
                    r += a[(i, j)].abs();
                }
            }
            if c == 0.0 || r == 0.0 || !c.is_finite() || !r.is_finite() {
                continue;
            }
            let s = c + r;
            let mut f = 1.0;
            let mut cc = c;
            let mut rr = r;
            while cc < rr / radix {
                cc *= radix;
                rr /= radix;
                f *= radix;
            }
            while cc >= rr * radix {
                cc /= radix;
                rr *= radix;
                f /= radix;
            }
            if (cc + rr) < 0.95 * s {
                converged = false;
                d[i] *= f;
                for j in 0..n {
                    a[(i, j)] /= f;
                }
                for j in 0..n {
                    a[(j, i)] *= f;
                }
            }
        }
        if converged {
            break;
        }
    }
    (a, d)
}

/// Sort complex roots for stable presentation: by real part, then imaginary part.
pub fn sort_roots(r: &mut [C64]) {
    r.sort_by(|a, b| a.re.total_cmp(&b.re).then(a.im.total_cmp(&b.im)));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: C64, b: C64, tol: f64) -> bool {
        (a - b).norm() <= tol * b.norm().max(1.0)
    }

    /// The roots of `p`, sorted, are `want`, sorted, pair by pair by `close`.
    fn assert_roots_are(p: &[f64], want: &[C64], close: impl Fn(C64, C64) -> bool) {
        let mut r = roots(p).expect("roots");
        sort_roots(&mut r);
        let mut w = want.to_vec();
        sort_roots(&mut w);
        for (x, y) in r.iter().zip(&w) {
            assert!(close(*x, *y), "{x} vs {y}");
        }
    }

    #[test]
    fn roots_of_quadratic_match_formula() {
        // s² + 2135 s + 4.56e6 (paper eq. 2 denominator): roots by the quadratic formula.
        let (a, b, c) = (1.0, 2135.0, 4.56e6);
        let disc = C64::new(b * b - 4.0 * a * c, 0.0).sqrt();
        let r1 = (-b + disc) / (2.0 * a);
        let r2 = (-b - disc) / (2.0 * a);
        assert_roots_are(&[a, b, c], &[r1, r2], |x, y| close(x, y, 1e-12));
    }

    #[test]
    fn roots_round_trip_through_poly_from_roots() {
        let want = [
            C64::new(-1.0, 0.0),
            C64::new(-0.5, 3.0),
            C64::new(-0.5, -3.0),
            C64::new(-1000.0, 0.0),
            C64::new(0.0, 0.0),
        ];
        let p = poly_from_roots(&want, 2.5);
        assert_roots_are(&p, &want, |x, y| close(x, y, 1e-10));
    }

    #[test]
    fn badly_scaled_polynomial_is_balanced() {
        // Roots spanning 1e-3 … 1e4 rad/s.
        let want = [
            C64::new(-1e-3, 0.0),
            C64::new(-1.0, 0.0),
            C64::new(-1e4, 0.0),
        ];
        let p = poly_from_roots(&want, 1.0);
        assert_roots_are(&p, &want, |x, y| (x - y).norm() <= 1e-9 * y.norm());
    }

    #[test]
    fn degenerate_inputs_are_errors() {
        assert!(roots(&[0.0, 0.0]).is_err());
        assert!(roots(&[1.0, f64::NAN]).is_err());
        assert_eq!(roots(&[0.0, 3.0]).expect("constant").len(), 0);
    }
}
