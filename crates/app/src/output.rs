//! Output helpers shared by the headless commands: JSON on stdout with
//! `--json`, a human-readable table otherwise.

use serde::Serialize;
use std::io::Write;

/// Write `value` as one line of JSON, or the human text, to stdout.
pub fn emit<T: Serialize>(
    json: bool,
    value: &T,
    human: impl FnOnce() -> String,
) -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    if json {
        // Serialised whole before anything is written: a value that
        // cannot be encoded is an error, never a truncated object.
        let mut text = serde_json::to_vec(value)?;
        text.push(b'\n');
        out.write_all(&text)?;
    } else {
        write!(out, "{}", human())?;
    }
    out.flush()?;
    Ok(())
}

/// Segmenting options shared by the Welch-based commands (`psd`, `frf`).
#[derive(Debug, Clone, clap::Args)]
pub struct WelchArgs {
    /// Sample rate in Hz.
    #[arg(long)]
    pub fs: f64,
    /// Segment length in samples.
    #[arg(long)]
    pub nperseg: usize,
    /// Overlap in samples (default nperseg/2).
    #[arg(long)]
    pub noverlap: Option<usize>,
}

impl WelchArgs {
    /// The dsp crate's configuration: scipy defaults (periodic Hann, constant
    /// detrend, one-sided density) with these segment settings.
    pub fn config(&self) -> kilotouch_dsp::spectral::WelchConfig {
        let mut cfg = kilotouch_dsp::spectral::WelchConfig::new(self.nperseg);
        cfg.noverlap = self.noverlap;
        cfg
    }
}

/// Wrap an angle in degrees to (−180, 180].
pub fn wrap_deg(mut d: f64) -> f64 {
    if !d.is_finite() {
        return d;
    }
    d %= 360.0;
    if d <= -180.0 {
        d += 360.0;
    } else if d > 180.0 {
        d -= 360.0;
    }
    d
}

/// Magnitude in dB (20·log10|x|); −inf for 0.
pub fn db(mag: f64) -> f64 {
    20.0 * mag.log10()
}

/// Parse a comma-separated list of positive finite frequencies in hertz.
pub fn parse_freqs(s: &str) -> anyhow::Result<Vec<f64>> {
    let mut out = Vec::new();
    for (i, tok) in s.split(',').enumerate() {
        let t = tok.trim();
        let v: f64 = t
            .parse()
            .map_err(|_| anyhow::anyhow!("--freqs: item {} (`{t}`) is not a number", i + 1))?;
        if !(v.is_finite() && v > 0.0) {
            anyhow::bail!(
                "--freqs: item {} ({v}) must be a positive finite frequency in Hz",
                i + 1
            );
        }
        out.push(v);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_is_half_open_interval() {
        assert_eq!(wrap_deg(180.0), 180.0);
        assert_eq!(wrap_deg(-180.0), 180.0);
        assert_eq!(wrap_deg(540.0), 180.0);
        assert!((wrap_deg(-190.0) - 170.0).abs() < 1e-12);
        assert!((wrap_deg(725.0) - 5.0).abs() < 1e-12);
    }

    #[test]
    fn freqs_parse_and_reject() {
        assert_eq!(
            parse_freqs("100, 200.5,1e3").unwrap(),
            vec![100.0, 200.5, 1000.0]
        );
        assert!(
            parse_freqs("100,abc")
                .unwrap_err()
                .to_string()
                .contains("item 2")
        );
        assert!(parse_freqs("0").is_err());
        assert!(parse_freqs("-5").is_err());
    }
}
