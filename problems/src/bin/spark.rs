//! `spark`: the command-line program. Lists the systems and methods, runs one
//! simulation, or reproduces the paper's experiments (§8) with one command.
//! The grammar and the subcommands live in [`problems::cli`]; this file
//! parses, runs and prints.

use problems::cli::Cli;
use std::process::ExitCode;

#[path = "shared/signals.rs"]
mod signals;
#[path = "shared/stdio.rs"]
mod stdio;

fn main() -> ExitCode {
    let cli = match stdio::parse::<Cli>() {
        Ok(cli) => cli,
        Err(status) => return status,
    };
    signals::clean_up_on_signals();
    match problems::cli::run(cli, &stdio::say) {
        Ok(text) => stdio::write_stdout(&text),
        Err(message) => {
            stdio::say(&format!("error: {message}"));
            ExitCode::FAILURE
        }
    }
}
