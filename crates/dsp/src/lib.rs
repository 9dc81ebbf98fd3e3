//! # kilotouch-dsp
//!
//! Pure numerics for the dual-stage haptic interface of Ji, Vézien, Hayward et
//! al. ("KiloHertz bandwidth, dual-stage haptic device lets you touch Brownian
//! motion"): IIR filters in second-order sections, Butterworth/bilinear design,
//! the Linkwitz–Riley crossover, the channel compensators C_L and C_H (§3.3),
//! the per-sample signal chain of Fig. 6, excitation signals, Welch spectral
//! estimation, continuous-time model fitting, third-octave analysis and the
//! (aliased) Lorentzian spectrum of a trapped bead with its fit.
//!
//! This crate does no I/O. All coefficients and filter state are `f64`.
//! Frequencies are in hertz unless a name says otherwise (`_rad_s` = rad/s);
//! sample rates `fs` are in hertz.
//!
//! The equations implemented are listed, with references, in
//! `docs/theory/` (index: `docs/THEORY.md`).

pub mod error;
pub mod poly;
pub mod tf;
pub mod zpk;

pub mod chain;
pub mod compensator;
pub mod crossover;
pub mod design;
pub mod filter;

pub mod excitation;
pub mod spectral;

pub mod fit;
pub mod thirdoctave;
pub mod trap_psd;

pub use error::DspError;
pub use num_complex::Complex64 as C64;
pub use tf::Tf;
pub use zpk::Zpk;

/// Result alias used throughout the crate.
pub type Result<T> = std::result::Result<T, DspError>;
