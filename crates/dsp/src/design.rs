//! IIR design: analog Butterworth prototypes, frequency transforms, the
//! bilinear transform with prewarping, and zpk → second-order sections.
//!
//! Everything stays in zero-pole-gain form until the final pairing into
//! sections; high-order polynomials are never expanded (an LR8 at
//! fc/fs = 1e-4 would be hopeless as a 16th-order polynomial).
//!
//! Conventions: analog zpk in rad/s, H(s) = k ∏(s − zᵢ)/∏(s − pᵢ); digital zpk
//! in z, H(z) = k ∏(z − zᵢ)/∏(z − pᵢ). Frequencies `fc`, `fs`, prewarp in hertz.
//!
//! References: scipy.signal `buttap`, `lp2hp_zpk`, `bilinear_zpk`, `zpk2sos`
//! (pairing = 'nearest'); Oppenheim & Schafer, *Discrete-Time Signal
//! Processing*, 3rd ed., §7.2 (bilinear transformation and frequency warping).

use crate::filter::BiquadCoeffs;
use crate::{C64, DspError, Result, Tf, Zpk};
use std::f64::consts::PI;

/// Highest Butterworth order accepted (LR8 needs 4; generous headroom).
pub const MAX_BUTTER_ORDER: usize = 24;

/// Low-pass or high-pass.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FilterKind {
    /// Low-pass.
    Lowpass,
    /// High-pass.
    Highpass,
}

/// Bilinear-transform frequency prewarping for filter designs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Prewarp {
    /// No prewarping: K = 2 fs. Analog frequencies are compressed by
    /// ω_d = 2 arctan(ω_a/(2 fs)).
    None,
    /// Prewarp at the design's cut-off frequency (the usual choice).
    AtCutoff,
    /// Prewarp at the given frequency in hertz, in (0, fs/2).
    AtHz(f64),
}

fn param(name: &'static str, value: f64, reason: &str) -> DspError {
    DspError::InvalidParameter {
        name,
        value,
        reason: reason.into(),
    }
}

fn check_fs(fs: f64) -> Result<()> {
    if fs.is_finite() && fs > 0.0 {
        Ok(())
    } else {
        Err(param("fs", fs, "sample rate must be finite and > 0"))
    }
}

fn check_order(order: usize) -> Result<()> {
    if (1..=MAX_BUTTER_ORDER).contains(&order) {
        Ok(())
    } else {
        Err(param(
            "order",
            order as f64,
            &format!("Butterworth order must be in 1..={MAX_BUTTER_ORDER}"),
        ))
    }
}

/// Analog Butterworth low-pass prototype of the given order (ωc = 1 rad/s):
/// no zeros, poles pₖ = −sin θₖ ± j cos θₖ with θₖ = π(2k+1)/(2n) (all on the
/// unit circle, left half plane), gain 1 (so H(0) = 1/∏(−pₖ) = 1).
///
/// Conjugate pairs are built explicitly, so they are exact conjugates; for odd
/// orders the real pole is exactly −1.
pub fn butter_prototype(order: usize) -> Result<Zpk> {
    check_order(order)?;
    let mut poles = Vec::with_capacity(order);
    for k in 0..order / 2 {
        let theta = PI * (2 * k + 1) as f64 / (2 * order) as f64;
        let p = C64::new(-theta.sin(), theta.cos());
        poles.push(p);
        poles.push(p.conj());
    }
    if order % 2 == 1 {
        poles.push(C64::new(-1.0, 0.0));
    }
    Ok(Zpk {
        zeros: Vec::new(),
        poles,
        gain: 1.0,
    })
}

fn check_wc(wc: f64) -> Result<()> {
    if wc.is_finite() && wc > 0.0 {
        Ok(())
    } else {
        Err(param("wc", wc, "cut-off must be finite and > 0 rad/s"))
    }
}

/// Low-pass → low-pass transform s → s/ωc (ωc in rad/s): zeros and poles
/// scaled by ωc, gain by ωc^(n_p − n_z) (scipy `lp2lp_zpk`).
pub fn lp_to_lp(proto: &Zpk, wc: f64) -> Result<Zpk> {
    check_wc(wc)?;
    let degree = proto.poles.len() as i32 - proto.zeros.len() as i32;
    Ok(Zpk {
        zeros: proto.zeros.iter().map(|z| z * wc).collect(),
        poles: proto.poles.iter().map(|p| p * wc).collect(),
        gain: proto.gain * wc.powi(degree),
    })
}

/// Low-pass → high-pass transform s → ωc/s (ωc in rad/s), scipy `lp2hp_zpk`:
/// zᵢ → ωc/zᵢ, pᵢ → ωc/pᵢ, n_p − n_z new zeros at s = 0,
/// k → k·Re(∏(−zᵢ)/∏(−pᵢ)). Errors if a zero or pole sits at s = 0.
pub fn lp_to_hp(proto: &Zpk, wc: f64) -> Result<Zpk> {
    check_wc(wc)?;
    if proto.zeros.len() > proto.poles.len() {
        return Err(DspError::NotProper {
            num_degree: proto.zeros.len(),
            den_degree: proto.poles.len(),
        });
    }
    if proto
        .zeros
        .iter()
        .chain(&proto.poles)
        .any(|r| r.norm() == 0.0)
    {
        return Err(DspError::Degenerate(
            "low-pass to high-pass transform of a zero or pole at s = 0".into(),
        ));
    }
    let mut zeros: Vec<C64> = proto.zeros.iter().map(|z| wc / z).collect();
    zeros.extend(std::iter::repeat_n(
        C64::new(0.0, 0.0),
        proto.poles.len() - proto.zeros.len(),
    ));
    let poles = proto.poles.iter().map(|p| wc / p).collect();
    let num: C64 = proto.zeros.iter().map(|z| -z).product();
    let den: C64 = proto.poles.iter().map(|p| -p).product();
    Ok(Zpk {
        zeros,
        poles,
        gain: proto.gain * (num / den).re,
    })
}

/// Analog Butterworth filter of the given order with −3 dB point at `wc`
/// rad/s, in zpk form.
pub fn butter_analog(order: usize, wc: f64, kind: FilterKind) -> Result<Zpk> {
    let proto = butter_prototype(order)?;
    match kind {
        FilterKind::Lowpass => lp_to_lp(&proto, wc),
        FilterKind::Highpass => lp_to_hp(&proto, wc),
    }
}

/// Bilinear-transform constant K in s = K (z − 1)/(z + 1).
///
/// Without prewarping K = 2 fs. With prewarping at f_p hertz,
/// K = ω_p / tan(ω_p/(2 fs)), ω_p = 2π f_p, so that the analog frequency ω_p
/// maps exactly onto the digital frequency ω_p (Oppenheim & Schafer eq. 7.26).
pub fn bilinear_constant(fs: f64, prewarp_hz: Option<f64>) -> Result<f64> {
    check_fs(fs)?;
    match prewarp_hz {
        None => Ok(2.0 * fs),
        Some(fp) => {
            if !(fp.is_finite() && fp > 0.0 && fp < fs / 2.0) {
                return Err(param(
                    "prewarp",
                    fp,
                    "prewarp frequency must be in (0, fs/2) hertz",
                ));
            }
            let wp = 2.0 * PI * fp;
            Ok(wp / (wp / (2.0 * fs)).tan())
        }
    }
}

/// Bilinear transform of an analog zpk (rad/s) to a digital zpk:
/// z = (K + s)/(K − s) for every zero and pole, n_p − n_z extra zeros at
/// z = −1, gain k·Re(∏(K − zᵢ)/∏(K − pᵢ)) (scipy `bilinear_zpk`, with K
/// from [`bilinear_constant`]).
///
/// Errors on an improper system (more zeros than poles) or a root at s = K.
pub fn bilinear(analog: &Zpk, fs: f64, prewarp_hz: Option<f64>) -> Result<Zpk> {
    let k = bilinear_constant(fs, prewarp_hz)?;
    if analog.zeros.len() > analog.poles.len() {
        return Err(DspError::NotProper {
            num_degree: analog.zeros.len(),
            den_degree: analog.poles.len(),
        });
    }
    if !analog.gain.is_finite()
        || analog
            .zeros
            .iter()
            .chain(&analog.poles)
            .any(|r| !r.is_finite())
    {
        return Err(DspError::InvalidInput(
            "analog zpk has non-finite entries".into(),
        ));
    }
    let kc = C64::new(k, 0.0);
    if analog
        .zeros
        .iter()
        .chain(&analog.poles)
        .any(|r| (kc - r).norm() == 0.0)
    {
        return Err(DspError::Degenerate(
            "a root at s = K maps to z = ∞ under the bilinear transform".into(),
        ));
    }
    let map = |r: &C64| (kc + r) / (kc - r);
    let mut zeros: Vec<C64> = analog.zeros.iter().map(map).collect();
    zeros.extend(std::iter::repeat_n(
        C64::new(-1.0, 0.0),
        analog.poles.len() - analog.zeros.len(),
    ));
    let poles = analog.poles.iter().map(map).collect();
    let num: C64 = analog.zeros.iter().map(|z| kc - z).product();
    let den: C64 = analog.poles.iter().map(|p| kc - p).product();
    let gain = analog.gain * (num / den).re;
    if !gain.is_finite() {
        return Err(DspError::Numerical(
            "bilinear transform gain overflowed".into(),
        ));
    }
    Ok(Zpk { zeros, poles, gain })
}

/// Digital Butterworth filter in zpk form (order n, −3 dB at `fc` hertz).
pub fn butter_zpk(
    order: usize,
    fc: f64,
    fs: f64,
    kind: FilterKind,
    prewarp: Prewarp,
) -> Result<Zpk> {
    check_fs(fs)?;
    if !(fc.is_finite() && fc > 0.0 && fc < fs / 2.0) {
        return Err(param("fc", fc, "cut-off must be in (0, fs/2) hertz"));
    }
    let analog = butter_analog(order, 2.0 * PI * fc, kind)?;
    let pw = match prewarp {
        Prewarp::None => None,
        Prewarp::AtCutoff => Some(fc),
        Prewarp::AtHz(f) => Some(f),
    };
    bilinear(&analog, fs, pw)
}

/// Digital Butterworth filter as second-order sections.
pub fn butter(
    order: usize,
    fc: f64,
    fs: f64,
    kind: FilterKind,
    prewarp: Prewarp,
) -> Result<Vec<BiquadCoeffs>> {
    zpk2sos(&butter_zpk(order, fc, fs, kind, prewarp)?)
}

/// Digital frequency response of a zpk at `f` hertz (sample rate `fs`):
/// H(e^{j2πf/fs}), evaluated factor by factor.
pub fn digital_response(zpk: &Zpk, f: f64, fs: f64) -> C64 {
    zpk.digital_response(f, fs)
}

/// Split roots into complex ones (one per conjugate pair, positive imaginary
/// part) and real ones, like scipy's `_cplxreal` (tolerance 100·eps·|z|).
/// Errors if a complex root has no conjugate partner.
fn cplxreal(roots: &[C64]) -> Result<(Vec<C64>, Vec<f64>)> {
    let tol = |z: &C64| 100.0 * f64::EPSILON * z.norm();
    let mut reals = Vec::new();
    let mut pos = Vec::new();
    let mut neg = Vec::new();
    for z in roots {
        if z.im.abs() <= tol(z) {
            reals.push(z.re);
        } else if z.im > 0.0 {
            pos.push(*z);
        } else {
            neg.push(*z);
        }
    }
    if pos.len() != neg.len() {
        return Err(DspError::InvalidInput(
            "complex roots are not in conjugate pairs".into(),
        ));
    }
    let mut out = Vec::with_capacity(pos.len());
    for z in pos {
        let (idx, d) = neg
            .iter()
            .enumerate()
            .map(|(i, w)| (i, (z - w.conj()).norm()))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .ok_or_else(|| DspError::InvalidInput("unpaired complex root".into()))?;
        if d > 1e3 * tol(&z).max(f64::MIN_POSITIVE) {
            return Err(DspError::InvalidInput(format!(
                "complex root {z} has no conjugate partner"
            )));
        }
        let w = neg.swap_remove(idx);
        out.push((z + w.conj()) / 2.0);
    }
    out.sort_by(|a, b| a.re.total_cmp(&b.re).then(a.im.total_cmp(&b.im)));
    reals.sort_by(f64::total_cmp);
    Ok((out, reals))
}

/// A root after `cplxreal`: complex (stands for the pair) or real.
#[derive(Debug, Clone, Copy)]
enum Root {
    Pair(C64),
    Real(f64),
}

impl Root {
    fn value(self) -> C64 {
        match self {
            Root::Pair(z) => z,
            Root::Real(r) => C64::new(r, 0.0),
        }
    }
    fn is_real(self) -> bool {
        matches!(self, Root::Real(_))
    }
}

fn reduce(roots: &[C64]) -> Result<Vec<Root>> {
    let (c, r) = cplxreal(roots)?;
    Ok(c.into_iter()
        .map(Root::Pair)
        .chain(r.into_iter().map(Root::Real))
        .collect())
}

/// Index of the root nearest to `to`, restricted to real / complex / any.
fn nearest(from: &[Root], to: C64, want: Option<bool>) -> Option<usize> {
    from.iter()
        .enumerate()
        .filter(|(_, r)| want.is_none_or(|real| r.is_real() == real))
        .min_by(|a, b| {
            (a.1.value() - to)
                .norm()
                .total_cmp(&(b.1.value() - to).norm())
        })
        .map(|(i, _)| i)
}

/// Monic polynomial coefficients in z⁻¹ (length 3) of up to two roots, in the
/// right-aligned convention of scipy `_single_zpksos`.
fn quad(roots: &[Root]) -> [f64; 3] {
    match roots {
        [] => [0.0, 0.0, 1.0],
        [Root::Real(r)] => [0.0, 1.0, -r],
        [Root::Pair(z)] => [1.0, -2.0 * z.re, z.norm_sqr()],
        [Root::Real(a), Root::Real(b)] => [1.0, -(a + b), a * b],
        // Mixed or two pairs cannot occur in the pairing below.
        _ => [f64::NAN; 3],
    }
}

/// Digital zpk → second-order sections with scipy's `zpk2sos` 'nearest'
/// pairing rules, in the variant scipy calls `pairing='keep_odd'`.
///
/// Poles closest to the unit circle are taken first and placed in the *last*
/// section; each is paired with the nearest zero(s); complex roots stay with
/// their conjugates and two real poles share a section. For an odd order the
/// one real pole left without a partner gets a true first-order section
/// (b2 = a2 = 0) with its nearest real zero. (Plain 'nearest' instead adds a
/// cancelling pole/zero pair at z = 0 and may split it across two sections,
/// leaving no section with b2 = a2 = 0; the overall response is the same.)
/// The overall gain goes into the first section's numerator.
///
/// Zeros in excess of poles (non-causal) are refused. Fewer zeros than poles
/// are realised as delays (leading zero numerator coefficients), so the
/// sections reproduce H(z) exactly; scipy instead pads zeros at z = 0, which
/// multiplies the response by a power of z. Bilinear designs always have equal
/// counts, where both agree.
pub fn zpk2sos(zpk: &Zpk) -> Result<Vec<BiquadCoeffs>> {
    if !zpk.gain.is_finite() {
        return Err(DspError::InvalidInput("zpk gain must be finite".into()));
    }
    if zpk.zeros.len() > zpk.poles.len() {
        return Err(DspError::NotProper {
            num_degree: zpk.zeros.len(),
            den_degree: zpk.poles.len(),
        });
    }
    if zpk.poles.is_empty() {
        return Ok(vec![BiquadCoeffs::gain(zpk.gain)?]);
    }
    let n_sections = zpk.poles.len().div_ceil(2);
    let mut z = reduce(&zpk.zeros)?;
    let mut p = reduce(&zpk.poles)?;
    let missing = || DspError::Numerical("zpk2sos pairing ran out of roots".into());
    let mut sos = vec![BiquadCoeffs::IDENTITY; n_sections];
    for si in (0..n_sections).rev() {
        // The "worst" remaining pole: closest to the unit circle.
        let p1_idx = p
            .iter()
            .enumerate()
            .min_by(|a, b| {
                (1.0 - a.1.value().norm())
                    .abs()
                    .total_cmp(&(1.0 - b.1.value().norm()).abs())
            })
            .map(|(i, _)| i)
            .ok_or_else(missing)?;
        let p1 = p.remove(p1_idx);
        let reals_p = p.iter().filter(|r| r.is_real()).count();
        let reals_z = z.iter().filter(|r| r.is_real()).count();
        let (zs, ps): (Vec<Root>, Vec<Root>) = if p1.is_real() && reals_p == 0 {
            // Special case 1: last remaining real pole → first-order section
            // (the added pole at z = 0 is cancelled by an added zero at 0).
            let zs = match nearest(&z, p1.value(), Some(true)) {
                Some(i) => vec![z.remove(i), Root::Real(0.0)],
                None if z.is_empty() => vec![Root::Real(0.0)],
                None => return Err(missing()),
            };
            (zs, vec![p1, Root::Real(0.0)])
        } else if p.len() + 1 == z.len() && !p1.is_real() && reals_p == 1 && reals_z == 1 {
            // Special case 2: one real pole and one real zero left with equal
            // counts: the complex pole must take a complex zero.
            let i = nearest(&z, p1.value(), Some(false)).ok_or_else(missing)?;
            (vec![z.remove(i)], vec![p1])
        } else {
            let p2 = if p1.is_real() {
                let i = p
                    .iter()
                    .enumerate()
                    .filter(|(_, r)| r.is_real())
                    .min_by(|a, b| {
                        (a.1.value().norm() - 1.0)
                            .abs()
                            .total_cmp(&(b.1.value().norm() - 1.0).abs())
                    })
                    .map(|(i, _)| i)
                    .ok_or_else(missing)?;
                Some(p.remove(i))
            } else {
                None
            };
            let ps: Vec<Root> = std::iter::once(p1).chain(p2).collect();
            if z.is_empty() {
                (Vec::new(), ps)
            } else {
                let i = nearest(&z, p1.value(), None).ok_or_else(missing)?;
                let z1 = z.remove(i);
                if !z1.is_real() {
                    (vec![z1], ps)
                } else if !z.is_empty() {
                    let j = nearest(&z, p1.value(), Some(true)).ok_or_else(missing)?;
                    (vec![z1, z.remove(j)], ps)
                } else {
                    (vec![z1], ps)
                }
            }
        };
        sos[si] = section(quad(&zs), quad(&ps))?;
    }
    sos[0] = sos[0].scaled(zpk.gain);
    Ok(sos)
}

/// Build a section from right-aligned polynomials in z (b and a of length 3).
/// Both are multiplied by z^(2 − deg a) so that a0 = 1.
fn section(b: [f64; 3], a: [f64; 3]) -> Result<BiquadCoeffs> {
    if b.iter().chain(a.iter()).any(|c| !c.is_finite()) {
        return Err(DspError::Numerical("zpk2sos produced a bad section".into()));
    }
    // In zpk2sos every section has two poles (one may be the added z = 0),
    // so a is monic: a = [1, a1, a2].
    BiquadCoeffs::new(b, a)
}

/// Continuous-time zpk (rad/s) → stable digital second-order sections via the
/// bilinear transform (prewarped at `prewarp_hz` if given).
///
/// Refuses an improper system ([`DspError::NotProper`]), analog poles that
/// are not strictly in the left half plane ([`DspError::Unstable`]) and
/// verifies that every digital pole is strictly inside the unit circle and
/// every section passes the stability triangle.
pub fn analog_zpk_to_sos(
    analog: &Zpk,
    fs: f64,
    prewarp_hz: Option<f64>,
) -> Result<Vec<BiquadCoeffs>> {
    if analog.zeros.len() > analog.poles.len() {
        return Err(DspError::NotProper {
            num_degree: analog.zeros.len(),
            den_degree: analog.poles.len(),
        });
    }
    if let Some(p) = analog.poles.iter().find(|p| p.re.is_nan() || p.re >= 0.0) {
        return Err(DspError::Unstable(format!(
            "analog pole {p} rad/s is not in the open left half plane"
        )));
    }
    let digital = bilinear(analog, fs, prewarp_hz)?;
    if let Some(p) = digital
        .poles
        .iter()
        .find(|p| p.norm().is_nan() || p.norm() >= 1.0)
    {
        return Err(DspError::Unstable(format!(
            "digital pole {p} (|p| = {}) is not inside the unit circle",
            p.norm()
        )));
    }
    let sos = zpk2sos(&digital)?;
    if let Some(c) = sos.iter().find(|c| !c.is_stable()) {
        return Err(DspError::Unstable(format!(
            "section {c:?} is unstable after rounding"
        )));
    }
    Ok(sos)
}

/// Continuous-time transfer function (e.g. a compensator in s) → stable
/// digital second-order sections: `tf` → zpk (roots of the low-order
/// numerator and denominator) → bilinear (prewarped at `prewarp_hz` if given)
/// → [`zpk2sos`]. See [`analog_zpk_to_sos`] for the refusals.
pub fn tf_to_sos(tf: &Tf, fs: f64, prewarp_hz: Option<f64>) -> Result<Vec<BiquadCoeffs>> {
    if !tf.is_proper() {
        return Err(DspError::NotProper {
            num_degree: tf.num_degree(),
            den_degree: tf.den_degree(),
        });
    }
    analog_zpk_to_sos(&tf.to_zpk()?, fs, prewarp_hz)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::sections_response;

    fn rel(a: C64, b: C64) -> f64 {
        (a - b).norm() / b.norm()
    }

    /// |B_n(jω)|² = 1/(1 + (ω/ωc)^{2n}) — the defining property.
    #[test]
    fn butterworth_analog_magnitude_is_maximally_flat() {
        for n in 1..=10 {
            let wc = 2.0 * PI * 123.0;
            let lp = butter_analog(n, wc, FilterKind::Lowpass).unwrap();
            let hp = butter_analog(n, wc, FilterKind::Highpass).unwrap();
            for p in &lp.poles {
                assert!((p.norm() - wc).abs() < 1e-12 * wc && p.re < 0.0);
            }
            for r in [0.01, 0.5, 1.0, 2.0, 30.0] {
                let w = r * wc;
                let s = C64::new(0.0, w);
                let want = 1.0 / (1.0 + r.powi(2 * n as i32));
                assert!((lp.eval(s).norm_sqr() - want).abs() < 1e-13, "n={n} r={r}");
                // High-pass: |H|² = r^{2n}/(1 + r^{2n}).
                let want_h = 1.0 - want;
                assert!(
                    (hp.eval(s).norm_sqr() - want_h).abs() < 1e-13,
                    "hp n={n} r={r}"
                );
            }
            assert_eq!(hp.zeros.len(), n);
        }
    }

    #[test]
    fn prototype_poles_are_conjugate_pairs_on_unit_circle() {
        let z = butter_prototype(5).unwrap();
        assert_eq!(z.poles.len(), 5);
        assert_eq!(z.poles[4], C64::new(-1.0, 0.0));
        assert_eq!(z.poles[0], z.poles[1].conj());
        // Order 2: poles −1/√2 ± j/√2.
        let z2 = butter_prototype(2).unwrap();
        assert!((z2.poles[0] - C64::new(-0.5f64.sqrt(), 0.5f64.sqrt())).norm() < 1e-15);
        assert!(butter_prototype(0).is_err());
        assert!(butter_prototype(MAX_BUTTER_ORDER + 1).is_err());
    }

    #[test]
    fn bilinear_maps_prewarp_frequency_exactly() {
        // Digital response at f equals the analog response at
        // ω_a = K tan(π f/fs) (the bilinear frequency map, O&S eq. 7.24).
        let fs = 10_000.0;
        let analog = butter_analog(4, 2.0 * PI * 1000.0, FilterKind::Lowpass).unwrap();
        for pw in [None, Some(1000.0), Some(37.0), Some(4900.0)] {
            let k = bilinear_constant(fs, pw).unwrap();
            let d = bilinear(&analog, fs, pw).unwrap();
            for f in [0.0, 10.0, 500.0, 1000.0, 3000.0, 4990.0] {
                let wa = k * (PI * f / fs).tan();
                let want = analog.eval(C64::new(0.0, wa));
                let got = d.digital_response(f, fs);
                assert!(
                    (got - want).norm() <= 1e-12 * want.norm().max(1e-12),
                    "pw={pw:?} f={f}"
                );
            }
        }
        // Prewarped at fc: |H(fc)| = 1/√2 exactly. Without prewarp the digital
        // 1 kHz sees the analog response at tan(π/10)/(π/10) = 1.0343 times
        // the corner (REFERENCE-VALUES.md), and the −3 dB point moves down to
        // fs/π·atan(π fc/fs) = 968.92 Hz.
        let d = bilinear(&analog, fs, Some(1000.0)).unwrap();
        assert!((d.digital_response(1000.0, fs).norm() - 0.5f64.sqrt()).abs() < 1e-13);
        let ratio = (PI / 10.0).tan() / (PI / 10.0);
        assert!((ratio - 1.0343).abs() < 5e-5);
        let k2 = bilinear_constant(fs, None).unwrap();
        assert_eq!(k2, 2.0 * fs);
        let d0 = bilinear(&analog, fs, None).unwrap();
        let at_1k = analog.eval(C64::new(0.0, ratio * 2.0 * PI * 1000.0));
        assert!((d0.digital_response(1000.0, fs) - at_1k).norm() < 1e-13);
        assert!((d0.digital_response(1000.0, fs).norm() - 0.5f64.sqrt()).abs() > 0.02);
        let f3 = fs / PI * (2.0 * PI * 1000.0 / (2.0 * fs)).atan();
        assert!((f3 - 968.92).abs() < 0.01, "{f3}");
        assert!((d0.digital_response(f3, fs).norm() - 0.5f64.sqrt()).abs() < 1e-13);
    }

    #[test]
    fn bilinear_argument_checks() {
        let a = butter_analog(2, 100.0, FilterKind::Lowpass).unwrap();
        assert!(bilinear(&a, 0.0, None).is_err());
        assert!(bilinear(&a, 1000.0, Some(500.0)).is_err());
        assert!(bilinear(&a, 1000.0, Some(0.0)).is_err());
        let improper = Zpk {
            zeros: vec![C64::new(-1.0, 0.0); 3],
            poles: vec![C64::new(-1.0, 0.0)],
            gain: 1.0,
        };
        assert!(matches!(
            bilinear(&improper, 1000.0, None),
            Err(DspError::NotProper { .. })
        ));
        assert!(butter(2, 600.0, 1000.0, FilterKind::Lowpass, Prewarp::AtCutoff).is_err());
        assert!(butter(2, -1.0, 1000.0, FilterKind::Lowpass, Prewarp::AtCutoff).is_err());
    }

    /// Sections' response equals the zpk's, across orders, kinds and fc/fs
    /// (1e-4 … 0.45); odd orders yield exactly one first-order section.
    #[test]
    fn zpk2sos_preserves_response_and_structure() {
        let fs = 10_000.0;
        for n in 1..=9 {
            for &fc in &[1.0, 200.0, 1000.0, 4500.0] {
                for kind in [FilterKind::Lowpass, FilterKind::Highpass] {
                    let z = butter_zpk(n, fc, fs, kind, Prewarp::AtCutoff).unwrap();
                    let sos = zpk2sos(&z).unwrap();
                    assert_eq!(sos.len(), n.div_ceil(2));
                    let first_order = sos.iter().filter(|c| c.is_first_order()).count();
                    assert_eq!(first_order, n % 2, "n={n}");
                    assert!(sos.iter().all(BiquadCoeffs::is_stable));
                    for f in [0.5 * fc, fc, 1.7 * fc.min(2000.0)] {
                        let a = sections_response(&sos, f, fs);
                        let b = z.digital_response(f, fs);
                        // Coefficient rounding: tolerance scales like
                        // eps/|1 − p|² for poles near z = 1 (see filter docs).
                        let w = 2.0 * PI * fc / fs;
                        let tol = 1e-13 + 1e-14 / (w * w);
                        assert!(
                            rel(a, b) < tol,
                            "n={n} fc={fc} f={f} {kind:?}: {}",
                            rel(a, b)
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn zpk2sos_matches_scipy_pairing_for_a_mixed_system() {
        // Poles: 0.9 (real), 0.5 ± 0.5j, 0.2 (real); zeros: −1, 1, 0.3 ± 0.8j, plus
        // nothing else. Expected by scipy.signal.zpk2sos(..., pairing='nearest'):
        // last section: pole 0.9 (nearest |1 − |p||) with real pole 0.2 and the
        // zeros nearest 0.9: 1 (any) then the nearest real −1 … computed here
        // from the rules, not by calling scipy.
        let zpk = Zpk {
            zeros: vec![
                C64::new(-1.0, 0.0),
                C64::new(1.0, 0.0),
                C64::new(0.3, 0.8),
                C64::new(0.3, -0.8),
            ],
            poles: vec![
                C64::new(0.9, 0.0),
                C64::new(0.5, 0.5),
                C64::new(0.5, -0.5),
                C64::new(0.2, 0.0),
            ],
            gain: 2.0,
        };
        let sos = zpk2sos(&zpk).unwrap();
        assert_eq!(sos.len(), 2);
        // Section 1 (last): poles 0.9 & 0.2 → a = [1, −1.1, 0.18]; zeros: the
        // nearest to 0.9 is 1 (real), then the nearest real: −1 → b = [1, 0, −1].
        let s1 = sos[1];
        assert!((s1.a1 + 1.1).abs() < 1e-15 && (s1.a2 - 0.18).abs() < 1e-15);
        assert!((s1.b0 - 1.0).abs() < 1e-15 && s1.b1.abs() < 1e-15 && (s1.b2 + 1.0).abs() < 1e-15);
        // Section 0: 0.5 ± 0.5j with 0.3 ± 0.8j, gain 2.
        let s0 = sos[0];
        assert!((s0.a1 + 1.0).abs() < 1e-15 && (s0.a2 - 0.5).abs() < 1e-15);
        assert!((s0.b0 - 2.0).abs() < 1e-15);
        assert!((s0.b1 + 1.2).abs() < 1e-15);
        assert!((s0.b2 - 2.0 * 0.73).abs() < 1e-14);
        // And the responses agree.
        for f in [0.0, 100.0, 1234.0, 4000.0] {
            let a = sections_response(&sos, f, 10_000.0);
            let b = zpk.digital_response(f, 10_000.0);
            assert!((a - b).norm() < 1e-13 * b.norm().max(1.0));
        }
        // Non-conjugate complex roots are refused; so are excess zeros.
        let bad = Zpk {
            zeros: vec![],
            poles: vec![C64::new(0.5, 0.5)],
            gain: 1.0,
        };
        assert!(zpk2sos(&bad).is_err());
        let noncausal = Zpk {
            zeros: vec![C64::new(0.5, 0.0); 2],
            poles: vec![C64::new(0.5, 0.0)],
            gain: 1.0,
        };
        assert!(zpk2sos(&noncausal).is_err());
        // Pure gain.
        let g = zpk2sos(&Zpk {
            zeros: vec![],
            poles: vec![],
            gain: 3.0,
        })
        .unwrap();
        assert_eq!(g, vec![BiquadCoeffs::gain(3.0).unwrap()]);
    }

    #[test]
    fn odd_order_matches_scipy_keep_odd_sections() {
        // scipy 1.17: zpk2sos(*butter(5, 0.2, output='zpk'), pairing='keep_odd')
        // (wn = 0.2 of Nyquist = 1 kHz at fs = 10 kHz, prewarped at fc).
        let want = [
            [1.28258108e-03, 1.28258108e-03, 0.0, -5.09525449e-01, 0.0],
            [1.0, 2.0, 1.0, -1.09657947e+00, 3.55446762e-01],
            [1.0, 2.0, 1.0, -1.36931719e+00, 6.92569135e-01],
        ];
        let sos = butter(5, 1000.0, 10_000.0, FilterKind::Lowpass, Prewarp::AtCutoff).unwrap();
        assert_eq!(sos.len(), 3);
        for (c, w) in sos.iter().zip(&want) {
            let got = [c.b0, c.b1, c.b2, c.a1, c.a2];
            for (g, w) in got.iter().zip(w) {
                assert!(
                    (g - w).abs() <= 1e-8 * w.abs().max(1e-3),
                    "{got:?} vs {w:?}"
                );
            }
        }
        assert!(sos[0].is_first_order());
        // High-pass order 3 at 1 kHz: [0.52762438, −0.52762438, 0, −0.50952545, 0],
        // [1, −2, 1, −1.25051643, 0.54572332].
        let hp = butter(3, 1000.0, 10_000.0, FilterKind::Highpass, Prewarp::AtCutoff).unwrap();
        let want = [
            [0.52762438, -0.52762438, 0.0, -0.50952545, 0.0],
            [1.0, -2.0, 1.0, -1.25051643, 0.54572332],
        ];
        for (c, w) in hp.iter().zip(&want) {
            let got = [c.b0, c.b1, c.b2, c.a1, c.a2];
            for (g, w) in got.iter().zip(w) {
                assert!((g - w).abs() <= 1e-8, "{got:?} vs {w:?}");
            }
        }
    }

    #[test]
    fn first_order_and_pole_only_sections() {
        // One pole, no zero (after bilinear there is always a zero, so build the
        // digital zpk directly): H(z) = 1/(z − 0.5) = z⁻¹/(1 − 0.5 z⁻¹).
        let sos = zpk2sos(&Zpk {
            zeros: vec![],
            poles: vec![C64::new(0.5, 0.0)],
            gain: 1.0,
        })
        .unwrap();
        assert_eq!(sos.len(), 1);
        let c = sos[0];
        // Added pole/zero at the origin cancel: b = [0, 1, 0]·?, a = [1, −0.5, 0].
        assert!((c.a1 + 0.5).abs() < 1e-16 && c.a2 == 0.0);
        for f in [0.0, 1000.0, 3000.0] {
            let z = C64::from_polar(1.0, 2.0 * PI * f / 10_000.0);
            let want = 1.0 / (z - 0.5);
            assert!((sections_response(&sos, f, 10_000.0) - want).norm() < 1e-14);
        }
    }

    #[test]
    fn tf_to_sos_matches_analog_response_through_frequency_map() {
        // Paper eq. 2, a proper stable TF: digital(f) = G(j K tan(πf/fs)).
        let g = Tf::new(vec![250.0, 6.40e5], vec![1.0, 2135.0, 4.56e6]).unwrap();
        let fs = 10_000.0;
        for pw in [None, Some(340.0), Some(1000.0)] {
            let sos = tf_to_sos(&g, fs, pw).unwrap();
            let k = bilinear_constant(fs, pw).unwrap();
            for f in [0.0, 63.0, 340.0, 1000.0, 4000.0] {
                let want = g.eval(C64::new(0.0, k * (PI * f / fs).tan()));
                let got = sections_response(&sos, f, fs);
                assert!(rel(got, want) < 1e-12, "pw={pw:?} f={f}");
            }
            if let Some(fp) = pw {
                // Exact at the prewarp frequency: the paper's |G_H(1 kHz)|.
                let got = sections_response(&sos, fp, fs);
                assert!(rel(got, g.response_hz(fp)) < 1e-12);
            }
        }
        let sos = tf_to_sos(&g, fs, Some(1000.0)).unwrap();
        assert!((sections_response(&sos, 1000.0, fs).norm() - 0.0453443).abs() < 1e-7);
    }

    #[test]
    fn tf_to_sos_refusals() {
        let fs = 10_000.0;
        let unstable = Tf::new(vec![1.0], vec![1.0, -5.0, 100.0]).unwrap();
        assert!(matches!(
            tf_to_sos(&unstable, fs, None),
            Err(DspError::Unstable(_))
        ));
        let integrator = Tf::new(vec![1.0], vec![1.0, 0.0]).unwrap();
        assert!(matches!(
            tf_to_sos(&integrator, fs, None),
            Err(DspError::Unstable(_))
        ));
        let oscillator = Tf::new(vec![1.0], vec![1.0, 0.0, 1e6]).unwrap();
        assert!(matches!(
            tf_to_sos(&oscillator, fs, None),
            Err(DspError::Unstable(_))
        ));
        let improper = Tf::new(vec![1.0, 0.0, 0.0], vec![1.0, 1.0]).unwrap();
        assert!(matches!(
            tf_to_sos(&improper, fs, None),
            Err(DspError::NotProper {
                num_degree: 2,
                den_degree: 1
            })
        ));
        // A pole so close to the imaginary axis that its digital image rounds
        // onto the unit circle is refused too.
        let marginal = Zpk {
            zeros: vec![],
            poles: vec![C64::new(-1e-300, 1e3), C64::new(-1e-300, -1e3)],
            gain: 1.0,
        };
        assert!(matches!(
            analog_zpk_to_sos(&marginal, fs, None),
            Err(DspError::Unstable(_))
        ));
        // Biproper TF is fine (equal degrees).
        let biproper = Tf::new(vec![1.0, 100.0], vec![1.0, 1000.0]).unwrap();
        assert!(tf_to_sos(&biproper, fs, None).is_ok());
    }

    /// High-order design at a tiny fc/fs: LR8's building block (Butterworth 4)
    /// at fc/fs = 1e-4 still matches the analog prototype through the
    /// frequency map, in zpk and in sections.
    #[test]
    fn high_order_low_fc_design_is_accurate() {
        let fs = 10_000.0;
        let fc = 1.0;
        for n in [4, 8] {
            let zpk = butter_zpk(n, fc, fs, FilterKind::Lowpass, Prewarp::AtCutoff).unwrap();
            let sos = zpk2sos(&zpk).unwrap();
            let analog = butter_analog(n, 2.0 * PI * fc, FilterKind::Lowpass).unwrap();
            let k = bilinear_constant(fs, Some(fc)).unwrap();
            for f in [0.01, 0.5, 1.0, 2.0, 10.0] {
                let want = analog.eval(C64::new(0.0, k * (PI * f / fs).tan()));
                assert!(
                    rel(zpk.digital_response(f, fs), want) < 1e-10,
                    "zpk n={n} f={f}"
                );
                // Sections: coefficient rounding ~ eps/|1 − p|² ≈ 1e-16/(6e-4)².
                let e = rel(sections_response(&sos, f, fs), want);
                assert!(e < 1e-8, "sos n={n} f={f}: {e:e}");
            }
            assert!((zpk.digital_response(fc, fs).norm() - 0.5f64.sqrt()).abs() < 1e-10);
        }
    }
}
