//! Pressing the bead against an obstacle (`kilotouch sim press`): the
//! closed loop's hardest state, simulated, with a verdict judged from the
//! signals alone (never from the margin analysis, which it checks).
//!
//! # Scenario
//!
//! The simulated hand holds the handle through the finger. It starts at rest
//! (bead in the trap, free), moves over [`APPROACH_S`] along the line from
//! the rest trap to the obstacle's centre until the trap sits `depth` past
//! the point of contact, and holds there. The hand target includes the
//! finger's static deflection F/k_f, so the trap settles at the requested
//! depth and the handle force at F ≈ g·κ·k_c/(κ + k_c)·depth.
//!
//! # Verdict
//!
//! From the hold, after [`SETTLE_S`]: the handle force along the pressing
//! direction (image + wall damper), its mean, and its oscillation (the force
//! minus a 2 Hz first-order low-pass of it). The oscillation's RMS over
//! windows of [`WINDOW_S`] gives the envelope; its growth is the
//! least-squares slope of 20·log₁₀(RMS) against time, dB/s. The loop is
//! **stable** when the bead stays trapped, the envelope does not grow by
//! more than [`MAX_GROWTH_DB_PER_S`] and the oscillation stays below
//! [`MAX_OSC_FRACTION`] of the mean force (a saturated limit cycle —
//! contact lost and regained every period — grows no more but is not stable).

use crate::condition::Condition;
use crate::config::ObstacleConfig;
use crate::config::RigConfig;
use crate::coupling::{HandMapping, LoopChain};
use crate::error::RigError;
use crate::haptic_loop::{Clearance, HapticLoop};
use crate::tweezer::{Obstacle, TweezerParams};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

/// Duration of the approach, s.
pub const APPROACH_S: f64 = 0.5;
/// Time after the approach before the verdict's analysis starts, s.
pub const SETTLE_S: f64 = 0.5;
/// Envelope window, s.
pub const WINDOW_S: f64 = 0.1;
/// Largest envelope growth of a stable loop, dB/s.
pub const MAX_GROWTH_DB_PER_S: f64 = 3.0;
/// Largest oscillation RMS of a stable loop, as a fraction of the mean force.
pub const MAX_OSC_FRACTION: f64 = 0.1;
/// Longest simulation, s.
pub const MAX_DURATION_S: f64 = 600.0;
/// Corner of the low-pass that separates the mean from the oscillation, Hz.
const MEAN_CORNER_HZ: f64 = 2.0;

/// What to simulate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PressOptions {
    /// P or D.
    pub condition: Condition,
    /// Total duration (approach, settle, analysis), s.
    pub duration_s: f64,
    /// Seed of the noise generators.
    pub seed: u64,
    /// How far past the point of contact the trap is pushed, m (below the
    /// escape distance).
    pub depth_m: f64,
}

impl Default for PressOptions {
    fn default() -> Self {
        Self {
            condition: Condition::D,
            duration_s: 5.0,
            seed: 1,
            depth_m: 0.8e-6,
        }
    }
}

/// The verdict (`kilotouch sim press --json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PressReport {
    /// Judged from the signals (module docs).
    pub stable: bool,
    /// Envelope growth of the force oscillation, dB/s.
    pub growth_db_per_s: f64,
    /// Mean handle force along the pressing direction, N (positive: pushing
    /// the hand back).
    pub handle_force_mean_n: f64,
    /// RMS of the force oscillation, N.
    pub handle_force_osc_rms_n: f64,
    /// The bead left the trap.
    pub escaped: bool,
    /// Fraction of the analysed samples in contact.
    pub contact_fraction: f64,
    /// Condition.
    pub condition: Condition,
    /// Where the chain came from.
    pub chain: String,
    /// Duration simulated, s.
    pub duration_s: f64,
    /// The force asked for: g·κ·k_c/(κ + k_c)·depth, N.
    pub expected_force_n: f64,
    /// Samples in which the passivity controller added damping (0 when it
    /// is off).
    pub passivity_active_samples: u64,
}

/// The time series of a press (for plots and CSV), one row per sample.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PressTrace {
    /// Time, s.
    pub t_s: Vec<f64>,
    /// Handle force along the pressing direction, N.
    pub force_n: Vec<f64>,
    /// Surface gap bead–obstacle, m.
    pub gap_m: Vec<f64>,
    /// Handle position along the pressing direction, m.
    pub handle_m: Vec<f64>,
    /// True fingertip acceleration along the pressing direction (the
    /// plant's output, before the sensor), m/s².
    pub accel_m_s2: Vec<f64>,
    /// The accelerometer's reading along the pressing direction (its
    /// response, noise and quantisation), m/s².
    pub accel_sensor_m_s2: Vec<f64>,
}

/// Where the hand goes: the scenario's geometry (module docs).
#[derive(Debug, Clone)]
struct Scenario {
    /// The rig file with the press's seeds, condition and one obstacle.
    cfg: RigConfig,
    /// Pressing direction in handle space (unit).
    uh: [f64; 2],
    /// Hand at rest and pressed, m.
    hand_start: [f64; 2],
    hand_end: [f64; 2],
    /// g·κ·k_c/(κ + k_c)·depth, N.
    expected_n: f64,
}

/// Check the options and lay out the scenario: the first obstacle of the
/// rig file (or one at (12, 0) µm, radius 5 µm), the line from the rest trap
/// to its centre, the trap `depth` past contact, the finger's static
/// deflection added to the hand.
fn scenario(cfg: &RigConfig, opts: &PressOptions) -> Result<Scenario, RigError> {
    if !opts.condition.haptic() {
        return Err(RigError::InvalidInput(
            "press needs a haptic condition (P or D)".into(),
        ));
    }
    let d = opts.duration_s;
    let shortest = APPROACH_S + SETTLE_S + 5.0 * WINDOW_S;
    if !(d.is_finite() && (shortest..=MAX_DURATION_S).contains(&d)) {
        return Err(RigError::InvalidParameter {
            name: "duration",
            value: d,
            reason: format!("must be in [{shortest}, {MAX_DURATION_S}] s"),
        });
    }
    let esc = cfg.tweezer.escape_distance_m;
    if !(opts.depth_m.is_finite() && opts.depth_m > 0.0 && opts.depth_m < esc) {
        return Err(RigError::InvalidParameter {
            name: "depth",
            value: opts.depth_m,
            reason: format!("must be in (0, {esc}) m (the escape distance)"),
        });
    }
    let mut cfg = cfg.clone();
    let mut seeds = rand_xoshiro::SplitMix64::seed_from_u64(opts.seed);
    cfg.accelerometer.seed = seeds.next_u64();
    cfg.tweezer.seed = seeds.next_u64();
    cfg.coupling.mode = opts.condition;
    let mapping = HandMapping::from_config(&cfg.coupling);
    let params = TweezerParams::from_config(&cfg.tweezer);
    let obstacle = params.obstacles.first().copied().unwrap_or(Obstacle {
        centre_m: [12e-6, 0.0],
        radius_m: 5e-6,
    });
    let rest = mapping.rest_trap_m();
    let dir = [
        obstacle.centre_m[0] - rest[0],
        obstacle.centre_m[1] - rest[1],
    ];
    let dn = (dir[0] * dir[0] + dir[1] * dir[1]).sqrt();
    if dn.is_nan() || dn <= obstacle.radius_m + params.radius_m {
        return Err(RigError::InvalidInput(
            "the rest trap is inside the obstacle: nothing to press against".into(),
        ));
    }
    let u = [dir[0] / dn, dir[1] / dn];
    let reach = dn - obstacle.radius_m - params.radius_m + opts.depth_m;
    let trap_end = [rest[0] + u[0] * reach, rest[1] + u[1] * reach];
    if !mapping.in_workspace(trap_end) {
        return Err(RigError::InvalidInput(
            "the pressed trap position lies outside the trap workspace".into(),
        ));
    }
    let (kappa, kc) = (params.stiffness_n_per_m, params.contact_stiffness_n_per_m);
    let expected_n = cfg.coupling.force_scale * kappa * kc / (kappa + kc) * opts.depth_m;
    let uh = [u[0] * mapping.scale.signum(), u[1] * mapping.scale.signum()];
    let push = mapping.to_hand(trap_end);
    let defl = expected_n / cfg.plant.k_f;
    cfg.tweezer.obstacles = vec![ObstacleConfig {
        x_m: obstacle.centre_m[0],
        y_m: obstacle.centre_m[1],
        radius_m: obstacle.radius_m,
    }];
    Ok(Scenario {
        cfg,
        uh,
        hand_start: mapping.to_hand(rest),
        hand_end: [push[0] + uh[0] * defl, push[1] + uh[1] * defl],
        expected_n,
    })
}

/// Simulate a press (module docs) with `chain`, armed by `clearance`.
///
/// # Errors
/// Invalid options or configuration; rig errors.
pub fn simulate_press(
    cfg: &RigConfig,
    chain: &LoopChain,
    clearance: Clearance,
    opts: &PressOptions,
) -> Result<(PressReport, PressTrace), RigError> {
    simulate_press_after_rest(cfg, chain, clearance, opts, 0.0)
}

/// [`simulate_press`] preceded by `rest_s` seconds with the hand still at
/// its start (the bead trapped in free space): the trace starts with the
/// rest, the verdict's analysis starts `rest_s` later (paper Fig. 9: free
/// space, collision, pressing in one record).
///
/// # Errors
/// Invalid options (also a `rest_s` outside [0, [`MAX_DURATION_S`]]) or
/// configuration; rig errors.
pub fn simulate_press_after_rest(
    cfg: &RigConfig,
    chain: &LoopChain,
    clearance: Clearance,
    opts: &PressOptions,
    rest_s: f64,
) -> Result<(PressReport, PressTrace), RigError> {
    let sc = scenario(cfg, opts)?;
    if !(rest_s.is_finite() && (0.0..=MAX_DURATION_S).contains(&rest_s)) {
        return Err(RigError::InvalidParameter {
            name: "rest",
            value: rest_s,
            reason: format!("must be in [0, {MAX_DURATION_S}] s"),
        });
    }
    let fs = sc.cfg.rig.sample_rate_hz;
    let mut lp = HapticLoop::simulated(&sc.cfg, chain, clearance)?;
    let n_rest = crate::round_half_away(rest_s * fs) as usize;
    let n = n_rest + crate::round_half_away(opts.duration_s * fs) as usize;
    let n_approach = crate::round_half_away(APPROACH_S * fs) as usize;
    let mut trace = PressTrace::default();
    for v in [
        &mut trace.t_s,
        &mut trace.force_n,
        &mut trace.gap_m,
        &mut trace.handle_m,
        &mut trace.accel_m_s2,
        &mut trace.accel_sensor_m_s2,
    ] {
        v.reserve_exact(n);
    }
    let (uh, h0, h1) = (sc.uh, sc.hand_start, sc.hand_end);
    let mut escaped = false;
    let mut contact = Vec::with_capacity(n);
    for k in 0..n {
        let a = ((k + 1).saturating_sub(n_rest) as f64 / n_approach as f64).min(1.0);
        // Smooth (raised-cosine) approach: no velocity step at either end.
        let w = 0.5 - 0.5 * (std::f64::consts::PI * a).cos();
        lp.rig
            .set_hand([h0[0] + w * (h1[0] - h0[0]), h0[1] + w * (h1[1] - h0[1])]);
        let s = lp.step()?;
        let r = s.rendered;
        let f = [r.image_n[0] + r.damping_n[0], r.image_n[1] + r.damping_n[1]];
        trace.t_s.push(k as f64 / fs);
        trace.force_n.push(-(f[0] * uh[0] + f[1] * uh[1]));
        trace.gap_m.push(s.tweezer.gap_m);
        let hm = s.sensors.handle_m;
        trace.handle_m.push(hm[0] * uh[0] + hm[1] * uh[1]);
        let at = lp.rig.truth().accel_m_s2;
        trace.accel_m_s2.push(at[0] * uh[0] + at[1] * uh[1]);
        let am = s.sensors.accel_m_s2;
        trace.accel_sensor_m_s2.push(am[0] * uh[0] + am[1] * uh[1]);
        escaped |= !s.tweezer.trapped;
        contact.push(s.tweezer.in_contact);
    }
    let start = (n_rest + crate::round_half_away((APPROACH_S + SETTLE_S) * fs) as usize).min(n);
    let (mean, osc_rms, growth) = envelope(&trace.force_n, start, fs);
    let cf = contact[start..].iter().filter(|c| **c).count() as f64 / (n - start).max(1) as f64;
    let stable = !escaped
        && growth.is_finite()
        && growth <= MAX_GROWTH_DB_PER_S
        && osc_rms <= MAX_OSC_FRACTION * mean.abs();
    Ok((
        PressReport {
            stable,
            growth_db_per_s: growth,
            handle_force_mean_n: mean,
            handle_force_osc_rms_n: osc_rms,
            escaped,
            contact_fraction: cf,
            condition: opts.condition,
            chain: chain.source.describe(),
            duration_s: opts.duration_s,
            expected_force_n: sc.expected_n,
            passivity_active_samples: lp.coupling.counters().passivity_active,
        },
        trace,
    ))
}

/// Mean, oscillation RMS and envelope growth (dB/s) of `x` from sample
/// `start` on (module docs).
pub fn envelope(x: &[f64], start: usize, fs: f64) -> (f64, f64, f64) {
    let a = 1.0 - (-2.0 * std::f64::consts::PI * MEAN_CORNER_HZ / fs).exp();
    let mut lp = x.first().copied().unwrap_or(0.0);
    let mut osc = Vec::with_capacity(x.len());
    for &v in x {
        lp += a * (v - lp);
        osc.push(v - lp);
    }
    let tail = &x[start.min(x.len())..];
    let osc = &osc[start.min(x.len())..];
    if tail.is_empty() {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    let mean = tail.iter().sum::<f64>() / tail.len() as f64;
    let rms = (osc.iter().map(|v| v * v).sum::<f64>() / osc.len() as f64).sqrt();
    let w = (WINDOW_S * fs).round().max(1.0) as usize;
    let pts: Vec<(f64, f64)> = osc
        .chunks_exact(w)
        .enumerate()
        .map(|(i, c)| {
            let r = (c.iter().map(|v| v * v).sum::<f64>() / c.len() as f64).sqrt();
            ((i as f64 + 0.5) * WINDOW_S, 20.0 * r.max(1e-300).log10())
        })
        .collect();
    let growth = if pts.len() >= 3 {
        let n = pts.len() as f64;
        let mt = pts.iter().map(|p| p.0).sum::<f64>() / n;
        let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
        let sxy: f64 = pts.iter().map(|p| (p.0 - mt) * (p.1 - my)).sum();
        let sxx: f64 = pts.iter().map(|p| (p.0 - mt).powi(2)).sum();
        sxy / sxx
    } else {
        f64::NAN
    };
    (mean, rms, growth)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn envelope_measures_growth_of_a_known_signal() {
        let fs = 10_000.0;
        // 1 N mean plus a 10 Hz oscillation growing at 6 dB/s.
        let x: Vec<f64> = (0..50_000)
            .map(|k| {
                let t = k as f64 / fs;
                1.0 + 0.01
                    * 10f64.powf(6.0 * t / 20.0)
                    * (2.0 * std::f64::consts::PI * 10.0 * t).sin()
            })
            .collect();
        let (mean, rms, g) = envelope(&x, 10_000, fs);
        assert!((g - 6.0).abs() < 0.3, "growth {g}");
        assert!((mean - 1.0).abs() < 0.01 && rms > 0.01, "{mean} {rms}");
    }
}
