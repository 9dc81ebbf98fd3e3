//! The session runner: a GUI-independent state machine that runs a study's
//! trials on a [`Station`] with a [`Participant`] and stores every finished
//! trial crash-safely in a [`StudyStore`].
//!
//! # Two layers
//!
//! * [`TrialEngine`] (`engine.rs`) runs one trial sample by sample: every
//!   `act_every` samples it asks the participant for a hand position (with
//!   the [`Observation`] of what happened since), interpolates the hand
//!   linearly over the samples, steps the station, feeds the task's metric
//!   accumulator, the camera, and the raw-signal sink. The per-sample path
//!   allocates nothing (buffers are sized when the engine is built) and
//!   performs no I/O except [`RawSink::push`].
//! * [`SessionRunner`] (`session.rs`) is the state machine
//!   `Idle → Training(trial) → … → Trial(trial) → … → Done`, with
//!   `Paused` and experimenter notes and aborts. [`SessionRunner::advance`]
//!   runs at most `n` samples and never touches the disk (except the raw
//!   sink); when a trial ends it reports [`RunnerEvents::needs_service`]
//!   and [`SessionRunner::service`] does the trial-boundary I/O: finish the
//!   raw file, commit the row (append + fsync), begin the next trial
//!   (journal + fsync). [`SessionRunner::run_to_end`] alternates both for
//!   headless use.
//!
//! Around them: [`TrialSetup`] (`setup.rs`) derives everything that
//! defines one trial from its key; [`RunnerConfig`] (`config.rs`) holds the
//! camera and control timing; `raw.rs` lays out a trial's raw-signal file
//! ([`raw_layout`], with the [`event`] codes of its `event` channel) and
//! defines the [`RawSink`]s its rows go to.
//!
//! A GUI engine thread calls `advance` with a block size of its choice and
//! `service` when asked (≈ 1 ms of fsyncs between trials, while the hand
//! is idle). For a live 10 kHz loop, give the runner a [`RawSink`] that
//! hands rows to a logging thread instead of the NPY writer (which makes a
//! `write` system call every 64 KiB).
//!
//! [`Station`]: crate::task::station::Station
//! [`Participant`]: crate::participant::Participant
//! [`Observation`]: crate::participant::Observation
//! [`StudyStore`]: crate::export::StudyStore

mod config;
mod engine;
pub mod event;
mod raw;
mod session;
mod setup;

pub use crate::error::RunError;
pub use config::RunnerConfig;
pub use engine::{TrialEngine, TrialOutcome};
pub use raw::{NoRaw, RAW_CHANNELS, RawSink, raw_channels, raw_layout, with_scene};
pub use session::{RunnerEvents, RunnerState, SessionRunner};
pub use setup::TrialSetup;
