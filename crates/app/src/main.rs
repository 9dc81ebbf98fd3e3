//! `kilotouch` binary: thin wrapper over the application library.

fn main() -> std::process::ExitCode {
    kilotouch::cli::main_entry()
}
