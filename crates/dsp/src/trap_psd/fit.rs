//! The analytical start and the weighted least-squares (maximum-likelihood)
//! fit of a blocked spectrum (module docs of [`super`]).

use super::model::{PreparedModel, PsdModel};
use super::periodogram::{BlockedSpectrum, Periodogram};
use crate::error::DspError;
use nalgebra::{DMatrix, DVector};
use std::f64::consts::PI;

/// Initial f_diode of the fit, Hz (pylake `DiodeModel`); clamped below the
/// Nyquist frequency.
pub const DIODE_START_HZ: f64 = 14_000.0;
/// Initial α of the fit (pylake `DiodeModel`).
pub const ALPHA_START: f64 = 0.3;
/// Iteration bound of the Levenberg–Marquardt loop.
pub const MAX_ITERATIONS: usize = 500;

/// Result of the analytical least-squares Lorentzian (BSF §IV).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnalyticalFit {
    /// Corner frequency, Hz.
    pub corner_hz: f64,
    /// Diffusion coefficient, u²/s.
    pub d: f64,
    /// Standard error of f_c (BSF eqs. 25–28), Hz.
    pub corner_se_hz: f64,
    /// Standard error of D, u²/s.
    pub d_se: f64,
}

/// Options of [`fit_power_spectrum`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PsdFitOptions {
    /// Range of the analytical start, Hz (pylake: 10 Hz to 10 kHz),
    /// intersected with the spectrum's range.
    pub analytical_range_hz: (f64, f64),
    /// Multiply D (and its error) by n/(n + 1) (Nørrelykke & Flyvbjerg 2010).
    pub bias_correction: bool,
}

impl Default for PsdFitOptions {
    fn default() -> Self {
        Self {
            analytical_range_hz: (10.0, 1e4),
            bias_correction: true,
        }
    }
}

/// A fitted spectrum.
#[derive(Debug, Clone, PartialEq)]
pub struct PsdFit {
    /// The model fitted.
    pub model: PsdModel,
    /// Fitted parameters (f_c Hz, D u²/s[, f_diode Hz, α]); D after the
    /// bias correction when it is on.
    pub theta: Vec<f64>,
    /// Their standard errors, same units.
    pub se: Vec<f64>,
    /// χ² = Σ n (P/P_model − 1)² at the optimum (before the bias correction).
    pub chi2: f64,
    /// Degrees of freedom: points − parameters.
    pub dof: usize,
    /// Statistical backing: P(χ²_dof ≥ χ²), % (BSF §VI).
    pub backing_pct: f64,
    /// The analytical start.
    pub analytical: AnalyticalFit,
    /// Levenberg–Marquardt iterations used.
    pub iterations: usize,
    /// The blocked spectrum that was fitted.
    pub spectrum: BlockedSpectrum,
}

impl PsdFit {
    /// Corner frequency, Hz.
    pub fn corner_hz(&self) -> f64 {
        self.theta[0]
    }
    /// Diffusion coefficient, u²/s.
    pub fn d(&self) -> f64 {
        self.theta[1]
    }
    /// χ² per degree of freedom.
    pub fn chi2_per_dof(&self) -> f64 {
        self.chi2 / self.dof as f64
    }
    /// The fitted model at `f` (Hz), u²/Hz (with the fitted D, i.e. after
    /// the bias correction).
    pub fn model_at(&self, f: f64) -> f64 {
        self.model.eval(f, &self.theta)
    }
}

/// Analytical least-squares fit of 1/P = a + b f² (BSF §IV, eqs. 13–14 and
/// 25–28 with S_pq = Σ f^{2p} P^q; pylake `fit_analytical_lorentzian`):
/// f_c = √(a/b), D = π²/b. Falls back like pylake when a/b or b is not
/// positive (f_c = half the lowest frequency, D = π² f_c² P₀).
pub fn fit_analytical_lorentzian(
    f: &[f64],
    p: &[f64],
    duration_s: f64,
) -> Result<AnalyticalFit, DspError> {
    if f.is_empty() || f.len() != p.len() {
        return Err(DspError::InvalidInput(
            "the analytical Lorentzian fit needs at least one point in its range (10 Hz–10 kHz \
             within the fit range)"
                .into(),
        ));
    }
    let mut s = [[0.0f64; 3]; 3];
    for (&fi, &pi) in f.iter().zip(p) {
        let f2 = fi * fi;
        let fp = [1.0, f2, f2 * f2];
        let pq = [1.0, pi, pi * pi];
        for (a, fpa) in fp.iter().enumerate() {
            for (b, pqb) in pq.iter().enumerate() {
                s[a][b] += fpa * pqb;
            }
        }
    }
    let den = s[0][2] * s[2][2] - s[1][2] * s[1][2];
    let a = (s[0][1] * s[2][2] - s[1][1] * s[1][2]) / den;
    let b = (s[1][1] * s[0][2] - s[0][1] * s[1][2]) / den;
    let corner_hz = if a / b > 0.0 {
        (a / b).sqrt()
    } else if f[0] > 0.0 {
        0.5 * f[0]
    } else {
        0.5 * f.get(1).copied().unwrap_or(1.0)
    };
    let d = if b > 0.0 {
        PI * PI / b
    } else {
        PI * PI * corner_hz * corner_hz * p[0]
    };
    let fmin = f.iter().copied().fold(f64::INFINITY, f64::min);
    let fmax = f.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let (x0, x1) = (fmin / corner_hz, fmax / corner_hz);
    let at = ((x1 - x0) / (1.0 + x0 * x1)).atan();
    let u = 2.0 * x1 / (1.0 + x1 * x1) - 2.0 * x0 / (1.0 + x0 * x0) + 2.0 * at;
    let v = 4.0 / (x1 - x0) * at * at;
    let s_fc = (PI / (u - v)).sqrt();
    let corner_se_hz = corner_hz * s_fc / (PI * corner_hz * duration_s).sqrt();
    let s_d = (u / ((1.0 + PI / 2.0) * (x1 - x0))).sqrt() * s_fc;
    let d_se = d * ((1.0 + PI / 2.0) / (PI * corner_hz * duration_s)).sqrt() * s_d;
    Ok(AnalyticalFit {
        corner_hz,
        d,
        corner_se_hz,
        d_se,
    })
}

/// Residuals r_i = √n (P_i/P_model,i − 1) of the weighted fit of 1/P (BSF
/// eq. 39: σ(1/P_i) = (1/P_i)/√n), for scaled parameters `u` (θ = u ⊙ s).
fn residuals(pm: &PreparedModel, p: &[f64], sqrt_n: f64, theta: &[f64], r: &mut [f64]) {
    for (i, (ri, pi)) in r.iter_mut().zip(p).enumerate() {
        *ri = sqrt_n * (pi / pm.eval_at(i, theta) - 1.0);
    }
}

/// Fit `model` to the bins of `pg` in (`f_lo`, `f_hi`] blocked by
/// `points_per_block` (module docs of [`super`]): the analytical start on
/// the part of the range inside `opts.analytical_range_hz`, then
/// Levenberg–Marquardt on the scaled parameters (all start at 1; f_diode
/// bounded to [1 Hz, f_s/2], α to [0, 1], f_c and D to ≥ 0), standard
/// errors from (JᵀJ)⁻¹ at the optimum.
pub fn fit_power_spectrum(
    pg: &Periodogram,
    f_lo: f64,
    f_hi: f64,
    points_per_block: usize,
    model: &PsdModel,
    opts: &PsdFitOptions,
) -> Result<PsdFit, DspError> {
    model.validate()?;
    let spec = pg.blocked(f_lo, f_hi, points_per_block)?;
    let np = model.n_params();
    if spec.f.len() < np + 2 {
        return Err(DspError::InvalidInput(format!(
            "only {} blocked points in the fit range {f_lo},{f_hi} Hz with {points_per_block} \
             points per block; need at least {} (widen the range, record longer, or use fewer \
             points per block)",
            spec.f.len(),
            np + 2
        )));
    }
    let (alo, ahi) = opts.analytical_range_hz;
    let an_spec = pg.blocked(f_lo.max(alo), f_hi.min(ahi), points_per_block)?;
    let analytical = fit_analytical_lorentzian(&an_spec.f, &an_spec.p, spec.duration_s)?;
    let problem = Problem::new(model, &analytical, pg.fs_hz, &spec)?;
    let (u, chi2, iterations) = problem.levenberg_marquardt()?;
    let mut se = problem.standard_errors(&u)?;
    let mut theta: Vec<f64> = problem.theta_of(&u).iter().map(|v| v.abs()).collect();
    if opts.bias_correction {
        let c = points_per_block as f64 / (points_per_block as f64 + 1.0);
        theta[1] *= c;
        se[1] *= c;
    }
    let dof = spec.f.len() - np;
    let backing_pct = chi2_sf(chi2, dof as f64) * 100.0;
    if theta.iter().any(|v| !v.is_finite()) {
        return Err(DspError::Numerical("the fit did not converge".into()));
    }
    Ok(PsdFit {
        model: *model,
        theta,
        se,
        chi2,
        dof,
        backing_pct,
        analytical,
        iterations,
        spectrum: spec,
    })
}

/// The weighted least-squares problem of [`fit_power_spectrum`] in scaled
/// parameters u (θ = u ⊙ scale, the start at u = 1), with their bounds.
struct Problem<'a> {
    pm: PreparedModel,
    p: &'a [f64],
    sqrt_n: f64,
    scale: Vec<f64>,
    lo_u: Vec<f64>,
    hi_u: Vec<f64>,
}

impl<'a> Problem<'a> {
    /// Scales from the analytical start (f_c, D) and, with the diode, the
    /// pylake starts of f_diode (below Nyquist) and α; bounds as documented
    /// on [`fit_power_spectrum`].
    fn new(
        model: &PsdModel,
        analytical: &AnalyticalFit,
        fs_hz: f64,
        spec: &'a BlockedSpectrum,
    ) -> Result<Self, DspError> {
        let nyq = 0.5 * fs_hz;
        let mut scale = vec![analytical.corner_hz, analytical.d];
        let mut lower = vec![0.0, 0.0];
        let mut upper = vec![f64::INFINITY, f64::INFINITY];
        if model.diode {
            scale.extend([DIODE_START_HZ.min(0.999 * nyq), ALPHA_START]);
            lower.extend([1.0, 0.0]);
            upper.extend([nyq, 1.0]);
        }
        if scale.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(DspError::Numerical(format!(
                "the analytical Lorentzian start is unusable (f_c = {} Hz, D = {})",
                analytical.corner_hz, analytical.d
            )));
        }
        let lo_u: Vec<f64> = lower.iter().zip(&scale).map(|(l, s)| l / s).collect();
        let hi_u: Vec<f64> = upper.iter().zip(&scale).map(|(h, s)| h / s).collect();
        Ok(Self {
            pm: model.prepare(&spec.f),
            p: &spec.p,
            sqrt_n: (spec.points_per_block as f64).sqrt(),
            scale,
            lo_u,
            hi_u,
        })
    }

    fn np(&self) -> usize {
        self.scale.len()
    }

    fn m(&self) -> usize {
        self.p.len()
    }

    fn theta_of(&self, u: &[f64]) -> Vec<f64> {
        u.iter().zip(&self.scale).map(|(a, s)| a * s).collect()
    }

    /// χ² at `u` (∞ when not finite), leaving the residuals in `r`.
    fn chi2_of(&self, u: &[f64], r: &mut [f64]) -> f64 {
        residuals(&self.pm, self.p, self.sqrt_n, &self.theta_of(u), r);
        let c: f64 = r.iter().map(|v| v * v).sum();
        if c.is_finite() { c } else { f64::INFINITY }
    }

    /// Central-difference Jacobian of the residuals in u.
    fn jacobian(&self, u: &[f64], jac: &mut DMatrix<f64>) {
        let m = self.m();
        let mut rp = vec![0.0; m];
        let mut rm = vec![0.0; m];
        for j in 0..self.np() {
            let h = 1e-6 * u[j].abs().max(1e-3);
            let mut up = u.to_vec();
            let mut um = u.to_vec();
            up[j] += h;
            um[j] -= h;
            residuals(&self.pm, self.p, self.sqrt_n, &self.theta_of(&up), &mut rp);
            residuals(&self.pm, self.p, self.sqrt_n, &self.theta_of(&um), &mut rm);
            for i in 0..m {
                jac[(i, j)] = (rp[i] - rm[i]) / (2.0 * h);
            }
        }
    }

    /// Levenberg–Marquardt from u = 1 (clamped to the bounds), at most
    /// [`MAX_ITERATIONS`]: the optimum u, its χ² and the iterations used.
    fn levenberg_marquardt(&self) -> Result<(Vec<f64>, f64, usize), DspError> {
        let (m, np) = (self.m(), self.np());
        let mut u: Vec<f64> = (0..np)
            .map(|j| 1.0f64.clamp(self.lo_u[j], self.hi_u[j]))
            .collect();
        let mut r = vec![0.0; m];
        let mut chi2 = self.chi2_of(&u, &mut r);
        if !chi2.is_finite() {
            return Err(DspError::Numerical(
                "the model is not finite at the analytical start".into(),
            ));
        }
        let mut jac = DMatrix::<f64>::zeros(m, np);
        let mut lambda = 1e-3;
        let mut iterations = 0;
        let mut r_try = vec![0.0; m];
        'outer: while iterations < MAX_ITERATIONS {
            iterations += 1;
            self.jacobian(&u, &mut jac);
            let jtj = jac.transpose() * &jac;
            loop {
                let delta = damped_step(&jac, &jtj, &r, lambda)?;
                let u_try: Vec<f64> = (0..np)
                    .map(|j| (u[j] + delta[j]).clamp(self.lo_u[j], self.hi_u[j]))
                    .collect();
                let c = self.chi2_of(&u_try, &mut r_try);
                if c < chi2 {
                    let gain = chi2 - c;
                    let step: f64 = (0..np).map(|j| (u_try[j] - u[j]).abs()).fold(0.0, f64::max);
                    u = u_try;
                    std::mem::swap(&mut r, &mut r_try);
                    chi2 = c;
                    lambda = (lambda * 0.1).max(1e-12);
                    if gain <= 1e-12 * chi2 || step <= 1e-12 {
                        break 'outer;
                    }
                    break;
                }
                lambda *= 10.0;
                if lambda > 1e12 {
                    break 'outer;
                }
            }
        }
        Ok((u, chi2, iterations))
    }

    /// Standard errors of θ at `u` from (JᵀJ)⁻¹ by the SVD of J (∞ for a
    /// direction J does not resolve), in θ's units.
    fn standard_errors(&self, u: &[f64]) -> Result<Vec<f64>, DspError> {
        let np = self.np();
        let mut jac = DMatrix::<f64>::zeros(self.m(), np);
        self.jacobian(u, &mut jac);
        let svd = jac.svd(false, true);
        let v_t = svd
            .v_t
            .ok_or_else(|| DspError::Numerical("SVD of the Jacobian failed".into()))?;
        let smax = svd.singular_values.max();
        let mut se = vec![0.0; np];
        for (j, se_j) in se.iter_mut().enumerate() {
            let mut var = 0.0;
            for k in 0..np {
                let sk = svd.singular_values[k];
                if sk > 1e-13 * smax {
                    var += (v_t[(k, j)] / sk).powi(2);
                } else {
                    var = f64::INFINITY;
                }
            }
            *se_j = var.sqrt() * self.scale[j];
        }
        Ok(se)
    }
}

/// Damped step by least squares on [J; √λ·diag(JᵀJ)^½] δ = [−r; 0] (SVD: no
/// normal equations are formed).
fn damped_step(
    jac: &DMatrix<f64>,
    jtj: &DMatrix<f64>,
    r: &[f64],
    lambda: f64,
) -> Result<DVector<f64>, DspError> {
    let (m, np) = jac.shape();
    let mut aug = DMatrix::<f64>::zeros(m + np, np);
    aug.view_mut((0, 0), (m, np)).copy_from(jac);
    for j in 0..np {
        aug[(m + j, j)] = (lambda * jtj[(j, j)].max(1e-30)).sqrt();
    }
    let mut rhs = DVector::<f64>::zeros(m + np);
    for i in 0..m {
        rhs[i] = -r[i];
    }
    aug.svd(true, true)
        .solve(&rhs, 1e-14)
        .map_err(|e| DspError::Numerical(format!("fit step: {e}")))
}

/// Survival function of χ² with `k` degrees of freedom, Q(k/2, x/2).
fn chi2_sf(x: f64, k: f64) -> f64 {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    ChiSquared::new(k).map_or(f64::NAN, |d| d.sf(x))
}

#[cfg(test)]
mod tests {
    use super::super::model::SpectrumShape;
    use super::*;

    #[test]
    fn analytical_fit_is_exact_on_a_lorentzian() {
        let (corner_hz, d) = (437.0, 0.0123);
        let f: Vec<f64> = (1..400).map(|k| k as f64 * 25.0).collect();
        let p: Vec<f64> = f
            .iter()
            .map(|&f| d / (PI * PI * (corner_hz * corner_hz + f * f)))
            .collect();
        let a = fit_analytical_lorentzian(&f, &p, 10.0).unwrap();
        assert!((a.corner_hz / corner_hz - 1.0).abs() < 1e-9, "{a:?}");
        assert!((a.d / d - 1.0).abs() < 1e-9, "{a:?}");
        assert!(a.corner_se_hz > 0.0 && a.d_se > 0.0);
        assert!(fit_analytical_lorentzian(&[], &[], 1.0).is_err());
    }

    #[test]
    fn chi2_survival_reference() {
        // scipy.stats.chi2.sf(110, 100) = 0.232205…, chi2.sf(100, 100) = 0.48119…
        assert!((chi2_sf(110.0, 100.0) - 0.232_205).abs() < 1e-5);
        assert!((chi2_sf(100.0, 100.0) - 0.481_192).abs() < 1e-5);
    }

    /// A periodogram equal to the model (no noise): every fit must return
    /// the parameters it was made with.
    fn exact_periodogram(model: &PsdModel, theta: &[f64], n: usize, fs: f64) -> Periodogram {
        let df = fs / n as f64;
        let f: Vec<f64> = (0..=n / 2).map(|k| k as f64 * df).collect();
        let p = f
            .iter()
            .map(|&fi| if fi > 0.0 { model.eval(fi, theta) } else { 0.0 })
            .collect();
        Periodogram {
            f,
            p,
            fs_hz: fs,
            n_samples: n,
        }
    }

    #[test]
    fn noise_free_spectra_give_back_their_parameters() {
        use super::super::model::Hydrodynamics;
        let opts = PsdFitOptions {
            bias_correction: false,
            ..PsdFitOptions::default()
        };
        let hydro = Hydrodynamics {
            gamma0_n_s_m: 6.0 * PI * 1e-3 * 2e-6,
            radius_m: 2e-6,
            fluid_density_kg_m3: 997.0,
            bead_density_kg_m3: 1050.0,
            distance_to_surface_m: Some(6e-6),
        };
        let cases: [(PsdModel, Vec<f64>); 4] = [
            (
                PsdModel {
                    shape: SpectrumShape::Lorentzian,
                    diode: false,
                },
                vec![650.0, 0.3],
            ),
            (
                PsdModel {
                    shape: SpectrumShape::Lorentzian,
                    diode: true,
                },
                vec![650.0, 0.3, 7000.0, 0.4],
            ),
            (
                PsdModel {
                    shape: SpectrumShape::AliasedLorentzian { fs_hz: 50e3 },
                    diode: false,
                },
                vec![2400.0, 1.7],
            ),
            (
                PsdModel {
                    shape: SpectrumShape::Hydrodynamic(hydro),
                    diode: false,
                },
                vec![900.0, 0.05],
            ),
        ];
        for (m, theta) in cases {
            // One bin per block: the data are the model exactly (blocks would
            // add their curvature: the model at the mean frequency is not the
            // mean of the model).
            let pg = exact_periodogram(&m, &theta, 1 << 14, 50e3);
            let fit = fit_power_spectrum(&pg, 50.0, 25e3, 1, &m, &opts).unwrap();
            for (j, (a, b)) in fit.theta.iter().zip(&theta).enumerate() {
                assert!((a / b - 1.0).abs() < 1e-7, "{m:?} θ{j}: {a} vs {b}");
            }
            assert!(fit.chi2 < 1e-10, "{m:?}: χ² {}", fit.chi2);
            assert!(
                fit.se.iter().all(|s| s.is_finite() && *s > 0.0),
                "{:?}",
                fit.se
            );
        }
    }

    #[test]
    fn fit_needs_enough_points() {
        let x: Vec<f64> = (0..256).map(|i| (i as f64).sin()).collect();
        let pg = Periodogram::new(&x, 1e3).unwrap();
        let m = PsdModel {
            shape: SpectrumShape::Lorentzian,
            diode: false,
        };
        let e = fit_power_spectrum(&pg, 10.0, 400.0, 100, &m, &PsdFitOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("blocked points"), "{e}");
    }
}
