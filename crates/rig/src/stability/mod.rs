//! Closed-loop stability of the bilateral coupling: gain and phase margins,
//! critical trap stiffness and force scale, from the models (paper §5 names
//! closed-loop stability as the open question of channel separation).
//!
//! # The loop
//!
//! Per axis and sample n (the order of [`crate::haptic_loop`]): the encoder
//! position x₁[n] sets the trap, trap = s·x₁; the bead moves over one sample
//! with the trap moving linearly (exact Ornstein–Uhlenbeck step, drift
//! only: the noise does not enter a linear stability question); the haptic
//! image F = g·κ·(bead − trap) plus, in contact, the wall damper
//! −b_c·v̂ (v̂ = 2nd-order Butterworth low-pass of the backward difference of
//! x₁) enters the controller path of the condition (D on x: crossover with
//! C_L to the Pantograph force and g_H·C_H to the Haptuator drive, g_H the
//! rendering gain of the high band `coupling.high_band_gain`; P: `p_mode`;
//! the y axis has no Haptuator and gets the P path in P and the full band in
//! D); the commands are held over the next sample (ZOH) by the plant of
//! eq. 1 with the hand held still behind the finger spring, whose output is
//! x₁[n+1]. As a discrete transfer function, with C(z) the controller path
//! and P(z) = C(zI − Φ)⁻¹Γ the exact ZOH plant from its inputs to x₁,
//!
//! ```text
//! L(z) = −[E(z) − b_c·V(z)] · [P_f(z)·C_low(z) + g_H·P_v(z)·C_high(z)]
//! E(z) = g·κ·s·(B(z) − 1),   B(z) = β·((1 − a)z + a − c)/(z − c)
//! ```
//!
//! where B maps trap to bead: c = e^{−T/τ}, τ = γ/k, a = τ(1 − c)/T, k = κ
//! and β = 1 in free space; pressed against an obstacle k = κ + k_c,
//! β = κ/(κ + k_c) and γ is the drag along the obstacle normal at the
//! tweezer's contact clamp (Brenner at h/R = 1.1, `crate::tweezer`). At DC
//! the pressed environment is the spring K_e = g·s·κ·k_c/(κ + k_c) at the
//! handle (≈ 790 N/m at the defaults). The closed loop is 1 + L = 0; its
//! verdict comes from the eigenvalues of the closed-loop state matrix
//! (spectral radius < 1), its margins from L(e^{jω}) ([`margins`], python-
//! control's definitions).
//!
//! # Worst case
//!
//! Every haptic condition (P, D) × axis (x, y) × state (free, pressed) ×
//! hand (the corners of `[stability]`'s finger stiffness × damping ranges
//! and the rig file's nominal `k_f`, `b_f`); a condition's margins are the
//! worst over its cases. Not modelled: encoder quantisation, actuator and
//! safety limits, the slew limit and the passivity controller (nonlinear
//! nets that only act once something is wrong).

pub mod discrete;
pub mod margins;

use crate::condition::{Condition, PMode};
use crate::config::RigConfig;
use crate::error::RigError;
use crate::plant::{Axis, AxisModel, IN_DRIVE, IN_FORCE, OUT_MOTOR};
use crate::tweezer::{DRAG_CLAMP_GAP_OVER_R, TweezerParams, brenner_perpendicular};
use crate::units::to_pn_per_um;
use discrete::Dss;
use kilotouch_dsp::chain::ChainCoefficients;
use kilotouch_dsp::design::{FilterKind, Prewarp, butter};
use kilotouch_dsp::filter::{BiquadCoeffs, sections_response};
use margins::Margins;
use nalgebra::DMatrix;
use num_complex::Complex64 as C64;
use serde::{Deserialize, Serialize};
use std::cell::Cell;
use std::f64::consts::PI;

/// Where the bead is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LoopState {
    /// Trapped in free space (the environment is the trap's viscous spring).
    Free,
    /// Pressed against an obstacle (the environment is a stiff spring).
    Pressed,
}

/// A finger impedance (tip to hand).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Hand {
    /// Stiffness, N/m.
    pub stiffness_n_per_m: f64,
    /// Damping, N·s/m.
    pub damping_n_s_per_m: f64,
}

/// One analysed configuration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Case {
    /// Condition.
    pub condition: Condition,
    /// Axis.
    pub axis: Axis,
    /// Bead state.
    pub state: LoopState,
    /// Hand.
    pub hand: Hand,
}

/// Verdict and margins of one case.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaseResult {
    /// The case.
    pub case: Case,
    /// All closed-loop poles strictly inside the unit circle.
    pub stable: bool,
    /// Largest closed-loop pole magnitude.
    pub spectral_radius: f64,
    /// Growth of the slowest closed-loop mode, 20·log₁₀(ρ)·f_s, dB/s
    /// (negative: it decays). What `sim press` measures on the envelope.
    pub growth_db_per_s: f64,
    /// Margins (module docs), when asked for.
    pub margins: Option<Margins>,
}

/// A condition's worst-case margins over its cases.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ConditionMargins {
    /// Condition (`"P"` or `"D"`).
    pub condition: Condition,
    /// Worst gain margin, dB (null: no phase crossover anywhere).
    pub gain_margin_db: f64,
    /// Worst phase margin, degrees (null: no gain crossover anywhere).
    pub phase_margin_deg: f64,
    /// Smallest distance of the Nyquist curve from −1.
    pub vector_margin: f64,
    /// Every case stable (eigenvalues).
    pub stable: bool,
    /// Stable and both margins at least the configured minima.
    pub meets_minimum: bool,
    /// Largest closed-loop pole magnitude over the cases.
    pub spectral_radius: f64,
    /// Growth of the slowest mode pressed along x with the rig file's own
    /// finger (`k_f`, `b_f`), dB/s (negative: decays): what `sim press`
    /// should measure.
    pub nominal_growth_db_per_s: f64,
    /// The loop pressed along x with the rig file's own finger is stable.
    pub nominal_stable: bool,
    /// Phase crossover of the worst gain margin, Hz.
    pub phase_crossover_hz: f64,
    /// Gain crossover of the worst phase margin, Hz.
    pub gain_crossover_hz: f64,
    /// The case with the worst gain margin.
    pub worst_gain_case: Case,
    /// The case with the worst phase margin.
    pub worst_phase_case: Case,
}

/// The stability report (`kilotouch rig margins --json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StabilityReport {
    /// P and D.
    pub conditions: Vec<ConditionMargins>,
    /// Trap stiffness at which some case turns unstable, N/m (at the
    /// configured force scale; infinite, JSON null: none below 10⁴× the
    /// configured value; JSON key `critical_trap_stiffness_pn_um`, pN/µm).
    #[serde(
        rename = "critical_trap_stiffness_pn_um",
        with = "crate::units::pn_per_um"
    )]
    pub critical_trap_stiffness_n_per_m: f64,
    /// Largest force scale (N/N) at which every case meets the minimum
    /// margins: the largest safe value.
    pub max_force_scale: f64,
    /// Force scale at which some case turns unstable (N/N).
    pub critical_force_scale: f64,
    /// Configured force scale, N/N.
    pub force_scale: f64,
    /// Configured trap stiffness, N/m (JSON key `trap_stiffness_pn_um`, pN/µm).
    #[serde(rename = "trap_stiffness_pn_um", with = "crate::units::pn_per_um")]
    pub trap_stiffness_n_per_m: f64,
    /// Pressed environment stiffness at the handle, K_e = g·s·κ·k_c/(κ + k_c), N/m.
    pub pressed_stiffness_n_per_m: f64,
    /// Required gain margin, dB.
    pub min_gain_margin_db: f64,
    /// Required phase margin, degrees.
    pub min_phase_margin_deg: f64,
    /// Every condition meets the minima.
    pub safe: bool,
    /// Largest high-band handle force the Haptuator renders without
    /// clipping: drive limit / max_f |g_H·C_high(f)|, N.
    pub high_band_force_full_scale_n: f64,
    /// Configured rendering gain of the high band, g_H (dimensionless).
    #[serde(default = "one")]
    pub high_band_gain: f64,
    /// Largest g_H at which every D case meets the minimum margins at the
    /// configured force scale: the largest safe value (null: none below
    /// 10⁴× the configured value, or 10⁴ when it is 0).
    #[serde(default)]
    pub max_high_band_gain: f64,
    /// What P receives.
    pub p_mode: PMode,
    /// Extra loop delay the report is for, s (0: the simulated loop's one
    /// sample only; [`analyse_with_latency`]).
    #[serde(default)]
    pub latency_s: f64,
    /// That delay in whole samples, d = ⌈latency·f_s⌉ ([`delay_samples`]).
    #[serde(default)]
    pub latency_samples: usize,
}

fn one() -> f64 {
    1.0
}

impl StabilityReport {
    /// The margins of `c`, if analysed.
    pub fn condition(&self, c: Condition) -> Option<&ConditionMargins> {
        self.conditions.iter().find(|m| m.condition == c)
    }

    /// A one-line reason when the loop is not safe to arm, naming the
    /// failing margin and the largest safe force scale.
    pub fn refusal(&self) -> Option<String> {
        if self.safe {
            return None;
        }
        let bad: Vec<String> = self
            .conditions
            .iter()
            .filter(|c| !c.meets_minimum)
            .map(|c| {
                if !c.stable {
                    format!(
                        "{} is unstable (phase margin {:.1}°, gain margin {:.1} dB)",
                        c.condition, c.phase_margin_deg, c.gain_margin_db
                    )
                } else if c.gain_margin_db < self.min_gain_margin_db {
                    format!(
                        "{} has a gain margin of {:.1} dB (minimum {} dB)",
                        c.condition, c.gain_margin_db, self.min_gain_margin_db
                    )
                } else {
                    format!(
                        "{} has a phase margin of {:.1}° (minimum {}°)",
                        c.condition, c.phase_margin_deg, self.min_phase_margin_deg
                    )
                }
            })
            .collect();
        let (with_delay, at_delay) = match self.delay_text() {
            Some(d) => (
                format!(" with an extra loop delay of {d}"),
                " at that delay",
            ),
            None => (String::new(), ""),
        };
        let high = if self.high_band_gain > self.max_high_band_gain {
            format!(
                "; the largest safe high-band gain{at_delay} is {:.3} (now {:.3})",
                self.max_high_band_gain, self.high_band_gain
            )
        } else {
            String::new()
        };
        Some(format!(
            "closed loop not safe{with_delay}: {}; the largest safe force scale{at_delay} is {:.3e} N/N (now {:.3e}){high}",
            bad.join(", "),
            self.max_force_scale,
            self.force_scale
        ))
    }

    /// The extra loop delay as "3.00 ms (30 samples)"; `None` without one.
    pub fn delay_text(&self) -> Option<String> {
        (self.latency_samples > 0).then(|| {
            format!(
                "{:.2} ms ({} sample{})",
                1e3 * self.latency_s,
                self.latency_samples,
                if self.latency_samples == 1 { "" } else { "s" }
            )
        })
    }

    /// Plain-text summary (CLI, GUI).
    pub fn summary(&self) -> String {
        let mut s = String::new();
        if let Some(d) = self.delay_text() {
            s.push_str(&format!(
                "with an extra loop delay of {d} on top of the simulated loop's one sample\n"
            ));
        }
        for c in &self.conditions {
            s.push_str(&format!(
                "{}: gain margin {} dB, phase margin {}°, {}{}\n",
                c.condition,
                fmt_margin(c.gain_margin_db),
                fmt_margin(c.phase_margin_deg),
                if c.stable { "stable" } else { "UNSTABLE" },
                if c.meets_minimum {
                    ""
                } else {
                    " — below the minimum"
                },
            ));
        }
        s.push_str(&format!(
            "critical trap stiffness {} pN/µm (now {:.1}); largest safe force scale {:.3e} N/N (now {:.3e}); instability at {:.3e}\n",
            fmt_margin(to_pn_per_um(self.critical_trap_stiffness_n_per_m)),
            to_pn_per_um(self.trap_stiffness_n_per_m),
            self.max_force_scale,
            self.force_scale,
            self.critical_force_scale
        ));
        s.push_str(&format!(
            "high-band gain g_H {:.3}; largest safe {}\n",
            self.high_band_gain,
            fmt_margin(self.max_high_band_gain)
        ));
        s
    }
}

fn fmt_margin(x: f64) -> String {
    if x.is_finite() {
        format!("{x:.1}")
    } else {
        "∞".into()
    }
}

/// Frequency responses of the controller path of a (condition, axis).
#[derive(Debug, Clone)]
struct CtrlPath {
    low: Vec<BiquadCoeffs>,
    /// Haptuator path (x axis in D only).
    high: Option<Vec<BiquadCoeffs>>,
}

impl CtrlPath {
    /// (low, high) responses at `f` Hz (high 0 without a Haptuator path).
    fn response(&self, f: f64, fs: f64) -> [C64; 2] {
        [
            sections_response(&self.low, f, fs),
            self.high
                .as_ref()
                .map_or(C64::new(0.0, 0.0), |h| sections_response(h, f, fs)),
        ]
    }
}

#[derive(Debug, Clone)]
struct PlantCase {
    axis: Axis,
    hand: Hand,
    /// ZOH plant from [force (, drive)] to x₁.
    ss: Dss,
    /// Responses on the grid: [x₁/f, x₁/u_v].
    resp: Vec<[C64; 2]>,
}

impl PlantCase {
    fn eval(&self, f: f64, fs: f64) -> [C64; 2] {
        let z = C64::from_polar(1.0, 2.0 * PI * f / fs);
        let ss = &self.ss;
        let n = ss.n_states();
        let mut m = DMatrix::<C64>::from_fn(n, n, |i, j| C64::new(-ss.a[(i, j)], 0.0));
        for i in 0..n {
            m[(i, i)] += z;
        }
        let lu = m.lu();
        let mut out = [C64::new(0.0, 0.0); 2];
        for (k, o) in out.iter_mut().enumerate().take(ss.b.ncols()) {
            let rhs = DMatrix::<C64>::from_fn(n, 1, |i, _| C64::new(ss.b[(i, k)], 0.0));
            if let Some(x) = lu.solve(&rhs) {
                let mut y = C64::new(ss.d[(0, k)], 0.0);
                for i in 0..n {
                    y += ss.c[(0, i)] * x[(i, 0)];
                }
                *o = y;
            } else {
                *o = C64::new(f64::INFINITY, 0.0);
            }
        }
        out
    }
}

/// A controller path's (low, high) responses on the grid, per (condition, axis).
type PathResponse = ((Condition, Axis), Vec<[C64; 2]>);

/// The loop model of a rig file and a (force-normalised) chain, ready to
/// evaluate cases at any trap stiffness and force scale.
#[derive(Debug, Clone)]
pub struct LoopAnalysis {
    cfg: RigConfig,
    fs: f64,
    chain: ChainCoefficients,
    grid: Vec<f64>,
    plants: Vec<PlantCase>,
    damper: Vec<BiquadCoeffs>,
    /// b_c·V on the grid.
    damper_resp: Vec<C64>,
    /// Controller path responses (low, high) on the grid per (condition, axis).
    paths: Vec<PathResponse>,
    tweezer: TweezerParams,
    /// Extra loop delay, whole samples (z⁻ᵈ; [`Self::with_latency`]).
    delay: usize,
    /// The extra loop delay asked for, s (`delay` is it rounded up).
    latency_s: f64,
}

impl LoopAnalysis {
    /// Build the plant maps for every axis and hand of `cfg` and the
    /// controller paths of `chain` (the chain the D loop runs, force in N →
    /// Pantograph N and Haptuator V).
    ///
    /// # Errors
    /// Invalid configuration, a chain at another sample rate, numerical
    /// failure of the plant discretisation.
    pub fn new(cfg: &RigConfig, chain: &ChainCoefficients) -> Result<Self, RigError> {
        cfg.validate()?;
        let fs = cfg.rig.sample_rate_hz;
        if (chain.fs() - fs).abs() > 1e-9 * fs {
            return Err(RigError::InvalidInput(format!(
                "the chain runs at {} Hz, the rig at {fs} Hz",
                chain.fs()
            )));
        }
        let st = &cfg.stability;
        let mut hands = vec![Hand {
            stiffness_n_per_m: cfg.plant.k_f,
            damping_n_s_per_m: cfg.plant.b_f,
        }];
        for k in st.hand_stiffness_n_per_m {
            for b in st.hand_damping_n_s_per_m {
                let h = Hand {
                    stiffness_n_per_m: k,
                    damping_n_s_per_m: b,
                };
                if !hands.contains(&h) {
                    hands.push(h);
                }
            }
        }
        let grid = margins::grid(fs);
        let mut plants = Vec::new();
        for axis in [Axis::X, Axis::Y] {
            for &hand in &hands {
                let mut c = cfg.clone();
                c.plant.k_f = hand.stiffness_n_per_m;
                c.plant.b_f = hand.damping_n_s_per_m;
                let model = AxisModel::new(&c, axis)?;
                let ss = model.active_free();
                let inputs: &[usize] = match axis {
                    Axis::X => &[IN_FORCE, IN_DRIVE],
                    Axis::Y => &[IN_FORCE],
                };
                let b = DMatrix::from_fn(ss.b.nrows(), inputs.len(), |i, j| ss.b[(i, inputs[j])]);
                let (phi, gam) = crate::lti::zoh(&ss.a, &b, 1.0 / fs)?;
                let dss = Dss {
                    a: phi,
                    b: gam,
                    c: ss.c.rows(OUT_MOTOR, 1).into_owned(),
                    d: DMatrix::zeros(1, inputs.len()),
                };
                plants.push(PlantCase {
                    axis,
                    hand,
                    ss: dss,
                    resp: Vec::new(),
                });
            }
        }
        let c = &cfg.coupling;
        let mut damper = vec![BiquadCoeffs {
            b0: fs,
            b1: -fs,
            b2: 0.0,
            a1: 0.0,
            a2: 0.0,
        }];
        damper.extend(butter(
            2,
            c.velocity_filter_hz,
            fs,
            FilterKind::Lowpass,
            Prewarp::AtCutoff,
        )?);
        let mut out = Self {
            cfg: cfg.clone(),
            fs,
            chain: chain.clone(),
            grid,
            plants,
            damper,
            damper_resp: Vec::new(),
            paths: Vec::new(),
            tweezer: TweezerParams::from_config(&cfg.tweezer),
            delay: 0,
            latency_s: 0.0,
        };
        out.tabulate()?;
        Ok(out)
    }

    /// The plant, damper and controller path responses on the grid.
    fn tabulate(&mut self) -> Result<(), RigError> {
        let fs = self.fs;
        for pc in &mut self.plants {
            pc.resp = self.grid.iter().map(|&f| pc.eval(f, fs)).collect();
        }
        let b = self.cfg.coupling.contact_damping_n_s_per_m;
        self.damper_resp = self
            .grid
            .iter()
            .map(|&f| b * sections_response(&self.damper, f, fs))
            .collect();
        self.paths.clear();
        for cond in Condition::HAPTIC {
            for axis in [Axis::X, Axis::Y] {
                let p = self.ctrl(cond, axis, 1.0)?;
                let r = self.grid.iter().map(|&f| p.response(f, fs)).collect();
                self.paths.push(((cond, axis), r));
            }
        }
        Ok(())
    }

    /// The same loop with an extra delay of `latency_s` seconds between
    /// the sensors and the command (on top of the one sample of the
    /// simulated loop): z⁻ᵈ with d = [`delay_samples`]`(latency_s, f_s)`
    /// whole samples, rounded up (conservative). The delay enters the
    /// eigenvalue verdict as d shift-register states appended to the open
    /// loop ([`Dss::delay`]) and the margins as the factor e^{−j2πfd/f_s}
    /// on L (docs/theory/coupling-and-stability.md, loop delay). 0 s: the loop of [`Self::new`].
    ///
    /// # Errors
    /// A latency that is not finite, negative or above [`MAX_LATENCY_S`]
    /// (or [`MAX_DELAY_SAMPLES`]).
    pub fn with_latency(mut self, latency_s: f64) -> Result<Self, RigError> {
        let d = delay_samples(latency_s, self.fs)?;
        self.delay = d;
        self.latency_s = latency_s;
        let grid = margins::grid_for_delay(self.fs, d);
        if grid != self.grid {
            self.grid = grid;
            self.tabulate()?;
        }
        Ok(self)
    }

    /// The extra loop delay, s (as asked for).
    pub fn latency_s(&self) -> f64 {
        self.latency_s
    }

    /// The extra loop delay, whole samples.
    pub fn latency_samples(&self) -> usize {
        self.delay
    }

    /// `l` times the extra delay's z⁻ᵈ at `f` Hz (`l` itself without one).
    /// The phase is reduced to one turn before the sine and cosine, so L
    /// stays real at Nyquist for any d.
    fn delayed(&self, l: C64, f: f64) -> C64 {
        if self.delay == 0 {
            return l;
        }
        let turns = f * self.delay as f64 / self.fs;
        l * C64::from_polar(1.0, -2.0 * PI * (turns - turns.floor()))
    }

    /// The controller path of `condition` on `axis` (module docs), the
    /// Haptuator's path times the high-band gain `gh`.
    fn ctrl(&self, condition: Condition, axis: Axis, gh: f64) -> Result<CtrlPath, RigError> {
        let fs = self.fs;
        let p_path = |axis: Axis| -> Result<Vec<BiquadCoeffs>, RigError> {
            Ok(match (self.cfg.coupling.p_mode, axis) {
                (PMode::FullBand, _) | (PMode::LowChannel, Axis::Y) => Vec::new(),
                (PMode::LowChannel, Axis::X) => self.chain.low().to_vec(),
                (PMode::Lowpass { hz }, _) => {
                    butter(2, hz, fs, FilterKind::Lowpass, Prewarp::AtCutoff)?
                }
            })
        };
        Ok(match (condition, axis) {
            (Condition::D, Axis::X) => CtrlPath {
                low: self.chain.low().to_vec(),
                high: Some(scaled_sections(self.chain.high(), gh)),
            },
            (Condition::D, Axis::Y) => CtrlPath {
                low: Vec::new(),
                high: None,
            },
            (Condition::P, a) => CtrlPath {
                low: p_path(a)?,
                high: None,
            },
            (Condition::V, _) => {
                return Err(RigError::InvalidInput(
                    "condition V renders no force: there is no loop".into(),
                ));
            }
        })
    }

    /// Environment coefficients (one section) for `state` at trap stiffness
    /// `kappa` (N/m) and force scale `g` (N/N): F = E(z)·x₁.
    fn environment(&self, state: LoopState, kappa: f64, g: f64) -> BiquadCoeffs {
        let t = &self.tweezer;
        let s = self.cfg.coupling.position_scale;
        let gamma_free = t.gamma_free();
        let (k, beta, gamma) = match state {
            LoopState::Free => (kappa, 1.0, gamma_free),
            LoopState::Pressed => {
                let kc = t.contact_stiffness_n_per_m;
                let sr = 1.0 / (1.0 + DRAG_CLAMP_GAP_OVER_R);
                (
                    kappa + kc,
                    kappa / (kappa + kc),
                    gamma_free * brenner_perpendicular(sr),
                )
            }
        };
        let dt = 1.0 / self.fs;
        let tau = gamma / k;
        let c = (-dt / tau).exp();
        let a = tau * (1.0 - c) / dt;
        // The handle force is g·sign(s)·κ(bead − trap) and trap = s·x₁:
        // the product g·κ·|s|.
        let gk = g * kappa * s.abs();
        BiquadCoeffs {
            b0: gk * (beta * (1.0 - a) - 1.0),
            b1: gk * (beta * (a - c) + c),
            b2: 0.0,
            a1: -c,
            a2: 0.0,
        }
    }

    /// Every case of the haptic conditions (module docs).
    pub fn cases(&self) -> Vec<Case> {
        let mut v = Vec::new();
        for condition in Condition::HAPTIC {
            for p in &self.plants {
                for state in [LoopState::Free, LoopState::Pressed] {
                    v.push(Case {
                        condition,
                        axis: p.axis,
                        state,
                        hand: p.hand,
                    });
                }
            }
        }
        v
    }

    fn plant(&self, case: &Case) -> Result<&PlantCase, RigError> {
        self.plants
            .iter()
            .find(|p| p.axis == case.axis && p.hand == case.hand)
            .ok_or_else(|| RigError::InvalidInput(format!("no plant for {case:?}")))
    }

    /// The loop of `case` as a state-space block from the force at the
    /// controller's input back to itself.
    fn open_loop(&self, case: &Case, kappa: f64, g: f64, gh: f64) -> Result<Dss, RigError> {
        let plant = self.plant(case)?;
        let ctrl = self.ctrl(case.condition, case.axis, gh)?;
        let low = Dss::sections(&ctrl.low);
        let to_plant = match (&ctrl.high, case.axis) {
            (Some(h), Axis::X) => low.stack(&Dss::sections(h)),
            (None, Axis::X) => low.stack(&Dss::gain(0.0)),
            (_, Axis::Y) => low,
        };
        let mut env = Dss::sections(&[self.environment(case.state, kappa, g)]);
        if case.state == LoopState::Pressed && self.cfg.coupling.contact_damping_n_s_per_m > 0.0 {
            let d =
                Dss::sections(&self.damper).scaled(-self.cfg.coupling.contact_damping_n_s_per_m);
            env = env.plus(&d);
        }
        let ol = to_plant.then(&plant.ss).then(&env);
        Ok(if self.delay > 0 {
            ol.then(&Dss::delay(self.delay))
        } else {
            ol
        })
    }

    /// L from the responses at one frequency: plant `p`, controller path
    /// `c`, environment `env`, damper `damp` (b_c·V).
    fn loop_value(state: LoopState, p: [C64; 2], c: [C64; 2], env: C64, damp: C64) -> C64 {
        let damp = if state == LoopState::Pressed {
            damp
        } else {
            C64::new(0.0, 0.0)
        };
        -(env - damp) * (p[0] * c[0] + p[1] * c[1])
    }

    /// L at any frequency (refinement of crossings).
    fn loop_at(
        &self,
        case: &Case,
        ctrl: &CtrlPath,
        plant: &PlantCase,
        f: f64,
        env: &BiquadCoeffs,
    ) -> C64 {
        let fs = self.fs;
        let damp =
            self.cfg.coupling.contact_damping_n_s_per_m * sections_response(&self.damper, f, fs);
        let l = Self::loop_value(
            case.state,
            plant.eval(f, fs),
            ctrl.response(f, fs),
            env.response(f, fs),
            damp,
        );
        self.delayed(l, f)
    }

    /// Verdict (and margins when `with_margins`) of one case at trap
    /// stiffness `kappa` (N/m) and force scale `g` (N/N).
    ///
    /// # Errors
    /// Numerical failure, condition V.
    pub fn case(
        &self,
        case: &Case,
        kappa: f64,
        g: f64,
        with_margins: bool,
    ) -> Result<CaseResult, RigError> {
        self.case_with(case, kappa, g, with_margins, true)
    }

    fn case_with(
        &self,
        case: &Case,
        kappa: f64,
        g: f64,
        with_margins: bool,
        refine: bool,
    ) -> Result<CaseResult, RigError> {
        let gh = self.cfg.coupling.high_band_gain;
        self.case_gains(case, [kappa, g, gh], with_margins, refine)
    }

    /// [`Self::case_with`] at trap stiffness, force scale and high-band gain
    /// `[κ (N/m), g (N/N), g_H]`.
    fn case_gains(
        &self,
        case: &Case,
        [kappa, g, gh]: [f64; 3],
        with_margins: bool,
        refine: bool,
    ) -> Result<CaseResult, RigError> {
        let ol = self.open_loop(case, kappa, g, gh)?;
        let (stable, rho) = match ol.closed_unity() {
            Some(a) => {
                let rho = crate::lti::spectral_radius(&a);
                (rho.is_finite() && rho < 1.0 - 1e-12, rho)
            }
            None => (false, f64::INFINITY),
        };
        let margins = if with_margins {
            let plant = self.plant(case)?;
            let ctrl = self.ctrl(case.condition, case.axis, gh)?;
            let paths = &self
                .paths
                .iter()
                .find(|(k, _)| *k == (case.condition, case.axis))
                .ok_or_else(|| RigError::InvalidInput(format!("no controller path for {case:?}")))?
                .1;
            let env = self.environment(case.state, kappa, g);
            let values: Vec<C64> = (0..self.grid.len())
                .map(|i| {
                    let l = Self::loop_value(
                        case.state,
                        plant.resp[i],
                        [paths[i][0], gh * paths[i][1]],
                        env.response(self.grid[i], self.fs),
                        self.damper_resp[i],
                    );
                    self.delayed(l, self.grid[i])
                })
                .collect();
            let eval = |f: f64| self.loop_at(case, &ctrl, plant, f, &env);
            Some(if refine {
                margins::margins(&self.grid, &values, &eval, self.fs)
            } else {
                margins::margins_on_grid(
                    &self.grid,
                    &values,
                    eval(0.0),
                    eval(0.5 * self.fs),
                    self.fs,
                )
            })
        } else {
            None
        };
        Ok(CaseResult {
            case: *case,
            stable,
            spectral_radius: rho,
            growth_db_per_s: 20.0 * rho.log10() * self.fs,
            margins,
        })
    }

    /// All cases at (`kappa`, `g`).
    ///
    /// # Errors
    /// As [`Self::case`].
    pub fn evaluate(
        &self,
        kappa: f64,
        g: f64,
        with_margins: bool,
    ) -> Result<Vec<CaseResult>, RigError> {
        self.cases()
            .iter()
            .map(|c| self.case(c, kappa, g, with_margins))
            .collect()
    }

    /// Every case satisfies `ok`. The case that failed last (`hint`, an
    /// index into [`Self::cases`]) is tried first: across a scan's points
    /// an unsafe one then usually costs one case instead of many (each is
    /// an eigenvalue problem of 30 + d states). The answer does not depend
    /// on the order.
    fn all_cases(
        &self,
        hint: &Cell<usize>,
        ok: &dyn Fn(&Case) -> Result<bool, RigError>,
    ) -> Result<bool, RigError> {
        let cases = self.cases();
        let n = cases.len();
        for k in 0..n {
            let i = (hint.get() + k) % n;
            if !ok(&cases[i])? {
                hint.set(i);
                return Ok(false);
            }
        }
        Ok(true)
    }

    fn meets_minimum(&self, results: &[CaseResult]) -> bool {
        let st = &self.cfg.stability;
        results.iter().all(|r| {
            r.stable
                && r.margins.is_some_and(|m| {
                    m.gain_margin_db >= st.min_gain_margin_db
                        && m.phase_margin_deg >= st.min_phase_margin_deg
                })
        })
    }

    /// The full report at the configured trap stiffness and force scale.
    ///
    /// # Errors
    /// Numerical failure.
    pub fn report(&self) -> Result<StabilityReport, RigError> {
        let kappa = self.cfg.tweezer.stiffness_n_per_m;
        let g = self.cfg.coupling.force_scale;
        let st = &self.cfg.stability;
        let results = self.evaluate(kappa, g, true)?;
        let mut conditions = Vec::new();
        for cond in Condition::HAPTIC {
            let rs: Vec<&CaseResult> = results
                .iter()
                .filter(|r| r.case.condition == cond)
                .collect();
            let Some(first) = rs.first() else { continue };
            let mut worst_g = *first;
            let mut worst_p = *first;
            let mut vector = f64::INFINITY;
            let mut rho: f64 = 0.0;
            for r in &rs {
                let (Some(m), Some(wg), Some(wp)) = (r.margins, worst_g.margins, worst_p.margins)
                else {
                    continue;
                };
                if m.gain_margin_db < wg.gain_margin_db {
                    worst_g = r;
                }
                if m.phase_margin_deg < wp.phase_margin_deg {
                    worst_p = r;
                }
                vector = vector.min(m.vector_margin);
                rho = rho.max(r.spectral_radius);
            }
            let stable = rs.iter().all(|r| r.stable);
            let nominal = rs.iter().find(|r| {
                r.case.axis == Axis::X
                    && r.case.state == LoopState::Pressed
                    && r.case.hand.stiffness_n_per_m == self.cfg.plant.k_f
                    && r.case.hand.damping_n_s_per_m == self.cfg.plant.b_f
            });
            let (mg, mp) = (
                worst_g.margins.map_or(f64::NAN, |m| m.gain_margin_db),
                worst_p.margins.map_or(f64::NAN, |m| m.phase_margin_deg),
            );
            conditions.push(ConditionMargins {
                condition: cond,
                gain_margin_db: mg,
                phase_margin_deg: mp,
                vector_margin: vector,
                stable,
                meets_minimum: stable
                    && mg >= st.min_gain_margin_db
                    && mp >= st.min_phase_margin_deg,
                spectral_radius: rho,
                nominal_growth_db_per_s: nominal.map_or(f64::NAN, |r| r.growth_db_per_s),
                nominal_stable: nominal.is_some_and(|r| r.stable),
                phase_crossover_hz: worst_g.margins.map_or(f64::NAN, |m| m.phase_crossover_hz),
                gain_crossover_hz: worst_p.margins.map_or(f64::NAN, |m| m.gain_crossover_hz),
                worst_gain_case: worst_g.case,
                worst_phase_case: worst_p.case,
            });
        }
        let hint = Cell::new(0);
        let critical_kappa = self.critical(kappa, &|k| {
            self.all_cases(&hint, &|c| Ok(self.case(c, k, g, false)?.stable))
        })?;
        let critical_g = self.critical(g, &|x| {
            self.all_cases(&hint, &|c| Ok(self.case(c, kappa, x, false)?.stable))
        })?;
        let max_g = self.critical(g, &|x| {
            self.all_cases(&hint, &|c| {
                let r = self.case_with(c, kappa, x, true, false)?;
                Ok(self.meets_minimum(std::slice::from_ref(&r)))
            })
        })?;
        let gh = self.cfg.coupling.high_band_gain;
        // Only D's x axis carries the Haptuator: the other cases do not
        // depend on g_H.
        let max_gh = self.critical(if gh > 0.0 { gh } else { 1.0 }, &|x| {
            self.all_cases(&hint, &|c| {
                if c.condition != Condition::D || c.axis != Axis::X {
                    return Ok(true);
                }
                let r = self.case_gains(c, [kappa, g, x], true, false)?;
                Ok(self.meets_minimum(std::slice::from_ref(&r)))
            })
        })?;
        let t = &self.tweezer;
        let kc = t.contact_stiffness_n_per_m;
        let drive_max = self.cfg.limits.haptuator_drive_max_v;
        let high_gain = self
            .grid
            .iter()
            .map(|&f| gh * sections_response(self.chain.high(), f, self.fs).norm())
            .fold(0.0, f64::max);
        Ok(StabilityReport {
            safe: conditions.iter().all(|c| c.meets_minimum),
            conditions,
            critical_trap_stiffness_n_per_m: critical_kappa,
            max_force_scale: max_g,
            critical_force_scale: critical_g,
            force_scale: g,
            trap_stiffness_n_per_m: kappa,
            pressed_stiffness_n_per_m: g * self.cfg.coupling.position_scale.abs() * kappa * kc
                / (kappa + kc),
            min_gain_margin_db: st.min_gain_margin_db,
            min_phase_margin_deg: st.min_phase_margin_deg,
            high_band_force_full_scale_n: if high_gain > 0.0 {
                drive_max / high_gain
            } else {
                f64::INFINITY
            },
            high_band_gain: gh,
            max_high_band_gain: max_gh,
            p_mode: self.cfg.coupling.p_mode,
            latency_s: self.latency_s,
            latency_samples: self.delay,
        })
    }

    /// The boundary x* of the predicate `ok` on a log scale around `x0`:
    /// the largest x with `ok` on [x0, x*) when `ok(x0)`, else the largest x
    /// below x0 with `ok` (0 when none above 10⁻⁴·x0). +∞ when `ok` holds up
    /// to 10⁴·x0. Bisection to 0.1 %.
    fn critical(
        &self,
        x0: f64,
        ok: &dyn Fn(f64) -> Result<bool, RigError>,
    ) -> Result<f64, RigError> {
        const STEP: f64 = 1.25;
        const SPAN: f64 = 1e4;
        let (mut good, mut bad);
        if ok(x0)? {
            good = x0;
            bad = f64::INFINITY;
            let mut x = x0 * STEP;
            while x <= x0 * SPAN {
                if !ok(x)? {
                    bad = x;
                    break;
                }
                good = x;
                x *= STEP;
            }
            if bad.is_infinite() {
                return Ok(f64::INFINITY);
            }
        } else {
            bad = x0;
            good = 0.0;
            let mut x = x0 / STEP;
            while x >= x0 / SPAN {
                if ok(x)? {
                    good = x;
                    break;
                }
                bad = x;
                x /= STEP;
            }
            if good == 0.0 {
                return Ok(0.0);
            }
        }
        while bad / good > 1.001 {
            let mid = (good * bad).sqrt();
            if ok(mid)? {
                good = mid;
            } else {
                bad = mid;
            }
        }
        Ok(good)
    }
}

/// `sections` with the numerator of the first section times `k`: the
/// cascade's response times `k` (none: `sections` is empty).
fn scaled_sections(sections: &[BiquadCoeffs], k: f64) -> Vec<BiquadCoeffs> {
    let mut v = sections.to_vec();
    if let Some(s) = v.first_mut() {
        s.b0 *= k;
        s.b1 *= k;
        s.b2 *= k;
    }
    v
}

/// Largest extra loop delay [`LoopAnalysis::with_latency`] takes, s. A
/// haptic loop with a tenth of a second of delay is no longer one (the
/// default rig turns unstable near 14 ms), and the eigenvalue verdict's
/// state dimension grows with the delay.
pub const MAX_LATENCY_S: f64 = 0.1;

/// Largest extra loop delay, samples (the same bound at any sample rate:
/// the delay adds this many states to the closed loop, whose eigenvalues
/// cost O(n³)).
pub const MAX_DELAY_SAMPLES: usize = 1000;

/// The whole samples d of an extra loop delay of `latency_s` seconds at
/// `fs` Hz: d = ⌈latency·f_s⌉, rounded up (a delay between two whole
/// samples is charged the longer one: conservative). A product within
/// 10⁻⁶ sample of a whole number counts as that number (3 ms at 10 kHz is
/// 30 samples, not 31 by floating-point rounding).
///
/// # Errors
/// [`RigError::InvalidParameter`] when `latency_s` is not finite, negative,
/// above [`MAX_LATENCY_S`], or gives more than [`MAX_DELAY_SAMPLES`].
pub fn delay_samples(latency_s: f64, fs: f64) -> Result<usize, RigError> {
    let bad = |reason: String| RigError::InvalidParameter {
        name: "latency",
        value: latency_s,
        reason,
    };
    if !(latency_s.is_finite() && latency_s >= 0.0) {
        return Err(bad(
            "the extra loop delay must be a finite number of seconds ≥ 0".into(),
        ));
    }
    if latency_s > MAX_LATENCY_S {
        return Err(bad(format!(
            "the extra loop delay must be at most {} ms",
            1e3 * MAX_LATENCY_S
        )));
    }
    RigError::require_positive("sample rate", fs)?;
    let d = (latency_s * fs - 1e-6).ceil().max(0.0);
    if d > MAX_DELAY_SAMPLES as f64 {
        return Err(bad(format!(
            "{d} samples at {fs} Hz: the analysis takes at most {MAX_DELAY_SAMPLES} samples of extra delay"
        )));
    }
    Ok(d as usize)
}

/// Reports kept by [`analyse_with_latency`] (most recent last).
const MEMO_CAPACITY: usize = 16;

type Memo = std::sync::Mutex<Vec<(String, StabilityReport)>>;

fn memo() -> &'static Memo {
    static MEMO: std::sync::OnceLock<Memo> = std::sync::OnceLock::new();
    MEMO.get_or_init(|| std::sync::Mutex::new(Vec::new()))
}

/// The stability report of a rig file with the chain its D loop runs (the
/// simulated loop: no extra delay). [`analyse_with_latency`] at 0 s.
///
/// # Errors
/// As [`LoopAnalysis::new`] and [`LoopAnalysis::report`].
pub fn analyse(cfg: &RigConfig, chain: &ChainCoefficients) -> Result<StabilityReport, RigError> {
    analyse_with_latency(cfg, chain, 0.0)
}

/// The stability report of a rig file with the chain its D loop runs and
/// an extra loop delay of `latency_s` seconds ([`LoopAnalysis::with_latency`]).
/// The analysis takes from a few hundred milliseconds (no delay) to
/// seconds (long delays); the last [`MEMO_CAPACITY`] reports are kept per
/// process (keyed by everything the analysis reads: the rig file without
/// its noise seeds, the chain and the latency).
///
/// # Errors
/// As [`LoopAnalysis::new`], [`LoopAnalysis::with_latency`] and
/// [`LoopAnalysis::report`].
pub fn analyse_with_latency(
    cfg: &RigConfig,
    chain: &ChainCoefficients,
    latency_s: f64,
) -> Result<StabilityReport, RigError> {
    let mut c = cfg.clone();
    c.accelerometer.seed = 0;
    c.tweezer.seed = 0;
    let key = format!("{c:?}{chain:?}{latency_s:?}");
    if let Ok(m) = memo().lock()
        && let Some((_, r)) = m.iter().find(|(k, _)| *k == key)
    {
        return Ok(r.clone());
    }
    let r = LoopAnalysis::new(cfg, chain)?
        .with_latency(latency_s)?
        .report()?;
    if let Ok(mut m) = memo().lock() {
        if m.len() >= MEMO_CAPACITY {
            m.remove(0);
        }
        m.push((key, r.clone()));
    }
    Ok(r)
}
