//! The one thread-CPU clock: `spark run`'s statistics, the work-precision
//! study and the criterion benches read it. Thread CPU time, unlike wall
//! time, does not grow when other processes compete for the cores.

use std::time::Duration;

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thread_clock_advances_with_work() {
        let start = thread_cpu_seconds();
        let mut x = 0.0f64;
        for i in 0..2_000_000 {
            x += (i as f64).sqrt();
        }
        std::hint::black_box(x);
        assert!(thread_cpu_seconds() > start);
    }
}
