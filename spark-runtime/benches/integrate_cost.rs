//! Cost of `integrate` for systems without events and schedules without
//! dense sampling: the dense output and event location must add nothing
//! there. The file uses only API that predates them, so the same bench
//! builds against the code before and after they were added and the two
//! binaries' lines compare side by side (docs/dense-output-and-events.md).
//! Run with `cargo bench -p spark-runtime --bench integrate_cost`.
//!
//! `integrate/<system>/Gauss s=2/200 steps`: one `integrate` call of 200
//! fixed steps at h = 0.05 (full Newton, default options), timed by the
//! measuring thread's CPU time.

use criterion::measurement::WallTime;
use criterion::{black_box, criterion_group, criterion_main, Criterion};
use spark_runtime::fixtures::paper::{MobileRobot, Particle, Skate};
use spark_runtime::{Method, NoObserver, NonholonomicSystem, RunOptions, Schedule, State, Stepper, Tableau, Vector};

use std::time::Duration;

#[path = "common/clock.rs"]
mod clock;
use clock::{ThreadCpu, C};

fn bench_integrate<Sys, const N: usize, const M: usize, const D: usize>(
    c: &mut C,
    name: &str,
    sys: Sys,
    start: State<N>,
) where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let mut st = Stepper::<Sys, N, M, 2, D>::new(sys, Tableau::new(Method::Gauss).unwrap());
    let options = RunOptions { record_every: 0, ..RunOptions::default() };
    c.bench_function(&format!("integrate/{name}/Gauss s=2/200 steps"), |b| {
        b.iter(|| {
            let traj = st
                .integrate(
                    start.t,
                    &start.q,
                    &start.v,
                    Schedule::Fixed { h: 0.05, steps: 200 },
                    &options,
                    &mut NoObserver,
                )
                .unwrap();
            black_box(traj.samples.len())
        })
    });
}

fn benches(c: &mut C) {
    let particle = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    bench_integrate::<_, 3, 1, 11>(c, "particle", Particle, particle);
    let skate = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    bench_integrate::<_, 3, 1, 11>(c, "skate", Skate::default(), skate);
    let robot = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    bench_integrate::<_, 4, 2, 16>(c, "robot", MobileRobot::default(), robot);
}

criterion_group! {
    name = integrate_cost;
    config = Criterion::default().with_measurement(ThreadCpu(WallTime)).sample_size(30)
        .measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
    targets = benches
}
criterion_main!(integrate_cost);
