//! Rig files: TOML description of a (simulated) dual-stage rig.
//!
//! The plant section uses the parameter names of the paper's Table 2
//! (`m_h`, `m_v`, `m_1`, `m_2`, `k_v`, `b_v`, `k_1`, `b_1`, `k_2`, `b_2`,
//! `k_f`, `b_f`), all in SI units (kg, N/m, N·s/m). Other keys carry their
//! unit in the name (`_hz`, `_m`, `_n_per_m`, …).
//!
//! Parsing uses serde with `deny_unknown_fields`, so a misspelt key is an
//! error naming the file, line and column; semantic validation (non-positive
//! masses, corner frequencies above Nyquist, …) reports the same position by
//! locating the key in the text.
//!
//! The embedded default, `assets/rigs/default.toml`, is returned verbatim by
//! [`default_config_text`] (`kilotouch rig default-config`).

use crate::condition::{Condition, PMode};
use crate::error::RigError;
use crate::toml_location::{field_at, line_col, locate};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Text of the embedded default rig file (`assets/rigs/default.toml`).
pub fn default_config_text() -> &'static str {
    include_str!("../../../assets/rigs/default.toml")
}

/// A complete rig description.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigConfig {
    /// Identity and timing.
    pub rig: RigSection,
    /// Lumped mechanical parameters (paper §2.2, eq. 1, Table 2).
    pub plant: PlantConfig,
    /// Haptuator drive electronics and end stops.
    pub haptuator: HaptuatorConfig,
    /// Fingertip accelerometer (MMA7361L model).
    pub accelerometer: AccelerometerConfig,
    /// Optical tweezer (paper §4.1).
    pub tweezer: TweezerConfig,
    /// Bilateral coupling between handle and trap.
    pub coupling: CouplingConfig,
    /// Actuator limits.
    pub limits: LimitsConfig,
    /// Safety layer (`crate::safety`); absent = the defaults.
    #[serde(default)]
    pub safety: SafetyConfig,
    /// Closed-loop stability requirements (`crate::stability`); absent =
    /// the defaults.
    #[serde(default)]
    pub stability: StabilityConfig,
    /// The microscope camera the participant watches; absent = the
    /// defaults (not written when default, so rig files and their hashes
    /// from before the section existed stay the same).
    #[serde(default, skip_serializing_if = "CameraConfig::is_default")]
    pub camera: CameraConfig,
}

/// `[camera]`: the microscope camera whose frames the participant's screen
/// shows (paper §4.1: the bead, the trap and the obstacles as the
/// participant sees them). What vision-only trials depend on.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Frames per second (default 25, a video-rate camera).
    pub frame_rate_hz: f64,
    /// From the end of a frame's exposure to its display, s (default 40 ms:
    /// one frame of transfer and display).
    pub latency_s: f64,
    /// Exposure time, s: a frame shows the mean positions over this window
    /// ending at its capture (motion blur). 0 (default) = instantaneous;
    /// at most one frame period.
    pub exposure_s: f64,
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            frame_rate_hz: 25.0,
            latency_s: 0.04,
            exposure_s: 0.0,
        }
    }
}

/// Largest camera latency accepted, s.
pub const MAX_CAMERA_LATENCY_S: f64 = 10.0;

impl CameraConfig {
    /// Whether every key has its default value.
    pub fn is_default(&self) -> bool {
        *self == Self::default()
    }

    /// Problems with the values at loop rate `fs` Hz (key, message).
    pub fn issues(&self, fs: f64) -> Vec<(&'static str, String)> {
        let mut v = Vec::new();
        let r = self.frame_rate_hz;
        if !(r.is_finite() && r > 0.0 && (!fs.is_finite() || r <= fs)) {
            v.push((
                "frame_rate_hz",
                format!("must be > 0 and at most the loop rate {fs} Hz (got {r})"),
            ));
        }
        let l = self.latency_s;
        if !(l.is_finite() && (0.0..=MAX_CAMERA_LATENCY_S).contains(&l)) {
            v.push((
                "latency_s",
                format!("must be in [0, {MAX_CAMERA_LATENCY_S}] s (got {l})"),
            ));
        }
        let e = self.exposure_s;
        if !(e.is_finite() && e >= 0.0 && (r <= 0.0 || e <= 1.0 / r + 1e-12)) {
            v.push((
                "exposure_s",
                format!("must be in [0, 1/frame_rate_hz] s (got {e})"),
            ));
        }
        v
    }
}

/// `[rig]`: identity and timing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigSection {
    /// Human-readable name reported by the rig's identity.
    pub name: String,
    /// Loop sample rate in Hz (paper: 10 kHz).
    pub sample_rate_hz: f64,
    /// Resolution of the handle-position encoders in m (the Pantograph
    /// resolves about 10 µm, paper §2.1). 0 disables quantisation.
    pub encoder_resolution_m: f64,
}

/// `[plant]`: the lumped model of eq. 1 plus two optional side branches.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantConfig {
    /// Mass of the terminal interface assembly, kg.
    pub m_h: f64,
    /// Mass of the Haptuator's moving magnet, kg.
    pub m_v: f64,
    /// Combined (reflected) mass of the motor windings, kg.
    pub m_1: f64,
    /// Apparent mass of the links, kg.
    pub m_2: f64,
    /// Haptuator suspension stiffness, N/m.
    pub k_v: f64,
    /// Haptuator suspension damping, N·s/m.
    pub b_v: f64,
    /// Combined stiffness of the proximal links / shafts, N/m.
    pub k_1: f64,
    /// Combined damping of the proximal links, N·s/m.
    pub b_1: f64,
    /// Combined stiffness of the distal links, N/m.
    pub k_2: f64,
    /// Combined damping of the distal links, N·s/m.
    pub b_2: f64,
    /// Finger stiffness (tip to hand), N/m.
    pub k_f: f64,
    /// Finger damping (tip to hand), N·s/m.
    pub b_f: f64,
    /// Optional side branch hanging off the motor node x_1 (motor shaft /
    /// rotor torsion): produces the sharp antiresonance/resonance pair near
    /// 800 Hz. Absent = the paper's 4-DOF model along this path.
    #[serde(default)]
    pub motor_branch: Option<BranchConfig>,
    /// Optional side branch hanging off the link node x_2 (link bending
    /// mode): produces the damped antiresonance just above 200 Hz.
    #[serde(default)]
    pub link_branch: Option<BranchConfig>,
}

/// A mass hanging off a node through a spring–damper.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BranchConfig {
    /// Modal mass, kg.
    pub mass: f64,
    /// Stiffness to the node, N/m.
    pub stiffness: f64,
    /// Damping to the node, N·s/m.
    pub damping: f64,
}

/// `[haptuator]`: drive electronics and end stops of the moving magnet.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HaptuatorConfig {
    /// Laplace force per drive volt at DC, N/V.
    pub drive_gain_n_per_v: f64,
    /// Corner of the first-order drive low-pass (amplifier + coil), Hz.
    pub drive_corner_hz: f64,
    /// Free stroke of the magnet relative to the case, ±m.
    pub stroke_m: f64,
    /// Stiffness of the one-sided end stops beyond ±stroke, N/m.
    pub stop_stiffness_n_per_m: f64,
    /// Damping of the end stops while in contact, N·s/m.
    pub stop_damping_n_s_per_m: f64,
}

/// `[accelerometer]`: three-axis MEMS accelerometer after the MMA7361L.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccelerometerConfig {
    /// Full-scale range, ±g (MMA7361L: 1.5 or 6 g).
    pub range_g: f64,
    /// One-pole bandwidth per axis (x, y, z), Hz (datasheet: 400, 400, 300).
    pub corner_hz: [f64; 3],
    /// White noise density, µg/√Hz (datasheet: 350).
    pub noise_density_ug_per_rthz: f64,
    /// Quantisation step of the acquisition, m/s² (0 = none). 16 bit over
    /// ±10 V at 206 mV/g gives 1.45e-2 m/s².
    pub lsb_m_s2: f64,
    /// Static acceleration added to the readings (gravity), m/s².
    pub static_m_s2: [f64; 3],
    /// Seed of the noise generator.
    pub seed: u64,
}

/// `[tweezer]`: simulated optical trap (paper §4.1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TweezerConfig {
    /// Bead radius, m (paper: 3 µm bead → 1.5e-6).
    pub radius_m: f64,
    /// Dynamic viscosity of the medium, Pa·s (water, 20 °C: 1.0016e-3).
    pub viscosity_pa_s: f64,
    /// Absolute temperature, K.
    pub temperature_k: f64,
    /// Trap stiffness, N/m (20 pN/µm = 2e-5 N/m).
    pub stiffness_n_per_m: f64,
    /// Bead-centre to coverslip distance, m; absent = no wall correction.
    #[serde(default)]
    pub wall_distance_m: Option<f64>,
    /// Linear range of the trap, m: beyond it the bead escapes (with
    /// `profile = "gaussian"`, the bead escapes beyond the larger of this and
    /// 2 `waist_m`).
    pub escape_distance_m: f64,
    /// Radial force profile: `"linear"` (default, a spring up to the escape
    /// distance) or `"gaussian"` (the gradient force of a Gaussian beam of
    /// waist `waist_m`; docs/theory/tweezer.md).
    #[serde(default, skip_serializing_if = "TrapProfileKind::is_linear")]
    pub profile: TrapProfileKind,
    /// Beam waist w0 of the Gaussian profile (1/e² intensity radius), m;
    /// required with `profile = "gaussian"`, refused otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub waist_m: Option<f64>,
    /// Range of the short-range contact repulsion, m.
    pub contact_range_m: f64,
    /// Stiffness of the contact repulsion, N/m.
    pub contact_stiffness_n_per_m: f64,
    /// Seed of the thermal noise generator.
    pub seed: u64,
    /// Fixed spherical obstacles (paper: 10 µm glass beads on the coverslip).
    #[serde(default)]
    pub obstacles: Vec<ObstacleConfig>,
    /// Position detector between the bead and the reported signal.
    #[serde(default)]
    pub detector: DetectorConfig,
}

/// `[tweezer] profile`: the radial force profile of the trap.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TrapProfileKind {
    /// Linear spring with an escape cliff (default).
    #[default]
    Linear,
    /// Gaussian-beam gradient force (needs `waist_m`).
    Gaussian,
}

impl TrapProfileKind {
    /// The default linear profile.
    pub fn is_linear(&self) -> bool {
        matches!(self, Self::Linear)
    }
}

/// `[tweezer.detector]`: the simulated position detector
/// (`crate::tweezer::detector`; every key has a default).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorConfig {
    /// Sensitivity S, V/m (default 5e5 V/m = 0.5 V/µm, i.e. R_d = 2 µm/V).
    pub sensitivity_v_per_m: f64,
    /// Photodiode roll-off f_diode, Hz (absent: a fast detector, no filter).
    pub diode_hz: Option<f64>,
    /// Fraction α of the signal the photodiode passes at once (0 … 1; used
    /// with `diode_hz`).
    pub diode_alpha: f64,
    /// White noise of amplifier and converter, V rms per sample.
    pub noise_v_rms: f64,
    /// Seed of the detector's own noise stream.
    pub seed: u64,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        Self {
            sensitivity_v_per_m: 5.0e5,
            diode_hz: None,
            diode_alpha: 0.3,
            noise_v_rms: 1.0e-5,
            seed: 7,
        }
    }
}

impl DetectorConfig {
    /// Check every field.
    pub fn validate(&self) -> Result<(), RigError> {
        let bad = |name: &'static str, value: f64, reason: &str| RigError::InvalidParameter {
            name,
            value,
            reason: reason.into(),
        };
        if !(self.sensitivity_v_per_m.is_finite() && self.sensitivity_v_per_m != 0.0) {
            return Err(bad(
                "detector.sensitivity_v_per_m",
                self.sensitivity_v_per_m,
                "must be finite and non-zero",
            ));
        }
        if let Some(f) = self.diode_hz
            && !(f.is_finite() && f > 0.0)
        {
            return Err(bad("detector.diode_hz", f, "must be finite and > 0"));
        }
        if !(0.0..=1.0).contains(&self.diode_alpha) {
            return Err(bad(
                "detector.diode_alpha",
                self.diode_alpha,
                "must be in [0, 1]",
            ));
        }
        if !(self.noise_v_rms.is_finite() && self.noise_v_rms >= 0.0) {
            return Err(bad(
                "detector.noise_v_rms",
                self.noise_v_rms,
                "must be finite and ≥ 0",
            ));
        }
        Ok(())
    }
}

/// A fixed spherical obstacle in the focal plane.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleConfig {
    /// Centre x, m.
    pub x_m: f64,
    /// Centre y, m.
    pub y_m: f64,
    /// Radius, m.
    pub radius_m: f64,
}

/// `[coupling]`: the bilateral coupling between handle and trap
/// (`crate::coupling`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CouplingConfig {
    /// Condition the Explore engine starts in (`"V"`, `"P"`, `"D"`; also
    /// `"vision"`, `"pantograph"`, `"dual"`).
    pub mode: Condition,
    /// What the Pantograph receives in condition P (default `"full-band"`;
    /// `"low-channel"`, or `{ lowpass = { hz = … } }`).
    #[serde(default)]
    pub p_mode: PMode,
    /// Trap displacement per handle displacement (m/m); negative mirrors.
    pub position_scale: f64,
    /// Handle position mapped to the trap offset, m (x, y).
    pub handle_origin_m: [f64; 2],
    /// Trap position when the handle is at its origin, m (x, y).
    pub trap_offset_m: [f64; 2],
    /// Trap workspace: lower corner, m (x, y).
    pub trap_min_m: [f64; 2],
    /// Trap workspace: upper corner, m (x, y).
    pub trap_max_m: [f64; 2],
    /// Handle force per optical force (N/N).
    pub force_scale: f64,
    /// Rendering gain of the high band in D, g_H (dimensionless): the
    /// Haptuator drive is g_H·C_H·F, so the band above the crossover is
    /// rendered g_H times the force image while the low band stays at
    /// `force_scale` (the paper's "magnified representation" of the bead's
    /// agitation, §4.2). The stability analysis includes it on the high
    /// path of every D case (`docs/theory/coupling-and-stability.md`,
    /// rendering gain of the high band). 1 = the force image as it is.
    ///
    /// 1 when the key is absent, and not written when 1, so rig files and
    /// their hashes from before the key existed stay the same; the
    /// shipped rig file sets 30 (`assets/rigs/default.toml`).
    #[serde(
        default = "default_high_band_gain",
        skip_serializing_if = "is_unit_gain"
    )]
    pub high_band_gain: f64,
    /// Damping rendered along the contact normal while the bead touches an
    /// obstacle, N·s/m at the handle: the virtual wall's damper (Colgate &
    /// Brown 1994). It gives the pressed loop its phase margin
    /// (`docs/theory/coupling-and-stability.md`, closed-loop stability). 0 = none.
    #[serde(default = "default_contact_damping")]
    pub contact_damping_n_s_per_m: f64,
    /// Corner of the 2nd-order Butterworth low-pass on the handle-velocity
    /// estimate (backward difference of the encoder position), Hz.
    #[serde(default = "default_velocity_filter")]
    pub velocity_filter_hz: f64,
    /// Run the passivity observer/controller (Hannaford & Ryu 2002) on the
    /// Pantograph forces: a run-time net that adds damping whenever the
    /// rendering has produced net energy.
    #[serde(default)]
    pub passivity_controller: bool,
    /// Removed: P's band limit is now `p_mode = { lowpass = { hz = … } }`.
    /// Present only to give a clear error for old rig files.
    #[serde(default, skip_serializing)]
    pub pantograph_band_hz: Option<f64>,
}

fn default_contact_damping() -> f64 {
    15.0
}

fn default_velocity_filter() -> f64 {
    100.0
}

fn default_high_band_gain() -> f64 {
    1.0
}

#[allow(clippy::trivially_copy_pass_by_ref)] // serde's skip_serializing_if signature
fn is_unit_gain(g: &f64) -> bool {
    *g == 1.0
}

/// Smallest Gaussian beam waist w0 accepted, m: the 1/e² radius of the
/// tightest diffraction-limited focus (≈ 0.42 λ/NA at λ = 0.35 µm,
/// NA = 1.5).
pub const WAIST_MIN_M: f64 = 1.0e-7;
/// Largest Gaussian beam waist w0 accepted, m (an effective profile of a
/// bead a few micrometres across; beyond it the "trap" is not a focus).
pub const WAIST_MAX_M: f64 = 2.0e-5;

/// Largest accepted `coupling.high_band_gain`.
pub const MAX_HIGH_BAND_GAIN: f64 = 1e5;

/// `[stability]`: what the closed-loop analysis assumes and requires
/// (`crate::stability`). Every key has a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StabilityConfig {
    /// Smallest gain margin a loop may be armed with, dB.
    pub min_gain_margin_db: f64,
    /// Smallest phase margin a loop may be armed with, degrees.
    pub min_phase_margin_deg: f64,
    /// Range of the finger stiffness (tip to hand) the loop must be stable
    /// for, N/m [low, high]; the plant's `k_f` is the nominal value.
    pub hand_stiffness_n_per_m: [f64; 2],
    /// Range of the finger damping, N·s/m [low, high]; `b_f` is nominal.
    pub hand_damping_n_s_per_m: [f64; 2],
}

impl Default for StabilityConfig {
    fn default() -> Self {
        Self {
            min_gain_margin_db: 6.0,
            min_phase_margin_deg: 30.0,
            hand_stiffness_n_per_m: [200.0, 800.0],
            hand_damping_n_s_per_m: [2.0, 4.5],
        }
    }
}

/// `[limits]`: actuator limits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitsConfig {
    /// Largest Pantograph force command per axis, N (Table 1: 5 N).
    pub pantograph_force_max_n: f64,
    /// Largest Haptuator drive, V.
    pub haptuator_drive_max_v: f64,
}

/// Largest velocity span L of the safety layer, samples.
pub const MAX_VELOCITY_SPAN: u32 = 250;
/// Largest watchdog window W of the safety layer, samples.
pub const MAX_WATCHDOG_WINDOW: usize = 1 << 20;

/// `[safety]`: the safety layer every closed-loop run passes through
/// (`crate::safety`, `docs/theory/safety-and-audio.md`). Per-axis force and drive limits
/// are `[limits]`; this section adds the rest. Every key has a default, so a
/// rig file may omit the section or any key of it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SafetyConfig {
    /// Largest norm of the Pantograph force vector (x, y), N.
    pub force_norm_max_n: f64,
    /// Largest rate of change of the force vector, N/s (norm of ΔF·f_s).
    pub force_slew_max_n_per_s: f64,
    /// Duration of the raised-cosine ramp when forces come on, s (0 = none).
    pub ramp_time_s: f64,
    /// Forces come on only once the commanded force norm is below this, N.
    pub enable_force_max_n: f64,
    /// Handle speed above which the layer trips, m/s.
    pub handle_velocity_max_m_s: f64,
    /// Span L of the handle-velocity differences, samples (3 ≤ L ≤ 250).
    pub velocity_span_samples: u32,
    /// Length of the watchdog's sliding window, s.
    pub watchdog_window_s: f64,
    /// The watchdog trips when more than this fraction of the window's
    /// samples missed their deadline (M = round(fraction·W) samples; the
    /// fraction keeps the setting independent of the sample rate).
    pub watchdog_max_missed_fraction: f64,
    /// Arm when a closed loop starts (forces still wait for a small command
    /// and ramp on).
    pub arm_on_start: bool,
    /// A sitting's timing verdict is "late" when more than this fraction
    /// of its samples ran late (in blocks that missed their deadline, or
    /// on a command the device received late): its data then deserve a
    /// second look before analysis (docs/STUDY.md, timing verdict).
    pub sitting_max_late_fraction: f64,
}

impl Default for SafetyConfig {
    fn default() -> Self {
        Self {
            force_norm_max_n: 5.0,
            force_slew_max_n_per_s: 2000.0,
            ramp_time_s: 0.2,
            enable_force_max_n: 0.05,
            handle_velocity_max_m_s: 2.0,
            velocity_span_samples: 10,
            watchdog_window_s: 0.1,
            watchdog_max_missed_fraction: 0.1,
            arm_on_start: true,
            sitting_max_late_fraction: 1e-3,
        }
    }
}

impl StabilityConfig {
    /// Problems as (key, message).
    pub fn issues(&self) -> Vec<(&'static str, String)> {
        let mut v = Vec::new();
        let g = self.min_gain_margin_db;
        if !(g.is_finite() && (0.0..=60.0).contains(&g)) {
            v.push((
                "min_gain_margin_db",
                format!("must be in [0, 60] dB (got {g})"),
            ));
        }
        let p = self.min_phase_margin_deg;
        if !(p.is_finite() && (0.0..90.0).contains(&p)) {
            v.push((
                "min_phase_margin_deg",
                format!("must be in [0, 90) degrees (got {p})"),
            ));
        }
        for (key, [lo, hi], upper) in [
            ("hand_stiffness_n_per_m", self.hand_stiffness_n_per_m, 1e6),
            ("hand_damping_n_s_per_m", self.hand_damping_n_s_per_m, 1e4),
        ] {
            if !(lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= hi && hi <= upper) {
                v.push((
                    key,
                    format!("must be [low, high] with 0 < low ≤ high ≤ {upper} (got [{lo}, {hi}])"),
                ));
            }
        }
        v
    }
}

impl SafetyConfig {
    /// Ramp length at `fs` Hz: round(`ramp_time_s`·fs) samples.
    pub fn ramp_samples(&self, fs: f64) -> u64 {
        crate::round_half_away(self.ramp_time_s * fs).max(0.0) as u64
    }

    /// Watchdog window at `fs` Hz: round(`watchdog_window_s`·fs) samples,
    /// at least 1.
    pub fn watchdog_window_samples(&self, fs: f64) -> usize {
        (crate::round_half_away(self.watchdog_window_s * fs).max(1.0) as usize)
            .min(MAX_WATCHDOG_WINDOW + 1)
    }

    /// Watchdog limit at `fs` Hz: M = round(fraction·W) missed samples
    /// (more than M trip).
    pub fn watchdog_max_missed(&self, fs: f64) -> u32 {
        let m = crate::round_half_away(
            self.watchdog_max_missed_fraction * self.watchdog_window_samples(fs) as f64,
        );
        if m.is_finite() && m > 0.0 {
            m.min(u32::MAX as f64) as u32
        } else {
            0
        }
    }

    /// Problems for a rig at `fs` Hz as (key, value, message).
    pub fn issue(&self, fs: f64) -> Vec<(&'static str, f64, String)> {
        let mut v = Vec::new();
        for (k, x) in [
            ("force_norm_max_n", self.force_norm_max_n),
            ("force_slew_max_n_per_s", self.force_slew_max_n_per_s),
            ("enable_force_max_n", self.enable_force_max_n),
            ("handle_velocity_max_m_s", self.handle_velocity_max_m_s),
            ("watchdog_window_s", self.watchdog_window_s),
        ] {
            if !(x.is_finite() && x > 0.0) {
                v.push((k, x, format!("must be finite and > 0 (got {x})")));
            }
        }
        for (k, x, max, unit) in [
            (
                "force_norm_max_n",
                self.force_norm_max_n,
                MAX_ACTUATOR_LIMIT,
                "N",
            ),
            (
                "enable_force_max_n",
                self.enable_force_max_n,
                MAX_ACTUATOR_LIMIT,
                "N",
            ),
            (
                "force_slew_max_n_per_s",
                self.force_slew_max_n_per_s,
                1e9,
                "N/s",
            ),
            (
                "handle_velocity_max_m_s",
                self.handle_velocity_max_m_s,
                1e3,
                "m/s",
            ),
            ("watchdog_window_s", self.watchdog_window_s, 3600.0, "s"),
        ] {
            if x.is_finite() && x > max {
                v.push((k, x, format!("must be at most {max:e} {unit} (got {x:e})")));
            }
        }
        let r = self.ramp_time_s;
        if !(r.is_finite() && (0.0..=3600.0).contains(&r)) {
            v.push((
                "ramp_time_s",
                r,
                format!("must be in [0, 3600] s (got {r})"),
            ));
        }
        let l = self.velocity_span_samples;
        if !(3..=MAX_VELOCITY_SPAN).contains(&l) {
            v.push((
                "velocity_span_samples",
                l as f64,
                format!("must be in [3, {}] (got {l})", MAX_VELOCITY_SPAN),
            ));
        }
        if self.watchdog_window_s.is_finite() && self.watchdog_window_s > 0.0 && fs.is_finite() {
            let w = self.watchdog_window_samples(fs);
            if w > MAX_WATCHDOG_WINDOW {
                v.push((
                    "watchdog_window_s",
                    self.watchdog_window_s,
                    format!(
                        "is {w} samples at {fs} Hz; at most {} allowed",
                        MAX_WATCHDOG_WINDOW
                    ),
                ));
            }
        }
        let q = self.watchdog_max_missed_fraction;
        if !(q.is_finite() && (0.0..1.0).contains(&q)) {
            v.push((
                "watchdog_max_missed_fraction",
                q,
                format!("must be in [0, 1) (got {q}); 1 would never trip"),
            ));
        }
        let l = self.sitting_max_late_fraction;
        if !(l.is_finite() && (0.0..=1.0).contains(&l)) {
            v.push((
                "sitting_max_late_fraction",
                l,
                format!("must be in [0, 1] (got {l})"),
            ));
        }
        v
    }
}

impl Default for RigConfig {
    fn default() -> Self {
        // The embedded file is validated by a unit test; parse failure here
        // would be a build defect, not a user error.
        match Self::from_toml_str(default_config_text(), "<default>") {
            Ok(c) => c,
            Err(e) => panic!("embedded default rig file is invalid: {e}"),
        }
    }
}

impl RigConfig {
    /// Parse and validate rig-file text. `origin` names the source in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, RigError> {
        let cfg: RigConfig = toml::from_str(text).map_err(|e| toml_error(text, origin, &e))?;
        cfg.validate_located(text, origin)?;
        Ok(cfg)
    }

    /// Read, parse and validate a rig file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, RigError> {
        let path = path.as_ref();
        let text = crate::input::read_text_capped(path, crate::input::MAX_CONFIG_BYTES).map_err(
            |source| RigError::Io {
                path: path.display().to_string(),
                source,
            },
        )?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// The rig file at `path`, or the built-in rig (the paper's, [`Default`])
    /// when no path is given.
    pub fn load_or_default(path: Option<impl AsRef<Path>>) -> Result<Self, RigError> {
        match path {
            Some(p) => Self::load(p),
            None => Ok(Self::default()),
        }
    }

    /// Serialise back to TOML.
    pub fn to_toml_string(&self) -> Result<String, RigError> {
        toml::to_string_pretty(self).map_err(|e| RigError::InvalidInput(e.to_string()))
    }

    /// Validate without position information (for configurations built in code).
    pub fn validate(&self) -> Result<(), RigError> {
        self.validate_located("", "<in-memory>")
    }

    fn validate_located(&self, text: &str, origin: &str) -> Result<(), RigError> {
        let issues = self.issues();
        match issues.into_iter().next() {
            None => Ok(()),
            Some((section, key, message)) => {
                let field = if section.is_empty() {
                    key.to_string()
                } else {
                    format!("{section}.{key}")
                };
                let (line, column) =
                    locate(text, &field).map_or((None, None), |o| line_col(text, o));
                Err(RigError::Config {
                    origin: origin.to_string(),
                    line,
                    column,
                    field,
                    message,
                })
            }
        }
    }

    /// All semantic problems as (section, key, message): each section
    /// checks itself (the sections that depend on the sample rate get it).
    fn issues(&self) -> Vec<(String, &'static str, String)> {
        let fs = self.rig.sample_rate_hz;
        let mut v = Vec::new();
        let rate_ok = fs.is_finite() && fs > 0.0;
        let mut add = |section: &str, issues: Vec<(&'static str, String)>| {
            v.extend(issues.into_iter().map(|(k, m)| (section.to_owned(), k, m)));
        };
        add("rig", self.rig.issues());
        add("plant", self.plant.issues());
        for (section, br) in [
            ("plant.motor_branch", &self.plant.motor_branch),
            ("plant.link_branch", &self.plant.link_branch),
        ] {
            if let Some(b) = br {
                add(section, b.issues());
            }
        }
        add("haptuator", self.haptuator.issues(fs));
        add("camera", self.camera.issues(fs));
        add("accelerometer", self.accelerometer.issues(fs));
        add("tweezer", self.tweezer.issues());
        for (i, o) in self.tweezer.obstacles.iter().enumerate() {
            add(&format!("tweezer.obstacles[{i}]"), o.issues());
        }
        add("coupling", self.coupling.issues(fs));
        add("limits", self.limits.issues());
        if rate_ok {
            add(
                "safety",
                self.safety
                    .issue(fs)
                    .into_iter()
                    .map(|(k, _, m)| (k, m))
                    .collect(),
            );
        }
        add("stability", self.stability.issues());
        v
    }
}

/// A problem unless `x` is finite and > 0: "{what} must be finite and > 0".
fn positive(v: &mut Vec<(&'static str, String)>, key: &'static str, x: f64, what: &str) {
    if !(x.is_finite() && x > 0.0) {
        v.push((key, format!("{what} must be finite and > 0 (got {x})")));
    }
}

/// A problem when `x` exceeds `max` (a physical bound far beyond any real
/// rig, stated so that absurd values — `k_1 = 1e308` — are refused here,
/// naming the field, instead of overflowing a computation later).
fn at_most(v: &mut Vec<(&'static str, String)>, key: &'static str, x: f64, max: f64, unit: &str) {
    if x.is_finite() && x > max {
        v.push((key, format!("must be at most {max:e} {unit} (got {x:e})")));
    }
}

/// Highest sample rate of a rig, Hz.
pub const MAX_SAMPLE_RATE_HZ: f64 = 1e6;
/// Lowest sample rate of a rig, Hz (the loop and its filters are designed
/// for audio-band rates; the paper's rig runs at 10 kHz).
pub const MIN_SAMPLE_RATE_HZ: f64 = 100.0;
/// Smallest mass of the plant model, kg (1 µg: below it the plant's
/// state matrices overflow).
pub const MIN_MASS_KG: f64 = 1e-9;
/// Smallest stiffness of the plant model, N/m.
pub const MIN_STIFFNESS_N_PER_M: f64 = 1e-3;
/// Largest mass of the plant model, kg.
pub const MAX_MASS_KG: f64 = 1e3;
/// Largest stiffness of the plant model, N/m.
pub const MAX_STIFFNESS_N_PER_M: f64 = 1e10;
/// Largest damping of the plant model, N·s/m.
pub const MAX_DAMPING_N_S_PER_M: f64 = 1e6;
/// Most obstacles in a tweezer scene.
pub const MAX_OBSTACLES: usize = 1_000;
/// Largest actuator limit of a rig file (Pantograph force per axis and
/// norm, N; Haptuator drive, V): squares of limited values cannot
/// overflow, and every command builds its safety limits from the same
/// bound ([`crate::safety::HardLimits::new`]).
pub const MAX_ACTUATOR_LIMIT: f64 = 1e6;

/// A problem when `x` is below `min` (a physical bound, stated so that a
/// tiny value is refused here instead of overflowing a model later).
fn at_least(v: &mut Vec<(&'static str, String)>, key: &'static str, x: f64, min: f64, unit: &str) {
    if x.is_finite() && x > 0.0 && x < min {
        v.push((key, format!("must be at least {min:e} {unit} (got {x:e})")));
    }
}

/// A problem unless `x` is finite and ≥ 0.
fn non_negative(v: &mut Vec<(&'static str, String)>, key: &'static str, x: f64) {
    if !(x.is_finite() && x >= 0.0) {
        v.push((key, format!("must be finite and ≥ 0 (got {x})")));
    }
}

/// A problem unless `x` is a corner frequency in (0, fs/2) (skipped when
/// `fs` itself is unusable: that is the `[rig]` section's problem).
fn below_nyquist(v: &mut Vec<(&'static str, String)>, key: &'static str, x: f64, fs: f64) {
    let nyq = 0.5 * fs;
    if fs.is_finite() && fs > 0.0 && x.is_finite() && x >= nyq {
        v.push((key, format!("must be below Nyquist ({nyq} Hz), got {x}")));
    }
}

impl RigSection {
    /// Problems as (key, message).
    pub fn issues(&self) -> Vec<(&'static str, String)> {
        let mut v = Vec::new();
        positive(&mut v, "sample_rate_hz", self.sample_rate_hz, "sample rate");
        at_most(
            &mut v,
            "sample_rate_hz",
            self.sample_rate_hz,
            MAX_SAMPLE_RATE_HZ,
            "Hz",
        );
        at_least(
            &mut v,
            "sample_rate_hz",
            self.sample_rate_hz,
            MIN_SAMPLE_RATE_HZ,
            "Hz",
        );
        non_negative(&mut v, "encoder_resolution_m", self.encoder_resolution_m);
        at_most(
            &mut v,
            "encoder_resolution_m",
            self.encoder_resolution_m,
            1e-2,
            "m",
        );
        v
    }
}

impl PlantConfig {
    /// Problems of the masses, stiffnesses and dampings as (key, message).
    pub fn issues(&self) -> Vec<(&'static str, String)> {
        let mut v = Vec::new();
        for (k, x) in [
            ("m_h", self.m_h),
            ("m_v", self.m_v),
            ("m_1", self.m_1),
            ("m_2", self.m_2),
        ] {
            positive(&mut v, k, x, "mass");
            at_most(&mut v, k, x, MAX_MASS_KG, "kg");
            at_least(&mut v, k, x, MIN_MASS_KG, "kg");
        }
        for (k, x) in [
            ("k_v", self.k_v),
            ("k_1", self.k_1),
            ("k_2", self.k_2),
            ("k_f", self.k_f),
        ] {
            positive(&mut v, k, x, "stiffness");
            at_most(&mut v, k, x, MAX_STIFFNESS_N_PER_M, "N/m");
            at_least(&mut v, k, x, MIN_STIFFNESS_N_PER_M, "N/m");
        }
        for (k, x) in [
            ("b_v", self.b_v),
            ("b_1", self.b_1),
            ("b_2", self.b_2),
            ("b_f", self.b_f),
        ] {
            non_negative(&mut v, k, x);
            at_most(&mut v, k, x, MAX_DAMPING_N_S_PER_M, "N·s/m");
        }
        v
    }
}

impl BranchConfig {
    /// Problems as (key, message).
    pub fn issues(&self) -> Vec<(&'static str, String)> {
        let mut v = Vec::new();
        positive(&mut v, "mass", self.mass, "mass");
        at_most(&mut v, "mass", self.mass, MAX_MASS_KG, "kg");
        at_least(&mut v, "mass", self.mass, MIN_MASS_KG, "kg");
        positive(&mut v, "stiffness", self.stiffness, "stiffness");
        at_most(
            &mut v,
            "stiffness",
            self.stiffness,
            MAX_STIFFNESS_N_PER_M,
            "N/m",
        );
        at_least(
            &mut v,
            "stiffness",
            self.stiffness,
            MIN_STIFFNESS_N_PER_M,
            "N/m",
        );
        non_negative(&mut v, "damping", self.damping);
        at_most(
            &mut v,
            "damping",
            self.damping,
            MAX_DAMPING_N_S_PER_M,
            "N·s/m",
        );
        v
    }
}

impl HaptuatorConfig {
    /// Problems at sample rate `fs` as (key, message).
    pub fn issues(&self, fs: f64) -> Vec<(&'static str, String)> {
        let mut v = Vec::new();
        positive(
            &mut v,
            "drive_gain_n_per_v",
            self.drive_gain_n_per_v,
            "drive gain",
        );
        positive(
            &mut v,
            "drive_corner_hz",
            self.drive_corner_hz,
            "drive corner",
        );
        below_nyquist(&mut v, "drive_corner_hz", self.drive_corner_hz, fs);
        positive(&mut v, "stroke_m", self.stroke_m, "stroke");
        non_negative(
            &mut v,
            "stop_stiffness_n_per_m",
            self.stop_stiffness_n_per_m,
        );
        non_negative(
            &mut v,
            "stop_damping_n_s_per_m",
            self.stop_damping_n_s_per_m,
        );
        at_most(
            &mut v,
            "drive_gain_n_per_v",
            self.drive_gain_n_per_v,
            1e3,
            "N/V",
        );
        at_least(
            &mut v,
            "drive_gain_n_per_v",
            self.drive_gain_n_per_v,
            1e-6,
            "N/V",
        );
        at_least(&mut v, "drive_corner_hz", self.drive_corner_hz, 1e-3, "Hz");
        at_most(&mut v, "stroke_m", self.stroke_m, 1.0, "m");
        at_least(&mut v, "stroke_m", self.stroke_m, 1e-9, "m");
        at_most(
            &mut v,
            "stop_stiffness_n_per_m",
            self.stop_stiffness_n_per_m,
            MAX_STIFFNESS_N_PER_M,
            "N/m",
        );
        at_most(
            &mut v,
            "stop_damping_n_s_per_m",
            self.stop_damping_n_s_per_m,
            MAX_DAMPING_N_S_PER_M,
            "N·s/m",
        );
        v
    }
}

impl AccelerometerConfig {
    /// Problems at sample rate `fs` as (key, message).
    pub fn issues(&self, fs: f64) -> Vec<(&'static str, String)> {
        let mut v = Vec::new();
        positive(&mut v, "range_g", self.range_g, "range");
        at_most(&mut v, "range_g", self.range_g, 1e4, "g");
        at_least(&mut v, "range_g", self.range_g, 1e-3, "g");
        non_negative(
            &mut v,
            "noise_density_ug_per_rthz",
            self.noise_density_ug_per_rthz,
        );
        at_most(
            &mut v,
            "noise_density_ug_per_rthz",
            self.noise_density_ug_per_rthz,
            1e7,
            "µg/√Hz",
        );
        non_negative(&mut v, "lsb_m_s2", self.lsb_m_s2);
        at_most(&mut v, "lsb_m_s2", self.lsb_m_s2, 1e4, "m/s²");
        if fs.is_finite() && fs > 0.0 {
            let nyq = 0.5 * fs;
            for (i, fc) in self.corner_hz.iter().enumerate() {
                if !(fc.is_finite() && *fc >= 1e-3 && *fc < nyq) {
                    v.push((
                        "corner_hz",
                        format!("axis {i}: corner must be in [0.001, {nyq}) Hz, got {fc}"),
                    ));
                }
            }
        }
        if self
            .static_m_s2
            .iter()
            .any(|x| !(x.is_finite() && x.abs() <= 1e5))
        {
            v.push((
                "static_m_s2",
                "must be finite, each at most 1e5 m/s²".into(),
            ));
        }
        v
    }
}

impl TweezerConfig {
    /// Problems as (key, message) (the obstacles check themselves).
    pub fn issues(&self) -> Vec<(&'static str, String)> {
        let mut v = Vec::new();
        positive(&mut v, "radius_m", self.radius_m, "bead radius");
        if self.obstacles.len() > MAX_OBSTACLES {
            v.push((
                "obstacles",
                format!(
                    "at most {MAX_OBSTACLES} obstacles (got {})",
                    self.obstacles.len()
                ),
            ));
        }
        positive(&mut v, "viscosity_pa_s", self.viscosity_pa_s, "viscosity");
        positive(&mut v, "temperature_k", self.temperature_k, "temperature");
        positive(
            &mut v,
            "stiffness_n_per_m",
            self.stiffness_n_per_m,
            "trap stiffness",
        );
        positive(
            &mut v,
            "escape_distance_m",
            self.escape_distance_m,
            "escape distance",
        );
        positive(
            &mut v,
            "contact_range_m",
            self.contact_range_m,
            "contact range",
        );
        positive(
            &mut v,
            "contact_stiffness_n_per_m",
            self.contact_stiffness_n_per_m,
            "contact stiffness",
        );
        if let Some(hw) = self.wall_distance_m
            && !(hw.is_finite() && hw > self.radius_m)
        {
            v.push((
                "wall_distance_m",
                format!("must exceed the bead radius {} m (got {hw})", self.radius_m),
            ));
        }
        match (self.profile, self.waist_m) {
            (TrapProfileKind::Gaussian, None) => v.push((
                "profile",
                "the gaussian profile needs `waist_m`, the beam's 1/e² intensity radius in m \
                 (≈ 0.4–0.6 µm for a high-NA 1064 nm trap)"
                    .into(),
            )),
            (TrapProfileKind::Linear, Some(_)) => v.push((
                "waist_m",
                "is used only with profile = \"gaussian\" (the linear profile has no waist)".into(),
            )),
            (TrapProfileKind::Gaussian, Some(w))
                if !(w.is_finite() && (WAIST_MIN_M..=WAIST_MAX_M).contains(&w)) =>
            {
                v.push((
                    "waist_m",
                    format!(
                        "beam waist must be finite and within [{WAIST_MIN_M}, {WAIST_MAX_M}] m \
                         (got {w})"
                    ),
                ))
            }
            _ => {}
        }
        if let Err(e) = self.detector.validate() {
            v.push(("detector", e.to_string()));
        }
        v
    }
}

impl ObstacleConfig {
    /// Problems as (key, message).
    pub fn issues(&self) -> Vec<(&'static str, String)> {
        if self.radius_m.is_finite()
            && self.radius_m > 0.0
            && self.x_m.is_finite()
            && self.y_m.is_finite()
        {
            Vec::new()
        } else {
            vec![("radius_m", format!("obstacle {self:?} is invalid"))]
        }
    }
}

impl CouplingConfig {
    /// Problems at sample rate `fs` as (key, message).
    pub fn issues(&self, fs: f64) -> Vec<(&'static str, String)> {
        let mut v = Vec::new();
        let nyq = 0.5 * fs;
        if fs.is_finite() && fs > 0.0 {
            if let PMode::Lowpass { hz } = self.p_mode
                && !(hz.is_finite() && hz > 0.0 && hz < nyq)
            {
                v.push((
                    "p_mode",
                    format!("the low-pass corner must be in (0, {nyq}) Hz, got {hz}"),
                ));
            }
            let fv = self.velocity_filter_hz;
            if !(fv.is_finite() && fv > 0.0 && fv < nyq) {
                v.push((
                    "velocity_filter_hz",
                    format!("must be in (0, {nyq}) Hz, got {fv}"),
                ));
            }
        }
        if !(self.position_scale.is_finite() && (1e-9..=1e3).contains(&self.position_scale.abs())) {
            v.push((
                "position_scale",
                format!(
                    "must be finite with 1e-9 ≤ |scale| ≤ 1e3 (got {})",
                    self.position_scale
                ),
            ));
        }
        if !(self.force_scale.is_finite() && self.force_scale.abs() <= 1e15) {
            v.push((
                "force_scale",
                format!(
                    "must be finite with |scale| ≤ 1e15 (got {})",
                    self.force_scale
                ),
            ));
        }
        let gh = self.high_band_gain;
        if !(gh.is_finite() && (0.0..=MAX_HIGH_BAND_GAIN).contains(&gh)) {
            v.push((
                "high_band_gain",
                format!("must be finite with 0 ≤ g_H ≤ {MAX_HIGH_BAND_GAIN:e} (got {gh})"),
            ));
        }
        if let Some(hz) = self.pantograph_band_hz {
            v.push((
                "pantograph_band_hz",
                format!(
                    "was removed: P's signal is now `p_mode` (\"full-band\", \"low-channel\", or \
                     `p_mode = {{ lowpass = {{ hz = {hz} }} }}` for the old behaviour)"
                ),
            ));
        }
        let d = self.contact_damping_n_s_per_m;
        if !(d.is_finite() && (0.0..=1e4).contains(&d)) {
            v.push((
                "contact_damping_n_s_per_m",
                format!("must be in [0, 10000] N·s/m (got {d})"),
            ));
        }
        for i in 0..2 {
            if !(self.trap_min_m[i].is_finite()
                && self.trap_max_m[i].is_finite()
                && self.trap_min_m[i] < self.trap_max_m[i])
            {
                v.push((
                    "trap_min_m",
                    format!("axis {i}: need trap_min_m < trap_max_m"),
                ));
            }
            if !(self.handle_origin_m[i].is_finite() && self.trap_offset_m[i].is_finite()) {
                v.push(("trap_offset_m", "must be finite".into()));
            }
        }
        v
    }
}

impl LimitsConfig {
    /// Problems as (key, message).
    pub fn issues(&self) -> Vec<(&'static str, String)> {
        let mut v = Vec::new();
        positive(
            &mut v,
            "pantograph_force_max_n",
            self.pantograph_force_max_n,
            "force limit",
        );
        positive(
            &mut v,
            "haptuator_drive_max_v",
            self.haptuator_drive_max_v,
            "drive limit",
        );
        at_most(
            &mut v,
            "pantograph_force_max_n",
            self.pantograph_force_max_n,
            MAX_ACTUATOR_LIMIT,
            "N",
        );
        at_most(
            &mut v,
            "haptuator_drive_max_v",
            self.haptuator_drive_max_v,
            MAX_ACTUATOR_LIMIT,
            "V",
        );
        v
    }
}

fn toml_error(text: &str, origin: &str, e: &toml::de::Error) -> RigError {
    let offset = e.span().map(|span| span.start);
    let (line, column) = offset.map_or((None, None), |o| line_col(text, o));
    RigError::Config {
        origin: origin.to_string(),
        line,
        column,
        field: offset.and_then(|o| field_at(text, o)).unwrap_or_default(),
        message: crate::toml_location::researcher_words(e.message()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_file_parses_and_validates() {
        let c = RigConfig::from_toml_str(default_config_text(), "default.toml").unwrap();
        assert_eq!(c.rig.sample_rate_hz, 10_000.0);
        assert!(c.plant.motor_branch.is_some());
        // Round trip through serde keeps every value.
        let again = RigConfig::from_toml_str(&c.to_toml_string().unwrap(), "rt").unwrap();
        assert_eq!(c, again);
    }

    #[test]
    fn unknown_key_names_file_line_and_field() {
        let text = default_config_text().replace("m_h = ", "m_hh = ");
        let e = RigConfig::from_toml_str(&text, "my.toml").unwrap_err();
        let msg = e.to_string();
        let expected_line = default_config_text()
            .lines()
            .position(|l| l.starts_with("m_h = "))
            .unwrap()
            + 1;
        match &e {
            RigError::Config {
                origin,
                line,
                field,
                ..
            } => {
                assert_eq!(origin, "my.toml");
                assert_eq!(*line, Some(expected_line), "{msg}");
                assert_eq!(field, "plant.m_hh", "{msg}");
            }
            other => panic!("wrong error {other:?}"),
        }
        assert!(msg.contains("my.toml:"), "{msg}");
    }

    #[test]
    fn a_bad_obstacle_is_named_by_its_index_and_line() {
        // The second obstacle's radius made negative.
        let text = default_config_text().replacen(
            "y_m = 14.0e-6\nradius_m = 5.0e-6",
            "y_m = 14.0e-6\nradius_m = -5.0e-6",
            1,
        );
        assert_ne!(text, default_config_text(), "the rig file changed");
        let expected_line = text
            .lines()
            .position(|l| l.starts_with("radius_m = -5.0e-6"))
            .unwrap()
            + 1;
        match RigConfig::from_toml_str(&text, "o.toml").unwrap_err() {
            RigError::Config { line, field, .. } => {
                assert_eq!(field, "tweezer.obstacles[1].radius_m");
                assert_eq!(line, Some(expected_line));
            }
            other => panic!("wrong error {other:?}"),
        }
    }

    /// The high-band gain: a negative one is located; an absent key is 1
    /// and 1 is not written, so a rig file's content hash is the one it
    /// had before the key.
    #[test]
    fn high_band_gain_is_checked_and_one_is_not_written() {
        let text = default_config_text().replace("high_band_gain = 30.0", "high_band_gain = -3.0");
        assert_ne!(text, default_config_text());
        let line = text
            .lines()
            .position(|l| l.starts_with("high_band_gain"))
            .unwrap()
            + 1;
        match RigConfig::from_toml_str(&text, "g.toml").unwrap_err() {
            RigError::Config {
                line: got,
                field,
                message,
                ..
            } => {
                assert_eq!(field, "coupling.high_band_gain");
                assert_eq!(got, Some(line));
                assert!(message.contains("-3"), "{message}");
            }
            other => panic!("wrong error {other:?}"),
        }
        let mut c = RigConfig::default();
        assert_eq!(c.coupling.high_band_gain, 30.0);
        assert!(
            c.to_toml_string()
                .unwrap()
                .contains("high_band_gain = 30.0")
        );
        assert!(!c.to_toml_string().unwrap().contains("[camera]"));
        let without = default_config_text().replace("high_band_gain = 30.0\n", "");
        let old = RigConfig::from_toml_str(&without, "old.toml").unwrap();
        assert_eq!(old.coupling.high_band_gain, 1.0);
        c.coupling.high_band_gain = 1.0;
        assert_eq!(old, c);
        assert!(!c.to_toml_string().unwrap().contains("high_band_gain"));
        c.coupling.high_band_gain = 38.0;
        let again = RigConfig::from_toml_str(&c.to_toml_string().unwrap(), "rt").unwrap();
        assert_eq!(again.coupling.high_band_gain, 38.0);
    }

    #[test]
    fn non_positive_mass_is_located() {
        let text = default_config_text().replace("m_2 = ", "m_2 = -");
        let e = RigConfig::from_toml_str(&text, "f.toml").unwrap_err();
        let expected_line = text.lines().position(|l| l.starts_with("m_2 = ")).unwrap() + 1;
        match e {
            RigError::Config {
                line,
                field,
                message,
                ..
            } => {
                assert_eq!(field, "plant.m_2");
                assert_eq!(line, Some(expected_line));
                assert!(message.contains("> 0"), "{message}");
            }
            other => panic!("wrong error {other:?}"),
        }
    }

    #[test]
    fn wrong_type_and_missing_key_are_errors() {
        let text = default_config_text().replace("k_f = ", "k_f = \"soft\" #");
        assert!(matches!(
            RigConfig::from_toml_str(&text, "t").unwrap_err(),
            RigError::Config { line: Some(_), .. }
        ));
        let text: String = default_config_text()
            .lines()
            .filter(|l| !l.starts_with("b_f = "))
            .collect::<Vec<_>>()
            .join("\n");
        let e = RigConfig::from_toml_str(&text, "t").unwrap_err();
        assert!(e.to_string().contains("b_f"), "{e}");
    }

    #[test]
    fn corner_above_nyquist_rejected() {
        let text =
            default_config_text().replace("sample_rate_hz = 10000.0", "sample_rate_hz = 250.0");
        let e = RigConfig::from_toml_str(&text, "t").unwrap_err();
        assert!(e.to_string().contains("Nyquist"), "{e}");
    }

    #[test]
    fn nan_and_inf_rejected() {
        let text = default_config_text().replace("k_2 = ", "k_2 = nan #");
        assert!(RigConfig::from_toml_str(&text, "t").is_err());
        let text = default_config_text().replace("m_1 = ", "m_1 = inf #");
        assert!(RigConfig::from_toml_str(&text, "t").is_err());
    }

    #[test]
    fn load_reports_missing_file() {
        let e = RigConfig::load("/nonexistent/rig.toml").unwrap_err();
        assert!(matches!(e, RigError::Io { .. }));
    }
}
