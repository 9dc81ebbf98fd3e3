//! Per-trial seed derivation: fixed test vectors (computed by an independent
//! Python implementation of the documented formulas, with the ChaCha20 key
//! stream from the `cryptography` package) and statistical independence.

use std::collections::HashSet;

use kilotouch_study::protocol::Condition;
use kilotouch_study::seeds::{
    Phase, STREAM_PARTICIPANT, STREAM_RIG, STREAM_TASK, SplitMix64, TRIAL_DOMAIN, TrialKey,
    format_seed,
};
use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::{Rng, SeedableRng};

#[test]
fn splitmix64_matches_vignas_reference_outputs() {
    // splitmix64.c with x = 0 and x = 1234567 (published test values).
    let mut g = SplitMix64::new(0);
    assert_eq!(g.next_u64(), 0xe220_a839_7b1d_cdaf);
    assert_eq!(g.next_u64(), 0x6e78_9e6a_a1b9_65f4);
    assert_eq!(g.next_u64(), 0x06c4_5d18_8009_454f);
    let mut g = SplitMix64::new(1_234_567);
    assert_eq!(g.next_u64(), 0x599e_d017_fb08_fc85);
    assert_eq!(g.next_u64(), 0x2c73_f084_5854_0fa5);
    assert_eq!(g.next_u64(), 0x883e_bce5_a3f2_7c77);
}

#[test]
fn rand_chacha_is_the_djb_chacha20_key_stream() {
    // All-zero key and nonce: the first key-stream bytes are
    // 76 b8 e0 ad a0 f1 3d 90 … (RFC 7539 §2.3.2 / djb's test vector).
    let mut rng = ChaCha20Rng::from_seed([0; 32]);
    assert_eq!(rng.next_u64(), 0x903d_f1a0_ade0_b876);
}

#[test]
fn trial_seed_test_vectors() {
    // (study, participant, condition, phase, trial) → seed, from the Python
    // reference. A change here changes every recorded trial.
    let cases = [
        (
            0,
            TrialKey::new(0, Condition::V, Phase::Practice, 1),
            0x1b1a_4b43_30ed_23c2_u64,
        ),
        (
            2016,
            TrialKey::new(0, Condition::V, Phase::Test, 1),
            0x7fd3_4199_86a0_77f5,
        ),
        (
            2016,
            TrialKey::new(7, Condition::D, Phase::Test, 10),
            0xf205_effa_ab4d_1087,
        ),
        (
            2016,
            TrialKey::new(3, Condition::P, Phase::Practice, 2),
            0xfe5e_ee13_1e8f_cdac,
        ),
        (
            (1 << 63) - 1,
            TrialKey::new(u32::MAX, Condition::D, Phase::Test, u32::MAX),
            0xd776_178a_8d10_67a4,
        ),
    ];
    for (study, key, expected) in cases {
        assert_eq!(key.seed(study), expected, "{key} study {study}");
    }
    assert_eq!(
        format_seed(TrialKey::new(0, Condition::V, Phase::Test, 1).seed(2016)),
        "0x7fd3419986a077f5"
    );
}

#[test]
fn trial_generator_test_vectors() {
    let cases = [
        (
            2016,
            TrialKey::new(0, Condition::V, Phase::Test, 1),
            STREAM_TASK,
            [
                0xd98f_ef67_7d63_49af_u64,
                0x3155_7981_fdba_ac14,
                0xeb71_0f10_b2e6_b1c6,
            ],
        ),
        (
            2016,
            TrialKey::new(7, Condition::D, Phase::Test, 10),
            STREAM_RIG,
            [
                0xa097_cb56_2a2b_76a6,
                0xacb7_f841_4de0_3e5a,
                0x350f_0b41_7df3_b238,
            ],
        ),
        (
            0,
            TrialKey::new(0, Condition::V, Phase::Practice, 1),
            0,
            [
                0x92ce_efbb_0121_c65d,
                0x91ef_8ef9_cfa7_107d,
                0x6644_0563_1d92_d02a,
            ],
        ),
    ];
    for (study, key, stream, expected) in cases {
        let mut rng = key.rng(study, stream);
        let got = [rng.next_u64(), rng.next_u64(), rng.next_u64()];
        assert_eq!(got, expected, "{key} stream {stream}");
    }
}

#[test]
fn chacha_key_layout_is_injective_and_disjoint_from_counterbalancing() {
    let key = TrialKey::new(0x0102_0304, Condition::P, Phase::Test, 0x0a0b_0c0d);
    let k = key.chacha_key(0x1122_3344_5566_7788);
    assert_eq!(&k[0..8], &0x1122_3344_5566_7788_u64.to_le_bytes());
    assert_eq!(&k[8..16], &TRIAL_DOMAIN.to_le_bytes());
    assert_eq!(
        &k[8..16],
        b"lairt-tk",
        "tag is ASCII kt-trial read big-endian"
    );
    assert_eq!(&k[16..20], &[4, 3, 2, 1]);
    assert_eq!((k[20], k[21]), (b'P', 1));
    assert_eq!(&k[22..24], &[0, 0]);
    assert_eq!(&k[24..28], &[0x0d, 0x0c, 0x0b, 0x0a]);
    assert_eq!(&k[28..32], &[0; 4]);
    // Counterbalancing keys are seed ‖ 24 zero bytes: never a trial key.
    assert_ne!(&k[8..16], &[0; 8]);

    // Every tuple of a study-sized grid gets its own key and its own seed.
    let mut keys = HashSet::new();
    let mut seeds = HashSet::new();
    for p in 0..40 {
        for c in Condition::ALL {
            for phase in [Phase::Practice, Phase::Test] {
                for t in 1..=50 {
                    let key = TrialKey::new(p, c, phase, t);
                    assert!(keys.insert(key.chacha_key(2016)));
                    assert!(seeds.insert(key.seed(2016)));
                }
            }
        }
    }
    assert_eq!(seeds.len(), 40 * 3 * 2 * 50);
}

#[test]
fn seed_depends_on_every_component_with_full_avalanche() {
    // Changing one component of the tuple flips each output bit with
    // probability 1/2: mean Hamming distance 32, sd 4 per pair, so over
    // n pairs the mean is 32 ± 4/√n. Tolerance 8 standard errors.
    let mut total = 0_u64;
    let mut n = 0_u64;
    let mut add = |a: u64, b: u64| {
        total += u64::from((a ^ b).count_ones());
        n += 1;
    };
    for p in 0..20_u32 {
        for t in 1..=40_u32 {
            for c in Condition::ALL {
                let k = TrialKey::new(p, c, Phase::Test, t);
                let s = k.seed(2016);
                add(s, TrialKey::new(p + 1, c, Phase::Test, t).seed(2016));
                add(s, TrialKey::new(p, c, Phase::Test, t + 1).seed(2016));
                add(s, TrialKey::new(p, c, Phase::Practice, t).seed(2016));
                add(s, k.seed(2017));
            }
            let v = TrialKey::new(p, Condition::V, Phase::Test, t).seed(2016);
            add(v, TrialKey::new(p, Condition::P, Phase::Test, t).seed(2016));
            add(v, TrialKey::new(p, Condition::D, Phase::Test, t).seed(2016));
        }
    }
    let mean = total as f64 / n as f64;
    let se = 4.0 / (n as f64).sqrt();
    assert!(
        (mean - 32.0).abs() < 8.0 * se,
        "mean Hamming distance {mean}, n {n}"
    );
}

/// Uniform in [0, 1) from the top 53 bits.
fn unit(x: u64) -> f64 {
    (x >> 11) as f64 * (1.0 / (1_u64 << 53) as f64)
}

/// Pearson correlation.
fn corr(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let ma = a.iter().sum::<f64>() / n;
    let mb = b.iter().sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    sab / (saa * sbb).sqrt()
}

#[test]
fn neighbouring_trials_and_streams_are_uncorrelated() {
    // First draws of adjacent trials, and of two streams of one trial, over
    // n = 6000 trials: |r| < 5/√n for independent uniforms (5 sd).
    let mut first = Vec::new();
    let mut next_trial = Vec::new();
    let mut other_stream = Vec::new();
    let mut other_participant = Vec::new();
    for p in 0..20 {
        for c in Condition::ALL {
            for t in 1..=100 {
                let k = TrialKey::new(p, c, Phase::Test, t);
                first.push(unit(k.rng(2016, STREAM_RIG).next_u64()));
                next_trial.push(unit(
                    TrialKey::new(p, c, Phase::Test, t + 1)
                        .rng(2016, STREAM_RIG)
                        .next_u64(),
                ));
                other_stream.push(unit(k.rng(2016, STREAM_PARTICIPANT).next_u64()));
                other_participant.push(unit(
                    TrialKey::new(p + 1, c, Phase::Test, t)
                        .rng(2016, STREAM_RIG)
                        .next_u64(),
                ));
            }
        }
    }
    let n = first.len() as f64;
    let bound = 5.0 / n.sqrt();
    for (name, other) in [
        ("next trial", &next_trial),
        ("other stream", &other_stream),
        ("next participant", &other_participant),
    ] {
        let r = corr(&first, other);
        assert!(r.abs() < bound, "{name}: r = {r}, bound {bound}");
    }
    // The draws are uniform: mean 1/2 ± 5·(1/√12)/√n.
    let mean = first.iter().sum::<f64>() / n;
    assert!((mean - 0.5).abs() < 5.0 / (12.0 * n).sqrt(), "mean {mean}");
}

#[test]
fn generators_are_stable_and_history_free() {
    // The same key gives the same sequence whatever ran before, in this or
    // another generator.
    let k = TrialKey::new(2, Condition::D, Phase::Test, 5);
    let reference: Vec<u64> = {
        let mut r = k.rng(9, STREAM_TASK);
        (0..64).map(|_| r.next_u64()).collect()
    };
    for other in 0..5 {
        let mut noise = TrialKey::new(other, Condition::V, Phase::Practice, 1).rng(9, STREAM_TASK);
        for _ in 0..1000 {
            noise.next_u64();
        }
        let mut r = k.rng(9, STREAM_TASK);
        let again: Vec<u64> = (0..64).map(|_| r.next_u64()).collect();
        assert_eq!(again, reference);
    }
    // Different study seeds give different sequences.
    assert_ne!(
        k.rng(9, STREAM_TASK).next_u64(),
        k.rng(10, STREAM_TASK).next_u64()
    );
}
