//! The one thread-CPU clock, and the medians of timed repeats: `spark
//! run`'s statistics, the work-precision study and the criterion benches
//! read it. Thread CPU time, unlike wall time, does not grow when other
//! processes compete for the cores.

use crate::report::stats::median;
use std::time::{Duration, Instant};

/// CPU time consumed so far by the calling thread
/// (`CLOCK_THREAD_CPUTIME_ID`); `None` where the clock is unavailable.
pub fn thread_cpu_time() -> Option<Duration> {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes one timespec through a valid pointer.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    (rc == 0).then(|| Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32))
}

/// [`thread_cpu_time`] in seconds, NaN where the clock is unavailable.
pub fn thread_cpu_seconds() -> f64 {
    thread_cpu_time().map_or(f64::NAN, |d| d.as_secs_f64())
}

/// Medians of the wall and thread-CPU times of `run`, repeated `repeats`
/// times or until `min_total` has been spent (at most 1000 times).
pub fn median_time<F: FnMut() -> bool>(repeats: usize, min_total: Duration, mut run: F) -> Option<(f64, f64, usize)> {
    timed_repeats(repeats, min_total, &mut run)
}

/// [`median_time`] with `run` as a trait object: the loop is compiled
/// once, not once per timed closure.
fn timed_repeats(repeats: usize, min_total: Duration, run: &mut dyn FnMut() -> bool) -> Option<(f64, f64, usize)> {
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    let start = Instant::now();
    while wall.len() < repeats.max(1) || (start.elapsed() < min_total && wall.len() < 1000) {
        let (t, c) = (Instant::now(), thread_cpu_seconds());
        if !run() {
            return None;
        }
        cpu.push(thread_cpu_seconds() - c);
        wall.push(t.elapsed().as_secs_f64());
    }
    let n = wall.len();
    Some((median(wall), median(cpu), n))
}
