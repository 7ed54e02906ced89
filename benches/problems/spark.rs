//! Criterion benchmarks of the generated systems (not part of the test suite;
//! run with `cargo bench -p spark-benches --bench spark`):
//! - one SPARK step per paper system × method family × stage count
//!   (warm-started, at the work-precision sweep's mid-range step), full
//!   Newton (`step/…`) and simplified Newton (`step-simplified/…`), default
//!   options (energy guard on);
//! - for Gauss s = 2 and Lobatto IIIA-B s = 2 the same steps with the energy
//!   guard off (`step-no-guard/…`, `step-simplified-no-guard/…`,
//!   `energy_drift_limit: None`), measured in the same run as the default so
//!   that the guard's cost per step is the difference of neighbouring benches;
//! - the Newton linear algebra of one iteration alone (`newton/…`: factor
//!   the assembled `D × D` matrix and solve once, on a copy of the matrix
//!   of a real step) and the solve alone (`newton-solve/…`);
//! - the fused derivative evaluations alone (`stage_values`,
//!   `stage_jacobians`), generated code against num-dual and central
//!   differences;
//! - the ψ-eliminated right-hand side the ODE peers integrate.
//!
//! Every bench is timed by the measuring thread's CPU time
//! (`CLOCK_THREAD_CPUTIME_ID`), not wall time: the machine is shared, and
//! CPU time is what stays comparable between runs under load.

use criterion::measurement::WallTime;
use criterion::{black_box, criterion_group, criterion_main, Criterion};
use problems::catalog::SystemKind;
use problems::peers::dual::{AutoDiff, DualTwin};
use problems::peers::finite_difference::FiniteDifference;
use problems::peers::ode;
use problems::run::paper_initial_values;
use problems::systems::{McLachlanPerlmutter7, MobileRobot, NonholonomicParticle, Skate};
use spark_runtime::{Method, NewtonMode, NewtonOptions, NonholonomicSystem, State, Stepper, Tableau, Vector};
use std::time::Duration;

#[path = "../common/clock.rs"]
mod clock;
use clock::{ThreadCpu, C};

fn start<const N: usize>(kind: SystemKind) -> State<N> {
    let (q, v) = paper_initial_values(kind);
    State::new(0.0, Vector::<N>::from_column_slice(&q), Vector::<N>::from_column_slice(&v))
}

fn step<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    c: &mut C,
    kind: SystemKind,
    method: Method,
    h: f64,
    guard_pair: bool,
) where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let label = format!("{}/{}", kind.key(), method.label(S));
    let s0 = start::<N>(kind);
    let mut runs = vec![("step", NewtonMode::Full, true), ("step-simplified", NewtonMode::Simplified, true)];
    if guard_pair {
        runs.push(("step-no-guard", NewtonMode::Full, false));
        runs.push(("step-simplified-no-guard", NewtonMode::Simplified, false));
    }
    for (group, mode, guard) in runs {
        let mut opts = NewtonOptions { mode, ..NewtonOptions::default() };
        if !guard {
            opts.energy_drift_limit = None;
        }
        let mut st = Stepper::<Sys, N, M, S, D>::new(Sys::default(), Tableau::new(method).unwrap()).with_options(opts);
        let mut s = s0;
        c.bench_function(&format!("{group}/{label}"), |b| {
            b.iter(|| {
                // Stay in the paper's regime: restart every 10 time units.
                if s.t > 10.0 {
                    s = s0;
                    st.reset_warm_start();
                }
                s = st.step(&s, h).unwrap().state;
                black_box(s.q[0])
            })
        });
    }
    // The linear algebra of one Newton iteration, on the matrix of a real
    // step (one second into the trajectory, warm).
    let mut st = Stepper::<Sys, N, M, S, D>::new(Sys::default(), Tableau::new(method).unwrap());
    let mut s = s0;
    while s.t < 1.0 {
        s = st.step(&s, h).unwrap().state;
    }
    let (matrix, g) = st.newton_matrix(&s, h);
    let mut work = matrix.clone();
    c.bench_function(&format!("newton/{label}"), |b| {
        b.iter(|| {
            work.factor().unwrap();
            let mut x = g;
            work.solve_in_place(&mut x);
            black_box(x[0])
        })
    });
    c.bench_function(&format!("newton-solve/{label}"), |b| {
        b.iter(|| {
            let mut x = black_box(g);
            work.solve_in_place(&mut x);
            black_box(x[0])
        })
    });
}

macro_rules! all_methods {
    ($c:expr, $sys:ty, $kind:expr, $h:expr) => {{
        const NN: usize = <$sys>::N;
        const MM: usize = <$sys>::M;
        step::<$sys, NN, MM, 1, { NN + MM + NN }>($c, $kind, Method::Gauss, $h, false);
        step::<$sys, NN, MM, 2, { 2 * (NN + MM) + NN }>($c, $kind, Method::Gauss, $h, true);
        step::<$sys, NN, MM, 3, { 3 * (NN + MM) + NN }>($c, $kind, Method::Gauss, $h, false);
        step::<$sys, NN, MM, 4, { 4 * (NN + MM) + NN }>($c, $kind, Method::Gauss, $h, false);
        step::<$sys, NN, MM, 5, { 5 * (NN + MM) + NN }>($c, $kind, Method::Gauss, $h, false);
        for m in [Method::LobattoIIIAB, Method::LobattoIIIABD] {
            step::<$sys, NN, MM, 2, { 2 * (NN + MM) + NN }>($c, $kind, m, $h, m == Method::LobattoIIIAB);
            step::<$sys, NN, MM, 3, { 3 * (NN + MM) + NN }>($c, $kind, m, $h, false);
            step::<$sys, NN, MM, 4, { 4 * (NN + MM) + NN }>($c, $kind, m, $h, false);
            step::<$sys, NN, MM, 5, { 5 * (NN + MM) + NN }>($c, $kind, m, $h, false);
        }
        step::<$sys, NN, MM, 1, { NN + MM + NN }>($c, $kind, Method::SymplecticEulerI, $h, false);
        step::<$sys, NN, MM, 1, { NN + MM + NN }>($c, $kind, Method::SymplecticEulerII, $h, false);
        step::<$sys, NN, MM, 2, { 2 * (NN + MM) + NN }>($c, $kind, Method::LobattoIIIBALda, $h, false);
    }};
}

fn steps(c: &mut C) {
    all_methods!(c, NonholonomicParticle, SystemKind::Particle, 0.05);
    all_methods!(c, Skate, SystemKind::Skate, 0.05);
    all_methods!(c, MobileRobot, SystemKind::Robot, 0.05);
    all_methods!(c, McLachlanPerlmutter7, SystemKind::McLachlanPerlmutter7, 0.05);
}

fn derivatives_of<Sys, const N: usize, const M: usize>(c: &mut C, kind: SystemKind)
where
    Sys: NonholonomicSystem<N, M> + DualTwin<N, M> + Default,
{
    let s = start::<N>(kind);
    let (q, v) = (s.q.add_scalar(0.1), s.v.add_scalar(0.2));
    let psi = Vector::<M>::repeat(0.3);
    let generated = Sys::default();
    let ad = AutoDiff(<Sys as DualTwin<N, M>>::Twin::default());
    let fd = FiniteDifference(Sys::default());
    let key = kind.key();
    c.bench_function(&format!("derivatives/{key}/stage_values/generated"), |b| {
        b.iter(|| black_box(generated.stage_values(0.0, black_box(&q), &v, &psi)))
    });
    c.bench_function(&format!("derivatives/{key}/stage_values/num-dual"), |b| {
        b.iter(|| black_box(ad.stage_values(0.0, black_box(&q), &v, &psi)))
    });
    c.bench_function(&format!("derivatives/{key}/stage_jacobians/generated"), |b| {
        b.iter(|| black_box(generated.stage_jacobians(0.0, black_box(&q), &v, &psi)))
    });
    c.bench_function(&format!("derivatives/{key}/stage_jacobians/num-dual"), |b| {
        b.iter(|| black_box(ad.stage_jacobians(0.0, black_box(&q), &v, &psi)))
    });
    c.bench_function(&format!("derivatives/{key}/stage_jacobians/finite-differences"), |b| {
        b.iter(|| black_box(fd.stage_jacobians(0.0, black_box(&q), &v, &psi)))
    });
    c.bench_function(&format!("derivatives/{key}/psi-eliminated-rhs"), |b| {
        b.iter(|| black_box(ode::acceleration::<Sys, N, M>(&generated, 0.0, black_box(&q), &v)))
    });
}

fn derivatives(c: &mut C) {
    derivatives_of::<NonholonomicParticle, 3, 1>(c, SystemKind::Particle);
    derivatives_of::<Skate, 3, 1>(c, SystemKind::Skate);
    derivatives_of::<MobileRobot, 4, 2>(c, SystemKind::Robot);
    derivatives_of::<McLachlanPerlmutter7, 7, 1>(c, SystemKind::McLachlanPerlmutter7);
}

criterion_group! {
    name = benches;
    config = Criterion::default().with_measurement(ThreadCpu(WallTime)).warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(1));
    targets = derivatives, steps
}
criterion_main!(benches);
