//! The session runner: a GUI-independent state machine that runs a study's
//! trials on a [`Station`] with a [`Participant`] and stores every finished
//! trial crash-safely in a [`StudyStore`].
//!
//! # Two halves, two drivers
//!
//! * The **trial side**: [`TrialCore`] (`trial.rs`) runs one trial sample
//!   by sample on a station handed to it block by block: every
//!   `act_every` samples it asks the participant for a hand position (with
//!   the [`Observation`] of what happened since), interpolates the hand
//!   linearly over the samples, advances the station, feeds the task's
//!   metric accumulator, the camera, and the raw-signal sink. It allocates
//!   nothing and performs no I/O except [`RawSink::push`].
//!   [`TrialEngine`] (`engine.rs`) pairs it with a station it prepares
//!   itself (the simulated station).
//! * The **store side**: [`SittingCore`] (`sitting.rs`) is the state
//!   machine `Idle → Training(trial) → … → Trial(trial) → … → Done`, with
//!   `Paused`, `Waiting`, notes and aborts, and the trial-boundary I/O:
//!   journal a trial's beginning, open its raw file, finish it and commit
//!   its row (append + fsync). It runs no sample: it says which trial
//!   comes next ([`Next`]) and takes each outcome.
//!
//! [`SessionRunner`] (`session.rs`) drives both halves inline:
//! [`SessionRunner::advance`] runs at most `n` samples and never touches the
//! disk (except the raw sink); when a trial ends it reports
//! [`RunnerEvents::needs_service`] and [`SessionRunner::service`] commits
//! and begins the next trial. [`SessionRunner::run_to_end`] alternates
//! both for headless use. The app's real-time sitting drives them on two
//! threads instead: the trial side on the engine's own closed loop (its
//! rig, simulated or live), the store side on a worker thread, with the
//! raw rows, the prepared trials and the outcomes travelling between them
//! through lock-free queues.
//!
//! Around them: [`TrialSetup`] (`setup.rs`) derives everything that
//! defines one trial from its key; [`RunnerConfig`] (`config.rs`) holds the
//! camera and control timing; `raw.rs` lays out a trial's raw-signal file
//! ([`raw_layout`], with the [`event`] codes of its `event` channel) and
//! defines the [`RawSink`]s its rows go to.
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
mod sitting;
mod trial;

pub use crate::error::RunError;
pub use config::RunnerConfig;
pub use engine::TrialEngine;
pub use raw::{NoRaw, RAW_CHANNELS, RawSink, raw_channels, raw_layout, with_scene};
pub use session::{RunnerEvents, RunnerState, SessionRunner};
pub use setup::TrialSetup;
pub use sitting::{Next, Resumed, SittingCore, StationFrame};
pub use trial::{TrialCore, TrialOutcome, trajectory_capacity};
