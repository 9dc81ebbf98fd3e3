//! # kilotouch-rig
//!
//! The dual-stage haptic rig of Ji, Vézien, Hayward et al. ("KiloHertz
//! bandwidth, dual-stage haptic device lets you touch Brownian motion"),
//! simulated: the lumped plant of §2.2 (eq. 1, Table 2) with exact
//! zero-order-hold discretisation, the fingertip accelerometer, the optical
//! tweezer of §4.1 (eqs. 4–6), the [`Rig`] interface that the live rigs
//! implement too, the bilateral coupling between handle and trap, the closed
//! loop ([`HapticLoop`]) and its stability analysis ([`stability`]).
//!
//! Units are SI unless a name says otherwise; pN/µm, µm/V and pN/V only at
//! the edges (command line, text, GUI, files: [`units`]). Theory and references:
//! `docs/theory/` (index: `docs/THEORY.md`); speed and accuracy tables: `docs/PERFORMANCE.md`.

pub mod accel;
#[cfg(feature = "audio")]
pub mod audio;
pub mod backend;
pub mod calibration;
pub mod condition;
pub mod config;
pub mod coupling;
pub mod device;
pub mod error;
pub mod haptic_loop;
pub mod input;
pub mod lanes;
pub mod lti;
pub mod normal;
pub mod plant;
pub mod press;
pub mod realtime;
pub mod safety;
pub mod serial;
pub mod sim;
pub mod stability;
pub mod text;
pub mod toml_location;
pub mod tweezer;
pub mod units;

pub use backend::{AnyRig, AnyTweezer, open_rig};
pub use condition::{Condition, PMode};
pub use config::{RigConfig, default_config_text};
pub use device::{ActuatorFrame, Rig, SensorFrame};
pub use error::RigError;
pub use haptic_loop::{Clearance, HapticLoop, LoopSample};
pub use lti::Integrator;
pub use plant::{Axis, AxisModel, Channel, DualStagePlant};
pub use sim::{FrfReport, SimRig, simulate_frf};
pub use tweezer::{SimTweezer, Tweezer, TweezerParams};

/// `x.round()` (half away from zero), bit for bit, without a libm call or
/// an integer round trip (baseline x86-64 has no rounding instruction):
/// for |x| < 2⁵², (|x| + 2⁵²) − 2⁵² rounds |x| to the nearest integer with
/// ties to even (exactly, in the default rounding mode), and a tie that went
/// down (|x| − r = 0.5, an exact difference) goes up instead. Larger |x| are
/// already integral (or ±∞, NaN) and returned unchanged.
#[doc(hidden)]
#[inline(always)]
pub fn round_half_away(x: f64) -> f64 {
    if x.abs() < TWO52 {
        round_half_away_small(x)
    } else {
        x
    }
}

/// 2⁵².
const TWO52: f64 = 4_503_599_627_370_496.0;

/// `x` (a count computed in floating point, e.g. seconds × Hz, already
/// rounded as the caller wants) as an integer when it is finite, ≥ 0 and
/// below 2⁵² (where every integer is exact): the checked form of `x as
/// u64`, which saturates silently. `None` otherwise — the caller names the
/// field.
pub fn checked_count(x: f64) -> Option<u64> {
    // The range check makes the conversion exact.
    (x.is_finite() && (0.0..TWO52).contains(&x)).then_some(x as u64)
}

/// [`round_half_away`] for |x| < 2⁵² (the caller guarantees it; for
/// larger or non-finite x the result is wrong). The tie correction is added
/// as 0 or 1 (r + 0 = r exactly for r ≥ 0) and the sign is or-ed onto the
/// non-negative r, which is `copysign` here: fewer instructions, same bits.
#[inline(always)]
pub(crate) fn round_half_away_small(x: f64) -> f64 {
    let a = x.abs();
    let r = (a + TWO52) - TWO52;
    let r = r + if a - r == 0.5 { 1.0 } else { 0.0 };
    f64::from_bits(r.to_bits() | (x.to_bits() & (1 << 63)))
}
