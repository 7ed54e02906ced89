//! `spark`: the command-line program. Lists the systems and methods, runs one
//! simulation, or reproduces the paper's experiments (§8) with one command.
//! The grammar and the subcommands live in [`problems::cli`]; this file
//! parses, runs and prints.

use clap::Parser;
use problems::cli::Cli;
use std::process::ExitCode;

fn main() -> ExitCode {
    match problems::cli::run(Cli::parse(), &|line| eprintln!("{line}")) {
        Ok(text) => {
            print!("{text}");
            ExitCode::SUCCESS
        }
        Err(message) => {
            eprintln!("error: {message}");
            ExitCode::FAILURE
        }
    }
}
