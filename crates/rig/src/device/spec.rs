//! `--rig` specifications: `sim`,
//! `serial:PATH[,baud=N][,timeout-ms=N][,lead=auto|N][,min-rate=PERCENT]`, `audio[:DEVICE]`.

use crate::error::RigError;
use crate::serial::{CommandLead, SerialConfig};
use std::time::Duration;

/// Which rig a command talks to.
#[derive(Debug, Clone, PartialEq)]
pub enum RigSpec {
    /// The simulated rig.
    Sim,
    /// A DAQ (or the emulator) on a serial port.
    Serial(SerialConfig),
    /// An audio interface (`None`: the default device).
    Audio(Option<String>),
}

impl RigSpec {
    /// Short description for messages, e.g. `serial:/dev/ttyACM0`.
    pub fn describe(&self) -> String {
        match self {
            RigSpec::Sim => "sim".into(),
            RigSpec::Serial(c) => format!("serial:{}", c.path),
            RigSpec::Audio(None) => "audio".into(),
            RigSpec::Audio(Some(d)) => format!("audio:{d}"),
        }
    }

    /// The error for an audio rig in a build without it.
    pub fn audio_not_built() -> RigError {
        RigError::NotReady(
            "audio-interface rigs are not available in this build (cargo feature `audio`)".into(),
        )
    }
}

fn bad(spec: &str, why: impl std::fmt::Display) -> RigError {
    RigError::InvalidInput(format!(
        "--rig {spec}: {why} (expected `sim`, \
         `serial:PATH[,baud=N][,timeout-ms=N][,lead=auto|N][,min-rate=PERCENT]` or `audio[:DEVICE]`)"
    ))
}

impl std::str::FromStr for RigSpec {
    type Err = RigError;

    fn from_str(s: &str) -> Result<Self, RigError> {
        let t = s.trim();
        if t == "sim" {
            return Ok(RigSpec::Sim);
        }
        if t == "audio" {
            return Ok(RigSpec::Audio(None));
        }
        if let Some(dev) = t.strip_prefix("audio:") {
            if dev.is_empty() {
                return Err(bad(s, "empty audio device name"));
            }
            return Ok(RigSpec::Audio(Some(dev.to_string())));
        }
        let Some(rest) = t.strip_prefix("serial:") else {
            return Err(bad(s, "unknown rig"));
        };
        let mut parts = rest.split(',');
        let path = parts.next().unwrap_or("");
        if path.is_empty() {
            return Err(bad(s, "missing port path"));
        }
        let mut cfg = SerialConfig::new(path);
        // A closed loop over a link leads by default (`lead=0` for
        // block-synchronous exchange).
        cfg.lead = CommandLead::Auto;
        for opt in parts {
            let (k, v) = opt
                .split_once('=')
                .ok_or_else(|| bad(s, format!("option `{opt}` is not key=value")))?;
            if k == "lead" {
                cfg.lead = match v {
                    "auto" => CommandLead::Auto,
                    n => match n.parse::<u32>() {
                        Ok(b) if b <= 64 => CommandLead::Blocks(b),
                        _ => {
                            return Err(bad(
                                s,
                                format!(
                                    "`lead` is `auto` or a number of blocks 0 ..= 64, got `{v}`"
                                ),
                            ));
                        }
                    },
                };
                continue;
            }
            let num: u64 = v
                .parse()
                .map_err(|_| bad(s, format!("`{k}` needs a whole number, got `{v}`")))?;
            match k {
                "baud" if (1..=u64::from(u32::MAX)).contains(&num) => cfg.baud = num as u32,
                // The answers to HELLO and START are waited for as long
                // (at least the default 2 s).
                "timeout-ms" if (1..=60_000).contains(&num) => {
                    cfg.timeout = Duration::from_millis(num);
                    cfg.handshake_timeout = cfg.handshake_timeout.max(cfg.timeout);
                }
                "min-rate" if num <= 100 => cfg.min_rate_fraction = num as f64 / 100.0,
                "baud" | "timeout-ms" | "min-rate" => {
                    return Err(bad(s, format!("`{k}` = {num} out of range")));
                }
                _ => return Err(bad(s, format!("unknown option `{k}`"))),
            }
        }
        Ok(RigSpec::Serial(cfg))
    }
}

/// Which tweezer the loop talks to (`--tweezer`): the simulated one of the
/// rig file, or a live tweezer (or its emulator) on a serial port, with the
/// same options as a serial rig (`serial:PATH[,baud=N][,timeout-ms=N]
/// [,lead=auto|N]`).
#[derive(Debug, Clone, PartialEq, Default)]
pub enum TweezerSpec {
    /// The simulated tweezer (with its simulated position detector).
    #[default]
    Sim,
    /// A live tweezer on a serial port.
    Serial(SerialConfig),
}

impl TweezerSpec {
    /// Short description for messages, e.g. `serial:/dev/ttyACM1`.
    pub fn describe(&self) -> String {
        match self {
            TweezerSpec::Sim => "sim".into(),
            TweezerSpec::Serial(c) => format!("serial:{}", c.path),
        }
    }
}

impl std::str::FromStr for TweezerSpec {
    type Err = RigError;

    fn from_str(s: &str) -> Result<Self, RigError> {
        let t = s.trim();
        if t.starts_with("audio") {
            return Err(RigError::InvalidInput(format!(
                "--tweezer {s}: an audio interface is not a tweezer \
                 (expected `sim` or `serial:PATH[,baud=N][,timeout-ms=N][,lead=auto|N]`)"
            )));
        }
        match t.parse::<RigSpec>() {
            Ok(RigSpec::Serial(c)) => Ok(TweezerSpec::Serial(c)),
            Ok(_) => Ok(TweezerSpec::Sim),
            Err(RigError::InvalidInput(m)) => Err(RigError::InvalidInput(m.replacen(
                "--rig ",
                "--tweezer ",
                1,
            ))),
            Err(e) => Err(e),
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn tweezer_specs_are_sim_or_serial() {
        assert_eq!("sim".parse::<TweezerSpec>().unwrap(), TweezerSpec::Sim);
        let TweezerSpec::Serial(c) = "serial:/dev/pts/4,lead=2".parse().unwrap() else {
            panic!()
        };
        assert_eq!(
            (c.path.as_str(), c.lead),
            ("/dev/pts/4", CommandLead::Blocks(2))
        );
        let e = "audio".parse::<TweezerSpec>().unwrap_err().to_string();
        assert!(e.contains("not a tweezer"), "{e}");
        let e = "serial:".parse::<TweezerSpec>().unwrap_err().to_string();
        assert!(
            e.contains("--tweezer serial:") && e.contains("missing port path"),
            "{e}"
        );
    }

    /// The serial rig of `spec`.
    fn serial(spec: &str) -> SerialConfig {
        match spec.parse::<RigSpec>().unwrap() {
            RigSpec::Serial(c) => c,
            other => panic!("{spec}: {other:?}"),
        }
    }

    #[test]
    fn parses_every_form_and_rejects_bad_ones() {
        assert_eq!("sim".parse::<RigSpec>().unwrap(), RigSpec::Sim);
        assert_eq!("audio".parse::<RigSpec>().unwrap(), RigSpec::Audio(None));
        assert_eq!(
            "audio:hw:1".parse::<RigSpec>().unwrap(),
            RigSpec::Audio(Some("hw:1".into()))
        );
        let c = serial("serial:/dev/ttyACM0");
        assert_eq!(c.path, "/dev/ttyACM0");
        assert_eq!(c.baud, SerialConfig::DEFAULT_BAUD);
        let c = serial("serial:/dev/pts/3,baud=921600,timeout-ms=40");
        assert_eq!((c.path.as_str(), c.baud), ("/dev/pts/3", 921_600));
        assert_eq!(c.timeout, Duration::from_millis(40));
        assert_eq!(c.handshake_timeout, Duration::from_secs(2));
        assert_eq!(c.lead, CommandLead::Auto);
        // A long time-out covers the answers to HELLO and START too; the
        // rate check's share is a percentage.
        let c = serial("serial:/dev/pts/3,timeout-ms=30000,min-rate=0");
        assert_eq!(c.timeout, Duration::from_secs(30));
        assert_eq!(c.handshake_timeout, Duration::from_secs(30));
        assert_eq!(c.min_rate_fraction, 0.0);
        let c = serial("serial:/dev/pts/3,lead=0");
        assert_eq!(c.lead, CommandLead::Blocks(0));
        for bad in [
            "serial:/dev/x,lead=-1",
            "serial:/dev/x,lead=65",
            "serial:/dev/x,lead=fast",
        ] {
            let e = bad.parse::<RigSpec>().unwrap_err().to_string();
            assert!(e.contains("lead"), "{bad}: {e}");
        }
        for bad in [
            "",
            "serial:",
            "serial:/dev/x,baud",
            "serial:/dev/x,baud=fast",
            "serial:/dev/x,baud=0",
            "serial:/dev/x,parity=odd",
            "audio:",
            "usb",
        ] {
            let e = bad.parse::<RigSpec>().unwrap_err().to_string();
            assert!(e.contains("--rig"), "{bad}: {e}");
        }
    }
}
