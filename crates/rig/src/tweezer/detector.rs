//! Position detector of the simulated tweezer: what a calibration meets in
//! a real instrument between the bead and the reported signal
//! (docs/theory/tweezer.md, "Position detector").
//!
//! Per axis the output is V = S·(α x + (1 − α) y) + σ_n ξ, with x the
//! bead's displacement from the trap centre (m), S the sensitivity (V/m),
//! y the first-order low-pass of x at f_diode (the slow photodiode's
//! delayed fraction 1 − α; Berg-Sørensen et al. 2003, eq. 11 — its power
//! transfer is α² + (1 − α²)/(1 + (f/f_diode)²)) and σ_n the white noise
//! of the amplifier and converter (V rms per sample).
//!
//! **Exact filter.** In free space x is an Ornstein–Uhlenbeck process of
//! rate a = 2πf_c, so (x, y) is a linear SDE with
//! A = [[−a, 0], [b, −b]], b = 2πf_diode, noise on x only. Its exact
//! transition over a sample h is Gaussian: y(h) = Φ₂₁ x₀ + e^{−bh} y₀ + w₂
//! with Φ₂₁ = b(e^{−ah} − e^{−bh})/(b − a), and (w₁, w₂) of covariance Q
//! (closed form below). The tweezer realises w₁ = x(h) − e^{−ah} x₀; the
//! detector draws w₂ conditioned on it, w₂ = (Q₁₂/Q₁₁) w₁ +
//! √(Q₂₂ − Q₁₂²/Q₁₁) ξ from its own noise stream, so the sampled output has
//! exactly the aliased spectrum of the continuous filtered process, and the
//! tweezer's random stream is not touched. Near obstacles or with a moving
//! trap x is no longer that OU process; the filter then stays a smooth
//! approximation.

use super::sim::SimTweezer;
use super::{AppliedTrap, Tweezer, TweezerParams, TweezerSample};
pub use crate::config::DetectorConfig;
use crate::error::RigError;
use crate::normal::NormalStream;
use std::f64::consts::PI;

/// Coefficients of the exact joint step of (x, y) (module docs).
#[derive(Debug, Clone, Copy)]
struct DiodeStep {
    c_x: f64,
    phi21: f64,
    c_y: f64,
    gain: f64,
    sd: f64,
    alpha: f64,
}

/// The detector of one tweezer (two axes).
#[derive(Debug, Clone)]
pub struct Detector {
    cfg: DetectorConfig,
    step: Option<DiodeStep>,
    x_prev: [f64; 2],
    y: [f64; 2],
    rng: NormalStream,
}

impl Detector {
    /// A detector for a trap of corner frequency `corner_hz` sampled at `fs_hz`.
    pub fn new(cfg: &DetectorConfig, corner_hz: f64, fs_hz: f64) -> Result<Self, RigError> {
        cfg.validate()?;
        if !(corner_hz.is_finite() && corner_hz > 0.0 && fs_hz.is_finite() && fs_hz > 0.0) {
            return Err(RigError::InvalidParameter {
                name: "fc",
                value: corner_hz,
                reason: "corner and sample frequencies must be finite and > 0".into(),
            });
        }
        let step = cfg.diode_hz.map(|fd| {
            let h = 1.0 / fs_hz;
            let a = 2.0 * PI * corner_hz;
            let mut b = 2.0 * PI * fd;
            if ((b - a) / a).abs() < 1e-6 {
                b = a * (1.0 + 1e-6);
            }
            // ∫₀ʰ e^{−ks} ds = −expm1(−kh)/k
            let int = |k: f64| -(-k * h).exp_m1() / k;
            let r = b / (b - a);
            // Per unit noise intensity (the OU's σ² cancels in the ratios
            // below once Q₁₁ is its own variance).
            let q11 = int(2.0 * a);
            let q12 = r * (int(2.0 * a) - int(a + b));
            let q22 = r * r * (int(2.0 * a) - 2.0 * int(a + b) + int(2.0 * b));
            let c_x = (-a * h).exp();
            // Stationary variance of x per unit intensity is 1/(2a); the
            // conditional sd of w₂ is scaled to x's units via √(2a·var_x)
            // at run time — here in units of x's stationary sd.
            let sd = ((q22 - q12 * q12 / q11).max(0.0) * 2.0 * a).sqrt();
            DiodeStep {
                c_x,
                phi21: r * (c_x - (-b * h).exp()),
                c_y: (-b * h).exp(),
                gain: q12 / q11,
                sd,
                alpha: cfg.diode_alpha,
            }
        });
        Ok(Self {
            step,
            x_prev: [0.0; 2],
            y: [0.0; 2],
            rng: NormalStream::new(cfg.seed),
            cfg: cfg.clone(),
        })
    }

    /// Parameters.
    pub fn config(&self) -> &DetectorConfig {
        &self.cfg
    }

    /// Start the filter state in step with a displacement `x_m` (m).
    pub fn reset(&mut self, x_m: [f64; 2]) {
        self.x_prev = x_m;
        self.y = x_m;
    }

    /// Output (V, both axes) for the displacement `x_m` (m) of the bead from
    /// the trap centre at this sample; `x_sd_m` is the stationary standard
    /// deviation √(k_BT/κ) of one axis (m), which scales the filter's own
    /// noise. Allocates nothing; non-finite input gives 0 V.
    pub fn output(&mut self, x_m: [f64; 2], x_sd_m: f64) -> [f64; 2] {
        let mut v = [0.0; 2];
        for k in 0..2 {
            let x = if x_m[k].is_finite() { x_m[k] } else { 0.0 };
            let seen = match self.step {
                None => x,
                Some(s) => {
                    let w1 = x - s.c_x * self.x_prev[k];
                    let y = s.phi21 * self.x_prev[k]
                        + s.c_y * self.y[k]
                        + s.gain * w1
                        + s.sd * x_sd_m * self.rng.sample();
                    self.y[k] = if y.is_finite() { y } else { x };
                    s.alpha * x + (1.0 - s.alpha) * self.y[k]
                }
            };
            self.x_prev[k] = x;
            v[k] = self.cfg.sensitivity_v_per_m * seen + self.cfg.noise_v_rms * self.rng.sample();
        }
        v
    }
}

/// The simulated tweezer seen through its detector: steps like
/// [`SimTweezer`] and reports the detector's signals for the bead's
/// displacement from the trap ([`Tweezer::detector_v`]). With a trap
/// calibration applied ([`DetectedTweezer::set_calibration`]) it reports
/// what a host with that calibration sees, as the live link does: the
/// bead at trap + R_d·V and the force κ_cal (trap − bead)
/// ([`AppliedTrap::bead_and_force`]); the simulated bead itself moves as
/// before.
#[derive(Debug, Clone)]
pub struct DetectedTweezer {
    tw: SimTweezer,
    det: Detector,
    sd_m: f64,
    last_v: [f64; 2],
    calibration: Option<AppliedTrap>,
}

impl DetectedTweezer {
    /// The tweezer of `params` at `fs_hz` behind the detector `cfg`.
    pub fn new(params: TweezerParams, cfg: &DetectorConfig, fs_hz: f64) -> Result<Self, RigError> {
        Self::wrap(SimTweezer::new(params, fs_hz)?, cfg)
    }

    /// The simulated tweezer `tw` behind the detector `cfg` (at the
    /// tweezer's rate), no trap calibration applied: it steps exactly as
    /// `tw` would.
    pub fn wrap(tw: SimTweezer, cfg: &DetectorConfig) -> Result<Self, RigError> {
        let p = tw.params();
        let det = Detector::new(cfg, p.corner_hz(), tw.sample_rate_hz())?;
        let sd_m = p.variance_theory().sqrt();
        Ok(Self {
            tw,
            det,
            sd_m,
            last_v: [0.0; 2],
            calibration: None,
        })
    }

    /// The simulated tweezer.
    pub fn tweezer(&self) -> &SimTweezer {
        &self.tw
    }

    /// The simulated bead's centre, m.
    pub fn bead(&self) -> [f64; 2] {
        self.tw.bead()
    }

    /// Put the simulated bead at `bead` (m); the detector's filter starts
    /// in step with it.
    pub fn set_bead(&mut self, bead: [f64; 2]) {
        self.tw.set_bead(bead);
        let t = self.tw.trap();
        self.det.reset([bead[0] - t[0], bead[1] - t[1]]);
    }

    /// Report through this trap calibration from the next sample on
    /// (`None`: the simulated bead and stiffness). An invalid calibration
    /// is refused and the one in use kept.
    pub fn set_calibration(&mut self, c: Option<AppliedTrap>) -> Result<(), RigError> {
        if let Some(c) = &c {
            c.validate()?;
        }
        self.calibration = c;
        Ok(())
    }

    /// The trap calibration in use.
    pub fn calibration(&self) -> Option<AppliedTrap> {
        self.calibration
    }

    /// The bead from the stationary distribution around the trap, the
    /// detector's filter in step with it.
    pub fn start_stationary(&mut self) {
        self.tw.start_stationary();
        let (b, t) = (self.tw.bead(), self.tw.trap());
        self.det.reset([b[0] - t[0], b[1] - t[1]]);
    }
}

impl Tweezer for DetectedTweezer {
    fn sample_rate_hz(&self) -> f64 {
        self.tw.sample_rate_hz()
    }
    fn stiffness_n_per_m(&self) -> f64 {
        self.calibration
            .map_or_else(|| self.tw.stiffness_n_per_m(), |c| c.stiffness_n_per_m)
    }
    fn step(&mut self, trap_m: [f64; 2]) -> TweezerSample {
        let mut s = self.tw.step(trap_m);
        self.last_v = self.det.output(
            [s.bead_m[0] - s.trap_m[0], s.bead_m[1] - s.trap_m[1]],
            self.sd_m,
        );
        if let Some(c) = &self.calibration
            && s.trapped
        {
            (s.bead_m, s.force_n) = c.bead_and_force(s.trap_m, self.last_v);
        }
        s
    }
    fn reset(&mut self, trap_m: [f64; 2]) {
        self.tw.reset(trap_m);
        self.det.reset([0.0; 2]);
    }
    fn detector_v(&self) -> Option<[f64; 2]> {
        Some(self.last_v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Exact OU samples of rate a with stationary sd `sd`.
    fn ou(n: usize, corner_hz: f64, fs: f64, sd: f64, seed: u64) -> Vec<f64> {
        let c = (-2.0 * PI * corner_hz / fs).exp();
        let mut rng = NormalStream::new(seed);
        let mut x = sd * rng.sample();
        (0..n)
            .map(|_| {
                x = c * x + sd * (1.0 - c * c).sqrt() * rng.sample();
                x
            })
            .collect()
    }

    #[test]
    fn filtered_variance_matches_the_integrated_spectrum() {
        // ∫ Lorentzian·g_diode df = (k_BT/κ)[α² + (1 − α²) f_d/(f_d + f_c)]
        // (sampling does not change a variance).
        let (corner_hz, fs, fd, alpha, sd) = (800.0, 10e3, 1500.0, 0.3, 1e-8);
        let cfg = DetectorConfig {
            sensitivity_v_per_m: 1.0,
            diode_hz: Some(fd),
            diode_alpha: alpha,
            noise_v_rms: 0.0,
            seed: 3,
        };
        let mut det = Detector::new(&cfg, corner_hz, fs).unwrap();
        let x = ou(400_000, corner_hz, fs, sd, 11);
        det.reset([x[0], 0.0]);
        let v: Vec<f64> = x.iter().map(|&xi| det.output([xi, 0.0], sd)[0]).collect();
        let var = v.iter().map(|a| a * a).sum::<f64>() / v.len() as f64;
        let expect = sd * sd * (alpha * alpha + (1.0 - alpha * alpha) * fd / (fd + corner_hz));
        assert!((var / expect - 1.0).abs() < 0.02, "{var} vs {expect}");
        // Without the diode the output is S·x plus the white noise.
        let plain = DetectorConfig {
            sensitivity_v_per_m: 2.0,
            noise_v_rms: 0.0,
            ..DetectorConfig::default()
        };
        let mut d = Detector::new(&plain, corner_hz, fs).unwrap();
        assert_eq!(d.output([1e-7, -2e-7], sd), [2e-7, -4e-7]);
        assert!(
            Detector::new(
                &DetectorConfig {
                    diode_alpha: 1.5,
                    ..plain
                },
                corner_hz,
                fs
            )
            .is_err()
        );
    }

    #[test]
    fn a_calibrated_view_reports_the_measured_bead_and_the_calibrated_force() {
        let p = TweezerParams {
            seed: 5,
            ..TweezerParams::paper_default()
        };
        let cfg = DetectorConfig::default();
        let mut plain = DetectedTweezer::new(p.clone(), &cfg, 1e4).unwrap();
        let mut cal = DetectedTweezer::new(p, &cfg, 1e4).unwrap();
        let applied = AppliedTrap {
            stiffness_n_per_m: 4e-5,
            rd_m_per_v: [1.0 / cfg.sensitivity_v_per_m; 2],
        };
        cal.set_calibration(Some(applied)).unwrap();
        assert_eq!(cal.stiffness_n_per_m(), 4e-5);
        let bad = AppliedTrap {
            stiffness_n_per_m: f64::NAN,
            ..applied
        };
        assert!(cal.set_calibration(Some(bad)).is_err());
        assert_eq!(cal.calibration(), Some(applied));
        for i in 0..2000 {
            let trap = [1e-7 * (i as f64 * 0.01).sin(), 0.0];
            let (a, b) = (plain.step(trap), cal.step(trap));
            // The simulated bead moves the same; the view differs by the
            // detector noise (1e-5 V ↔ 20 pm) and uses κ_cal.
            assert_eq!(plain.bead(), cal.bead());
            for k in 0..2 {
                assert!((a.bead_m[k] - b.bead_m[k]).abs() < 1e-10, "{i}");
                let f = 4e-5 * (b.trap_m[k] - b.bead_m[k]);
                assert!((b.force_n[k] - f).abs() <= 1e-12 * f.abs().max(1e-18));
            }
        }
        cal.set_calibration(None).unwrap();
        assert_eq!(cal.stiffness_n_per_m(), 2e-5);
    }
}
