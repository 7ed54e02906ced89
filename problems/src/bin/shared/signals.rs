//! Ending on SIGINT, SIGTERM and SIGHUP (Ctrl-C, `kill`, a closed
//! terminal) without leaving temporary files or running children behind.
//!
//! A thread waits for the signals (`signal_hook`'s iterator: the signal
//! handler itself only wakes the thread, so the cleanup runs outside signal
//! context and may take locks). On one it calls
//! [`problems::children::end_children`], which passes the signal on to the
//! process group of every running child (a child runs in a group of its
//! own, so Ctrl-C at a terminal reaches it through this handler only) and
//! kills the groups that have not ended within a moment, then
//! [`problems::report::files::remove_temporary_files`], which finishes a
//! folder commit in progress, removes every temporary file of the process
//! and keeps any thread from creating or renaming one; then it ends the
//! process by the same signal with its default action, so a shell sees
//! the status it would without the handler (130 for Ctrl-C) and a script
//! looping over runs stops on Ctrl-C.
//!
//! A signal that is ignored when the program starts (`nohup` ignores
//! SIGHUP, a shell's background job SIGINT) stays ignored.

use problems::children::end_children;
use problems::report::files::remove_temporary_files;
use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
use signal_hook::iterator::Signals;

/// Starts the thread that handles the signals. Should the handlers not be
/// installed, the signals keep their default action: an interrupted run
/// still leaves its earlier results whole, the next run in the folder
/// removes the temporary files, and on Linux the kernel ends the children
/// the program started (`PR_SET_PDEATHSIG`, see [`problems::children`]).
pub fn clean_up_on_signals() {
    let handled: Vec<i32> = [SIGINT, SIGTERM, SIGHUP].into_iter().filter(|&s| !ignored(s)).collect();
    let Ok(mut signals) = Signals::new(&handled) else { return };
    let _ = std::thread::Builder::new().name("signals".into()).spawn(move || {
        if let Some(signal) = signals.forever().next() {
            let _no_children = end_children(signal);
            let _held = remove_temporary_files();
            // SAFETY: `signal` and `kill` are async-signal-safe and take
            // plain integers; the default action of these signals ends the
            // process.
            unsafe {
                libc::signal(signal, libc::SIG_DFL);
                libc::kill(libc::getpid(), signal);
            }
            // Not reached unless the signal could not be delivered.
            std::process::exit(128 + signal);
        }
    });
}

/// Whether `signal` is ignored (`SIG_IGN`) in this process.
fn ignored(signal: i32) -> bool {
    // SAFETY: a null new action only reads the current one into `old`.
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        libc::sigaction(signal, std::ptr::null(), &mut old) == 0 && old.sa_sigaction == libc::SIG_IGN
    }
}
