//! Recording and calibrating a tweezer on a background thread, for the Rig
//! page's Tweezer section.
//!
//! [`TrapCalibrationRun::start`] records the detector signals of the
//! tweezer a `--rig` spec names through the one recording path of
//! `kilotouch tweezer record` ([`kilotouch_rig::tweezer::record::record`]) and
//! calibrates both axes ([`kilotouch_rig::tweezer::record::calibrate_axes`]) on a
//! thread of its own. Progress (the fraction of the record taken) travels
//! to the UI thread through an `mpsc` channel; the UI drains it with the
//! non-blocking [`TrapCalibrationRun::poll`] once per frame and never waits
//! for the worker. A panic in the worker is caught and reported as a
//! failure; dropping the run detaches the thread (its result is dropped).

use kilotouch_dsp::trap_psd::PsdFit;
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::RigSpec;
use kilotouch_rig::tweezer::TrapCalibrationRecord;
use kilotouch_rig::tweezer::calibration::TrapCalibrationSettings;
use std::sync::mpsc::{self, Receiver, TryRecvError};

/// A finished calibration: the record of both axes and their fits.
#[derive(Debug, Clone)]
pub struct TrapCalibrationDone {
    /// What the calibration gives and would apply.
    pub record: TrapCalibrationRecord,
    /// The fits of the x and y axes (blocked spectra and models).
    pub fits: [PsdFit; 2],
}

enum Msg {
    Progress(f64),
    Done(Result<Box<TrapCalibrationDone>, String>),
}

/// A record-and-calibrate run in progress (module docs).
#[derive(Debug)]
pub struct TrapCalibrationRun {
    rx: Receiver<Msg>,
    progress: f64,
}

impl std::fmt::Debug for Msg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Msg::Progress(p) => write!(f, "Progress({p})"),
            Msg::Done(r) => write!(f, "Done(ok: {})", r.is_ok()),
        }
    }
}

impl TrapCalibrationRun {
    /// Start recording `duration_s` s from the tweezer `spec` names (the
    /// simulated one of `rc`, or a serial link) with the trap at `trap_m`
    /// (m), then calibrate both axes with `settings`.
    pub fn start(
        spec: RigSpec,
        rc: RigConfig,
        duration_s: f64,
        trap_m: [f64; 2],
        settings: TrapCalibrationSettings,
    ) -> Result<Self, String> {
        let (tx, rx) = mpsc::channel();
        std::thread::Builder::new()
            .name("kilotouch-trap-calibration".into())
            .stack_size(kilotouch_rig::realtime::THREAD_STACK_BYTES)
            .spawn(move || {
                let ptx = tx.clone();
                let work = move || -> anyhow::Result<TrapCalibrationDone> {
                    let mut last = 0.0;
                    let rec = kilotouch_rig::tweezer::record::record(
                        &spec,
                        &rc,
                        duration_s,
                        trap_m,
                        &mut |f| {
                            if f - last >= 0.01 {
                                last = f;
                                let _ = ptx.send(Msg::Progress(f));
                            }
                        },
                    )?;
                    let (record, fits) =
                        kilotouch_rig::tweezer::record::calibrate_axes(&rec, &settings)?;
                    Ok(TrapCalibrationDone { record, fits })
                };
                let r = match std::panic::catch_unwind(std::panic::AssertUnwindSafe(work)) {
                    Ok(Ok(d)) => Ok(Box::new(d)),
                    Ok(Err(e)) => Err(format!("{e:#}")),
                    Err(_) => Err("the calibration thread failed (panic)".to_owned()),
                };
                let _ = tx.send(Msg::Done(r));
            })
            .map_err(|e| format!("cannot start the calibration thread: {e}"))?;
        Ok(Self { rx, progress: 0.0 })
    }

    /// Drain the worker's messages; `Some` once it has finished.
    pub fn poll(&mut self) -> Option<Result<Box<TrapCalibrationDone>, String>> {
        loop {
            match self.rx.try_recv() {
                Ok(Msg::Progress(p)) => self.progress = p,
                Ok(Msg::Done(r)) => return Some(r),
                Err(TryRecvError::Empty) => return None,
                Err(TryRecvError::Disconnected) => {
                    return Some(Err("the calibration thread ended without a result".into()));
                }
            }
        }
    }

    /// Fraction of the record taken, in [0, 1].
    pub fn progress(&self) -> f64 {
        self.progress
    }
}
