//! The thread-CPU clock the runtime's benches share: a criterion
//! [`Measurement`] by the measuring thread's CPU time
//! (`CLOCK_THREAD_CPUTIME_ID`), not wall time: the machine is shared, and
//! CPU time is what stays comparable between runs under load.

use criterion::measurement::{Measurement, ValueFormatter, WallTime};
use criterion::Criterion;
use std::time::Duration;

#[repr(C)]
struct Timespec {
    tv_sec: i64,
    tv_nsec: i64,
}

extern "C" {
    fn clock_gettime(clock: i32, ts: *mut Timespec) -> i32;
}

/// `CLOCK_THREAD_CPUTIME_ID` on Linux.
const THREAD_CPU_CLOCK: i32 = 3;

/// The calling thread's CPU time in seconds (NaN when the clock fails).
#[allow(dead_code)] // called directly by some benches only
pub fn thread_cpu_time() -> f64 {
    let mut ts = Timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes one timespec through a valid pointer.
    let rc = unsafe { clock_gettime(THREAD_CPU_CLOCK, &mut ts) };
    if rc == 0 {
        ts.tv_sec as f64 + 1e-9 * ts.tv_nsec as f64
    } else {
        f64::NAN
    }
}

/// Criterion measurement by the calling thread's CPU time.
pub struct ThreadCpu(pub WallTime);

impl Measurement for ThreadCpu {
    type Intermediate = f64;
    type Value = Duration;
    fn start(&self) -> f64 {
        thread_cpu_time()
    }
    fn end(&self, start: f64) -> Duration {
        Duration::from_secs_f64((thread_cpu_time() - start).max(0.0))
    }
    fn add(&self, a: &Duration, b: &Duration) -> Duration {
        *a + *b
    }
    fn zero(&self) -> Duration {
        Duration::ZERO
    }
    fn to_f64(&self, v: &Duration) -> f64 {
        v.as_nanos() as f64
    }
    fn formatter(&self) -> &dyn ValueFormatter {
        self.0.formatter()
    }
}

/// A criterion run measured by [`ThreadCpu`].
pub type C = Criterion<ThreadCpu>;
