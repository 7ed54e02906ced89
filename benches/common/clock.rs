//! The criterion measurement every bench shares: the measuring thread's CPU
//! time (`problems::report::clock`, `CLOCK_THREAD_CPUTIME_ID`), not wall
//! time: the machine is shared, and CPU time is what stays comparable between
//! runs under load.

use criterion::measurement::{Measurement, ValueFormatter, WallTime};
use criterion::Criterion;
use std::time::Duration;

/// The calling thread's CPU time in seconds (NaN when the clock fails).
pub use problems::report::clock::thread_cpu_seconds as thread_cpu_time;

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
