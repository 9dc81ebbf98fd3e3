//! The spectra fitted in a trap calibration (module docs of [`super`]).
//!
//! Parameters are always ordered θ = (f_c Hz, D u²/s, f_diode Hz, α): the
//! last two only with the diode filter.

use crate::error::DspError;
use num_complex::Complex64;
use std::f64::consts::PI;

/// One-sided aliased Lorentzian (Berg-Sørensen & Flyvbjerg 2004, eq. 4) at
/// `f` (Hz) for corner `corner_hz` (Hz), diffusion coefficient `d` (u²/s) and sample
/// rate `fs` (Hz), u²/Hz: the exact spectrum of the point-sampled
/// Ornstein–Uhlenbeck process x\[n+1\] = c x\[n\] + σ ξ, c = e^{−x},
/// x = 2π f_c/f_s, whose two-sided density is
/// P₂(f) = (D/(2π f_c f_s)) · sinh x / (cosh x − cos(2π f/f_s)), so that
/// ∫P₂ = D/(2π f_c) = k_BT/κ; the one-sided density is twice that
/// (docs/theory/tweezer.md, "Aliased Lorentzian").
pub fn aliased_lorentzian_one_sided(f: f64, corner_hz: f64, d: f64, fs: f64) -> f64 {
    let x = 2.0 * PI * corner_hz / fs;
    // sinh x/(cosh x − cos θ) written to stay accurate for small x and θ.
    let th = 2.0 * PI * f / fs;
    let num = x.sinh();
    // cosh x − cos θ = 2 sinh²(x/2) + 2 sin²(θ/2)
    let den = 2.0 * (0.5 * x).sinh().powi(2) + 2.0 * (0.5 * th).sin().powi(2);
    2.0 * d / (2.0 * PI * corner_hz * fs) * num / den
}

/// One-sided plain (continuous) Lorentzian D/(π²(f_c² + f²)) (BSF eq. 10)
/// at `f` (Hz) for corner `corner_hz` (Hz) and diffusion coefficient `d` (u²/s),
/// u²/Hz.
pub fn lorentzian_one_sided(f: f64, corner_hz: f64, d: f64) -> f64 {
    d / (PI * PI * (corner_hz * corner_hz + f * f))
}

/// Slow-photodiode filter (Berg-Sørensen et al. 2003, eq. 11; pylake
/// `g_diode`): the fraction α of the signal passes at once, the rest
/// through a first-order low-pass at `f_diode_hz`:
/// g(f) = α² + (1 − α²)/(1 + (f/f_diode)²). Dimensionless.
pub fn diode_filter(f: f64, f_diode_hz: f64, alpha: f64) -> f64 {
    let a2 = alpha * alpha;
    let u = f / f_diode_hz;
    a2 + (1.0 - a2) / (1.0 + u * u)
}

/// Fluid and bead properties of the hydrodynamically correct spectrum.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hydrodynamics {
    /// Bulk Stokes drag γ₀ = 6πηR, N·s/m.
    pub gamma0_n_s_m: f64,
    /// Bead radius R, m.
    pub radius_m: f64,
    /// Fluid density ρ, kg/m³.
    pub fluid_density_kg_m3: f64,
    /// Bead density ρ_b, kg/m³.
    pub bead_density_kg_m3: f64,
    /// Bead-centre to surface distance l, m (None: far from any surface).
    pub distance_to_surface_m: Option<f64>,
}

impl Hydrodynamics {
    /// Complex drag γ(f)/γ₀ of a sphere oscillating at `f` (Hz), with the
    /// wall term when a distance is given (Tolić-Nørrelykke et al. 2006,
    /// eqs. D4 and D6; pylake `calculate_complex_drag`):
    /// γ/γ₀ = [1 + (1 − i)√(f/f_ν) − (2i/9) f/f_ν] / {1 − (9/16)(R/l)[1 −
    /// ((1 − i)/3)√(f/f_ν) + (2i/9) f/f_ν − (4/3)(1 − e^{−(1−i)(2l−R)/δ})]},
    /// f_ν = ν/(πR²), ν = γ₀/(6πρR), δ = R/√(f/f_ν).
    pub fn complex_drag(&self, f: f64) -> Complex64 {
        let r = self.radius_m;
        let nu = self.gamma0_n_s_m / (6.0 * PI * self.fluid_density_kg_m3 * r);
        let f_nu = nu / (PI * r * r);
        let ratio = Complex64::new(f / f_nu, 0.0);
        let sq = ratio.sqrt();
        let one_m_i = Complex64::new(1.0, -1.0);
        let i = Complex64::new(0.0, 1.0);
        let stokes = 1.0 + one_m_i * sq - (2.0 / 9.0) * i * ratio;
        let Some(l) = self.distance_to_surface_m else {
            return stokes;
        };
        let eps = (2.0 * l - r) * sq / r;
        let den = 1.0
            - (9.0 / 16.0)
                * (r / l)
                * (1.0 - one_m_i / 3.0 * sq + (2.0 / 9.0) * i * ratio
                    - (4.0 / 3.0) * (1.0 - (-(one_m_i * eps)).exp()));
        stokes / den
    }

    /// Dissipation frequency f_m = γ₀/(2π m) of the bead's kinetic energy,
    /// m = (4/3)πR³ρ_b (the bead's mass alone, as in Tolić-Nørrelykke et al.
    /// 2006 and pylake), Hz.
    pub fn dissipation_hz(&self) -> f64 {
        let m = 4.0 / 3.0 * PI * self.radius_m.powi(3) * self.bead_density_kg_m3;
        self.gamma0_n_s_m / (2.0 * PI * m)
    }

    /// Check the parameters; the model holds for l/R ≥ 1.5 only.
    pub fn validate(&self) -> Result<(), DspError> {
        let pos = |name: &'static str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(DspError::InvalidParameter {
                    name,
                    value: v,
                    reason: "must be finite and > 0".into(),
                })
            }
        };
        pos("gamma0", self.gamma0_n_s_m)?;
        pos("radius", self.radius_m)?;
        pos("fluid_density", self.fluid_density_kg_m3)?;
        pos("bead_density", self.bead_density_kg_m3)?;
        if let Some(l) = self.distance_to_surface_m
            && !(l.is_finite() && l >= 1.5 * self.radius_m)
        {
            return Err(DspError::InvalidParameter {
                name: "distance_to_surface",
                value: l,
                reason: "the hydrodynamically correct model holds for a bead-centre distance \
                         of at least 1.5 radii (Tolić-Nørrelykke et al. 2006); nearer the \
                         surface fit the Lorentzian with Faxén's correction"
                    .into(),
            });
        }
        Ok(())
    }
}

/// The physical spectrum, before the diode filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SpectrumShape {
    /// D/(π²(f_c² + f²)) (BSF eq. 10, one-sided; pylake
    /// `passive_power_spectrum_model`). For anti-aliased records.
    Lorentzian,
    /// The aliased Lorentzian of a record point-sampled at `fs_hz` without
    /// an anti-aliasing filter (BSF eq. 4).
    AliasedLorentzian {
        /// Sample rate, Hz.
        fs_hz: f64,
    },
    /// Hydrodynamically correct spectrum (Tolić-Nørrelykke et al. 2006, eq.
    /// D2; pylake `passive_power_spectrum_model_hydro`):
    /// P = (D/π²) Re γ̃ / ((f_c + f Im γ̃ − f²/f_m)² + (f Re γ̃)²), γ̃ = γ(f)/γ₀.
    Hydrodynamic(Hydrodynamics),
}

/// A spectrum model: a shape, with or without the fitted diode filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PsdModel {
    /// Physical spectrum.
    pub shape: SpectrumShape,
    /// Multiply by the diode filter and fit f_diode and α.
    pub diode: bool,
}

/// A model evaluated on fixed frequencies: the parameter-free factors
/// (the complex drag of the hydrodynamic model) computed once.
#[derive(Debug, Clone)]
pub struct PreparedModel {
    model: PsdModel,
    f: Vec<f64>,
    drag: Vec<Complex64>,
    f_m: f64,
}

impl PsdModel {
    /// Number of parameters: 2, or 4 with the diode.
    pub fn n_params(&self) -> usize {
        if self.diode { 4 } else { 2 }
    }

    /// Check the model's fixed parameters.
    pub fn validate(&self) -> Result<(), DspError> {
        match self.shape {
            SpectrumShape::Lorentzian => Ok(()),
            SpectrumShape::AliasedLorentzian { fs_hz } => {
                if !(fs_hz.is_finite() && fs_hz > 0.0) {
                    return Err(DspError::InvalidParameter {
                        name: "fs",
                        value: fs_hz,
                        reason: "must be finite and > 0".into(),
                    });
                }
                if self.diode {
                    return Err(DspError::InvalidInput(
                        "the aliased Lorentzian is fitted without the diode filter: a \
                         point-sampled record has no anti-aliasing filter, and a slow \
                         photodiode's aliases are not modelled"
                            .into(),
                    ));
                }
                Ok(())
            }
            SpectrumShape::Hydrodynamic(h) => h.validate(),
        }
    }

    /// Prepare the model on frequencies `f` (Hz).
    pub fn prepare(&self, f: &[f64]) -> PreparedModel {
        let (drag, f_m) = match self.shape {
            SpectrumShape::Hydrodynamic(h) => (
                f.iter().map(|&fi| h.complex_drag(fi)).collect(),
                h.dissipation_hz(),
            ),
            _ => (Vec::new(), f64::INFINITY),
        };
        PreparedModel {
            model: *self,
            f: f.to_vec(),
            drag,
            f_m,
        }
    }

    /// The model at one frequency `f` (Hz) for parameters `theta`, u²/Hz.
    pub fn eval(&self, f: f64, theta: &[f64]) -> f64 {
        self.prepare(&[f]).eval_at(0, theta)
    }
}

impl PreparedModel {
    /// Frequencies, Hz.
    pub fn f(&self) -> &[f64] {
        &self.f
    }

    /// The model at the `i`-th frequency for parameters `theta`
    /// (f_c, D[, f_diode, α]), u²/Hz.
    #[inline]
    pub fn eval_at(&self, i: usize, theta: &[f64]) -> f64 {
        let f = self.f[i];
        let (corner_hz, d) = (theta[0], theta[1]);
        let phys = match self.model.shape {
            SpectrumShape::Lorentzian => lorentzian_one_sided(f, corner_hz, d),
            SpectrumShape::AliasedLorentzian { fs_hz } => {
                aliased_lorentzian_one_sided(f, corner_hz, d, fs_hz)
            }
            SpectrumShape::Hydrodynamic(_) => {
                let g = self.drag[i];
                let a = corner_hz + f * (g.im - f / self.f_m);
                let b = f * g.re;
                d / (PI * PI) * g.re / (a * a + b * b)
            }
        };
        if self.model.diode {
            phys * diode_filter(f, theta[2], theta[3])
        } else {
            phys
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hydro(l: Option<f64>) -> Hydrodynamics {
        let (eta, r) = (1.002e-3, 2.25e-6);
        Hydrodynamics {
            gamma0_n_s_m: 6.0 * PI * eta * r,
            radius_m: r,
            fluid_density_kg_m3: 997.0,
            bead_density_kg_m3: 1040.0,
            distance_to_surface_m: l,
        }
    }

    #[test]
    fn hydrodynamic_spectrum_tends_to_the_lorentzian_at_low_frequency() {
        // γ(f)/γ₀ → 1 as f → 0 in bulk; at a wall it → Faxén's 1/(1 − 9R/16l)
        // to first order (D6 at f = 0 is 1/(1 − (9/16)(R/l))).
        let h = hydro(None);
        let g = h.complex_drag(1e-9);
        assert!((g.re - 1.0).abs() < 1e-4 && g.im.abs() < 1e-4, "{g}");
        let hw = hydro(Some(10e-6));
        let gw = hw.complex_drag(0.0);
        let expect = 1.0 / (1.0 - 9.0 / 16.0 * 0.225);
        assert!((gw.re / expect - 1.0).abs() < 1e-12, "{gw} vs {expect}");
        let m = PsdModel {
            shape: SpectrumShape::Hydrodynamic(h),
            diode: false,
        };
        let (corner_hz, d) = (300.0, 0.5);
        // The leading correction is √(f/f_ν) (f_ν = 63 kHz here): 4e-5 at 0.1 mHz.
        let r = m.eval(1e-4, &[corner_hz, d]) / lorentzian_one_sided(1e-4, corner_hz, d);
        assert!((r - 1.0).abs() < 1e-4, "{r}");
        // At high frequency the bead's inertia and the fluid's reduce the power
        // below the Lorentzian (BSF Fig. 4).
        let r = m.eval(20e3, &[corner_hz, d]) / lorentzian_one_sided(20e3, corner_hz, d);
        assert!(r < 0.95, "{r}");
    }

    #[test]
    fn diode_filter_limits() {
        assert_eq!(diode_filter(0.0, 8e3, 0.3), 1.0);
        assert!((diode_filter(1e9, 8e3, 0.3) - 0.09).abs() < 1e-9);
        assert!((diode_filter(8e3, 8e3, 0.0) - 0.5).abs() < 1e-15);
        let m = PsdModel {
            shape: SpectrumShape::AliasedLorentzian { fs_hz: 1e4 },
            diode: true,
        };
        assert!(m.validate().is_err());
        assert!(
            PsdModel {
                shape: SpectrumShape::Hydrodynamic(hydro(Some(3e-6))),
                diode: false
            }
            .validate()
            .is_err()
        );
    }

    #[test]
    fn aliased_lorentzian_reference_ratios() {
        // REFERENCE-VALUES.md: fs = 10 kHz, corner_hz = 281 Hz → aliased/plain ratio
        // 1.036 at 1 kHz and 2.47 at 5 kHz.
        let (fs, corner_hz, d) = (10e3, 281.0, 1.0);
        let r1 = aliased_lorentzian_one_sided(1000.0, corner_hz, d, fs)
            / lorentzian_one_sided(1000.0, corner_hz, d);
        let r5 = aliased_lorentzian_one_sided(5000.0, corner_hz, d, fs)
            / lorentzian_one_sided(5000.0, corner_hz, d);
        assert!((r1 - 1.036).abs() < 1e-3, "{r1}");
        assert!((r5 - 2.47).abs() < 5e-3, "{r5}");
    }

    #[test]
    fn aliased_lorentzian_integrates_to_equipartition() {
        // ∫₀^{fs/2} P₁ df = D/(2π corner_hz) = kT/κ, for any corner_hz (even above Nyquist).
        for (corner_hz, fs) in [(50.0, 1e4), (281.0, 1e4), (8000.0, 1e4)] {
            let d = 2.0;
            let n = 200_000;
            let h = 0.5 * fs / n as f64;
            let mut s = 0.0;
            for i in 0..=n {
                let w = if i == 0 || i == n { 0.5 } else { 1.0 };
                s += w * aliased_lorentzian_one_sided(i as f64 * h, corner_hz, d, fs);
            }
            s *= h;
            let expect = d / (2.0 * PI * corner_hz);
            assert!(
                (s / expect - 1.0).abs() < 1e-6,
                "corner_hz {corner_hz}: {s} vs {expect}"
            );
        }
    }
}
