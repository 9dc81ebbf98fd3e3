//! Small discrete-time state-space algebra for the loop analysis: blocks
//! x[n+1] = A x[n] + B u[n], y[n] = C x[n] + D u[n], built from second-order
//! sections or a plant's ZOH map and connected in series, in parallel and
//! around a unity feedback. Dense `nalgebra` matrices: the loops analysed
//! here have ≤ ~40 states, and the analysis runs outside the real-time path.

use kilotouch_dsp::filter::BiquadCoeffs;
use nalgebra::DMatrix;

/// A discrete-time linear block (any number of inputs and outputs).
#[derive(Debug, Clone, PartialEq)]
pub struct Dss {
    /// State matrix, n×n.
    pub a: DMatrix<f64>,
    /// Input matrix, n×m.
    pub b: DMatrix<f64>,
    /// Output matrix, p×n.
    pub c: DMatrix<f64>,
    /// Feed-through, p×m.
    pub d: DMatrix<f64>,
}

impl Dss {
    /// A static gain (SISO, no state).
    pub fn gain(k: f64) -> Self {
        Self {
            a: DMatrix::zeros(0, 0),
            b: DMatrix::zeros(0, 1),
            c: DMatrix::zeros(1, 0),
            d: DMatrix::from_element(1, 1, k),
        }
    }

    /// One second-order section in transposed direct form II (state
    /// s = [s₁, s₂]: y = b₀u + s₁, s₁' = b₁u − a₁y + s₂, s₂' = b₂u − a₂y).
    pub fn biquad(c: &BiquadCoeffs) -> Self {
        Self {
            a: DMatrix::from_row_slice(2, 2, &[-c.a1, 1.0, -c.a2, 0.0]),
            b: DMatrix::from_row_slice(2, 1, &[c.b1 - c.a1 * c.b0, c.b2 - c.a2 * c.b0]),
            c: DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            d: DMatrix::from_element(1, 1, c.b0),
        }
    }

    /// A cascade of sections (the identity for none).
    pub fn sections(s: &[BiquadCoeffs]) -> Self {
        s.iter()
            .fold(Self::gain(1.0), |acc, c| acc.then(&Self::biquad(c)))
    }

    /// A pure delay of `d` samples, y[n] = u[n − d] (z⁻ᵈ; SISO): a shift
    /// register of `d` states (state k holds u[n − k − 1]). The identity
    /// for `d` = 0.
    pub fn delay(d: usize) -> Self {
        if d == 0 {
            return Self::gain(1.0);
        }
        let mut a = DMatrix::zeros(d, d);
        for k in 1..d {
            a[(k, k - 1)] = 1.0;
        }
        let mut b = DMatrix::zeros(d, 1);
        b[(0, 0)] = 1.0;
        let mut c = DMatrix::zeros(1, d);
        c[(0, d - 1)] = 1.0;
        Self {
            a,
            b,
            c,
            d: DMatrix::zeros(1, 1),
        }
    }

    /// Number of states.
    pub fn n_states(&self) -> usize {
        self.a.nrows()
    }

    /// `self` followed by `next` (the outputs of `self` feed `next`).
    pub fn then(&self, next: &Dss) -> Dss {
        let mut a = block_diag(&self.a, &next.a);
        let n1 = self.n_states();
        a.view_mut((n1, 0), (next.n_states(), n1))
            .copy_from(&(&next.b * &self.c));
        Dss {
            a,
            b: vstack(&self.b, &(&next.b * &self.d)),
            c: hstack(&(&next.d * &self.c), &next.c),
            d: &next.d * &self.d,
        }
    }

    /// `self + other`: the same inputs, outputs added.
    pub fn plus(&self, other: &Dss) -> Dss {
        Dss {
            a: block_diag(&self.a, &other.a),
            b: vstack(&self.b, &other.b),
            c: hstack(&self.c, &other.c),
            d: &self.d + &other.d,
        }
    }

    /// `self` and `other` side by side on the same input: outputs stacked
    /// (`self`'s first).
    pub fn stack(&self, other: &Dss) -> Dss {
        Dss {
            a: block_diag(&self.a, &other.a),
            b: vstack(&self.b, &other.b),
            c: block_diag(&self.c, &other.c),
            d: vstack(&self.d, &other.d),
        }
    }

    /// `self` times a scalar (outputs scaled).
    pub fn scaled(&self, k: f64) -> Dss {
        Dss {
            a: self.a.clone(),
            b: self.b.clone(),
            c: &self.c * k,
            d: &self.d * k,
        }
    }

    /// State matrix of the SISO loop closed by u = y (unity *positive*
    /// feedback; the loop's sign lives in its blocks): A + B(1 − D)⁻¹C.
    /// `None` when 1 − D = 0 (an algebraic loop without solution).
    pub fn closed_unity(&self) -> Option<DMatrix<f64>> {
        let d = self.d[(0, 0)];
        if (1.0 - d).abs() < 1e-12 {
            return None;
        }
        Some(&self.a + &self.b * &self.c / (1.0 - d))
    }
}

/// [[x, 0], [0, y]]. (nalgebra's `stack!` would do; it needs the crate's
/// `macros` feature, which the workspace does not build.)
fn block_diag(x: &DMatrix<f64>, y: &DMatrix<f64>) -> DMatrix<f64> {
    let (r1, c1) = x.shape();
    let (r2, c2) = y.shape();
    let mut m = DMatrix::zeros(r1 + r2, c1 + c2);
    m.view_mut((0, 0), (r1, c1)).copy_from(x);
    m.view_mut((r1, c1), (r2, c2)).copy_from(y);
    m
}

/// [x; y]: `y`'s rows below `x`'s (equal column counts).
fn vstack(x: &DMatrix<f64>, y: &DMatrix<f64>) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(x.nrows() + y.nrows(), x.ncols());
    m.view_mut((0, 0), x.shape()).copy_from(x);
    m.view_mut((x.nrows(), 0), y.shape()).copy_from(y);
    m
}

/// [x, y]: `y`'s columns right of `x`'s (equal row counts).
fn hstack(x: &DMatrix<f64>, y: &DMatrix<f64>) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(x.nrows(), x.ncols() + y.ncols());
    m.view_mut((0, 0), x.shape()).copy_from(x);
    m.view_mut((0, x.ncols()), y.shape()).copy_from(y);
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use kilotouch_dsp::filter::sections_response;
    use num_complex::Complex64 as C64;

    fn response(s: &Dss, z: C64) -> C64 {
        let n = s.n_states();
        if n == 0 {
            return C64::new(s.d[(0, 0)], 0.0);
        }
        let mut m = DMatrix::<C64>::from_fn(n, n, |i, j| C64::new(-s.a[(i, j)], 0.0));
        for i in 0..n {
            m[(i, i)] += z;
        }
        let rhs = DMatrix::<C64>::from_fn(n, 1, |i, _| C64::new(s.b[(i, 0)], 0.0));
        let x = m.lu().solve(&rhs).unwrap_or(rhs);
        let mut y = C64::new(s.d[(0, 0)], 0.0);
        for i in 0..n {
            y += s.c[(0, i)] * x[(i, 0)];
        }
        y
    }

    #[test]
    fn sections_state_space_matches_the_transfer_function() {
        let secs = [
            BiquadCoeffs::new([0.2, 0.4, 0.2], [1.0, -0.5, 0.3]).unwrap(),
            BiquadCoeffs::new([1.0, -1.9, 0.95], [1.0, -1.2, 0.5]).unwrap(),
        ];
        let s = Dss::sections(&secs).scaled(-2.5);
        for f in [1.0, 100.0, 1234.0, 4999.0] {
            let z = C64::from_polar(1.0, 2.0 * std::f64::consts::PI * f / 1e4);
            let want = -2.5 * sections_response(&secs, f, 1e4);
            let got = response(&s, z);
            assert!((got - want).norm() < 1e-12 * (1.0 + want.norm()), "{f}");
        }
        // Parallel sum and stacking.
        let g = Dss::gain(3.0).plus(&Dss::biquad(&secs[0]));
        let z = C64::from_polar(1.0, 0.3);
        let want = 3.0 + sections_response(&secs[..1], 0.3 / (2.0 * std::f64::consts::PI), 1.0);
        assert!((response(&g, z) - want).norm() < 1e-12);
        let st = Dss::gain(2.0).stack(&Dss::gain(5.0));
        assert_eq!(st.d.as_slice(), &[2.0, 5.0]);
    }

    #[test]
    fn delay_is_z_to_the_minus_d() {
        for d in [0usize, 1, 3, 17] {
            let s = Dss::delay(d);
            assert_eq!(s.n_states(), d);
            for w in [0.0, 0.3, 1.7, std::f64::consts::PI] {
                let z = C64::from_polar(1.0, w);
                let want = z.powi(-(d as i32));
                assert!((response(&s, z) - want).norm() < 1e-12, "{d} {w}");
            }
            // Its impulse response is one sample at n = d.
            let mut x = DMatrix::<f64>::zeros(d, 1);
            for n in 0..d + 3 {
                let u = if n == 0 { 1.0 } else { 0.0 };
                let y = (&s.c * &x)[(0, 0)] + s.d[(0, 0)] * u;
                assert_eq!(y, if n == d { 1.0 } else { 0.0 }, "d {d} n {n}");
                x = &s.a * &x + &s.b * u;
            }
        }
    }

    #[test]
    fn unity_feedback_poles() {
        // y = k·u/(z − p) closed by u = y: pole at p + k.
        let c = BiquadCoeffs::new([0.0, 0.3, 0.0], [1.0, -0.5, 0.0]).unwrap();
        let cl = Dss::biquad(&c).closed_unity().unwrap();
        let ev = crate::lti::eigenvalues(&cl);
        assert!(
            ev.iter().any(|z| (z - C64::new(0.8, 0.0)).norm() < 1e-12),
            "{ev:?}"
        );
    }
}
