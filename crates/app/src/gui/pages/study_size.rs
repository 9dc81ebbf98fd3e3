//! The Study page's size check before a sitting opens: what the sitting
//! will write, estimated on a background thread
//! ([`crate::session::estimate_size`]), checked against the free space of
//! the folder's disk, and confirmed by the
//! experimenter when it exceeds [`SizeGate::confirm_over_bytes`] (default
//! [`CONFIRM_OVER_BYTES`], 1 GB): write it, write it without raw signals,
//! or cancel. A sitting without raw files writes a few kB per trial and
//! opens at once. The page never waits: it polls the estimate every frame.

use std::sync::mpsc::{self, Receiver, TryRecvError};

use egui::{Color32, RichText};
use kilotouch_study::size::{StudySize, check_free_space, format_bytes};

use crate::session::SessionOptions;

/// The default size above which the page asks before a sitting writes,
/// bytes (1 GB).
pub const CONFIRM_OVER_BYTES: u64 = 1_000_000_000;

/// A sitting the page has validated and is about to open.
#[derive(Debug, Clone)]
pub struct PreparedSitting {
    /// The sitting's options (the raw files as chosen).
    pub opts: SessionOptions,
    /// The participant of the sitting (0-based index, ID).
    pub pid: crate::session::ParticipantId,
    /// Reopen the folder at its next pending trial.
    pub resume: bool,
    /// Send Start as soon as it opens (run all, autostart).
    pub start: bool,
}

/// What the gate decided.
#[derive(Debug)]
pub enum Verdict {
    /// Open this sitting.
    Open(Box<PreparedSitting>),
    /// Do not open it, for this reason (shown as the page's error).
    Refused(String),
    /// The experimenter cancelled.
    Cancelled,
}

type Estimate = Result<(StudySize, u64), String>;

#[derive(Debug)]
enum State {
    Idle,
    Estimating {
        rx: Receiver<Estimate>,
        sitting: Box<PreparedSitting>,
    },
    Confirm {
        size: StudySize,
        sitting: Box<PreparedSitting>,
    },
}

/// The size check (module docs).
#[derive(Debug)]
pub struct SizeGate {
    state: State,
    /// Ask before a sitting that writes more than this, bytes.
    pub confirm_over_bytes: u64,
    /// Free space of the target disk in bytes instead of asking the
    /// operating system (tests of the refusal).
    pub assume_free_bytes: Option<u64>,
    /// The estimate of a sitting that was refused or cancelled, one
    /// sentence (shown beside the page's message until the next check; a
    /// sitting that opens clears it).
    pub last: Option<String>,
}

impl Default for SizeGate {
    fn default() -> Self {
        Self {
            state: State::Idle,
            confirm_over_bytes: CONFIRM_OVER_BYTES,
            assume_free_bytes: None,
            last: None,
        }
    }
}

impl SizeGate {
    /// Is an estimate running or a confirmation waiting?
    pub fn is_busy(&self) -> bool {
        !matches!(self.state, State::Idle)
    }

    /// Check `sitting`: opens at once ([`Verdict::Open`]) when it writes
    /// no raw files; else starts the estimate and returns `None` (the
    /// verdict comes from [`Self::ui`]).
    pub fn check(&mut self, sitting: PreparedSitting) -> Option<Verdict> {
        self.last = None;
        if sitting.opts.runner.raw.is_none() {
            return Some(Verdict::Open(Box::new(sitting)));
        }
        let opts = sitting.opts.clone();
        let only = opts.only_participant;
        let assume = self.assume_free_bytes;
        let threshold = self.confirm_over_bytes;
        let (tx, rx) = mpsc::channel();
        let spawned = std::thread::Builder::new()
            .name("size-estimate".into())
            .stack_size(kilotouch_rig::realtime::THREAD_STACK_BYTES)
            .spawn(move || {
                let r = std::panic::catch_unwind(|| {
                    crate::session::estimate_size(&opts, only, assume, threshold)
                })
                .unwrap_or_else(|_| Err("the size estimate failed (a panic)".into()));
                let _ = tx.send(r);
            });
        if let Err(e) = spawned {
            return Some(Verdict::Refused(format!(
                "could not start the size estimate: {e}"
            )));
        }
        self.state = State::Estimating {
            rx,
            sitting: Box::new(sitting),
        };
        None
    }

    /// Draw the estimate's progress or the confirmation; the verdict once
    /// there is one.
    pub fn ui(&mut self, ui: &mut egui::Ui) -> Option<Verdict> {
        match std::mem::replace(&mut self.state, State::Idle) {
            State::Idle => None,
            State::Estimating { rx, sitting } => match rx.try_recv() {
                Err(TryRecvError::Empty) => {
                    ui.horizontal(|ui| {
                        ui.spinner();
                        ui.label(
                            "estimating what the sitting will write (a pilot of a few trials \
                             by the simulated participant)…",
                        );
                    });
                    ui.ctx()
                        .request_repaint_after(std::time::Duration::from_millis(50));
                    self.state = State::Estimating { rx, sitting };
                    None
                }
                Err(TryRecvError::Disconnected) => Some(Verdict::Refused(
                    "the size estimate ended without an answer".into(),
                )),
                Ok(Err(e)) => Some(Verdict::Refused(e)),
                Ok(Ok((size, available))) => {
                    if let Err(e) = check_free_space(&size, &sitting.opts.out, available) {
                        self.last = Some(format!("the sitting would write {}", size.describe()));
                        return Some(Verdict::Refused(crate::session::space_refusal(
                            &e,
                            "run without raw signals",
                        )));
                    }
                    if size.bytes > self.confirm_over_bytes {
                        self.state = State::Confirm { size, sitting };
                        ui.ctx().request_repaint();
                        None
                    } else {
                        Some(Verdict::Open(sitting))
                    }
                }
            },
            State::Confirm { size, mut sitting } => {
                let mut verdict = None;
                egui::Frame::group(ui.style()).show(ui, |ui| {
                    ui.label(
                        RichText::new(format!(
                            "This sitting will write {}, more than the {} the page asks about.",
                            format_bytes(size.bytes),
                            format_bytes(self.confirm_over_bytes)
                        ))
                        .color(Color32::from_rgb(0xff, 0xb0, 0x40))
                        .strong(),
                    );
                    ui.label(size.describe());
                    ui.horizontal(|ui| {
                        if ui
                            .button(format!("Write {}", format_bytes(size.bytes)))
                            .clicked()
                        {
                            verdict = Some(Verdict::Open(sitting.clone()));
                        }
                        if ui
                            .button(format!(
                                "Without raw signals ({})",
                                format_bytes(size.no_raw_bytes)
                            ))
                            .on_hover_text(
                                "trials.csv, the journal and session.json only: the per-trial \
                                 metrics, not the signals",
                            )
                            .clicked()
                        {
                            sitting.opts.runner.raw = None;
                            verdict = Some(Verdict::Open(sitting.clone()));
                        }
                        if ui.button("Cancel").clicked() {
                            self.last =
                                Some(format!("the sitting would write {}", size.describe()));
                            verdict = Some(Verdict::Cancelled);
                        }
                    });
                });
                if verdict.is_none() {
                    self.state = State::Confirm { size, sitting };
                }
                verdict
            }
        }
    }
}
