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
//! ahead of its row is simply rewritten). An extra practice trial
//! (`training.practice_retries`) joins the plan when an unsuccessful
//! practice row is committed; it goes to the front of the workers' queue
//! and its row is committed in its place, so `trials.csv` has the rows in
//! the order a sitting writes them.

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::{Condvar, Mutex, PoisonError, mpsc};
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
use crate::seeds::TrialKey;
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
    meta.camera = Some(rig.camera);
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
    let (simulated, ran) = run_in_plan_order(
        opts,
        &mut store,
        &pending,
        &in_shard,
        engines,
        &mut |planned| {
            completed += 1;
            progress(completed, planned);
        },
    )?;
    let planned_total = store.plan().iter().filter(|p| in_shard(p)).count();
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
        ran,
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

/// The trials to run, handed out to the workers in plan order. An extra
/// practice trial earned while the rows are committed goes to the front
/// (the committer waits for it); workers wait for work until the queue is
/// closed (every trial committed, or an error).
struct Queue {
    state: Mutex<QueueState>,
    ready: Condvar,
}

struct QueueState {
    trials: VecDeque<PlannedTrial>,
    closed: bool,
}

impl Queue {
    fn new(trials: &[PlannedTrial]) -> Self {
        Self {
            state: Mutex::new(QueueState {
                trials: trials.iter().cloned().collect(),
                closed: false,
            }),
            ready: Condvar::new(),
        }
    }

    /// The next trial to run; `None` once the queue is closed.
    fn take(&self) -> Option<PlannedTrial> {
        let mut s = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        loop {
            if s.closed {
                return None;
            }
            if let Some(t) = s.trials.pop_front() {
                return Some(t);
            }
            s = self.ready.wait(s).unwrap_or_else(PoisonError::into_inner);
        }
    }

    /// Runs `t` before every trial still queued.
    fn first(&self, t: PlannedTrial) {
        let mut s = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        s.trials.push_front(t);
        self.ready.notify_one();
    }

    /// Stops handing out trials; waiting workers return.
    fn close(&self) {
        let mut s = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        s.closed = true;
        s.trials.clear();
        self.ready.notify_all();
    }
}

/// Closes the queue when dropped by a panicking worker.
struct CloseOnPanic<'a>(&'a Queue);

impl Drop for CloseOnPanic<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.close();
        }
    }
}

/// Runs `pending` on one thread per engine and commits the rows on this
/// thread strictly in plan order (module docs), calling `committed` after
/// each; the extra practice trials earned meanwhile
/// (`training.practice_retries`) run at once, in their place in the plan.
/// `keep`: the trials of this run (a shard's). Returns the simulated time
/// of the trials run, s, and how many ran.
///
/// # Errors
/// The first worker or storage error (the workers then stop after their
/// current trial).
fn run_in_plan_order(
    opts: &SimulateOptions,
    store: &mut StudyStore,
    pending: &[PlannedTrial],
    keep: &dyn Fn(&PlannedTrial) -> bool,
    engines: Vec<TrialEngine<SimStation>>,
    committed: &mut dyn FnMut(usize),
) -> Result<(f64, usize), RunError> {
    let queue = Queue::new(pending);
    std::thread::scope(|scope| {
        let (tx, rx) = mpsc::channel::<(TrialKey, WorkerResult)>();
        for mut engine in engines {
            let (tx, queue) = (tx.clone(), &queue);
            let spawned = std::thread::Builder::new()
                .name("kilotouch-simulate".into())
                .stack_size(kilotouch_rig::realtime::THREAD_STACK_BYTES)
                .spawn_scoped(scope, move || {
                    // A worker that panics closes the queue, so the others stop
                    // waiting for work and the committer sees them gone.
                    let _guard = CloseOnPanic(queue);
                    while let Some(planned) = queue.take() {
                        let r = run_planned(&mut engine, &opts.protocol, &planned, &opts.out);
                        let failed = r.is_err();
                        if tx.send((planned.key, r)).is_err() || failed {
                            break;
                        }
                    }
                });
            if let Err(e) = spawned {
                queue.close();
                return Err(RunError::State(format!(
                    "could not start a simulation thread: {e}"
                )));
            }
        }
        drop(tx);
        let attach_raw = opts.runner.raw.is_some();
        let r = commit_results(store, &queue, keep, &rx, attach_raw, committed);
        queue.close();
        r
    })
}

/// Commits the workers' results (trial, start time and outcome) in plan
/// order as they arrive: the next row is always the store's first pending
/// trial that `keep` accepts; an extra practice trial it earns joins the
/// front of `queue`. `attach_raw`: the rows name the raw files the workers
/// wrote. Returns the simulated time, s (each trial's samples at its own
/// rate), and the number of trials committed.
///
/// # Errors
/// A worker's error; storage errors; [`RunError::State`] when the workers
/// stopped before every trial was run.
fn commit_results(
    store: &mut StudyStore,
    queue: &Queue,
    keep: &dyn Fn(&PlannedTrial) -> bool,
    results: &mpsc::Receiver<(TrialKey, WorkerResult)>,
    attach_raw: bool,
    committed: &mut dyn FnMut(usize),
) -> Result<(f64, usize), RunError> {
    let mut done: HashMap<TrialKey, (UtcTime, TrialOutcome)> = HashMap::new();
    let (mut simulated, mut n) = (0.0, 0usize);
    let mut planned = store.plan().iter().filter(|p| keep(p)).count();
    // The plan position of the next row: rows are committed in plan order
    // and an extra trial is always inserted after the row that earned it.
    let mut at = 0usize;
    loop {
        let next = loop {
            match store.plan().get(at) {
                None => break None,
                Some(p) if keep(p) && !store.is_completed(&p.key) => break Some(p.key),
                Some(_) => at += 1,
            }
        };
        let Some(next) = next else {
            return Ok((simulated, n));
        };
        let Some((started, outcome)) = done.remove(&next) else {
            match results.recv() {
                Ok((key, r)) => {
                    done.insert(key, r?);
                    continue;
                }
                Err(_) => {
                    return Err(RunError::State(format!(
                        "workers stopped after {n} trials, before trial {next}"
                    )));
                }
            }
        };
        let len = store.plan().len();
        let mut ticket = store.begin_trial(next, started)?;
        if attach_raw {
            store.attach_raw(&mut ticket)?;
        }
        let mut row = ticket.row();
        outcome.metrics.fill_row(&mut row);
        store.commit_trial(ticket, &row)?;
        if store.plan().len() > len {
            // The extra practice trial the row earned: the last of its
            // block (contiguous in the plan), run before everything queued.
            let plan = store.plan();
            let same_block = |p: &PlannedTrial| {
                p.key.participant == next.participant
                    && p.key.condition == next.condition
                    && p.key.phase == next.phase
            };
            let end = plan[at..].iter().take_while(|p| same_block(p)).count();
            if let Some(extra) = plan.get(at + end.saturating_sub(1)) {
                planned += 1;
                queue.first(extra.clone());
            }
        }
        at += 1;
        simulated += outcome.samples as f64 / outcome.sample_rate_hz;
        n += 1;
        committed(planned);
    }
}
