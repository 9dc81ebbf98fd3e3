//! `kilotouch tweezer calibrate|record`: passive power-spectral calibration
//! of an optical trap (Berg-Sørensen & Flyvbjerg 2004, pylake's
//! formulation) from a CSV detector record, and the recording of such a
//! record from a live (or emulated, or simulated) tweezer.

use crate::csvio::read_columns;
use crate::output::emit;
use anyhow::Context;
use clap::Subcommand;
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::RigSpec;
use kilotouch_rig::tweezer::calibration::{
    DEFAULT_BEAD_DENSITY_KG_M3, DEFAULT_FLUID_DENSITY_KG_M3, TrapCalibrationSettings,
    calibrate_trap,
};
use std::io::Write;
use std::path::PathBuf;

/// `kilotouch tweezer` subcommands.
#[derive(Debug, Subcommand)]
pub enum TweezerCommand {
    /// Calibrate a trap from a detector record (CSV, volts): corner frequency, stiffness κ and sensitivities with standard errors.
    Calibrate(CalibrateArgs),
    /// Record the position detector's signals (x_v, y_v) with the trap held still, to CSV.
    Record(RecordArgs),
}

/// Arguments of `kilotouch tweezer calibrate`.
#[derive(Debug, clap::Args)]
pub struct CalibrateArgs {
    /// CSV file with a header row; the column holds the detector signal in volts.
    pub file: PathBuf,
    /// Sample rate of the record, Hz.
    #[arg(long)]
    pub fs: f64,
    /// Column to calibrate.
    #[arg(long)]
    pub column: String,
    /// Bead radius, µm.
    #[arg(long)]
    pub radius_um: f64,
    /// Viscosity of the medium, Pa·s (water at 20 °C: 1.0016e-3).
    #[arg(long)]
    pub viscosity_pa_s: f64,
    /// Temperature, K.
    #[arg(long)]
    pub temperature_k: f64,
    /// Frequency range fitted, Hz: LO,HI (bins in (LO, HI]).
    #[arg(long, value_parser = parse_range)]
    pub fit_range: (f64, f64),
    /// Periodogram bins averaged per block.
    #[arg(long)]
    pub points_per_block: usize,
    /// Fit the hydrodynamically correct spectrum (large beads, high frequencies).
    #[arg(long)]
    pub hydro: bool,
    /// Fit the slow-photodiode filter too (f_diode, α).
    #[arg(long)]
    pub diode: bool,
    /// Fluid density, kg/m³ (with --hydro).
    #[arg(long, default_value_t = DEFAULT_FLUID_DENSITY_KG_M3)]
    pub fluid_density_kg_m3: f64,
    /// Bead density, kg/m³ (with --hydro).
    #[arg(long, default_value_t = DEFAULT_BEAD_DENSITY_KG_M3)]
    pub bead_density_kg_m3: f64,
    /// Bead-centre to coverslip distance, µm (Faxén's correction; with --hydro, the wall term).
    #[arg(long)]
    pub distance_to_surface_um: Option<f64>,
    /// The record was point-sampled without an anti-aliasing filter: fit the aliased Lorentzian.
    #[arg(long)]
    pub aliased: bool,
    /// Write a plot of the spectrum and the fit (PNG).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `kilotouch tweezer record`.
#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// Tweezer: `sim` (the simulated tweezer behind its simulated detector) or `serial:PATH[,…]`.
    #[arg(long, default_value = "sim")]
    pub rig: String,
    /// Rig file (default: the built-in rig): the simulated tweezer and detector.
    #[arg(long)]
    pub rig_config: Option<PathBuf>,
    /// Duration, s.
    #[arg(long)]
    pub duration_s: f64,
    /// Trap position held during the record, µm: X,Y (choose a spot far from obstacles and
    /// surfaces other than the coverslip, whose drag the calibration does not model).
    #[arg(long, value_parser = parse_range, default_value = "0,0")]
    pub trap_um: (f64, f64),
    /// Output CSV (columns t_s, x_v, y_v).
    #[arg(long)]
    pub out: PathBuf,
    /// Print JSON (sample rate, samples, file).
    #[arg(long)]
    pub json: bool,
}

fn parse_range(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s
        .split_once(',')
        .ok_or_else(|| format!("`{s}`: expected LO,HI in Hz, e.g. 100,20000"))?;
    let lo: f64 = a.trim().parse().map_err(|e| format!("`{a}`: {e}"))?;
    let hi: f64 = b.trim().parse().map_err(|e| format!("`{b}`: {e}"))?;
    Ok((lo, hi))
}

impl CalibrateArgs {
    /// The calibration settings in SI units.
    pub fn settings(&self) -> TrapCalibrationSettings {
        TrapCalibrationSettings {
            fs_hz: self.fs,
            radius_m: self.radius_um * 1e-6,
            viscosity_pa_s: self.viscosity_pa_s,
            temperature_k: self.temperature_k,
            fit_range_hz: self.fit_range,
            points_per_block: self.points_per_block,
            hydro: self.hydro,
            diode: self.diode,
            aliased: self.aliased,
            fluid_density_kg_m3: self.fluid_density_kg_m3,
            bead_density_kg_m3: self.bead_density_kg_m3,
            distance_to_surface_m: self.distance_to_surface_um.map(|h| h * 1e-6),
        }
    }
}

/// Run a `kilotouch tweezer` subcommand.
pub fn run(c: &TweezerCommand) -> anyhow::Result<()> {
    match c {
        TweezerCommand::Calibrate(a) => calibrate(a),
        TweezerCommand::Record(a) => record(a),
    }
}

fn calibrate(a: &CalibrateArgs) -> anyhow::Result<()> {
    let cols = read_columns(&a.file, &[a.column.as_str()], &[])?;
    let s = a.settings();
    let (cal, fit) = calibrate_trap(&cols.data[0], &s)
        .with_context(|| format!("calibrating column `{}` of {}", a.column, a.file.display()))?;
    if let Some(p) = &a.plot {
        crate::tweezer_cal::plot_fit(p, &fit, &cal, &s)
            .with_context(|| format!("writing the plot {}", p.display()))?;
    }
    emit(a.json, &cal, || {
        let mut t = format!(
            "Trap calibration of `{}` ({} samples at {} Hz; {}; {} points of {} bins)\n",
            a.column,
            cols.data[0].len(),
            a.fs,
            crate::tweezer_cal::model_name(&s),
            cal.n_points,
            a.points_per_block
        );
        t += &format!("  f_c   = {:.3} ± {:.3} Hz\n", cal.fc_hz, cal.fc_se_hz);
        t += &format!(
            "  D     = {:.5e} ± {:.2e} V²/s\n",
            cal.diffusion_v2_s, cal.diffusion_se_v2_s
        );
        t += &format!(
            "  κ     = {:.4} ± {:.4} pN/µm\n",
            cal.kappa_pn_um, cal.kappa_se_pn_um
        );
        t += &format!(
            "  R_d   = {:.5} ± {:.5} µm/V\n",
            cal.rd_um_per_v, cal.rd_se_um_per_v
        );
        t += &format!("  R_f   = {:.4} pN/V\n", cal.rf_pn_per_v);
        if let (Some(fd), Some(al)) = (cal.f_diode_hz, cal.alpha) {
            t += &format!(
                "  f_diode = {:.1} ± {:.1} Hz, α = {:.4} ± {:.4}\n",
                fd,
                cal.f_diode_se_hz.unwrap_or(f64::NAN),
                al,
                cal.alpha_se.unwrap_or(f64::NAN)
            );
        }
        t += &format!(
            "  χ²/dof = {:.3}, backing {:.1} %\n",
            cal.chi2_per_dof, cal.backing_pct
        );
        t
    })
}

/// JSON of `kilotouch tweezer record`.
#[derive(Debug, serde::Serialize)]
struct RecordReport {
    file: String,
    fs_hz: f64,
    n_samples: usize,
}

fn record(a: &RecordArgs) -> anyhow::Result<()> {
    let spec: RigSpec = a.rig.parse()?;
    let rc = RigConfig::load_or_default(a.rig_config.as_deref())?;
    let trap = [a.trap_um.0 * 1e-6, a.trap_um.1 * 1e-6];
    let rec = crate::tweezer_cal::record(&spec, &rc, a.duration_s, trap, &mut |_| {})?;
    let (fs, n, [x, y]) = (rec.fs_hz, rec.volts[0].len(), &rec.volts);
    let file =
        std::fs::File::create(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let mut w = std::io::BufWriter::new(file);
    writeln!(w, "t_s,x_v,y_v")?;
    for (i, (xv, yv)) in x.iter().zip(y).enumerate() {
        writeln!(w, "{},{xv:e},{yv:e}", i as f64 / fs)?;
    }
    w.flush()
        .with_context(|| format!("writing {}", a.out.display()))?;
    emit(
        a.json,
        &RecordReport {
            file: a.out.display().to_string(),
            fs_hz: fs,
            n_samples: n,
        },
        || format!("{n} samples at {fs} Hz written to {}\n", a.out.display()),
    )
}
