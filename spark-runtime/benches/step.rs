//! Cost of one SPARK step (full and simplified Newton) on the paper's systems
//! at the paper's step sizes, with hand-written derivatives.

use criterion::{criterion_group, criterion_main, Criterion};
use spark_runtime::handwritten::{MobileRobot, MpParticles, Particle, Skate};
use spark_runtime::{Method, NewtonMode, NewtonOptions, NonholonomicSystem, State, Stepper, Tableau, Vector};

fn bench_run<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    c: &mut Criterion,
    name: &str,
    sys: Sys,
    method: Method,
    mode: NewtonMode,
    start: State<N>,
    h: f64,
) where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let opts = NewtonOptions { mode, ..NewtonOptions::default() };
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap()).with_options(opts);
    let mut s = start;
    c.bench_function(&format!("{name} {method} s={S} {mode:?}"), |b| {
        b.iter(|| {
            // Restart from the initial condition now and then so the
            // trajectory stays in the paper's regime.
            if s.t > 50.0 {
                s = start;
                st.reset_warm_start();
            }
            s = st.step(&s, h).unwrap().state;
            s.q[0]
        })
    });
}

fn benches(c: &mut Criterion) {
    let p0 = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let s0 = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let r0 = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0));
    let m0 = State::new(
        0.0,
        Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]),
        Vector::<7>::from_row_slice(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
    );
    for mode in [NewtonMode::Full, NewtonMode::Simplified] {
        bench_run::<_, 3, 1, 2, 11>(c, "particle", Particle, Method::Gauss, mode, p0, 0.2);
        bench_run::<_, 3, 1, 3, 15>(c, "skate", Skate::default(), Method::LobattoIIIAB, mode, s0, 0.1);
        bench_run::<_, 4, 2, 3, 22>(c, "robot", MobileRobot::default(), Method::LobattoIIIABD, mode, r0, 0.2);
        for m in [Method::LobattoIIIAB, Method::ModifiedLobattoIIIAB, Method::LobattoIIIBALda] {
            bench_run::<_, 7, 1, 2, 23>(c, "MP", MpParticles, m, mode, m0, 0.05);
        }
    }
}

criterion_group!(step, benches);
criterion_main!(step);
