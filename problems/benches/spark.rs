//! Criterion benchmarks of the generated systems (not part of the test suite;
//! run with `cargo bench -p problems --bench spark`):
//! - one SPARK step per paper system × method family × stage count (full
//!   Newton, warm-started, at the work-precision sweep's mid-range step);
//! - the fused derivative evaluations alone (`stage_values`,
//!   `stage_jacobians`), generated code against num-dual and central
//!   differences;
//! - the ψ-eliminated right-hand side the ODE peers integrate.
//!
//! The Newton linear algebra alone is the step minus its derivative calls;
//! `docs/performance/README.md` splits one step that way.

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use problems::peers::dual::{AutoDiff, DualTwin};
use problems::peers::finite_difference::FiniteDifference;
use problems::peers::ode;
use problems::simulate::{paper_initial_values, SystemKind};
use problems::systems::{McLachlanPerlmutter7, MobileRobot, NonholonomicParticle, Skate};
use problems::workprecision::method_label;
use spark_runtime::{Method, NonholonomicSystem, State, Stepper, Tableau, Vector};
use std::time::Duration;

fn start<const N: usize>(kind: SystemKind) -> State<N> {
    let (q, v) = paper_initial_values(kind);
    State::new(0.0, Vector::<N>::from_column_slice(&q), Vector::<N>::from_column_slice(&v))
}

fn step<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    c: &mut Criterion,
    kind: SystemKind,
    method: Method,
    h: f64,
) where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let mut st = Stepper::<Sys, N, M, S, D>::new(Sys::default(), Tableau::new(method).unwrap());
    let s0 = start::<N>(kind);
    let mut s = s0;
    c.bench_function(&format!("step/{}/{}", kind.key(), method_label(method, S)), |b| {
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

macro_rules! all_methods {
    ($c:expr, $sys:ty, $kind:expr, $h:expr) => {{
        const NN: usize = <$sys>::N;
        const MM: usize = <$sys>::M;
        step::<$sys, NN, MM, 1, { NN + MM + NN }>($c, $kind, Method::Gauss, $h);
        step::<$sys, NN, MM, 2, { 2 * (NN + MM) + NN }>($c, $kind, Method::Gauss, $h);
        step::<$sys, NN, MM, 3, { 3 * (NN + MM) + NN }>($c, $kind, Method::Gauss, $h);
        step::<$sys, NN, MM, 4, { 4 * (NN + MM) + NN }>($c, $kind, Method::Gauss, $h);
        step::<$sys, NN, MM, 5, { 5 * (NN + MM) + NN }>($c, $kind, Method::Gauss, $h);
        for m in [Method::LobattoIIIAB, Method::LobattoIIIABD] {
            step::<$sys, NN, MM, 2, { 2 * (NN + MM) + NN }>($c, $kind, m, $h);
            step::<$sys, NN, MM, 3, { 3 * (NN + MM) + NN }>($c, $kind, m, $h);
            step::<$sys, NN, MM, 4, { 4 * (NN + MM) + NN }>($c, $kind, m, $h);
            step::<$sys, NN, MM, 5, { 5 * (NN + MM) + NN }>($c, $kind, m, $h);
        }
        step::<$sys, NN, MM, 1, { NN + MM + NN }>($c, $kind, Method::SymplecticEulerI, $h);
        step::<$sys, NN, MM, 1, { NN + MM + NN }>($c, $kind, Method::SymplecticEulerII, $h);
        step::<$sys, NN, MM, 2, { 2 * (NN + MM) + NN }>($c, $kind, Method::LobattoIIIBALda, $h);
    }};
}

fn steps(c: &mut Criterion) {
    all_methods!(c, NonholonomicParticle, SystemKind::Particle, 0.05);
    all_methods!(c, Skate, SystemKind::Skate, 0.05);
    all_methods!(c, MobileRobot, SystemKind::Robot, 0.05);
    all_methods!(c, McLachlanPerlmutter7, SystemKind::McLachlanPerlmutter7, 0.05);
}

fn derivatives_of<Sys, const N: usize, const M: usize>(c: &mut Criterion, kind: SystemKind)
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

fn derivatives(c: &mut Criterion) {
    derivatives_of::<NonholonomicParticle, 3, 1>(c, SystemKind::Particle);
    derivatives_of::<Skate, 3, 1>(c, SystemKind::Skate);
    derivatives_of::<MobileRobot, 4, 2>(c, SystemKind::Robot);
    derivatives_of::<McLachlanPerlmutter7, 7, 1>(c, SystemKind::McLachlanPerlmutter7);
}

criterion_group! {
    name = benches;
    config = Criterion::default().warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(1));
    targets = derivatives, steps
}
criterion_main!(benches);
