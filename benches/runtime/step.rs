//! Cost of one SPARK step on the paper's systems with hand-written
//! derivatives (fast to build; the generated-code benches live in
//! `benches/problems/spark.rs`). Run with `cargo bench -p spark-benches --bench step`.
//!
//! - `step/<system>/<method>/<mode>`: one warm-started step at h = 0.05,
//!   full Newton, simplified Newton on the exact matrix, and simplified
//!   Newton on the stage-decoupled matrix (`Simplified-decoupled`), default
//!   options otherwise (energy guard on);
//! - `step/<system>/<method>/<mode>/no-guard`: the same with
//!   `energy_drift_limit: None`, measured in the same run so that the
//!   guard's cost per step is the difference of two neighbouring lines.
//!
//! Timed by the measuring thread's CPU time (`CLOCK_THREAD_CPUTIME_ID`),
//! not wall time: the machine is shared, and CPU time is what stays
//! comparable between runs under load.

use criterion::measurement::WallTime;
use criterion::{criterion_group, criterion_main, Criterion};
use spark_benches::paper::{restarting_steps, Starts};
use spark_runtime::fixtures::paper::{MobileRobot, MpParticles, Particle, Skate};
use spark_runtime::{Jacobian, Method, NewtonMode, NewtonOptions, NonholonomicSystem, State, Stepper, Tableau};

use std::time::Duration;

#[path = "../common/clock.rs"]
mod clock;
use clock::{ThreadCpu, C};

const H: f64 = 0.05;

fn bench_run<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    c: &mut C,
    name: &str,
    sys: Sys,
    method: Method,
    start: State<N>,
    guard_pair: bool,
) where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let modes = [
        (NewtonMode::Full, Jacobian::Exact, "Full"),
        (NewtonMode::Simplified, Jacobian::Exact, "Simplified"),
        (NewtonMode::Simplified, Jacobian::StageDecoupled, "Simplified-decoupled"),
    ];
    for (mode, jacobian, mode_name) in modes {
        let variants: &[bool] = if guard_pair { &[true, false] } else { &[true] };
        for &guard in variants {
            let mut opts = NewtonOptions { mode, jacobian, ..NewtonOptions::default() };
            let mut label = format!("step/{name}/{method} s={S}/{mode_name}");
            if !guard {
                opts.energy_drift_limit = None;
                label.push_str("/no-guard");
            }
            let mut st = Stepper::<Sys, N, M, S, D>::new(sys.clone(), Tableau::new(method).unwrap()).with_options(opts);
            let mut steps = restarting_steps(&mut st, start, H);
            c.bench_function(&label, |b| b.iter(&mut steps));
        }
    }
}

fn benches(c: &mut C) {
    let Starts { particle: p0, skate: s0, robot: r0, mp7: m0 } = Starts::paper();
    let (gauss, lob) = (Method::Gauss, Method::LobattoIIIAB);
    bench_run::<_, 3, 1, 2, 11>(c, "particle", Particle, gauss, p0, false);
    bench_run::<_, 3, 1, 2, 11>(c, "skate", Skate::default(), gauss, s0, true);
    bench_run::<_, 4, 2, 2, 16>(c, "robot", MobileRobot::default(), gauss, r0, true);
    bench_run::<_, 7, 1, 2, 23>(c, "mp7", MpParticles, gauss, m0, true);
    bench_run::<_, 3, 1, 3, 15>(c, "skate", Skate::default(), lob, s0, false);
    bench_run::<_, 4, 2, 3, 22>(c, "robot", MobileRobot::default(), lob, r0, false);
    bench_run::<_, 7, 1, 2, 23>(c, "mp7", MpParticles, lob, m0, true);
    bench_run::<_, 7, 1, 4, 39>(c, "mp7", MpParticles, gauss, m0, false);
}

criterion_group! {
    name = step;
    config = Criterion::default()
        .with_measurement(ThreadCpu(WallTime))
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(1));
    targets = benches
}
criterion_main!(step);
