//! Continuous-time rational transfer functions G(s) = N(s)/D(s).
//!
//! Coefficients are in descending powers of s (`[b_m, …, b_0]`), with s in
//! rad/s, as scipy.signal and MATLAB use. Only low-order models (identified
//! channels, compensators) are held this way; filters are designed in zpk
//! form and realised as second-order sections.

use crate::poly;
use crate::{C64, DspError, Result, Zpk};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// A continuous-time rational transfer function N(s)/D(s), descending powers of s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Tf {
    /// Numerator coefficients, highest power first.
    pub num: Vec<f64>,
    /// Denominator coefficients, highest power first.
    pub den: Vec<f64>,
}

impl Tf {
    /// Build and validate: finite coefficients, non-zero numerator and
    /// denominator. Leading zeros are trimmed.
    pub fn new(num: Vec<f64>, den: Vec<f64>) -> Result<Self> {
        if num.iter().chain(den.iter()).any(|c| !c.is_finite()) {
            return Err(DspError::InvalidInput(
                "transfer function has non-finite coefficients".into(),
            ));
        }
        let n = poly::trim_leading_zeros(&num).to_vec();
        let d = poly::trim_leading_zeros(&den).to_vec();
        if d.is_empty() {
            return Err(DspError::Degenerate("denominator is zero".into()));
        }
        if n.is_empty() {
            return Err(DspError::Degenerate("numerator is zero".into()));
        }
        Ok(Self { num: n, den: d })
    }

    /// Degree of the numerator.
    pub fn num_degree(&self) -> usize {
        self.num.len().saturating_sub(1)
    }

    /// Degree of the denominator.
    pub fn den_degree(&self) -> usize {
        self.den.len().saturating_sub(1)
    }

    /// True when deg N ≤ deg D.
    pub fn is_proper(&self) -> bool {
        self.num_degree() <= self.den_degree()
    }

    /// Value at a complex frequency s (rad/s).
    pub fn eval(&self, s: C64) -> C64 {
        poly::polyval(&self.num, s) / poly::polyval(&self.den, s)
    }

    /// Frequency response at `f` hertz: G(j 2π f).
    pub fn response_hz(&self, f: f64) -> C64 {
        self.eval(C64::new(0.0, 2.0 * PI * f))
    }

    /// Static gain G(0) = b_0/a_0 (infinite if the denominator has a root at 0).
    pub fn dc_gain(&self) -> f64 {
        self.num.last().copied().unwrap_or(0.0) / self.den.last().copied().unwrap_or(f64::NAN)
    }

    /// Zeros (roots of N) in rad/s.
    pub fn zeros(&self) -> Result<Vec<C64>> {
        poly::roots(&self.num)
    }

    /// Poles (roots of D) in rad/s.
    pub fn poles(&self) -> Result<Vec<C64>> {
        poly::roots(&self.den)
    }

    /// True when every pole has a strictly negative real part.
    pub fn is_stable(&self) -> Result<bool> {
        Ok(self.poles()?.iter().all(|p| p.re < 0.0))
    }

    /// Equivalent zero-pole-gain form (analog: gain k with
    /// G(s) = k ∏(s − z)/∏(s − p)).
    pub fn to_zpk(&self) -> Result<Zpk> {
        Ok(Zpk {
            zeros: self.zeros()?,
            poles: self.poles()?,
            gain: self.num[0] / self.den[0],
        })
    }

    /// Scale so that the denominator is monic.
    pub fn normalized(&self) -> Self {
        let a = self.den[0];
        Self {
            num: self.num.iter().map(|c| c / a).collect(),
            den: self.den.iter().map(|c| c / a).collect(),
        }
    }
}

impl std::fmt::Display for Tf {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        fn p(c: &[f64]) -> String {
            let n = c.len();
            c.iter()
                .enumerate()
                .map(|(i, v)| match n - 1 - i {
                    0 => format!("{v:.6e}"),
                    1 => format!("{v:.6e}·s"),
                    k => format!("{v:.6e}·s^{k}"),
                })
                .collect::<Vec<_>>()
                .join(" + ")
        }
        write!(f, "({}) / ({})", p(&self.num), p(&self.den))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Paper eq. 2: G_H(s) = (250 s + 6.40e5)/(s² + 2135 s + 4.56e6).
    fn g_h() -> Tf {
        Tf::new(vec![250.0, 6.40e5], vec![1.0, 2135.0, 4.56e6]).expect("valid")
    }

    #[test]
    fn paper_g_h_reference_values() {
        // REFERENCE-VALUES.md: DC gain 0.140351, |G_H| at 63.0957, 316.228, 1000 Hz.
        let g = g_h();
        assert!((g.dc_gain() - 0.140351).abs() < 1e-6);
        assert!((g.response_hz(63.0957).norm() - 0.144449).abs() < 1e-6);
        assert!((g.response_hz(316.228).norm() - 0.189021).abs() < 1e-6);
        let h = g.response_hz(1000.0);
        assert!((h.norm() - 0.0453443).abs() < 1e-7);
        assert!((h.arg().to_degrees() - -91.1525).abs() < 1e-3);
        let z = g.zeros().expect("zeros");
        assert!((z[0].re + 2560.0).abs() < 1e-9);
        assert!(g.is_stable().expect("poles"));
        // Natural frequency sqrt(4.56e6) = 2135.42 rad/s, damping 2135/(2·2135.42).
        let wn = 4.56e6_f64.sqrt();
        assert!((wn - 2135.42).abs() < 0.01);
        assert!((2135.0 / (2.0 * wn) - 0.49990).abs() < 1e-5);
    }

    #[test]
    fn zpk_form_evaluates_identically() {
        let g = g_h();
        let z = g.to_zpk().expect("zpk");
        for f in [1.0, 63.0, 340.0, 1000.0, 5000.0] {
            let s = C64::new(0.0, 2.0 * PI * f);
            let a = g.eval(s);
            let b = z.eval(s);
            assert!((a - b).norm() <= 1e-12 * a.norm(), "f={f}: {a} vs {b}");
        }
    }

    #[test]
    fn invalid_transfer_functions_are_rejected() {
        assert!(Tf::new(vec![1.0], vec![0.0]).is_err());
        assert!(Tf::new(vec![0.0], vec![1.0]).is_err());
        assert!(Tf::new(vec![f64::INFINITY], vec![1.0]).is_err());
        let improper = Tf::new(vec![1.0, 0.0, 0.0], vec![1.0, 1.0]).expect("valid");
        assert!(!improper.is_proper());
    }
}
