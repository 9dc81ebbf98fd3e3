//! `kilotouch sim …`: the simulated rig's models, headless.

use crate::output::{db, emit, parse_freqs, wrap_deg};
use crate::tweezer_sim::{TweezerSimArgs, simulate_tweezer};
use clap::Subcommand;
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::plant::Channel;
use kilotouch_rig::sim::simulate_frf;
use kilotouch_rig::tweezer::TweezerIntegrator;
use serde::Serialize;
use std::path::PathBuf;

/// `kilotouch sim` subcommands.
#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// The model's true (analytic) response from a channel's drive to the tip acceleration.
    Frf(FrfArgs),
    /// Simulate a trapped bead and fit the aliased Lorentzian to its PSD.
    Tweezer(TweezerArgs),
    /// Simulate the hand pressing the bead against an obstacle in closed loop and judge its
    /// stability from the signals (oscillation envelope).
    Press(PressArgs),
}

/// Arguments of `kilotouch sim press`.
#[derive(Debug, clap::Args)]
pub struct PressArgs {
    /// Rig and chain.
    #[command(flatten)]
    pub rig: super::rig::LoopArgs,
    /// Condition: P or D.
    #[arg(long, default_value = "D", value_parser = ["P", "D"])]
    pub condition: String,
    /// Simulated duration, s (approach 0.5 s, settling 0.5 s, then the analysed hold).
    #[arg(long, default_value_t = 5.0)]
    pub duration: f64,
    /// Seed of the noise generators.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// How far past contact the trap is pushed, µm (below the escape distance).
    #[arg(long, default_value_t = 0.8)]
    pub depth_um: f64,
    /// Simulate even when the margins are below the rig file's minimum (the loop is
    /// simulated, never a live rig).
    #[arg(long)]
    pub allow_unstable: bool,
    /// Write the time series (t, force along the pressing direction, gap, handle) to this CSV.
    #[arg(long, value_name = "FILE")]
    pub csv: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// `kilotouch sim press --json`: the verdict from the signals, and what the
/// margin analysis predicted for comparison.
#[derive(Debug, Serialize)]
pub struct PressOutput {
    /// The simulation.
    #[serde(flatten)]
    pub report: kilotouch_rig::press::PressReport,
    /// The analysis' growth of the slowest mode pressed along x with the rig
    /// file's finger, dB/s (for comparison; not used for `stable`).
    pub predicted_growth_db_per_s: f64,
    /// The analysis' verdict for the same case.
    pub predicted_stable: bool,
}

fn press(a: &PressArgs) -> anyhow::Result<()> {
    use anyhow::Context;
    use kilotouch_rig::haptic_loop::Clearance;
    use kilotouch_rig::press::{PressOptions, simulate_press};
    let (cfg, chain) = a.rig.load()?;
    let condition: kilotouch_rig::Condition = a
        .condition
        .parse()
        .map_err(|e: String| anyhow::anyhow!(e))?;
    let report = kilotouch_rig::stability::analyse(&cfg, &chain.coefficients)?;
    let clearance = match Clearance::check(&cfg, &chain) {
        Ok(c) => c,
        Err(e) if a.allow_unstable => {
            eprintln!("warning: {e}; simulating anyway (--allow-unstable)");
            Clearance::overridden(chain.source.clone())
        }
        Err(e) => anyhow::bail!("{e}; pass --allow-unstable to simulate it anyway"),
    };
    let opts = PressOptions {
        condition,
        duration_s: a.duration,
        seed: a.seed,
        depth_m: a.depth_um * 1e-6,
    };
    let (r, trace) = simulate_press(&cfg, &chain, clearance, &opts).context("sim press")?;
    if let Some(path) = &a.csv {
        let mut w = csv::Writer::from_path(path)
            .with_context(|| format!("cannot create {}", path.display()))?;
        w.write_record(["t_s", "force_n", "gap_m", "handle_m"])?;
        for i in 0..trace.t_s.len() {
            w.write_record([
                trace.t_s[i].to_string(),
                trace.force_n[i].to_string(),
                trace.gap_m[i].to_string(),
                trace.handle_m[i].to_string(),
            ])?;
        }
        w.flush()?;
    }
    let predicted = report.condition(condition);
    let out = PressOutput {
        predicted_growth_db_per_s: predicted.map_or(f64::NAN, |c| c.nominal_growth_db_per_s),
        predicted_stable: predicted.is_some_and(|c| c.nominal_stable),
        report: r,
    };
    emit(a.json, &out, || {
        let r = &out.report;
        format!(
            "{} pressed for {} s ({}): {}\n  mean handle force {:.4} N (asked {:.4} N), \
             oscillation {:.4} N rms, envelope growth {:.2} dB/s (analysis: {:.2} dB/s), \
             contact {:.0} %, bead {}\n",
            r.condition,
            r.duration_s,
            r.chain,
            if r.stable { "STABLE" } else { "UNSTABLE" },
            r.handle_force_mean_n,
            r.expected_force_n,
            r.handle_force_osc_rms_n,
            r.growth_db_per_s,
            out.predicted_growth_db_per_s,
            100.0 * r.contact_fraction,
            if r.escaped { "ESCAPED" } else { "kept" },
        )
    })
}

/// Arguments of `kilotouch sim frf`.
#[derive(Debug, clap::Args)]
pub struct FrfArgs {
    /// `low` (Pantograph force, N → m/s²) or `high` (Haptuator drive → m/s²).
    #[arg(long, value_parser = ["low", "high"])]
    pub channel: String,
    /// Rig file (default: the built-in rig, `kilotouch rig default-config`).
    #[arg(long)]
    pub rig_config: Option<PathBuf>,
    /// Comma-separated frequencies in Hz.
    #[arg(long)]
    pub freqs: String,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `kilotouch sim tweezer`.
#[derive(Debug, clap::Args)]
pub struct TweezerArgs {
    /// Simulated duration, s.
    #[arg(long, default_value_t = 10.0)]
    pub duration: f64,
    /// Sample rate, Hz.
    #[arg(long, default_value_t = 10_000.0)]
    pub fs: f64,
    /// Trap stiffness κ, pN/µm.
    #[arg(long, default_value_t = 20.0)]
    pub stiffness_pn_um: f64,
    /// Bead radius, µm.
    #[arg(long, default_value_t = 1.5)]
    pub radius_um: f64,
    /// Temperature, K.
    #[arg(long, default_value_t = 293.15)]
    pub temperature_k: f64,
    /// Viscosity, Pa·s (water at 20 °C: 1.0016e-3).
    #[arg(long, default_value_t = 1.0016e-3)]
    pub viscosity_pa_s: f64,
    /// Bead-centre to coverslip distance, µm (Faxén's correction); none = bulk.
    #[arg(long)]
    pub wall_distance_um: Option<f64>,
    /// Integrator: exact Ornstein–Uhlenbeck or Euler–Maruyama.
    #[arg(long, default_value = "exact", value_parser = ["exact", "euler"])]
    pub integrator: String,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// One point of `sim frf`.
#[derive(Debug, Serialize)]
pub struct FrfPoint {
    /// Frequency, Hz.
    pub f: f64,
    /// Magnitude, dB re 1 (m/s²) per unit drive.
    pub db: f64,
    /// Phase, degrees in (−180, 180].
    pub deg: f64,
}

/// JSON document of `sim frf`.
#[derive(Debug, Serialize)]
pub struct FrfReport {
    /// Points in the order given.
    pub points: Vec<FrfPoint>,
}

/// Run a `sim` subcommand.
pub fn run(cmd: &SimCommand) -> anyhow::Result<()> {
    match cmd {
        SimCommand::Press(a) => press(a),
        SimCommand::Frf(a) => {
            let freqs = parse_freqs(&a.freqs)?;
            let cfg = RigConfig::load_or_default(a.rig_config.as_ref())?;
            let channel: Channel = a.channel.parse()?;
            let report = simulate_frf(&cfg, channel, &freqs)?;
            let points = report
                .points
                .iter()
                .map(|p| FrfPoint {
                    f: p.f_hz,
                    db: db((p.re * p.re + p.im * p.im).sqrt()),
                    deg: wrap_deg(p.im.atan2(p.re).to_degrees()),
                })
                .collect();
            let r = FrfReport { points };
            emit(a.json, &r, || {
                let mut t = format!(
                    "{} channel → tip acceleration, rig `{}` ({})\n{:>10} {:>10} {:>9}\n",
                    a.channel, report.rig_name, report.units, "f [Hz]", "dB", "deg"
                );
                for p in &r.points {
                    t += &format!("{:>10.3} {:>10.3} {:>9.2}\n", p.f, p.db, p.deg);
                }
                t
            })
        }
        SimCommand::Tweezer(a) => {
            let args = TweezerSimArgs {
                duration_s: a.duration,
                fs_hz: a.fs,
                stiffness_pn_um: a.stiffness_pn_um,
                radius_um: a.radius_um,
                temperature_k: a.temperature_k,
                viscosity_pa_s: a.viscosity_pa_s,
                wall_distance_um: a.wall_distance_um,
                integrator: if a.integrator == "euler" {
                    TweezerIntegrator::Euler
                } else {
                    TweezerIntegrator::Exact
                },
                seed: a.seed,
            };
            let r = simulate_tweezer(&args)?;
            emit(a.json, &r, || {
                format!(
                    "variance x {:.4e} m², y {:.4e} m² (theory k_BT/κ = {:.4e} m²)\n\
                     corner frequency: fit {:.2} Hz, theory {:.2} Hz\n\
                     diffusion: fit {:.4e} m²/s, theory {:.4e} m²/s\n\
                     dt/τ = {:.3}, {} samples per axis, seed {}\n",
                    r.var_x_m2,
                    r.var_y_m2,
                    r.var_theory_m2,
                    r.fc_fit_hz,
                    r.fc_theory_hz,
                    r.d_fit_m2_s,
                    r.d_theory_m2_s,
                    r.dt_over_tau,
                    r.n_samples,
                    r.seed
                )
            })
        }
    }
}
