//! `kilotouch study run`: one participant's sitting, headless, on the
//! real-time engine — the simulated rig with the simulated participant, or
//! a live rig (a DAQ or its emulator on a serial port) whose handle a real
//! hand moves (a person, or the emulator's own simulated participant:
//! `kilotouch emulate daq --pty --participant operator:SEED`, hardware in
//! the loop). The same folder, journal, resume and data package as every
//! study; the sitting's device and its measured loop delay are recorded in
//! `session.json`.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::device::{RigSpec, TweezerSpec};
use kilotouch_study::export::{DeviceRecord, SESSION_FILE, read_session};
use kilotouch_study::runner::RunnerConfig;
use serde::Serialize;

use super::progress::Progress;
use crate::engine::{EngineEvent, EngineHandle, EngineOptions};
use crate::output::emit;
use crate::session::{
    FinishReason, ParticipantKind, SessionCommand, SessionEvent, SessionHandle, SessionHealth,
    SessionOptions, Speed, validate_participant_id,
};

/// Arguments of `kilotouch study run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Protocol of a new study: a TOML file, or a built-in name (`paper`,
    /// `blind`). A folder that holds a study runs its own protocol.
    #[arg(long, default_value = "paper")]
    pub protocol: String,
    /// The rig: `sim` (the simulated participant on the simulated rig) or
    /// `serial:PATH[,…]` (a live DAQ or its emulator; the hand at the
    /// handle is real).
    #[arg(long, default_value = "sim")]
    pub rig: String,
    /// The tweezer: `sim` (the simulated tweezer on the host) or
    /// `serial:PATH[,…]` (a live tweezer or its emulator, streaming at the
    /// rig's rate; its command lead enters the stability check).
    #[arg(long, default_value = "sim")]
    pub tweezer: String,
    /// Apply this trap calibration (κ, detector sensitivity R_d) to the
    /// tweezer for the sitting: a JSON file written by `kilotouch tweezer
    /// record --calibration-out` from the same tweezer. Refused when its fit
    /// fails the checks, it was recorded from another tweezer, or its κ
    /// would take the loop beyond its margins. `session.json` records it.
    #[arg(long, value_name = "FILE")]
    pub trap_calibration: Option<PathBuf>,
    /// The participant of this sitting (pseudonymous ID: `P01`, `p1`, `1`).
    #[arg(long)]
    pub participant: String,
    /// Study folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue the study in --out (after a stop, a crash or a failed rig).
    #[arg(long)]
    pub resume: bool,
    /// Do not write raw-signal files.
    #[arg(long)]
    pub no_raw: bool,
    /// The simulated rig only: run as fast as possible instead of in real
    /// time.
    #[arg(long)]
    pub fast: bool,
    /// Free space of the target disk in bytes, instead of asking the
    /// operating system (tests of the refusal).
    #[arg(long, hide = true, value_name = "BYTES")]
    pub assume_free_bytes: Option<u64>,
    /// Give up (stop the sitting, exit non-zero) after this long, s.
    #[arg(long, default_value_t = 86_400.0)]
    pub timeout_s: f64,
    /// The rig file and D's chain.
    #[command(flatten)]
    pub loop_args: super::rig::LoopArgs,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Stream trial markers and the haptic signals to Lab Streaming Layer
    /// (`kilotouch-markers`, `kilotouch-signals`; docs/LSL.md) and record
    /// the LSL clock against UTC in the study folder (`lsl_clock.json`).
    #[cfg(feature = "lsl")]
    #[arg(long)]
    pub lsl: bool,
    /// Rate of the LSL signal stream, Hz (the engine's samples decimated).
    #[cfg(feature = "lsl")]
    #[arg(long, default_value_t = 1000.0, requires = "lsl")]
    pub lsl_rate_hz: f64,
    /// Before the first trial, wait up to this long for a consumer on both
    /// LSL streams (LabRecorder recording them), s; 0: do not wait.
    #[cfg(feature = "lsl")]
    #[arg(long, default_value_t = 0.0, requires = "lsl")]
    pub lsl_wait_s: f64,
}

/// `kilotouch study run --json`.
#[derive(Debug, Serialize)]
pub struct RunReport {
    /// Study folder.
    pub out: PathBuf,
    /// The rig (`sim`, `serial:PATH`).
    pub rig: String,
    /// The live devices and the loop delay (`null`: the simulated rig and
    /// tweezer).
    pub device: Option<DeviceRecord>,
    /// The participant of the sitting.
    pub participant: String,
    /// Rows committed in this sitting.
    pub committed: usize,
    /// Rows in the folder / planned.
    pub completed: usize,
    /// Trials planned.
    pub planned: usize,
    /// How the sitting ended: `participant_done`, `study_done`, `stopped`,
    /// `failed`.
    pub finish: String,
    /// Why, for a failed sitting.
    pub reason: Option<String>,
    /// Timing health of the sitting (the engine's).
    pub deadline_misses: u64,
    /// Worst lateness of a block, ms.
    pub worst_lateness_ms: f64,
    /// The sitting's timing verdict as `session.json` records it (`null`:
    /// the sitting did not close).
    pub timing: Option<kilotouch_study::export::SittingTiming>,
    /// Wall time of the sitting, s.
    pub wall_s: f64,
}

/// Run the command.
pub fn run(a: &RunArgs) -> anyhow::Result<()> {
    let (report, finish) = sitting(a, None)?;
    emit(a.json, &report, || human(&report))?;
    match finish {
        FinishReason::Failed(why) => anyhow::bail!("the sitting failed: {why}"),
        FinishReason::Stopped => anyhow::bail!("the sitting was stopped before its end"),
        _ => Ok(()),
    }
}

/// One sitting as `a` asks (`protocol` instead of `--protocol` for a new
/// study, e.g. a benchmark's): spawns the engine on the rig, runs the
/// sitting to its end with a progress bar on stderr, closes both. Returns
/// the report and how the sitting ended.
pub fn sitting(
    a: &RunArgs,
    protocol: Option<kilotouch_study::protocol::Protocol>,
) -> anyhow::Result<(RunReport, FinishReason)> {
    if !(a.timeout_s.is_finite() && a.timeout_s > 0.0) {
        anyhow::bail!("--timeout-s must be finite and > 0, got {}", a.timeout_s);
    }
    let spec: RigSpec = a.rig.parse()?;
    let tweezer: TweezerSpec = a.tweezer.parse()?;
    let rig = RigConfig::load_or_default(a.loop_args.rig_config.as_ref())?;
    let protocol = match protocol {
        Some(p) if !a.resume => p,
        _ => folder_or_new_protocol(a)?,
    };
    let table = protocol.assignment()?;
    #[cfg(feature = "lsl")]
    let study_name = protocol.name.clone();
    let pid = validate_participant_id(&a.participant, &table)
        .map_err(|e| anyhow::anyhow!("--participant: {e}"))?;
    let live = spec != RigSpec::Sim;
    if live && a.fast {
        anyhow::bail!("--fast is for the simulated rig: a live rig runs in real time");
    }
    if tweezer != TweezerSpec::Sim && a.fast {
        anyhow::bail!("--fast is for the simulated tweezer: a live tweezer runs in real time");
    }
    let mut engine = EngineHandle::spawn_devices(&rig, &spec, &tweezer, EngineOptions::default())
        .with_context(|| {
        if tweezer == TweezerSpec::Sim {
            format!("--rig {}", spec.describe())
        } else {
            format!("--rig {} --tweezer {}", spec.describe(), tweezer.describe())
        }
    })?;
    let opts = apply_trap_calibration(a, &mut engine)
        .and_then(|t| session_options(a, protocol, rig, live, pid.index, t));
    let opts = match opts {
        Ok(o) => o,
        Err(e) => {
            engine.shutdown();
            return Err(e);
        }
    };
    let mut session = SessionHandle::spawn(opts, &mut engine)
        .with_context(|| format!("study run into {}", a.out.display()))?;
    let mut info = session.info().clone();
    eprintln!(
        "sitting of {} on {} ({}), {} of {} trials done",
        pid.id,
        info.rig,
        info.device.as_ref().map_or_else(
            || "simulated rig".to_owned(),
            |d| format!("loop delay {:.1} ms", d.loop_delay_ms)
        ),
        info.completed,
        info.planned
    );
    #[cfg(feature = "lsl")]
    let lsl = match start_lsl(a, &engine, &pid.id, study_name) {
        Ok(l) => l,
        Err(e) => {
            let _ = session.close(&mut engine);
            engine.shutdown();
            return Err(e);
        }
    };
    session.send(SessionCommand::Start);
    let t0 = Instant::now();
    let mut planned = info.planned;
    #[cfg(not(feature = "lsl"))]
    let mut on_note = |_msg: &str| {};
    #[cfg(feature = "lsl")]
    let mut on_note = |msg: &str| {
        if let Some((_, s)) = &lsl {
            s.note(msg);
        }
    };
    let ended = wait_for_end(
        &mut session,
        &mut engine,
        a.timeout_s,
        &mut planned,
        &mut on_note,
    );
    #[cfg(feature = "lsl")]
    if let Some((p, s)) = lsl {
        let recorded = s.end();
        p.stop();
        recorded.with_context(|| format!("--lsl: {}", a.out.display()))?;
    }
    let (finish, committed) = ended?;
    // Extra practice trials earned during the sitting are in the plan now.
    info.planned = planned;
    let health = session.health(&engine);
    let _ = session.close(&mut engine);
    let report = report(a, &pid.id, &info, committed, &finish, health, t0);
    engine.shutdown();
    Ok((report, finish))
}

/// The trap calibration of `--trap-calibration`, checked and applied to
/// the engine's tweezer (`None`: none asked for).
fn apply_trap_calibration(
    a: &RunArgs,
    engine: &mut EngineHandle,
) -> anyhow::Result<Option<kilotouch_rig::tweezer::TrapCalibrationRecord>> {
    let Some(path) = &a.trap_calibration else {
        return Ok(None);
    };
    let t = super::tweezer::read_calibration(path)?;
    let applied = engine.check_trap_calibration(&t).and_then(|()| {
        engine
            .apply_trap_calibration(Some(t.applied()))
            .map_err(|e| e.to_string())
    });
    if let Err(why) = applied {
        anyhow::bail!("--trap-calibration {}: not applied: {why}", path.display());
    }
    Ok(Some(t))
}

/// The sitting's options as `a` asks (participant `index`, the trap
/// calibration applied), checked against the free space of the disk.
fn session_options(
    a: &RunArgs,
    protocol: kilotouch_study::protocol::Protocol,
    rig: RigConfig,
    live: bool,
    index: u32,
    trap_calibration: Option<kilotouch_rig::tweezer::TrapCalibrationRecord>,
) -> anyhow::Result<SessionOptions> {
    let mut runner = RunnerConfig::default();
    if a.no_raw {
        runner.raw = None;
    }
    let mut opts = SessionOptions::new(&a.out, (!a.resume).then_some(protocol), rig);
    opts.participant = if live {
        ParticipantKind::Handle
    } else {
        ParticipantKind::Simulated
    };
    opts.speed = if a.fast { Speed::Fast } else { Speed::RealTime };
    opts.only_participant = Some(index);
    opts.runner = runner;
    opts.calibration.clone_from(&a.loop_args.calibration);
    opts.trap_calibration = trap_calibration;
    // What the sitting will write, against the free space of the disk (no
    // confirmation on the command line: the bound suffices when it fits).
    crate::session::estimate_size(&opts, opts.only_participant, a.assume_free_bytes, u64::MAX)
        .and_then(|(size, available)| {
            eprintln!("kilotouch: the sitting will write {}", size.describe());
            kilotouch_study::size::check_free_space(&size, &a.out, available)
                .map_err(|e| crate::session::space_refusal(&e, "add --no-raw"))
        })
        .map_err(|why| anyhow::anyhow!("{why}"))?;
    Ok(opts)
}

/// With `--lsl`: the outlets of the sitting of `participant` in `study`
/// open, the wait for a consumer (`--lsl-wait-s`), and the sitting's start
/// on the marker stream; `None` without `--lsl`.
#[cfg(feature = "lsl")]
fn start_lsl(
    a: &RunArgs,
    engine: &EngineHandle,
    participant: &str,
    study: String,
) -> anyhow::Result<Option<(crate::lsl::LslPublisher, crate::lsl::LslSitting)>> {
    if !a.lsl {
        return Ok(None);
    }
    let id = crate::lsl::LslIdentity {
        study: study.clone(),
        participant: participant.to_owned(),
        id_width: participant.len().saturating_sub(1),
    };
    let p = engine
        .start_lsl(a.lsl_rate_hz, id)
        .map_err(|e| anyhow::anyhow!("--lsl: {e}"))?;
    eprintln!(
        "kilotouch: LSL outlets {} and {} ({} Hz)",
        crate::lsl::MARKER_STREAM,
        crate::lsl::SIGNAL_STREAM,
        p.signal_rate_hz
    );
    if a.lsl_wait_s > 0.0 {
        let until = Instant::now() + Duration::from_secs_f64(a.lsl_wait_s.min(86_400.0));
        while p.consumers() != (true, true) && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(10));
        }
        if p.consumers() != (true, true) {
            eprintln!(
                "kilotouch: no LSL consumer on both streams after {} s: starting anyway",
                a.lsl_wait_s
            );
        }
    }
    let s = crate::lsl::LslSitting::start(p.markers(), &a.out, participant, &study);
    Ok(Some((p, s)))
}

/// The protocol of the folder (a resume) or the one named.
fn folder_or_new_protocol(a: &RunArgs) -> anyhow::Result<kilotouch_study::protocol::Protocol> {
    let session = a.out.join(SESSION_FILE);
    if a.resume {
        if !session.exists() {
            anyhow::bail!(
                "--resume: {} holds no study ({} is missing)",
                a.out.display(),
                SESSION_FILE
            );
        }
        return Ok(read_session(&session)?.protocol);
    }
    if session.exists() {
        anyhow::bail!(
            "{} already holds a study: add --resume to continue it",
            a.out.display()
        );
    }
    super::protocol_arg::load_protocol(&a.protocol)
}

/// Polls the sitting until it ends: progress on stderr, the engine's rig
/// errors passed on, a hard time-out. Returns how it ended and the rows
/// committed.
fn wait_for_end(
    session: &mut SessionHandle,
    engine: &mut EngineHandle,
    timeout_s: f64,
    planned: &mut usize,
    on_note: &mut dyn FnMut(&str),
) -> anyhow::Result<(FinishReason, usize)> {
    let deadline = Instant::now() + Duration::from_secs_f64(timeout_s);
    let mut bar = Progress::new("trials");
    let mut committed = 0usize;
    let mut done = session.info().completed;
    loop {
        for e in engine.poll_events() {
            if let EngineEvent::RigError(err) = e {
                eprintln!("rig: {err}");
            }
        }
        for e in session.poll() {
            match e {
                SessionEvent::Committed(_) => {
                    committed += 1;
                    done += 1;
                    bar.count(done, *planned);
                }
                SessionEvent::Error(msg) => eprintln!("sitting: {msg}"),
                SessionEvent::Noted(msg) => {
                    on_note(&msg);
                    eprintln!("journal: {msg}");
                }
                SessionEvent::Replanned(n) => {
                    *planned = n;
                    bar.count(done, n);
                }
                SessionEvent::Finished(r) => return Ok((r, committed)),
                _ => {}
            }
        }
        if Instant::now() >= deadline {
            session.send(SessionCommand::Stop);
            anyhow::bail!("the sitting did not end within --timeout-s {timeout_s} s");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn report(
    a: &RunArgs,
    participant: &str,
    info: &crate::session::SessionInfo,
    committed: usize,
    finish: &FinishReason,
    health: SessionHealth,
    t0: Instant,
) -> RunReport {
    let (finish, reason) = match finish {
        FinishReason::ParticipantDone(_) => ("participant_done", None),
        FinishReason::StudyDone => ("study_done", None),
        FinishReason::Stopped => ("stopped", None),
        FinishReason::Failed(w) => ("failed", Some(w.clone())),
    };
    RunReport {
        out: a.out.clone(),
        rig: info.rig.clone(),
        device: info.device.clone(),
        participant: participant.to_owned(),
        committed,
        completed: info.completed + committed,
        planned: info.planned,
        finish: finish.to_owned(),
        reason,
        deadline_misses: health.deadline_misses,
        worst_lateness_ms: if health.worst_lateness_s.is_finite() {
            health.worst_lateness_s * 1e3
        } else {
            0.0
        },
        wall_s: t0.elapsed().as_secs_f64(),
        timing: kilotouch_study::export::read_session(
            &a.out.join(kilotouch_study::export::SESSION_FILE),
        )
        .ok()
        .and_then(|s| s.sittings.last().and_then(|x| x.timing.clone())),
    }
}

fn human(r: &RunReport) -> String {
    let mut s = format!(
        "sitting of {} on {}: {} ({} row(s) committed, {} of {} trials done) in {:.1} s\n",
        r.participant,
        r.rig,
        r.finish.replace('_', " "),
        r.committed,
        r.completed,
        r.planned,
        r.wall_s
    );
    if let Some(d) = &r.device {
        s.push_str(&format!(
            "  device: {} (firmware {}), loop delay {} samples = {:.2} ms\n",
            d.name, d.firmware, d.loop_delay_samples, d.loop_delay_ms
        ));
        if let Some(t) = &d.tweezer {
            s.push_str(&format!(
                "  tweezer: {} on {} (firmware {}), command lead {} samples = {:.2} ms\n",
                t.name, t.spec, t.firmware, t.lead_samples, t.lead_ms
            ));
        }
    }
    s.push_str(&format!(
        "  timing: {} deadline miss(es), worst block {:.2} ms late\n",
        r.deadline_misses, r.worst_lateness_ms
    ));
    if let Some(t) = &r.timing {
        s.push_str(&format!("  timing verdict: {}\n", t.describe()));
    }
    if let Some(w) = &r.reason {
        s.push_str(&format!("  reason: {w}\n"));
    }
    s
}
