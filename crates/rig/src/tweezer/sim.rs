//! The simulated tweezer ([`SimTweezer`]): the exact step of the module
//! docs of [`super`], with sub-steps in contact, the reflecting boundary,
//! escape and recapture; and its two fast paths (free space; near an
//! obstacle with the tabulated coefficients) that must equal the general
//! path (free space bit for bit; near an obstacle within the table's error).
//!
//! **Gaussian profile** ([`super::TrapProfile::Gaussian`]). The fast paths
//! (free space, the drag table, the exact contact step) assume the linear
//! spring and are off; every sample takes the general path, whose
//! (sub)step uses the *secant* stiffness k = κ exp(−u), u = 2|d|²/w0², of
//! the sub-step's start (d = bead − trap) in the exact OU update (written
//! with `exp_m1`, so k → 0 far out tends to free diffusion without
//! cancellation): exact where the force is linear, and for the nonlinear
//! force a first-order (weak) scheme. Its local error at leading order in
//! the sub-step h — the missing (h²/2)(μF·∇ + DΔ)(μF) of the mean and
//! h² D μ (J + Jᵀ) of the covariance, J = ∇F — relative to the linear
//! spring's drift μκ|d|h and to the diffusion 2Dh, is at most
//!
//! η = (h/τ) (2u e^{−u} + 2 k_BT/U0),  τ = γ/κ, U0 = κ w0²/4
//!
//! (u e^{−2u} and 8 (k_BT/κw0²) e^{−u}|1 − u/2| for the mean, 2u e^{−u} for
//! the variance; 2u e^{−u} ≤ 2/e). The sample is split into n sub-steps so
//! that η ≤ [`GAUSSIAN_STEP_TOL`] = 1 %, u taken at the worst point of
//! |d| ± (trap travel + 4√(2D dt)) and τ with the free drag (near an
//! obstacle the drag is larger and τ longer). In a deep trap the bead stays
//! where u ≈ 0 and one step per sample suffices (the default rig with
//! w0 = 0.5 µm: η ≈ 0.2 %); at the force peak the default rig takes 6.
//! Euler–Maruyama uses the same sub-steps with the nonlinear force.

use super::drag::{
    DRAG_CLAMP_GAP_OVER_R, faxen_parallel_mobility, perpendicular_mobility,
    perpendicular_mobility_ds,
};
use super::table::DragTable;
use super::{
    MAX_SUBSTEPS, Obstacle, TrapProfile, Tweezer, TweezerEvents, TweezerIntegrator, TweezerParams,
    TweezerSample,
};
use crate::error::RigError;
use crate::lanes::{l2_add, l2_mul, l2_sub, norm2};
use crate::normal::NormalStream;

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
    // The exact contact step ([`SimTweezer::set_contact_exact`]): enabled,
    // its coefficients (None when the parameters do not allow it) and the
    // samples it took.
    contact_exact: bool,
    contact: Option<ContactStep>,
    contact_steps: u64,
    // Distance from the trap beyond which the bead is lost, m
    // ([`TweezerParams::escape_radius_m`]).
    esc: f64,
    // The Gaussian profile's step control (None: linear profile).
    gauss: Option<GaussStep>,
}
/// Largest local error η of a sub-step of the Gaussian profile (module
/// docs), relative to the linear spring's drift and to the diffusion.
pub const GAUSSIAN_STEP_TOL: f64 = 0.01;
/// Sub-step control of the Gaussian profile (module docs).
#[derive(Debug, Clone, Copy)]
struct GaussStep {
    /// 2/w0², 1/m².
    two_over_w2: f64,
    /// dt/τ with the free drag.
    dt_over_tau: f64,
    /// 2 k_BT/U0.
    thermal: f64,
}
impl GaussStep {
    /// Sub-steps for a sample that starts at |d| = `d0` (m) and may move by
    /// `l` (m): η ≤ [`GAUSSIAN_STEP_TOL`] at the worst u in
    /// [2 (d0 − l)²/w0², 2 (d0 + l)²/w0²], 1 … [`MAX_SUBSTEPS`].
    #[inline]
    fn substeps(&self, d0: f64, l: f64) -> u32 {
        let lo = (d0 - l).max(0.0);
        let (u_min, u_max) = (
            self.two_over_w2 * lo * lo,
            self.two_over_w2 * (d0 + l) * (d0 + l),
        );
        // 2u e^{−u} is largest at u = 1: the point of the range nearest 1.
        let uc = if u_max < 1.0 {
            u_max
        } else if u_min > 1.0 {
            u_min
        } else {
            1.0
        };
        let g = if uc < 700.0 {
            2.0 * uc * (-uc).exp()
        } else {
            0.0
        };
        let x = self.dt_over_tau * (g + self.thermal) / GAUSSIAN_STEP_TOL;
        if x.is_finite() {
            (x.ceil() as u32).clamp(1, MAX_SUBSTEPS)
        } else {
            MAX_SUBSTEPS
        }
    }
}
/// Coefficients of the exact full-sample step of a bead next to the
/// obstacle ([`SimTweezer::step_contact_exact`]). Inside the drag clamp
/// (gap < 0.1 R) every coefficient of the sub-step is constant — the clamped
/// mobilities, no Itô drift, stiffness κ + k_c along the normal inside the
/// contact zone (gap < δ) and κ outside it, κ along the tangent — so one
/// exact OU step of a whole sample replaces the sub-steps while the bead
/// stays in one of the two zones.
#[derive(Debug, Clone, Copy)]
struct ContactStep {
    /// Normal direction inside the contact zone, κ + k_c: (c, τ(1 − c) in s,
    /// σ in m); outside it, κ alone.
    n_in: [f64; 3],
    n_out: [f64; 3],
    /// κ + k_c, N/m.
    kn: f64,
    /// Tangent direction (κ): (c, τ(1 − c) in s, σ in m).
    t: [f64; 3],
    /// Contact stiffness k_c, N/m; R + R_o + δ, m; R + R_o, m.
    kc: f64,
    s_star: f64,
    r_c: f64,
    /// Smallest gap of the fast step, m: [`CONTACT_EXACT_MARGIN_SD`] normal
    /// step SDs from the surface, where the reflecting boundary acts.
    margin: f64,
    /// Contact range δ and the clamp gap 0.1 R, m.
    delta: f64,
    clamp: f64,
}
/// Smallest gap of the exact contact step, in standard deviations of its
/// normal step inside the contact zone: closer to the surface the general
/// path sub-steps (and reflects), as it does wherever a step may change
/// zone.
pub const CONTACT_EXACT_MARGIN_SD: f64 = 4.0;
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
impl ContactStep {
    /// The coefficients for `p` at step `dt` (s), k_BT `kt` (J) and free
    /// mobility `mu0` = 1/(γ₀ f_w) (m/(N·s)); `None` unless there is exactly
    /// one obstacle, δ < 0.1 R (the contact zone inside the drag clamp) and
    /// the integrator is exact.
    fn new(p: &TweezerParams, dt: f64, kt: f64, mu0: f64) -> Option<Self> {
        let clamp = DRAG_CLAMP_GAP_OVER_R * p.radius_m;
        let delta = p.contact_range_m;
        let [o] = p.obstacles.as_slice() else {
            return None;
        };
        if p.integrator != TweezerIntegrator::Exact || delta >= clamp {
            return None;
        }
        // The clamped mobilities of the sub-step (gap < 0.1 R).
        let s = p.radius_m / (p.radius_m + clamp);
        let mu_n = mu0 * perpendicular_mobility(s);
        let mu_t = mu0 * faxen_parallel_mobility(s);
        let kappa = p.stiffness_n_per_m;
        let kc = p.contact_stiffness_n_per_m;
        let kn = kappa + kc;
        // The exact step's coefficients as `scalar_step` computes them.
        let coef = |k: f64, mu: f64| {
            let kmu = k * mu;
            let c = (-dt * kmu).exp();
            [c, (1.0 / kmu) * (1.0 - c), (kt / k * (1.0 - c * c)).sqrt()]
        };
        let n_in = coef(kn, mu_n);
        let r_c = p.radius_m + o.radius_m;
        Some(Self {
            n_in,
            n_out: coef(kappa, mu_n),
            kn,
            t: coef(kappa, mu_t),
            kc,
            s_star: r_c + delta,
            r_c,
            margin: CONTACT_EXACT_MARGIN_SD * n_in[2],
            delta,
            clamp,
        })
    }
}
/// Nearest obstacle: (index, unit normal from its centre to the bead, gap).
type Near = Option<(usize, [f64; 2], f64)>;

/// The obstacle nearest to a bead of radius `bead_radius_m` centred at `r`
/// (m): its index, the unit normal of its surface at the bead (from its
/// centre toward the bead; (1, 0) with the bead at its centre) and the
/// surface gap g = |r − c| − R − R_o (m, negative on overlap); `None`
/// without obstacles. The one geometry of a scene: the simulated tweezer
/// steps with it, a live tweezer's samples get their gap and normal from
/// it ([`crate::serial::LinkTweezer`]).
#[inline(always)]
pub fn nearest_obstacle(
    obstacles: &[Obstacle],
    bead_radius_m: f64,
    r: [f64; 2],
) -> Option<(usize, [f64; 2], f64)> {
    // Pick the nearest by gap first; normalise only the winner's offset
    // (one division, two products).
    let (mut bi, mut bd, mut bgap, mut bdist) = (usize::MAX, [0.0; 2], f64::INFINITY, 0.0);
    for (i, o) in obstacles.iter().enumerate() {
        let d = [r[0] - o.centre_m[0], r[1] - o.centre_m[1]];
        let dist = norm2(d);
        let gap = dist - bead_radius_m - o.radius_m;
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
        let gauss = match params.profile {
            TrapProfile::Linear => None,
            TrapProfile::Gaussian { waist_m } => Some(GaussStep {
                two_over_w2: 2.0 / (waist_m * waist_m),
                dt_over_tau: dt / tau,
                thermal: 2.0 * kt / params.depth_j(),
            }),
        };
        let drag = if params.obstacles.is_empty()
            || params.integrator != TweezerIntegrator::Exact
            || gauss.is_some()
        {
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
        let contact = ContactStep::new(&params, dt, kt, 1.0 / gf).filter(|_| gauss.is_none());
        Ok(Self {
            esc: params.escape_radius_m(),
            gauss,
            contact_exact: false,
            contact,
            contact_steps: 0,
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

    /// Current trap centre, m.
    pub fn trap(&self) -> [f64; 2] {
        self.trap
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

    /// Use the exact full-sample step for a bead in sustained contact
    /// ([`Self::step_contact_exact`]) instead of the sub-steps (off by
    /// default: the sub-stepped path is the reference). Has no effect when
    /// the parameters do not allow it (more than one obstacle, δ > 0.1 R,
    /// Euler–Maruyama).
    pub fn set_contact_exact(&mut self, on: bool) {
        self.contact_exact = on;
    }

    /// Whether the exact contact step is enabled and possible.
    pub fn contact_exact(&self) -> bool {
        self.contact_exact && self.contact.is_some()
    }

    /// Samples advanced by the exact contact step.
    pub fn contact_exact_steps(&self) -> u64 {
        self.contact_steps
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

    /// Nearest obstacle ([`nearest_obstacle`]).
    #[inline(always)]
    fn nearest(&self, r: [f64; 2]) -> Option<(usize, [f64; 2], f64)> {
        nearest_obstacle(&self.p.obstacles, self.p.radius_m, r)
    }

    #[inline]
    fn normal(&mut self) -> f64 {
        self.rng.sample()
    }

    /// [`Tweezer::step`] by the general path alone (no fast path): the
    /// reference the free-space path must equal bit for bit and the
    /// near-obstacle table path within the table's error, for the
    /// equivalence harness (`tests/equivalence.rs`).
    #[doc(hidden)]
    pub fn step_reference(&mut self, trap_m: [f64; 2]) -> TweezerSample {
        let p0 = self.trap;
        let p1 = if trap_m.iter().all(|v| v.is_finite()) {
            trap_m
        } else {
            p0
        };
        self.step_general(p0, p1)
    }

    /// Put the bead at a position drawn from the free trap's stationary
    /// distribution around the trap centre (variance k_BT/κ per axis), from
    /// the tweezer's own noise stream: a simulation that starts there needs
    /// no warm-up.
    pub fn start_stationary(&mut self) {
        let sd = self.p.variance_theory().sqrt();
        let t = self.trap;
        let b = [t[0] + sd * self.normal(), t[1] + sd * self.normal()];
        self.set_bead(b);
    }

    /// One exact/EM update of a scalar coordinate x over h (see [`Ou`]).
    /// `inv_h` = 1/h.
    #[inline]
    fn scalar_step(&mut self, x: f64, ou: Ou, h: f64, inv_h: f64) -> f64 {
        let Ou { k, e0, e1, mu, v } = ou;
        let n = self.normal();
        match self.p.integrator {
            TweezerIntegrator::Exact if self.gauss.is_some() => {
                // The same transition with 1 − c and 1 − c² from `exp_m1`:
                // no cancellation when k (the secant stiffness) is tiny.
                if k > 0.0 {
                    let kmu = k * mu;
                    let omc = -(-h * kmu).exp_m1();
                    let w = (e1 - e0) * inv_h;
                    e1 + (1.0 - omc) * (x - e0)
                        + (v - w) * (omc / kmu)
                        + (self.kt / k * -(-2.0 * h * kmu).exp_m1()).sqrt() * n
                } else {
                    x + v * h + (2.0 * self.kt * h * mu).sqrt() * n
                }
            }
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
        let kappa = if self.gauss.is_some() {
            // The secant stiffness at the sub-step's start, trapped or not.
            let d = [self.bead[0] - ta[0], self.bead[1] - ta[1]];
            self.p.secant_stiffness(d[0] * d[0] + d[1] * d[1])
        } else if self.trapped {
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
            let e = self.esc;
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
        let u = l2_sub(self.bead, p0);
        let v = l2_sub(p1, p0);
        // Projections on (n, t): a = u_x (n_x, t_x) + u_y (n_y, t_y).
        let (ntx, nty) = ([n[0], t[0]], [n[1], t[1]]);
        let a = l2_add(l2_mul([u[0]; 2], ntx), l2_mul([u[1]; 2], nty));
        let b = l2_add(l2_mul([v[0]; 2], ntx), l2_mul([v[1]; 2], nty));
        let w = l2_mul(b, [self.fs; 2]);
        let dx = l2_add(
            l2_add(l2_mul(c, a), l2_sub(dr, l2_mul(w, g))),
            l2_mul(sg, nz),
        );
        // Back to (x, y): p₁ + dx_n n + dx_t t.
        self.bead = l2_add(p1, l2_add(l2_mul([dx[0]; 2], n), l2_mul([dx[1]; 2], t)));
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
        let force = if self.gauss.is_some() {
            // The Gaussian force acts on a lost bead too.
            self.p
                .optical_force_n([self.bead[0] - p1[0], self.bead[1] - p1[1]])
        } else if self.trapped {
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

    /// The exact step of a trapped bead next to the (only) obstacle,
    /// inside the drag clamp: there the trap (plus the contact spring inside
    /// the contact zone) is linear with constant coefficients
    /// ([`ContactStep`]), so one exact OU step over the whole sample in the
    /// (normal, tangent) frame of the start replaces the general path's
    /// sub-steps (the module docs of [`super`], with k = κ + k_c and the
    /// equilibrium (κ t·n + k_c s*)/(κ + k_c) along the normal in contact).
    /// Taken only when the start gap and the mean end gap lie in the same
    /// zone — [m, δ) (contact) or [δ, 0.1 R) — with m =
    /// [`CONTACT_EXACT_MARGIN_SD`] normal SDs from the surface; otherwise
    /// returns `None` (nothing changed) and the general path sub-steps the
    /// sample, so the samples that may cross a zone's boundary are resolved
    /// as before. Same draws as one general sub-step (normal, then
    /// tangent); the epilogue (reflection, escape, contact events) is the
    /// general path's.
    #[inline]
    fn step_contact_exact(&mut self, p0: [f64; 2], p1: [f64; 2]) -> Option<TweezerSample> {
        let cs = self.contact?;
        let Some(Some((oi, n, g0))) = self.near_cache else {
            return None;
        };
        // Zone of a gap: Some(true) in contact, Some(false) between δ and
        // the clamp, None elsewhere (near the surface, outside the clamp).
        let zone = |g: f64| {
            if g >= cs.margin && g < cs.delta {
                Some(true)
            } else if g >= cs.delta && g < cs.clamp {
                Some(false)
            } else {
                None
            }
        };
        let contact = zone(g0)?;
        if !self.trapped {
            return None;
        }
        let o = self.p.obstacles[oi];
        let t = [-n[1], n[0]];
        let proj = |p: [f64; 2], u: [f64; 2]| {
            (p[0] - o.centre_m[0]) * u[0] + (p[1] - o.centre_m[1]) * u[1]
        };
        let kappa = self.p.stiffness_n_per_m;
        let ([c, tau_1mc, sigma], en0, en1) = if contact {
            (
                cs.n_in,
                (kappa * proj(p0, n) + cs.kc * cs.s_star) / cs.kn,
                (kappa * proj(p1, n) + cs.kc * cs.s_star) / cs.kn,
            )
        } else {
            (cs.n_out, proj(p0, n), proj(p1, n))
        };
        let sn = cs.r_c + g0;
        let mean_n = en1 + c * (sn - en0) - (en1 - en0) * self.fs * tau_1mc;
        if zone(mean_n - cs.r_c) != Some(contact) {
            return None;
        }
        let nz = self.rng.sample2();
        let sn1 = mean_n + sigma * nz[0];
        let st = proj(self.bead, t);
        let (et0, et1) = (proj(p0, t), proj(p1, t));
        let [ct, tau_1mc_t, sigma_t] = cs.t;
        let st1 = et1 + ct * (st - et0) - (et1 - et0) * self.fs * tau_1mc_t + sigma_t * nz[1];
        self.bead = [
            o.centre_m[0] + sn1 * n[0] + st1 * t[0],
            o.centre_m[1] + sn1 * n[1] + st1 * t[1],
        ];
        let near = self.finish_move(p1);
        let ev = TweezerEvents {
            escaped: !self.trapped,
            ..TweezerEvents::default()
        };
        self.contact_steps += 1;
        Some(self.finish_sample(p1, near, ev, 1))
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
        let mut n_sub: u32 = match near {
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
        if let Some(g) = self.gauss {
            let l = norm2([p1[0] - p0[0], p1[1] - p0[1]]) + self.diff_len;
            let d0 = norm2([self.bead[0] - p0[0], self.bead[1] - p0[1]]);
            n_sub = n_sub.max(g.substeps(d0, l));
        }
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
        } else if near.is_none()
            && self.trapped
            && self.p.integrator == TweezerIntegrator::Exact
            && self.gauss.is_none()
        {
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
            if d < 0.5 * self.esc {
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
        if self.contact_exact
            && let Some(sample) = self.step_contact_exact(p0, p1)
        {
            return sample;
        }
        if matches!(self.near_cache, Some(None))
            && self.trapped
            && self.p.integrator == TweezerIntegrator::Exact
            && self.gauss.is_none()
        {
            return self.step_free(p0, p1);
        }
        self.step_general(p0, p1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
