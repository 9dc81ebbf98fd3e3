//! Gain, phase and vector margins of a discrete-time loop from its
//! frequency response L(e^{jω}), with the definitions of python-control's
//! `stability_margins` (the reference the tests compare against):
//!
//! * **phase crossovers** f₁₈₀: Im L = 0 with Re L ≤ 0; the gain margin is
//!   GM = 1/|L(f₁₈₀)| at the crossover whose |log GM| is smallest (the
//!   nearest gain change, up or down, that puts a pole on the unit circle);
//! * **gain crossovers** f_c: |L| = 1; the phase margin is
//!   PM = (arg L mod 360°) − 180° at the crossover whose |PM| is smallest;
//! * **vector (stability) margin** min_f |1 + L|: the distance of the
//!   Nyquist curve from −1.
//!
//! The loop is L = −(what comes back to the loop's input), i.e. the closed
//! loop is 1 + L = 0 (negative feedback). Crossings are bracketed on a
//! logarithmic grid from [`F_MIN_HZ`] to Nyquist and refined by bisection on
//! the exact response; DC and Nyquist, where L is real, are checked
//! directly. The grid is dense enough (≈ 0.16 % spacing) to resolve a
//! resonance with ζ ≥ 10⁻³ at the sample rates a rig runs.
//!
//! A pure delay z⁻ᵈ turns the phase by 360°·f·d/f_s: the phase crossovers
//! multiply (about d of them up to Nyquist) while |L| and the gain
//! crossovers stay. [`grid_for_delay`] refines the grid so that the delay
//! turns by at most [`DELAY_STEP_DEG`] between points, and only the phase
//! crossings that can decide the gain or the vector margin (their
//! interpolated estimate within [`GM_REFINE_DB`] of the best, or |1 + L|
//! within [`VECTOR_REFINE`]·|L| of the smallest) are refined: the others
//! cost 60 evaluations each and cannot win.

use num_complex::Complex64 as C64;

/// Lowest frequency of the grid, Hz.
pub const F_MIN_HZ: f64 = 1e-2;

/// Points of the logarithmic grid.
pub const GRID_POINTS: usize = 6000;

/// Bisection steps when refining a crossing (interval shrinks by 2⁻⁶⁰).
const REFINE_STEPS: usize = 60;

/// Largest turn of a pure delay's phase between two points of
/// [`grid_for_delay`], degrees. Linear interpolation across such a step
/// misjudges |L| at a crossing by at most 1 − cos(22.5°) = 7.6 % (0.7 dB).
pub const DELAY_STEP_DEG: f64 = 45.0;

/// A phase crossing whose interpolated |gain margin| is more than this
/// above the smallest interpolated one is not refined, dB (4× the 0.7 dB
/// interpolation error of a [`DELAY_STEP_DEG`] step, both ways).
pub const GM_REFINE_DB: f64 = 3.0;

/// A phase crossing whose interpolated |1 + L| exceeds the smallest
/// interpolated one by more than this fraction of the two |L| is not
/// refined (3× the 7.6 % interpolation error).
pub const VECTOR_REFINE: f64 = 0.25;

/// Margins of one loop (module docs). Infinite when there is no crossing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Margins {
    /// Gain margin, dB (20·log₁₀ GM); +∞ without a phase crossover.
    pub gain_margin_db: f64,
    /// Frequency of that phase crossover, Hz (NaN without one).
    pub phase_crossover_hz: f64,
    /// Phase margin, degrees; +∞ without a gain crossover.
    pub phase_margin_deg: f64,
    /// Frequency of that gain crossover, Hz (NaN without one).
    pub gain_crossover_hz: f64,
    /// min |1 + L| over the grid and the crossings.
    pub vector_margin: f64,
}

/// The logarithmic frequency grid from [`F_MIN_HZ`] to just below `fs`/2.
pub fn grid(fs: f64) -> Vec<f64> {
    let hi = 0.5 * fs * (1.0 - 1e-9);
    let r = (hi / F_MIN_HZ).ln();
    (0..GRID_POINTS)
        .map(|i| F_MIN_HZ * (r * i as f64 / (GRID_POINTS - 1) as f64).exp())
        .collect()
}

/// [`grid`] refined for a loop with a pure delay of `d` samples: every
/// interval is split evenly so that the delay turns by at most
/// [`DELAY_STEP_DEG`] between points (about 8·d/f_s points per Hz at the
/// top: 4·d points added over the band at most). [`grid`] itself when no
/// interval needs it (d = 0, or a short delay).
pub fn grid_for_delay(fs: f64, d: usize) -> Vec<f64> {
    let base = grid(fs);
    if d == 0 {
        return base;
    }
    // Phase of the delay per Hz, degrees.
    let deg_per_hz = 360.0 * d as f64 / fs;
    let mut out = Vec::with_capacity(base.len());
    for w in base.windows(2) {
        let (f0, f1) = (w[0], w[1]);
        let pieces = ((f1 - f0) * deg_per_hz / DELAY_STEP_DEG).ceil().max(1.0) as usize;
        out.extend((0..pieces).map(|k| f0 + (f1 - f0) * k as f64 / pieces as f64));
    }
    out.extend(base.last());
    out
}

fn bisect(mut lo: f64, mut hi: f64, sign_lo: bool, test: &dyn Fn(f64) -> bool) -> f64 {
    for _ in 0..REFINE_STEPS {
        let mid = 0.5 * (lo + hi);
        if test(mid) == sign_lo {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Margins of the loop L sampled as `values` on `freqs` (Hz, increasing,
/// typically [`grid`]); `eval` gives L at any frequency for refinement;
/// `fs` the sample rate (Nyquist is checked).
pub fn margins(freqs: &[f64], values: &[C64], eval: &dyn Fn(f64) -> C64, fs: f64) -> Margins {
    margins_with(freqs, values, Some(eval), fs)
}

/// [`margins`] without refinement: crossings are interpolated linearly
/// between grid points (about 0.01 dB and 0.1° on the default grid), for
/// scans that evaluate many loops.
/// `dc` and `nyquist` are L at 0 and fs/2 (real there).
pub fn margins_on_grid(freqs: &[f64], values: &[C64], dc: C64, nyquist: C64, fs: f64) -> Margins {
    margins_with(freqs, values, None, fs).with_ends([(0.0, dc), (0.5 * fs, nyquist)])
}

impl Margins {
    /// Include the real values (frequency, L) at DC and Nyquist.
    fn with_ends(mut self, ends: [(f64, C64); 2]) -> Self {
        for (f, l) in ends {
            self.vector_margin = self.vector_margin.min((l + 1.0).norm());
            if l.re <= 0.0 && l.im.abs() <= 1e-12 * l.norm().max(1e-300) {
                let gm = -20.0 * l.norm().log10();
                if gm.abs() < self.gain_margin_db.abs() {
                    self.gain_margin_db = gm;
                    self.phase_crossover_hz = f;
                }
            }
        }
        self
    }
}

fn margins_with(
    freqs: &[f64],
    values: &[C64],
    eval: Option<&dyn Fn(f64) -> C64>,
    fs: f64,
) -> Margins {
    let mut phase_x: Vec<(f64, C64)> = Vec::new();
    let mut gain_x: Vec<(f64, C64)> = Vec::new();
    let mut vector = f64::INFINITY;
    let n = freqs.len().min(values.len());
    // DC and Nyquist: L is real there.
    if let Some(eval) = eval {
        for f in [0.0, 0.5 * fs] {
            let l = eval(f);
            vector = vector.min((l + 1.0).norm());
            if l.re <= 0.0 && l.im.abs() <= 1e-12 * l.norm().max(1e-300) {
                phase_x.push((f, l));
            }
        }
    }
    for v in &values[..n] {
        vector = vector.min((v + 1.0).norm());
    }
    // Brackets of the crossings with their linear interpolation.
    let mut im_brackets = Vec::new();
    for i in 0..n.saturating_sub(1) {
        let (f0, f1) = (freqs[i], freqs[i + 1]);
        let (a, b) = (values[i], values[i + 1]);
        if (a.im >= 0.0) != (b.im >= 0.0) {
            let t = a.im / (a.im - b.im);
            im_brackets.push(Bracket {
                f0,
                f1,
                a,
                f: f0 + t * (f1 - f0),
                l: a + (b - a) * t,
            });
        }
        if (a.norm() >= 1.0) != (b.norm() >= 1.0) {
            let (f, l) = match eval {
                Some(ev) => {
                    let f = bisect(f0, f1, a.norm() >= 1.0, &|f| ev(f).norm() >= 1.0);
                    (f, ev(f))
                }
                None => {
                    let t = (a.norm() - 1.0) / (a.norm() - b.norm());
                    let l = a + (b - a) * t;
                    (f0 + t * (f1 - f0), l / l.norm())
                }
            };
            gain_x.push((f, l));
        }
    }
    let decisive = decisive_phase_crossings(&im_brackets);
    for (br, refine) in im_brackets.iter().zip(decisive) {
        let (f, l) = match eval {
            Some(ev) if refine => {
                let f = bisect(br.f0, br.f1, br.a.im >= 0.0, &|f| ev(f).im >= 0.0);
                (f, ev(f))
            }
            Some(_) => continue,
            None => (br.f, br.l),
        };
        if l.re <= 0.0 {
            phase_x.push((f, l));
        }
    }
    for &(_, l) in phase_x.iter().chain(&gain_x) {
        vector = vector.min((l + 1.0).norm());
    }
    let mut out = Margins {
        gain_margin_db: f64::INFINITY,
        phase_crossover_hz: f64::NAN,
        phase_margin_deg: f64::INFINITY,
        gain_crossover_hz: f64::NAN,
        vector_margin: vector,
    };
    let mut best = f64::INFINITY;
    for &(f, l) in &phase_x {
        let gm_db = -20.0 * l.norm().log10();
        if gm_db.abs() < best {
            best = gm_db.abs();
            out.gain_margin_db = gm_db;
            out.phase_crossover_hz = f;
        }
    }
    let mut best = f64::INFINITY;
    for &(f, l) in &gain_x {
        let pm = l.arg().to_degrees().rem_euclid(360.0) - 180.0;
        if pm.abs() < best {
            best = pm.abs();
            out.phase_margin_deg = pm;
            out.gain_crossover_hz = f;
        }
    }
    out
}

/// A sign change of Im L between two grid points.
#[derive(Debug, Clone, Copy)]
struct Bracket {
    f0: f64,
    f1: f64,
    /// L at `f0`.
    a: C64,
    /// Linear interpolation of the crossing: frequency and L.
    f: f64,
    l: C64,
}

/// Which Im L sign changes can decide a margin (module docs): those whose
/// interpolated |gain margin| is within [`GM_REFINE_DB`] of the best
/// interpolated phase crossover, or whose interpolated |1 + L| is within
/// [`VECTOR_REFINE`]·(|L| + |L_min|) of the smallest. All of them when
/// none is estimated to be a phase crossover (Re L ≤ 0).
fn decisive_phase_crossings(br: &[Bracket]) -> Vec<bool> {
    let gm = |l: C64| (20.0 * l.norm().log10()).abs();
    let mut best_gm = f64::INFINITY;
    let mut best_vec = f64::INFINITY;
    for b in br.iter().filter(|b| b.l.re <= 0.0) {
        best_gm = best_gm.min(gm(b.l));
        best_vec = best_vec.min((b.l + 1.0).norm() + VECTOR_REFINE * b.l.norm());
    }
    br.iter()
        .map(|b| {
            !best_gm.is_finite()
                || gm(b.l) <= best_gm + GM_REFINE_DB
                || (b.l + 1.0).norm() - VECTOR_REFINE * b.l.norm() <= best_vec
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// L(z) = k·(z + 0.5)/((z − 0.9)(z − 0.5)) at fs = 1 Hz.
    fn l(k: f64, f: f64) -> C64 {
        let z = C64::from_polar(1.0, 2.0 * PI * f);
        k * (z + 0.5) / ((z - 0.9) * (z - 0.5))
    }

    #[test]
    fn margins_of_a_simple_loop_are_consistent() {
        let fs = 1.0;
        let g = grid(fs);
        let v: Vec<C64> = g.iter().map(|&f| l(0.05, f)).collect();
        let m = margins(&g, &v, &|f| l(0.05, f), fs);
        // At the phase crossover L is real and negative; |L| there sets GM.
        let lp = l(0.05, m.phase_crossover_hz);
        assert!(lp.im.abs() < 1e-9 && lp.re < 0.0, "{lp}");
        assert!((m.gain_margin_db + 20.0 * lp.norm().log10()).abs() < 1e-9);
        // Raising the gain by exactly GM puts the loop on the −1 point.
        let k_crit = 0.05 * 10f64.powf(m.gain_margin_db / 20.0);
        assert!((l(k_crit, m.phase_crossover_hz) + 1.0).norm() < 1e-7);
        let lc = l(0.05, m.gain_crossover_hz);
        assert!((lc.norm() - 1.0).abs() < 1e-9);
        assert!(m.phase_margin_deg > 0.0 && m.vector_margin > 0.0);
    }

    #[test]
    fn no_crossing_gives_infinite_margins() {
        let fs = 1.0;
        let g = grid(fs);
        let f = |f: f64| C64::new(0.1, 0.0) / C64::from_polar(1.0, 2.0 * PI * f);
        let v: Vec<C64> = g.iter().map(|&x| f(x)).collect();
        let m = margins(&g, &v, &f, fs);
        // 0.1·z⁻¹ reaches −0.1 at Nyquist: a phase crossover with GM 20 dB.
        assert!((m.gain_margin_db - 20.0).abs() < 1e-9, "{m:?}");
        assert!(m.phase_margin_deg.is_infinite());
    }
}
