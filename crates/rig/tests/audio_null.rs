//! Audio-interface rig and monitor against ALSA's `null` PCM ("Discard all
//! samples (playback) or generate zero samples (capture)"), which exists
//! without a sound card. `cargo test -p kilotouch-rig --features audio`.
//!
//! The null PCM has no clock: it consumes and produces samples as fast as
//! the callbacks run. The rig's wall-clock pacing makes the exchanged frames
//! advance at the device's nominal rate; with device pacing they advance at
//! least that fast.

#![cfg(feature = "audio")]
#![allow(clippy::unwrap_used)]

use kilotouch_rig::audio::*;
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::device::{ActuatorFrame, FrameFlags, Rig, RigFault, RigKind, SensorFrame};
use std::time::{Duration, Instant};

fn null_cfg(pacing: AudioPacing) -> AudioRigConfig {
    let mut c = AudioRigConfig::new(Some("null"), &RigConfig::default());
    c.pacing = pacing;
    c.latency_frames = 960;
    c.ring_frames = 4800;
    c
}

#[test]
fn null_device_is_listed_with_both_directions() {
    let list = list_audio_devices().unwrap();
    let null = list.iter().find(|d| d.id == "null").expect("ALSA null PCM");
    let out = null.output.as_ref().unwrap();
    let inp = null.input.as_ref().unwrap();
    for d in [out, inp] {
        assert!(d.default_channels >= 1 && d.max_channels >= d.default_channels);
        assert!(d.min_rate_hz <= d.default_rate_hz && d.default_rate_hz <= d.max_rate_hz);
        assert_eq!(d.default_format, "f32");
    }
    assert!(null.name.contains("Discard all samples"), "{}", null.name);
}

#[test]
fn unknown_device_and_bad_settings_are_errors() {
    let mut c = null_cfg(AudioPacing::Device);
    c.device = Some("no-such-device".into());
    let e = AudioRig::open(&c).unwrap_err().to_string();
    assert!(e.contains("not found") && e.contains("null"), "{e}");
    let mut c = null_cfg(AudioPacing::Device);
    c.latency_frames = c.ring_frames;
    assert!(AudioRig::open(&c).is_err());
    let mut c = null_cfg(AudioPacing::Device);
    c.pantograph_channels = Some([0, 1]); // 0 is the Haptuator
    assert!(AudioRig::open(&c).is_err());
    let mut c = null_cfg(AudioPacing::Device);
    c.haptuator_full_scale_v = f64::NAN;
    assert!(AudioRig::open(&c).is_err());
}

/// One second of 480-frame blocks with wall-clock pacing: frames advance at
/// the device rate within 10 %, every command beyond the limits is clamped
/// (and counted), non-finite commands are zeroed, the null capture reads 0,
/// the callbacks ran and their counters add up.
#[test]
fn null_device_streams_at_the_device_rate_with_limited_outputs() {
    let mut c = null_cfg(AudioPacing::WallClock);
    c.pantograph_channels = Some([1, 2]);
    c.output_channels = None;
    let mut rig = AudioRig::open(&c).unwrap();
    let id = rig.identity().clone();
    assert_eq!(id.kind, RigKind::Audio);
    let fs = id.sample_rate_hz;
    assert_eq!(fs, rig.output_config().sample_rate as f64);
    assert!(rig.output_config().channels >= 3);
    assert!(!rig.handle_available());
    rig.start().unwrap();
    let n = 480;
    let mut cmds = vec![ActuatorFrame::default(); n];
    let mut sens = vec![SensorFrame::default(); n];
    let (mut frames, mut expect_limited, mut expect_nonfinite) = (0u64, 0u64, 0u64);
    let t0 = Instant::now();
    let mut next_seq = 0;
    while t0.elapsed() < Duration::from_secs(1) {
        for (k, cmd) in cmds.iter_mut().enumerate() {
            let i = frames as usize + k;
            *cmd = match i % 7 {
                0 => ActuatorFrame {
                    force_n: [1e9, -3.0],
                    haptuator_v: 0.5,
                },
                1 => ActuatorFrame {
                    force_n: [0.1, 0.2],
                    haptuator_v: -1e6,
                },
                2 => ActuatorFrame {
                    force_n: [f64::NAN, 0.0],
                    haptuator_v: 0.0,
                },
                _ => ActuatorFrame {
                    force_n: [0.01 * k as f64 / n as f64, 0.0],
                    haptuator_v: 1.0,
                },
            };
            match i % 7 {
                0 | 1 => expect_limited += 1,
                2 => expect_nonfinite += 1,
                _ => {}
            }
        }
        let r = rig.process_block(&cmds, &mut sens).unwrap();
        assert_eq!((r.first_seq, r.frames), (next_seq, n));
        for (k, s) in sens.iter().enumerate() {
            assert_eq!(s.seq, next_seq + k as u64);
            assert_eq!(s.handle_m, [0.0, 0.0]);
            assert_eq!(s.accel_m_s2, [0.0, 0.0, 0.0], "null capture is silent");
            let i = frames as usize + k;
            assert_eq!(s.flags.has(FrameFlags::LIMITED), i % 7 < 2);
            assert_eq!(s.flags.has(FrameFlags::NONFINITE_COMMAND), i % 7 == 2);
        }
        next_seq += n as u64;
        frames += n as u64;
    }
    let dt = t0.elapsed().as_secs_f64();
    let rate = frames as f64 / dt;
    assert!(
        (rate / fs - 1.0).abs() < 0.1,
        "{frames} frames in {dt:.3} s = {rate:.0} Hz vs {fs} Hz"
    );
    let st = rig.status();
    assert_eq!(st.frames, frames);
    assert_eq!(st.limited_frames, expect_limited);
    assert_eq!(st.nonfinite_commands, expect_nonfinite);
    // Stop the streams first: the callback adds to the frame and under-run
    // counters one after the other, so a snapshot taken while it runs can
    // see one without the other.
    rig.stop().unwrap();
    let cnt = rig.counters();
    // Everything queued was played (the null PCM consumes at once), the rest
    // of the device's frames were silence; inputs were delivered; the host
    // limits left nothing for the callback to clamp; no stream errors.
    assert!(cnt.out_callbacks > 0 && cnt.in_callbacks > 0);
    let played = cnt.out_frames - cnt.underrun_frames;
    let queued = frames + c.latency_frames as u64;
    assert!(played <= queued && played + c.ring_frames as u64 >= queued);
    assert!(cnt.in_frames - cnt.overflow_frames >= frames);
    assert_eq!(cnt.clamped_samples, 0);
    assert_eq!(cnt.stream_errors, 0);
    // Under-runs surface as overrun faults and skipped samples.
    let mut overruns = 0;
    while let Some(f) = rig.pop_fault() {
        if let RigFault::Overrun { .. } = f {
            overruns += 1;
        }
    }
    assert!(overruns > 0 || st.faults_dropped > 0);
    assert!(rig.process_block(&cmds, &mut sens).is_err());
}

/// Device pacing on the clockless null PCM: no waiting on the wall clock, so
/// frames advance at least at the nominal rate; a restart resumes the
/// sequence.
#[test]
fn device_pacing_on_the_null_pcm_runs_at_least_at_the_rate() {
    let mut rig = AudioRig::open(&null_cfg(AudioPacing::Device)).unwrap();
    let fs = rig.identity().sample_rate_hz;
    rig.start().unwrap();
    let n = 256;
    let cmds = vec![ActuatorFrame::default(); n];
    let mut sens = vec![SensorFrame::default(); n];
    let t0 = Instant::now();
    let mut frames = 0u64;
    while t0.elapsed() < Duration::from_millis(300) {
        rig.process_block(&cmds, &mut sens).unwrap();
        frames += n as u64;
    }
    let rate = frames as f64 / t0.elapsed().as_secs_f64();
    assert!(rate > 0.9 * fs, "{rate} Hz");
    rig.stop().unwrap();
    rig.start().unwrap();
    let r = rig.process_block(&cmds, &mut sens).unwrap();
    assert_eq!(r.first_seq, frames);
}

/// A full scale below the drive limit: the host limits to 2 V, which is
/// beyond ±1 of a 1 V full scale, so the callback clamps (defence in depth).
#[test]
fn callback_clamps_to_digital_full_scale() {
    let mut c = null_cfg(AudioPacing::Device);
    c.haptuator_full_scale_v = 1.0;
    let mut rig = AudioRig::open(&c).unwrap();
    rig.start().unwrap();
    let cmds = vec![
        ActuatorFrame {
            force_n: [0.0, 0.0],
            haptuator_v: 2.0,
        };
        512
    ];
    let mut sens = vec![SensorFrame::default(); 512];
    let t0 = Instant::now();
    while rig.counters().clamped_samples == 0 && t0.elapsed() < Duration::from_secs(5) {
        rig.process_block(&cmds, &mut sens).unwrap();
    }
    assert!(rig.counters().clamped_samples > 0);
}

#[test]
fn monitor_plays_on_the_null_device() {
    let mut m = AudioMonitor::open(&MonitorConfig::new(Some("null"), 10_000.0)).unwrap();
    assert_eq!(m.device_rate_hz(), 48_000.0);
    let block: Vec<f64> = (0..1000)
        .map(|k| (2.0 * std::f64::consts::PI * 1000.0 * k as f64 / 1e4).sin())
        .collect();
    let mut offered = 0u64;
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(300) {
        m.push(&block);
        m.push(&[f64::NAN, f64::INFINITY]);
        offered += 1002;
        std::thread::sleep(Duration::from_millis(10));
    }
    let c = m.counters();
    assert_eq!(c.pushed + c.dropped, offered);
    assert!(c.pushed > 0 && c.callbacks > 0 && c.frames > 0);
    // The clockless null PCM drains the ring at once and then under-runs.
    assert!(c.underrun_samples > 0);
}

/// Linear interpolation of a sinusoid: the error is at most
/// A(2πf/f_in)²/8 plus f32 rounding, for up- and down-sampling; ratio 1 is
/// a pure one-sample delay.
#[test]
fn resampler_error_is_within_the_linear_interpolation_bound() {
    for (f_in, f_out, f) in [
        (10_000.0, 48_000.0, 1000.0),
        (10_000.0, 44_100.0, 200.0),
        (48_000.0, 10_000.0, 300.0),
        (10_000.0, 48_000.0, 4000.0),
    ] {
        let mut rs = LinearResampler::new(f_in, f_out).unwrap();
        let w = 2.0 * std::f64::consts::PI * f / f_in;
        let x = |k: i64| if k < 0 { 0.0 } else { (w * k as f64).sin() };
        let mut k = 0i64;
        let bound = w * w / 8.0 + 1e-6;
        let mut worst: f64 = 0.0;
        for m in 0..20_000 {
            let y = rs.next_sample(|| {
                let v = x(k) as f32;
                k += 1;
                Some(v)
            }) as f64;
            let p = m as f64 * f_in / f_out - 1.0;
            if p >= 1.0 {
                worst = worst.max((y - (w * p).sin()).abs());
            }
        }
        assert!(
            worst <= bound,
            "{f_in}→{f_out} at {f} Hz: {worst} > {bound}"
        );
        // The bound is nearly reached at 4 kHz (exact worst case
        // 1 − cos(w/2) = 0.87 of it, times |sin| ≤ 0.95 at the sampled phases).
        if f == 4000.0 {
            assert!(worst > 0.7 * (w * w / 8.0), "{worst}");
        }
    }
    let mut rs = LinearResampler::new(1.0, 1.0).unwrap();
    let mut k = 0.0f32;
    let ys: Vec<f32> = (0..5)
        .map(|_| {
            rs.next_sample(|| {
                k += 1.0;
                Some(k)
            })
        })
        .collect();
    assert_eq!(ys, [0.0, 1.0, 2.0, 3.0, 4.0]);
    assert!(LinearResampler::new(0.0, 1.0).is_err());
}
