//! `--protocol`: a protocol TOML file or a built-in protocol's name, the
//! argument `study simulate` and `study run` share.

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
