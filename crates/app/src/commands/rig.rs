//! `kilotouch rig …`: rig files and rig checks.

use clap::Subcommand;
use kilotouch_rig::config::default_config_text;

/// `kilotouch rig` subcommands.
#[derive(Debug, Subcommand)]
pub enum RigCommand {
    /// Print the default rig file (TOML, SI units; parameters named after the paper's Table 2).
    DefaultConfig,
}

/// Run a `rig` subcommand.
pub fn run(cmd: &RigCommand) -> anyhow::Result<()> {
    match cmd {
        RigCommand::DefaultConfig => {
            print!("{}", default_config_text());
            Ok(())
        }
    }
}
