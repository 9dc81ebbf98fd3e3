//! The plant's channels as second-order sections in parallel: what the
//! firmware's QEMU build simulates in place of the analog front end
//! (`firmware/`, docs/FIRMWARE.md), loaded through test frames.
//!
//! Per axis, the free regime of eq. 1 restricted to its active states is
//! discretised exactly as the simulated rig does (zero-order hold at the
//! rig's rate, outputs at the end of the step: y[n] = C x[n+1] + D u[n]),
//! then put in real modal form T⁻¹ΦT = Λ ([`super::modal`]). Each channel
//! (input j → output i) is then H(z) = z·(CT)(zI − Λ)⁻¹(T⁻¹Γ) + D, a sum
//! over Λ's blocks: for a 2×2 block [[p, q], [r, s]] with c = (CT)ᵢ,
//! g = (T⁻¹Γ)ⱼ,
//!
//! H_b(z) = (n₁ + n₀ z⁻¹)/(1 − (p + s) z⁻¹ + (ps − qr) z⁻²),
//! n₁ = c·g, n₀ = −s c₁g₁ + q c₁g₂ + r c₂g₁ − p c₂g₂
//!
//! (the adjugate of zI − Λ_b), and for a real eigenvalue λ, c g/(1 − λ z⁻¹).
//! A block whose numerator is exactly zero (a mode the input or output does
//! not see) is left out. The end stops are not modelled: below the stroke
//! the sections reproduce the simulated rig's response (checked sample
//! for sample in `tests/plant_sections.rs`).

use super::model::AxisModel;
use super::{Axis, IN_DRIVE, IN_FORCE, OUT_ACCEL, OUT_MOTOR};
use crate::config::RigConfig;
use crate::error::RigError;
use crate::lti;
use kilotouch_dsp::filter::BiquadCoeffs;
use nalgebra::DMatrix;

/// A channel's input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChannelInput {
    /// Pantograph force on the axis, N.
    Force,
    /// Haptuator drive, V (x axis only).
    Drive,
}

/// A channel's output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChannelOutput {
    /// Tip acceleration, m/s² (before the accelerometer).
    Accel,
    /// Motor position x₁, m (what the encoders see).
    Handle,
}

/// One channel of the plant: the sum of its sections.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelSections {
    /// Axis.
    pub axis: Axis,
    /// Input.
    pub input: ChannelInput,
    /// Output.
    pub output: ChannelOutput,
    /// Sections in parallel (their outputs add), each b/a with a0 = 1.
    pub sections: Vec<BiquadCoeffs>,
}

impl ChannelSections {
    /// Response at `f` Hz for sample rate `fs` (sum of the sections).
    pub fn response(&self, f: f64, fs: f64) -> num_complex::Complex64 {
        self.sections.iter().map(|s| s.response(f, fs)).sum()
    }
}

/// The channels of both axes at the rig's sample rate (module docs): x
/// force and drive to x acceleration and handle, y force to y acceleration
/// and handle.
pub fn plant_sections(cfg: &RigConfig) -> Result<Vec<ChannelSections>, RigError> {
    let dt = 1.0 / cfg.rig.sample_rate_hz;
    let mut out = Vec::new();
    for axis in [Axis::X, Axis::Y] {
        let model = AxisModel::new(cfg, axis)?;
        let ss = model.active_free();
        let (phi, gamma) = lti::zoh(&ss.a, &ss.b, dt)?;
        let (t, tinv, lam) = super::modal::real_eigenbasis(&phi).ok_or_else(|| {
            RigError::Numerical(format!(
                "the {axis:?} axis has no well-conditioned real eigenbasis (repeated modes?)"
            ))
        })?;
        let ct = &ss.c * &t;
        let g = &tinv * &gamma;
        let inputs: &[ChannelInput] = match axis {
            Axis::X => &[ChannelInput::Force, ChannelInput::Drive],
            Axis::Y => &[ChannelInput::Force],
        };
        for &input in inputs {
            let j = match input {
                ChannelInput::Force => IN_FORCE,
                ChannelInput::Drive => IN_DRIVE,
            };
            for output in [ChannelOutput::Accel, ChannelOutput::Handle] {
                let i = match output {
                    ChannelOutput::Accel => OUT_ACCEL,
                    ChannelOutput::Handle => OUT_MOTOR,
                };
                let mut sections = blocks(&lam, &ct, &g, i, j)?;
                let d = ss.d[(i, j)];
                if d != 0.0 {
                    sections.push(coeffs([d, 0.0, 0.0], [0.0, 0.0])?);
                }
                out.push(ChannelSections {
                    axis,
                    input,
                    output,
                    sections,
                });
            }
        }
    }
    Ok(out)
}

fn coeffs(b: [f64; 3], a: [f64; 2]) -> Result<BiquadCoeffs, RigError> {
    BiquadCoeffs::new(b, [1.0, a[0], a[1]])
        .map_err(|e| RigError::Numerical(format!("plant section: {e}")))
}

/// The sections of output `i` from input `j` over the blocks of `lam`.
fn blocks(
    lam: &DMatrix<f64>,
    ct: &DMatrix<f64>,
    g: &DMatrix<f64>,
    i: usize,
    j: usize,
) -> Result<Vec<BiquadCoeffs>, RigError> {
    let n = lam.nrows();
    let mut v = Vec::new();
    let mut k = 0;
    while k < n {
        let pair = k + 1 < n && (lam[(k, k + 1)] != 0.0 || lam[(k + 1, k)] != 0.0);
        if pair {
            let (p, q, r, s) = (
                lam[(k, k)],
                lam[(k, k + 1)],
                lam[(k + 1, k)],
                lam[(k + 1, k + 1)],
            );
            let (c1, c2, g1, g2) = (ct[(i, k)], ct[(i, k + 1)], g[(k, j)], g[(k + 1, j)]);
            let n1 = c1 * g1 + c2 * g2;
            let n0 = -s * c1 * g1 + q * c1 * g2 + r * c2 * g1 - p * c2 * g2;
            if n1 != 0.0 || n0 != 0.0 {
                v.push(coeffs([n1, n0, 0.0], [-(p + s), p * s - q * r])?);
            }
            k += 2;
        } else {
            let cg = ct[(i, k)] * g[(k, j)];
            if cg != 0.0 {
                v.push(coeffs([cg, 0.0, 0.0], [-lam[(k, k)], 0.0])?);
            }
            k += 1;
        }
    }
    Ok(v)
}
