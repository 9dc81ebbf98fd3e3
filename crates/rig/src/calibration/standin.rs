//! A small linear stand-in rig with one nonlinearity, for testing the
//! procedure independently of the full simulated plant. A test double: it
//! is compiled only with the crate's `testing` feature (the crate's own
//! tests turn it on through a dev-dependency on itself).
//!
//! * Low channel (Pantograph force → tip acceleration):
//!   G_L(s) = G0_L · s²/(s² + 2ζ_f ω_f s + ω_f²) · Π_k (ω_rk²/ω_ak²)·
//!   (s² + 2ζ_ak ω_ak s + ω_ak²)/(s² + 2ζ_rk ω_rk s + ω_rk²):
//!   flat at G0_L above the finger corner ω_f, with antiresonance/resonance
//!   pairs above (the paper's Fig. 5 shape).
//! * High channel (Haptuator drive → tip acceleration): a given G_H(s)
//!   (default: the paper's eq. 2 times a gain).
//! * End stops: the magnet's stroke d = u/(m_v (s² + 2ζ_v ω_v s + ω_v²));
//!   beyond ±`stroke_m` the overtravel e adds −k_e·e to the tip acceleration
//!   (an impact), and each such sample is counted as an end-stop hit. Large
//!   low-frequency drive saturates, as in the paper below 100 Hz.
//! * Sensor: white noise of density `noise_density` (m/s²/√Hz, one-sided)
//!   added to the tip acceleration, then a 1-pole low-pass at `sensor_hz`
//!   (MMA7361L: 400 Hz) and clipping at ±`accel_range_m_s2`.
//!
//! Every continuous factor is discretised on its own with the bilinear
//! transform prewarped at its own corner ([`kilotouch_dsp::design::tf_to_sos`])
//! and run as second-order sections. The true responses of the discretised
//! rig are available ([`StandInRig::true_response`]) for tests.

use super::error::{CalibrationError, Result};
use super::hash::content_hash;
use super::interface::check_run_lengths;
use super::interface::{ActuatorLimits, CalibrationRig, Channel, CheckReport, RigRecord, RunStats};
use kilotouch_dsp::design::tf_to_sos;
use kilotouch_dsp::filter::{BiquadCoeffs, Sos, sections_response};
use kilotouch_dsp::{C64, Tf};
use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// An antiresonance/resonance pair of the low channel.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ModePair {
    /// Antiresonance frequency, Hz.
    pub anti_hz: f64,
    /// Antiresonance damping ratio.
    pub anti_zeta: f64,
    /// Resonance frequency, Hz.
    pub res_hz: f64,
    /// Resonance damping ratio.
    pub res_zeta: f64,
}

/// A fault to inject.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum StandInFault {
    /// No fault.
    #[default]
    None,
    /// The sensor output is stuck at zero (the rig does not know).
    DeadSensor,
    /// The rig reports its safety limits as not armed.
    Unarmed,
    /// The sensor returns NaN.
    NanOutput,
}

/// Parameters of the stand-in rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StandInConfig {
    /// Sample rate, Hz.
    pub fs: f64,
    /// Rig name.
    pub name: String,
    /// Serial.
    pub serial: String,
    /// Low-channel gain G0_L, (m/s²)/N.
    pub g0_l: f64,
    /// Finger corner (high-pass) of the low channel, Hz (0 = none).
    pub finger_hz: f64,
    /// Damping ratio of the finger corner.
    pub finger_zeta: f64,
    /// Modes of the low channel.
    pub low_modes: Vec<ModePair>,
    /// High channel G_H(s), (m/s²) per drive unit.
    pub high: Tf,
    /// Moving magnet mass, kg.
    pub magnet_mass_kg: f64,
    /// Magnet suspension resonance, Hz.
    pub magnet_hz: f64,
    /// Magnet suspension damping ratio.
    pub magnet_zeta: f64,
    /// Half stroke before the end stops, m.
    pub stroke_m: f64,
    /// Tip acceleration per metre of overtravel at an end stop, (m/s²)/m.
    pub end_stop_gain: f64,
    /// Sensor low-pass corner, Hz (`None`: no low-pass).
    pub sensor_hz: Option<f64>,
    /// Whether the rig reports its sensor response.
    pub sensor_known: bool,
    /// Sensor noise density, m/s²/√Hz (one-sided).
    pub noise_density: f64,
    /// Sensor full scale, m/s².
    pub accel_range_m_s2: f64,
    /// Pantograph force limit, N.
    pub max_force_n: f64,
    /// Haptuator drive limit.
    pub max_high_drive: f64,
    /// Noise seed.
    pub seed: u64,
    /// Injected fault.
    pub fault: StandInFault,
}

impl Default for StandInConfig {
    /// Paper-like defaults (Fig. 5): G0_L = 8 (m/s²)/N flat from ~20 Hz to
    /// ~200 Hz, an antiresonance at 350 Hz and resonance at 440 Hz, a sharp
    /// pair at 780/820 Hz; G_H = 20 × eq. 2; magnet 5 g at 60 Hz with ±0.5 mm of
    /// stroke; MMA7361L-like sensor (400 Hz, 350 µg/√Hz, ±6 g).
    fn default() -> Self {
        Self {
            fs: 10_000.0,
            name: "standin".into(),
            serial: "-".into(),
            g0_l: 8.0,
            finger_hz: 10.0,
            finger_zeta: 0.7,
            low_modes: vec![
                ModePair {
                    anti_hz: 350.0,
                    anti_zeta: 0.1,
                    res_hz: 440.0,
                    res_zeta: 0.15,
                },
                ModePair {
                    anti_hz: 780.0,
                    anti_zeta: 0.02,
                    res_hz: 820.0,
                    res_zeta: 0.02,
                },
            ],
            high: Tf {
                num: vec![20.0 * 250.0, 20.0 * 6.40e5],
                den: vec![1.0, 2135.0, 4.56e6],
            },
            magnet_mass_kg: 0.005,
            magnet_hz: 60.0,
            magnet_zeta: 0.3,
            stroke_m: 0.5e-3,
            end_stop_gain: 1e5,
            sensor_hz: Some(400.0),
            sensor_known: true,
            noise_density: 350e-6 * 9.80665,
            accel_range_m_s2: 6.0 * 9.80665,
            max_force_n: 5.0,
            max_high_drive: 3.0,
            seed: 1,
            fault: StandInFault::None,
        }
    }
}

/// The stand-in rig (see the module documentation).
#[derive(Debug, Clone)]
pub struct StandInRig {
    cfg: StandInConfig,
    low: Sos,
    high: Sos,
    stroke: Sos,
    sensor: Option<Sos>,
    rng: ChaCha8Rng,
    noise_std: f64,
    tip: Vec<f64>,
}

fn second_order(num: [f64; 3], f_hz: f64, zeta: f64, fs: f64) -> Result<Vec<BiquadCoeffs>> {
    let w = 2.0 * PI * f_hz;
    let tf = Tf::new(num.to_vec(), vec![1.0, 2.0 * zeta * w, w * w])
        .map_err(|e| CalibrationError::dsp("stand-in model", e))?;
    tf_to_sos(&tf, fs, Some(f_hz)).map_err(|e| CalibrationError::dsp("stand-in model", e))
}

fn sos(sections: Vec<BiquadCoeffs>) -> Result<Sos> {
    Sos::new(sections).map_err(|e| CalibrationError::dsp("stand-in model", e))
}

fn natural_hz(tf: &Tf) -> f64 {
    let d = &tf.den;
    if d.len() >= 3 && d[0] != 0.0 && d[d.len() - 1] / d[0] > 0.0 {
        (d[d.len() - 1] / d[0]).powf(1.0 / (d.len() - 1) as f64) / (2.0 * PI)
    } else {
        1000.0
    }
}

impl StandInRig {
    /// Build the rig.
    pub fn new(cfg: StandInConfig) -> Result<Self> {
        let fs = cfg.fs;
        if !(fs.is_finite() && fs > 0.0) {
            return Err(CalibrationError::config(
                "standin.fs",
                fs,
                "must be finite and > 0",
            ));
        }
        let mut low = Vec::new();
        if cfg.finger_hz > 0.0 {
            low.extend(second_order(
                [1.0, 0.0, 0.0],
                cfg.finger_hz,
                cfg.finger_zeta,
                fs,
            )?);
        }
        for m in &cfg.low_modes {
            let (wa, wr) = (2.0 * PI * m.anti_hz, 2.0 * PI * m.res_hz);
            let k = wr * wr / (wa * wa);
            low.extend(second_order(
                [k, k * 2.0 * m.anti_zeta * wa, k * wa * wa],
                m.res_hz,
                m.res_zeta,
                fs,
            )?);
        }
        if low.is_empty() {
            low.push(BiquadCoeffs::IDENTITY);
        }
        low[0] = low[0].scaled(cfg.g0_l);
        let high = tf_to_sos(&cfg.high, fs, Some(natural_hz(&cfg.high)))
            .map_err(|e| CalibrationError::dsp("stand-in high channel", e))?;
        let stroke = second_order(
            [0.0, 0.0, 1.0 / cfg.magnet_mass_kg],
            cfg.magnet_hz,
            cfg.magnet_zeta,
            fs,
        )?;
        let sensor = match cfg.sensor_hz {
            Some(fc) => {
                let tf = Tf::new(vec![1.0], vec![1.0 / (2.0 * PI * fc), 1.0])
                    .map_err(|e| CalibrationError::dsp("stand-in sensor", e))?;
                Some(sos(tf_to_sos(&tf, fs, Some(fc))
                    .map_err(|e| CalibrationError::dsp("stand-in sensor", e))?)?)
            }
            None => None,
        };
        let noise_std = cfg.noise_density * (fs / 2.0).sqrt();
        Ok(Self {
            rng: ChaCha8Rng::seed_from_u64(cfg.seed),
            low: sos(low)?,
            high: sos(high)?,
            stroke: sos(stroke)?,
            sensor,
            noise_std,
            tip: Vec::new(),
            cfg,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &StandInConfig {
        &self.cfg
    }

    /// True response of `channel` (tip acceleration per unit drive) of the
    /// discretised rig at `f_hz`, in the linear regime, without the sensor.
    pub fn true_response(&self, channel: Channel, f_hz: f64) -> C64 {
        let s = match channel {
            Channel::Low => &self.low,
            Channel::High => &self.high,
        };
        sections_response(s.sections(), f_hz, self.cfg.fs)
    }

    /// True tip acceleration (m/s², before the sensor) of the last run.
    pub fn last_tip(&self) -> &[f64] {
        &self.tip
    }

    /// Zero the state of every filter (the rig at rest).
    pub fn reset(&mut self) {
        self.low.reset();
        self.high.reset();
        self.stroke.reset();
        if let Some(s) = &mut self.sensor {
            s.reset();
        }
    }
}

impl CalibrationRig for StandInRig {
    fn sample_rate(&self) -> f64 {
        self.cfg.fs
    }

    fn record(&self) -> RigRecord {
        RigRecord {
            name: self.cfg.name.clone(),
            serial: self.cfg.serial.clone(),
            config_hash: content_hash(&self.cfg).unwrap_or_else(|_| "fnv1a64:unhashable".into()),
            sample_rate_hz: self.cfg.fs,
        }
    }

    fn check(&mut self) -> Result<CheckReport> {
        let armed = self.cfg.fault != StandInFault::Unarmed;
        Ok(CheckReport {
            sensor_alive: true,
            sensor_in_range: true,
            responding: true,
            safety_armed: armed,
            messages: if armed {
                vec![]
            } else {
                vec!["drive clamps disabled".into()]
            },
        })
    }

    fn run(
        &mut self,
        low_drive: &[f64],
        high_drive: &[f64],
        accel: &mut [f64],
    ) -> Result<RunStats> {
        let n = check_run_lengths(low_drive, high_drive, accel)?;
        let c = &self.cfg;
        let mut stats = RunStats {
            samples: n,
            end_stop_hits: Some(0),
            ..RunStats::default()
        };
        let mut hits = 0;
        self.tip.clear();
        self.tip.reserve(n);
        for i in 0..n {
            let clamp = |u: f64, lim: f64, clipped: &mut usize| {
                let u = if u.is_finite() { u } else { 0.0 };
                if u.abs() > lim {
                    *clipped += 1;
                    lim.copysign(u)
                } else {
                    u
                }
            };
            let ul = clamp(low_drive[i], c.max_force_n, &mut stats.drive_clipped);
            let uh = clamp(high_drive[i], c.max_high_drive, &mut stats.drive_clipped);
            let mut a = self.low.process(ul) + self.high.process(uh);
            let d = self.stroke.process(uh);
            let over = d.abs() - c.stroke_m;
            if over > 0.0 {
                hits += 1;
                a -= c.end_stop_gain * over.copysign(d);
            }
            self.tip.push(a);
            // Noise enters the sensing element, so the sensor's low-pass
            // limits its bandwidth (datasheet noise density × √bandwidth).
            let z: f64 = StandardNormal.sample(&mut self.rng);
            let sensed = a + self.noise_std * z;
            let mut s = match &mut self.sensor {
                Some(f) => f.process(sensed),
                None => sensed,
            };
            if s.abs() >= c.accel_range_m_s2 {
                stats.accel_clipped += 1;
                s = c.accel_range_m_s2.copysign(s);
            }
            accel[i] = match c.fault {
                StandInFault::DeadSensor => 0.0,
                StandInFault::NanOutput => f64::NAN,
                _ => s,
            };
        }
        stats.end_stop_hits = Some(hits);
        Ok(stats)
    }

    fn limits(&self) -> ActuatorLimits {
        ActuatorLimits {
            max_force_n: self.cfg.max_force_n,
            max_high_drive: self.cfg.max_high_drive,
            accel_range_m_s2: Some(self.cfg.accel_range_m_s2),
        }
    }

    fn sensor_response(&self, f_hz: f64) -> Option<C64> {
        if !self.cfg.sensor_known {
            return None;
        }
        Some(match &self.sensor {
            Some(s) => s.response(f_hz, self.cfg.fs),
            None => C64::new(1.0, 0.0),
        })
    }
}
