//! Zero-pole-gain representation, analog or digital.
//!
//! H(x) = k ∏(x − z_i) / ∏(x − p_i), with x = s (rad/s) for analog systems
//! and x = z for digital ones. Frequency responses are evaluated factor by
//! factor, never through expanded polynomials, which keeps high orders (LR8,
//! fc/fs = 1e-4) accurate.

use crate::C64;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Zeros, poles and gain of a rational transfer function.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Zpk {
    /// Zeros (complex ones in conjugate pairs).
    pub zeros: Vec<C64>,
    /// Poles (complex ones in conjugate pairs).
    pub poles: Vec<C64>,
    /// Gain k.
    pub gain: f64,
}

impl Zpk {
    /// H(x) evaluated factor by factor.
    pub fn eval(&self, x: C64) -> C64 {
        let mut h = C64::new(self.gain, 0.0);
        for &z in &self.zeros {
            h *= x - z;
        }
        for &p in &self.poles {
            h /= x - p;
        }
        h
    }

    /// Analog frequency response at `f` hertz (x = j 2π f).
    pub fn analog_response(&self, f: f64) -> C64 {
        self.eval(C64::new(0.0, 2.0 * PI * f))
    }

    /// Digital frequency response at `f` hertz for sample rate `fs` (x = e^{j 2π f/fs}).
    pub fn digital_response(&self, f: f64, fs: f64) -> C64 {
        self.eval(C64::from_polar(1.0, 2.0 * PI * f / fs))
    }
}
