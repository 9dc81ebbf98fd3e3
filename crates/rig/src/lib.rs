//! # kilotouch-rig
//!
//! The dual-stage haptic rig of Ji, Vézien, Hayward et al. ("KiloHertz
//! bandwidth, dual-stage haptic device lets you touch Brownian motion"),
//! simulated: the lumped plant of §2.2 (eq. 1, Table 2) with exact
//! zero-order-hold discretisation, the fingertip accelerometer, the optical
//! tweezer of §4.1 (eqs. 4–6), the [`Rig`] interface that live
//! rigs will also implement, and the bilateral coupling between handle and
//! trap.
//!
//! Units are SI unless a name says otherwise. Theory and references:
//! `docs/THEORY.md`; speed and accuracy tables: `docs/PERFORMANCE.md`.

pub mod accel;
#[cfg(feature = "audio")]
pub mod audio;
pub mod calibration;
pub mod config;
pub mod coupling;
pub mod error;
pub mod live;
pub mod lorentzian;
pub mod lti;
pub mod plant;
pub mod rig;
pub mod safety;
pub mod sim;
pub mod tweezer;

pub use config::{RigConfig, default_config_text};
pub use error::RigError;
pub use lti::Integrator;
pub use plant::{Axis, AxisModel, Channel, DualStagePlant};
pub use rig::{ActuatorFrame, Rig, SensorFrame, SimRig};
pub use sim::{FrfReport, simulate_frf};
pub use tweezer::{SimTweezer, Tweezer, TweezerParams};

/// `x.round()` (half away from zero), bit for bit, without the libm call
/// (baseline x86-64 has no rounding instruction). Falls back to
/// [`f64::round`] for |x| ≥ 2⁵² (already integral) and non-finite x.
#[inline]
pub(crate) fn round_half_away(x: f64) -> f64 {
    if x.abs() < 4_503_599_627_370_496.0 {
        // Truncation is exact here, and so is the fractional part x − t.
        let t = x as i64 as f64;
        let r = if (x - t).abs() >= 0.5 {
            t + 1.0_f64.copysign(x)
        } else {
            t
        };
        r.copysign(x)
    } else {
        x.round()
    }
}

#[cfg(test)]
mod round_tests {
    use super::round_half_away;

    #[test]
    fn matches_f64_round_bit_for_bit() {
        let mut v = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            -2.5,
            0.49999999999999994,
            -0.49999999999999994,
            4503599627370495.5,
            -4503599627370495.5,
            4503599627370496.0,
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            0.3,
            -0.3,
            0.7,
            -0.7,
        ];
        let mut s = 0x9E37_79B9_7F4A_7C15_u64;
        for _ in 0..200_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let u = (s >> 11) as f64 / (1u64 << 53) as f64;
            v.push((u - 0.5) * 10_000.0);
            v.push(((u - 0.5) * 8192.0).round() + 0.5);
            v.push(f64::from_bits(s));
        }
        for x in v {
            let (a, b) = (round_half_away(x), x.round());
            assert!(
                a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                "{x:e}: {a:e} vs {b:e}"
            );
        }
    }
}
