//! Bilateral coupling between the haptic handle and the optical trap.
//!
//! Per sample, from the handle position the encoders read:
//!
//! 1. **Trap**: the [`HandMapping`] puts the trap at offset + s·(handle −
//!    origin), clamped to the workspace; a non-finite handle keeps the
//!    previous trap (counted).
//! 2. **Haptic image**: the optical force's reaction, g·sign(s)·κ(bead −
//!    trap), plus, while the bead touches an obstacle, the wall damper
//!    −b·(v̂·n)·n ([`damper`]). This is the force to render at the handle, N.
//! 3. **Routing by [`Condition`]**: V — zero (every filter still runs, so
//!    switching is glitch-free); P — the Pantograph alone with
//!    [`PMode`] (`coupling.p_mode`), Haptuator off; D — the paper's chain
//!    (Fig. 6) on x: Linkwitz–Riley crossover, C_L on the Pantograph force
//!    and g_H·C_H on the Haptuator drive (g_H = `coupling.high_band_gain`),
//!    from a force-normalised chain ([`loop_chain`]) behind the
//!    [`ForceSplitter`] trait. The y axis has no
//!    Haptuator: it gets the P path in P and the full band in D. A change
//!    of condition cross-fades the two routings over [`CONDITION_FADE_S`].
//! 4. **Passivity controller** (optional, [`passivity`]) on the Pantograph
//!    forces.
//!
//! The coupling does not limit its outputs: the safety layer
//! ([`crate::safety`]) is the one place where commands are limited.

pub mod damper;
pub mod loop_chain;
pub mod mapping;
pub mod p_path;
pub mod passivity;

pub use loop_chain::{ChainSource, LoopChain, model_chain_design};
pub use mapping::HandMapping;

use crate::condition::{Condition, PMode};
use crate::config::RigConfig;
use crate::device::{ActuatorFrame, SensorFrame};
use crate::error::RigError;
use crate::tweezer::{Tweezer, TweezerSample};
use damper::WallDamper;
use kilotouch_dsp::chain::{Chain, ChainCoefficients};
use p_path::PPath;
use passivity::PassivityController;
use serde::{Deserialize, Serialize};

/// Duration of the cross-fade between two conditions' routings, s.
pub const CONDITION_FADE_S: f64 = 0.05;

/// Force sample (N) → (Pantograph force N, Haptuator drive V). The minimal
/// interface the coupling needs from the dsp chain.
pub trait ForceSplitter: Send {
    /// Split one sample. Must not allocate, lock or panic.
    fn split(&mut self, force_n: f64) -> (f64, f64);
    /// Clear the state.
    fn reset(&mut self);
}

impl ForceSplitter for Chain {
    #[inline]
    fn split(&mut self, force_n: f64) -> (f64, f64) {
        self.process(force_n)
    }
    fn reset(&mut self) {
        Chain::reset(self);
    }
}

/// Counters of the coupling's nets.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CouplingCounters {
    /// Non-finite handle positions or forces replaced (trap held, force 0).
    pub nonfinite: u64,
    /// Handle positions outside the trap workspace (trap clamped).
    pub workspace_clamped: u64,
    /// Samples in which the passivity controller added damping.
    pub passivity_active: u64,
}

/// One sample's rendering.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Rendered {
    /// The optical force's image at the handle, g·sign(s)·κ(bead − trap), N
    /// (what the study's force metrics use; zero in V).
    pub image_n: [f64; 2],
    /// The wall damper's force, N (zero in V and out of contact).
    pub damping_n: [f64; 2],
    /// The commands before the safety layer (Pantograph N, Haptuator V).
    pub command: ActuatorFrame,
}

/// Handle ↔ trap coupling (module docs), generic over the D-mode splitter.
#[derive(Debug, Clone)]
pub struct Coupling<S: ForceSplitter = Chain> {
    mapping: HandMapping,
    condition: Condition,
    p_mode: PMode,
    p_x: PPath,
    p_y: PPath,
    dual: S,
    damper: WallDamper,
    passivity: Option<PassivityController>,
    fade_from: Condition,
    fade_k: u32,
    fade_n: u32,
    last_trap: [f64; 2],
    counters: CouplingCounters,
    lean: bool,
    /// Rendering gain of the high band, g_H (`coupling.high_band_gain`).
    high_gain: f64,
}

impl Coupling<Chain> {
    /// Coupling with the model's as-designed chain ([`model_chain_design`]).
    ///
    /// # Errors
    /// Invalid configuration, chain design failure.
    pub fn from_config(cfg: &RigConfig) -> Result<Self, RigError> {
        Self::with_chain(cfg, &LoopChain::as_designed(cfg)?.coefficients)
    }

    /// Coupling with explicit (force-normalised) chain coefficients.
    ///
    /// # Errors
    /// Invalid configuration, a chain at another sample rate.
    pub fn with_chain(cfg: &RigConfig, coeffs: &ChainCoefficients) -> Result<Self, RigError> {
        if coeffs.fs() != cfg.rig.sample_rate_hz {
            return Err(RigError::InvalidInput(format!(
                "the chain runs at {} Hz, the rig at {} Hz",
                coeffs.fs(),
                cfg.rig.sample_rate_hz
            )));
        }
        Self::with_splitter(cfg, Chain::new(coeffs))
    }
}

impl<S: ForceSplitter> Coupling<S> {
    /// Coupling with an explicit D-mode splitter (e.g. a swappable chain).
    ///
    /// # Errors
    /// Invalid configuration.
    pub fn with_splitter(cfg: &RigConfig, dual: S) -> Result<Self, RigError> {
        cfg.validate()?;
        let fs = cfg.rig.sample_rate_hz;
        let c = &cfg.coupling;
        let mapping = HandMapping::from_config(c);
        Ok(Self {
            mapping,
            condition: c.mode,
            p_mode: c.p_mode,
            p_x: PPath::new(c.p_mode, fs)?,
            p_y: PPath::new(c.p_mode, fs)?,
            dual,
            damper: WallDamper::new(c.contact_damping_n_s_per_m, c.velocity_filter_hz, fs)?,
            passivity: c.passivity_controller.then(|| PassivityController::new(fs)),
            fade_from: c.mode,
            fade_k: 0,
            fade_n: crate::round_half_away(CONDITION_FADE_S * fs).max(1.0) as u32,
            last_trap: mapping.rest_trap_m(),
            counters: CouplingCounters::default(),
            lean: false,
            high_gain: c.high_band_gain,
        })
    }

    /// Current condition.
    pub fn condition(&self) -> Condition {
        self.condition
    }

    /// Switch condition: the routing cross-fades from the old to the new
    /// one over [`CONDITION_FADE_S`] (no step in force).
    pub fn set_condition(&mut self, c: Condition) {
        if c != self.condition {
            self.fade_from = self.condition;
            self.condition = c;
            self.fade_k = self.fade_n;
        }
    }

    /// Switch condition at once (a new trial: the filters were reset).
    pub fn set_condition_now(&mut self, c: Condition) {
        self.condition = c;
        self.fade_from = c;
        self.fade_k = 0;
    }

    /// Skip (true) or run (false, the default) the filters whose outputs
    /// the routing ignores, outside a cross-fade: every filter in V (the
    /// rendering is zero), the D chain in P (unless `p_mode` is the D
    /// chain's low channel). The rendering is the same either way (bit for
    /// bit); lean, the skipped filters' states go stale, so a later switch
    /// of condition starts them from there instead of from their history.
    /// For simulated trials that run one condition from a reset (scene
    /// fidelity); the engine switches conditions live and stays non-lean.
    pub fn set_lean(&mut self, on: bool) {
        self.lean = on;
    }

    /// What P renders.
    pub fn p_mode(&self) -> PMode {
        self.p_mode
    }

    /// The hand ↔ trap mapping.
    pub fn mapping(&self) -> &HandMapping {
        &self.mapping
    }

    /// Map the handle position `origin_m` (m) to the trap's rest position
    /// from now on (a live trial starts wherever the handle is: the
    /// mapping is re-centred on it, as a clutch re-indexes a master arm).
    pub fn set_handle_origin(&mut self, origin_m: [f64; 2]) {
        if origin_m.iter().all(|v| v.is_finite()) {
            self.mapping.handle_origin_m = origin_m;
        }
    }

    /// Counters.
    pub fn counters(&self) -> CouplingCounters {
        let mut c = self.counters;
        c.passivity_active = self.passivity.as_ref().map_or(0, |p| p.active_samples());
        c
    }

    /// The passivity controller, when enabled.
    pub fn passivity(&self) -> Option<&PassivityController> {
        self.passivity.as_ref()
    }

    /// The D-mode splitter.
    pub fn splitter(&self) -> &S {
        &self.dual
    }

    /// The latest handle-velocity estimate, m/s.
    pub fn handle_velocity(&self) -> [f64; 2] {
        self.damper.velocity()
    }

    /// Clear filter states and the fade; the trap restarts at rest.
    pub fn reset(&mut self) {
        self.p_x.reset();
        self.p_y.reset();
        self.dual.reset();
        self.damper.reset();
        if let Some(p) = &mut self.passivity {
            p.reset();
        }
        self.fade_k = 0;
        self.fade_from = self.condition;
        self.last_trap = self.mapping.rest_trap_m();
    }

    /// Trap position (m) for a handle position (m): the mapping, clamped to
    /// the workspace. A non-finite handle keeps the previous trap position.
    #[inline]
    pub fn trap_target(&mut self, handle_m: [f64; 2]) -> [f64; 2] {
        let v = self.mapping.to_trap_unclamped(handle_m);
        if self.mapping.in_workspace(v) {
            self.last_trap = v;
            return v;
        }
        self.trap_target_clamped(v)
    }

    #[cold]
    #[inline(never)]
    fn trap_target_clamped(&mut self, v: [f64; 2]) -> [f64; 2] {
        let mut t = self.last_trap;
        let mut clamped = false;
        let cl = self.mapping.clamp(v);
        for i in 0..2 {
            if v[i].is_finite() {
                clamped |= cl[i] != v[i];
                t[i] = cl[i];
            } else {
                self.counters.nonfinite += 1;
            }
        }
        if clamped {
            self.counters.workspace_clamped += 1;
        }
        self.last_trap = t;
        t
    }

    /// The optical force's image at the handle, N (zero when the bead is
    /// lost: the tweezer reports no force then).
    #[inline]
    pub fn image(&self, s: &TweezerSample) -> [f64; 2] {
        self.mapping.to_hand_force(s.force_n)
    }

    /// The rendering gain of the high band, g_H (dimensionless).
    pub fn high_band_gain(&self) -> f64 {
        self.high_gain
    }

    /// The routing of condition `c` for the force `fy` (N) and the chain/P
    /// outputs already computed; `g_h` scales D's Haptuator drive.
    #[inline(always)]
    fn route(c: Condition, fy: f64, p: (f64, f64), d: (f64, f64), g_h: f64) -> (f64, f64, f64) {
        match c {
            Condition::V => (0.0, 0.0, 0.0),
            Condition::P => (p.0, p.1, 0.0),
            Condition::D => (d.0, fy, g_h * d.1),
        }
    }

    /// Render one sample: `handle_m` is the handle position the trap was
    /// set from, `s` the tweezer sample.
    #[inline]
    pub fn render(&mut self, handle_m: [f64; 2], s: &TweezerSample) -> Rendered {
        if self.lean && self.fade_k == 0 && self.condition == Condition::V {
            // V renders zero; its filters run only to keep switching
            // glitch-free, which a lean coupling does not need.
            return Rendered::default();
        }
        let v = self.damper.update(handle_m);
        let image = self.image(s);
        let damping = self.damper.force(s);
        let mut f = [image[0] + damping[0], image[1] + damping[1]];
        if !(f[0].is_finite() && f[1].is_finite()) {
            self.counters.nonfinite += 1;
            f = [0.0; 2];
        }
        let chain_unused = self.lean
            && self.fade_k == 0
            && self.condition == Condition::P
            && self.p_mode != PMode::LowChannel;
        let d = if chain_unused {
            (0.0, 0.0)
        } else {
            self.dual.split(f[0])
        };
        let px = match self.p_mode {
            PMode::LowChannel => d.0,
            _ => self.p_x.process(f[0]),
        };
        let py = self.p_y.process(f[1]);
        let g_h = self.high_gain;
        let (mut lx, mut ly, mut hx) = Self::route(self.condition, f[1], (px, py), d, g_h);
        if self.fade_k > 0 {
            let a = f64::from(self.fade_k) / f64::from(self.fade_n);
            let (ox, oy, oh) = Self::route(self.fade_from, f[1], (px, py), d, g_h);
            lx += a * (ox - lx);
            ly += a * (oy - ly);
            hx += a * (oh - hx);
            self.fade_k -= 1;
        }
        if let Some(pc) = &mut self.passivity
            && self.condition.haptic()
        {
            [lx, ly] = pc.apply([lx, ly], v);
        }
        let haptic = self.condition.haptic();
        Rendered {
            image_n: if haptic { image } else { [0.0; 2] },
            damping_n: if haptic { damping } else { [0.0; 2] },
            command: ActuatorFrame {
                force_n: [lx, ly],
                haptuator_v: hx,
            },
        }
    }

    /// One coupling sample: handle → trap → tweezer → rendering.
    #[inline]
    pub fn step<T: Tweezer>(
        &mut self,
        sensors: &SensorFrame,
        tweezer: &mut T,
    ) -> (Rendered, TweezerSample) {
        let trap = self.trap_target(sensors.handle_m);
        let s = tweezer.step(trap);
        (self.render(sensors.handle_m, &s), s)
    }
}
