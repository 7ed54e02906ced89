//! Cost of one full Newton step at the step sizes of the catalogue's
//! defaults for the paper's systems (particle h = 0.2, skate 0.1, robot 0.2,
//! McLachlan–Perlmutter particles 0.05), Gauss s = 1..3 and Lobatto IIIA-B
//! s = 2..4: the benchmark of Newton's stopping rule. Run with
//! `cargo bench -p spark-benches --bench newton_stop`.
//!
//! Before timing, each case runs 10 time units and prints its mean Newton
//! iterations and factorizations per step (`counts ...` lines on stderr).
//! Timed by the measuring thread's CPU time, like the `step` bench.

use criterion::measurement::WallTime;
use criterion::{criterion_group, criterion_main, Criterion};
use spark_benches::paper::{restarting_steps, Starts, RESTART_AFTER};
use spark_runtime::fixtures::paper::{MobileRobot, MpParticles, Particle, Skate};
use spark_runtime::{Method, NewtonMode, NewtonOptions, NonholonomicSystem, State, Stepper, Tableau};

use std::time::Duration;

#[path = "../common/clock.rs"]
mod clock;
use clock::{ThreadCpu, C};

fn case<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    c: &mut C,
    name: &str,
    sys: Sys,
    method: Method,
    start: State<N>,
    h: f64,
) where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let opts = NewtonOptions { mode: NewtonMode::Full, ..NewtonOptions::default() };
    let label = format!("stop/{name} h={h}/{method} s={S}/Full");
    let new = || Stepper::<Sys, N, M, S, D>::new(sys.clone(), Tableau::new(method).unwrap()).with_options(opts);
    let mut st = new();
    let (mut s, mut steps, mut iterations, mut factorizations) = (start, 0usize, 0usize, 0usize);
    while s.t < RESTART_AFTER {
        let r = st.step(&s, h).unwrap();
        (s, steps) = (r.state, steps + 1);
        iterations += r.iterations;
        factorizations += r.factorizations;
    }
    let per = |x: usize| x as f64 / steps as f64;
    eprintln!("counts {label}: iterations/step {:.3}, factorizations/step {:.3}", per(iterations), per(factorizations));
    let mut st = new();
    let mut steps = restarting_steps(&mut st, start, h);
    c.bench_function(&label, |b| b.iter(&mut steps));
}

fn benches(c: &mut C) {
    let Starts { particle: p0, skate: s0, robot: r0, mp7: m0 } = Starts::paper();
    let (gauss, lob) = (Method::Gauss, Method::LobattoIIIAB);
    macro_rules! family {
        ($name:literal, $sys:expr, $start:expr, $h:expr, $n:literal, $m:literal) => {
            case::<_, $n, $m, 1, { $n + $m + $n }>(c, $name, $sys, gauss, $start, $h);
            case::<_, $n, $m, 2, { 2 * ($n + $m) + $n }>(c, $name, $sys, gauss, $start, $h);
            case::<_, $n, $m, 3, { 3 * ($n + $m) + $n }>(c, $name, $sys, gauss, $start, $h);
            case::<_, $n, $m, 2, { 2 * ($n + $m) + $n }>(c, $name, $sys, lob, $start, $h);
            case::<_, $n, $m, 3, { 3 * ($n + $m) + $n }>(c, $name, $sys, lob, $start, $h);
            case::<_, $n, $m, 4, { 4 * ($n + $m) + $n }>(c, $name, $sys, lob, $start, $h);
        };
    }
    family!("particle", Particle, p0, 0.2, 3, 1);
    family!("skate", Skate::default(), s0, 0.1, 3, 1);
    family!("robot", MobileRobot::default(), r0, 0.2, 4, 2);
    family!("mp7", MpParticles, m0, 0.05, 7, 1);
}

criterion_group! {
    name = stop;
    config = Criterion::default()
        .with_measurement(ThreadCpu(WallTime))
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(1));
    targets = benches
}
criterion_main!(stop);
