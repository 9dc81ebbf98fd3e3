//! The plant's channels as parallel second-order sections (what the
//! firmware's QEMU build runs) against the simulated rig's own plant: the
//! same tip accelerations and motor positions, sample for sample, for a
//! random excitation of both Pantograph axes and the Haptuator below the
//! end stops; and against the continuous model's analytic response.

#![allow(clippy::unwrap_used)]

use kilotouch_dsp::filter::Biquad;
use kilotouch_rig::RigConfig;
use kilotouch_rig::lti::Integrator;
use kilotouch_rig::plant::sections::{ChannelInput, ChannelOutput, plant_sections};
use kilotouch_rig::plant::{Axis, AxisModel, Channel, DualStagePlant, PlantInput};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[test]
fn sections_reproduce_the_simulated_plant_sample_for_sample() {
    let cfg = RigConfig::default();
    let chans = plant_sections(&cfg).unwrap();
    assert_eq!(chans.len(), 6);
    let n_sections: usize = chans.iter().map(|c| c.sections.len()).sum();
    assert!(
        n_sections <= 64,
        "{n_sections} sections: more than the firmware holds"
    );
    let mut banks: Vec<Vec<Biquad>> = chans
        .iter()
        .map(|c| {
            c.sections
                .iter()
                .map(|s| Biquad::new(*s).unwrap())
                .collect()
        })
        .collect();
    let mut plant = DualStagePlant::new(&cfg, Integrator::Zoh).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let (fmax, vmax) = (
        cfg.limits.pantograph_force_max_n,
        cfg.limits.haptuator_drive_max_v,
    );
    let mut worst = [0.0f64; 6];
    let mut scale = [0.0f64; 6];
    for _ in 0..20_000 {
        let u = [
            0.3 * fmax * rng.random_range(-1.0..1.0),
            0.3 * fmax * rng.random_range(-1.0..1.0),
            0.05 * vmax * rng.random_range(-1.0..1.0),
        ];
        let o = plant.step(&PlantInput {
            force_n: [u[0], u[1]],
            drive_v: u[2],
            hand_m: [0.0; 2],
            hand_vel_m_s: [0.0; 2],
        });
        assert_eq!(
            plant.x.end_stop_steps(),
            0,
            "the test must stay off the stops"
        );
        let mut y = [0.0f64; 4]; // accel x, accel y, motor x, motor y
        for (c, bank) in chans.iter().zip(banks.iter_mut()) {
            let x = match (c.axis, c.input) {
                (Axis::X, ChannelInput::Force) => u[0],
                (Axis::Y, ChannelInput::Force) => u[1],
                (_, ChannelInput::Drive) => u[2],
            };
            let k = match (c.axis, c.output) {
                (Axis::X, ChannelOutput::Accel) => 0,
                (Axis::Y, ChannelOutput::Accel) => 1,
                (Axis::X, ChannelOutput::Handle) => 2,
                (Axis::Y, ChannelOutput::Handle) => 3,
            };
            y[k] += bank.iter_mut().map(|b| b.process(x)).sum::<f64>();
        }
        let want = [o.accel_m_s2[0], o.accel_m_s2[1], o.motor_m[0], o.motor_m[1]];
        for k in 0..4 {
            worst[k] = worst[k].max((y[k] - want[k]).abs());
            scale[k] = scale[k].max(want[k].abs());
        }
    }
    for k in 0..4 {
        assert!(scale[k] > 0.0);
        assert!(
            worst[k] <= 1e-9 * scale[k],
            "output {k}: worst {:e} of {:e}",
            worst[k],
            scale[k]
        );
    }
}

/// The sections' frequency response equals the ZOH-discretised model's:
/// below 1 kHz within 0.5 % of the continuous model's analytic response
/// (the zero-order hold's own effect at 10 kHz, sinc and half-sample delay,
/// is below 0.5 % in magnitude up to 1 kHz… so it is compared loosely),
/// and exactly (1e-6) in magnitude at 20 Hz.
#[test]
fn sections_follow_the_analytic_channel_responses() {
    let cfg = RigConfig::default();
    let fs = cfg.rig.sample_rate_hz;
    let chans = plant_sections(&cfg).unwrap();
    let mx = AxisModel::new(&cfg, Axis::X).unwrap();
    for (input, ch) in [
        (ChannelInput::Force, Channel::Low),
        (ChannelInput::Drive, Channel::High),
    ] {
        let c = chans
            .iter()
            .find(|c| c.axis == Axis::X && c.input == input && c.output == ChannelOutput::Accel)
            .unwrap();
        for f in [20.0, 63.0, 200.0, 500.0, 1000.0] {
            let h = c.response(f, fs);
            let a = mx.channel_response(ch, f).unwrap();
            let rel = (h.norm() - a.norm()).abs() / a.norm();
            // ZOH magnitude error |sinc(f/fs)| − 1 ≤ 1.6 % at 1 kHz, and
            // the half-sample delay only turns the phase.
            assert!(
                rel < 0.02,
                "{input:?} at {f} Hz: |H| {} vs {}",
                h.norm(),
                a.norm()
            );
        }
    }
}
