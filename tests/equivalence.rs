//! The one equivalence harness: every fast path of the workspace against the
//! readable reference it must equal, driven by the same inputs and compared
//! output by output — bit for bit where the fast path promises it, within a
//! stated tolerance where it computes the same map another way.
//!
//! | pair | fast | reference | comparison |
//! |---|---|---|---|
//! | rounding | `round_half_away` | `f64::round` | bits |
//! | accelerometer | `Accelerometer::sample` | `sample_reference` (general path) | bits |
//! | safety layer | `SafetyLayer::apply` | `apply_reference` (general velocity and limiting) | bits |
//! | tweezer, free space | `Tweezer::step` | `SimTweezer::step_reference` | bits |
//! | tweezer, near an obstacle | `Tweezer::step` (tabulated coefficients) | `step_reference` (exact) | 1e-15 m |
//! | tweezer, next to an obstacle (scene fidelity) | `Tweezer::step` with `set_contact_exact` (one exact OU step per sample) | `Tweezer::step` (sub-steps) | distributions: mean and SD of the gap, mean optical force and angular progress within 4 standard errors (batch means) |
//! | plant, outputs on demand | `DualStagePlant::step_fast` + `tip_m` | `step` | bits |
//! | plant, modal form | modal ZOH update | dense ZOH update (`force_dense`) | 2e-9 of full scale |
//! | simulated rig | `SimRig::process_frame` | one-frame `process_block` | bits |
//! | signal chain | `Chain::new` (packed kernels, every stage count) | `Chain::new_reference` (plain TDF-II, the operations of `Sos`) | 1e-10 of the peak output; reference vs `Sos` and `process`/`stream`/`process_block` bits |
//!
//! Each pair's inputs cover the fast path and every way out of it (limits,
//! non-finite values, state changes), and the pair checks that the fast path
//! was taken often enough for the comparison to mean something.

use kilotouch_dsp::chain::{Chain, ChainCoefficients, MAX_STAGES};
use kilotouch_dsp::filter::{BiquadCoeffs, Sos};
use kilotouch_rig::accel::Accelerometer;
use kilotouch_rig::device::{ActuatorFrame, Rig, SensorFrame};
use kilotouch_rig::plant::PlantInput;
use kilotouch_rig::safety::{SafetyLayer, SafetyState};
use kilotouch_rig::sim::SimRig;
use kilotouch_rig::tweezer::{Obstacle, SimTweezer, Tweezer, TweezerParams, TweezerSample};
use kilotouch_rig::{DualStagePlant, Integrator, RigConfig};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use std::collections::BTreeSet;
use std::f64::consts::PI;

/// How a pair's outputs must agree.
#[derive(Debug, Clone, Copy)]
enum Tol {
    /// Bit for bit (NaN equal to NaN).
    Bits,
    /// |fast − reference| ≤ abs + rel·|reference| per output.
    Close { rel: f64, abs: f64 },
}

/// Run one pair: `fast` and `reference` each own their state and map the
/// same input to a vector of outputs; panics with the pair, the sample and
/// the output on the first disagreement. Returns the largest deviation.
fn check<I>(
    name: &str,
    tol: Tol,
    inputs: &[I],
    mut fast: impl FnMut(&I) -> Vec<f64>,
    mut reference: impl FnMut(&I) -> Vec<f64>,
) -> f64 {
    let mut worst: f64 = 0.0;
    for (k, i) in inputs.iter().enumerate() {
        let (a, b) = (fast(i), reference(i));
        assert_eq!(a.len(), b.len(), "{name}: output count");
        for (j, (x, y)) in a.iter().zip(&b).enumerate() {
            let same = match tol {
                Tol::Bits => x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()),
                Tol::Close { rel, abs } => {
                    (x.is_nan() && y.is_nan()) || (x - y).abs() <= abs + rel * y.abs()
                }
            };
            assert!(
                same,
                "{name}: sample {k}, output {j}: fast {x:e} vs reference {y:e}"
            );
            if x.is_finite() && y.is_finite() {
                worst = worst.max((x - y).abs());
            }
        }
    }
    worst
}

/// A deterministic stream of uniform numbers in [0, 1) (xorshift64).
struct Uniform(u64);

impl Uniform {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn bits(&mut self) -> u64 {
        self.next();
        self.0
    }
}

fn b(x: bool) -> f64 {
    f64::from(u8::from(x))
}

#[test]
fn rounding() {
    let mut u = Uniform(0x9E37_79B9_7F4A_7C15);
    let mut inputs = vec![
        0.0,
        -0.0,
        0.5,
        -0.5,
        2.5,
        -2.5,
        0.49999999999999994,
        4503599627370495.5,
        4503599627370496.0,
        1e300,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NAN,
        f64::MIN_POSITIVE,
        5e-324,
    ];
    for _ in 0..200_000 {
        let x = u.next() - 0.5;
        inputs.push(x * 10_000.0);
        inputs.push((x * 8192.0).round() + 0.5);
        inputs.push((x * 1e15).round() + 0.5);
        inputs.push(f64::from_bits(u.bits()));
    }
    check(
        "rounding",
        Tol::Bits,
        &inputs,
        |&x| vec![kilotouch_rig::round_half_away(x)],
        |&x| vec![x.round()],
    );
}

#[test]
fn accelerometer() {
    let cfg = RigConfig::default().accelerometer;
    let mut fast = Accelerometer::new(&cfg, 10_000.0).expect("accelerometer");
    let mut reference = fast.clone();
    assert!(
        fast.has_fast_path(),
        "the default sensor takes the fast path"
    );
    let range = fast.range_m_s2();
    let mut u = Uniform(0x2545_F491_4F6C_DD1D);
    let inputs: Vec<[f64; 3]> = (0..200_000)
        .map(|k| {
            let x = u.next() - 0.5;
            // Mostly in range, bursts beyond it (clipping), some NaN/∞.
            let mut a = match (k / 1000) % 8 {
                3 => [2.0 * range * (1.0 + 0.1 * x), -0.5 * range * x, 0.0],
                6 => [0.5 * range * x, -3.0 * range * (1.0 + x), 0.0],
                _ => [range * x, -0.7 * range * x, 0.0],
            };
            if k % 9973 == 0 {
                a[k % 2] = if k % 3 == 0 { f64::NAN } else { f64::INFINITY };
            }
            a
        })
        .collect();
    let out = |r: kilotouch_rig::accel::AccelReading, a: &Accelerometer| {
        let mut v = r.m_s2.to_vec();
        v.extend([
            b(r.clipped),
            a.clipped_samples() as f64,
            a.nonfinite_inputs() as f64,
        ]);
        v
    };
    let mut in_range = 0usize;
    check(
        "accelerometer",
        Tol::Bits,
        &inputs,
        |x| {
            let r = fast.sample(*x);
            in_range += usize::from(!r.clipped);
            out(r, &fast)
        },
        |x| {
            let r = reference.sample_reference(*x);
            out(r, &reference)
        },
    );
    assert!(in_range > 100_000, "fast path taken {in_range} times");
}

/// One sample of the safety layer's input, and an event applied before it.
#[derive(Debug, Clone, Copy)]
struct SafetyInput {
    cmd: ActuatorFrame,
    handle_m: [f64; 2],
    missed: bool,
    /// 0 none, 1 emergency stop, 2 reset and re-arm.
    event: u8,
}

#[test]
fn safety_layer() {
    let cfg = RigConfig::default();
    let mut u = Uniform(0x1234_5678_9ABC_DEF1);
    let mut handle = [0.0f64; 2];
    let inputs: Vec<SafetyInput> = (0..300_000)
        .map(|k| {
            let phase = (k / 5000) % 10;
            // Slow handle motion, occasional jumps and NaN positions.
            for h in &mut handle {
                *h += 2e-6 * (u.next() - 0.5);
            }
            let mut h = handle;
            if k % 7919 == 0 {
                h[0] += 0.05;
            }
            if k % 10_007 == 0 {
                h[1] = f64::NAN;
            }
            let scale = match phase {
                0 => 0.01,
                3 => 8.0,
                5 => 0.5,
                _ => 0.3,
            };
            let mut cmd = ActuatorFrame {
                force_n: [scale * (u.next() - 0.5), scale * (u.next() - 0.5)],
                haptuator_v: 4.0 * (u.next() - 0.5),
            };
            if k % 12_007 == 0 {
                cmd.force_n[0] = f64::NAN;
            }
            // An emergency stop now and then; a reset and re-arm every
            // 5000 samples clears it and any trip alike in both layers.
            let event = match (k % 50_000, k % 5000) {
                (40_000, _) => 1,
                (_, 4000) => 2,
                _ => 0,
            };
            SafetyInput {
                cmd,
                handle_m: h,
                missed: k % 997 == 0 || (phase == 7 && k % 3 == 0),
                event,
            }
        })
        .collect();
    let make = || {
        let mut s = SafetyLayer::from_config(&cfg).expect("safety layer");
        s.arm().expect("arm");
        s
    };
    let (mut fast, mut reference) = (make(), make());
    let step = |s: &mut SafetyLayer, i: &SafetyInput, general: bool| {
        match i.event {
            1 => s.estop(),
            2 => {
                s.reset();
                s.arm().expect("arm after reset");
            }
            _ => {}
        }
        let sensors = SensorFrame {
            handle_m: i.handle_m,
            ..SensorFrame::default()
        };
        let o = if general {
            s.apply_reference(i.cmd, &sensors, i.missed)
        } else {
            s.apply(i.cmd, &sensors, i.missed)
        };
        let st = s.status();
        let c = st.counters;
        vec![
            o.force_n[0],
            o.force_n[1],
            o.haptuator_v,
            st.gain,
            st.state as u8 as f64,
            st.handle_speed_m_s.unwrap_or(-1.0),
            c.limited as f64,
            c.slew_limited as f64,
            c.nonfinite_commands as f64,
            c.nonfinite_sensors as f64,
            c.missed_deadlines as f64,
            c.faults as f64,
            c.latched_zeroed as f64,
        ]
    };
    let mut enabled = 0usize;
    check(
        "safety layer",
        Tol::Bits,
        &inputs,
        |i| {
            let v = step(&mut fast, i, false);
            enabled += usize::from(fast.state() == SafetyState::Enabled);
            v
        },
        |i| step(&mut reference, i, true),
    );
    assert!(enabled > 50_000, "forces on for {enabled} samples");
}

/// Batch means of a series: (mean, standard error of the mean) from
/// `batches` equal batches (the samples are correlated over a few
/// relaxation times; the batches are far longer).
fn batch_mean(x: &[f64], batches: usize) -> (f64, f64) {
    let n = x.len() / batches;
    let means: Vec<f64> = x
        .chunks_exact(n)
        .map(|c| c.iter().sum::<f64>() / n as f64)
        .collect();
    let m = means.iter().sum::<f64>() / means.len() as f64;
    let var = means.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (means.len() - 1) as f64;
    (m, (var / means.len() as f64).sqrt())
}

/// Statistics of a run next to the obstacle: per sample the gap (m), the
/// optical force's magnitude (N), the squared deviation of the gap from
/// `gap_ref` (m²) and the bead's polar angle increment (rad).
fn contact_run(
    exact: bool,
    seed: u64,
    scene: &dyn Fn(usize) -> [f64; 2],
    n: usize,
) -> (Vec<[f64; 4]>, u64) {
    let p = TweezerParams {
        seed,
        obstacles: vec![Obstacle {
            centre_m: [0.0, 0.0],
            radius_m: 5e-6,
        }],
        ..TweezerParams::paper_default()
    };
    let mut t = SimTweezer::new(p, 1e4).expect("tweezer");
    t.set_contact_exact(exact);
    t.reset(scene(0));
    let mut out = Vec::with_capacity(n);
    let mut angle = t.bead()[1].atan2(t.bead()[0]);
    for k in 1..=n {
        let s = t.step(scene(k));
        let a = s.bead_m[1].atan2(s.bead_m[0]);
        let mut d = a - angle;
        if d > PI {
            d -= 2.0 * PI;
        } else if d < -PI {
            d += 2.0 * PI;
        }
        angle = a;
        out.push([
            s.gap_m,
            s.force_n[0].hypot(s.force_n[1]),
            s.gap_m * s.gap_m,
            d,
        ]);
    }
    (out, t.contact_exact_steps())
}

/// A named trap trajectory (sample → trap position, m) and its tolerance.
type Scene<'a> = (&'a str, &'a dyn Fn(usize) -> [f64; 2], f64);

/// The exact full-sample step next to an obstacle (scene fidelity) against
/// the sub-stepped general path: the two integrate the same SDE (the trap,
/// the contact spring, the clamped wall drag), so their distributions must
/// agree — not their noise sequences. Two scenes: the circling task's
/// (trap pressed 0.4 µm into the obstacle's contact circle, going round it
/// at 3 µm/s: the bead in the contact zone) and a trap held at a 60 nm gap
/// (the bead in the drag clamp, touching now and then). Means over 300 000
/// samples (30 s) per path, standard errors from 60 batch means; the fast
/// path must agree within 4 combined standard errors (plus 0.1 nm or 0.05 pN
/// of round-off and binning slack) and must carry most samples.
#[test]
fn tweezer_contact_exact_step() {
    let rc = 1.5e-6 + 5e-6;
    let n = 300_000;
    let circling = move |k: usize| {
        let r = rc - 0.4e-6;
        let a = 3e-6 / r * k as f64 * 1e-4;
        [r * a.cos(), r * a.sin()]
    };
    let held = move |_k: usize| [rc + 60e-9, 0.0];
    let scenes: [Scene<'_>; 2] = [("circling", &circling, 0.9), ("held at 60 nm", &held, 0.5)];
    for (name, scene, min_share) in scenes {
        let (fast, steps) = contact_run(true, 5, scene, n);
        let (reference, ref_steps) = contact_run(false, 6, scene, n);
        assert_eq!(ref_steps, 0, "{name}: the reference took the fast step");
        assert!(
            steps as f64 > min_share * n as f64,
            "{name}: exact contact step on {steps} of {n} samples"
        );
        let col = |v: &[[f64; 4]], j: usize| v.iter().map(|r| r[j]).collect::<Vec<f64>>();
        for (j, what, slack) in [
            (0, "gap (m)", 1e-10),
            (1, "optical force (N)", 5e-14),
            (2, "gap² (m²)", 1e-17),
            (3, "angle step (rad)", 1e-12),
        ] {
            let (mf, sf) = batch_mean(&col(&fast, j), 60);
            let (mr, sr) = batch_mean(&col(&reference, j), 60);
            let tol = 4.0 * sf.hypot(sr) + slack;
            assert!(
                (mf - mr).abs() <= tol,
                "{name}, {what}: exact step {mf:e} ± {sf:e}, sub-steps {mr:e} ± {sr:e}"
            );
        }
    }
}

/// Tweezer outputs compared: bead, optical force, gap, flags.
fn tweezer_out(s: TweezerSample) -> Vec<f64> {
    vec![
        s.bead_m[0],
        s.bead_m[1],
        s.force_n[0],
        s.force_n[1],
        s.gap_m,
        b(s.trapped),
        b(s.in_contact),
        b(s.events.escaped),
        b(s.events.contact_start),
    ]
}

#[test]
fn tweezer_free_space() {
    let p = TweezerParams {
        seed: 11,
        ..TweezerParams::paper_default()
    };
    let mut fast = SimTweezer::new(p.clone(), 1e4).expect("tweezer");
    let mut reference = SimTweezer::new(p, 1e4).expect("tweezer");
    let mut u = Uniform(77);
    let mut t = [0.0f64; 2];
    let inputs: Vec<[f64; 2]> = (0..200_000)
        .map(|k| {
            t[0] += 2e-9 * (u.next() - 0.5);
            t[1] += 2e-9 * (u.next() - 0.5);
            let mut x = t;
            if k % 50_000 == 49_999 {
                // A jump beyond the escape distance: lost, then recaptured.
                x[0] += 5e-6;
            }
            if k % 33_331 == 0 {
                x[1] = f64::NAN;
            }
            x
        })
        .collect();
    check(
        "tweezer, free space",
        Tol::Bits,
        &inputs,
        |x| tweezer_out(fast.step(*x)),
        |x| tweezer_out(reference.step_reference(*x)),
    );
}

#[test]
fn tweezer_near_an_obstacle() {
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
    let mut fast = SimTweezer::new(p.clone(), 1e4).expect("tweezer");
    let mut reference = SimTweezer::new(p, 1e4).expect("tweezer");
    // The reference: the general path with the exact coefficients.
    reference.set_drag_table(false);
    // Trap between x = −1 µm and 1.2 µm: surface gaps 0.3 … 2.5 µm, the
    // tabulated path's range.
    let inputs: Vec<[f64; 2]> = (0..40_000)
        .map(|k| [0.1e-6 + 1.1e-6 * (k as f64 * 2e-4).sin(), 0.2e-6])
        .collect();
    let mut near = 0usize;
    // The table reproduces the exact coefficients to ≈ 1e-12 relative; over
    // the run the bead positions stay within 1e-15 m (a millionth of the
    // thermal spread), forces within κ·1e-15 m.
    let worst = check(
        "tweezer, near an obstacle",
        Tol::Close {
            rel: 0.0,
            abs: 1e-15,
        },
        &inputs,
        |x| {
            let s = fast.step(*x);
            near += usize::from(s.gap_m < 1e-6);
            tweezer_out(s)
        },
        |x| tweezer_out(reference.step_reference(*x)),
    );
    assert!(
        near > 5_000,
        "the bead must spend time near the obstacle: {near}"
    );
    assert!(worst > 0.0, "not vacuous: the two paths round differently");
}

/// The plant's outputs in one vector: tip acceleration (x, y), motor
/// position (x, y), Haptuator stroke, tip position (x, y).
fn outputs(accel: [f64; 2], motor: [f64; 2], stroke: f64, tip: [f64; 2]) -> Vec<f64> {
    vec![
        accel[0], accel[1], motor[0], motor[1], stroke, tip[0], tip[1],
    ]
}

fn plant_inputs(vmax: f64) -> Vec<PlantInput> {
    (0..40_000)
        .map(|k| {
            let w = 2.0 * std::f64::consts::PI * k as f64 * 1e-4;
            let mut i = PlantInput {
                force_n: [0.8 * (37.0 * w).sin(), 0.5 * (23.0 * w).cos()],
                drive_v: vmax * (55.0 * w).sin(),
                hand_m: [1e-3 * (3.0 * w).sin(), 0.0],
                hand_vel_m_s: [6e-3 * std::f64::consts::PI * (3.0 * w).cos(), 0.0],
            };
            if k % 997 == 5 {
                i.force_n[k % 2] = f64::NAN;
                i.drive_v = f64::INFINITY;
            }
            i
        })
        .collect()
}

#[test]
fn plant_outputs_on_demand() {
    let cfg = RigConfig::default();
    let mut fast = DualStagePlant::new(&cfg, Integrator::Zoh).expect("plant");
    let mut reference = fast.clone();
    check(
        "plant, outputs on demand",
        Tol::Bits,
        &plant_inputs(cfg.limits.haptuator_drive_max_v),
        |i| {
            let o = fast.step_fast(i);
            outputs(o.accel_m_s2, o.motor_m, o.stroke_m, fast.tip_m())
        },
        |i| {
            let o = reference.step(i);
            outputs(o.accel_m_s2, o.motor_m, o.stroke_m, o.tip_m)
        },
    );
    assert!(fast.x.end_stop_steps() > 100, "end-stop episodes exercised");
}

/// Largest deviation of the modal form from the dense one, as a fraction of
/// full scale (measured: 3.8e-10 on this run).
const FULL_SCALE_TOL: f64 = 2e-9;

#[test]
fn plant_modal_form() {
    let cfg = RigConfig::default();
    let mut fast = DualStagePlant::new(&cfg, Integrator::Zoh).expect("plant");
    let mut reference = fast.clone();
    assert!(fast.x.is_modal() && fast.y.is_modal());
    reference.x.force_dense();
    reference.y.force_dense();
    // The same exact ZOH map in a modal basis: only the round-off differs.
    // Each output is divided by its scale in this run (accelerations reach
    // ≈ 50 m/s², motor positions ≈ 1 mm, the stroke ≈ 1 mm), so the
    // tolerance is relative to full scale.
    let scaled = |o: kilotouch_rig::plant::PlantOutput| {
        vec![
            o.accel_m_s2[0] / 50.0,
            o.accel_m_s2[1] / 50.0,
            o.motor_m[0] / 1e-3,
            o.motor_m[1] / 1e-3,
            o.stroke_m / 1e-3,
        ]
    };
    let worst = check(
        "plant, modal form",
        Tol::Close {
            rel: 0.0,
            abs: FULL_SCALE_TOL,
        },
        &plant_inputs(cfg.limits.haptuator_drive_max_v),
        |i| scaled(fast.step(i)),
        |i| scaled(reference.step(i)),
    );
    eprintln!("plant, modal form: largest deviation {worst:e} of full scale");
    assert!(worst > 0.0, "not vacuous: the two forms round differently");
}

/// Random commands (±1.5 N, ±1.5 V) with a sinusoidal hand, a NaN force
/// every 4 999 samples and an over-limit one every 3 001.
fn rig_inputs(seed: u64, n: usize) -> Vec<(ActuatorFrame, [f64; 2])> {
    let mut u = Uniform(seed);
    (0..n)
        .map(|k| {
            let mut c = ActuatorFrame {
                force_n: [3.0 * (u.next() - 0.5), 3.0 * (u.next() - 0.5)],
                haptuator_v: 3.0 * (u.next() - 0.5),
            };
            if k % 4999 == 0 {
                c.force_n[1] = f64::NAN;
            }
            if k % 3001 == 0 {
                c.force_n[0] = 9.0;
            }
            (c, [1e-3 * (k as f64 * 1e-3).sin(), 0.0])
        })
        .collect()
}

/// What a simulated rig's frame and counters show.
fn rig_outputs(s: SensorFrame, r: &SimRig) -> Vec<f64> {
    let st = r.status();
    vec![
        s.seq as f64,
        s.handle_m[0],
        s.handle_m[1],
        s.accel_m_s2[0],
        s.accel_m_s2[1],
        s.accel_m_s2[2],
        f64::from(s.flags.0),
        st.frames as f64,
        st.limited_frames as f64,
        st.nonfinite_commands as f64,
    ]
}

#[test]
fn simulated_rig_frame_path() {
    let cfg = RigConfig::default();
    let mut fast = SimRig::new(&cfg).expect("rig");
    let mut reference = SimRig::new(&cfg).expect("rig");
    fast.start().expect("start");
    reference.start().expect("start");
    let inputs = rig_inputs(5, 100_000);
    check(
        "simulated rig, frame path",
        Tol::Bits,
        &inputs,
        |(c, h)| {
            fast.set_hand(*h);
            let mut s = SensorFrame::default();
            fast.process_frame(c, &mut s).expect("frame");
            rig_outputs(s, &fast)
        },
        |(c, h)| {
            reference.set_hand(*h);
            let mut s = [SensorFrame::default()];
            reference
                .process_block(std::slice::from_ref(c), &mut s)
                .expect("block");
            rig_outputs(s[0], &reference)
        },
    );
    while let Some(f) = fast.pop_fault() {
        assert_eq!(Some(f), reference.pop_fault());
    }
}

/// A rig rebuilt from a used one ([`SimRig::rebuilt`], what a study does
/// per trial) equals a newly constructed rig with the same accelerometer
/// seed, bit for bit.
#[test]
fn simulated_rig_rebuilt() {
    let mut cfg = RigConfig::default();
    let mut used = SimRig::new(&cfg).expect("rig");
    used.start().expect("start");
    used.set_accelerometer_rendering(false);
    for k in 0..1000 {
        used.set_hand([1e-4 * f64::from(k), 0.0]);
        let c = ActuatorFrame {
            force_n: [0.5, -0.5],
            haptuator_v: 9.0,
        };
        used.process_frame(&c, &mut SensorFrame::default())
            .expect("frame");
    }
    cfg.accelerometer.seed = 0xfeed;
    let mut fast = used.rebuilt(0xfeed);
    let mut reference = SimRig::new(&cfg).expect("rig");
    fast.start().expect("start");
    reference.start().expect("start");
    let inputs = rig_inputs(7, 20_000);
    let step = |r: &mut SimRig, (c, h): &(ActuatorFrame, [f64; 2])| {
        r.set_hand(*h);
        let mut s = SensorFrame::default();
        r.process_frame(c, &mut s).expect("frame");
        rig_outputs(s, r)
    };
    check(
        "simulated rig, rebuilt",
        Tol::Bits,
        &inputs,
        |i| step(&mut fast, i),
        |i| step(&mut reference, i),
    );
}

// ---------------------------------------------------------------------------
// Signal chain: the packed kernels against the reference kernel.
//
// The chain has a fast kernel (two paths packed as lanes, sections
// normalised to b0 = 1, one monomorphised kernel per stage count and
// first-order tail) and a reference kernel (plain TDF-II per lane, the same
// operations as `filter::Sos`). `Chain::new_reference` builds a chain that
// always runs the reference kernel; it is `#[doc(hidden)]` and exists for
// this harness, as does `Chain::fast_kernel_shape`.

/// Largest pole radius of the random sections (stable: < 1).
const R_POLE: f64 = 0.95;
/// Largest zero radius of the random sections (zeros may lie outside the
/// unit circle).
const R_ZERO: f64 = 1.5;
/// Samples per run.
const LEN: usize = 4096;
/// Input scales: every run is repeated at each, from tiny to huge.
const SCALES: [f64; 5] = [1e-150, 1e-5, 1.0, 1e5, 1e150];
/// Largest |fast − reference| allowed, relative to the reference's peak
/// |output| in the same lane and run (see [`signal_chain`]).
const TOL: f64 = 1e-10;

/// Two roots as (sum, product), either a complex pair of radius < `r` or
/// two real roots in (−r, r): the polynomial is 1 − sum z⁻¹ + product z⁻².
fn root_pair(rng: &mut StdRng, r: f64) -> (f64, f64) {
    if rng.random_bool(0.5) {
        let rho = r * rng.random::<f64>().sqrt();
        let theta = PI * rng.random::<f64>();
        (2.0 * rho * theta.cos(), rho * rho)
    } else {
        let p1 = rng.random_range(-r..r);
        let p2 = rng.random_range(-r..r);
        (p1 + p2, p1 * p2)
    }
}

/// A random stable section (poles of radius < [`R_POLE`]), first order
/// (b2 = a2 = 0) when `first`; |b0| log-uniform in [0.1, 3.2], either sign.
fn random_section(rng: &mut StdRng, first: bool) -> BiquadCoeffs {
    let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let g = sign * 10f64.powf(rng.random_range(-1.0..0.5));
    let c = if first {
        let p = rng.random_range(-R_POLE..R_POLE);
        let z = rng.random_range(-R_ZERO..R_ZERO);
        BiquadCoeffs::new([g, -g * z, 0.0], [1.0, -p, 0.0])
    } else {
        let (ps, pp) = root_pair(rng, R_POLE);
        let (zs, zp) = root_pair(rng, R_ZERO);
        BiquadCoeffs::new([g, -g * zs, g * zp], [1.0, -ps, pp])
    };
    let c = c.expect("finite section");
    assert!(c.is_stable(), "{c:?}");
    c
}

/// `n` random sections; each first order with probability 1/3, the last
/// one first order whenever `tail_first_order`.
fn random_path(rng: &mut StdRng, n: usize, tail_first_order: bool) -> Vec<BiquadCoeffs> {
    (0..n)
        .map(|k| {
            let first = (tail_first_order && k + 1 == n) || rng.random_bool(1.0 / 3.0);
            random_section(rng, first)
        })
        .collect()
}

/// `LEN` samples of `scale`·u, u uniform in [−1, 1), with 2 % spikes (×1e3),
/// 2 % dips (×1e-12), 1 % exact zeros and a stretch of silence.
fn random_input(rng: &mut StdRng, scale: f64) -> Vec<f64> {
    (0..LEN)
        .map(|i| {
            if (LEN / 2..LEN / 2 + 200).contains(&i) {
                return 0.0;
            }
            let u: f64 = rng.random_range(-1.0..1.0);
            let kind: f64 = rng.random();
            let v = if kind < 0.02 {
                u * 1e3
            } else if kind < 0.04 {
                u * 1e-12
            } else if kind < 0.05 {
                0.0
            } else {
                u
            };
            scale * v
        })
        .collect()
}

/// Outputs of `chain` through `process`, `stream` and `process_block`
/// (irregular block sizes), each from a fresh clone; asserts the three are
/// bit-identical (the module docs of `chain` promise it) and returns them.
fn run_all_apis(chain: &Chain, x: &[f64]) -> Vec<(f64, f64)> {
    let mut a = chain.clone();
    let per: Vec<(f64, f64)> = x.iter().map(|&v| a.process(v)).collect();
    let mut b = chain.clone();
    let mut st = Vec::with_capacity(x.len());
    b.stream(x.iter().copied(), |l, h| st.push((l, h)));
    let mut c = chain.clone();
    let (mut bl, mut bh) = (vec![0.0; x.len()], vec![0.0; x.len()]);
    let mut start = 0;
    for size in [1, 5, 63, 64, 65, 200, 1000].iter().cycle() {
        if start >= x.len() {
            break;
        }
        let end = (start + size).min(x.len());
        c.process_block(&x[start..end], &mut bl[start..end], &mut bh[start..end]);
        start = end;
    }
    let bits = |(l, h): (f64, f64)| (l.to_bits(), h.to_bits());
    for i in 0..x.len() {
        assert_eq!(bits(per[i]), bits(st[i]), "stream differs at {i}");
        assert_eq!(bits(per[i]), bits((bl[i], bh[i])), "block differs at {i}");
    }
    for ch in [&a, &b, &c] {
        assert_eq!(ch.nonfinite_events(), 0, "no event expected");
    }
    per
}

/// The fast kernel against the reference kernel, over every supported stage
/// count: every (low, high) pair of section counts in 1..=[`MAX_STAGES`],
/// each drawn twice (first-order sections at random, and with the last
/// section of both paths first order, so that all 2·[`MAX_STAGES`] fast
/// kernels, with and without the first-order tail, run), with random stable
/// sections and random inputs at scales from 1e-150 to 1e150.
///
/// Bit-identical, because the code promises it:
/// * `process`, `stream` and `process_block` of one chain, for both kernels;
/// * the reference kernel and two `Sos` cascades of the same sections (same
///   TDF-II operations in the same order, same flush schedule), up to the
///   sign of zero: the reference kernel also runs the identity sections that
///   pad both paths to [`MAX_STAGES`], and 1·(−0) + 0 = +0, so an output
///   that `Sos` gives as −0 comes out as +0 (IEEE 754 equal, so `==`).
///
/// Within [`TOL`] = 1e-10 of the reference's peak |output| per lane and run:
/// the fast kernel. Both evaluate the same linear recursion, but the fast
/// one rounds differently: it divides each section by b0
/// (c1 = b1/b0 − a1, c2 = b2/b0 − a2), carries the state divided by the
/// product of the b0 and applies that product once at the output. Each
/// difference starts as a relative rounding error of at most
/// u = 2⁻⁵³ ≈ 1.1e-16 of one coefficient or one intermediate value, and
/// reaches the output through stable recursions whose gain from an
/// internal node to the output is bounded by the ℓ1 norm of the impulse
/// response from that node; with poles of radius < 0.95 and up to 8
/// sections the worst deviation over these draws is 1.1e-13 of the peak
/// (printed by the test). 1e-10 leaves a factor of ~1000 for other draws
/// and platforms, and is still tight: one feedback coefficient of a
/// first-order tail off by 1e-9 relative already exceeds it (checked by
/// hand while writing this test); a skipped stage or a mis-scaled state
/// errs by far more. The flush to zero of state below 1e-200 acts on
/// differently scaled states in the two kernels; its effect (of the order
/// of 1e-200 absolute) is far below this tolerance at every scale used here.
#[test]
fn signal_chain() {
    let mut rng = StdRng::seed_from_u64(0x6b69_6c6f);
    let mut shapes = BTreeSet::new();
    let mut worst: f64 = 0.0;
    for n_low in 1..=MAX_STAGES {
        for n_high in 1..=MAX_STAGES {
            for tail_first_order in [false, true] {
                let low = random_path(&mut rng, n_low, tail_first_order);
                let high = random_path(&mut rng, n_high, tail_first_order);
                let coeffs = ChainCoefficients::new(10_000.0, low.clone(), high.clone())
                    .expect("stable sections");
                let fast = Chain::new(&coeffs);
                let reference = Chain::new_reference(&coeffs);
                assert!(fast.uses_fast_kernel());
                assert!(!reference.uses_fast_kernel());
                assert_eq!(reference.fast_kernel_shape(), None);
                let shape = fast.fast_kernel_shape().expect("fast kernel");
                assert_eq!(shape.0, n_low.max(n_high));
                if tail_first_order {
                    assert!(shape.1, "first-order tail not detected");
                }
                shapes.insert(shape);
                for scale in SCALES {
                    let x = random_input(&mut rng, scale);
                    let yf = run_all_apis(&fast, &x);
                    let yr = run_all_apis(&reference, &x);
                    let mut lo = Sos::new(low.clone()).expect("low");
                    let mut hi = Sos::new(high.clone()).expect("high");
                    let (mut peak, mut err) = ([0.0f64; 2], [0.0f64; 2]);
                    for (i, (&v, (&f, &r))) in x.iter().zip(yf.iter().zip(&yr)).enumerate() {
                        let s = (lo.process(v), hi.process(v));
                        // `==` on finite values: bit equality, except that
                        // +0 and −0 compare equal (see the doc comment).
                        assert!(
                            r == s,
                            "reference vs Sos, {n_low}/{n_high} sections, scale {scale:e}, \
                             i={i}: {r:?} vs {s:?}"
                        );
                        peak = [peak[0].max(r.0.abs()), peak[1].max(r.1.abs())];
                        err = [err[0].max((f.0 - r.0).abs()), err[1].max((f.1 - r.1).abs())];
                    }
                    for lane in 0..2 {
                        assert!(peak[lane] > 0.0 && peak[lane].is_finite());
                        let rel = err[lane] / peak[lane];
                        worst = worst.max(rel);
                        assert!(
                            rel <= TOL,
                            "{n_low}/{n_high} sections (tail {tail_first_order}), scale \
                             {scale:e}, lane {lane}: |fast − reference| = {rel:e} of the peak"
                        );
                    }
                }
            }
        }
    }
    // Every fast kernel ran: stage counts 1..=MAX_STAGES, with and without
    // the first-order tail.
    let all: BTreeSet<(usize, bool)> = (1..=MAX_STAGES)
        .flat_map(|n| [(n, false), (n, true)])
        .collect();
    assert_eq!(shapes, all);
    eprintln!("worst |fast − reference| / peak: {worst:e}");
}
