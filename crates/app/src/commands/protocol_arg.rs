//! `--protocol`: a protocol TOML file or a built-in protocol's name, the
//! argument `study simulate`, `study run`, `study power --simulate` and
//! `bench fidelity` share, with their `--participants` and `--seed`
//! overrides.

use std::path::PathBuf;

use kilotouch_study::protocol::Protocol;

/// The protocol `spec` names: an existing file, else a built-in name
/// (`paper`, `blind`); an error naming both choices otherwise.
pub fn load_protocol(spec: &str) -> anyhow::Result<Protocol> {
    let path = PathBuf::from(spec);
    if path.is_file() {
        return Protocol::load(&path).map_err(anyhow::Error::from);
    }
    if kilotouch_study::protocol::BUILTIN_NAMES.contains(&spec) {
        return Protocol::builtin(spec).map_err(anyhow::Error::from);
    }
    anyhow::bail!(
        "--protocol {spec}: no such file, and not a built-in protocol (expected a TOML file or one of: {})",
        kilotouch_study::protocol::BUILTIN_NAMES.join(", ")
    )
}

/// The protocol `spec` names with the command line's participants and
/// study seed (where given), validated again after the overrides.
pub fn load_protocol_with(
    spec: &str,
    participants: Option<u32>,
    seed: Option<u64>,
) -> anyhow::Result<Protocol> {
    let mut protocol = load_protocol(spec)?;
    if let Some(n) = participants {
        protocol.participants = n;
    }
    if let Some(s) = seed {
        protocol.seeds.study = s;
    }
    protocol
        .validate()
        .map_err(|e| anyhow::anyhow!("invalid protocol after the command-line overrides: {e}"))?;
    Ok(protocol)
}

/// `--threads`: the number given (at least 1), or the available cores.
pub fn threads(arg: Option<usize>) -> anyhow::Result<usize> {
    match arg {
        Some(0) => anyhow::bail!("--threads must be at least 1"),
        Some(t) => Ok(t),
        None => Ok(std::thread::available_parallelism().map_or(1, usize::from)),
    }
}
