//! Cost of `integrate` for systems without events and schedules without
//! dense sampling: the dense output and event location must add nothing
//! there (docs/dense-output-and-events.md). Run with
//! `cargo bench -p spark-runtime --bench integrate_cost`.
//!
//! Two measurements in one run, each of 200 fixed Gauss `s = 2` steps at
//! h = 0.05 (full Newton, default step options), timed by the measuring
//! thread's CPU time:
//!
//! - criterion benches `integrate/<system>/Gauss s=2/200 steps` (one
//!   `integrate` call, observation off, nothing recorded) and
//!   `step-loop/<system>/Gauss s=2/200 steps` (the same 200 steps as a bare
//!   loop of `Stepper::step`, the least a run can do). The `integrate` lines
//!   use only API that predates dense output and events, so the same bench
//!   also builds against a stepper without them;
//! - the paired comparison `integrate / step loop`: the two alternate
//!   (order swapped every round) for `ROUNDS` rounds of `CALLS` runs each, so
//!   load on the machine hits both alike; it prints the median of each, the
//!   ratio of the medians and the median and quartiles of the per-round
//!   ratios. A ratio of 1 means the driver's dense-output, event, schedule and
//!   observation code costs nothing on this path.

use criterion::measurement::WallTime;
use criterion::{black_box, criterion_group, Criterion};
use spark_runtime::fixtures::paper::{MobileRobot, MpParticles, Particle, Skate};
use spark_runtime::{
    Method, NoObserver, NonholonomicSystem, Observe, RunOptions, Schedule, State, Stepper, Tableau, Vector,
};

use std::time::Duration;

#[path = "common/clock.rs"]
mod clock;
use clock::{thread_cpu_time, ThreadCpu, C};

/// Steps per run and their size.
const STEPS: usize = 200;
const H: f64 = 0.05;
/// Rounds of the paired comparison, and runs per timed sample.
const ROUNDS: usize = 61;
const CALLS: usize = 5;

/// One system of the comparison: its stepper and initial state.
struct Case<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize, const D: usize> {
    name: &'static str,
    stepper: Stepper<Sys, N, M, 2, D>,
    start: State<N>,
}

/// `integrate` with nothing observed and nothing recorded but the end.
fn quiet() -> RunOptions {
    RunOptions {
        observe: Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        ..RunOptions::default()
    }
}

impl<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize, const D: usize> Case<Sys, N, M, D> {
    fn new(name: &'static str, sys: Sys, start: State<N>) -> Self {
        Case { name, stepper: Stepper::new(sys, Tableau::new(Method::Gauss).unwrap()), start }
    }

    /// One `integrate` call; returns the end state.
    fn integrate(&mut self, options: &RunOptions) -> State<N> {
        let s = self.start;
        let traj = self
            .stepper
            .integrate(s.t, &s.q, &s.v, Schedule::Fixed { h: H, steps: STEPS }, options, &mut NoObserver)
            .unwrap();
        let end = traj.samples.last().unwrap();
        State::new(end.t, end.q, end.v)
    }

    /// The same steps as a bare `Stepper::step` loop; returns the end state.
    fn step_loop(&mut self) -> State<N> {
        let mut state = self.start;
        for _ in 0..STEPS {
            state = self.stepper.step(&state, H).unwrap().state;
        }
        state
    }

    fn criterion(&mut self, c: &mut C) {
        let options = quiet();
        c.bench_function(&format!("integrate/{}/Gauss s=2/{STEPS} steps", self.name), |b| {
            b.iter(|| black_box(self.integrate(&options)))
        });
        c.bench_function(&format!("step-loop/{}/Gauss s=2/{STEPS} steps", self.name), |b| {
            b.iter(|| black_box(self.step_loop()))
        });
    }

    /// The paired, alternating comparison; prints one table row.
    fn paired(&mut self) {
        let options = quiet();
        // Both paths take the same steps: the end states agree.
        let (a, b) = (self.integrate(&options), self.step_loop());
        let diff = (a.q - b.q).amax().max((a.v - b.v).amax());
        assert!(diff < 1e-12, "{}: integrate and the step loop end {diff:.3e} apart", self.name);
        let mut time = |integrate: bool| {
            let t0 = thread_cpu_time();
            for _ in 0..CALLS {
                black_box(if integrate { self.integrate(&options) } else { self.step_loop() });
            }
            (thread_cpu_time() - t0) / CALLS as f64
        };
        for _ in 0..3 {
            time(true);
            time(false);
        }
        let (mut ti, mut ts, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
        for round in 0..ROUNDS {
            let (i, s) = if round % 2 == 0 {
                let i = time(true);
                (i, time(false))
            } else {
                let s = time(false);
                (time(true), s)
            };
            ti.push(i);
            ts.push(s);
            ratios.push(i / s);
        }
        let (mi, ms) = (quantile(&mut ti, 0.5), quantile(&mut ts, 0.5));
        let (q1, q2, q3) = (quantile(&mut ratios, 0.25), quantile(&mut ratios, 0.5), quantile(&mut ratios, 0.75));
        println!(
            "| {} | {:.1} µs | {:.1} µs | {:.3} | {:.3} [{:.3}, {:.3}] |",
            self.name,
            mi * 1e6,
            ms * 1e6,
            mi / ms,
            q2,
            q1,
            q3
        );
    }
}

/// The `p`-quantile of `x` (nearest rank).
fn quantile(x: &mut [f64], p: f64) -> f64 {
    x.sort_by(f64::total_cmp);
    x[((x.len() - 1) as f64 * p).round() as usize]
}

fn particle() -> Case<Particle, 3, 1, 11> {
    Case::new("particle", Particle, State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0)))
}
fn skate() -> Case<Skate, 3, 1, 11> {
    Case::new("skate", Skate::default(), State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0)))
}
fn robot() -> Case<MobileRobot, 4, 2, 16> {
    let start = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    Case::new("robot", MobileRobot::default(), start)
}
fn mp7() -> Case<MpParticles, 7, 1, 23> {
    // The paper's §8.4 state with β = 0.5 (the constraint holds: v₁ = v₅ = v₆ = v₇ = 0).
    let q = Vector::<7>::from_column_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
    let v = Vector::<7>::from_column_slice(&[0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0]);
    Case::new("mp7", MpParticles, State::new(0.0, q, v))
}

fn benches(c: &mut C) {
    particle().criterion(c);
    skate().criterion(c);
    robot().criterion(c);
    mp7().criterion(c);
}

criterion_group! {
    name = integrate_cost;
    config = Criterion::default().with_measurement(ThreadCpu(WallTime)).sample_size(30)
        .measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
    targets = benches
}

fn main() {
    integrate_cost();
    println!(
        "\nintegrate against the bare step loop, {STEPS} Gauss s=2 steps, alternating, {ROUNDS} rounds of {CALLS} runs \
         (thread CPU):\n"
    );
    println!(
        "| system | integrate (median) | step loop (median) | ratio of medians | paired ratio, median [quartiles] |"
    );
    println!("|---|---:|---:|---:|---:|");
    particle().paired();
    skate().paired();
    robot().paired();
    mp7().paired();
    Criterion::default().configure_from_args().final_summary();
}
