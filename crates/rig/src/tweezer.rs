//! Optical tweezer: an overdamped Brownian bead in a harmonic trap
//! (paper §4.1, eqs. 4–6), with a coverslip wall, fixed spherical obstacles,
//! contact and escape.
//!
//! **Model.** The bead's inertia is dropped: m/γ₀ ≈ 1 µs for a 3 µm glass
//! bead in water, two orders of magnitude below the 100 µs sample period
//! (the paper quotes ≈2 µs and drops it too, eq. 6). In each direction i of
//! a frame in which the drag is diagonal,
//!
//! γ_i ẋ_i = −k_i (x_i − e_i(t)) + γ_i v_d,i + √(2 k_B T γ_i) ξ_i(t),
//!
//! with k_i the trap stiffness κ (plus the contact stiffness along the
//! obstacle normal inside the contact zone), e_i the equilibrium (trap
//! position, moving linearly over a step) and v_d the Itô drift
//! k_B T ∂(1/γ_⊥)/∂h along the normal near an obstacle.
//!
//! **Exact step.** With γ_i frozen over a (sub)step h, c = e^{−h/τ},
//! τ = γ_i/k_i, w = ė_i:
//! x(h) = e(h) + c (x₀ − e(0)) + (v_d − w) τ (1 − c) + √((k_BT/k_i)(1 − c²)) N(0,1),
//! the exact Ornstein–Uhlenbeck transition (REFERENCE-VALUES.md), stable for
//! every h. Euler–Maruyama is available for comparison (biased variance
//! (k_BT/κ)/(1 − h/2τ), unstable for h > 2τ).
//!
//! **Drag.** Stokes γ₀ = 6πηR. A coverslip at centre distance H scales the
//! in-plane drag by Faxén's parallel factor. Near an obstacle (surface at
//! distance h from the bead centre along the normal n) the drag along n is
//! Brenner's (Schäffer et al. 2007 approximation) and along the tangent
//! Faxén's, both treating the obstacle surface as locally plane; the nearest
//! obstacle only; wall and obstacle factors multiply. h is clamped at
//! h/R ≥ 1.1 ([`DRAG_CLAMP_GAP_OVER_R`]) near contact, and the Itô drift is
//! zero inside the clamp.
//!
//! **Contact.** A short-range linear repulsion k_c (δ − g) along n for a
//! surface gap g < δ; sub-steps (more when the trap moves fast or the bead
//! is close) keep each move below a fraction of δ and of the gap, and a
//! reflecting boundary at g = 0 guarantees that nothing tunnels.
//!
//! **Escape.** Beyond `escape_distance` from the trap centre (the linear
//! range, default ≈ R) the bead is lost: no optical force, free diffusion,
//! until the trap comes back within half that distance (recapture).

use crate::config::TweezerConfig;
use crate::error::RigError;
use crate::normal::NormalStream;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Boltzmann constant, J/K (exact, SI 2019).
pub const BOLTZMANN: f64 = 1.380_649e-23;

/// Largest number of sub-steps per sample: bounds the worst-case cost of a
/// sample (≈ 40 µs, within the 100 µs period at 10 kHz). When the cap binds
/// (trap moving > ~0.6 µm per sample next to an obstacle) the contact zone is
/// resolved more coarsely; the reflecting boundary still prevents overlap.
pub const MAX_SUBSTEPS: u32 = 128;

/// Clamp of the drag formulas near contact: the surface distance h used in
/// Faxén/Brenner is at least (1 + this)·R, i.e. h/R ≥ 1.1, the range in which
/// Schäffer's approximation is validated (and the scale of surface
/// roughness below which lubrication theory stops applying).
pub const DRAG_CLAMP_GAP_OVER_R: f64 = 0.1;

/// Stokes drag of a sphere, γ₀ = 6π η R (N·s/m).
pub fn stokes_drag(viscosity_pa_s: f64, radius_m: f64) -> f64 {
    6.0 * PI * viscosity_pa_s * radius_m
}

/// Faxén's parallel wall correction γ∥/γ₀ for s = R/h (h = centre–wall
/// distance): 1/(1 − 9/16 s + 1/8 s³ − 45/256 s⁴ − 1/16 s⁵).
pub fn faxen_parallel(s: f64) -> f64 {
    1.0 / faxen_parallel_mobility(s)
}

/// Parallel mobility ratio γ₀/γ∥ = 1/[`faxen_parallel`] (Faxén's series).
#[inline]
fn faxen_parallel_mobility(s: f64) -> f64 {
    1.0 - 9.0 / 16.0 * s + 0.125 * s.powi(3) - 45.0 / 256.0 * s.powi(4) - 0.0625 * s.powi(5)
}

/// Perpendicular mobility ratio γ₀/γ⊥ (Schäffer et al. 2007 approximation
/// of Brenner's series), s = R/h.
pub fn perpendicular_mobility(s: f64) -> f64 {
    1.0 - 9.0 / 8.0 * s + 0.5 * s.powi(3) - 0.57 * s.powi(4)
        + 0.2 * s.powi(5)
        + 7.0 / 200.0 * s.powi(11)
        - 0.04 * s.powi(12)
}

/// d/ds of [`perpendicular_mobility`].
pub fn perpendicular_mobility_ds(s: f64) -> f64 {
    -9.0 / 8.0 + 1.5 * s * s - 2.28 * s.powi(3) + s.powi(4) + 77.0 / 200.0 * s.powi(10)
        - 0.48 * s.powi(11)
}

/// Brenner's perpendicular wall correction γ⊥/γ₀ (Schäffer's approximation,
/// within 0.1 % of the exact series for h/R ≥ 1.1), s = R/h.
pub fn brenner_perpendicular(s: f64) -> f64 {
    1.0 / perpendicular_mobility(s)
}

/// Bead integrator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TweezerIntegrator {
    /// Exact Ornstein–Uhlenbeck transition (default).
    Exact,
    /// Euler–Maruyama (comparison only).
    Euler,
}

impl std::str::FromStr for TweezerIntegrator {
    type Err = RigError;
    fn from_str(s: &str) -> Result<Self, RigError> {
        match s {
            "exact" => Ok(Self::Exact),
            "euler" => Ok(Self::Euler),
            _ => Err(RigError::InvalidInput(format!(
                "unknown integrator `{s}` (expected exact|euler)"
            ))),
        }
    }
}

/// A fixed spherical obstacle whose centre lies in the focal plane.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Obstacle {
    /// Centre (x, y), m.
    pub centre_m: [f64; 2],
    /// Radius, m.
    pub radius_m: f64,
}

/// Physical and numerical parameters of the simulated tweezer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TweezerParams {
    /// Bead radius R, m.
    pub radius_m: f64,
    /// Dynamic viscosity η, Pa·s.
    pub viscosity_pa_s: f64,
    /// Temperature T, K.
    pub temperature_k: f64,
    /// Trap stiffness κ, N/m.
    pub stiffness_n_per_m: f64,
    /// Bead-centre to coverslip distance H, m (None: no wall).
    pub wall_distance_m: Option<f64>,
    /// Trap linear range, m (escape beyond it).
    pub escape_distance_m: f64,
    /// Contact range δ, m.
    pub contact_range_m: f64,
    /// Contact stiffness k_c, N/m.
    pub contact_stiffness_n_per_m: f64,
    /// Obstacles.
    pub obstacles: Vec<Obstacle>,
    /// Integrator.
    pub integrator: TweezerIntegrator,
    /// Apply the Itô drift k_BT ∂(1/γ⊥)/∂h near obstacles (disable only to
    /// demonstrate the artefact).
    pub ito_drift: bool,
    /// RNG seed.
    pub seed: u64,
}

impl TweezerParams {
    /// Paper defaults: R = 1.5 µm glass bead in water at 20 °C, κ = 20 pN/µm,
    /// no wall, no obstacles.
    pub fn paper_default() -> Self {
        Self {
            radius_m: 1.5e-6,
            viscosity_pa_s: 1.0016e-3,
            temperature_k: 293.15,
            stiffness_n_per_m: 2.0e-5,
            wall_distance_m: None,
            escape_distance_m: 1.5e-6,
            contact_range_m: 2.0e-8,
            contact_stiffness_n_per_m: 2.0e-3,
            obstacles: Vec::new(),
            integrator: TweezerIntegrator::Exact,
            ito_drift: true,
            seed: 0,
        }
    }

    /// From the `[tweezer]` section of a rig file.
    pub fn from_config(c: &TweezerConfig) -> Self {
        Self {
            radius_m: c.radius_m,
            viscosity_pa_s: c.viscosity_pa_s,
            temperature_k: c.temperature_k,
            stiffness_n_per_m: c.stiffness_n_per_m,
            wall_distance_m: c.wall_distance_m,
            escape_distance_m: c.escape_distance_m,
            contact_range_m: c.contact_range_m,
            contact_stiffness_n_per_m: c.contact_stiffness_n_per_m,
            obstacles: c
                .obstacles
                .iter()
                .map(|o| Obstacle {
                    centre_m: [o.x_m, o.y_m],
                    radius_m: o.radius_m,
                })
                .collect(),
            integrator: TweezerIntegrator::Exact,
            ito_drift: true,
            seed: c.seed,
        }
    }

    /// Check every parameter.
    pub fn validate(&self) -> Result<(), RigError> {
        let pos = |name: &'static str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(RigError::InvalidParameter {
                    name,
                    value: v,
                    reason: "must be finite and > 0".into(),
                })
            }
        };
        pos("radius_m", self.radius_m)?;
        pos("viscosity_pa_s", self.viscosity_pa_s)?;
        pos("temperature_k", self.temperature_k)?;
        pos("stiffness_n_per_m", self.stiffness_n_per_m)?;
        pos("escape_distance_m", self.escape_distance_m)?;
        pos("contact_range_m", self.contact_range_m)?;
        pos("contact_stiffness_n_per_m", self.contact_stiffness_n_per_m)?;
        if let Some(h) = self.wall_distance_m
            && !(h.is_finite() && h > self.radius_m)
        {
            return Err(RigError::InvalidParameter {
                name: "wall_distance_m",
                value: h,
                reason: format!("must exceed the bead radius {} m", self.radius_m),
            });
        }
        for o in &self.obstacles {
            if !(o.radius_m.is_finite()
                && o.radius_m > 0.0
                && o.centre_m.iter().all(|v| v.is_finite()))
            {
                return Err(RigError::InvalidParameter {
                    name: "obstacles",
                    value: o.radius_m,
                    reason: "obstacle radius must be > 0 and centre finite".into(),
                });
            }
        }
        Ok(())
    }

    /// k_B T, J.
    pub fn kt(&self) -> f64 {
        BOLTZMANN * self.temperature_k
    }

    /// Stokes drag γ₀, N·s/m.
    pub fn gamma0(&self) -> f64 {
        stokes_drag(self.viscosity_pa_s, self.radius_m)
    }

    /// Faxén factor of the coverslip (1 without wall).
    pub fn wall_factor(&self) -> f64 {
        self.wall_distance_m
            .map_or(1.0, |h| faxen_parallel(self.radius_m / h))
    }

    /// In-plane drag far from obstacles, N·s/m.
    pub fn gamma_free(&self) -> f64 {
        self.gamma0() * self.wall_factor()
    }

    /// Corner frequency f_c = κ/(2πγ) far from obstacles, Hz.
    pub fn corner_hz(&self) -> f64 {
        self.stiffness_n_per_m / (2.0 * PI * self.gamma_free())
    }

    /// Diffusion coefficient D = k_BT/γ far from obstacles, m²/s.
    pub fn diffusion(&self) -> f64 {
        self.kt() / self.gamma_free()
    }

    /// Equipartition variance k_BT/κ per axis, m².
    pub fn variance_theory(&self) -> f64 {
        self.kt() / self.stiffness_n_per_m
    }

    /// Relaxation time τ = γ/κ, s.
    pub fn tau(&self) -> f64 {
        self.gamma_free() / self.stiffness_n_per_m
    }
}

/// Events of one sample.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TweezerEvents {
    /// The bead entered an obstacle's contact zone.
    pub contact_start: bool,
    /// The bead left the contact zone (with hysteresis, 3δ).
    pub contact_end: bool,
    /// The bead left the trap's linear range and is lost.
    pub escaped: bool,
    /// A lost bead was recaptured by the trap.
    pub recaptured: bool,
}

impl TweezerEvents {
    /// True if any event fired.
    pub fn any(&self) -> bool {
        self.contact_start || self.contact_end || self.escaped || self.recaptured
    }
}

/// One sample of tweezer output.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TweezerSample {
    /// Bead centre (x, y), m.
    pub bead_m: [f64; 2],
    /// Trap centre (x, y), m.
    pub trap_m: [f64; 2],
    /// Optical force on the bead κ(trap − bead), N (0 when lost).
    pub force_n: [f64; 2],
    /// Surface gap to the nearest obstacle, m (∞ without obstacles).
    pub gap_m: f64,
    /// Unit normal of the nearest obstacle's surface at the bead (from the
    /// obstacle's centre toward the bead); zero without obstacles.
    pub normal: [f64; 2],
    /// Inside an obstacle's contact zone.
    pub in_contact: bool,
    /// Bead held by the trap.
    pub trapped: bool,
    /// Events of this sample.
    pub events: TweezerEvents,
    /// Sub-steps used.
    pub substeps: u32,
}

/// An optical tweezer driven at the loop rate: trap position in, bead
/// position, optical force and events out. Implemented by [`SimTweezer`]
/// now and by live tweezers later.
pub trait Tweezer {
    /// Loop sample rate, Hz.
    fn sample_rate_hz(&self) -> f64;
    /// Trap stiffness κ, N/m.
    fn stiffness_n_per_m(&self) -> f64;
    /// Move the trap to `trap_m` (linearly over the sample period) and
    /// advance one sample. Must not allocate, lock or panic.
    fn step(&mut self, trap_m: [f64; 2]) -> TweezerSample;
    /// Put the trap at `trap_m` and the bead in it (trapped, no contact).
    fn reset(&mut self, trap_m: [f64; 2]);
}

/// Simulated tweezer (module docs).
#[derive(Debug, Clone)]
pub struct SimTweezer {
    p: TweezerParams,
    fs: f64,
    dt: f64,
    kt: f64,
    gamma0: f64,
    fw: f64,
    bead: [f64; 2],
    trap: [f64; 2],
    trapped: bool,
    in_contact: bool,
    rng: NormalStream,
    // Free-space full-step coefficients (exact OU): c, τ(1 − c), σ.
    free_c: f64,
    free_tau_1mc: f64,
    free_sigma: f64,
    // Free-space mobility 1/(γ₀ f_w), m/(N·s); 1/R, 1/m.
    free_mu: f64,
    inv_radius: f64,
    // 4·√(2 D dt): diffusion length scale of one sample, m.
    diff_len: f64,
    // Nearest obstacle after the last step (None inside: not yet known).
    near_cache: Option<Near>,
    // Tabulated exact-OU coefficients near obstacles (None: exact path only).
    drag: Option<Box<DragTable>>,
    use_drag_table: bool,
    // `drag` present and `use_drag_table`.
    table_on: bool,
    // Smallest gap of the tabulated step: max(δ, 0.1 R) (clamp and contact
    // zones excluded), m.
    fast_gap_min: f64,
    // All obstacles have the same radius (nearest by squared distance).
    equal_radii: bool,
    reflections: u64,
    nonfinite: u64,
}

/// Scalar Ornstein–Uhlenbeck coefficients of one direction over a sub-step:
/// stiffness `k` (N/m) toward an equilibrium moving linearly `e0` → `e1` (m),
/// mobility `mu` = 1/γ (m/(N·s), the inverse drag: the wall corrections are
/// mobility polynomials, so no division is needed), drift velocity `v` (m/s).
#[derive(Debug, Clone, Copy)]
struct Ou {
    k: f64,
    e0: f64,
    e1: f64,
    mu: f64,
    v: f64,
}

/// Nearest obstacle: (index, unit normal from its centre to the bead, gap).
type Near = Option<(usize, [f64; 2], f64)>;

/// Number of cubic pieces of [`DragTable`] over s ∈ [0, s_clamp].
pub const DRAG_TABLE_PIECES: usize = 512;

/// Exact-OU coefficients of one full sample near an obstacle, for a trapped
/// bead outside the contact zone, as functions of s = R/h (h = distance from
/// the bead centre to the obstacle surface), in lane pairs (normal,
/// tangent): c = e^{−dt k μ}, g = τ(1 − c) = (1 − c)/(k μ),
/// σ = √((k_BT/k)(1 − c²)), and the Itô drift's displacement v_d·g⊥ (normal
/// only), with μ⊥ = μ₀·[`perpendicular_mobility`], μ∥ = μ₀·Faxén's parallel
/// mobility, k = κ and v_d = k_BT μ₀ p′(s)(−s²/R) (module docs).
///
/// These are the exact step's coefficients (two exponentials, a division
/// and two square roots per direction, two mobility polynomials). Tabulated
/// as piecewise cubics on [`DRAG_TABLE_PIECES`] equal pieces of
/// [0, s_clamp], s_clamp = 1/(1 + [`DRAG_CLAMP_GAP_OVER_R`]) (the clamp
/// region and the contact zone take the exact path), each cubic
/// interpolating at the four Chebyshev points of its piece. The largest
/// relative deviation from the exact coefficients is measured at
/// construction on a grid 8× finer than the pieces (see
/// [`SimTweezer::drag_table_error`]; ≈ 1e-13 for the defaults) and the
/// table is not used if it exceeds 1e-9.
/// One cubic piece of [`DragTable`]: `[power][pair][lane]`.
type DragPiece = [[[f64; 2]; 4]; 4];

/// 1.5·2⁵²: (x − 0.5) + this (x ∈ [0, 2⁵⁰]) is 1.5·2⁵² + round(x − 0.5),
/// in the binade [2⁵², 2⁵³) of unit spacing, i.e. ⌊x⌋ (or ⌊x⌋ − 1 when x
/// is an odd integer: the tie rounds to even; then t = 1 on the piece
/// below), so the piece index is in the low bits of the sum — no
/// saturating float→integer conversion.
const PIECE_ROUND: f64 = 6_755_399_441_055_744.0;

#[derive(Debug, Clone)]
struct DragTable {
    inv_ds: f64,
    /// Per piece, the monomial coefficients (t⁰…t³, t ∈ [0, 1] across the
    /// piece) of the four lane pairs (c, g, σ, drift), contiguous (256
    /// bytes per piece); a fixed-size array so that a masked index needs
    /// no bounds check.
    coef: Box<[DragPiece; DRAG_TABLE_PIECES]>,
    max_rel_err: f64,
}

impl DragTable {
    /// Largest accepted relative interpolation error.
    const MAX_REL_ERR: f64 = 1e-9;

    /// Exact coefficients at s (see the type docs): [c⊥, c∥, g⊥, g∥, σ⊥, σ∥, drift⊥].
    fn exact(s: f64, k: f64, h: f64, kt: f64, mu0: f64, inv_r: f64, drift: bool) -> [f64; 7] {
        let mp = mu0 * perpendicular_mobility(s);
        let mt = mu0 * faxen_parallel_mobility(s);
        let vd = if drift {
            kt * mu0 * perpendicular_mobility_ds(s) * (-(s * s) * inv_r)
        } else {
            0.0
        };
        let one = |mu: f64| {
            let kmu = k * mu;
            let c = (-h * kmu).exp();
            (c, (1.0 - c) / kmu, (kt / k * (1.0 - c * c)).sqrt())
        };
        let (cp, gp, sp) = one(mp);
        let (ct, gt, st) = one(mt);
        [cp, ct, gp, gt, sp, st, vd * gp]
    }

    #[allow(clippy::needless_range_loop)] // q indexes the 7 coefficients of every table row
    fn new(k: f64, h: f64, kt: f64, mu0: f64, inv_r: f64, drift: bool) -> Option<Self> {
        let n = DRAG_TABLE_PIECES;
        let s_max = 1.0 / (1.0 + DRAG_CLAMP_GAP_OVER_R);
        let ds = s_max / n as f64;
        let f = |s: f64| Self::exact(s, k, h, kt, mu0, inv_r, drift);
        // Chebyshev points of [0, 1] and the cubic through them (Newton
        // divided differences, then expanded to monomials in t).
        let tn: [f64; 4] =
            std::array::from_fn(|j| 0.5 * (1.0 - ((2 * j + 1) as f64 * PI / 8.0).cos()));
        let mut coef = Vec::with_capacity(n);
        for i in 0..n {
            let vals: [[f64; 7]; 4] = std::array::from_fn(|j| f((i as f64 + tn[j]) * ds));
            let mut piece = [[[0.0; 2]; 4]; 4];
            for q in 0..7 {
                let y: [f64; 4] = std::array::from_fn(|j| vals[j][q]);
                // Divided differences.
                let mut d = y;
                for lvl in 1..4 {
                    for j in (lvl..4).rev() {
                        d[j] = (d[j] - d[j - 1]) / (tn[j] - tn[j - lvl]);
                    }
                }
                // Newton form → monomials: p(t) = d0 + (t−t0)(d1 + (t−t1)(d2 + (t−t2) d3)).
                let mut m = [d[3], 0.0, 0.0, 0.0]; // coefficients of the inner polynomial, t⁰ first
                for lvl in (0..3).rev() {
                    // m ← m·(t − t_lvl) + d_lvl
                    let mut nm = [0.0; 4];
                    for p in 0..4 {
                        if p + 1 < 4 {
                            nm[p + 1] += m[p];
                        }
                        nm[p] -= tn[lvl] * m[p];
                    }
                    nm[0] += d[lvl];
                    m = nm;
                }
                let (pair, lane) = (q / 2, q % 2);
                for (p, mp) in m.iter().enumerate() {
                    piece[p][pair][lane] = *mp;
                }
            }
            coef.push(piece);
        }
        let coef: Box<[DragPiece; DRAG_TABLE_PIECES]> = coef.into_boxed_slice().try_into().ok()?;
        let mut t = Self {
            inv_ds: 1.0 / ds,
            coef,
            max_rel_err: 0.0,
        };
        // Measure the interpolation error on a grid 8× finer than the pieces.
        let mut err: f64 = 0.0;
        for i in 0..=(8 * n) {
            let s = s_max * i as f64 / (8 * n) as f64;
            let e = f(s);
            let a = t.eval(s);
            let got = [
                a[0][0], a[0][1], a[1][0], a[1][1], a[2][0], a[2][1], a[3][0],
            ];
            for q in 0..7 {
                // The drift displacement is measured against the step's
                // noise amplitude σ⊥ (it vanishes at s = 0).
                let scale = if q == 6 { e[4] } else { e[q].abs() };
                err = err.max((got[q] - e[q]).abs() / scale);
            }
        }
        if err.is_nan() || err > Self::MAX_REL_ERR {
            return None;
        }
        t.max_rel_err = err;
        Some(t)
    }

    /// The four lane pairs (c, g, σ, drift) at s ∈ [0, s_max].
    #[inline(always)]
    fn eval(&self, s: f64) -> [[f64; 2]; 4] {
        // Piece i = ⌊x⌋ (x ≥ 0; [`PIECE_ROUND`]) and t = x − i ∈ [0, 1]; the
        // mask and the clamp keep i in the table for any s (out of
        // [0, s_max] the value is meaningless but nothing panics).
        let x = s * self.inv_ds;
        let y = (x - 0.5) + PIECE_ROUND;
        let i = ((y.to_bits() as usize) & (2 * DRAG_TABLE_PIECES - 1)).min(DRAG_TABLE_PIECES - 1);
        let t = x - i as f64;
        let c = &self.coef[i];
        std::array::from_fn(|q| {
            let mut v = c[3][q];
            for p in (0..3).rev() {
                v = add2(mul2(v, [t; 2]), c[p][q]);
            }
            v
        })
    }
}

/// Lane-wise a + b.
#[inline(always)]
fn add2(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] + b[0], a[1] + b[1]]
}

/// Lane-wise a − b.
#[inline(always)]
fn sub2(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

/// Lane-wise a·b.
#[inline(always)]
fn mul2(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] * b[0], a[1] * b[1]]
}

fn norm2(v: [f64; 2]) -> f64 {
    (v[0] * v[0] + v[1] * v[1]).sqrt()
}

impl SimTweezer {
    /// Create at sample rate `fs_hz` with the bead in the trap at the origin.
    pub fn new(params: TweezerParams, fs_hz: f64) -> Result<Self, RigError> {
        params.validate()?;
        if !(fs_hz.is_finite() && fs_hz > 0.0) {
            return Err(RigError::InvalidParameter {
                name: "fs",
                value: fs_hz,
                reason: "must be finite and > 0".into(),
            });
        }
        let dt = 1.0 / fs_hz;
        let kt = params.kt();
        let gamma0 = params.gamma0();
        let fw = params.wall_factor();
        let gf = gamma0 * fw;
        let tau = gf / params.stiffness_n_per_m;
        let c = (-dt / tau).exp();
        let rng = NormalStream::new(params.seed);
        let drag = if params.obstacles.is_empty() || params.integrator != TweezerIntegrator::Exact {
            None
        } else {
            DragTable::new(
                params.stiffness_n_per_m,
                dt,
                kt,
                1.0 / gf,
                1.0 / params.radius_m,
                params.ito_drift,
            )
            .map(Box::new)
        };
        let equal_radii = params
            .obstacles
            .iter()
            .all(|o| o.radius_m == params.obstacles[0].radius_m);
        Ok(Self {
            table_on: drag.is_some(),
            fast_gap_min: params
                .contact_range_m
                .max(DRAG_CLAMP_GAP_OVER_R * params.radius_m),
            equal_radii,
            drag,
            use_drag_table: true,
            free_c: c,
            free_tau_1mc: tau * (1.0 - c),
            free_sigma: (kt / params.stiffness_n_per_m * (1.0 - c * c)).sqrt(),
            diff_len: 4.0 * (2.0 * kt / gf * dt).sqrt(),
            free_mu: 1.0 / gf,
            inv_radius: 1.0 / params.radius_m,
            near_cache: None,
            p: params,
            fs: fs_hz,
            dt,
            kt,
            gamma0,
            fw,
            bead: [0.0; 2],
            trap: [0.0; 2],
            trapped: true,
            in_contact: false,
            rng,
            reflections: 0,
            nonfinite: 0,
        })
    }

    /// Parameters.
    pub fn params(&self) -> &TweezerParams {
        &self.p
    }

    /// Current bead position, m.
    pub fn bead(&self) -> [f64; 2] {
        self.bead
    }

    /// Place the bead (tests, scenes). Non-finite → unchanged.
    pub fn set_bead(&mut self, bead: [f64; 2]) {
        if bead.iter().all(|v| v.is_finite()) {
            self.bead = bead;
            self.near_cache = None;
        }
    }

    /// Largest relative deviation of the tabulated near-obstacle step
    /// coefficients from the exact ones ([`DragTable`]; the drift term
    /// relative to the step's noise amplitude), measured at construction;
    /// `None` when no table is used (no obstacles, Euler–Maruyama, or the
    /// table missed its 1e-9 accuracy).
    pub fn drag_table_error(&self) -> Option<f64> {
        self.drag.as_ref().map(|t| t.max_rel_err)
    }

    /// Use (default) or bypass the tabulated near-obstacle coefficients
    /// (bypassed, every step evaluates the exponentials and mobility
    /// polynomials: for comparisons).
    pub fn set_drag_table(&mut self, on: bool) {
        self.use_drag_table = on;
        self.table_on = on && self.drag.is_some();
    }

    /// Is the bead held by the trap?
    pub fn trapped(&self) -> bool {
        self.trapped
    }

    /// Number of reflections at an obstacle surface (overlap prevented).
    pub fn reflections(&self) -> u64 {
        self.reflections
    }

    /// Number of non-finite bead states that were reset (diverging Euler).
    pub fn nonfinite_resets(&self) -> u64 {
        self.nonfinite
    }

    /// Nearest obstacle: (index, unit normal from its centre to the bead,
    /// surface gap g = |r − c| − R − R_o).
    #[inline(always)]
    fn nearest(&self, r: [f64; 2]) -> Option<(usize, [f64; 2], f64)> {
        // Pick the nearest by gap first; normalise only the winner's offset
        // (one division, two products).
        let (mut bi, mut bd, mut bgap, mut bdist) = (usize::MAX, [0.0; 2], f64::INFINITY, 0.0);
        for (i, o) in self.p.obstacles.iter().enumerate() {
            let d = [r[0] - o.centre_m[0], r[1] - o.centre_m[1]];
            let dist = norm2(d);
            let gap = dist - self.p.radius_m - o.radius_m;
            if bi == usize::MAX || gap < bgap {
                (bi, bd, bgap, bdist) = (i, d, gap, dist);
            }
        }
        if bi == usize::MAX {
            return None;
        }
        let n = if bdist > 0.0 {
            let inv = 1.0 / bdist;
            [bd[0] * inv, bd[1] * inv]
        } else {
            [1.0, 0.0]
        };
        Some((bi, n, bgap))
    }

    #[inline]
    fn normal(&mut self) -> f64 {
        self.rng.sample()
    }

    /// One exact/EM update of a scalar coordinate x over h (see [`Ou`]).
    /// `inv_h` = 1/h.
    #[inline]
    fn scalar_step(&mut self, x: f64, ou: Ou, h: f64, inv_h: f64) -> f64 {
        let Ou { k, e0, e1, mu, v } = ou;
        let n = self.normal();
        match self.p.integrator {
            TweezerIntegrator::Exact => {
                if k > 0.0 {
                    // τ = γ/k, c = e^{−h/τ} = e^{−h k μ}.
                    let kmu = k * mu;
                    let c = (-h * kmu).exp();
                    let tau = 1.0 / kmu;
                    let w = (e1 - e0) * inv_h;
                    e1 + c * (x - e0)
                        + (v - w) * tau * (1.0 - c)
                        + (self.kt / k * (1.0 - c * c)).sqrt() * n
                } else {
                    x + v * h + (2.0 * self.kt * h * mu).sqrt() * n
                }
            }
            TweezerIntegrator::Euler => {
                x - h * k * (x - e0) * mu + v * h + (2.0 * self.kt * h * mu).sqrt() * n
            }
        }
    }

    /// One sub-step; `near` is the nearest obstacle at the start, the return
    /// value the nearest obstacle at the end (after any reflection).
    fn substep(&mut self, ta: [f64; 2], tb: [f64; 2], h: f64, inv_h: f64, near: Near) -> Near {
        let kappa = if self.trapped {
            self.p.stiffness_n_per_m
        } else {
            0.0
        };
        let r = self.p.radius_m;
        let delta = self.p.contact_range_m;
        match near {
            None => {
                let mu = 1.0 / (self.gamma0 * self.fw);
                for i in 0..2 {
                    self.bead[i] = self.scalar_step(
                        self.bead[i],
                        Ou {
                            k: kappa,
                            e0: ta[i],
                            e1: tb[i],
                            mu,
                            v: 0.0,
                        },
                        h,
                        inv_h,
                    );
                }
            }
            Some((oi, n, gap)) => {
                let o = self.p.obstacles[oi];
                let t = [-n[1], n[0]];
                let rel = [self.bead[0] - o.centre_m[0], self.bead[1] - o.centre_m[1]];
                let sn = rel[0] * n[0] + rel[1] * n[1];
                let st = rel[0] * t[0] + rel[1] * t[1];
                let proj = |p: [f64; 2], u: [f64; 2]| {
                    (p[0] - o.centre_m[0]) * u[0] + (p[1] - o.centre_m[1]) * u[1]
                };
                // Distance from the bead centre to the obstacle surface.
                let gmin = DRAG_CLAMP_GAP_OVER_R * r;
                let clamped = gap < gmin;
                let hs = r + gap.max(gmin);
                let s = r / hs;
                // Mobilities 1/γ⊥ and 1/γ∥ (no division on the bead's
                // dependency chain).
                let mu0 = self.free_mu;
                let mu_perp = mu0 * perpendicular_mobility(s);
                let mu_par = mu0 * faxen_parallel_mobility(s);
                let vd = if self.p.ito_drift && !clamped {
                    // k_BT d(1/γ⊥)/dh = k_BT/(γ₀ f_w) · p'(s) · (−R/h²),
                    // with R/h² = s²/R.
                    self.kt * mu0 * perpendicular_mobility_ds(s) * (-(s * s) * self.inv_radius)
                } else {
                    0.0
                };
                let (kc, s_star) = if gap < delta {
                    (self.p.contact_stiffness_n_per_m, r + o.radius_m + delta)
                } else {
                    (0.0, 0.0)
                };
                let kn = kappa + kc;
                let (en0, en1) = if kn > 0.0 {
                    (
                        (kappa * proj(ta, n) + kc * s_star) / kn,
                        (kappa * proj(tb, n) + kc * s_star) / kn,
                    )
                } else {
                    (sn, sn)
                };
                let sn1 = self.scalar_step(
                    sn,
                    Ou {
                        k: kn,
                        e0: en0,
                        e1: en1,
                        mu: mu_perp,
                        v: vd,
                    },
                    h,
                    inv_h,
                );
                let st1 = self.scalar_step(
                    st,
                    Ou {
                        k: kappa,
                        e0: proj(ta, t),
                        e1: proj(tb, t),
                        mu: mu_par,
                        v: 0.0,
                    },
                    h,
                    inv_h,
                );
                self.bead = [
                    o.centre_m[0] + sn1 * n[0] + st1 * t[0],
                    o.centre_m[1] + sn1 * n[1] + st1 * t[1],
                ];
            }
        }
        self.finish_move(tb)
    }

    /// After a (sub)step that ended with the trap at `tb`: non-finite guard,
    /// reflecting boundary, escape. Returns the nearest obstacle of the
    /// final bead position.
    #[inline(always)]
    fn finish_move(&mut self, tb: [f64; 2]) -> Near {
        if !(self.bead[0].is_finite() && self.bead[1].is_finite()) {
            self.bead = tb;
            self.nonfinite += 1;
        }
        let mut end = self.nearest(self.bead);
        if matches!(end, Some((_, _, gap)) if gap < 0.0) {
            end = self.reflect(end);
        }
        if self.trapped {
            let d = [self.bead[0] - tb[0], self.bead[1] - tb[1]];
            let e = self.p.escape_distance_m;
            // |d| > e, without the square root.
            if d[0] * d[0] + d[1] * d[1] > e * e {
                self.trapped = false;
            }
        }
        end
    }

    /// Reflecting boundary at g = 0: the nearest obstacle is the only one
    /// the bead can overlap; reflect until none does (obstacles may touch).
    #[cold]
    #[inline(never)]
    fn reflect(&mut self, mut end: Near) -> Near {
        let r = self.p.radius_m;
        for _ in 0..4 {
            match end {
                Some((oi, u, gap)) if gap < 0.0 => {
                    let ob = self.p.obstacles[oi];
                    let target = r + ob.radius_m - gap;
                    self.bead = [
                        ob.centre_m[0] + u[0] * target,
                        ob.centre_m[1] + u[1] * target,
                    ];
                    self.reflections += 1;
                    end = self.nearest(self.bead);
                }
                _ => break,
            }
        }
        end
    }

    /// One full-sample exact step near an obstacle (unit normal `n` from its
    /// centre to the bead, surface gap `gap`) with the coefficients from the
    /// [`DragTable`]: the same update as [`Self::substep`] with one sub-step,
    /// for a trapped bead with the clamp and contact zones excluded (`gap` ≥
    /// both). The two directions (normal, tangent) run as the lanes of
    /// `[f64; 2]`.
    ///
    /// The OU update is written for the displacement from the trap's end
    /// position p₁: with u = x₀ − p₀ and v = p₁ − p₀ projected on (n, t),
    /// x₁ − p₁ = c·u + v_d g − (v f_s) g + σ ξ per direction, i.e.
    /// e₁ + c (x₀ − e₀) + (v_d − w) g + σ ξ − e₁ of the module docs, with
    /// the obstacle centre cancelled exactly (x₀ − e₀ and e₁ − e₀ are
    /// projections of differences). Equal to the centre-relative form up to
    /// round-off (smaller: the bead's nanometre displacement is rounded
    /// instead of its micrometre distance to the obstacle centre). The
    /// caller runs the move's epilogue. Out of line on purpose: inlined,
    /// LLVM's SLP vectoriser pairs the table's lanes across coefficients
    /// and the step costs ≈ 13 more instructions.
    #[inline(never)]
    fn near_table_move(&mut self, p0: [f64; 2], p1: [f64; 2], n: [f64; 2], gap: f64) {
        // Same order of draws as the exact path: normal, then tangent.
        let nz = self.rng.sample2();
        let Some(tab) = self.drag.as_deref() else {
            return;
        };
        let r = self.p.radius_m;
        let s = r / (r + gap);
        let [c, g, sg, dr] = tab.eval(s);
        // Every operation below is lane-wise on pairs (normal, tangent) or
        // (x, y), so that it compiles to packed SSE2 arithmetic.
        let t = [-n[1], n[0]];
        let u = sub2(self.bead, p0);
        let v = sub2(p1, p0);
        // Projections on (n, t): a = u_x (n_x, t_x) + u_y (n_y, t_y).
        let (ntx, nty) = ([n[0], t[0]], [n[1], t[1]]);
        let a = add2(mul2([u[0]; 2], ntx), mul2([u[1]; 2], nty));
        let b = add2(mul2([v[0]; 2], ntx), mul2([v[1]; 2], nty));
        let w = mul2(b, [self.fs; 2]);
        let dx = add2(add2(mul2(c, a), sub2(dr, mul2(w, g))), mul2(sg, nz));
        // Back to (x, y): p₁ + dx_n n + dx_t t.
        self.bead = add2(p1, add2(mul2([dx[0]; 2], n), mul2([dx[1]; 2], t)));
    }

    /// After a trapped move that ended farther than the escape distance
    /// from the trap at `tb` (or not finite): a non-finite bead goes back
    /// into the trap (counted, still trapped), a finite one is lost.
    /// Returns true on escape.
    #[cold]
    #[inline(never)]
    fn nonfinite_or_escape(&mut self, tb: [f64; 2]) -> bool {
        if self.bead[0].is_finite() && self.bead[1].is_finite() {
            self.trapped = false;
            true
        } else {
            self.bead = tb;
            self.nonfinite += 1;
            false
        }
    }

    /// Nearest obstacle when all obstacles have the same radius (at least
    /// one): the smallest squared centre distance wins, one square root and
    /// one division for the winner only. Same result as [`Self::nearest`]
    /// (gap, normal and index; only exact ties of the rounded distances may
    /// pick another of the equidistant obstacles); `None` without obstacles
    /// or with the bead at an obstacle's centre (no normal).
    #[inline(always)]
    fn nearest_equal_radii(&self, r: [f64; 2]) -> Near {
        let obs = &self.p.obstacles[..];
        let first = obs.first()?;
        let d2 = |o: &Obstacle| {
            let d = [r[0] - o.centre_m[0], r[1] - o.centre_m[1]];
            (d, d[0] * d[0] + d[1] * d[1])
        };
        let (mut bd, mut bd2) = d2(first);
        let mut bi = 0;
        if let [_, second] = obs {
            // The common scene (two obstacles), straight-line.
            let (d, q) = d2(second);
            if q < bd2 {
                (bi, bd, bd2) = (1, d, q);
            }
        } else {
            let mut i = 1;
            while let Some(o) = obs.get(i) {
                let (d, q) = d2(o);
                if q < bd2 {
                    (bi, bd, bd2) = (i, d, q);
                }
                i += 1;
            }
        }
        let dist = bd2.sqrt();
        let gap = dist - self.p.radius_m - first.radius_m;
        if dist.is_nan() || dist <= 0.0 {
            // At an obstacle's centre: left to the general search.
            return None;
        }
        let inv = 1.0 / dist;
        Some((bi, [bd[0] * inv, bd[1] * inv], gap))
    }

    /// Contact bookkeeping, optical force and the returned sample, for the
    /// trap at `p1` and the nearest obstacle `near` of the final bead.
    #[inline(always)]
    fn finish_sample(
        &mut self,
        p1: [f64; 2],
        near: Near,
        mut ev: TweezerEvents,
        n_sub: u32,
    ) -> TweezerSample {
        self.trap = p1;
        self.near_cache = Some(near);
        let (normal, gap) = near.map_or(([0.0; 2], f64::INFINITY), |n| (n.1, n.2));
        let delta = self.p.contact_range_m;
        // Enter the contact zone below δ, leave it above 3δ.
        let flip = if self.in_contact {
            gap > 3.0 * delta
        } else {
            gap < delta
        };
        if flip {
            self.in_contact = !self.in_contact;
            ev.contact_start = self.in_contact;
            ev.contact_end = !self.in_contact;
        }
        let force = if self.trapped {
            let k = self.p.stiffness_n_per_m;
            [k * (p1[0] - self.bead[0]), k * (p1[1] - self.bead[1])]
        } else {
            [0.0; 2]
        };
        TweezerSample {
            bead_m: self.bead,
            trap_m: p1,
            force_n: force,
            gap_m: gap,
            normal,
            in_contact: self.in_contact,
            trapped: self.trapped,
            events: ev,
            substeps: n_sub,
        }
    }

    /// The hot path of [`Tweezer::step`]: trapped bead near an obstacle,
    /// outside the clamp and contact zones, far enough that one sub-step
    /// suffices (the same tests as the general path, on the cached nearest
    /// obstacle), table on. Returns `None` (nothing changed) otherwise.
    #[inline(always)]
    fn step_near_table(&mut self, p0: [f64; 2], p1: [f64; 2]) -> Option<TweezerSample> {
        let Some(Some((_, n, gap))) = self.near_cache else {
            return None;
        };
        if !(self.table_on && self.trapped && gap >= self.fast_gap_min) {
            return None;
        }
        // n_sub = 1 exactly when the general path finds no sub-stepping
        // needed (same expression, same rounding).
        let travel = norm2([p1[0] - p0[0], p1[1] - p0[1]]);
        let l = travel + self.diff_len;
        if gap < l + 2.0 * self.p.contact_range_m + self.p.escape_distance_m {
            return None;
        }
        self.near_table_move(p0, p1, n, gap);
        // One test for both rare cases: a non-finite bead (reset into the
        // trap, as in `finish_move`) or an escape (|d| > e, squared).
        let mut ev = TweezerEvents::default();
        let d = [self.bead[0] - p1[0], self.bead[1] - p1[1]];
        let e = self.p.escape_distance_m;
        let d2 = d[0] * d[0] + d[1] * d[1];
        if d2.is_nan() || d2 > e * e {
            ev.escaped = self.nonfinite_or_escape(p1);
        }
        let near = if self.equal_radii {
            self.nearest_equal_radii(self.bead)
        } else {
            self.nearest(self.bead)
        };
        match near {
            Some(nr) if nr.2 >= 0.0 => Some(self.finish_sample(p1, Some(nr), ev, 1)),
            _ => Some(self.finish_rare(p1, ev)),
        }
    }

    /// End of a hot-path step whose bead overlaps an obstacle (reflection)
    /// or sits at an obstacle's centre: the general nearest-obstacle search
    /// and the reflecting boundary, then the usual epilogue.
    #[cold]
    #[inline(never)]
    fn finish_rare(&mut self, p1: [f64; 2], ev: TweezerEvents) -> TweezerSample {
        let mut near = self.nearest(self.bead);
        if matches!(near, Some((_, _, g)) if g < 0.0) {
            near = self.reflect(near);
        }
        self.finish_sample(p1, near, ev, 1)
    }

    /// The free-space path (no obstacles, trapped, exact): one exact OU step
    /// per axis, the same expressions and order of draws as the general
    /// path (bit-identical), without its bookkeeping.
    #[inline(always)]
    fn step_free(&mut self, p0: [f64; 2], p1: [f64; 2]) -> TweezerSample {
        let nz = self.rng.sample2();
        let x0 = self.bead;
        // Computed as a pair and stored once (two scalar stores followed by
        // the 16-byte load of the next step stall store forwarding).
        let x1: [f64; 2] = std::array::from_fn(|i| {
            let w = (p1[i] - p0[i]) / self.dt;
            p1[i] + self.free_c * (x0[i] - p0[i]) - w * self.free_tau_1mc + self.free_sigma * nz[i]
        });
        self.bead = x1;
        let mut ev = TweezerEvents::default();
        if !(x1[0].is_finite() && x1[1].is_finite()) {
            self.bead = p1;
            self.nonfinite += 1;
        }
        if norm2([self.bead[0] - p1[0], self.bead[1] - p1[1]]) > self.p.escape_distance_m {
            self.trapped = false;
            ev.escaped = true;
        }
        self.finish_sample(p1, None, ev, 1)
    }

    /// Every case but the hot paths: free space untrapped or Euler, sub-steps (contact, clamp,
    /// fast trap), lost bead, Euler–Maruyama, table off.
    #[inline(never)]
    fn step_general(&mut self, p0: [f64; 2], p1: [f64; 2]) -> TweezerSample {
        let was_trapped = self.trapped;
        let mut ev = TweezerEvents::default();
        let mut near = match self.near_cache.take() {
            Some(n) => n,
            None => self.nearest(self.bead),
        };
        let n_sub: u32 = match near {
            None => 1,
            Some((_, _, gap)) => {
                let travel = norm2([p1[0] - p0[0], p1[1] - p0[1]]);
                let l = travel + self.diff_len;
                let delta = self.p.contact_range_m;
                if gap < l + 2.0 * delta + self.p.escape_distance_m {
                    let ell = (0.25 * delta).max(0.1 * gap.max(0.0));
                    ((l / ell).ceil() as u32).clamp(1, MAX_SUBSTEPS)
                } else {
                    1
                }
            }
        };
        let fast_near = match near {
            Some((_, n, gap))
                if n_sub == 1 && self.table_on && self.trapped && gap >= self.fast_gap_min =>
            {
                Some((n, gap))
            }
            _ => None,
        };
        if let Some((n, gap)) = fast_near {
            self.near_table_move(p0, p1, n, gap);
            near = self.finish_move(p1);
        } else if near.is_none() && self.trapped && self.p.integrator == TweezerIntegrator::Exact {
            // Fast path: free space, one exact step.
            for i in 0..2 {
                let w = (p1[i] - p0[i]) / self.dt;
                let n = self.normal();
                self.bead[i] = p1[i] + self.free_c * (self.bead[i] - p0[i]) - w * self.free_tau_1mc
                    + self.free_sigma * n;
            }
            if !(self.bead[0].is_finite() && self.bead[1].is_finite()) {
                self.bead = p1;
                self.nonfinite += 1;
            }
            if norm2([self.bead[0] - p1[0], self.bead[1] - p1[1]]) > self.p.escape_distance_m {
                self.trapped = false;
            }
        } else {
            let h = self.dt / n_sub as f64;
            let inv_h = n_sub as f64 * self.fs;
            let inv = 1.0 / n_sub as f64;
            for k in 0..n_sub {
                let a = k as f64 * inv;
                let b = (k + 1) as f64 * inv;
                let ta = [p0[0] + a * (p1[0] - p0[0]), p0[1] + a * (p1[1] - p0[1])];
                let tb = [p0[0] + b * (p1[0] - p0[0]), p0[1] + b * (p1[1] - p0[1])];
                near = self.substep(ta, tb, h, inv_h, near);
            }
        }
        if was_trapped && !self.trapped {
            ev.escaped = true;
        }
        if !self.trapped && !ev.escaped {
            let d = norm2([self.bead[0] - p1[0], self.bead[1] - p1[1]]);
            if d < 0.5 * self.p.escape_distance_m {
                self.trapped = true;
                ev.recaptured = true;
            }
        }
        // `near` now describes the bead's final position (the sub-steps
        // return it; the free-space path runs only without obstacles).
        self.finish_sample(p1, near, ev, n_sub)
    }
}

impl Tweezer for SimTweezer {
    fn sample_rate_hz(&self) -> f64 {
        self.fs
    }

    fn stiffness_n_per_m(&self) -> f64 {
        self.p.stiffness_n_per_m
    }

    fn reset(&mut self, trap_m: [f64; 2]) {
        let t = if trap_m.iter().all(|v| v.is_finite()) {
            trap_m
        } else {
            [0.0; 2]
        };
        self.trap = t;
        self.bead = t;
        self.near_cache = None;
        self.trapped = true;
        self.in_contact = false;
    }

    fn step(&mut self, trap_m: [f64; 2]) -> TweezerSample {
        let p0 = self.trap;
        let p1 = if trap_m.iter().all(|v| v.is_finite()) {
            trap_m
        } else {
            p0
        };
        if let Some(sample) = self.step_near_table(p0, p1) {
            return sample;
        }
        if matches!(self.near_cache, Some(None))
            && self.trapped
            && self.p.integrator == TweezerIntegrator::Exact
        {
            return self.step_free(p0, p1);
        }
        self.step_general(p0, p1)
    }
}

/// Arguments of `kilotouch sim tweezer` (units in the names).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TweezerSimArgs {
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Sample rate, Hz.
    pub fs_hz: f64,
    /// Trap stiffness, pN/µm.
    pub stiffness_pn_um: f64,
    /// Bead radius, µm.
    pub radius_um: f64,
    /// Temperature, K.
    pub temperature_k: f64,
    /// Viscosity, Pa·s.
    pub viscosity_pa_s: f64,
    /// Bead-centre to coverslip distance, µm.
    pub wall_distance_um: Option<f64>,
    /// Integrator.
    pub integrator: TweezerIntegrator,
    /// Seed.
    pub seed: u64,
}

impl Default for TweezerSimArgs {
    fn default() -> Self {
        Self {
            duration_s: 10.0,
            fs_hz: 10_000.0,
            stiffness_pn_um: 20.0,
            radius_um: 1.5,
            temperature_k: 293.15,
            viscosity_pa_s: 1.0016e-3,
            wall_distance_um: None,
            integrator: TweezerIntegrator::Exact,
            seed: 1,
        }
    }
}

/// Result of `kilotouch sim tweezer` (SI units in the names).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TweezerSimReport {
    /// Sample variance of x about its mean, m².
    pub var_x_m2: f64,
    /// Sample variance of y about its mean, m².
    pub var_y_m2: f64,
    /// Fitted corner frequency (aliased Lorentzian, x and y PSDs averaged), Hz.
    pub fc_fit_hz: f64,
    /// Fitted diffusion coefficient, m²/s.
    pub d_fit_m2_s: f64,
    /// κ/(2πγ) with γ including the wall factor, Hz.
    pub fc_theory_hz: f64,
    /// k_BT/κ, m².
    pub var_theory_m2: f64,
    /// k_BT/γ, m²/s.
    pub d_theory_m2_s: f64,
    /// Drag γ = γ₀·(Faxén factor), N·s/m.
    pub gamma_n_s_m: f64,
    /// Faxén factor of the wall (1 without).
    pub wall_factor: f64,
    /// Sample period over relaxation time, dt/τ.
    pub dt_over_tau: f64,
    /// Samples simulated per axis.
    pub n_samples: usize,
    /// Welch segment length used for the PSD.
    pub nperseg: usize,
    /// Fit band, Hz.
    pub fit_band_hz: [f64; 2],
    /// Integrator used.
    pub integrator: TweezerIntegrator,
    /// Seed used.
    pub seed: u64,
}

/// Library entry point of `kilotouch sim tweezer`: simulate a bead in a
/// fixed trap, report variances and an aliased-Lorentzian fit of the PSD
/// (Welch, Hann, 50 % overlap, from `kilotouch_dsp::spectral::welch`).
pub fn simulate_tweezer(args: &TweezerSimArgs) -> Result<TweezerSimReport, RigError> {
    let bad = |name: &'static str, value: f64, reason: &str| RigError::InvalidParameter {
        name,
        value,
        reason: reason.to_string(),
    };
    if !(args.duration_s.is_finite() && args.duration_s > 0.0) {
        return Err(bad("duration_s", args.duration_s, "must be finite and > 0"));
    }
    if !(args.fs_hz.is_finite() && args.fs_hz > 0.0) {
        return Err(bad("fs_hz", args.fs_hz, "must be finite and > 0"));
    }
    let n = (args.duration_s * args.fs_hz).round();
    if !(2048.0..=2.0e9).contains(&n) {
        return Err(bad(
            "duration_s",
            args.duration_s,
            "need between 2048 and 2e9 samples",
        ));
    }
    let n = n as usize;
    let params = TweezerParams {
        radius_m: args.radius_um * 1e-6,
        viscosity_pa_s: args.viscosity_pa_s,
        temperature_k: args.temperature_k,
        stiffness_n_per_m: args.stiffness_pn_um * 1e-6,
        wall_distance_m: args.wall_distance_um.map(|h| h * 1e-6),
        escape_distance_m: f64::MAX,
        integrator: args.integrator,
        seed: args.seed,
        ..TweezerParams::paper_default()
    };
    params.validate()?;
    let dt_over_tau = 1.0 / (args.fs_hz * params.tau());
    if args.integrator == TweezerIntegrator::Euler && dt_over_tau >= 2.0 {
        return Err(RigError::Unstable(format!(
            "Euler–Maruyama is unstable for dt/τ = {dt_over_tau:.3} ≥ 2; use the exact integrator"
        )));
    }
    let mut tw = SimTweezer::new(params.clone(), args.fs_hz)?;
    // Start from the stationary distribution.
    let sd = params.variance_theory().sqrt();
    let b0 = [sd * tw.normal(), sd * tw.normal()];
    tw.set_bead(b0);
    let mut xs = Vec::with_capacity(n);
    let mut ys = Vec::with_capacity(n);
    for _ in 0..n {
        let s = tw.step([0.0, 0.0]);
        xs.push(s.bead_m[0]);
        ys.push(s.bead_m[1]);
    }
    let var = |v: &[f64]| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64
    };
    let nperseg = (n / 16).clamp(256, 8192).next_power_of_two().min(n);
    let cfg = kilotouch_dsp::spectral::WelchConfig::new(nperseg);
    let px = kilotouch_dsp::spectral::welch(&xs, args.fs_hz, &cfg)?;
    let py = kilotouch_dsp::spectral::welch(&ys, args.fs_hz, &cfg)?;
    let psd: Vec<f64> = px.p.iter().zip(&py.p).map(|(a, b)| 0.5 * (a + b)).collect();
    let f_lo = 3.0 * args.fs_hz / nperseg as f64;
    let f_hi = 0.5 * args.fs_hz * (1.0 - 4.0 / nperseg as f64);
    let fit = crate::lorentzian::fit_aliased_lorentzian(&px.f, &psd, args.fs_hz, f_lo, f_hi)?;
    Ok(TweezerSimReport {
        var_x_m2: var(&xs),
        var_y_m2: var(&ys),
        fc_fit_hz: fit.fc_hz,
        d_fit_m2_s: fit.d_m2_s,
        fc_theory_hz: params.corner_hz(),
        var_theory_m2: params.variance_theory(),
        d_theory_m2_s: params.diffusion(),
        gamma_n_s_m: params.gamma_free(),
        wall_factor: params.wall_factor(),
        dt_over_tau,
        n_samples: n,
        nperseg,
        fit_band_hz: [f_lo, f_hi],
        integrator: args.integrator,
        seed: args.seed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wall_corrections_match_reference_table() {
        // REFERENCE-VALUES.md (h/R, parallel, perpendicular).
        let table = [
            (1.1, 2.360, 11.46),
            (1.5, 1.615, 3.205),
            (2.0, 1.386, 2.126),
            (3.0, 1.227, 1.569),
            (5.0, 1.126, 1.285),
            (10.0, 1.059, 1.126),
        ];
        for (hr, par, perp) in table {
            let s = 1.0 / hr;
            assert!(
                (faxen_parallel(s) / par - 1.0).abs() < 2e-3,
                "Faxén at h/R={hr}: {}",
                faxen_parallel(s)
            );
            // Schäffer's approximation is within 0.1 % of the exact series.
            assert!(
                (brenner_perpendicular(s) / perp - 1.0).abs() < 1.5e-3,
                "Brenner at h/R={hr}: {}",
                brenner_perpendicular(s)
            );
        }
    }

    #[test]
    fn mobility_derivative_matches_finite_difference() {
        for s in [0.05, 0.3, 0.6, 0.9, 0.99] {
            let h = 1e-6;
            let fd = (perpendicular_mobility(s + h) - perpendicular_mobility(s - h)) / (2.0 * h);
            assert!((fd - perpendicular_mobility_ds(s)).abs() < 1e-7, "s={s}");
        }
        // Lubrication limit: the mobility vanishes at contact like (1 − s).
        assert!(perpendicular_mobility(1.0).abs() < 1e-12);
    }

    #[test]
    fn stokes_and_default_corner() {
        let p = TweezerParams::paper_default();
        // γ₀ = 6π·1.0016e-3·1.5e-6 = 2.8318e-8 N·s/m.
        assert!((p.gamma0() - 2.8318e-8).abs() < 1e-11);
        // f_c = κ/(2πγ₀) ≈ 112.4 Hz for 20 pN/µm; inertia m/γ₀ ≈ 1 µs.
        assert!((p.corner_hz() / (2e-5 / (2.0 * PI * 2.8318e-8)) - 1.0).abs() < 1e-4);
        let mass = 4.0 / 3.0 * PI * p.radius_m.powi(3) * 2500.0;
        assert!(mass / p.gamma0() < 2e-6);
    }

    #[test]
    fn nonfinite_trap_is_ignored() {
        let mut t = SimTweezer::new(TweezerParams::paper_default(), 1e4).unwrap();
        for _ in 0..100 {
            let s = t.step([f64::NAN, f64::INFINITY]);
            assert!(s.bead_m.iter().chain(&s.force_n).all(|v| v.is_finite()));
        }
    }

    /// The tabulated near-obstacle coefficients agree with the exact
    /// formulas (independent evaluation at random s, finer than the check
    /// at construction) to 1e-9 relative, on several stiffnesses and rates.
    #[test]
    fn drag_table_matches_the_exact_coefficients() {
        let mut x = 0x2545_F491_4F6C_DD1D_u64;
        for (kappa, fs) in [(2e-5, 1e4), (1e-4, 1e4), (2e-5, 5e4), (1e-3, 2e3)] {
            let p = TweezerParams {
                stiffness_n_per_m: kappa,
                obstacles: vec![Obstacle {
                    centre_m: [12e-6, 0.0],
                    radius_m: 5e-6,
                }],
                ..TweezerParams::paper_default()
            };
            let t = SimTweezer::new(p.clone(), fs).unwrap();
            let err = t.drag_table_error().unwrap();
            assert!(err < 1e-9, "κ {kappa} fs {fs}: {err:e}");
            let tab = t.drag.as_deref().unwrap();
            let s_max = 1.0 / (1.0 + DRAG_CLAMP_GAP_OVER_R);
            for _ in 0..20_000 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let s = s_max * (x >> 11) as f64 / (1u64 << 53) as f64;
                let e = DragTable::exact(
                    s,
                    kappa,
                    1.0 / fs,
                    p.kt(),
                    1.0 / p.gamma_free(),
                    1.0 / p.radius_m,
                    true,
                );
                let a = tab.eval(s);
                let got = [
                    a[0][0], a[0][1], a[1][0], a[1][1], a[2][0], a[2][1], a[3][0],
                ];
                for q in 0..6 {
                    assert!((got[q] / e[q] - 1.0).abs() < 1e-9, "s {s} q {q}");
                }
                assert!((got[6] - e[6]).abs() < 1e-9 * e[4], "s {s} drift");
            }
        }
        // No table without obstacles or with Euler–Maruyama.
        assert!(
            SimTweezer::new(TweezerParams::paper_default(), 1e4)
                .unwrap()
                .drag_table_error()
                .is_none()
        );
    }

    /// The tabulated step and the exact one give the same trajectory (same
    /// draws, same order) while the trap drags the bead back and forth near
    /// an obstacle, within 1e-15 m (the bead's RMS excursion is ≈ 14 nm).
    #[test]
    fn tabulated_and_exact_near_obstacle_steps_agree() {
        let p = TweezerParams {
            obstacles: vec![
                Obstacle {
                    centre_m: [8e-6, 0.0],
                    radius_m: 5e-6,
                },
                Obstacle {
                    centre_m: [-10e-6, 14e-6],
                    radius_m: 5e-6,
                },
            ],
            seed: 4,
            ..TweezerParams::paper_default()
        };
        let mut fast = SimTweezer::new(p.clone(), 1e4).unwrap();
        let mut exact = SimTweezer::new(p, 1e4).unwrap();
        exact.set_drag_table(false);
        let (mut worst, mut near) = (0.0_f64, 0usize);
        for k in 0..40_000 {
            // Trap between x = −1 µm and 1.2 µm: surface gaps 0.3 … 2.5 µm.
            let trap = [0.1e-6 + 1.1e-6 * (k as f64 * 2e-4).sin(), 0.2e-6];
            let a = fast.step(trap);
            let b = exact.step(trap);
            worst = worst.max((a.bead_m[0] - b.bead_m[0]).abs());
            worst = worst.max((a.bead_m[1] - b.bead_m[1]).abs());
            near += usize::from(a.gap_m < 1e-6);
            assert_eq!(a.trapped, b.trapped);
        }
        assert!(
            near > 5_000,
            "the bead must spend time near the obstacle: {near}"
        );
        assert!(worst < 1e-15, "{worst:e} m");
        // Not vacuous: the two paths round differently (≈ 1e-19 m here).
        assert!(worst > 0.0);
    }

    #[test]
    fn invalid_parameters_rejected() {
        let p = TweezerParams {
            radius_m: -1.0,
            ..TweezerParams::paper_default()
        };
        assert!(SimTweezer::new(p, 1e4).is_err());
        let p = TweezerParams {
            wall_distance_m: Some(1.0e-6),
            ..TweezerParams::paper_default()
        };
        assert!(SimTweezer::new(p, 1e4).is_err());
        assert!(SimTweezer::new(TweezerParams::paper_default(), 0.0).is_err());
    }
}
