//! `kilotouch study merge`: joins study folders of one protocol and seed —
//! the shards of a simulated study ([`crate::shard`]) — into one study
//! folder, the folder an unsharded run writes (row for row; only the
//! journal's sittings differ).
//!
//! Every input is checked before anything is written: its `session.json`
//! is of this format and of the same protocol (SHA-256 of its canonical
//! TOML), study seed, calibration and simulation fidelity as the first;
//! `trials.csv` has a valid `row_crc32` on every row and no torn tail; every
//! row's CRC equals the one its journal's `trial_completed` record holds
//! (the journal's lines carry their own CRC); every raw file a row names
//! exists with its sidecar and has the length its sidecar's shape gives; no
//! trial is in two inputs. The output is then written through the same
//! [`StudyStore`] a run uses — each row begun, its raw file attached and
//! committed in plan order (journal, fsync), the summaries and
//! `session.json` regenerated when it closes — so the merged folder can be
//! resumed, analysed and merged like any other.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::error::RunError;
use crate::export::journal::{JOURNAL_FILE, Record, read_journal};
use crate::export::{
    ExportError, SESSION_FILE, SessionInfo, SimulationInfo, StudyMeta, StudyStore, TRIALS_FILE,
    TrialRow, read_session, read_trials,
};
use crate::rawsig::{npy_header, read_sidecar, sidecar_path};
use crate::seeds::TrialKey;

/// Largest number of input folders of one merge.
pub const MAX_INPUTS: usize = crate::shard::MAX_SHARDS as usize;

/// What a merge did.
#[derive(Debug, Clone, Serialize)]
pub struct MergeReport {
    /// Output folder.
    pub out: PathBuf,
    /// Input folders, in the order given.
    pub inputs: Vec<PathBuf>,
    /// Rows read from each input.
    pub rows_per_input: Vec<usize>,
    /// Rows in the merged `trials.csv`.
    pub rows: usize,
    /// Trials of the protocol's plan.
    pub planned: usize,
    /// Raw files copied.
    pub raw_files: usize,
    /// The plan is complete (every trial has its row).
    pub complete: bool,
}

/// One checked input folder.
struct Input {
    dir: PathBuf,
    session: SessionInfo,
    rows: Vec<(TrialRow, u32)>,
}

/// A clear error about input `dir`.
fn bad(dir: &Path, message: impl Into<String>) -> RunError {
    RunError::State(format!("{}: {}", dir.display(), message.into()))
}

/// Reads and checks one input folder (module docs).
fn read_input(dir: &Path) -> Result<Input, RunError> {
    let session_path = dir.join(SESSION_FILE);
    if !session_path.is_file() {
        return Err(ExportError::NotAStudyFolder {
            path: dir.to_path_buf(),
            reason: format!("no `{SESSION_FILE}`"),
        }
        .into());
    }
    let session = read_session(&session_path)?;
    let trials = read_trials(&dir.join(TRIALS_FILE))?;
    if let Some(t) = &trials.torn {
        return Err(bad(
            dir,
            format!(
                "`{TRIALS_FILE}` ends in a torn row ({} bytes at offset {}): resume this folder first so the trial is run again",
                t.len, t.offset
            ),
        ));
    }
    let journal = read_journal(&dir.join(JOURNAL_FILE))?;
    let mut journaled: HashMap<TrialKey, String> = HashMap::new();
    for e in &journal.entries {
        // A quarantined raw file rewrote its row: the later CRC is the row's.
        if let Record::TrialCompleted {
            trial, row_crc32, ..
        }
        | Record::RawQuarantined {
            trial, row_crc32, ..
        } = &e.record
        {
            journaled.insert(*trial, row_crc32.clone());
        }
    }
    let index: HashMap<&str, u32> = session
        .order_table
        .iter()
        .map(|o| (o.participant.as_str(), o.index))
        .collect();
    let mut rows = Vec::with_capacity(trials.rows.len());
    for ((row, crc), line) in trials.rows.into_iter().zip(trials.crcs).zip(trials.lines) {
        let Some(&p) = index.get(row.participant.as_str()) else {
            return Err(bad(
                dir,
                format!(
                    "{TRIALS_FILE} line {line}: participant `{}` is not in the order table of {SESSION_FILE}",
                    row.participant
                ),
            ));
        };
        let key = row.key(p);
        let hex = crate::export::checksum::crc32_hex(crc);
        match journaled.get(&key) {
            Some(j) if *j == hex => {}
            Some(j) => {
                return Err(bad(
                    dir,
                    format!(
                        "{TRIALS_FILE} line {line} (trial {key}) has row_crc32 {hex} but the journal recorded {j}: the row was changed after it was written"
                    ),
                ));
            }
            None => {
                return Err(bad(
                    dir,
                    format!(
                        "{TRIALS_FILE} line {line} (trial {key}) has no trial_completed record in {JOURNAL_FILE}: resume this folder first (it adopts the row)"
                    ),
                ));
            }
        }
        if !row.raw_file.is_empty() {
            check_raw(dir, &row.raw_file)?;
        }
        rows.push((row, crc));
    }
    Ok(Input {
        dir: dir.to_path_buf(),
        session,
        rows,
    })
}

/// A raw file named by a row exists with its sidecar and has the length
/// the sidecar's shape and dtype give.
fn check_raw(dir: &Path, rel: &str) -> Result<(), RunError> {
    let npy = dir.join(rel);
    let side = sidecar_path(&npy);
    if !npy.is_file() || !side.is_file() {
        return Err(bad(
            dir,
            format!("raw file `{rel}` or its sidecar is missing"),
        ));
    }
    let meta = read_sidecar(&side)?;
    let [rows, cols] = meta.shape;
    let want = npy_header(meta.dtype, rows, cols as usize).len() as u64
        + rows * cols * meta.dtype.size() as u64;
    let got = std::fs::metadata(&npy)
        .map_err(|e| bad(dir, format!("raw file `{rel}`: {e}")))?
        .len();
    if got != want {
        return Err(bad(
            dir,
            format!(
                "raw file `{rel}` is {got} bytes; its sidecar's shape {rows}×{cols} gives {want}"
            ),
        ));
    }
    Ok(())
}

/// The inputs agree on what study they are parts of.
fn check_same_study(first: &Input, other: &Input) -> Result<(), RunError> {
    let (a, b) = (&first.session, &other.session);
    let differs = |what: &str, x: String, y: String| {
        bad(
            &other.dir,
            format!(
                "its {what} is {y}, but {} has {x}: only parts of one study can be merged",
                first.dir.display()
            ),
        )
    };
    if a.protocol_sha256 != b.protocol_sha256 && a.protocol != b.protocol {
        return Err(differs(
            "protocol",
            format!("`{}` ({})", a.protocol.name, a.protocol_sha256),
            format!("`{}` ({})", b.protocol.name, b.protocol_sha256),
        ));
    }
    if a.seeds.study != b.seeds.study {
        return Err(differs(
            "study seed",
            a.seeds.study.to_string(),
            b.seeds.study.to_string(),
        ));
    }
    let cal = |s: &SessionInfo| {
        s.calibration
            .as_ref()
            .map_or("no calibration".to_owned(), |c| {
                format!("calibration {}", c.sha256)
            })
    };
    if cal(a) != cal(b) {
        return Err(differs("chain", cal(a), cal(b)));
    }
    let fid = |s: &SessionInfo| {
        s.simulation.map_or("no simulation record".to_owned(), |m| {
            format!("fidelity {}", m.fidelity)
        })
    };
    if fid(a) != fid(b) {
        return Err(differs("simulation", fid(a), fid(b)));
    }
    let rig = |s: &SessionInfo| {
        s.rig_hash
            .as_ref()
            .map_or("no recorded rig file hash".to_owned(), |h| {
                format!("rig file {h}")
            })
    };
    if rig(a) != rig(b) {
        return Err(differs("rig file", rig(a), rig(b)));
    }
    let raw = |s: &SessionInfo| match s.raw_signals {
        Some(true) => "raw recording on".to_owned(),
        Some(false) => "raw recording off".to_owned(),
        None => "no recorded raw setting".to_owned(),
    };
    if raw(a) != raw(b) {
        return Err(differs("raw setting", raw(a), raw(b)));
    }
    Ok(())
}

/// Merges the study folders `inputs` into the new folder `out` (module
/// docs).
///
/// # Errors
/// [`RunError::State`] naming the input and what is wrong with it (other
/// study, changed row, torn tail, missing raw file, a trial in two inputs),
/// or when `out` already holds a study; storage errors.
pub fn merge(inputs: &[PathBuf], out: &Path) -> Result<MergeReport, RunError> {
    check_request(inputs, out)?;
    let read: Vec<Input> = inputs
        .iter()
        .map(|d| read_input(d))
        .collect::<Result<_, _>>()?;
    let Some(first) = read.first() else {
        return Err(RunError::State("nothing to merge".into()));
    };
    for other in &read[1..] {
        check_same_study(first, other)?;
    }
    let by_key = index_trials(&read)?;
    let s = &first.session;
    let meta = merged_meta(s);
    let mut store = StudyStore::open(out, &s.protocol, &meta)?;
    if let Some(sim) = s.simulation {
        store.set_simulation(SimulationInfo {
            fidelity: sim.fidelity,
            shard: None,
        })?;
    }
    store.note(&format!(
        "merged from {}",
        inputs
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    ))?;
    // In plan order; the plan grows while the rows are committed when an
    // unsuccessful practice row earns an extra practice trial
    // (`training.practice_retries`), always after the row's own place.
    let mut raw_files = 0;
    let mut at = 0;
    while let Some(key) = store.plan().get(at).map(|p| p.key) {
        at += 1;
        let Some(&(i, row)) = by_key.get(&key) else {
            continue;
        };
        let mut ticket = store.begin_trial(key, row.started_utc)?;
        if !row.raw_file.is_empty() {
            copy_raw(&read[i].dir, out, &row.raw_file)?;
            store.attach_raw(&mut ticket)?;
            raw_files += 1;
        }
        store.commit_trial(ticket, row)?;
    }
    let rows = store.completed_count();
    if rows != by_key.len() {
        let lost: Vec<String> = by_key
            .keys()
            .filter(|k| !store.is_completed(k))
            .take(5)
            .map(ToString::to_string)
            .collect();
        return Err(RunError::State(format!(
            "{} of the inputs' rows are not trials of the protocol's plan (first: {}); \
             nothing was merged for them",
            by_key.len() - rows,
            lost.join(", ")
        )));
    }
    let planned = store.plan().len();
    store.close()?;
    Ok(MergeReport {
        out: out.to_path_buf(),
        inputs: inputs.to_vec(),
        rows_per_input: read.iter().map(|r| r.rows.len()).collect(),
        rows,
        planned,
        raw_files,
        complete: rows == planned,
    })
}

/// Refuses a merge request before reading anything: no input, more than
/// [`MAX_INPUTS`], or an output folder that already holds a study.
fn check_request(inputs: &[PathBuf], out: &Path) -> Result<(), RunError> {
    if inputs.is_empty() {
        return Err(RunError::State(
            "nothing to merge: name the shard folders".into(),
        ));
    }
    if inputs.len() > MAX_INPUTS {
        return Err(RunError::State(format!(
            "{} folders to merge; at most {MAX_INPUTS}",
            inputs.len()
        )));
    }
    if out.join(SESSION_FILE).exists() {
        return Err(RunError::State(format!(
            "{} already holds a study; merge into a new folder",
            out.display()
        )));
    }
    Ok(())
}

/// The inputs' rows by trial key, each with the index of its input; a
/// trial found in two inputs is refused (the folders overlap).
fn index_trials(read: &[Input]) -> Result<BTreeMap<TrialKey, (usize, &TrialRow)>, RunError> {
    let mut by_key: BTreeMap<TrialKey, (usize, &TrialRow)> = BTreeMap::new();
    for (i, input) in read.iter().enumerate() {
        let index: HashMap<&str, u32> = input
            .session
            .order_table
            .iter()
            .map(|o| (o.participant.as_str(), o.index))
            .collect();
        for (row, _) in &input.rows {
            let key = row.key(
                index
                    .get(row.participant.as_str())
                    .copied()
                    .unwrap_or(u32::MAX),
            );
            if let Some((j, _)) = by_key.insert(key, (i, row)) {
                return Err(bad(
                    &input.dir,
                    format!(
                        "trial {key} is also in {}: the folders overlap (merge each shard once)",
                        read[j].dir.display()
                    ),
                ));
            }
        }
    }
    Ok(by_key)
}

/// The settings of the merged folder: those the inputs share (their first
/// `session.json`), no recorded change, no device.
fn merged_meta(s: &SessionInfo) -> StudyMeta {
    StudyMeta {
        software_name: s.software.name.clone(),
        software_version: s.software.version.clone(),
        rig: s.rig.clone(),
        calibration: s.calibration.clone(),
        rig_hash: s.rig_hash.clone(),
        raw_signals: s.raw_signals,
        trap_calibration: s.trap_calibration.clone(),
        camera: s.camera,
        recorded_change: None,
        device: None,
    }
}

/// Copies a raw file and its sidecar from folder `from` to folder `to`
/// (same relative path).
fn copy_raw(from: &Path, to: &Path, rel: &str) -> Result<(), RunError> {
    let src = from.join(rel);
    let dst = to.join(rel);
    // A quarantined file (`recovery/quarantine/…`) keeps its place; no
    // link is followed on either side.
    if let Some(parent) = dst.parent() {
        crate::storage::fsutil::create_dir_durable(parent)?;
    }
    for (a, b) in [
        (src.clone(), dst.clone()),
        (sidecar_path(&src), sidecar_path(&dst)),
    ] {
        crate::storage::fsutil::refuse_link(&a)?;
        crate::storage::fsutil::refuse_link(&b)?;
        std::fs::copy(&a, &b).map_err(|e| {
            RunError::State(format!("copy {} to {}: {e}", a.display(), b.display()))
        })?;
    }
    Ok(())
}
