//! The Gaussian trap profile against independent references: the analytic
//! force profile, the Boltzmann density (deep trap: per-axis variance; a
//! shallow trap in a reflecting disc: the radial histogram), and the mean
//! first-passage time of thermally activated escape from the exact
//! overdamped MFPT integral and Kramers' flux-over-population estimate, and
//! the escape time of a bead pulled at constant speed from the 2-D backward
//! equation (`tests/kramers_reference.py` → `tests/data/kramers_reference.json`,
//! scipy quadrature and sparse solve). Also the rig-file keys and the non-finite guards.

#![allow(clippy::unwrap_used)]

use kilotouch_rig::config::{RigConfig, default_config_text};
use kilotouch_rig::tweezer::*;
use kilotouch_rig::{RigError, Tweezer};
use serde_json::Value;

fn reference() -> Value {
    serde_json::from_str(include_str!("data/kramers_reference.json")).unwrap()
}

fn gaussian(waist_m: f64, stiffness: f64, seed: u64) -> TweezerParams {
    TweezerParams {
        stiffness_n_per_m: stiffness,
        profile: TrapProfile::Gaussian { waist_m },
        // Below 2 w0: the escape radius is 2 w0.
        escape_distance_m: 0.1e-6,
        seed,
        ..TweezerParams::paper_default()
    }
}

fn f(v: &Value, k: &str) -> f64 {
    v[k].as_f64().unwrap_or_else(|| panic!("{k}"))
}

/// F(d) = −κ d exp(−2|d|²/w0²): the magnitude peaks at w0/2 with
/// κ w0 e^{−1/2}/2, the small-d slope is κ, the force points at the trap,
/// and −dU/dr is the force (numerical derivative of the potential).
#[test]
fn force_profile_is_the_gaussian_gradient_force() {
    let (w0, kappa) = (0.5e-6, 2.0e-5);
    let p = gaussian(w0, kappa, 0);
    // e^{−1/2}/2, independent of the library's expression.
    const HALF_EXP: f64 = 0.303_265_329_856_316_7;
    let n = 200_000;
    let (mut best_r, mut best_f) = (0.0, 0.0);
    for i in 0..=n {
        let r = 2.0 * w0 * i as f64 / n as f64;
        let fr = -p.optical_force_n([r, 0.0])[0];
        if fr > best_f {
            (best_r, best_f) = (r, fr);
        }
    }
    assert!((best_r / (0.5 * w0) - 1.0).abs() < 1e-4, "peak at {best_r}");
    assert!((best_f / (kappa * w0 * HALF_EXP) - 1.0).abs() < 1e-9);
    assert!((p.peak_force_n() / (kappa * w0 * HALF_EXP) - 1.0).abs() < 1e-12);
    // Small-d slope κ, in any direction, pointing at the trap.
    for dir in [[1.0, 0.0], [0.6, -0.8], [-0.28, 0.96]] {
        let d = [1e-12 * dir[0], 1e-12 * dir[1]];
        let fv = p.optical_force_n(d);
        for i in 0..2 {
            if dir[i] != 0.0 {
                assert!((fv[i] / (-kappa * d[i]) - 1.0).abs() < 1e-9);
            }
        }
    }
    // Depth κ w0²/4 and F = −dU/dr.
    assert!((p.depth_j() / (0.25 * kappa * w0 * w0) - 1.0).abs() < 1e-12);
    assert!(p.potential_j(20.0 * w0) / p.depth_j() > 1.0 - 1e-12);
    for r in [0.05e-6, 0.25e-6, 0.4e-6, 0.8e-6] {
        let h = 1e-12;
        let du = (p.potential_j(r + h) - p.potential_j(r - h)) / (2.0 * h);
        let fr = -p.optical_force_n([0.0, r])[1];
        assert!((du / fr - 1.0).abs() < 1e-5, "r {r}: {du} vs {fr}");
    }
    assert_eq!(p.escape_radius_m(), 2.0 * w0);
    let far = TweezerParams {
        escape_distance_m: 3e-6,
        ..p.clone()
    };
    assert_eq!(far.escape_radius_m(), 3e-6);
}

/// The sample's force is the profile's force at the sample's bead, also
/// for a lost bead.
#[test]
fn sample_force_is_the_profile_force() {
    let p = gaussian(0.5e-6, 2.0e-5, 3);
    let mut t = SimTweezer::new(p.clone(), 1e4).unwrap();
    t.start_stationary();
    for i in 0..2000 {
        let trap = [1e-9 * i as f64, 0.0];
        let s = t.step(trap);
        let want = p.optical_force_n([s.bead_m[0] - trap[0], s.bead_m[1] - trap[1]]);
        assert_eq!(s.force_n, want);
        assert!(s.trapped);
    }
    // Jump the trap 1.5 µm (3 w0): escape, a small but nonzero force.
    let s = t.step([2.0e-6 + 1.5e-6, 0.0]);
    assert!(s.events.escaped && !s.trapped);
    let want = p.optical_force_n([s.bead_m[0] - s.trap_m[0], s.bead_m[1] - s.trap_m[1]]);
    assert_eq!(s.force_n, want);
    assert!(s.force_n[0] > 0.0 && s.force_n[0] < 1e-3 * p.peak_force_n());
    // Back over the bead: recaptured.
    let mut recaptured = false;
    for _ in 0..10 {
        recaptured |= t.step(t.bead()).events.recaptured;
    }
    assert!(recaptured && t.trapped());
}

/// Deep trap (the default rig's bead and stiffness, w0 = 0.5 µm, U0 ≈ 309
/// k_BT): the per-axis variance equals the Boltzmann value (0.66 % above
/// k_BT/κ) within 3 % (≈ 5 standard errors of 4e5 correlated samples).
#[test]
fn deep_gaussian_trap_has_the_boltzmann_variance() {
    let r = &reference()["deep"];
    let p = gaussian(f(r, "waist_m"), f(r, "stiffness_n_per_m"), 11);
    assert!((p.depth_j() / p.kt() / f(r, "barrier_kt") - 1.0).abs() < 1e-9);
    let mut t = SimTweezer::new(p.clone(), 1e4).unwrap();
    t.start_stationary();
    let n = 400_000;
    let (mut sx, mut sy, mut subs) = (0.0, 0.0, 0u64);
    for _ in 0..n {
        let s = t.step([0.0; 2]);
        assert!(s.trapped);
        sx += s.bead_m[0] * s.bead_m[0];
        sy += s.bead_m[1] * s.bead_m[1];
        subs += u64::from(s.substeps);
    }
    let want = f(r, "variance_per_axis_m2");
    for v in [sx / n as f64, sy / n as f64] {
        eprintln!(
            "variance {v:.4e} m², Boltzmann {want:.4e}, kT/κ {:.4e}",
            p.variance_theory()
        );
        assert!((v / want - 1.0).abs() < 0.03, "{v:e} vs {want:e}");
    }
    // One step per sample in the deep trap.
    assert_eq!(subs, n as u64);
}

/// Shallow trap (U0 = 3 k_BT, w0 = 0.2 µm) with the bead kept in the disc
/// |d| ≤ 2 w0 by reflection at the disc's edge: the radial histogram (16
/// bins) matches the Boltzmann radial density r exp(−U/k_BT). The samples
/// are correlated, so each bin's standard error comes from 20 batch means;
/// χ² = Σ ((p̂ − p)/SE)² over the 16 bins must stay below 40 (16 degrees
/// of freedom: mean ≈ 16, 40 is beyond the 99.9 % point even with the
/// batch-variance inflation) and every bin within 4.5 SE.
#[test]
fn shallow_gaussian_trap_has_the_boltzmann_radial_density() {
    let r = &reference()["radial"];
    let w0 = f(r, "waist_m");
    let p = gaussian(w0, f(r, "stiffness_n_per_m"), 5);
    assert!((p.depth_j() / p.kt() / f(r, "barrier_kt") - 1.0).abs() < 1e-9);
    let b = f(r, "disc_radius_m");
    let edges: Vec<f64> = serde_json::from_value(r["edges_m"].clone()).unwrap();
    let prob: Vec<f64> = serde_json::from_value(r["probability"].clone()).unwrap();
    let k = prob.len();
    let mut t = SimTweezer::new(p, f(r, "fs_hz")).unwrap();
    t.start_stationary();
    let (batches, per_batch) = (20, 100_000);
    let mut means = vec![vec![0.0; k]; batches];
    for m in means.iter_mut() {
        for _ in 0..per_batch {
            let s = t.step([0.0; 2]);
            let mut d = s.bead_m;
            let mut rr = d[0].hypot(d[1]);
            if rr > b {
                // Reflect radially at the disc's edge.
                let to = (2.0 * b - rr).max(0.0);
                d = [d[0] * to / rr, d[1] * to / rr];
                t.set_bead(d);
                rr = to;
            }
            let i = edges.partition_point(|&e| e <= rr).clamp(1, k) - 1;
            m[i] += 1.0 / per_batch as f64;
        }
    }
    let mut chi2 = 0.0;
    for i in 0..k {
        let mean = means.iter().map(|m| m[i]).sum::<f64>() / batches as f64;
        let var = means.iter().map(|m| (m[i] - mean).powi(2)).sum::<f64>()
            / (batches - 1) as f64
            / batches as f64;
        let z = (mean - prob[i]) / var.sqrt();
        eprintln!("bin {i}: {mean:.4} vs {:.4} (z {z:+.2})", prob[i]);
        assert!(z.abs() < 4.5, "bin {i}: {mean} vs {} (z {z})", prob[i]);
        chi2 += z * z;
    }
    eprintln!("chi2 {chi2:.1} over {k} bins");
    assert!(chi2 < 40.0, "χ² {chi2}");
}

/// `n` escapes of a bead starting at rest at the centre of a trap that
/// moves at `speed_m_s` along x (0: held still), sampled at `fs`: the mean
/// escape time, its SD and its standard error, s.
fn escape_times(t: &mut SimTweezer, fs: f64, n: usize, speed_m_s: f64) -> (f64, f64, f64) {
    let mut times = Vec::with_capacity(n);
    for _ in 0..n {
        t.reset([0.0; 2]);
        let mut k = 0u64;
        loop {
            k += 1;
            let x = speed_m_s * k as f64 / fs;
            if t.step([x, 0.0]).events.escaped {
                break;
            }
        }
        times.push(k as f64 / fs);
    }
    let m = times.len() as f64;
    let mean = times.iter().sum::<f64>() / m;
    let sd = (times.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (m - 1.0)).sqrt();
    (mean, sd, sd / m.sqrt())
}

/// Thermally activated escape over U0 = 4 and 5.5 k_BT (w0 = 0.4 µm, escape
/// radius 2 w0 = 0.8 µm): the mean first-passage time from the trap centre
/// matches the exact overdamped MFPT integral within 3 standard errors of
/// the mean (SE from the escape times' own spread, ≈ mean/√n) plus the
/// discrete-monitoring shift (the Siegmund correction at the sample
/// period, ≤ 2 %); Kramers' harmonic-well estimate is lower by the factor
/// the reference gives (1.5 at 4 k_BT, 1.3 at 5.5 k_BT: it approaches the
/// exact time as the barrier grows) and the simulation agrees with it
/// within 60 %.
#[test]
fn escape_time_matches_the_mfpt_integral() {
    let r = reference();
    for (case, n_escapes) in r["escape"].as_array().unwrap().iter().zip([400, 200]) {
        let w0 = f(case, "waist_m");
        let p = gaussian(w0, f(case, "stiffness_n_per_m"), 17);
        assert!((p.depth_j() / p.kt() / f(case, "barrier_kt") - 1.0).abs() < 1e-9);
        assert_eq!(p.escape_radius_m(), f(case, "escape_radius_m"));
        let fs = f(case, "fs_hz");
        let mut t = SimTweezer::new(p, fs).unwrap();
        let (mean, sd, se) = escape_times(&mut t, fs, n_escapes, 0.0);
        let exact = f(case, "mfpt_s");
        let shift = f(case, "mfpt_shifted_s") - exact;
        let kramers = f(case, "mfpt_kramers_s");
        eprintln!(
            "U0 {} kT: MFPT {mean:.3} ± {se:.3} s (sd/mean {:.2}), exact {exact:.3} s, \
             Kramers {kramers:.3} s",
            f(case, "barrier_kt"),
            sd / mean
        );
        assert!(
            (mean - exact).abs() < 3.0 * se + shift,
            "{mean} ± {se} vs {exact}"
        );
        assert!(
            (mean / kramers - 1.0).abs() < 0.6,
            "{mean} vs Kramers {kramers}"
        );
    }
}

/// A trap pulled at constant speed v along x (the bead starts at rest at
/// its centre): the mean escape time falls with v as the drag γv tilts the
/// barrier, and above the critical speed v_c = F_max/γ (F_max = κ w0 e^{−1/2}/2,
/// the escape force) the bead is dragged out. At 0.25, 0.5, 0.75 and 1.25 v_c
/// (U0 = 5.5 k_BT at rest) the simulated mean matches the reference's
/// solution of the 2-D backward equation in the trap's frame
/// (`kramers_reference.py`, section 4, itself checked against the exact
/// radial integral at rest) within 3 standard errors plus 2 % (the
/// discrete escape check and the sampled trap path).
#[test]
fn escape_time_against_pulling_speed_matches_the_backward_equation() {
    let r = reference();
    let case = &r["pulled"];
    let w0 = f(case, "waist_m");
    let kappa = f(case, "stiffness_n_per_m");
    let fs = f(case, "fs_hz");
    let p = gaussian(w0, kappa, 23);
    let gamma = 6.0 * std::f64::consts::PI * p.viscosity_pa_s * p.radius_m;
    let f_max = kappa * w0 * (-0.5f64).exp() / 2.0;
    assert!((f_max / f(case, "escape_force_n") - 1.0).abs() < 1e-9);
    assert!((f_max / gamma / f(case, "critical_speed_m_s") - 1.0).abs() < 1e-6);
    let mut t = SimTweezer::new(p, fs).unwrap();
    let mut last = f64::INFINITY;
    for speed in case["speeds"].as_array().unwrap() {
        let v = f(speed, "speed_m_s");
        let exact = f(speed, "mfpt_s");
        let (mean, _, se) = escape_times(&mut t, fs, 200, v);
        eprintln!(
            "v = {:.2} v_c: MFPT {mean:.4} ± {se:.4} s, backward equation {exact:.4} s",
            f(speed, "speed_over_critical")
        );
        assert!(
            (mean - exact).abs() < 3.0 * se + 0.02 * exact,
            "v = {v} m/s: {mean} ± {se} s vs {exact} s"
        );
        assert!(mean < last, "the escape time does not fall with the speed");
        last = mean;
    }
}

/// Non-finite input never reaches the output (nor do set-points 1e300 m
/// away), and the Gaussian profile's Euler–Maruyama with a step far beyond
/// its stability limit stays finite (the force is bounded).
#[test]
fn gaussian_outputs_stay_finite() {
    for integrator in [TweezerIntegrator::Exact, TweezerIntegrator::Euler] {
        let p = TweezerParams {
            integrator,
            obstacles: vec![Obstacle {
                centre_m: [4e-6, 0.0],
                radius_m: 1e-6,
            }],
            ..gaussian(0.5e-6, 1e-2, 9)
        };
        // dt/τ ≈ 35 at 10 kHz.
        let mut t = SimTweezer::new(p, 1e4).unwrap();
        let traps = [
            [f64::NAN, 0.0],
            [0.0, f64::INFINITY],
            [1e-6, 0.0],
            [1e300, -1e300],
            [0.0, 0.0],
            [-1e300, 1e300],
            [2.5e-6, 0.0],
            [f64::NEG_INFINITY, f64::NAN],
        ];
        for i in 0..4000 {
            let s = t.step(traps[i % traps.len()]);
            assert!(
                s.bead_m
                    .iter()
                    .chain(&s.force_n)
                    .chain(&s.trap_m)
                    .all(|v| v.is_finite()),
                "{integrator:?} step {i}: {s:?}"
            );
        }
        t.set_bead([f64::NAN, 0.0]);
        assert!(t.bead().iter().all(|v| v.is_finite()));
    }
}

/// The rig file: `profile = "gaussian"` with `waist_m` reaches the tweezer;
/// no key (or `profile = "linear"`) is today's linear trap and serialises as
/// before; bad combinations name the file, line and key.
#[test]
fn rig_file_keys() {
    let base = default_config_text();
    let with = |extra: &str| base.replace("escape_distance_m = 1.5e-6\n", extra);
    let cfg = RigConfig::from_toml_str(
        &with("escape_distance_m = 1.5e-6\nprofile = \"gaussian\"\nwaist_m = 0.5e-6\n"),
        "g.toml",
    )
    .unwrap();
    assert_eq!(
        TweezerParams::from_config(&cfg.tweezer).profile,
        TrapProfile::Gaussian { waist_m: 0.5e-6 }
    );
    let def = RigConfig::from_toml_str(base, "d.toml").unwrap();
    let lin = RigConfig::from_toml_str(
        &with("escape_distance_m = 1.5e-6\nprofile = \"linear\"\n"),
        "l.toml",
    )
    .unwrap();
    assert_eq!(def, lin);
    assert_eq!(
        TweezerParams::from_config(&def.tweezer).profile,
        TrapProfile::Linear
    );
    let text = def.to_toml_string().unwrap();
    assert!(
        !text.contains("profile") && !text.contains("waist_m"),
        "{text}"
    );
    assert!(cfg.to_toml_string().unwrap().contains("waist_m"));

    let err = |extra: &str| RigConfig::from_toml_str(&with(extra), "bad.toml").unwrap_err();
    let line_of =
        |text: &str, key: &str| text.lines().position(|l| l.starts_with(key)).unwrap() + 1;
    for (extra, key, words) in [
        (
            "escape_distance_m = 1.5e-6\nprofile = \"gaussian\"\n",
            "profile",
            "waist_m",
        ),
        (
            "escape_distance_m = 1.5e-6\nprofile = \"gaussian\"\nwaist_m = -0.5e-6\n",
            "waist_m",
            "within",
        ),
        (
            "escape_distance_m = 1.5e-6\nprofile = \"gaussian\"\nwaist_m = 1.0\n",
            "waist_m",
            "within",
        ),
        (
            "escape_distance_m = 1.5e-6\nprofile = \"gaussian\"\nwaist_m = nan\n",
            "waist_m",
            "finite",
        ),
        (
            "escape_distance_m = 1.5e-6\nwaist_m = 0.5e-6\n",
            "waist_m",
            "gaussian",
        ),
    ] {
        match err(extra) {
            RigError::Config {
                origin,
                line,
                field,
                message,
                ..
            } => {
                assert_eq!(origin, "bad.toml");
                assert_eq!(field, format!("tweezer.{key}"));
                assert_eq!(line, Some(line_of(&with(extra), key)), "{message}");
                assert!(message.contains(words), "{message}");
            }
            e => panic!("{e}"),
        }
    }
    // An unknown profile is a parse error at its line.
    match err("escape_distance_m = 1.5e-6\nprofile = \"parabolic\"\n") {
        RigError::Config { line, .. } => {
            assert_eq!(
                line,
                Some(line_of(
                    &with("escape_distance_m = 1.5e-6\nprofile = \"parabolic\"\n"),
                    "profile"
                ))
            )
        }
        e => panic!("{e}"),
    }
    // The parameters refuse a bad waist too (configurations built in code).
    for w in [0.0, -1e-6, f64::NAN, 1.0, 1e-9] {
        assert!(SimTweezer::new(gaussian(w, 2e-5, 0), 1e4).is_err(), "{w}");
    }
}
