//! Passivity observer and controller (Hannaford & Ryu 2002) on the
//! Pantograph forces: a run-time net for loops whose margins the models got
//! wrong.
//!
//! Per axis, with f[n] the force the coupling commands and v̂[n] the handle
//! velocity estimate ([`super::damper::WallDamper`]), the energy the
//! rendering absorbs from the device port in sample n is
//! e[n] = −f[n]·v̂[n]·T. A passive rendering never gives back more than it
//! absorbed. The observer sums e over a sliding window of the last
//! [`WINDOW_S`] (the windowed observer of Ryu, Hannaford, Preusche &
//! Hirzinger 2005): a plain running sum would credit the rendering with the
//! energy a pressed spring stored long ago, and an instability growing
//! around the pressed point would go unseen until it had returned all of it
//! — by then the bead is lost. When the window's sum W[n] < 0 the
//! rendering has produced energy over the last window, and the controller
//! adds the variable damper α = −W[n]/(v̂[n]²·T) (at most [`ALPHA_MAX`]):
//! f ← f − α·v̂, which dissipates exactly the excess (W ← 0).
//!
//! The price of the window: releasing a spring that was pressed longer than
//! a window ago gives back energy the window no longer holds, and the
//! controller damps the release (the hand feels less push-back). That is why
//! the controller is an option (`coupling.passivity_controller`), off by
//! default: the loop's stability comes from its margins, this is the net.
//! The Haptuator's inertial force is left out: it is ungrounded and acts in
//! its own band.

/// Length of the observer's window, s: two periods of the slowest loop
/// mode the analysis finds (the hand–device mass on the pressed spring,
/// ≈ 8–10 Hz at the defaults).
pub const WINDOW_S: f64 = 0.25;

/// Largest damping the controller adds, N·s/m.
pub const ALPHA_MAX: f64 = 200.0;

/// Longest window, samples (bounds the ring's memory at any sample rate).
pub const MAX_WINDOW: usize = 1 << 16;

/// Below this speed the controller does not act (α would blow up), m/s.
const V_MIN: f64 = 1e-6;

/// Per-axis windowed passivity observer/controller (module docs). The
/// rings are allocated at construction; `apply` allocates nothing.
#[derive(Debug, Clone)]
pub struct PassivityController {
    dt: f64,
    ring: [Box<[f64]>; 2],
    pos: usize,
    w: [f64; 2],
    active: u64,
    dissipated_j: f64,
}

impl PassivityController {
    /// At sample rate `fs`, Hz.
    pub fn new(fs: f64) -> Self {
        let n = ((WINDOW_S * fs).round().max(1.0) as usize).min(MAX_WINDOW);
        Self {
            dt: 1.0 / fs,
            ring: [
                vec![0.0; n].into_boxed_slice(),
                vec![0.0; n].into_boxed_slice(),
            ],
            pos: 0,
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
            let ring = &mut self.ring[i];
            let Some(old) = ring.get(self.pos).copied() else {
                continue;
            };
            let mut e = -f[i] * v[i] * self.dt;
            if !e.is_finite() {
                e = 0.0;
            }
            let mut w = self.w[i] - old + e;
            let v2 = v[i] * v[i];
            if w < 0.0 && v[i].abs() > V_MIN {
                let alpha = (-w / (v2 * self.dt)).min(ALPHA_MAX);
                out[i] = f[i] - alpha * v[i];
                let d = alpha * v2 * self.dt;
                e += d;
                w += d;
                self.dissipated_j += d;
                acted = true;
            }
            if let Some(slot) = ring.get_mut(self.pos) {
                *slot = e;
            }
            self.w[i] = if w.is_finite() { w } else { 0.0 };
        }
        self.pos += 1;
        if self.pos >= self.ring[0].len() {
            self.pos = 0;
            // Re-sum once per window: no drift of the running sums.
            for i in 0..2 {
                self.w[i] = self.ring[i].iter().sum();
            }
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

    /// Energy absorbed over the window per axis, J.
    pub fn energy_j(&self) -> [f64; 2] {
        self.w
    }

    /// Forget the observed energy.
    pub fn reset(&mut self) {
        self.w = [0.0; 2];
        for r in &mut self.ring {
            r.fill(0.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_damped_spring_is_left_alone_and_an_active_force_is_damped() {
        let fs = 1000.0;
        // A damped spring f = −k x − c v (800 N/m, 1 cm, 10 Hz) over many
        // oscillations is passive over every window: the controller never
        // acts.
        let mut pc = PassivityController::new(fs);
        let w = 2.0 * std::f64::consts::PI * 10.0;
        for n in 0..5000 {
            let t = n as f64 / fs;
            let x = 0.01 * (w * t).sin();
            let v = 0.01 * w * (w * t).cos();
            let want = -800.0 * x - 0.5 * v;
            let f = pc.apply([want, 0.0], [v, 0.0]);
            assert_eq!(f[0], want, "sample {n}");
        }
        // The same spring with a delayed force (an active rendering, as the
        // crossover's lag makes it): the controller acts and keeps every
        // window's balance at zero or above.
        let mut pc = PassivityController::new(fs);
        let delay = 5;
        let mut xs = vec![0.0; delay];
        for n in 0..5000 {
            let t = n as f64 / fs;
            let x = 0.01 * (w * t).sin();
            let v = 0.01 * w * (w * t).cos();
            xs.push(x);
            let want = -800.0 * xs[n];
            pc.apply([want, 0.0], [v, 0.0]);
            assert!(
                pc.energy_j()[0] >= -1e-12,
                "sample {n}: {:?}",
                pc.energy_j()
            );
        }
        assert!(pc.active_samples() > 100 && pc.dissipated_j() > 0.0);
        // A force pushing along the motion (negative damping) produces
        // energy: from the first such sample on, the controller cancels it.
        let mut pc = PassivityController::new(fs);
        for _ in 0..100 {
            let f = pc.apply([0.5, 0.0], [0.1, 0.0]);
            assert!(f[0] <= 1e-12, "{f:?}");
        }
        assert_eq!(pc.active_samples(), 100);
    }
}
