//! Eight McLachlan–Perlmutter particle members (`n = 7`, Lobatto IIIA-B
//! `s = 2`, `h = 0.05`, simplified Newton with the stage-decoupled matrix:
//! the settings of the paper's Fig. 8.4), 500 steps each per iteration, for
//! the system declared with `nonholonomic_system!` (`mp7`, whose stage
//! values the kernel evaluates in lane form) and for the hand-written
//! fixture (`mp7-hand-written`, evaluated lane by lane):
//!
//! - `lanes/<system>/sequential`: eight steppers, one member after another;
//! - `lanes/<system>/lanes-4x2`: two [`LaneStepper`]s of four lanes;
//! - `lanes/<system>/lanes-8`: one [`LaneStepper`] of eight lanes;
//! - `lanes/<system>/lanes-8-without-kernel`: one group of eight whose
//!   members step alone, each by its own stepper
//!   ([`LaneStepper::without_kernel`]);
//!
//! timed by the measuring thread's CPU time (one core), and
//! - `lanes/mp7/ensemble-2-threads`: [`integrate_ensemble`] on a pool of
//!   two threads, by wall time.
//!
//! The same one-core cases for eight members of the paper's particle
//! (`particle`, `n = 3`, `h = 0.2`), whose quadratic potential the
//! stage-decoupled matrix and the kernel keep (`CONSTANT_STIFFNESS`), but
//! whose steps start from the previous step's factors (a closed affine
//! cover whose first update moves a curved pair), a path the kernel hands
//! back: its members step alone in their lanes, and the group shows what
//! the lanes cost where the kernel cannot hold them.
//!
//! Run with `cargo bench -p spark-benches --bench lanes`.

use criterion::measurement::WallTime;
use criterion::{black_box, criterion_group, criterion_main, Criterion};
use spark_runtime::fixtures::paper::MpParticles;
use spark_runtime::{
    integrate_ensemble, nonholonomic_system, Jacobian, LaneStepper, Method, NewtonMode, NewtonOptions,
    NonholonomicSystem, State, Stepper, Tableau, Vector,
};

use std::time::Duration;

#[path = "../common/clock.rs"]
mod clock;
use clock::{ThreadCpu, C};

const H: f64 = 0.05;
const STEPS: usize = 500;
const MEMBERS: usize = 8;

fn options() -> NewtonOptions {
    NewtonOptions { mode: NewtonMode::Simplified, jacobian: Jacobian::Auto, ..NewtonOptions::default() }
}

fn tableau() -> Tableau<2> {
    Tableau::new(Method::LobattoIIIAB).unwrap()
}

/// Eight particle members: `q₀ = (1, 0, 0)`, `v₀ = (0, 1 + 0.05 j, 0)`
/// (consistent: `k = v₃ − q₂ v₁`).
fn particle_starts() -> Vec<State<3>> {
    (0..MEMBERS)
        .map(|j| State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0 + 0.05 * j as f64, 0.0)))
        .collect()
}

fn starts() -> Vec<State<7>> {
    let q0 = Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
    (0..MEMBERS)
        .map(|j| {
            let mut v0 = Vector::<7>::zeros();
            v0[1] = 0.05 * j as f64;
            State::new(0.0, q0, v0)
        })
        .collect()
}

nonholonomic_system! {
    /// The McLachlan–Perlmutter particles of Fig. 8.4 (`problems`'
    /// `McLachlanPerlmutter7`).
    pub struct Mp7 {
        coordinates: [q1, q2, q3, q4, q5, q6, q7],
        lagrangian: (dot(q1)^2 + dot(q2)^2 + dot(q3)^2 + dot(q4)^2 + dot(q5)^2 + dot(q6)^2 + dot(q7)^2)/2
            - (q1^2 + q2^2 + q3^2 + q4^2 + q5^2 + q6^2 + q7^2
               + q5^2*q6^2 + q2^2*q5^2 + q3^2*q6^2 + q4^2*q7^2)/2,
        constraints: [ dot(q1) + q5*dot(q5) + q6*dot(q6) + q7*dot(q7) ],
    }
}

nonholonomic_system! {
    /// The paper's nonholonomic particle (`problems`' `NonholonomicParticle`).
    pub struct Particle {
        coordinates: [x, y, z],
        lagrangian: (dot(x)^2 + dot(y)^2 + dot(z)^2)/2 - (x^2 + y^2),
        constraints: [ dot(z) - y*dot(x) ],
    }
}

fn one_core(c: &mut C) {
    one_core_for::<_, 7, 23>(c, "mp7", Mp7::default(), &starts(), H);
    one_core_for::<_, 7, 23>(c, "mp7-hand-written", MpParticles, &starts(), H);
    one_core_for::<_, 3, 11>(c, "particle", Particle::default(), &particle_starts(), 0.2);
}

fn one_core_for<Sys, const N: usize, const D: usize>(c: &mut C, system: &str, sys: Sys, starts: &[State<N>], h: f64)
where
    Sys: NonholonomicSystem<N, 1> + Clone,
{
    let mut steppers: Vec<_> =
        (0..MEMBERS).map(|_| Stepper::<_, N, 1, 2, D>::new(sys.clone(), tableau()).with_options(options())).collect();
    c.bench_function(&format!("lanes/{system}/sequential"), |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for (st, start) in steppers.iter_mut().zip(starts) {
                st.reset_warm_start();
                let mut s = *start;
                for _ in 0..STEPS {
                    s = st.step(&s, h).unwrap().state;
                }
                acc += s.q[0];
            }
            black_box(acc)
        })
    });
    let mut groups: Vec<_> =
        (0..2).map(|_| LaneStepper::<_, N, 1, 2, D, 4>::new(sys.clone(), tableau(), options())).collect();
    c.bench_function(&format!("lanes/{system}/lanes-4x2"), |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for (lanes, chunk) in groups.iter_mut().zip(starts.chunks(4)) {
                lanes.start(chunk, h).unwrap();
                lanes.advance_by(STEPS);
                acc += lanes.state(0).unwrap().q[0];
            }
            black_box(acc)
        })
    });
    for (case, kernel) in [("lanes-8", true), ("lanes-8-without-kernel", false)] {
        let lanes = LaneStepper::<_, N, 1, 2, D, 8>::new(sys.clone(), tableau(), options());
        let mut lanes = if kernel { lanes } else { lanes.without_kernel() };
        c.bench_function(&format!("lanes/{system}/{case}"), |b| {
            b.iter(|| {
                lanes.start(starts, h).unwrap();
                lanes.advance_by(STEPS);
                black_box(lanes.state(0).unwrap().q[0])
            })
        });
    }
}

fn threads(c: &mut Criterion<WallTime>) {
    let starts = starts();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
    c.bench_function("lanes/mp7/ensemble-2-threads", |b| {
        b.iter(|| {
            pool.install(|| {
                let runs =
                    integrate_ensemble::<_, 7, 1, 2, 23>(&Mp7::default(), tableau(), options(), &starts, H, STEPS, 0)
                        .unwrap();
                black_box(runs[0].samples[1].q[0])
            })
        })
    });
}

criterion_group! {
    name = lanes_one_core;
    config = Criterion::default()
        .with_measurement(ThreadCpu(WallTime))
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    targets = one_core
}
criterion_group! {
    name = lanes_threads;
    config = Criterion::default().warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3));
    targets = threads
}
criterion_main!(lanes_one_core, lanes_threads);
