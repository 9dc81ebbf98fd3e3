//! Tweezer validation against docs/REFERENCE-VALUES.md near walls and
//! obstacles (the Itô drift keeps the Boltzmann distribution, no tunnelling)
//! and the paper's scenes (collision transient, reduced agitation when
//! pressed, escape). Equipartition, the aliased Lorentzian and the
//! Euler–Maruyama bias are checked through `kilotouch sim tweezer`
//! (`crates/app/tests/tweezer_sim.rs`).

#![allow(clippy::unwrap_used)]

use kilotouch_rig::tweezer::*;

fn plane_obstacle() -> Obstacle {
    // A 1 mm sphere is a plane at this scale: surface at x = 0.
    Obstacle {
        centre_m: [-1e-3, 0.0],
        radius_m: 1e-3,
    }
}

/// Mean surface gap from the Boltzmann density p(g) ∝ w(g)·exp(−U(g)/k_BT)
/// on g > 0, U = κ/2 (g − g_t)² + k_c/2 (δ − g)²·[g < δ].
fn boltzmann_mean(p: &TweezerParams, g_t: f64, weight: impl Fn(f64) -> f64) -> f64 {
    let kt = p.kt();
    let (mut s0, mut s1) = (0.0, 0.0);
    let n = 200_000;
    let gmax = g_t + 12.0 * (kt / p.stiffness_n_per_m).sqrt();
    for i in 0..n {
        let g = (i as f64 + 0.5) * gmax / n as f64;
        let mut u = 0.5 * p.stiffness_n_per_m * (g - g_t).powi(2);
        if g < p.contact_range_m {
            u += 0.5 * p.contact_stiffness_n_per_m * (p.contact_range_m - g).powi(2);
        }
        let w = weight(g) * (-u / kt).exp();
        s0 += w;
        s1 += w * g;
    }
    s1 / s0
}

/// Position-dependent drag needs the Itô drift k_BT ∂(1/γ⊥)/∂h: with it the
/// bead near a wall samples the Boltzmann distribution; without it, the
/// density is Boltzmann × γ⊥ (it piles up toward the wall).
#[test]
fn ito_drift_keeps_the_boltzmann_distribution_near_a_wall() {
    let base = TweezerParams {
        stiffness_n_per_m: 1e-6, // 1 pN/µm: σ ≈ 64 nm
        obstacles: vec![plane_obstacle()],
        escape_distance_m: f64::MAX,
        seed: 11,
        ..TweezerParams::paper_default()
    };
    let r = base.radius_m;
    let g_t = 300e-9;
    let trap = [r + g_t, 0.0];
    let fs = 1000.0;
    let n = 300_000;
    let gamma_ratio = |g: f64| {
        let h = r + g.max(DRAG_CLAMP_GAP_OVER_R * r);
        brenner_perpendicular(r / h)
    };
    let expect_on = boltzmann_mean(&base, g_t, |_| 1.0);
    let expect_off = boltzmann_mean(&base, g_t, gamma_ratio);
    assert!(
        expect_on - expect_off > 6e-9,
        "test would not discriminate: {expect_on:e} {expect_off:e}"
    );
    for (ito, expect) in [(true, expect_on), (false, expect_off)] {
        let p = TweezerParams {
            ito_drift: ito,
            ..base.clone()
        };
        let mut t = SimTweezer::new(p, fs).unwrap();
        t.reset(trap);
        let mut sum = 0.0;
        let burn = 20_000;
        for k in 0..n + burn {
            let s = t.step(trap);
            assert!(s.gap_m >= 0.0);
            if k >= burn {
                sum += s.gap_m;
            }
        }
        let mean = sum / n as f64;
        assert!(
            (mean - expect).abs() < 3.5e-9,
            "ito={ito}: mean gap {mean:e} vs {expect:e}"
        );
    }
}

/// No tunnelling: a trap swept straight through an obstacle at high speed
/// never puts the bead inside it; the bead is left behind and escapes.
#[test]
fn no_tunnelling_under_fast_trap_motion() {
    for speed in [1e-3, 1e-2, 5e-2] {
        let p = TweezerParams {
            obstacles: vec![Obstacle {
                centre_m: [5e-6, 0.0],
                radius_m: 5e-6,
            }],
            seed: 3,
            ..TweezerParams::paper_default()
        };
        let fs = 1e4;
        let mut t = SimTweezer::new(p.clone(), fs).unwrap();
        let x0 = -2.5e-6;
        t.reset([x0, 0.0]);
        let mut escaped = false;
        let mut n = 0;
        let mut x = x0;
        while x < 16e-6 {
            x += speed / fs;
            let s = t.step([x, 1e-9]);
            let d = ((s.bead_m[0] - 5e-6).powi(2) + s.bead_m[1].powi(2)).sqrt();
            assert!(
                d >= 5e-6 + p.radius_m - 1e-15,
                "speed {speed}: bead inside obstacle at sample {n}"
            );
            assert!(s.gap_m >= 0.0);
            escaped |= s.events.escaped;
            n += 1;
        }
        assert!(escaped, "speed {speed}: the bead should escape");
        assert!(!t.trapped());
        // Bring the trap back to the bead: recaptured.
        let b = t.bead();
        let s = t.step(b);
        assert!(s.events.recaptured && s.trapped);
    }
}

/// A collision (paper Fig. 9d): approaching an obstacle at constant speed,
/// the optical force along the motion is nearly flat (viscous lag), then its
/// slope jumps to κv within a millisecond of contact (the bead stops).
#[test]
fn collision_produces_a_sharp_force_transient() {
    let fs = 1e4;
    let v = 20e-6; // m/s
    let p0 = TweezerParams {
        obstacles: vec![Obstacle {
            centre_m: [10e-6, 0.0],
            radius_m: 5e-6,
        }],
        ..TweezerParams::paper_default()
    };
    let kappa = p0.stiffness_n_per_m;
    let seeds = 24;
    let win = 40; // samples on each side
    let mut avg = vec![0.0; 2 * win];
    for seed in 0..seeds {
        let mut t = SimTweezer::new(TweezerParams { seed, ..p0.clone() }, fs).unwrap();
        let mut x = 2.5e-6;
        t.reset([x, 0.0]);
        let mut hist = Vec::new();
        let mut contact_at = None;
        for k in 0..20_000 {
            x += v / fs;
            let s = t.step([x, 0.0]);
            hist.push(-s.force_n[0]); // push on the trap toward the obstacle
            if s.events.contact_start && contact_at.is_none() {
                contact_at = Some(k);
            }
            if let Some(c) = contact_at
                && k >= c + win
            {
                break;
            }
        }
        let c = contact_at.expect("contact must happen");
        assert!(c >= win);
        for i in 0..2 * win {
            avg[i] += hist[c - win + i] / seeds as f64;
        }
    }
    let slope = |a: usize, b: usize| (avg[b] - avg[a]) * fs / (b - a) as f64;
    let before = slope(5, win - 5);
    let after = slope(win + 10, 2 * win - 1);
    // Force here is −κ(trap − bead): pushing into the obstacle is negative.
    let kv = kappa * v;
    assert!(
        before.abs() < 0.3 * kv,
        "before contact slope {before:e} vs κv {kv:e}"
    );
    assert!(
        (-after / kv - 1.0).abs() < 0.25,
        "after contact slope {after:e} vs κv {kv:e}"
    );
}

/// Pressing against an obstacle (Fig. 9f–g): the force fluctuations along the
/// normal collapse (the contact stiffness adds to κ) and the high-frequency
/// tangential agitation drops (larger drag near the surface).
#[test]
fn pressing_reduces_the_agitation() {
    let fs = 1e4;
    let obstacle = Obstacle {
        centre_m: [10e-6, 0.0],
        radius_m: 5e-6,
    };
    let p = TweezerParams {
        obstacles: vec![obstacle],
        seed: 5,
        ..TweezerParams::paper_default()
    };
    let contact_x = 10e-6 - 5e-6 - p.radius_m;
    let run = |trap: [f64; 2]| {
        let mut t = SimTweezer::new(p.clone(), fs).unwrap();
        t.reset(trap);
        let mut fx = Vec::new();
        let mut fy = Vec::new();
        for k in 0..60_000 {
            let s = t.step(trap);
            assert!(s.trapped);
            if k > 5_000 {
                fx.push(s.force_n[0]);
                fy.push(s.force_n[1]);
            }
        }
        let var = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64
        };
        let dvar = |v: &[f64]| var(&v.windows(2).map(|w| w[1] - w[0]).collect::<Vec<_>>());
        (var(&fx), dvar(&fy))
    };
    let (free_n, free_t) = run([-5e-6, 0.0]);
    let (pressed_n, pressed_t) = run([contact_x + 0.5e-6, 0.0]);
    // Free: var F = κ k_BT.
    assert!((free_n / (p.stiffness_n_per_m * p.kt()) - 1.0).abs() < 0.1);
    // Pressed: κ² k_BT/(κ + k_c) along the normal.
    let expect =
        p.stiffness_n_per_m.powi(2) * p.kt() / (p.stiffness_n_per_m + p.contact_stiffness_n_per_m);
    assert!(pressed_n < 0.05 * free_n, "{pressed_n:e} vs {free_n:e}");
    assert!(pressed_n < 3.0 * expect, "{pressed_n:e} vs {expect:e}");
    assert!(
        pressed_t < 0.7 * free_t,
        "tangential increments {pressed_t:e} vs {free_t:e}"
    );
}

/// Pulling the trap away faster than the bead can follow loses it (the
/// participant "pushes too hard").
#[test]
fn pulling_too_fast_makes_the_bead_escape() {
    let mut t = SimTweezer::new(TweezerParams::paper_default(), 1e4).unwrap();
    t.reset([0.0, 0.0]);
    let mut escaped_at = None;
    for k in 0..100 {
        let s = t.step([k as f64 * 2e-7, 0.0]); // 2 mm/s: lag γv/κ ≈ 2.8 µm > R
        if s.events.escaped {
            escaped_at = Some(k);
            assert_eq!(s.force_n, [0.0, 0.0]);
            break;
        }
    }
    assert!(escaped_at.is_some());
    // Slow motion keeps it (lag 28 nm).
    let mut t = SimTweezer::new(TweezerParams::paper_default(), 1e4).unwrap();
    for k in 0..10_000 {
        let s = t.step([k as f64 * 2e-10, 0.0]);
        assert!(s.trapped && !s.events.escaped);
    }
}
