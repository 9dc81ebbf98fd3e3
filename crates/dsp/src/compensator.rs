//! Channel compensators of the paper, §3.3.
//!
//! * Low channel (Pantograph, flat from DC to 200 Hz, Ĝ_L ≈ G0_L):
//!   C_L = K_sys / G0_L, a pure gain.
//! * High channel (Haptuator, identified Ĝ_H(s), paper eq. 2): band-limited
//!   inversion C_H(s) = K_sys · F(s) / Ĝ_H(s), with F a realisable 2nd-order
//!   low-pass F(s) = ω_f²/(s² + 2ζω_f s + ω_f²), ω_f = 2π f_corner
//!   (default f_corner = 1 kHz, ζ = 1/√2, i.e. Butterworth: −3 dB at f_corner).
//!
//! Then C_H·Ĝ_H = K_sys·F exactly: flat up to the corner, −40 dB/decade above.
//!
//! Refusals for C_H (each with a clear [`DspError`]):
//! * zeros of Ĝ_H in the right half plane → [`DspError::RightHalfPlaneZeros`]
//!   (inverting them gives an unstable compensator); the error carries the
//!   minimum-phase reflection of Ĝ_H ([`minimum_phase`]), which has the same
//!   magnitude on s = jω and can be inverted instead;
//! * a zero on the imaginary axis (damping ratio below [`AXIS_ZETA`],
//!   including s = 0) → [`DspError::Unstable`] (the inverse would be
//!   marginally stable);
//! * poles of Ĝ_H not in the open left half plane → [`DspError::Unstable`]
//!   (they would be cancelled by compensator zeros: an unstable hidden mode);
//! * relative degree of Ĝ_H above 2 → [`DspError::NotProper`] (C_H would
//!   have more zeros than poles: deg num C_H = deg den Ĝ_H,
//!   deg den C_H = 2 + deg num Ĝ_H).
//!
//! All products are of low order (≤ 4 for the paper's model); C_H is also
//! available directly in zpk form ([`high_zpk`]) so that its digitisation
//! never re-roots an expanded polynomial.

use crate::poly;
use crate::{C64, DspError, Result, Tf, Zpk};
use std::f64::consts::PI;

/// Zeros whose damping ratio −Re(z)/|z| is below this are treated as lying on
/// the imaginary axis (a compensator pole there would ring for ~1e8 periods).
pub const AXIS_ZETA: f64 = 1e-9;

/// Band-limiting filter F(s) of the high compensator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HighCompensatorConfig {
    /// Corner frequency of F in hertz (paper: roll-off from 1 kHz).
    pub f_corner_hz: f64,
    /// Damping ratio of F (1/√2: Butterworth, −3 dB at the corner).
    pub zeta: f64,
}

impl Default for HighCompensatorConfig {
    fn default() -> Self {
        Self {
            f_corner_hz: 1000.0,
            zeta: std::f64::consts::FRAC_1_SQRT_2,
        }
    }
}

/// Low-channel compensator C_L = K_sys/G0_L (paper §3.3), dimensionless gain.
///
/// Errors unless both are finite and non-zero.
pub fn low_gain(k_sys: f64, g0_l: f64) -> Result<f64> {
    check_k_sys(k_sys)?;
    if !(g0_l.is_finite() && g0_l != 0.0) {
        return Err(DspError::InvalidParameter {
            name: "g0_l",
            value: g0_l,
            reason: "low-channel gain G0_L must be finite and non-zero".into(),
        });
    }
    let c = k_sys / g0_l;
    if !c.is_finite() || c == 0.0 {
        return Err(DspError::Numerical(format!(
            "C_L = K_sys/G0_L = {k_sys}/{g0_l} is not a usable gain"
        )));
    }
    Ok(c)
}

fn check_k_sys(k_sys: f64) -> Result<()> {
    if k_sys.is_finite() && k_sys != 0.0 {
        Ok(())
    } else {
        Err(DspError::InvalidParameter {
            name: "k_sys",
            value: k_sys,
            reason: "desired overall gain must be finite and non-zero".into(),
        })
    }
}

fn check_config(f_corner_hz: f64, zeta: f64) -> Result<()> {
    if !(f_corner_hz.is_finite() && f_corner_hz > 0.0) {
        return Err(DspError::InvalidParameter {
            name: "f_corner_hz",
            value: f_corner_hz,
            reason: "corner of F must be finite and > 0 Hz".into(),
        });
    }
    if !(zeta.is_finite() && zeta > 0.0) {
        return Err(DspError::InvalidParameter {
            name: "zeta",
            value: zeta,
            reason: "damping ratio of F must be finite and > 0".into(),
        });
    }
    Ok(())
}

/// F(s) = ω_f²/(s² + 2ζω_f s + ω_f²), ω_f = 2π `f_corner_hz`.
pub fn band_limit(f_corner_hz: f64, zeta: f64) -> Result<Tf> {
    check_config(f_corner_hz, zeta)?;
    let wf = 2.0 * PI * f_corner_hz;
    Tf::new(vec![wf * wf], vec![1.0, 2.0 * zeta * wf, wf * wf])
}

fn fmt_root(z: &C64) -> String {
    format!("{:.6e}{:+.6e}j", z.re, z.im)
}

/// Minimum-phase reflection of `g`: every zero with positive real part is
/// reflected to −z̄ (same imaginary part, negated real part). The leading
/// coefficient is kept, so |G_mp(jω)| = |G(jω)| for all ω, since
/// |jω − z| = |jω + z̄|. Zeros in the closed left half plane are kept as they
/// are (a model with no right-half-plane zero is returned unchanged).
pub fn minimum_phase(g: &Tf) -> Result<Tf> {
    let zeros = g.zeros()?;
    if zeros.iter().all(|z| z.re <= 0.0) {
        return Ok(g.clone());
    }
    let reflected: Vec<C64> = zeros
        .iter()
        .map(|z| {
            if z.re > 0.0 {
                C64::new(-z.re, z.im)
            } else {
                *z
            }
        })
        .collect();
    Tf::new(poly::poly_from_roots(&reflected, g.num[0]), g.den.clone())
}

/// C_H in zpk form (rad/s): zeros = poles of Ĝ_H, poles = zeros of Ĝ_H plus
/// the two poles of F, gain K_sys·ω_f²·(den₀/num₀) (leading coefficients of
/// Ĝ_H). See the module docs for the refusals.
pub fn high_zpk(k_sys: f64, g_h: &Tf, f_corner_hz: f64, zeta: f64) -> Result<Zpk> {
    check_k_sys(k_sys)?;
    check_config(f_corner_hz, zeta)?;
    let zeros = g_h.zeros()?;
    let poles = g_h.poles()?;
    if let Some(z) = zeros.iter().find(|z| -z.re <= AXIS_ZETA * z.norm()) {
        if z.re > AXIS_ZETA * z.norm() {
            let rhp: Vec<String> = zeros.iter().filter(|z| z.re > 0.0).map(fmt_root).collect();
            return Err(DspError::RightHalfPlaneZeros {
                count: rhp.len(),
                zeros: rhp,
                minimum_phase: Box::new(minimum_phase(g_h)?),
            });
        }
        return Err(DspError::Unstable(format!(
            "Ĝ_H has a zero on the imaginary axis at {} rad/s; its inverse would be marginally stable",
            fmt_root(z)
        )));
    }
    if let Some(p) = poles.iter().find(|p| p.re.is_nan() || p.re >= 0.0) {
        return Err(DspError::Unstable(format!(
            "Ĝ_H has a pole at {} rad/s outside the open left half plane; an identified channel must be stable",
            fmt_root(p)
        )));
    }
    // Relative degree of Ĝ_H must be ≤ 2 (F supplies two poles).
    let num_degree = poles.len();
    let den_degree = zeros.len() + 2;
    if num_degree > den_degree {
        return Err(DspError::NotProper {
            num_degree,
            den_degree,
        });
    }
    let wf = 2.0 * PI * f_corner_hz;
    let f = band_limit(f_corner_hz, zeta)?.poles()?;
    let gain = k_sys * wf * wf * g_h.den[0] / g_h.num[0];
    if !gain.is_finite() {
        return Err(DspError::Numerical("C_H gain overflowed".into()));
    }
    Ok(Zpk {
        zeros: poles,
        poles: zeros.into_iter().chain(f).collect(),
        gain,
    })
}

/// High-channel compensator C_H(s) = K_sys·F(s)/Ĝ_H(s) as a rational
/// transfer function (paper §3.3); `f_corner_hz`, `zeta` define F. The
/// products are low order: num = K_sys ω_f² · den(Ĝ_H),
/// den = (s² + 2ζω_f s + ω_f²) · num(Ĝ_H). See the module docs for the
/// refusals.
pub fn high(k_sys: f64, g_h: &Tf, f_corner_hz: f64, zeta: f64) -> Result<Tf> {
    // All checks (and the error variants) are shared with the zpk form.
    high_zpk(k_sys, g_h, f_corner_hz, zeta)?;
    let wf = 2.0 * PI * f_corner_hz;
    let num: Vec<f64> = g_h.den.iter().map(|c| c * k_sys * wf * wf).collect();
    let den = conv(&[1.0, 2.0 * zeta * wf, wf * wf], &g_h.num);
    Tf::new(num, den)
}

/// [`high`] with a [`HighCompensatorConfig`].
pub fn high_with(k_sys: f64, g_h: &Tf, cfg: &HighCompensatorConfig) -> Result<Tf> {
    high(k_sys, g_h, cfg.f_corner_hz, cfg.zeta)
}

/// Polynomial product (descending powers).
fn conv(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}

/// The paper's identified Haptuator channel, eq. 2:
/// Ĝ_H(s) = (250 s + 6.40e5)/(s² + 2135 s + 4.56e6).
pub fn paper_g_h() -> Tf {
    Tf {
        num: vec![250.0, 6.40e5],
        den: vec![1.0, 2135.0, 4.56e6],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn jw(f: f64) -> C64 {
        C64::new(0.0, 2.0 * PI * f)
    }

    #[test]
    fn low_gain_is_ratio_and_validated() {
        assert_eq!(low_gain(1.0, 1.0).unwrap(), 1.0);
        assert_eq!(low_gain(2.0, 0.5).unwrap(), 4.0);
        assert_eq!(low_gain(1.0, -4.0).unwrap(), -0.25);
        assert!(low_gain(1.0, 0.0).is_err());
        assert!(low_gain(0.0, 1.0).is_err());
        assert!(low_gain(f64::NAN, 1.0).is_err());
        assert!(low_gain(1.0, f64::INFINITY).is_err());
        assert!(low_gain(1e300, 1e-300).is_err());
    }

    #[test]
    fn default_config_is_paper_choice() {
        let c = HighCompensatorConfig::default();
        assert_eq!(c.f_corner_hz, 1000.0);
        assert!((c.zeta - 1.0 / 2f64.sqrt()).abs() < 1e-15);
    }

    /// |C_H·G_H| = K_sys·|F| with the paper's G_H: flat (K_sys) at low
    /// frequency, −3 dB at 1 kHz for ζ = 1/√2, −40 dB/decade above.
    #[test]
    fn compensated_high_channel_is_ksys_times_f() {
        let g = paper_g_h();
        let k_sys = 2.5;
        let cfg = HighCompensatorConfig::default();
        let c = high_with(k_sys, &g, &cfg).unwrap();
        let cz = high_zpk(k_sys, &g, cfg.f_corner_hz, cfg.zeta).unwrap();
        assert!(c.is_proper());
        assert_eq!((c.num_degree(), c.den_degree()), (2, 3));
        let wf = 2.0 * PI * 1000.0;
        for f in [
            1.0, 10.0, 63.0957, 200.0, 316.228, 500.0, 1000.0, 2000.0, 10_000.0,
        ] {
            let s = jw(f);
            let fs_ = wf * wf / (s * s + 2.0 * cfg.zeta * wf * s + wf * wf);
            let want = k_sys * fs_;
            let got = c.eval(s) * g.eval(s);
            assert!(
                (got - want).norm() < 1e-12 * want.norm(),
                "f={f}: {got} vs {want}"
            );
            let got_z = cz.eval(s) * g.eval(s);
            assert!((got_z - want).norm() < 1e-12 * want.norm(), "zpk f={f}");
            // Butterworth magnitude of F: 1/sqrt(1 + (f/1000)^4).
            let m = 1.0 / (1.0 + (f / 1000.0).powi(4)).sqrt();
            assert!((got.norm() / k_sys - m).abs() < 1e-12, "f={f}");
        }
        // −3 dB (−3.0103 dB) at the corner.
        let at = 20.0 * ((c.eval(jw(1000.0)) * g.eval(jw(1000.0))).norm() / k_sys).log10();
        assert!((at + 3.0103).abs() < 1e-4, "{at}");
        // C_H itself at 1 kHz: K_sys·|F|/|G_H| = 2.5·(1/√2)/0.0453443.
        let ch = c.eval(jw(1000.0)).norm();
        assert!((ch - k_sys * 0.5f64.sqrt() / 0.0453443).abs() < 1e-4 * ch);
        // DC gain K_sys/G_H(0) = 2.5/0.140351.
        assert!((c.dc_gain() - k_sys / 0.140351).abs() < 1e-4);
    }

    #[test]
    fn other_corner_and_damping() {
        let g = paper_g_h();
        let c = high(1.0, &g, 700.0, 0.4).unwrap();
        // At the corner |F| = 1/(2ζ).
        let s = jw(700.0);
        assert!(((c.eval(s) * g.eval(s)).norm() - 1.0 / 0.8).abs() < 1e-12);
    }

    #[test]
    fn right_half_plane_zero_is_refused_with_reflection() {
        // Non-minimum-phase variant of the paper's model: zero at +2560 rad/s.
        let g = Tf::new(vec![-250.0, 6.40e5], vec![1.0, 2135.0, 4.56e6]).unwrap();
        match high(1.0, &g, 1000.0, std::f64::consts::FRAC_1_SQRT_2) {
            Err(DspError::RightHalfPlaneZeros {
                count,
                zeros,
                minimum_phase,
            }) => {
                assert_eq!(count, 1);
                assert_eq!(zeros.len(), 1);
                let mp = *minimum_phase;
                // Same magnitude on jω, all zeros in the LHP.
                for f in [0.0, 10.0, 407.44, 1000.0, 1e5] {
                    let a = g.response_hz(f).norm();
                    let b = mp.response_hz(f).norm();
                    assert!((a - b).abs() < 1e-12 * a, "f={f}");
                }
                assert!(mp.zeros().unwrap().iter().all(|z| z.re < 0.0));
                // Reflected zero at −2560 rad/s.
                assert!((mp.zeros().unwrap()[0].re + 2560.0).abs() < 1e-9);
                // And the reflection can be compensated.
                assert!(high(1.0, &mp, 1000.0, 0.7).is_ok());
            }
            other => panic!("expected RightHalfPlaneZeros, got {other:?}"),
        }
        // Complex RHP pair, higher order: the reflection matches on jω too.
        let num = poly::poly_from_roots(
            &[
                C64::new(300.0, 2000.0),
                C64::new(300.0, -2000.0),
                C64::new(-50.0, 0.0),
            ],
            3.0,
        );
        let g2 = Tf::new(num, vec![1.0, 2000.0, 3e6, 1e9]).unwrap();
        let mp = minimum_phase(&g2).unwrap();
        for f in [1.0, 100.0, 318.0, 5000.0] {
            let a = g2.response_hz(f).norm();
            assert!((a - mp.response_hz(f).norm()).abs() < 1e-10 * a);
        }
        assert!(matches!(
            high(1.0, &g2, 1000.0, 0.7),
            Err(DspError::RightHalfPlaneZeros { count: 2, .. })
        ));
        // A minimum-phase model is returned unchanged.
        assert_eq!(minimum_phase(&paper_g_h()).unwrap(), paper_g_h());
    }

    #[test]
    fn zero_on_imaginary_axis_is_refused() {
        // Acceleration-type response with a zero at s = 0.
        let g = Tf::new(vec![250.0, 0.0], vec![1.0, 2135.0, 4.56e6]).unwrap();
        assert!(matches!(
            high(1.0, &g, 1000.0, 0.7),
            Err(DspError::Unstable(_))
        ));
        // Undamped zero pair at ±j 1000 rad/s.
        let g = Tf::new(vec![1.0, 0.0, 1e6], vec![1.0, 2135.0, 4.56e6]).unwrap();
        assert!(matches!(
            high(1.0, &g, 1000.0, 0.7),
            Err(DspError::Unstable(_))
        ));
    }

    #[test]
    fn improper_result_is_refused() {
        // Relative degree 3 > 2: C_H would have deg num 3 > deg den 2.
        let g = Tf::new(vec![1e9], vec![1.0, 3000.0, 4e6, 2e9]).unwrap();
        assert!(matches!(
            high(1.0, &g, 1000.0, 0.7),
            Err(DspError::NotProper {
                num_degree: 3,
                den_degree: 2
            })
        ));
        // Relative degree exactly 2 is fine (C_H biproper).
        let g = Tf::new(vec![4.56e6], vec![1.0, 2135.0, 4.56e6]).unwrap();
        let c = high(1.0, &g, 1000.0, 0.7).unwrap();
        assert_eq!(c.num_degree(), c.den_degree());
    }

    #[test]
    fn unstable_plant_and_bad_parameters_are_refused() {
        let g = Tf::new(vec![250.0, 6.4e5], vec![1.0, -10.0, 4.56e6]).unwrap();
        assert!(matches!(
            high(1.0, &g, 1000.0, 0.7),
            Err(DspError::Unstable(_))
        ));
        let g = paper_g_h();
        assert!(high(0.0, &g, 1000.0, 0.7).is_err());
        assert!(high(1.0, &g, 0.0, 0.7).is_err());
        assert!(high(1.0, &g, 1000.0, 0.0).is_err());
        assert!(high(1.0, &g, f64::NAN, 0.7).is_err());
    }
}
