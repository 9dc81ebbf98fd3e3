//! `kilotouch rig …`: rig files and rig checks.

use clap::Subcommand;
use kilotouch_rig::config::default_config_text;

/// `kilotouch rig` subcommands.
#[derive(Debug, Subcommand)]
pub enum RigCommand {
    /// Print the default rig file (TOML, SI units; parameters named after the paper's Table 2).
    DefaultConfig,
    /// List audio devices (id for `--rig audio:ID`, name, channels, rates); `audio` feature.
    #[cfg(feature = "audio")]
    ListAudio {
        /// JSON output.
        #[arg(long)]
        json: bool,
    },
}

/// Run a `rig` subcommand.
pub fn run(cmd: &RigCommand) -> anyhow::Result<()> {
    match cmd {
        RigCommand::DefaultConfig => {
            print!("{}", default_config_text());
            Ok(())
        }
        #[cfg(feature = "audio")]
        RigCommand::ListAudio { json } => list_audio(*json),
    }
}

#[cfg(feature = "audio")]
fn list_audio(json: bool) -> anyhow::Result<()> {
    let devices = kilotouch_rig::audio::list_audio_devices()?;
    if json {
        println!("{}", serde_json::to_string_pretty(&devices)?);
        return Ok(());
    }
    for d in &devices {
        println!("{} ({}): {}", d.id, d.host, d.name);
        for (dir, info) in [("out", &d.output), ("in", &d.input)] {
            if let Some(i) = info {
                println!(
                    "    {dir:>3}: default {} ch {} Hz {}; up to {} ch, {}–{} Hz",
                    i.default_channels,
                    i.default_rate_hz,
                    i.default_format,
                    i.max_channels,
                    i.min_rate_hz,
                    i.max_rate_hz
                );
            }
        }
    }
    Ok(())
}
