//! `kilotouch rig …`: rig files and rig checks.

use anyhow::Context;
use clap::Subcommand;
use kilotouch_rig::AnyRig;
use kilotouch_rig::RigConfig;
use kilotouch_rig::backend::Device;
use kilotouch_rig::config::default_config_text;
use kilotouch_rig::coupling::{ChainSource, LoopChain};
use kilotouch_rig::device::RigSpec;
use kilotouch_rig::device::{ActuatorFrame, FrameFlags, Rig, SensorFrame};
use kilotouch_rig::serial::LinkStats;
use kilotouch_rig::stability::{MAX_LATENCY_S, StabilityReport, analyse_with_latency};
use serde::Serialize;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use crate::output::emit;

/// `kilotouch rig` subcommands.
#[derive(Debug, Subcommand)]
pub enum RigCommand {
    /// Print the default rig file (TOML, SI units; parameters named after the paper's Table 2).
    DefaultConfig,
    /// List audio devices (id for `--rig audio:ID`, name, channels, rates); `audio` feature.
    #[cfg(feature = "audio")]
    ListAudio {
        /// JSON output.
        #[arg(long)]
        json: bool,
    },
    /// Stream zero commands to a rig for a while and report frames, lost frames, CRC errors and the rate.
    Check(CheckArgs),
    /// Closed-loop stability: gain and phase margins of P and D (worst case over the hand range,
    /// free and pressed), critical trap stiffness and the largest safe force scale; with
    /// `--latency-ms`, for a loop with that much extra delay (a live rig's block and link).
    Margins(MarginsArgs),
}

/// The rig and the chain condition D runs on it (`--rig-config`,
/// `--calibration`), shared by every command that closes the loop.
#[derive(Debug, Clone, clap::Args)]
pub struct LoopArgs {
    /// Rig file (default: the built-in rig).
    #[arg(long)]
    pub rig_config: Option<PathBuf>,
    /// Calibration file (`kilotouch calibrate --out`) whose chain D runs
    /// (default: the model's as-designed chain).
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
}

impl LoopArgs {
    /// The rig file (or the built-in one) and the chain D runs with it; a
    /// calibration made for another rig file is refused.
    pub fn load(&self) -> anyhow::Result<(RigConfig, LoopChain)> {
        let cfg = RigConfig::load_or_default(self.rig_config.as_ref())?;
        let chain = match &self.calibration {
            Some(p) => LoopChain::load(p, &cfg)?,
            None => LoopChain::as_designed(&cfg)?,
        };
        Ok((cfg, chain))
    }
}

/// Arguments of `kilotouch rig margins`.
#[derive(Debug, clap::Args)]
pub struct MarginsArgs {
    /// Rig and chain.
    #[command(flatten)]
    pub rig: LoopArgs,
    /// Extra loop delay, ms, on top of the simulated loop's one sample: a live rig's block
    /// length plus its link's command lead. Rounded up to whole samples; 0 to 100 ms.
    #[arg(
        long,
        default_value_t = 0.0,
        value_name = "MS",
        allow_negative_numbers = true
    )]
    pub latency_ms: f64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

impl MarginsArgs {
    /// `--latency-ms` in seconds, checked: finite, ≥ 0, at most
    /// [`MAX_LATENCY_S`].
    pub fn latency_s(&self) -> anyhow::Result<f64> {
        let ms = self.latency_ms;
        let max_ms = 1e3 * MAX_LATENCY_S;
        if !(ms.is_finite() && (0.0..=max_ms).contains(&ms)) {
            anyhow::bail!(
                "--latency-ms must be a number of milliseconds from 0 to {max_ms}, got {ms}"
            );
        }
        Ok(1e-3 * ms)
    }
}

/// `kilotouch rig margins --json`: the stability report and the chain it is for.
#[derive(Debug, Serialize)]
pub struct MarginsReport {
    /// The analysis.
    #[serde(flatten)]
    pub report: StabilityReport,
    /// Where the chain came from.
    pub chain: ChainSource,
    /// The extra loop delay asked for (`--latency-ms`), ms; the report's
    /// `latency_samples` is it in whole samples.
    pub latency_ms: f64,
}

/// Arguments of `kilotouch rig check`.
#[derive(Debug, clap::Args)]
pub struct CheckArgs {
    /// Rig: `sim` (paced simulation), `serial:PATH[,baud=N][,timeout-ms=N]`, `audio[:DEVICE]`.
    #[arg(long, default_value = "sim")]
    pub rig: String,
    /// Streaming time, s.
    #[arg(long, default_value_t = 5.0)]
    pub duration: f64,
    /// Frames per block.
    #[arg(long, default_value_t = 100)]
    pub block: usize,
    /// Stop after this many blocks (within --duration, which stays the hard bound).
    #[arg(long)]
    pub blocks: Option<u64>,
    /// Rig file of the simulated rig.
    #[arg(long)]
    pub rig_config: Option<PathBuf>,
    /// Verdict: fail when more than this fraction of the frames is lost.
    #[arg(long, default_value_t = CheckArgs::DEFAULT_MAX_LOSS)]
    pub max_loss: f64,
    /// Verdict: fail when the CRC errors exceed this fraction of the frames.
    #[arg(long, default_value_t = CheckArgs::DEFAULT_MAX_CRC)]
    pub max_crc_errors: f64,
    /// Verdict: fail when more than this fraction of the samples ran with a
    /// late (held) command after the start-up window (the first 100 ms).
    #[arg(long, default_value_t = CheckArgs::DEFAULT_MAX_LATE)]
    pub max_late: f64,
    /// Verdict: fail when more than this fraction of the frames carries a
    /// fault flag (accelerometer clipped, command limited, end stop,
    /// non-finite command).
    #[arg(long, default_value_t = CheckArgs::DEFAULT_MAX_FLAGGED)]
    pub max_flagged: f64,
    /// Verdict: fail when the measured rate is off the nominal (HELLO)
    /// rate by more than this fraction.
    #[arg(long, default_value_t = CheckArgs::DEFAULT_RATE_TOLERANCE)]
    pub rate_tolerance: f64,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

impl CheckArgs {
    /// Default loss limit: 0.1 % of the frames (10 per second at 10 kHz).
    pub const DEFAULT_MAX_LOSS: f64 = 1e-3;
    /// Default CRC-error limit: 0.1 % of the frames.
    pub const DEFAULT_MAX_CRC: f64 = 1e-3;
    /// Default late-command limit: 0.1 % of the samples.
    pub const DEFAULT_MAX_LATE: f64 = 1e-3;
    /// Default limit of frames with a fault flag: 0.1 % (the check streams
    /// zero commands to a handle at rest: nothing should be flagged).
    pub const DEFAULT_MAX_FLAGGED: f64 = 1e-3;
    /// Default rate tolerance: ±5 % of the nominal rate.
    pub const DEFAULT_RATE_TOLERANCE: f64 = 0.05;
    /// Samples the device may run on its watchdog's safe outputs: none (a
    /// watchdog sample means the host did not feed the device in time).
    pub const MAX_WATCHDOG_SAMPLES: u64 = 0;
    /// Time past `--duration` after which a rig that has not delivered
    /// its block is declared stalled: `--duration` is a hard bound.
    pub const GRACE: Duration = Duration::from_secs(1);
}

/// Result of `rig check` (JSON with `--json`).
#[derive(Debug, Clone, Serialize)]
pub struct CheckReport {
    /// The rig checked.
    pub rig: String,
    /// Device name.
    pub device: String,
    /// Device firmware.
    pub firmware: String,
    /// Nominal sample rate, Hz.
    pub nominal_rate_hz: f64,
    /// Blocks exchanged (`process_block` calls that returned).
    pub blocks: u64,
    /// Frames exchanged (received + lost).
    pub frames: u64,
    /// Frames received.
    pub received: u64,
    /// Frames lost (sequence gaps).
    pub lost: u64,
    /// Candidate frames with a bad CRC (serial rigs).
    pub crc_errors: u64,
    /// Bytes skipped while resynchronising (serial rigs).
    pub bytes_skipped: u64,
    /// Samples executed by the device with a held (late) command.
    pub late_commands: u64,
    /// Of these, after the first 100 ms (a command lead keeps a
    /// free-running device in commands once running: only start-up is late).
    pub late_commands_after_startup: u64,
    /// The command lead, samples (serial rigs; 0: block-synchronous).
    pub command_lead_samples: u64,
    /// The link's round trip measured at connection, ms (serial rigs).
    pub round_trip_ms: Option<f64>,
    /// late_commands_after_startup / frames (the verdict's late fraction).
    pub late_fraction: f64,
    /// Frames with a fault flag (clipped, limited, end stop, non-finite).
    pub flagged: u64,
    /// flagged / frames.
    pub flagged_fraction: f64,
    /// Samples the device ran on its watchdog's safe outputs.
    pub watchdog_samples: u64,
    /// Samples received outside the block waited for (stray sequence
    /// numbers).
    pub stray_samples: u64,
    /// Measured rate: frames / wall time of the streaming, Hz.
    pub rate_hz: f64,
    /// Wall time of the streaming, s.
    pub duration_s: f64,
    /// Longest `process_block` call, ms.
    pub max_block_ms: f64,
    /// lost / frames (0 without frames).
    pub loss_fraction: f64,
    /// crc_errors / frames (crc_errors when no frame arrived).
    pub crc_error_fraction: f64,
    /// The loss limit of the verdict.
    pub max_loss: f64,
    /// The CRC-error limit of the verdict.
    pub max_crc_errors: f64,
    /// The late-command limit of the verdict.
    pub max_late: f64,
    /// The fault-flag limit of the verdict.
    pub max_flagged: f64,
    /// The rate tolerance of the verdict (fraction of the nominal rate).
    pub rate_tolerance: f64,
    /// Verdict: streaming ended normally within both limits.
    pub passed: bool,
    /// Why the check failed (`None` when it passed).
    pub failure: Option<String>,
}

impl CheckReport {
    fn table(&self) -> String {
        let verdict = match &self.failure {
            None => format!(
                "  verdict   PASS (loss {:.3} % ≤ {:.3} %, CRC errors {:.3} % ≤ {:.3} %, late \
                 {:.3} % ≤ {:.3} %, flagged {:.3} % ≤ {:.3} %, no watchdog sample, rate within \
                 ±{:.1} %)\n",
                100.0 * self.loss_fraction,
                100.0 * self.max_loss,
                100.0 * self.crc_error_fraction,
                100.0 * self.max_crc_errors,
                100.0 * self.late_fraction,
                100.0 * self.max_late,
                100.0 * self.flagged_fraction,
                100.0 * self.max_flagged,
                100.0 * self.rate_tolerance
            ),
            Some(why) => format!("  verdict   FAIL: {why}\n"),
        };
        verdict
            + &format!(
                "rig check {} (`{}`, {})\n  frames    {} ({} received, {} lost)\n  \
             crc errors {} ({} bytes skipped)\n  late commands {}\n  flagged   {} \
             (watchdog samples {}, stray samples {})\n  rate      {:.1} Hz (nominal {:.0} Hz) \
             over {:.2} s, longest block {:.2} ms\n",
                self.rig,
                self.device,
                self.firmware,
                self.frames,
                self.received,
                self.lost,
                self.crc_errors,
                self.bytes_skipped,
                self.late_commands,
                self.flagged,
                self.watchdog_samples,
                self.stray_samples,
                self.rate_hz,
                self.nominal_rate_hz,
                self.duration_s,
                self.max_block_ms
            )
    }
}

/// Counters of a streaming run (kept when it ends in an error).
#[derive(Debug, Clone, Copy, Default)]
struct Streamed {
    blocks: u64,
    frames: u64,
    lost: u64,
    flagged: u64,
    elapsed_s: f64,
    max_block_s: f64,
    /// Late commands after the start-up window ([`STARTUP_S`]).
    late_after_startup: u64,
}

/// Flags of a frame that report a fault of the device or its commands.
const FAULT_FLAGS: u8 = FrameFlags::CLIPPED
    | FrameFlags::LIMITED
    | FrameFlags::END_STOP
    | FrameFlags::NONFINITE_COMMAND;

/// The start-up window of a check, s: the device runs from START while the
/// host's first commands travel (and, with a command lead, while the lead
/// fills), so late commands there are expected.
const STARTUP_S: f64 = 0.1;

/// Stream zero commands through `rig` for `duration` s in blocks of
/// `block`. The counters are returned with the error that ended the run,
/// if one did.
fn stream(
    rig: &mut dyn Rig,
    duration: f64,
    block: usize,
    blocks: Option<u64>,
) -> (Streamed, Option<anyhow::Error>) {
    let cmds = vec![ActuatorFrame::default(); block];
    let mut sens = vec![SensorFrame::default(); block];
    let mut s = Streamed::default();
    if let Err(e) = rig.start() {
        return (s, Some(e.into()));
    }
    // The exchange runs real-time where the system allows it, as the
    // engine's loop does.
    let rt = kilotouch_rig::realtime::promote_current_thread().is_realtime();
    let t0 = Instant::now();
    let mut error = None;
    let mut late_at_startup = None;
    let mut done = 0u64;
    while t0.elapsed().as_secs_f64() < duration && blocks.is_none_or(|n| done < n) {
        done += 1;
        if late_at_startup.is_none() && t0.elapsed().as_secs_f64() >= STARTUP_S {
            late_at_startup = Some(rig.status().late_commands);
        }
        let tb = Instant::now();
        match rig.process_block(&cmds, &mut sens) {
            Ok(r) => {
                s.blocks += 1;
                s.frames += r.frames as u64;
                s.lost += u64::from(r.lost_frames);
                s.flagged += sens[..r.frames.min(sens.len())]
                    .iter()
                    .filter(|f| !f.flags.has(FrameFlags::LOST) && f.flags.0 & FAULT_FLAGS != 0)
                    .count() as u64;
            }
            Err(e) => error = Some(e.into()),
        }
        s.max_block_s = s.max_block_s.max(tb.elapsed().as_secs_f64());
        if error.is_some() {
            break;
        }
    }
    s.elapsed_s = t0.elapsed().as_secs_f64();
    let late = rig.status().late_commands;
    s.late_after_startup = late - late_at_startup.unwrap_or(late).min(late);
    if rt {
        kilotouch_rig::realtime::demote_current_thread();
    }
    if let Err(e) = rig.stop() {
        error.get_or_insert(e.into());
    }
    (s, error)
}

/// The verdict on a run's counters: `Some(why)` when a limit is exceeded.
fn verdict(r: &CheckReport) -> Option<String> {
    let mut why = Vec::new();
    if r.frames == 0 {
        why.push("no frame was exchanged".to_owned());
    }
    if r.loss_fraction > r.max_loss {
        why.push(format!(
            "{:.3} % of the frames lost ({} of {}), limit {:.3} % (--max-loss)",
            100.0 * r.loss_fraction,
            r.lost,
            r.frames,
            100.0 * r.max_loss
        ));
    }
    if r.crc_error_fraction > r.max_crc_errors {
        why.push(format!(
            "{} CRC errors, {:.3} % of the frames, limit {:.3} % (--max-crc-errors)",
            r.crc_errors,
            100.0 * r.crc_error_fraction,
            100.0 * r.max_crc_errors
        ));
    }
    if r.late_fraction > r.max_late {
        why.push(format!(
            "{} late commands after start-up, {:.3} % of the samples, limit {:.3} % \
             (--max-late)",
            r.late_commands_after_startup,
            100.0 * r.late_fraction,
            100.0 * r.max_late
        ));
    }
    if r.flagged_fraction > r.max_flagged {
        why.push(format!(
            "{} frames with a fault flag (clipped, limited, end stop or non-finite), {:.3} % of \
             the frames, limit {:.3} % (--max-flagged)",
            r.flagged,
            100.0 * r.flagged_fraction,
            100.0 * r.max_flagged
        ));
    }
    if r.watchdog_samples > CheckArgs::MAX_WATCHDOG_SAMPLES {
        why.push(format!(
            "{} samples ran on the device watchdog's safe outputs (limit {})",
            r.watchdog_samples,
            CheckArgs::MAX_WATCHDOG_SAMPLES
        ));
    }
    if r.stray_samples as f64 > r.max_loss * r.frames as f64 {
        why.push(format!(
            "{} samples with sequence numbers outside the blocks waited for, limit {:.3} % of \
             the frames (--max-loss)",
            r.stray_samples,
            100.0 * r.max_loss
        ));
    }
    if r.frames > 0 && r.nominal_rate_hz > 0.0 {
        let off = r.rate_hz / r.nominal_rate_hz - 1.0;
        if off.is_nan() || off.abs() > r.rate_tolerance {
            why.push(format!(
                "measured rate {:.1} Hz is {:+.1} % off the nominal {:.0} Hz the device \
                 announced, limit ±{:.1} % (--rate-tolerance)",
                r.rate_hz,
                100.0 * off,
                r.nominal_rate_hz,
                100.0 * r.rate_tolerance
            ));
        }
    }
    (!why.is_empty()).then(|| why.join("; "))
}

/// Runs the check; the report always carries the counters, with the error
/// that ended the run (if any) as the second value.
fn check(a: &CheckArgs) -> anyhow::Result<(CheckReport, Option<anyhow::Error>)> {
    if !(a.duration.is_finite() && a.duration > 0.0 && a.duration <= 86_400.0) {
        anyhow::bail!("--duration must be in (0, 86400] s, got {}", a.duration);
    }
    if !(1..=65_536).contains(&a.block) {
        anyhow::bail!("--block must be in 1..=65536, got {}", a.block);
    }
    if a.blocks == Some(0) {
        anyhow::bail!("--blocks must be at least 1");
    }
    for (name, v) in [
        ("--max-loss", a.max_loss),
        ("--max-crc-errors", a.max_crc_errors),
        ("--max-late", a.max_late),
        ("--max-flagged", a.max_flagged),
        ("--rate-tolerance", a.rate_tolerance),
    ] {
        if !(0.0..=1.0).contains(&v) {
            anyhow::bail!("{name} must be a fraction in [0, 1], got {v}");
        }
    }
    let spec: RigSpec = a.rig.parse()?;
    let rc = RigConfig::load_or_default(a.rig_config.as_ref())?;
    let mut rig = match &spec {
        // The simulated rig paced by the wall clock, as a device would be.
        RigSpec::Sim => AnyRig::sim_paced(&rc, 0.5)?,
        _ => kilotouch_rig::open_rig(&spec, &rc)?,
    };
    if let Device::Serial(r) = rig.device_mut() {
        // START may take up to the handshake time-out; then the streaming
        // time and the grace: a hard bound on every block.
        let hs = match &spec {
            RigSpec::Serial(c) => c.handshake_timeout,
            _ => Duration::ZERO,
        };
        r.set_deadline(Some(
            Instant::now() + hs + Duration::from_secs_f64(a.duration) + CheckArgs::GRACE,
        ));
    }
    let lead = u64::from(
        rig.loop_delay_samples(a.block)
            .saturating_sub(a.block as u32),
    ) * u64::from(rig.is_live());
    let round_trip_ms = rig.round_trip_s().map(|s| s * 1e3);
    let (streamed, error) = stream(&mut rig, a.duration, a.block, a.blocks);
    let link = match rig.device() {
        Device::Serial(r) => r.link_stats(),
        _ => LinkStats::default(),
    };
    let id = rig.identity().clone();
    let Streamed {
        blocks,
        frames,
        lost,
        flagged,
        elapsed_s,
        max_block_s,
        late_after_startup,
    } = streamed;
    let ratio = |n: u64| {
        if frames == 0 {
            n as f64
        } else {
            n as f64 / frames as f64
        }
    };
    let mut report = CheckReport {
        rig: spec.describe(),
        device: id.name,
        firmware: id.firmware,
        nominal_rate_hz: id.sample_rate_hz,
        blocks,
        frames,
        received: frames - lost,
        lost,
        crc_errors: link.crc_errors,
        bytes_skipped: link.bytes_skipped,
        late_commands: link.late_commands,
        late_commands_after_startup: late_after_startup,
        command_lead_samples: lead,
        round_trip_ms,
        late_fraction: ratio(late_after_startup),
        flagged,
        flagged_fraction: ratio(flagged),
        watchdog_samples: link.watchdog_samples,
        stray_samples: link.stray_samples,
        rate_hz: if elapsed_s > 0.0 {
            frames as f64 / elapsed_s
        } else {
            0.0
        },
        duration_s: elapsed_s,
        max_block_ms: 1e3 * max_block_s,
        loss_fraction: ratio(lost),
        crc_error_fraction: ratio(link.crc_errors),
        max_loss: a.max_loss,
        max_crc_errors: a.max_crc_errors,
        max_late: a.max_late,
        max_flagged: a.max_flagged,
        rate_tolerance: a.rate_tolerance,
        passed: false,
        failure: None,
    };
    report.failure = match &error {
        Some(e) => Some(format!("streaming ended early: {e:#}")),
        None => verdict(&report),
    };
    report.passed = report.failure.is_none();
    Ok((report, error))
}

/// Run a `rig` subcommand.
pub fn run(cmd: &RigCommand) -> anyhow::Result<()> {
    match cmd {
        RigCommand::DefaultConfig => {
            print!("{}", default_config_text());
            Ok(())
        }
        #[cfg(feature = "audio")]
        RigCommand::ListAudio { json } => list_audio(*json),
        RigCommand::Check(a) => {
            let ctx = || format!("rig check --rig {}", a.rig);
            let (report, error) = check(a).with_context(ctx)?;
            // The counters are printed whatever the outcome.
            emit(a.json, &report, || report.table())?;
            match (error, &report.failure) {
                (Some(e), _) => Err(e.context(ctx())),
                (None, Some(why)) => Err(anyhow::anyhow!("{}: FAIL: {why}", ctx())),
                (None, None) => Ok(()),
            }
        }
        RigCommand::Margins(a) => {
            let latency_s = a.latency_s()?;
            let (cfg, chain) = a.rig.load()?;
            let report = analyse_with_latency(&cfg, &chain.coefficients, latency_s)
                .context("rig margins")?;
            let out = MarginsReport {
                report,
                chain: chain.source.clone(),
                latency_ms: a.latency_ms,
            };
            emit(a.json, &out, || {
                let mut t = format!("chain: {}\n", chain.source.describe());
                t += &out.report.summary();
                if let Some(why) = out.report.refusal() {
                    t += &format!("NOT SAFE: {why}\n");
                }
                t
            })
        }
    }
}

#[cfg(feature = "audio")]
fn list_audio(json: bool) -> anyhow::Result<()> {
    let devices = kilotouch_rig::audio::list_audio_devices()?;
    if json {
        println!("{}", serde_json::to_string_pretty(&devices)?);
        return Ok(());
    }
    for d in &devices {
        println!("{} ({}): {}", d.id, d.host, d.name);
        for (dir, info) in [("out", &d.output), ("in", &d.input)] {
            if let Some(i) = info {
                println!(
                    "    {dir:>3}: default {} ch {} Hz {}; up to {} ch, {}–{} Hz",
                    i.default_channels,
                    i.default_rate_hz,
                    i.default_format,
                    i.max_channels,
                    i.min_rate_hz,
                    i.max_rate_hz
                );
            }
        }
    }
    Ok(())
}
