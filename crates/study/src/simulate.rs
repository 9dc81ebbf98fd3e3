//! Simulated studies: every pending trial of a protocol run by the
//! simulated operator on the simulated station, in parallel, stored in plan
//! order (`kilotouch study simulate`).
//!
//! Each trial is a pure function of its key (scene, rig noise and operator
//! noise come from the trial's generators; the operator's individual traits
//! from (study seed, participant)), so worker threads may run trials in any
//! order: results do not depend on the thread count. Workers write each
//! trial's raw file directly to its final name; the calling thread commits
//! rows strictly in plan order (journal `trial_started`, row + fsync,
//! `trial_completed`), so after a kill the completed trials are a prefix of
//! the plan and a resumed run re-runs exactly the rest (a raw file written
//! ahead of its row is simply rewritten).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc;
use std::time::Instant;

use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::LoopChain;
use serde::Serialize;

use crate::export::{
    CalibrationRef, PlannedTrial, SESSION_FILE, SimulationInfo, StudyMeta, StudyStore, UtcTime,
    raw_file_name, raw_layout_for, read_session,
};
use crate::fidelity::Fidelity;
use crate::operator::SimCohort;
use crate::protocol::Protocol;
use crate::rawsig::NpyWriter;
use crate::runner::{
    NoRaw, RunError, RunnerConfig, TrialEngine, TrialOutcome, raw_layout, with_scene,
};
use crate::shard::Shard;
use crate::task::sim_station::SimStation;

/// Options of [`simulate`].
#[derive(Debug, Clone)]
pub struct SimulateOptions {
    /// The protocol (participants and seed already set).
    pub protocol: Protocol,
    /// Output folder.
    pub out: PathBuf,
    /// Continue an existing folder (otherwise an existing study is an
    /// error).
    pub resume: bool,
    /// Simulated rig.
    pub rig: RigConfig,
    /// Calibration file whose (force-normalised) chain the D condition runs;
    /// `None`: the model's as-designed chain, recorded as uncalibrated.
    pub calibration: Option<PathBuf>,
    /// Runner timing and raw-file dtype (`raw = None`: no raw files).
    pub runner: RunnerConfig,
    /// Worker threads (≥ 1).
    pub threads: usize,
    /// Resume with a changed rig file, calibration or raw recording,
    /// recording this reason (`None`: such a resume is refused).
    pub new_sitting: Option<String>,
    /// How much of the model each trial runs.
    pub fidelity: Fidelity,
    /// Run only this slice of the participants (`None`: all).
    pub shard: Option<Shard>,
}

impl SimulateOptions {
    /// `protocol` into a new folder `out` on the default simulated rig:
    /// no calibration, the default runner (raw files on), one thread,
    /// the default fidelity, all participants. Set the other fields with
    /// struct-update syntax.
    pub fn new(protocol: Protocol, out: impl Into<PathBuf>) -> Self {
        Self {
            protocol,
            out: out.into(),
            resume: false,
            rig: RigConfig::default(),
            calibration: None,
            runner: RunnerConfig::default(),
            threads: 1,
            new_sitting: None,
            fidelity: Fidelity::default(),
            shard: None,
        }
    }
}

/// What a simulation did.
#[derive(Debug, Clone, Serialize)]
pub struct SimulateReport {
    /// Output folder (in JSON as text, non-UTF-8 bytes replaced by U+FFFD).
    #[serde(serialize_with = "path_lossy")]
    pub out: PathBuf,
    /// Protocol name.
    pub protocol: String,
    /// Study seed.
    pub seed: u64,
    /// Participants.
    pub participants: u32,
    /// Trials in the plan (practice + test).
    pub planned: usize,
    /// Trials already complete when the run started (resume).
    pub already_completed: usize,
    /// Trials run now.
    pub ran: usize,
    /// Test rows in `trials.csv`.
    pub test_rows: usize,
    /// Practice rows.
    pub practice_rows: usize,
    /// Successful test trials.
    pub test_success: usize,
    /// Simulated time of the trials run now, s.
    pub simulated_s: f64,
    /// Wall time, s.
    pub wall_s: f64,
    /// Threads used.
    pub threads: usize,
    /// Raw files written.
    pub raw: bool,
    /// Fidelity of the trials run now.
    pub fidelity: Fidelity,
    /// The participant slice run (`None`: all participants).
    pub shard: Option<Shard>,
    /// What opening the folder found (resume report).
    pub recovery: String,
}

/// A path as JSON text whatever its bytes (U+FFFD for non-UTF-8 ones).
fn path_lossy<S: serde::Serializer>(p: &Path, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&p.to_string_lossy())
}

type WorkerResult = Result<(UtcTime, TrialOutcome), RunError>;

/// Runs one planned trial with the simulated operator on `engine`,
/// writing its raw file under `dir` when the runner config asks for it.
///
/// # Errors
/// Station, operator and raw-file errors.
pub fn run_planned(
    engine: &mut TrialEngine<SimStation>,
    protocol: &Protocol,
    planned: &PlannedTrial,
    dir: &Path,
) -> WorkerResult {
    let key = planned.key;
    let fs = engine.sample_rate_hz();
    let cfg = *engine.config();
    let mut op = SimCohort::new(protocol.seeds.study, fs / cfg.act_every as f64, fs);
    let setup = engine.setup(protocol, key);
    let started = UtcTime::now();
    let setup_ok = |op: &SimCohort| -> Result<(), RunError> {
        match op.error() {
            Some(e) => Err(RunError::Config(format!("simulated operator: {e}"))),
            None => Ok(()),
        }
    };
    let outcome = match cfg.raw {
        Some(dtype) => {
            let layout = raw_layout_for(
                planned,
                started,
                with_scene(raw_layout(fs, dtype), &setup.scene),
            );
            let mut w = NpyWriter::create(&dir.join(raw_file_name(planned)), layout)?;
            let o = engine.run_trial(&setup, &mut op, &mut w)?;
            setup_ok(&op)?;
            w.finish()?;
            o
        }
        None => {
            let o = engine.run_trial(&setup, &mut op, &mut NoRaw)?;
            setup_ok(&op)?;
            o
        }
    };
    Ok((started, outcome))
}

/// What a study folder records of a simulated set-up: the rig's name and
/// the content hash of its whole rig file, the calibration file (SHA-256)
/// whose chain D runs — `None`: the as-designed chain — whether raw files
/// are written, and the reason of a recorded change (`--new-sitting`).
/// A resume with other settings is refused by the store
/// ([`crate::export::ExportError::SettingsChanged`]). Returns the meta and
/// D's chain.
///
/// # Errors
/// The calibration file cannot be read or is not for this rig; the rig
/// file cannot be hashed.
pub fn sim_meta(
    rig: &RigConfig,
    calibration: Option<&Path>,
    raw: bool,
    recorded_change: Option<&str>,
) -> Result<(StudyMeta, LoopChain), RunError> {
    let mut meta = StudyMeta::new(&format!("simulated: {}", rig.rig.name));
    let chain = match calibration {
        Some(p) => {
            meta.calibration = Some(CalibrationRef::from_file(p)?);
            LoopChain::load(p, rig)?
        }
        None => LoopChain::as_designed(rig)?,
    };
    meta.rig_hash = Some(
        kilotouch_rig::calibration::hash::content_hash(rig)
            .map_err(|e| RunError::Config(format!("rig file: {e}")))?,
    );
    meta.raw_signals = Some(raw);
    meta.recorded_change = recorded_change.map(str::to_owned);
    Ok((meta, chain))
}

/// A resumed simulated study must run at the fidelity and on the shard it
/// was started with: one study of two fidelities would mix two models, and
/// a shard folder holds its own participants only.
///
/// # Errors
/// [`RunError::State`] naming both.
pub fn check_same_simulation(out: &Path, now: SimulationInfo) -> Result<(), RunError> {
    let path = out.join(SESSION_FILE);
    if !path.exists() {
        return Ok(());
    }
    let Some(was) = read_session(&path)?.simulation else {
        return Ok(());
    };
    let shard =
        |s: Option<Shard>| s.map_or("all participants".to_owned(), |s| format!("shard {s}"));
    if was.fidelity != now.fidelity {
        return Err(RunError::State(format!(
            "{} was simulated at fidelity {}; resume it with --fidelity {}",
            out.display(),
            was.fidelity,
            was.fidelity
        )));
    }
    if was.shard != now.shard {
        return Err(RunError::State(format!(
            "{} holds {}; resuming it as {} would mix two slices of the participants",
            out.display(),
            shard(was.shard),
            shard(now.shard)
        )));
    }
    Ok(())
}

/// Runs every pending trial of the study in `opts.out` (module docs); with
/// a shard, only the trials of its participants ([`crate::shard`]).
/// `progress(completed, planned)` is called after each commit.
///
/// # Errors
/// [`RunError::State`] when the folder holds a study and `resume` is false;
/// storage errors (e.g. a protocol mismatch on resume), station errors.
pub fn simulate(
    opts: &SimulateOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SimulateReport, RunError> {
    let t0 = Instant::now();
    crate::export::refuse_links(&opts.out)?;
    if opts.out.join(SESSION_FILE).exists() && !opts.resume {
        return Err(RunError::State(format!(
            "{} already holds a study; pass --resume to continue it or choose another folder",
            opts.out.display()
        )));
    }
    let threads = opts.threads.max(1);
    let (meta, chain) = sim_meta(
        &opts.rig,
        opts.calibration.as_deref(),
        opts.runner.raw.is_some(),
        opts.new_sitting.as_deref(),
    )?;
    let simulation = SimulationInfo {
        fidelity: opts.fidelity,
        shard: opts.shard,
    };
    if opts.resume {
        check_same_simulation(&opts.out, simulation)?;
    }
    let mut store = StudyStore::open(&opts.out, &opts.protocol, &meta)?;
    store.set_simulation(simulation)?;
    let recovery = store.recovery().to_string();
    let in_shard = |p: &PlannedTrial| opts.shard.is_none_or(|s| s.contains(p.key.participant));
    let planned_total = store.plan().iter().filter(|p| in_shard(p)).count();
    let already = store
        .plan()
        .iter()
        .filter(|p| in_shard(p) && store.is_completed(&p.key))
        .count();
    let pending: Vec<PlannedTrial> = store.pending().filter(|p| in_shard(p)).cloned().collect();
    // Build one station per worker up front (chain design), so that an
    // invalid rig is reported before anything runs.
    let mut engines = Vec::with_capacity(threads);
    for _ in 0..threads.min(pending.len().max(1)) {
        let mut station = SimStation::with_chain(&opts.rig, chain.clone())?;
        station.set_fidelity(opts.fidelity);
        engines.push(TrialEngine::new(station, opts.runner)?);
    }
    let mut completed = already;
    let simulated = run_in_plan_order(opts, &mut store, &pending, engines, &mut || {
        completed += 1;
        progress(completed, planned_total);
    })?;
    store.close()?;
    let rows = crate::export::read_trials(&opts.out.join(crate::export::TRIALS_FILE))?.rows;
    let test: Vec<_> = rows
        .iter()
        .filter(|r| r.phase == crate::seeds::Phase::Test)
        .collect();
    Ok(SimulateReport {
        out: opts.out.clone(),
        protocol: opts.protocol.name.clone(),
        seed: opts.protocol.seeds.study,
        participants: opts.protocol.participants,
        planned: planned_total,
        already_completed: already,
        ran: pending.len(),
        test_rows: test.len(),
        practice_rows: rows.len() - test.len(),
        test_success: test.iter().filter(|r| r.success).count(),
        simulated_s: simulated,
        wall_s: t0.elapsed().as_secs_f64(),
        threads,
        raw: opts.runner.raw.is_some(),
        fidelity: opts.fidelity,
        shard: opts.shard,
        recovery,
    })
}

/// The pending trials, handed out to the workers in plan order until they
/// run out or the run is cancelled.
struct Queue<'a> {
    pending: &'a [PlannedTrial],
    next: AtomicUsize,
    cancelled: AtomicBool,
}

impl Queue<'_> {
    /// The next trial to run and its index in `pending`.
    fn take(&self) -> Option<(usize, &PlannedTrial)> {
        if self.cancelled.load(Ordering::Relaxed) {
            return None;
        }
        let i = self.next.fetch_add(1, Ordering::Relaxed);
        self.pending.get(i).map(|p| (i, p))
    }

    /// Stops handing out trials.
    fn cancel(&self) {
        self.cancelled.store(true, Ordering::Relaxed);
    }
}

/// Runs `pending` on one thread per engine and commits the rows on this
/// thread strictly in plan order (module docs), calling `committed` after
/// each. Returns the simulated time of the trials run, s.
///
/// # Errors
/// The first worker or storage error (the workers then stop after their
/// current trial).
fn run_in_plan_order(
    opts: &SimulateOptions,
    store: &mut StudyStore,
    pending: &[PlannedTrial],
    engines: Vec<TrialEngine<SimStation>>,
    committed: &mut dyn FnMut(),
) -> Result<f64, RunError> {
    let queue = Queue {
        pending,
        next: AtomicUsize::new(0),
        cancelled: AtomicBool::new(false),
    };
    std::thread::scope(|scope| {
        let (tx, rx) = mpsc::channel::<(usize, WorkerResult)>();
        for mut engine in engines {
            let (tx, queue) = (tx.clone(), &queue);
            scope.spawn(move || {
                while let Some((i, planned)) = queue.take() {
                    let r = run_planned(&mut engine, &opts.protocol, planned, &opts.out);
                    let failed = r.is_err();
                    if tx.send((i, r)).is_err() || failed {
                        break;
                    }
                }
            });
        }
        drop(tx);
        let attach_raw = opts.runner.raw.is_some();
        let r = commit_results(store, pending, rx, attach_raw, committed);
        if r.is_err() {
            queue.cancel();
        }
        r
    })
}

/// Commits the workers' results (index in `pending`, start time and
/// outcome) in plan order as they arrive; `attach_raw`: the rows name the
/// raw files the workers wrote. Returns the simulated time, s (each trial's
/// samples at its own rate).
///
/// # Errors
/// A worker's error; storage errors; [`RunError::State`] when the workers
/// stopped before every trial was run.
fn commit_results(
    store: &mut StudyStore,
    pending: &[PlannedTrial],
    results: mpsc::Receiver<(usize, WorkerResult)>,
    attach_raw: bool,
    committed: &mut dyn FnMut(),
) -> Result<f64, RunError> {
    let mut done: BTreeMap<usize, (UtcTime, TrialOutcome)> = BTreeMap::new();
    let mut commit_at = 0usize;
    let mut simulated = 0.0;
    for (i, r) in results {
        done.insert(i, r?);
        while let Some((started, outcome)) = done.remove(&commit_at) {
            let mut ticket = store.begin_trial(pending[commit_at].key, started)?;
            if attach_raw {
                store.attach_raw(&mut ticket)?;
            }
            let mut row = ticket.row();
            outcome.metrics.fill_row(&mut row);
            store.commit_trial(ticket, &row)?;
            simulated += outcome.samples as f64 / outcome.sample_rate_hz;
            commit_at += 1;
            committed();
        }
    }
    if commit_at != pending.len() {
        return Err(RunError::State(format!(
            "workers stopped after {commit_at} of {} trials",
            pending.len()
        )));
    }
    Ok(simulated)
}
