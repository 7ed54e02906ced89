//! Child processes that do not outlive the program.
//!
//! The work-precision peers run in a Python interpreter, which starts
//! `gcc` and a timing driver of its own. Each child is started by [`spawn`]:
//! - in a process group of its own, so that the child and everything it
//!   starts (that does not leave the group) are ended together;
//! - registered, under the same lock as its start, so that a binary's
//!   handler of SIGINT, SIGTERM and SIGHUP ends every running group with
//!   [`end_children`] before the program ends by the signal, and no child
//!   starts after it;
//! - on Linux, with `PR_SET_PDEATHSIG`: the kernel kills the child when the
//!   thread that started it ends, so a program killed outright (SIGKILL, a
//!   crash) does not leave its child running. The thread waits for the
//!   child ([`Running::wait`]), so it ends no sooner than the child does.
//!   What the child starts in turn is then left to the child.
//!
//! A group's id is the child's process id, which stays the child's until
//! the child is reaped: [`Running::wait`] unregisters the child before it
//! reaps it, so no signal reaches a process that took the id since.

use std::process::{Child, Command, ExitStatus};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Process ids (and process group ids) of the running children.
static RUNNING: Mutex<Vec<libc::pid_t>> = Mutex::new(Vec::new());

/// How long [`end_children`] waits for the children to end by the signal
/// before it kills their groups.
pub const GRACE: Duration = Duration::from_secs(1);

/// The registry. A thread that panicked while holding it left the list
/// consistent (each operation updates it last), so a poisoned lock is taken
/// as is.
fn running() -> MutexGuard<'static, Vec<libc::pid_t>> {
    RUNNING.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A child started by [`spawn`], leader of its own process group. Dropped
/// without [`Running::wait`], its group is killed and the child reaped.
#[derive(Debug)]
pub struct Running {
    child: Child,
    /// Whether the child is reaped (and unregistered).
    reaped: bool,
}

/// Starts `command` as a child in a process group of its own and registers
/// it (see the module documentation).
pub fn spawn(command: &mut Command) -> std::io::Result<Running> {
    use std::os::unix::process::CommandExt;
    command.process_group(0);
    #[cfg(target_os = "linux")]
    {
        let parent = std::process::id();
        // SAFETY: `prctl` and `getppid` are async-signal-safe system calls
        // on plain integers, the only calls between fork and exec.
        unsafe {
            command.pre_exec(move || {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL as libc::c_ulong) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                // The parent may have ended before the request was made.
                if libc::getppid() as u32 != parent {
                    return Err(std::io::Error::from_raw_os_error(libc::ESRCH));
                }
                Ok(())
            });
        }
    }
    let mut live = running();
    let child = command.spawn()?;
    live.push(child.id() as libc::pid_t);
    Ok(Running { child, reaped: false })
}

impl Running {
    /// The child's process id, which is also its process group's id.
    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// The child, for its standard streams.
    pub fn child(&mut self) -> &mut Child {
        &mut self.child
    }

    /// Kills the child's process group (SIGKILL), ignoring errors; the
    /// child is still to be waited for.
    pub fn kill(&mut self) {
        if !self.reaped {
            // SAFETY: `kill` takes plain integers; the unreaped child keeps
            // the group's id from being taken by another process.
            unsafe { libc::kill(-(self.child.id() as libc::pid_t), libc::SIGKILL) };
        }
    }

    /// Waits for the child to end, unregisters it and reaps it.
    pub fn wait(&mut self) -> std::io::Result<ExitStatus> {
        if !self.reaped {
            let pid = self.child.id() as libc::pid_t;
            let ended = exited(pid, true);
            // Also when the wait failed: a child that cannot be waited for
            // (reaped elsewhere) is no longer known to hold its id.
            running().retain(|&p| p != pid);
            self.reaped = true;
            ended?;
        }
        self.child.wait()
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        if !self.reaped {
            self.kill();
            let _ = self.wait();
        }
    }
}

/// Whether the child `pid` has ended, without reaping it: waits for it when
/// `block`.
fn exited(pid: libc::pid_t, block: bool) -> std::io::Result<bool> {
    let wait = if block { 0 } else { libc::WNOHANG };
    let flags = libc::WEXITED | libc::WNOWAIT | wait;
    loop {
        // SAFETY: `info` is a plain struct the call fills in; `WNOWAIT`
        // leaves the child to be reaped by its `Child`.
        let mut info: libc::siginfo_t = unsafe { std::mem::zeroed() };
        let rc = unsafe { libc::waitid(libc::P_PID, pid as libc::id_t, &mut info, flags) };
        if rc == 0 {
            // With WNOHANG and no child ended, the call leaves the pid 0.
            // SAFETY: the field is set by a successful call.
            return Ok(unsafe { info.si_pid() } != 0);
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

/// Ends every running child and its process group: sends them `signal`,
/// gives the children [`GRACE`] to end, then kills the groups (SIGKILL),
/// which ends what the children started and left behind or that has not
/// ended by the signal. Returns the registry, held: until it is dropped no
/// child is started or reaped. For a binary's signal handler, which ends
/// the process while holding the value.
pub fn end_children(signal: i32) -> impl Sized {
    let live = running();
    for &pid in live.iter() {
        // SAFETY: `kill` takes plain integers; a registered child is not
        // reaped, so its group's id is still its own.
        unsafe { libc::kill(-pid, signal) };
    }
    let start = Instant::now();
    while start.elapsed() < GRACE && !live.iter().all(|&pid| exited(pid, false).unwrap_or(true)) {
        std::thread::sleep(Duration::from_millis(5));
    }
    for &pid in live.iter() {
        // SAFETY: as above.
        unsafe { libc::kill(-pid, libc::SIGKILL) };
    }
    live
}
