//! Progress of long headless commands on stderr (`study simulate`,
//! `study power`, `paper`, `bench --paced`): an `indicatif` bar (elapsed time, percentage,
//! count or stage) redrawn in place on a terminal; without a terminal (CI
//! logs, a cluster job's output file) one line per 10 % of a count, or per
//! stage, so logs stay short.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// Resolution of a fractional progress (positions per whole).
const FRACTION_STEPS: u64 = 1000;

/// Progress on stderr (module docs).
pub(crate) struct Progress {
    /// The bar, on a terminal only.
    bar: Option<ProgressBar>,
    /// What is counted ("trials", "simulated studies").
    unit: &'static str,
    last_decile: Option<usize>,
    last_stage: String,
}

impl Progress {
    /// Progress of a count of `unit`.
    pub(crate) fn new(unit: &'static str) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = ProgressBar::with_draw_target(Some(1), ProgressDrawTarget::stderr());
            b.set_style(
                ProgressStyle::with_template(
                    "[{elapsed_precise}] {bar:30} {percent:>3}% {pos}/{len} {msg}",
                )
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            b.set_message(unit);
            b
        });
        Self {
            bar,
            unit,
            last_decile: None,
            last_stage: String::new(),
        }
    }

    /// Progress of stages reported as a fraction and a message
    /// ("stage: detail"; the lines without a terminal name the stage).
    pub(crate) fn stages() -> Self {
        let p = Self::new("");
        if let Some(b) = &p.bar {
            b.set_style(
                ProgressStyle::with_template("[{elapsed_precise}] {bar:30} {percent:>3}% {msg}")
                    .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            b.set_length(FRACTION_STEPS);
        }
        p
    }

    /// `done` of `total` counted.
    pub(crate) fn count(&mut self, done: usize, total: usize) {
        let f = if total == 0 {
            1.0
        } else {
            done as f64 / total as f64
        };
        match &self.bar {
            Some(b) => {
                b.set_length(total as u64);
                b.set_position(done as u64);
            }
            None => {
                let decile = (f * 10.0).floor() as usize;
                if self.last_decile != Some(decile) {
                    eprintln!("[{:3.0}%] {done}/{total} {}", f * 100.0, self.unit);
                    self.last_decile = Some(decile);
                }
            }
        }
    }

    /// A fraction `f` in [0, 1] done, now at `msg`.
    pub(crate) fn fraction(&mut self, f: f64, msg: &str) {
        let f = if f.is_finite() {
            f.clamp(0.0, 1.0)
        } else {
            0.0
        };
        match &self.bar {
            Some(b) => {
                b.set_position((f * FRACTION_STEPS as f64) as u64);
                b.set_message(msg.to_owned());
            }
            None => {
                let stage = msg.split(':').next().unwrap_or(msg);
                if stage != self.last_stage {
                    eprintln!("[{:3.0}%] {stage}", f * 100.0);
                    self.last_stage = stage.to_owned();
                }
            }
        }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}
