//! Excitation signals for system identification (paper §3.2: "pseudo-random
//! binary sequence input … PSD analysis (Welch method)").
//!
//! * [`Mls`] — maximum-length sequences (m-sequences) of order 2–32 from a
//!   Fibonacci linear feedback shift register, bit-compatible with
//!   `scipy.signal.max_len_seq` (same tap table, same register convention,
//!   same all-ones seed). Lazy, allocation-free generator for real-time loops
//!   plus [`mls_bits`] / [`mls_signal`] builders.
//! * [`LogSweep`] — Farina's exponential (logarithmic) swept sine
//!   (Farina 2000, AES 108th Convention, preprint 5093).
//! * [`SteppedSineConfig`] / [`stepped_sine`] — stepped sines with settle and
//!   measurement windows of whole cycles, and the per-step schedule.
//! * [`sine_fit`] — three-parameter least-squares sine fit (IEEE Std 1057
//!   "three-parameter" fit, known frequency) solved by Householder QR;
//!   [`sine_dft`] — the single-bin DFT estimate of the same quantities.
//!
//! Units: frequencies in Hz, times in s, sample rates `fs` in Hz, phases in
//! rad, amplitudes in the caller's signal unit.
//!
//! One concept per file: the generators [`Mls`] (`mls.rs`), [`LogSweep`]
//! (`sweep.rs`) and the stepped sines (`stepped.rs`); the estimators
//! [`sine_fit`] / [`sine_dft`] (`sine_estimate.rs`); `buffer.rs` allocates
//! the generated signals. Every item is re-exported here, so its path is
//! `kilotouch_dsp::excitation::Item`.

mod buffer;
mod mls;
mod sine_estimate;
mod stepped;
mod sweep;

pub use mls::{MLS_MAX_ORDER, MLS_MIN_ORDER, Mls, mls_bits, mls_period, mls_signal, mls_taps};
pub use sine_estimate::{sine_dft, sine_fit};
pub use stepped::{SineStep, SteppedSineConfig, stepped_sine, stepped_sine_schedule};
pub use sweep::LogSweep;
