//! Passive power-spectral calibration of an optical trap (Berg-Sørensen &
//! Flyvbjerg 2004, "BSF"; with the refinements of LUMICKS' pylake,
//! `lumicks.pylake.force_calibration`, whose formulation this follows so
//! that the numbers agree; docs/theory/tweezer.md, "Trap calibration").
//!
//! * [`periodogram`]: the one-sided periodogram of a whole record (no
//!   window, mean removed, V²/Hz) and its blocking: the bins in
//!   (f_lo, f_hi] averaged in blocks of n points (BSF §IV; pylake
//!   `calculate_power_spectrum`).
//! * [`model`]: the spectra fitted — the Lorentzian D/(π²(f_c² + f²)) (BSF
//!   eq. 10), the aliased Lorentzian of a point-sampled record
//!   ([`model::aliased_lorentzian_one_sided`], BSF eq. 4), the
//!   hydrodynamically correct spectrum with the frequency-dependent drag of
//!   a sphere near a wall (Tolić-Nørrelykke et al. 2006, eqs. D2–D6), each
//!   optionally times the slow-photodiode filter
//!   g(f) = α² + (1 − α²)/(1 + (f/f_diode)²) (Berg-Sørensen et al. 2003,
//!   eq. 11).
//! * [`fit`]: the analytical least-squares Lorentzian (BSF §IV, eqs. 13–14)
//!   as the start, then the weighted least-squares fit of 1/P that is the
//!   maximum-likelihood fit of a blocked spectrum (BSF eq. 39), with
//!   standard errors from the inverse Gauss–Newton Hessian (JᵀJ)⁻¹, the
//!   bias correction n/(n + 1) of D (Nørrelykke & Flyvbjerg 2010), χ² per
//!   degree of freedom and the statistical backing (BSF §VI).
//!
//! Units: frequencies in Hz, the record in volts (or any unit u; D is then
//! in u²/s and P in u²/Hz).

pub mod fit;
pub mod model;
pub mod periodogram;
pub mod synth;

pub use fit::{
    AnalyticalFit, PsdFit, PsdFitOptions, fit_analytical_lorentzian, fit_power_spectrum,
};
pub use model::{
    Hydrodynamics, PsdModel, SpectrumShape, aliased_lorentzian_one_sided, diode_filter,
    lorentzian_one_sided,
};
pub use periodogram::{BlockedSpectrum, Periodogram};
