//! `kilotouch sim tweezer`: simulate a bead in a fixed trap and check it the
//! way the tweezer community checks a trap — stationary variance against
//! equipartition, and the aliased Lorentzian fitted to the power spectrum
//! the way a trap is calibrated (Berg-Sørensen & Flyvbjerg 2004;
//! `kilotouch_dsp::trap_psd`).

use kilotouch_dsp::trap_psd::{
    Periodogram, PsdFitOptions, PsdModel, SpectrumShape, fit_power_spectrum,
};
use kilotouch_rig::tweezer::{SimTweezer, Tweezer, TweezerIntegrator, TweezerParams};
use serde::{Deserialize, Serialize};

/// Arguments of `kilotouch sim tweezer` (units in the names).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TweezerSimArgs {
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Sample rate, Hz.
    pub fs_hz: f64,
    /// Trap stiffness, pN/µm.
    pub stiffness_pn_um: f64,
    /// Bead radius, µm.
    pub radius_um: f64,
    /// Temperature, K.
    pub temperature_k: f64,
    /// Viscosity, Pa·s.
    pub viscosity_pa_s: f64,
    /// Bead-centre to coverslip distance, µm.
    pub wall_distance_um: Option<f64>,
    /// Integrator.
    pub integrator: TweezerIntegrator,
    /// Seed.
    pub seed: u64,
}

impl Default for TweezerSimArgs {
    fn default() -> Self {
        Self {
            duration_s: 10.0,
            fs_hz: 10_000.0,
            stiffness_pn_um: 20.0,
            radius_um: 1.5,
            temperature_k: 293.15,
            viscosity_pa_s: 1.0016e-3,
            wall_distance_um: None,
            integrator: TweezerIntegrator::Exact,
            seed: 1,
        }
    }
}

/// Result of `kilotouch sim tweezer` (SI units in the names).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TweezerSimReport {
    /// Sample variance of x about its mean, m².
    pub var_x_m2: f64,
    /// Sample variance of y about its mean, m².
    pub var_y_m2: f64,
    /// Fitted corner frequency (aliased Lorentzian, mean of the x and y fits), Hz.
    pub fc_fit_hz: f64,
    /// Fitted diffusion coefficient (mean of the x and y fits), m²/s.
    pub d_fit_m2_s: f64,
    /// κ/(2πγ) with γ including the wall factor, Hz.
    pub fc_theory_hz: f64,
    /// k_BT/κ, m².
    pub var_theory_m2: f64,
    /// k_BT/γ, m²/s.
    pub d_theory_m2_s: f64,
    /// Drag γ = γ₀·(Faxén factor), N·s/m.
    pub gamma_n_s_m: f64,
    /// Faxén factor of the wall (1 without).
    pub wall_factor: f64,
    /// Sample period over relaxation time, dt/τ.
    pub dt_over_tau: f64,
    /// Samples simulated per axis.
    pub n_samples: usize,
    /// Periodogram bins averaged per block of the fitted spectrum.
    pub points_per_block: usize,
    /// Fit band (f_lo, f_hi], Hz.
    pub fit_band_hz: [f64; 2],
    /// Integrator used.
    pub integrator: TweezerIntegrator,
    /// Seed used.
    pub seed: u64,
}

/// The fitted spectrum's n/2 bins are averaged `n / BLOCKS` per block
/// (about 2048 blocks), but never fewer than [`MIN_POINTS_PER_BLOCK`]: the
/// least-squares fit of a blocked spectrum is the maximum-likelihood fit
/// only when each block averages many bins (BSF §IV).
const BLOCKS: usize = 4096;
/// Fewest periodogram bins per block.
const MIN_POINTS_PER_BLOCK: usize = 16;

/// Library entry point of `kilotouch sim tweezer`: simulate a bead in a
/// fixed trap, report variances and the aliased Lorentzian fitted to each
/// axis' blocked periodogram by `kilotouch_dsp::trap_psd::fit_power_spectrum`
/// (the trap calibration's least-squares fit, pylake's method, with its
/// n/(n + 1) bias correction of D), averaged over x and y.
pub fn simulate_tweezer(args: &TweezerSimArgs) -> anyhow::Result<TweezerSimReport> {
    let bad = |name: &'static str, value: f64, reason: &str| {
        anyhow::anyhow!("invalid `{name}` = {value}: {reason}")
    };
    if !(args.duration_s.is_finite() && args.duration_s > 0.0) {
        return Err(bad("duration_s", args.duration_s, "must be finite and > 0"));
    }
    if !(args.fs_hz.is_finite() && args.fs_hz > 0.0) {
        return Err(bad("fs_hz", args.fs_hz, "must be finite and > 0"));
    }
    let n = (args.duration_s * args.fs_hz).round();
    if !(2048.0..=2.0e9).contains(&n) {
        return Err(bad(
            "duration_s",
            args.duration_s,
            "need between 2048 and 2e9 samples",
        ));
    }
    let n = n as usize;
    let params = TweezerParams {
        radius_m: args.radius_um * 1e-6,
        viscosity_pa_s: args.viscosity_pa_s,
        temperature_k: args.temperature_k,
        stiffness_n_per_m: args.stiffness_pn_um * 1e-6,
        wall_distance_m: args.wall_distance_um.map(|h| h * 1e-6),
        escape_distance_m: f64::MAX,
        integrator: args.integrator,
        seed: args.seed,
        ..TweezerParams::paper_default()
    };
    params.validate()?;
    let dt_over_tau = 1.0 / (args.fs_hz * params.tau());
    if args.integrator == TweezerIntegrator::Euler && dt_over_tau >= 2.0 {
        anyhow::bail!(
            "Euler–Maruyama is unstable for dt/τ = {dt_over_tau:.3} ≥ 2; use the exact integrator"
        );
    }
    let mut tw = SimTweezer::new(params.clone(), args.fs_hz)?;
    // Start from the stationary distribution.
    tw.start_stationary();
    let mut xs = Vec::with_capacity(n);
    let mut ys = Vec::with_capacity(n);
    for _ in 0..n {
        let s = tw.step([0.0, 0.0]);
        xs.push(s.bead_m[0]);
        ys.push(s.bead_m[1]);
    }
    let var = |v: &[f64]| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64
    };
    let points_per_block = (n / BLOCKS).max(MIN_POINTS_PER_BLOCK);
    let f_lo = 0.0;
    let f_hi = 0.5 * args.fs_hz * (1.0 - 2.0 / n as f64);
    let model = PsdModel {
        shape: SpectrumShape::AliasedLorentzian { fs_hz: args.fs_hz },
        diode: false,
    };
    let fit = |v: &[f64]| -> anyhow::Result<(f64, f64)> {
        let pg = Periodogram::new(v, args.fs_hz)?;
        let opts = PsdFitOptions::default();
        let fit = fit_power_spectrum(&pg, f_lo, f_hi, points_per_block, &model, &opts)?;
        Ok((fit.corner_hz(), fit.d()))
    };
    let ((fc_x, d_x), (fc_y, d_y)) = (fit(&xs)?, fit(&ys)?);
    Ok(TweezerSimReport {
        var_x_m2: var(&xs),
        var_y_m2: var(&ys),
        fc_fit_hz: 0.5 * (fc_x + fc_y),
        d_fit_m2_s: 0.5 * (d_x + d_y),
        fc_theory_hz: params.corner_hz(),
        var_theory_m2: params.variance_theory(),
        d_theory_m2_s: params.diffusion(),
        gamma_n_s_m: params.gamma_free(),
        wall_factor: params.wall_factor(),
        dt_over_tau,
        n_samples: n,
        points_per_block,
        fit_band_hz: [f_lo, f_hi],
        integrator: args.integrator,
        seed: args.seed,
    })
}
