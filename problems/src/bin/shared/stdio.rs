//! Standard output and standard error of the binaries, written so that
//! nothing a user does with them (`> /dev/full`, `| head -1`, a closed
//! descriptor) panics or passes for success.
//!
//! - Text goes out through `write_all` and a flush, whose errors are
//!   checked, never through `print!`/`println!`, which panic when standard
//!   output cannot take the text.
//! - A full disk or any other write error on standard output is a message
//!   on standard error and exit status 1.
//! - A reader that has gone (`spark list | head -1`, a broken pipe) after
//!   taking what it wanted ends the program quietly with the status it
//!   would have had: the command did its work (its files are written), and
//!   a pipeline under `set -o pipefail` does not fail for it.
//! - Messages on standard error are written without `eprintln!`, which
//!   panics when standard error cannot take them: the message is lost, the
//!   exit status is kept.

use std::io::{ErrorKind, Write};
use std::process::ExitCode;

/// Writes `line` and a newline to standard error; a standard error that
/// cannot take it loses the line.
pub fn say(line: &str) {
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// Writes `text` to standard output and returns the exit status: success
/// when it is written or the reader has gone, 1 (with a message on standard
/// error) when it cannot be written.
pub fn write_stdout(text: &str) -> ExitCode {
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => stdout_failed(&e, ExitCode::SUCCESS),
    }
}

fn stdout_failed(e: &std::io::Error, success: ExitCode) -> ExitCode {
    if e.kind() == ErrorKind::BrokenPipe {
        return success;
    }
    say(&format!("error: cannot write to standard output: {e}"));
    ExitCode::FAILURE
}

/// The parsed command line, or the exit status after `--help`, `--version`
/// or a usage error has been printed. `clap::Parser::parse` would print
/// them with `Error::exit`, which ignores a failed write: `spark --help >
/// /dev/full` would end with status 0 and no help written anywhere.
pub fn parse<P: clap::Parser>() -> Result<P, ExitCode> {
    P::try_parse().map_err(|e| {
        // Help and version go to standard output with status 0, usage
        // errors to standard error with status 2.
        let status = ExitCode::from(u8::try_from(e.exit_code()).unwrap_or(1));
        let printed = e.print().and_then(|()| if e.use_stderr() { Ok(()) } else { std::io::stdout().flush() });
        match printed {
            Ok(()) => status,
            Err(err) if !e.use_stderr() => stdout_failed(&err, status),
            // A usage error that standard error cannot take keeps its
            // status, which is already a failure.
            Err(_) => status,
        }
    })
}
