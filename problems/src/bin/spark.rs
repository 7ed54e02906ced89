//! `spark`: the command-line program. Lists the systems and methods, runs one
//! simulation, or reproduces the paper's experiments (§8) with one command.
//! The grammar and the subcommands live in [`problems::cli`]; this file
//! parses, runs and prints.

use clap::Parser;
use problems::cli::Cli;
use std::io::Write;
use std::process::ExitCode;

fn main() -> ExitCode {
    // Standard error that cannot be written loses the message, not the run.
    let say = |line: &str| {
        let _ = writeln!(std::io::stderr(), "{line}");
    };
    match problems::cli::run(Cli::parse(), &say) {
        Ok(text) => {
            // Written, not `print!`ed: `print!` panics when standard output
            // cannot take the text (a full disk, a closed pipe), and so does
            // `eprintln!` on standard error.
            let mut out = std::io::stdout().lock();
            match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
                Ok(()) => ExitCode::SUCCESS,
                // The reader has gone (`spark list | head -1`) after taking
                // what it wanted: the command did its work (its files are
                // written), so it ends quietly and succeeds, and a pipeline
                // under `set -o pipefail` does not fail for it.
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
                Err(e) => {
                    say(&format!("error: cannot write to standard output: {e}"));
                    ExitCode::FAILURE
                }
            }
        }
        Err(message) => {
            say(&format!("error: {message}"));
            ExitCode::FAILURE
        }
    }
}
