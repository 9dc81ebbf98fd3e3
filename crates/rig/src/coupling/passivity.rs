//! Passivity observer and controller (Hannaford & Ryu 2002) on the
//! Pantograph forces: a run-time net for loops whose margins the models got
//! wrong.
//!
//! Per axis, with f[n] the force the coupling commands and v̂[n] the handle
//! velocity estimate ([`super::damper::WallDamper`]), the observer sums the
//! energy the rendering has absorbed from the device port,
//! W[n] = W[n−1] − f[n]·v̂[n]·T. A passive rendering keeps W ≥ 0 (a spring
//! gives back at most what it stored). When W[n] < 0 the rendering has
//! produced energy, and the controller adds the variable damper
//! α = −W[n]/(v̂[n]²·T) (at most [`ALPHA_MAX`]): f ← f − α·v̂, which
//! dissipates exactly the excess (W ← 0). W is capped at [`W_MAX_J`] so
//! that energy dissipated long ago (e.g. by the wall damper) cannot hide a
//! later instability for long; the cap must exceed what the rendering may
//! store and give back (a spring pressed to full force). The Haptuator's inertial force is left out: it is
//! ungrounded and acts in its own band.

/// Largest damping the controller adds, N·s/m.
pub const ALPHA_MAX: f64 = 200.0;

/// Largest absorbed energy the observer remembers, J: the work of the
/// Pantograph's full force (5 N) across 0.2 m of workspace, more than any
/// rendered spring stores.
pub const W_MAX_J: f64 = 1.0;

/// Below this speed the controller does not act (α would blow up), m/s.
const V_MIN: f64 = 1e-6;

/// Per-axis passivity observer/controller (module docs).
#[derive(Debug, Clone)]
pub struct PassivityController {
    dt: f64,
    w: [f64; 2],
    active: u64,
    dissipated_j: f64,
}

impl PassivityController {
    /// At sample rate `fs`, Hz.
    pub fn new(fs: f64) -> Self {
        Self {
            dt: 1.0 / fs,
            w: [0.0; 2],
            active: 0,
            dissipated_j: 0.0,
        }
    }

    /// Observe and, where needed, correct the Pantograph forces `f` (N)
    /// with the handle velocity `v` (m/s).
    #[inline]
    pub fn apply(&mut self, f: [f64; 2], v: [f64; 2]) -> [f64; 2] {
        let mut out = f;
        let mut acted = false;
        for i in 0..2 {
            let mut w = self.w[i] - f[i] * v[i] * self.dt;
            if !w.is_finite() {
                w = 0.0;
            }
            let v2 = v[i] * v[i];
            if w < 0.0 && v[i].abs() > V_MIN {
                let alpha = (-w / (v2 * self.dt)).min(ALPHA_MAX);
                out[i] = f[i] - alpha * v[i];
                let e = alpha * v2 * self.dt;
                w += e;
                self.dissipated_j += e;
                acted = true;
            }
            self.w[i] = w.min(W_MAX_J);
        }
        if acted {
            self.active += 1;
        }
        out
    }

    /// Samples in which the controller added damping.
    pub fn active_samples(&self) -> u64 {
        self.active
    }

    /// Energy the controller has dissipated, J.
    pub fn dissipated_j(&self) -> f64 {
        self.dissipated_j
    }

    /// Observed energy per axis, J.
    pub fn energy_j(&self) -> [f64; 2] {
        self.w
    }

    /// Forget the observed energy.
    pub fn reset(&mut self) {
        self.w = [0.0; 2];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spring_is_left_alone_and_an_active_force_is_damped() {
        let fs = 1000.0;
        // A damped spring f = −k x − c v (800 N/m, pressed 1 cm: 40 mJ
        // stored) over two oscillations is passive: the controller never acts.
        let mut pc = PassivityController::new(fs);
        for n in 0..2000 {
            let t = n as f64 / fs;
            let w = 2.0 * std::f64::consts::PI;
            let x = 0.01 * (w * t).sin();
            let v = 0.01 * w * (w * t).cos();
            let want = -800.0 * x - 0.5 * v;
            let f = pc.apply([want, 0.0], [v, 0.0]);
            assert_eq!(f[0], want);
        }
        // A force pushing along the motion (negative damping) produces
        // energy: from the first such sample on, the controller cancels it.
        let mut pc = PassivityController::new(fs);
        for _ in 0..100 {
            let f = pc.apply([0.5, 0.0], [0.1, 0.0]);
            assert!(f[0] <= 1e-12, "{f:?}");
        }
        assert_eq!(pc.active_samples(), 100);
        assert!(pc.energy_j()[0].abs() < 1e-15);
    }
}
