//! The wall damper: damping rendered along the contact normal while the bead
//! touches an obstacle, the damper of the classic virtual wall (Colgate &
//! Brown 1994). Pressed against an obstacle the coupling renders a stiff
//! spring (K_e = g·s·κ·k_c/(κ + k_c) ≈ 790 N/m at the handle with the
//! defaults) on the device's mass held by the finger; with only the finger's
//! damping that mode has a few degrees of phase margin, and the crossover's
//! delay in D (2√2/ω_c ≈ 2.25 ms at 200 Hz) takes the rest. The damper gives
//! the loop its margin back (`docs/theory/coupling-and-stability.md`, closed-loop stability).
//!
//! Velocity: v̂ = LP(fs·(x[n] − x[n−1])) per axis, LP a 2nd-order
//! Butterworth low-pass at `velocity_filter_hz` (bilinear, prewarped): the
//! backward difference of 10 µm encoder counts is 0.1 m/s per count at
//! 10 kHz, the low-pass keeps that quantisation noise below the filter's
//! corner, out of the Haptuator's band. Force: −b·(v̂·n)·n along the unit
//! normal n, only in contact; tangential sliding is not damped.

use crate::error::RigError;
use crate::tweezer::TweezerSample;
use kilotouch_dsp::design::{FilterKind, Prewarp, butter};
use kilotouch_dsp::filter::Biquad;

/// Handle-velocity estimate and wall damper (module docs).
#[derive(Debug, Clone)]
pub struct WallDamper {
    b: f64,
    fs: f64,
    last: [f64; 2],
    primed: bool,
    lp: [Biquad; 2],
    v: [f64; 2],
}

impl WallDamper {
    /// Damping `b_n_s_per_m` (N·s/m, ≥ 0), velocity low-pass at `filter_hz`,
    /// sample rate `fs`.
    ///
    /// # Errors
    /// A corner at or above Nyquist, a negative or non-finite damping.
    pub fn new(b_n_s_per_m: f64, filter_hz: f64, fs: f64) -> Result<Self, RigError> {
        if !(b_n_s_per_m.is_finite() && b_n_s_per_m >= 0.0) {
            return Err(RigError::InvalidParameter {
                name: "contact_damping_n_s_per_m",
                value: b_n_s_per_m,
                reason: "must be finite and ≥ 0".into(),
            });
        }
        let s = butter(2, filter_hz, fs, FilterKind::Lowpass, Prewarp::AtCutoff)?;
        let c = *s.first().ok_or_else(|| RigError::InvalidParameter {
            name: "velocity_filter_hz",
            value: filter_hz,
            reason: "no filter section".into(),
        })?;
        Ok(Self {
            b: b_n_s_per_m,
            fs,
            last: [0.0; 2],
            primed: false,
            lp: [Biquad::new(c)?, Biquad::new(c)?],
            v: [0.0; 2],
        })
    }

    /// Damping, N·s/m.
    pub fn damping(&self) -> f64 {
        self.b
    }

    /// Feed this sample's handle position (m); returns the filtered velocity
    /// (m/s). A non-finite position counts as no motion.
    #[inline]
    pub fn update(&mut self, x: [f64; 2]) -> [f64; 2] {
        for (((xi, last), lp), v) in x
            .iter()
            .zip(&mut self.last)
            .zip(&mut self.lp)
            .zip(&mut self.v)
        {
            let raw = if xi.is_finite() && self.primed {
                (xi - *last) * self.fs
            } else {
                0.0
            };
            if xi.is_finite() {
                *last = *xi;
            }
            *v = lp.process(raw);
        }
        self.primed = true;
        self.v
    }

    /// Latest velocity estimate, m/s.
    pub fn velocity(&self) -> [f64; 2] {
        self.v
    }

    /// The damper's force at the handle (N) for the tweezer sample `s`:
    /// −b (v̂·n) n in contact with the bead trapped, zero otherwise.
    #[inline]
    pub fn force(&self, s: &TweezerSample) -> [f64; 2] {
        if !(s.in_contact && s.trapped) || self.b == 0.0 {
            return [0.0; 2];
        }
        let n = s.normal;
        let vn = self.v[0] * n[0] + self.v[1] * n[1];
        [-self.b * vn * n[0], -self.b * vn * n[1]]
    }

    /// Clear the estimator (the next sample primes it).
    pub fn reset(&mut self) {
        self.primed = false;
        self.v = [0.0; 2];
        for f in &mut self.lp {
            f.reset();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_velocity_and_normal_damping() {
        let fs = 10_000.0;
        let mut d = WallDamper::new(15.0, 100.0, fs).unwrap();
        // Handle moving at 0.02 m/s along x: the estimate settles to it.
        let mut v = [0.0; 2];
        for n in 0..2000 {
            v = d.update([0.02 * n as f64 / fs, 1e-3]);
        }
        assert!((v[0] - 0.02).abs() < 1e-9 && v[1].abs() < 1e-12, "{v:?}");
        let mut s = TweezerSample {
            in_contact: true,
            trapped: true,
            normal: [-1.0, 0.0],
            ..TweezerSample::default()
        };
        // Moving into the obstacle (against its normal) is resisted.
        let f = d.force(&s);
        assert!(
            (f[0] + 15.0 * 0.02).abs() < 1e-9 && f[1].abs() < 1e-15,
            "{f:?}"
        );
        // Tangential motion is not damped.
        s.normal = [0.0, 1.0];
        assert_eq!(d.force(&s), [0.0, 0.0]);
        s.in_contact = false;
        s.normal = [-1.0, 0.0];
        assert_eq!(d.force(&s), [0.0, 0.0]);
        // A non-finite position is no motion and is not remembered.
        let v = d.update([f64::NAN, 1e-3]);
        assert!(v[0].is_finite());
    }
}
