//! Progress of long headless commands on stderr (`study simulate`,
//! `study power`).

use std::io::Write;

/// Progress on stderr: a bar redrawn in place on a terminal, a line per
/// 10 % otherwise.
pub(crate) struct Bar {
    pub(crate) tty: bool,
    pub(crate) last_decile: Option<usize>,
    /// What is counted ("trials", "simulated studies").
    pub(crate) unit: &'static str,
}

impl Bar {
    pub(crate) fn report(&mut self, done: usize, total: usize) {
        let f = if total == 0 {
            1.0
        } else {
            done as f64 / total as f64
        };
        let mut err = std::io::stderr().lock();
        if self.tty {
            let width = 30;
            let filled = ((f * width as f64).round() as usize).min(width);
            let _ = write!(
                err,
                "\r\x1b[2K[{}{}] {:3.0}% {done}/{total} {}",
                "#".repeat(filled),
                " ".repeat(width - filled),
                f * 100.0,
                self.unit
            );
            if done >= total {
                let _ = writeln!(err);
            }
        } else {
            let decile = (f * 10.0).floor() as usize;
            if self.last_decile != Some(decile) {
                let _ = writeln!(err, "[{:3.0}%] {done}/{total} {}", f * 100.0, self.unit);
                self.last_decile = Some(decile);
            }
        }
    }
}
