//! Linear time-invariant state-space models and their discretisations.
//!
//! A continuous model ẋ = A x + B u, y = C x + D u is held with dynamic
//! sizes ([`StateSpace`]); it is built and analysed offline (allocation is
//! fine there). A one-step map x\[n+1\] = Φ x\[n\] + Γ u\[n\] for a step `dt`
//! (input held constant over the step) is produced by:
//!
//! * [`zoh`]: exact zero-order hold, Φ = e^{A dt}, Γ = ∫₀^dt e^{Aτ} dτ B,
//!   read off the matrix exponential of the augmented matrix
//!   [[A, B], [0, 0]]·dt (Van Loan 1978). The exponential is nalgebra's
//!   Padé approximant with scaling and squaring (Higham 2005), applied to a
//!   diagonally balanced copy (Osborne/Parlett–Reinsch), since positions (m)
//!   and velocities (m/s) make A badly scaled.
//! * [`rk4_map`]: classical Runge–Kutta, Φ = Σ_{k≤4} (A dt)^k/k!.
//! * [`semi_implicit_euler_map`]: symplectic Euler (velocities first, then
//!   positions with the new velocities).
//!
//! Stability of a map is its spectral radius ρ(Φ) < 1 ([`spectral_radius`]);
//! [`stability_limit`] bisects the largest stable step.

use crate::error::RigError;
use nalgebra::DMatrix;
use num_complex::Complex64 as C64;
use std::f64::consts::PI;

/// Continuous-time state-space model ẋ = A x + B u, y = C x + D u.
#[derive(Debug, Clone, PartialEq)]
pub struct StateSpace {
    /// State matrix, n×n.
    pub a: DMatrix<f64>,
    /// Input matrix, n×m.
    pub b: DMatrix<f64>,
    /// Output matrix, p×n.
    pub c: DMatrix<f64>,
    /// Feed-through, p×m.
    pub d: DMatrix<f64>,
}

impl StateSpace {
    /// Number of states.
    pub fn n_states(&self) -> usize {
        self.a.nrows()
    }

    /// Frequency response from input `input` to output `output` at `f` Hz:
    /// C (jωI − A)⁻¹ B + D, evaluated by an LU solve (never by expanding
    /// polynomials).
    pub fn response(&self, output: usize, input: usize, f_hz: f64) -> Result<C64, RigError> {
        let n = self.n_states();
        if output >= self.c.nrows() || input >= self.b.ncols() {
            return Err(RigError::InvalidInput(format!(
                "response({output}, {input}) out of range for {}×{} system",
                self.c.nrows(),
                self.b.ncols()
            )));
        }
        let s = C64::new(0.0, 2.0 * PI * f_hz);
        let mut m = DMatrix::<C64>::from_fn(n, n, |i, j| C64::new(-self.a[(i, j)], 0.0));
        for i in 0..n {
            m[(i, i)] += s;
        }
        let rhs = DMatrix::<C64>::from_fn(n, 1, |i, _| C64::new(self.b[(i, input)], 0.0));
        let x = m
            .lu()
            .solve(&rhs)
            .ok_or_else(|| RigError::Numerical(format!("sI − A singular at {f_hz} Hz")))?;
        let mut y = C64::new(self.d[(output, input)], 0.0);
        for i in 0..n {
            y += self.c[(output, i)] * x[(i, 0)];
        }
        Ok(y)
    }

    /// Poles (eigenvalues of A), rad/s, computed on a balanced copy.
    pub fn poles(&self) -> Vec<C64> {
        eigenvalues(&self.a)
    }

    /// Restrict to a subset of states (drop unused "phantom" states).
    pub fn restrict(&self, keep: &[usize]) -> StateSpace {
        let k = keep.len();
        StateSpace {
            a: DMatrix::from_fn(k, k, |i, j| self.a[(keep[i], keep[j])]),
            b: DMatrix::from_fn(k, self.b.ncols(), |i, j| self.b[(keep[i], j)]),
            c: DMatrix::from_fn(self.c.nrows(), k, |i, j| self.c[(i, keep[j])]),
            d: self.d.clone(),
        }
    }
}

/// Integration scheme of the simulated plant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Integrator {
    /// Exact zero-order-hold discretisation (matrix exponential). Default.
    Zoh,
    /// Classical 4th-order Runge–Kutta with the input held over the step.
    Rk4,
    /// Semi-implicit (symplectic) Euler.
    SemiImplicitEuler,
}

impl Integrator {
    /// All schemes, for tables.
    pub const ALL: [Integrator; 3] = [
        Integrator::Zoh,
        Integrator::Rk4,
        Integrator::SemiImplicitEuler,
    ];

    /// Short name.
    pub fn name(self) -> &'static str {
        match self {
            Integrator::Zoh => "zoh",
            Integrator::Rk4 => "rk4",
            Integrator::SemiImplicitEuler => "semi-implicit-euler",
        }
    }
}

pub use kilotouch_dsp::poly::balance;

/// Eigenvalues of a real square matrix (balanced first; nalgebra's Schur).
pub fn eigenvalues(m: &DMatrix<f64>) -> Vec<C64> {
    if m.nrows() == 0 {
        return Vec::new();
    }
    let (b, _) = balance(m);
    b.complex_eigenvalues().iter().copied().collect()
}

/// Spectral radius max |λ| of a square matrix.
pub fn spectral_radius(m: &DMatrix<f64>) -> f64 {
    eigenvalues(m).iter().map(|z| z.norm()).fold(0.0, f64::max)
}

fn check_dt(dt: f64) -> Result<(), RigError> {
    if !(dt.is_finite() && dt > 0.0) {
        return Err(RigError::InvalidParameter {
            name: "dt",
            value: dt,
            reason: "time step must be finite and > 0".into(),
        });
    }
    Ok(())
}

/// Exact zero-order-hold discretisation: (Φ, Γ) with Φ = e^{A dt},
/// Γ = ∫₀^dt e^{Aτ}dτ B, from exp([[A, B], [0, 0]] dt) (Van Loan).
pub fn zoh(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    dt: f64,
) -> Result<(DMatrix<f64>, DMatrix<f64>), RigError> {
    check_dt(dt)?;
    let n = a.nrows();
    let m = b.ncols();
    if a.iter().chain(b.iter()).any(|x| !x.is_finite()) {
        return Err(RigError::InvalidInput(
            "non-finite entries in A or B".into(),
        ));
    }
    let mut aug = DMatrix::<f64>::zeros(n + m, n + m);
    aug.view_mut((0, 0), (n, n)).copy_from(&(a * dt));
    aug.view_mut((0, n), (n, m)).copy_from(&(b * dt));
    let (bal, d) = balance(&aug);
    let e = bal.exp();
    if e.iter().any(|x| !x.is_finite()) {
        return Err(RigError::Numerical("matrix exponential overflowed".into()));
    }
    // Undo the similarity: exp(D B D⁻¹) = D exp(B) D⁻¹ with bal = D⁻¹ aug D.
    let full = DMatrix::from_fn(n + m, n + m, |i, j| e[(i, j)] * d[i] / d[j]);
    Ok((
        full.view((0, 0), (n, n)).into_owned(),
        full.view((0, n), (n, m)).into_owned(),
    ))
}

/// One-step map of classical RK4 for ẋ = A x + B u with u held over the
/// step: Φ = Σ_{k=0}^{4} (hA)^k/k!, Γ = h Σ_{k=0}^{3} (hA)^k/(k+1)! B.
pub fn rk4_map(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    dt: f64,
) -> Result<(DMatrix<f64>, DMatrix<f64>), RigError> {
    check_dt(dt)?;
    let n = a.nrows();
    let ha = a * dt;
    let i = DMatrix::<f64>::identity(n, n);
    let ha2 = &ha * &ha;
    let ha3 = &ha2 * &ha;
    let ha4 = &ha3 * &ha;
    let phi = &i + &ha + &ha2 / 2.0 + &ha3 / 6.0 + &ha4 / 24.0;
    let s = (&i + &ha / 2.0 + &ha2 / 6.0 + &ha3 / 24.0) * dt;
    Ok((phi, s * b))
}

/// One-step map of semi-implicit (symplectic) Euler. The first `n_pos`
/// states are positions, whose derivatives must depend on the remaining
/// states only; the remaining states are advanced first by explicit Euler,
/// then the positions with the new values:
/// p' = p + h (A_pq q + A_pp p + B_p u), q' = q + h A_qp p'.
pub fn semi_implicit_euler_map(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    dt: f64,
    n_pos: usize,
) -> Result<(DMatrix<f64>, DMatrix<f64>), RigError> {
    check_dt(dt)?;
    let n = a.nrows();
    let m = b.ncols();
    let mut phi = DMatrix::<f64>::zeros(n, n);
    let mut gam = DMatrix::<f64>::zeros(n, m);
    // Apply the step to each basis vector (state and input) — the map is linear.
    for col in 0..(n + m) {
        let mut x = vec![0.0; n];
        let mut u = vec![0.0; m];
        if col < n {
            x[col] = 1.0;
        } else {
            u[col - n] = 1.0;
        }
        let mut xn = x.clone();
        for r in n_pos..n {
            let mut d = 0.0;
            for j in 0..n {
                d += a[(r, j)] * x[j];
            }
            for j in 0..m {
                d += b[(r, j)] * u[j];
            }
            xn[r] = x[r] + dt * d;
        }
        for r in 0..n_pos {
            let mut d = 0.0;
            for j in n_pos..n {
                d += a[(r, j)] * xn[j];
            }
            xn[r] = x[r] + dt * d;
        }
        for r in 0..n {
            if col < n {
                phi[(r, col)] = xn[r];
            } else {
                gam[(r, col - n)] = xn[r];
            }
        }
    }
    Ok((phi, gam))
}

/// One-step map of `integrator` for (A, B) at step `dt`.
pub fn one_step_map(
    integrator: Integrator,
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    dt: f64,
    n_pos: usize,
) -> Result<(DMatrix<f64>, DMatrix<f64>), RigError> {
    match integrator {
        Integrator::Zoh => zoh(a, b, dt),
        Integrator::Rk4 => rk4_map(a, b, dt),
        Integrator::SemiImplicitEuler => semi_implicit_euler_map(a, b, dt, n_pos),
    }
}

/// Frequency response of the sampled system x\[n+1\] = Φx\[n\] + Γu\[n\] with the
/// output read at the end of each step, y\[n\] = C x\[n+1\] + D u\[n\] (the
/// convention of the simulated rig: a command written at sample n is seen
/// by the sensors read at the same tick, one step later):
/// H(z) = z C (zI − Φ)⁻¹ Γ + D at z = e^{j2πf/fs}.
pub fn discrete_response(
    phi: &DMatrix<f64>,
    gamma: &DMatrix<f64>,
    out: (&DMatrix<f64>, &DMatrix<f64>),
    output: usize,
    input: usize,
    f_hz: f64,
    fs: f64,
) -> Result<C64, RigError> {
    let (c, d) = out;
    let n = phi.nrows();
    let z = C64::from_polar(1.0, 2.0 * PI * f_hz / fs);
    let mut m = DMatrix::<C64>::from_fn(n, n, |i, j| C64::new(-phi[(i, j)], 0.0));
    for i in 0..n {
        m[(i, i)] += z;
    }
    let rhs = DMatrix::<C64>::from_fn(n, 1, |i, _| C64::new(gamma[(i, input)], 0.0));
    let x = m
        .lu()
        .solve(&rhs)
        .ok_or_else(|| RigError::Numerical(format!("zI − Φ singular at {f_hz} Hz")))?;
    let mut y = C64::new(0.0, 0.0);
    for i in 0..n {
        y += c[(output, i)] * x[(i, 0)];
    }
    Ok(y * z + d[(output, input)])
}

/// Largest step in [`dt_lo`, `dt_hi`] for which ρ(Φ(dt)) ≤ 1, by bisection
/// (relative tolerance 1e-6). Returns `None` if even `dt_hi` is stable, and
/// `Some(dt_lo)` if `dt_lo` is already unstable.
pub fn stability_limit(
    map: impl Fn(f64) -> Result<DMatrix<f64>, RigError>,
    dt_lo: f64,
    dt_hi: f64,
) -> Result<Option<f64>, RigError> {
    let stable =
        |dt: f64| -> Result<bool, RigError> { Ok(spectral_radius(&map(dt)?) <= 1.0 + 1e-12) };
    if stable(dt_hi)? {
        return Ok(None);
    }
    if !stable(dt_lo)? {
        return Ok(Some(dt_lo));
    }
    let (mut lo, mut hi) = (dt_lo, dt_hi);
    while (hi - lo) > 1e-6 * hi {
        let mid = (lo * hi).sqrt();
        if stable(mid)? {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(Some(lo))
}

/// Hankel singular values σ₁ ≥ σ₂ ≥ … ≥ 0 of the stable discrete-time
/// system x⁺ = Φx + Γu, y = Cx: σᵢ = √λᵢ(PQ), with the controllability and
/// observability gramians P = ΦPΦᵀ + ΓΓᵀ and Q = ΦᵀQΦ + CᵀC (Moore 1981;
/// Antoulas, *Approximation of Large-Scale Dynamical Systems*, 2005, §4.3
/// and §7.1). They are invariant under a change of state coordinates and
/// measure how much each state direction of a balanced realisation carries
/// from input to output: no model with k states comes closer than σ_{k+1}
/// in H∞ norm (Glover 1984), balanced truncation to k states stays within
/// 2(σ_{k+1} + … + σ_n), and σᵢ = 0 marks a state that is uncontrollable or
/// unobservable. σ₁ is at most the H∞ norm (peak gain).
///
/// Gramians by Smith's doubling, P ← P + Φ_k P Φ_kᵀ, Φ_k ← Φ_k² (each
/// round doubles the number of terms of Σ Φᵏ ΓΓᵀ Φᵏᵀ), until two rounds
/// in a row change no entry p_ij by more than 10⁻¹⁷√(p_ii p_jj). The states
/// are then scaled so that P and Q have equal diagonals (a similarity, so
/// the σᵢ do not change; the plant mixes metres, m/s and newtons), and σᵢ²
/// are the eigenvalues of the symmetric LᵀQL with P = LLᵀ from P's
/// symmetric eigen-decomposition (defined also when P is singular).
/// Accuracy: relative to σ₁, ≈ 1e-11 on the plant-like test system (against
/// scipy); a badly conditioned realisation loses more (the gramians'
/// eigenvalues span many decades), as with any method in f64.
pub fn hankel_singular_values(
    phi: &DMatrix<f64>,
    gamma: &DMatrix<f64>,
    c: &DMatrix<f64>,
) -> Result<Vec<f64>, RigError> {
    let n = phi.nrows();
    if phi.ncols() != n || gamma.nrows() != n || c.ncols() != n {
        return Err(RigError::InvalidInput(format!(
            "Hankel singular values: Φ is {}×{}, Γ {}×{}, C {}×{} (need n×n, n×m, p×n)",
            phi.nrows(),
            phi.ncols(),
            gamma.nrows(),
            gamma.ncols(),
            c.nrows(),
            c.ncols()
        )));
    }
    if phi
        .iter()
        .chain(gamma.iter())
        .chain(c.iter())
        .any(|x| !x.is_finite())
    {
        return Err(RigError::InvalidInput(
            "Hankel singular values: non-finite entries in Φ, Γ or C".into(),
        ));
    }
    let rho = spectral_radius(phi);
    if rho >= 1.0 {
        return Err(RigError::Unstable(format!(
            "Hankel singular values need a stable Φ (spectral radius {rho})"
        )));
    }
    let gramian = |a0: DMatrix<f64>, p0: DMatrix<f64>| -> Result<DMatrix<f64>, RigError> {
        let (mut a, mut p) = (a0, p0);
        let mut quiet = 0;
        for _ in 0..64 {
            let next = &a * &p * a.transpose();
            // Converged when this round changes no entry by more than
            // 1e-17 of √(p_ii p_jj) (the bound on |p_ij|; entrywise, because
            // the plant's states differ in scale by many decades), twice.
            let small = (0..n).all(|i| {
                (0..n).all(|j| next[(i, j)].abs() <= 1e-17 * (p[(i, i)] * p[(j, j)]).sqrt())
            });
            p += next;
            a = &a * &a;
            if !a.iter().all(|x| x.is_finite()) {
                break;
            }
            quiet = if small { quiet + 1 } else { 0 };
            if quiet == 2 {
                // Symmetrise the round-off.
                return Ok((&p + p.transpose()) * 0.5);
            }
        }
        Err(RigError::Numerical(format!(
            "gramian doubling did not converge (spectral radius {rho})"
        )))
    };
    let p = gramian(phi.clone(), gamma * gamma.transpose())?;
    let q = gramian(phi.transpose(), c.transpose() * c)?;
    // Diagonal similarity D: P̃ = D⁻¹PD⁻¹, Q̃ = DQD with d = (P_ii/Q_ii)^¼.
    let d: Vec<f64> = (0..n)
        .map(|i| {
            let (pi, qi) = (p[(i, i)], q[(i, i)]);
            if pi > 0.0 && qi > 0.0 {
                (pi / qi).powf(0.25)
            } else {
                1.0
            }
        })
        .collect();
    let pt = DMatrix::from_fn(n, n, |i, j| p[(i, j)] / (d[i] * d[j]));
    let qt = DMatrix::from_fn(n, n, |i, j| q[(i, j)] * d[i] * d[j]);
    let e = pt.symmetric_eigen();
    let l = DMatrix::from_fn(n, n, |i, j| {
        e.eigenvectors[(i, j)] * e.eigenvalues[j].max(0.0).sqrt()
    });
    let m = l.transpose() * qt * &l;
    let m = (&m + m.transpose()) * 0.5;
    let mut s: Vec<f64> = m
        .symmetric_eigenvalues()
        .iter()
        .map(|v| v.max(0.0).sqrt())
        .collect();
    s.sort_by(|a, b| b.total_cmp(a));
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Damped oscillator ẍ + 2ζω ẋ + ω² x = u, states (x, v).
    fn osc(w: f64, z: f64) -> (DMatrix<f64>, DMatrix<f64>) {
        (
            DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -w * w, -2.0 * z * w]),
            DMatrix::from_row_slice(2, 1, &[0.0, 1.0]),
        )
    }

    #[test]
    fn zoh_of_scalar_system_is_exact() {
        // ẋ = −a x + u: Φ = e^{−a dt}, Γ = (1 − e^{−a dt})/a.
        let a = DMatrix::from_element(1, 1, -3.0e4);
        let b = DMatrix::from_element(1, 1, 1.0);
        let (p, g) = zoh(&a, &b, 1e-4).unwrap();
        let e = (-3.0_f64).exp();
        assert!((p[(0, 0)] - e).abs() < 1e-14);
        assert!((g[(0, 0)] - (1.0 - e) / 3.0e4).abs() < 1e-18);
    }

    #[test]
    fn zoh_of_oscillator_matches_closed_form() {
        // Undamped oscillator: Φ = [[cos, sin/ω], [−ω sin, cos]],
        // Γ = [(1 − cos)/ω², sin/ω]. Badly scaled on purpose (ω = 2e4).
        let w = 2.0e4;
        let (a, b) = osc(w, 0.0);
        let dt = 1e-4;
        let (p, g) = zoh(&a, &b, dt).unwrap();
        let (s, c) = (w * dt).sin_cos();
        let exp = [c, s / w, -w * s, c];
        for (k, e) in exp.iter().enumerate() {
            let v = p[(k / 2, k % 2)];
            assert!(
                (v - e).abs() <= 1e-12 * e.abs().max(1.0),
                "Φ[{k}] {v} vs {e}"
            );
        }
        assert!((g[(0, 0)] - (1.0 - c) / (w * w)).abs() < 1e-12 / (w * w));
        assert!((g[(1, 0)] - s / w).abs() < 1e-12 / w);
    }

    #[test]
    fn zoh_semigroup_property() {
        let (a, b) = osc(1.5e4, 0.01);
        let (p1, g1) = zoh(&a, &b, 1e-4).unwrap();
        let (p2, g2) = zoh(&a, &b, 2e-4).unwrap();
        let pp = &p1 * &p1;
        let gg = &p1 * &g1 + &g1;
        assert!((pp - &p2).norm() < 1e-12 * p2.norm());
        assert!((gg - &g2).norm() < 1e-12 * g2.norm());
    }

    #[test]
    fn rk4_and_symplectic_euler_limits_match_theory() {
        // Undamped oscillator: symplectic Euler is stable iff ω dt ≤ 2;
        // RK4 on the imaginary axis iff ω dt ≤ 2√2.
        let w = 1.0e4;
        let (a, b) = osc(w, 0.0);
        let sie = stability_limit(
            |dt| Ok(semi_implicit_euler_map(&a, &b, dt, 1)?.0),
            1e-6,
            1e-2,
        )
        .unwrap()
        .unwrap();
        assert!((sie * w - 2.0).abs() < 1e-4, "{}", sie * w);
        let rk = stability_limit(|dt| Ok(rk4_map(&a, &b, dt)?.0), 1e-6, 1e-2)
            .unwrap()
            .unwrap();
        assert!((rk * w - 2.0 * 2.0_f64.sqrt()).abs() < 1e-4, "{}", rk * w);
        // ZOH is stable for every step.
        let z = stability_limit(|dt| Ok(zoh(&a, &b, dt)?.0), 1e-6, 1e-2).unwrap();
        // Undamped: ρ = 1 exactly (within rounding) → counted as stable.
        assert!(z.is_none());
    }

    #[test]
    fn continuous_response_of_oscillator() {
        let (w, z) = (2.0 * PI * 300.0, 0.1);
        let (a, b) = osc(w, z);
        let ss = StateSpace {
            a,
            b,
            c: DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            d: DMatrix::zeros(1, 1),
        };
        for f in [10.0, 300.0, 1000.0] {
            let s = C64::new(0.0, 2.0 * PI * f);
            let expect = 1.0 / (s * s + 2.0 * z * w * s + w * w);
            let got = ss.response(0, 0, f).unwrap();
            assert!((got - expect).norm() < 1e-12 * expect.norm());
        }
    }

    #[test]
    fn discrete_response_converges_to_continuous() {
        let (w, z) = (2.0 * PI * 300.0, 0.1);
        let (a, b) = osc(w, z);
        let c = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
        let d = DMatrix::zeros(1, 1);
        let ss = StateSpace {
            a: a.clone(),
            b: b.clone(),
            c: c.clone(),
            d: d.clone(),
        };
        let f = 200.0;
        let hc = ss.response(0, 0, f).unwrap();
        let mut prev = f64::INFINITY;
        for fs in [1e4, 1e5, 1e6] {
            let (p, g) = zoh(&a, &b, 1.0 / fs).unwrap();
            let hd = discrete_response(&p, &g, (&c, &d), 0, 0, f, fs).unwrap();
            // ZOH input: H_d ≈ H(jω)·e^{+jωT/2}·sinc (output read one step later).
            let err = ((hd / hc).norm() - 1.0).abs();
            assert!(err < prev, "error must shrink with fs");
            prev = err;
        }
        assert!(prev < 1e-6);
    }

    #[test]
    fn invalid_steps_are_rejected() {
        let (a, b) = osc(1.0, 0.1);
        assert!(zoh(&a, &b, 0.0).is_err());
        assert!(rk4_map(&a, &b, f64::NAN).is_err());
        assert!(semi_implicit_euler_map(&a, &b, -1.0, 1).is_err());
    }

    #[test]
    fn hankel_singular_value_of_a_first_order_system_is_analytic() {
        // x⁺ = a x + b u, y = c x: P = b²/(1 − a²), Q = c²/(1 − a²),
        // σ = |bc|/(1 − a²). a close to 1 needs many doubling rounds.
        for (a, b, c) in [(0.5, 2.0, -3.0), (-0.9, 1e-3, 1e4), (0.99974, 1.0, 1.0)] {
            let m = |v: f64| DMatrix::from_element(1, 1, v);
            let s = hankel_singular_values(&m(a), &m(b), &m(c)).unwrap();
            let want = (b * c).abs() / (1.0 - a * a);
            assert!(
                (s[0] - want).abs() <= 1e-12 * want,
                "{a}: {} vs {want}",
                s[0]
            );
        }
    }

    #[test]
    fn hankel_singular_values_match_scipy_and_ignore_units() {
        // ZOH (10 kHz) of two oscillators (300 Hz, ζ 0.05; 800 Hz, ζ 0.01;
        // states x, ẋ) and a 50 Hz real mode, one input, one output with
        // weights over five decades.
        let mut a = DMatrix::<f64>::zeros(5, 5);
        let (o1, b1) = osc(2.0 * PI * 300.0, 0.05);
        let (o2, b2) = osc(2.0 * PI * 800.0, 0.01);
        a.view_mut((0, 0), (2, 2)).copy_from(&o1);
        a.view_mut((2, 2), (2, 2)).copy_from(&o2);
        a[(4, 4)] = -2.0 * PI * 50.0;
        let mut b = DMatrix::<f64>::zeros(5, 1);
        b.view_mut((0, 0), (2, 1)).copy_from(&b1);
        b.view_mut((2, 0), (2, 1)).copy_from(&b2);
        b[(4, 0)] = 30.0;
        let c = DMatrix::from_row_slice(1, 5, &[1e5, 3.0, -2e5, 1.0, 0.5]);
        let (phi, gam) = zoh(&a, &b, 1e-4).unwrap();
        let s0 = hankel_singular_values(&phi, &gam, &c).unwrap();
        // scipy 1.17.1: cont2discrete (zoh), solve_discrete_lyapunov for
        // both gramians, singular values of R̃ᵀL̃ from their Cholesky factors.
        let scipy = [
            0.199_230_651_081_218_6,
            0.195_495_816_897_945_76,
            0.148_428_567_297_737_93,
            0.132_722_890_961_603_5,
            0.022_492_611_374_999_118,
        ];
        for (x, y) in s0.iter().zip(&scipy) {
            assert!((x - y).abs() <= 1e-11 * scipy[0], "{s0:?} vs {scipy:?}");
        }
        // The same system in other units: x = D z with D over ten decades.
        let scale = [1e-6, 1e-3, 1.0, 1e2, 1e4];
        let d = DMatrix::from_fn(5, 5, |i, j| if i == j { scale[i] } else { 0.0 });
        let di = DMatrix::from_fn(5, 5, |i, j| if i == j { 1.0 / scale[i] } else { 0.0 });
        let s1 = hankel_singular_values(&(&di * &phi * &d), &(&di * &gam), &(&c * &d)).unwrap();
        for (x, y) in s0.iter().zip(&s1) {
            assert!((x - y).abs() <= 1e-9 * s0[0], "{s0:?} vs {s1:?}");
        }
        // An extra state that the input never reaches has σ = 0, and the
        // others do not change.
        let mut phi2 = DMatrix::<f64>::zeros(6, 6);
        phi2.view_mut((0, 0), (5, 5)).copy_from(&phi);
        phi2[(5, 5)] = 0.7;
        let gam2 = gam.clone().insert_row(5, 0.0);
        let c2 = c.clone().insert_column(5, 1.0);
        let s2 = hankel_singular_values(&phi2, &gam2, &c2).unwrap();
        assert!(s2[5] <= 1e-10 * s2[0], "{s2:?}");
        for (x, y) in s0.iter().zip(&s2) {
            assert!((x - y).abs() <= 1e-9 * s0[0]);
        }
    }

    #[test]
    fn hankel_singular_values_are_invariant_under_a_change_of_coordinates() {
        // A well-scaled discrete system (two damped rotations, a real pole),
        // then x = T z with a general (non-orthogonal) T.
        let rot = |r: f64, th: f64| [r * th.cos(), r * th.sin(), -r * th.sin(), r * th.cos()];
        let mut phi = DMatrix::<f64>::zeros(5, 5);
        let (r1, r2) = (rot(0.99, 0.19), rot(0.995, 0.5));
        phi.view_mut((0, 0), (2, 2)).copy_from_slice(&r1);
        phi.view_mut((2, 2), (2, 2)).copy_from_slice(&r2);
        phi[(4, 4)] = 0.97;
        let gam =
            DMatrix::from_column_slice(5, 2, &[1.0, 0.5, -0.3, 1.0, 0.2, 0.0, 1.0, 0.4, 0.0, -1.0]);
        let c = DMatrix::from_row_slice(1, 5, &[1.0, -2.0, 0.5, 1.0, 3.0]);
        let s0 = hankel_singular_values(&phi, &gam, &c).unwrap();
        let t = DMatrix::from_fn(5, 5, |i, j| {
            if i == j {
                1.0
            } else {
                0.4 * ((i * 5 + j) as f64).sin()
            }
        });
        let ti = t.clone().try_inverse().unwrap();
        let s1 = hankel_singular_values(&(&ti * &phi * &t), &(&ti * &gam), &(&c * &t)).unwrap();
        assert!(s0[4] > 1e-3 * s0[0], "{s0:?}");
        for (x, y) in s0.iter().zip(&s1) {
            assert!((x - y).abs() <= 1e-10 * s0[0], "{s0:?} vs {s1:?}");
        }
    }

    #[test]
    fn hankel_singular_values_reject_unstable_and_mismatched_systems() {
        let m = |v: f64| DMatrix::from_element(1, 1, v);
        assert!(matches!(
            hankel_singular_values(&m(1.0), &m(1.0), &m(1.0)),
            Err(RigError::Unstable(_))
        ));
        assert!(matches!(
            hankel_singular_values(&m(0.5), &DMatrix::zeros(2, 1), &m(1.0)),
            Err(RigError::InvalidInput(_))
        ));
        assert!(matches!(
            hankel_singular_values(&m(f64::NAN), &m(1.0), &m(1.0)),
            Err(RigError::InvalidInput(_))
        ));
    }
}
