//! [`TrialEngine`]: a [`TrialCore`] paired with a station it prepares
//! itself (the simulated station): what `study simulate`, the session
//! runner's headless runs, the paper's figures and the benchmarks drive.

use crate::error::RunError;
use crate::participant::Participant;
use crate::protocol::Protocol;
use crate::seeds::TrialKey;
use crate::task::TrialEnd;
use crate::task::station::PrepareStation;

use super::config::RunnerConfig;
use super::raw::RawSink;
use super::setup::TrialSetup;
use super::trial::{TrialCore, TrialOutcome};

/// A station and the trial core that runs trials on it (module docs).
#[derive(Debug)]
pub struct TrialEngine<S: PrepareStation> {
    station: S,
    core: TrialCore,
}

impl<S: PrepareStation> TrialEngine<S> {
    /// An engine on `station`, whose rig file's camera the participant
    /// watches.
    ///
    /// # Errors
    /// [`RunError::Config`] for a zero control period or a camera setting
    /// out of range.
    pub fn new(station: S, cfg: RunnerConfig) -> Result<Self, RunError> {
        let core = TrialCore::new(station.sample_rate_hz(), cfg, station.camera())?;
        Ok(Self { station, core })
    }

    /// The station.
    pub fn station(&self) -> &S {
        &self.station
    }

    /// The trial core.
    pub fn core(&self) -> &TrialCore {
        &self.core
    }

    /// Configuration.
    pub fn config(&self) -> &RunnerConfig {
        self.core.config()
    }

    /// The station's sample rate, Hz (a trial may run at a divisor of it:
    /// [`TrialOutcome::sample_rate_hz`]).
    pub fn sample_rate_hz(&self) -> f64 {
        self.core.sample_rate_hz()
    }

    /// The sample rate of the current trial, Hz.
    pub fn trial_sample_rate_hz(&self) -> f64 {
        self.core.trial_sample_rate_hz()
    }

    /// The setup of trial `key` of `protocol` on this engine's station.
    pub fn setup(&self, protocol: &Protocol, key: TrialKey) -> TrialSetup {
        TrialSetup::new(
            protocol,
            key,
            self.station.rest_trap_m(),
            self.station.mapping(),
        )
    }

    /// Prepares the station for trial `setup` (a fresh rig and tweezer from
    /// the trial's rig generator: not real-time) and starts it.
    ///
    /// # Errors
    /// Station preparation errors.
    pub fn start<P: Participant + ?Sized>(
        &mut self,
        setup: &TrialSetup,
        participant: &mut P,
    ) -> Result<(), RunError> {
        let mut rng = setup.rig_rng.clone();
        self.station.prepare(
            &setup.scene,
            setup.feedback.condition,
            setup.params.escape_distance_m(),
            self.core.max_decimation(),
            &mut rng,
        )?;
        let d = self.station.trial_decimation();
        let trajectory = Vec::with_capacity(self.core.trajectory_capacity(setup, d)?);
        self.core.start(setup, d, participant, trajectory)
    }

    /// The trial in progress (or just ended).
    pub fn key(&self) -> Option<TrialKey> {
        self.core.key()
    }

    /// How the trial ended, once it has.
    pub fn end(&self) -> Option<TrialEnd> {
        self.core.end()
    }

    /// Samples run in the current trial.
    pub fn samples(&self) -> u64 {
        self.core.samples()
    }

    /// Ends the current trial as aborted (its metrics so far are kept).
    pub fn abort(&mut self) {
        self.core.abort();
    }

    /// Runs up to `n` samples of the current trial ([`TrialCore::run`]).
    ///
    /// # Errors
    /// Station and raw-sink errors; [`RunError::State`] without a trial.
    pub fn run<P: Participant + ?Sized, W: RawSink + ?Sized>(
        &mut self,
        participant: &mut P,
        raw: &mut W,
        n: usize,
    ) -> Result<Option<TrialEnd>, RunError> {
        self.core.run(&mut self.station, participant, raw, n)
    }

    /// The outcome of the current trial (metrics so far if not ended).
    ///
    /// # Errors
    /// [`RunError::State`] without a trial.
    pub fn outcome(&self) -> Result<TrialOutcome, RunError> {
        self.core.outcome()
    }

    /// Runs a whole trial (start, run to its end) and returns its outcome.
    ///
    /// # Errors
    /// Those of [`TrialEngine::start`] and [`TrialEngine::run`].
    pub fn run_trial<P: Participant + ?Sized, W: RawSink + ?Sized>(
        &mut self,
        setup: &TrialSetup,
        participant: &mut P,
        raw: &mut W,
    ) -> Result<TrialOutcome, RunError> {
        self.start(setup, participant)?;
        let limit = self.core.sample_limit(setup.params.timeout_s())?;
        while self.core.end().is_none() {
            self.run(participant, raw, 10_000)?;
            if self.core.samples() > limit {
                return Err(RunError::State(format!(
                    "trial {} did not end by its time-out",
                    setup.key
                )));
            }
        }
        self.core.take_outcome()
    }
}
