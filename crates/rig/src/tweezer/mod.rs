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
//! Files: [`drag`] (the wall-drag laws), [`sim`] (the simulated tweezer and
//! its step: a general path and two fast paths, free space and near an
//! obstacle, each checked against the general one), [`table`] (the
//! tabulated near-obstacle coefficients of the fast path).
//!
//! **Exact step.** With γ_i frozen over a (sub)step h, c = e^{−h/τ},
//! τ = γ_i/k_i, w = ė_i:
//! x(h) = e(h) + c (x₀ − e(0)) + (v_d − w) τ (1 − c) + √((k_BT/k_i)(1 − c²)) N(0,1),
//! the exact Ornstein–Uhlenbeck transition (docs/REFERENCE-VALUES.md), stable for
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
//!
//! **Trap profile** ([`TrapProfile`]). The linear spring above with its
//! cliff is the default. The Gaussian profile replaces it by the
//! Rayleigh-regime gradient force of a Gaussian beam, F ∝ ∇I with
//! I ∝ exp(−2|d|²/w0²) (Ashkin 1992, Biophys. J. 61:569; Harada & Asakura
//! 1996, Opt. Commun. 124:529):
//!
//! F(d) = −κ d exp(−2|d|²/w0²),  U(d) = (κ w0²/4)(1 − exp(−2|d|²/w0²)),
//!
//! d = bead − trap in the plane: stiffness κ at small d, the force peaks at
//! |d| = w0/2 with F_max = κ (w0/2) e^{−1/2} ≈ 0.303 κ w0, depth
//! U0 = κ w0²/4. The force acts whether or not the bead counts as trapped,
//! so escape is thermally activated (or forced) by the Langevin dynamics
//! themselves; "escaped" is bookkeeping, declared beyond
//! max(2 w0, `escape_distance`) (at 2 w0 the force is 0.2 % of F_max and U
//! is within 0.03 % of U0; a configured escape distance beyond that is
//! kept, so the rest of the code's escape radius is never shortened), and
//! recapture within half of it. The integrator of this profile is
//! described in [`sim`].

pub mod applied;
pub mod calibration;
pub mod detector;
pub mod drag;
pub mod record;
pub mod sim;
pub mod spot;
pub mod table;

pub use applied::{AppliedTrap, TrapCalibrationRecord, check_applicable, check_loop_gain};
pub use calibration::{TrapCalibration, TrapCalibrationSettings, calibrate_trap};
pub use detector::{DetectedTweezer, Detector, DetectorConfig};
pub use drag::{
    DRAG_CLAMP_GAP_OVER_R, brenner_perpendicular, faxen_parallel, perpendicular_mobility,
    perpendicular_mobility_ds, stokes_drag,
};
pub use sim::{CONTACT_EXACT_MARGIN_SD, SimTweezer, nearest_obstacle};
pub use spot::{KAPPA_BIAS_WARN, SurfaceDrag, surface_drag};
pub use table::DRAG_TABLE_PIECES;

use crate::config::TweezerConfig;
use crate::error::RigError;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Boltzmann constant, J/K (exact, SI 2019).
pub const BOLTZMANN: f64 = 1.380_649e-23;
/// Largest number of sub-steps per sample: bounds the worst-case cost of a
/// sample (≈ 40 µs, within the 100 µs period at 10 kHz). When the cap binds
/// (trap moving > ~0.6 µm per sample next to an obstacle) the contact zone is
/// resolved more coarsely; the reflecting boundary still prevents overlap.
pub const MAX_SUBSTEPS: u32 = 128;
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
pub use crate::config::{WAIST_MAX_M, WAIST_MIN_M};

impl TrapProfile {
    /// The trap profile of a rig file's `profile` and `waist_m` (a
    /// Gaussian profile without a waist gets NaN, which
    /// [`crate::config::TweezerConfig::issues`] and
    /// [`TweezerParams::validate`] refuse).
    pub fn of(c: &TweezerConfig) -> Self {
        match c.profile {
            crate::config::TrapProfileKind::Linear => Self::Linear,
            crate::config::TrapProfileKind::Gaussian => Self::Gaussian {
                waist_m: c.waist_m.unwrap_or(f64::NAN),
            },
        }
    }
}

/// Radial profile of the optical force (module docs).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TrapProfile {
    /// Linear spring F = −κ d up to the escape distance, then no force
    /// (default).
    #[default]
    Linear,
    /// Gaussian-beam gradient force F = −κ d exp(−2|d|²/w0²).
    Gaussian {
        /// Beam waist w0 (1/e² intensity radius), m.
        waist_m: f64,
    },
}
impl TrapProfile {
    /// The default linear profile.
    pub fn is_linear(&self) -> bool {
        matches!(self, Self::Linear)
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
    /// Radial force profile (default linear).
    #[serde(default, skip_serializing_if = "TrapProfile::is_linear")]
    pub profile: TrapProfile,
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
            profile: TrapProfile::Linear,
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
            profile: TrapProfile::of(c),
        }
    }

    /// Check every parameter.
    pub fn validate(&self) -> Result<(), RigError> {
        let pos = RigError::require_positive;
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
        if let TrapProfile::Gaussian { waist_m } = self.profile
            && !(waist_m.is_finite() && (WAIST_MIN_M..=WAIST_MAX_M).contains(&waist_m))
        {
            return Err(RigError::InvalidParameter {
                name: "waist_m",
                value: waist_m,
                reason: format!("beam waist must lie in [{WAIST_MIN_M}, {WAIST_MAX_M}] m"),
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

    /// Optical force on a bead at `d` = bead − trap (m), N: −κ d for the
    /// linear profile (inside the escape distance; the caller handles a
    /// lost bead), −κ d exp(−2|d|²/w0²) for the Gaussian one.
    pub fn optical_force_n(&self, d: [f64; 2]) -> [f64; 2] {
        let k = self.secant_stiffness(d[0] * d[0] + d[1] * d[1]);
        [-k * d[0], -k * d[1]]
    }

    /// Secant stiffness F/|d| at |d|² = `d2` (m²), N/m: κ (linear) or
    /// κ exp(−2|d|²/w0²) (Gaussian; 0 once the exponent exceeds 600, where
    /// the force is below 1e-260 κ w0).
    #[inline]
    pub fn secant_stiffness(&self, d2: f64) -> f64 {
        match self.profile {
            TrapProfile::Linear => self.stiffness_n_per_m,
            TrapProfile::Gaussian { waist_m } => {
                let u = 2.0 * d2 / (waist_m * waist_m);
                if u <= 600.0 {
                    self.stiffness_n_per_m * (-u).exp()
                } else {
                    0.0
                }
            }
        }
    }

    /// Optical potential U at distance `r` (m) from the trap centre, J:
    /// κ r²/2 (linear, inside the escape distance) or
    /// (κ w0²/4)(1 − exp(−2 r²/w0²)) (Gaussian).
    pub fn potential_j(&self, r: f64) -> f64 {
        let k = self.stiffness_n_per_m;
        match self.profile {
            TrapProfile::Linear => 0.5 * k * r * r,
            TrapProfile::Gaussian { waist_m } => {
                let w2 = waist_m * waist_m;
                -0.25 * k * w2 * (-2.0 * r * r / w2).exp_m1()
            }
        }
    }

    /// Depth of the trap, J: κ w0²/4 (Gaussian), κ e²/2 at the escape
    /// distance e (linear).
    pub fn depth_j(&self) -> f64 {
        match self.profile {
            TrapProfile::Linear => self.potential_j(self.escape_distance_m),
            TrapProfile::Gaussian { waist_m } => 0.25 * self.stiffness_n_per_m * waist_m * waist_m,
        }
    }

    /// Largest restoring force, N: κ (w0/2) e^{−1/2} at |d| = w0/2
    /// (Gaussian), κ e at the escape distance (linear).
    pub fn peak_force_n(&self) -> f64 {
        match self.profile {
            TrapProfile::Linear => self.stiffness_n_per_m * self.escape_distance_m,
            TrapProfile::Gaussian { waist_m } => {
                self.stiffness_n_per_m * 0.5 * waist_m * (-0.5_f64).exp()
            }
        }
    }

    /// Distance from the trap centre beyond which the bead counts as
    /// escaped, m: the escape distance (linear) or max(2 w0, escape
    /// distance) (Gaussian, module docs).
    pub fn escape_radius_m(&self) -> f64 {
        match self.profile {
            TrapProfile::Linear => self.escape_distance_m,
            TrapProfile::Gaussian { waist_m } => (2.0 * waist_m).max(self.escape_distance_m),
        }
    }
}
/// Events of one sample.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TweezerEvents {
    /// The bead entered an obstacle's contact zone.
    pub contact_start: bool,
    /// The bead left the contact zone (with hysteresis, 3δ).
    pub contact_end: bool,
    /// The bead left the trap's escape radius
    /// ([`TweezerParams::escape_radius_m`]) and is lost.
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
    /// Optical force on the bead, N: κ(trap − bead), 0 when lost (linear
    /// profile); the Gaussian profile's force, also when lost
    /// ([`TweezerParams::optical_force_n`]).
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
    /// Position-detector signals (x, y) of the last sample, V, when the
    /// tweezer reports them (live tweezers; [`detector::Detector`]).
    fn detector_v(&self) -> Option<[f64; 2]> {
        None
    }
    /// Advance `traps.len()` samples at once: `out[i]` is the sample in
    /// which the trap moved to `traps[i]` (`out` at least as long). A live
    /// tweezer exchanges the block in one round trip, with its command lead
    /// ([`Self::loop_delay_samples`]); a simulated one steps sample by
    /// sample (the default), so block and sample stepping agree exactly.
    /// Must not allocate, lock or panic.
    fn step_block(&mut self, traps: &[[f64; 2]], out: &mut [TweezerSample]) {
        for (t, o) in traps.iter().zip(out.iter_mut()) {
            *o = self.step(*t);
        }
    }
    /// Samples by which the bead's answer to a trap set-point comes later
    /// than in the simulated loop, for blocks of `block_len` samples: 0 for
    /// a simulated tweezer and for a block-synchronous link (the block's
    /// samples answer the block's set-points within the same exchange); a
    /// live link's command lead otherwise. The stability clearance adds it
    /// to the rig's loop delay.
    fn loop_delay_samples(&self, block_len: usize) -> u32 {
        let _ = block_len;
        0
    }
    /// A link failure since the last [`Self::reset`] (live tweezers): the
    /// samples after it carry no force, and the loop ends with a link error
    /// naming the tweezer instead of reporting an escape.
    fn link_error(&self) -> Option<crate::device::LinkErrorKind> {
        None
    }
    /// Round trip of the link measured at connection, s (live tweezers).
    fn round_trip_s(&self) -> Option<f64> {
        None
    }
    /// [`Self::step_block`], and the position-detector signals (x, y, V) of
    /// each sample in `volts[i]` (at least as long as `traps`); `false`
    /// when the tweezer reports no detector signals. The default steps
    /// sample by sample and reads [`Self::detector_v`] after each. Must not
    /// allocate, lock or panic.
    fn step_block_detected(
        &mut self,
        traps: &[[f64; 2]],
        out: &mut [TweezerSample],
        volts: &mut [[f64; 2]],
    ) -> bool {
        for ((t, o), v) in traps.iter().zip(out.iter_mut()).zip(volts.iter_mut()) {
            *o = self.step(*t);
            match self.detector_v() {
                Some(d) => *v = d,
                None => return false,
            }
        }
        true
    }
}
