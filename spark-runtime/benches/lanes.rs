//! Eight McLachlan–Perlmutter particle members (`n = 7`, Lobatto IIIA-B
//! `s = 2`, `h = 0.05`, simplified Newton with the stage-decoupled matrix:
//! the settings of the paper's Fig. 8.4), 500 steps each per iteration:
//!
//! - `lanes/mp7/sequential`: eight steppers, one member after another;
//! - `lanes/mp7/lanes-4x2`: two [`LaneStepper`]s of four lanes;
//! - `lanes/mp7/lanes-8`: one [`LaneStepper`] of eight lanes;
//! - `lanes/mp7/lanes-8-without-kernel`: one group of eight whose members
//!   step alone, each by its own stepper ([`LaneStepper::without_kernel`]);
//!
//! timed by the measuring thread's CPU time (one core), and
//! - `lanes/mp7/ensemble-2-threads`: [`integrate_ensemble`] on a pool of
//!   two threads, by wall time.
//!
//! Run with `cargo bench -p spark-runtime --bench lanes`.

use criterion::measurement::WallTime;
use criterion::{black_box, criterion_group, criterion_main, Criterion};
use spark_runtime::fixtures::paper::MpParticles;
use spark_runtime::{
    integrate_ensemble, Jacobian, LaneStepper, Method, NewtonMode, NewtonOptions, State, Stepper, Tableau, Vector,
};

use std::time::Duration;

#[path = "common/clock.rs"]
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

fn one_core(c: &mut C) {
    let starts = starts();
    let mut steppers: Vec<_> =
        (0..MEMBERS).map(|_| Stepper::<_, 7, 1, 2, 23>::new(MpParticles, tableau()).with_options(options())).collect();
    c.bench_function("lanes/mp7/sequential", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for (st, start) in steppers.iter_mut().zip(&starts) {
                st.reset_warm_start();
                let mut s = *start;
                for _ in 0..STEPS {
                    s = st.step(&s, H).unwrap().state;
                }
                acc += s.q[0];
            }
            black_box(acc)
        })
    });
    let mut groups: Vec<_> =
        (0..2).map(|_| LaneStepper::<_, 7, 1, 2, 23, 4>::new(MpParticles, tableau(), options())).collect();
    c.bench_function("lanes/mp7/lanes-4x2", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for (lanes, chunk) in groups.iter_mut().zip(starts.chunks(4)) {
                lanes.start(chunk, H).unwrap();
                lanes.advance_by(STEPS);
                acc += lanes.state(0).unwrap().q[0];
            }
            black_box(acc)
        })
    });
    for (name, kernel) in [("lanes/mp7/lanes-8", true), ("lanes/mp7/lanes-8-without-kernel", false)] {
        let lanes = LaneStepper::<_, 7, 1, 2, 23, 8>::new(MpParticles, tableau(), options());
        let mut lanes = if kernel { lanes } else { lanes.without_kernel() };
        c.bench_function(name, |b| {
            b.iter(|| {
                lanes.start(&starts, H).unwrap();
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
                    integrate_ensemble::<_, 7, 1, 2, 23>(&MpParticles, tableau(), options(), &starts, H, STEPS, 0)
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
