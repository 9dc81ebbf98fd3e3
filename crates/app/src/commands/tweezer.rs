//! `kilotouch tweezer calibrate|record`: passive power-spectral calibration
//! of an optical trap (Berg-Sørensen & Flyvbjerg 2004, pylake's
//! formulation) from a CSV detector record, and the recording of such a
//! record from a live (or emulated, or simulated) tweezer.

use crate::output::emit;
use anyhow::Context;
use clap::Subcommand;
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::RigSpec;
use kilotouch_rig::tweezer::TrapCalibrationRecord;
use kilotouch_rig::tweezer::calibration::{
    DEFAULT_BEAD_DENSITY_KG_M3, DEFAULT_FLUID_DENSITY_KG_M3, TrapCalibrationSettings,
    calibrate_trap,
};
use kilotouch_rig::units::{to_pn_per_um, to_pn_per_v, to_um_per_v};
use kilotouch_study::csvio::read_columns;
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
    /// Where the trap is held: `free` (free solution: the rig file's obstacles left out, as a
    /// trap is calibrated away from the specimen) or X,Y in µm in the rig file's scene, obstacles
    /// included; the record warns when an obstacle is close enough to bias κ by more than 1 %.
    #[arg(long, value_parser = parse_spot, default_value = "free", value_name = "free|X,Y")]
    pub trap_um: TrapSpot,
    /// Output CSV (columns t_s, x_v, y_v).
    #[arg(long)]
    pub out: PathBuf,
    /// Also calibrate both axes with the settings the rig file implies (its bead, medium and
    /// detector; 10 Hz to Nyquist) and write the trap calibration (JSON) that `kilotouch study
    /// run --trap-calibration` applies. Refused, and not written, when the fit fails the
    /// checks the Rig page applies (the CSV is kept).
    #[arg(long, value_name = "FILE")]
    pub calibration_out: Option<PathBuf>,
    /// Print JSON (sample rate, samples, file).
    #[arg(long)]
    pub json: bool,
}

/// Where `kilotouch tweezer record` holds the trap.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TrapSpot {
    /// Free solution: the rig file's obstacles left out, trap at (0, 0).
    Free,
    /// This position (µm) in the rig file's scene, obstacles included.
    At(f64, f64),
}

fn parse_spot(s: &str) -> Result<TrapSpot, String> {
    if s.trim() == "free" {
        return Ok(TrapSpot::Free);
    }
    let (x, y) = parse_range(s).map_err(|_| format!("`{s}`: expected `free` or X,Y in µm"))?;
    if !(x.is_finite() && y.is_finite()) {
        return Err(format!("`{s}`: the trap position must be finite"));
    }
    Ok(TrapSpot::At(x, y))
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

/// JSON of `kilotouch tweezer calibrate`: the calibration's fields and the
/// warnings (a record taken next to a known surface).
#[derive(Debug, serde::Serialize)]
struct CalibrateReport {
    #[serde(flatten)]
    cal: kilotouch_rig::tweezer::TrapCalibration,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    warnings: Vec<String>,
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
    let warnings: Vec<String> = record_surface_warning(&a.file, &a.column)
        .into_iter()
        .collect();
    for m in &warnings {
        eprintln!("warning: {m}");
    }
    let report = CalibrateReport {
        cal: cal.clone(),
        warnings,
    };
    emit(a.json, &report, || {
        let mut t = format!(
            "Trap calibration of `{}` ({} samples at {} Hz; {}; {} points of {} bins)\n",
            a.column,
            cols.data[0].len(),
            a.fs,
            kilotouch_rig::tweezer::record::model_name(&s),
            cal.n_points,
            a.points_per_block
        );
        t += &format!(
            "  f_c   = {:.3} ± {:.3} Hz\n",
            cal.corner_hz, cal.corner_se_hz
        );
        t += &format!(
            "  D     = {:.5e} ± {:.2e} V²/s\n",
            cal.diffusion_v2_s, cal.diffusion_se_v2_s
        );
        t += &format!(
            "  κ     = {:.4} ± {:.4} pN/µm\n",
            to_pn_per_um(cal.kappa_n_per_m),
            to_pn_per_um(cal.kappa_se_n_per_m)
        );
        t += &format!(
            "  R_d   = {:.5} ± {:.5} µm/V\n",
            to_um_per_v(cal.rd_m_per_v),
            to_um_per_v(cal.rd_se_m_per_v)
        );
        t += &format!("  R_f   = {:.4} pN/V\n", to_pn_per_v(cal.rf_n_per_v));
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
    /// A live tweezer's link: round trip at connection, command lead.
    link: Option<kilotouch_rig::tweezer::record::LinkTiming>,
    /// `free` or `scene`.
    spot: &'static str,
    trap_um: [f64; 2],
    /// Predicted drag of the nearest obstacle at the spot (x, y), relative
    /// to free solution (simulated tweezer only).
    drag_factor: Option<[f64; 2]>,
    /// Predicted relative error of κ (x, y).
    kappa_bias: Option<[f64; 2]>,
    /// The calibration of both axes (with `--calibration-out`).
    calibration: Option<RecordCalibration>,
    warnings: Vec<String>,
}

/// The trap calibration `kilotouch tweezer record --calibration-out` wrote.
#[derive(Debug, Clone, serde::Serialize)]
struct RecordCalibration {
    /// The JSON file written.
    file: String,
    /// κ of both axes, inverse-variance weighted, N/m (JSON key
    /// `kappa_pn_um`, pN/µm).
    #[serde(rename = "kappa_pn_um", with = "kilotouch_rig::units::pn_per_um")]
    kappa_n_per_m: f64,
    /// Its standard error, N/m (JSON key `kappa_se_pn_um`, pN/µm).
    #[serde(rename = "kappa_se_pn_um", with = "kilotouch_rig::units::pn_per_um")]
    kappa_se_n_per_m: f64,
    /// R_d per axis (x, y), m/V (JSON key `rd_um_per_v`, µm/V).
    #[serde(rename = "rd_um_per_v", with = "kilotouch_rig::units::um_per_v")]
    rd_m_per_v: [f64; 2],
    /// Corner frequency per axis (x, y), Hz (JSON key `fc_hz`).
    #[serde(rename = "fc_hz")]
    corner_hz: [f64; 2],
}

fn record(a: &RecordArgs) -> anyhow::Result<()> {
    let spec: RigSpec = a.rig.parse()?;
    let mut rc = RigConfig::load_or_default(a.rig_config.as_deref())?;
    let (spot, trap_um) = match a.trap_um {
        TrapSpot::Free => {
            rc.tweezer.obstacles.clear();
            ("free", [0.0, 0.0])
        }
        TrapSpot::At(x, y) => ("scene", [x, y]),
    };
    let trap = trap_um.map(|v| v * 1e-6);
    let rec = kilotouch_rig::tweezer::record::record(&spec, &rc, a.duration_s, trap, &mut |_| {})?;
    let (fs, n, [x, y]) = (rec.fs_hz, rec.volts[0].len(), &rec.volts);
    let mut warnings = Vec::new();
    if let Some(d) = rec.surface.filter(|d| d.biased()) {
        warnings.push(format!(
            "{}; record in free solution (--trap-um free) or farther from the obstacles",
            d.describe()
        ));
    }
    let file =
        std::fs::File::create(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let mut w = std::io::BufWriter::new(file);
    writeln!(
        w,
        "# kilotouch tweezer record: {}, trap at ({}, {}) µm{}",
        rec.source,
        trap_um[0],
        trap_um[1],
        match (&spec, spot) {
            (RigSpec::Sim, "free") => " in free solution",
            (RigSpec::Sim, _) => " in the rig file's scene",
            _ => "",
        }
    )?;
    if let Some(d) = &rec.surface {
        writeln!(
            w,
            "{}",
            kilotouch_rig::tweezer::record::surface_drag_line(d)
        )?;
    }
    writeln!(w, "t_s,x_v,y_v")?;
    for (i, (xv, yv)) in x.iter().zip(y).enumerate() {
        writeln!(w, "{},{xv:e},{yv:e}", i as f64 / fs)?;
    }
    w.flush()
        .with_context(|| format!("writing {}", a.out.display()))?;
    for m in &warnings {
        eprintln!("warning: {m}");
    }
    let calibration = match &a.calibration_out {
        Some(path) => Some(write_calibration(&rec, &rc, path, &a.out)?),
        None => None,
    };
    emit(
        a.json,
        &RecordReport {
            file: a.out.display().to_string(),
            fs_hz: fs,
            n_samples: n,
            link: rec.link,
            spot,
            trap_um,
            drag_factor: rec.surface.map(|d| d.drag_factor),
            kappa_bias: rec.surface.map(|d| d.kappa_bias()),
            calibration: calibration.as_ref().map(|(c, _)| c.clone()),
            warnings: warnings.clone(),
        },
        || {
            let mut t = format!("{n} samples at {fs} Hz written to {}\n", a.out.display());
            if let Some((c, _)) = &calibration {
                t += &format!(
                    "trap calibration: κ = {:.4} ± {:.4} pN/µm, R_d = ({:.5}, {:.5}) µm/V, \
                     f_c = ({:.1}, {:.1}) Hz, written to {}\n",
                    to_pn_per_um(c.kappa_n_per_m),
                    to_pn_per_um(c.kappa_se_n_per_m),
                    to_um_per_v(c.rd_m_per_v[0]),
                    to_um_per_v(c.rd_m_per_v[1]),
                    c.corner_hz[0],
                    c.corner_hz[1],
                    c.file
                );
            }
            t
        },
    )
}

/// Calibrate both axes of `rec` with the settings the rig file `rc`
/// implies ([`kilotouch_rig::tweezer::record::default_settings`]) and write the record
/// to `path` (JSON, [`TrapCalibrationRecord`]) when it passes the checks of
/// an applicable calibration; `csv` (the record's file, kept) is named in
/// the refusal.
fn write_calibration(
    rec: &kilotouch_rig::tweezer::record::DetectorRecord,
    rc: &RigConfig,
    path: &std::path::Path,
    csv: &std::path::Path,
) -> anyhow::Result<(RecordCalibration, TrapCalibrationRecord)> {
    let settings = kilotouch_rig::tweezer::record::default_settings(rc);
    let (cal, _) = kilotouch_rig::tweezer::record::calibrate_axes(rec, &settings)
        .with_context(|| format!("calibrating the record {}", csv.display()))?;
    if let Err(why) = cal.check() {
        anyhow::bail!(
            "the trap calibration was not written to {}: {why} (the record is kept in {}; \
             calibrate it with other settings with `kilotouch tweezer calibrate`)",
            path.display(),
            csv.display()
        );
    }
    let text = serde_json::to_string_pretty(&cal)?;
    std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))?;
    Ok((
        RecordCalibration {
            file: path.display().to_string(),
            kappa_n_per_m: cal.kappa_n_per_m,
            kappa_se_n_per_m: cal.kappa_se_n_per_m,
            rd_m_per_v: cal.rd_m_per_v,
            corner_hz: [cal.x.corner_hz, cal.y.corner_hz],
        },
        cal,
    ))
}

/// Read a trap calibration written by `kilotouch tweezer record
/// --calibration-out`.
///
/// # Errors
/// The file cannot be read, or is not such a record (the parser's line and
/// column named).
pub fn read_calibration(path: &std::path::Path) -> anyhow::Result<TrapCalibrationRecord> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| {
        anyhow::anyhow!(
            "{}:{}:{}: not a trap calibration (as `kilotouch tweezer record --calibration-out` \
             writes): {e}",
            path.display(),
            e.line(),
            e.column()
        )
    })
}

/// The surface-drag warning for column `column` of the record `file`
/// (written by `kilotouch tweezer record` next to a known surface), if the
/// record's header says the spot biases κ by more than 1 %.
fn record_surface_warning(file: &std::path::Path, column: &str) -> Option<String> {
    use std::io::BufRead;
    let f = std::fs::File::open(file).ok()?;
    let factors = std::io::BufReader::new(f)
        .lines()
        .map_while(Result::ok)
        .take_while(|l| l.starts_with('#'))
        .find_map(|l| kilotouch_rig::tweezer::record::parse_surface_drag_line(&l))?;
    let axes: &[usize] = match column {
        "x_v" => &[0],
        "y_v" => &[1],
        _ => &[0, 1],
    };
    let worst = axes
        .iter()
        .map(|&k| 1.0 / factors[k] - 1.0)
        .max_by(|a, b| a.abs().total_cmp(&b.abs()))?;
    (worst.abs() > kilotouch_rig::tweezer::KAPPA_BIAS_WARN).then(|| {
        format!(
            "the record was taken next to an obstacle whose drag biases κ of `{column}` by about \
             {:+.1} % (the record's header says why); calibrate a record taken in free solution \
             (`kilotouch tweezer record --trap-um free`)",
            100.0 * worst
        )
    })
}
