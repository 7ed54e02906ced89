//! Cost of `integrate` for systems without events and schedules without
//! dense sampling: the dense output and event location must add nothing
//! there (docs/performance/README.md, "Driver cost"). Run with
//! `cargo bench -p spark-benches --bench integrate_cost` (add `-- none` to
//! skip the criterion benches and print only the paired tables).
//!
//! Every run is 200 fixed Gauss `s = 2` steps at h = 0.05 (full Newton,
//! default step options), timed by the measuring thread's CPU time:
//!
//! - criterion benches `integrate/<system>/Gauss s=2/200 steps` (one
//!   `integrate` call, observation off, nothing recorded) and
//!   `step-loop/<system>/Gauss s=2/200 steps` (the same 200 steps as a bare
//!   loop of `Stepper::step`, the least a run can do). The `integrate` lines
//!   use only API that predates dense output and events, so the same bench
//!   also builds against a stepper without them;
//! - the paired comparison `integrate / step loop` on the paper's four
//!   systems: a ratio of 1 means the driver's dense-output, event, schedule,
//!   failure-policy and observation code costs nothing on this path;
//! - the paired comparison of two declarations of one system by
//!   `nonholonomic_system!`, the skate of §8.2 without and with an `events:`
//!   block, both stepped by `integrate` with no event requested (the second
//!   through `integrate_with_events` and `NoEvents`): a ratio of 1 means a
//!   system pays nothing for the events it declares but a run does not use.
//!   A third column runs the declared events (located in every step), for
//!   what using them costs.
//!
//! A paired comparison alternates its two sides (order swapped every round)
//! for `ROUNDS` rounds of `CALLS` runs each, so load on the machine hits both
//! alike; it prints the median of each side, the ratio of the medians and
//! the median and quartiles of the per-round ratios.

use criterion::measurement::WallTime;
use criterion::{black_box, criterion_group, Criterion};
// The catalogue's skate (`problems`), declared by `nonholonomic_system!`
// without events.
use problems::systems::Skate as DslSkate;
use spark_runtime::fixtures::paper::{MobileRobot, MpParticles, Particle, Skate};
use spark_runtime::{
    nonholonomic_system, Method, NoEvents, NoObserver, NonholonomicSystem, Observe, RunOptions, Schedule, State,
    Stepper, Tableau, Vector,
};

use std::time::Duration;

#[path = "../common/clock.rs"]
mod clock;
use clock::{thread_cpu_time, ThreadCpu, C};

/// Steps per run and their size.
const STEPS: usize = 200;
const H: f64 = 0.05;
/// Rounds of a paired comparison, and runs per timed sample.
const ROUNDS: usize = 101;
const CALLS: usize = 5;

nonholonomic_system! {
    /// The catalogue's skate again, with an `events:` block: the heading crossing the
    /// slope's direction and the skate turning back up the slope.
    pub struct DslSkateEvents {
        coordinates: [x, y, theta],
        parameters: { m = 1.0, inertia = 1.0, g = 1.0, beta = 1.5707963267948966 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + m*g*x*sin(beta),
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) ],
        events: {
            heading: sin(theta),
            turning: falling(dot(x)),
        },
    }
}

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

/// The schedule of every run.
const SCHEDULE: Schedule<'static> = Schedule::Fixed { h: H, steps: STEPS };

impl<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize, const D: usize> Case<Sys, N, M, D> {
    fn new(name: &'static str, sys: Sys, start: State<N>) -> Self {
        Case { name, stepper: Stepper::new(sys, Tableau::new(Method::Gauss).unwrap()), start }
    }

    /// One `integrate` call; returns the end state.
    fn integrate(&mut self, options: &RunOptions) -> State<N> {
        let s = self.start;
        let traj = self.stepper.integrate(s.t, &s.q, &s.v, SCHEDULE, options, &mut NoObserver).unwrap();
        let end = traj.samples.last().unwrap();
        State::new(end.t, end.q, end.v)
    }

    /// One `integrate_with_events` call locating no events; returns the end state.
    fn integrate_no_events(&mut self, options: &RunOptions) -> State<N> {
        let s = self.start;
        let traj =
            self.stepper.integrate_with_events(s.t, &s.q, &s.v, SCHEDULE, options, &mut NoObserver, &NoEvents).unwrap();
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

    /// `integrate` against the step loop; prints one table row.
    fn against_step_loop(&mut self) {
        let options = quiet();
        // Both paths take the same steps: the end states agree.
        let (a, b) = (self.integrate(&options), self.step_loop());
        let diff = (a.q - b.q).amax().max((a.v - b.v).amax());
        assert!(diff < 1e-12, "{}: integrate and the step loop end {diff:.3e} apart", self.name);
        let p = paired(self, |c| black_box(c.integrate(&options)), |c| black_box(c.step_loop()));
        println!("| {} | {} |", self.name, p.row());
    }
}

/// What a paired comparison measured (seconds per run).
struct Paired {
    a: f64,
    b: f64,
    ratios: [f64; 3],
}

impl Paired {
    /// `a (median) | b (median) | ratio of medians | paired ratio [quartiles]`.
    fn row(&self) -> String {
        let [q1, q2, q3] = self.ratios;
        format!(
            "{:.1} µs | {:.1} µs | {:.3} | {:.3} [{:.3}, {:.3}]",
            self.a * 1e6,
            self.b * 1e6,
            self.a / self.b,
            q2,
            q1,
            q3
        )
    }
}

/// Times `a` and `b` on `x` alternately (the first of each round swapped
/// every round), `CALLS` runs per sample, after three warm-up rounds.
fn paired<X, A: FnMut(&mut X) -> R, B: FnMut(&mut X) -> R, R>(x: &mut X, mut a: A, mut b: B) -> Paired {
    let mut time = |x: &mut X, first: bool| {
        let t0 = thread_cpu_time();
        for _ in 0..CALLS {
            if first {
                a(x);
            } else {
                b(x);
            }
        }
        (thread_cpu_time() - t0) / CALLS as f64
    };
    for _ in 0..3 {
        time(x, true);
        time(x, false);
    }
    let (mut ta, mut tb, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
    for round in 0..ROUNDS {
        let (i, s) = if round % 2 == 0 {
            let i = time(x, true);
            (i, time(x, false))
        } else {
            let s = time(x, false);
            (time(x, true), s)
        };
        ta.push(i);
        tb.push(s);
        ratios.push(i / s);
    }
    Paired {
        a: quantile(&mut ta, 0.5),
        b: quantile(&mut tb, 0.5),
        ratios: [quantile(&mut ratios, 0.25), quantile(&mut ratios, 0.5), quantile(&mut ratios, 0.75)],
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
fn skate_start() -> State<3> {
    State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0))
}
fn skate() -> Case<Skate, 3, 1, 11> {
    Case::new("skate", Skate::default(), skate_start())
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

/// The skate declared without and with events: `integrate` on the first,
/// `integrate_with_events(NoEvents)` on the second, then the second's own
/// events located by `integrate`; prints two table rows.
fn events_block() {
    let mut plain: Case<DslSkate, 3, 1, 11> = Case::new("skate (DSL)", DslSkate::default(), skate_start());
    let mut with: Case<DslSkateEvents, 3, 1, 11> =
        Case::new("skate (DSL) + events", DslSkateEvents::default(), skate_start());
    let options = quiet();
    let located = {
        let s = with.start;
        with.stepper.integrate(s.t, &s.q, &s.v, SCHEDULE, &options, &mut NoObserver).unwrap().events.len()
    };
    // The same steps on both declarations, bit for bit.
    assert_eq!(plain.integrate(&options), with.integrate_no_events(&options));
    let mut both = (plain, with);
    let unused = paired(
        &mut both,
        |(_, w)| black_box(w.integrate_no_events(&options)),
        |(p, _)| black_box(p.integrate(&options)),
    );
    let used = paired(&mut both, |(_, w)| black_box(w.integrate(&options)), |(p, _)| black_box(p.integrate(&options)));
    println!("| events declared, none requested (`integrate_with_events`, `NoEvents`) | {} |", unused.row());
    println!("| events declared and located by `integrate` ({located} located per run) | {} |", used.row());
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
    particle().against_step_loop();
    skate().against_step_loop();
    robot().against_step_loop();
    mp7().against_step_loop();
    println!(
        "\nthe skate declared with an `events:` block against the same skate declared without, both by `integrate`, \
         {STEPS} Gauss s=2 steps, alternating, {ROUNDS} rounds of {CALLS} runs (thread CPU):\n"
    );
    println!(
        "| run of the skate with events | with events (median) | without events block (median) | ratio of medians \
         | paired ratio, median [quartiles] |"
    );
    println!("|---|---:|---:|---:|---:|");
    events_block();
    Criterion::default().configure_from_args().final_summary();
}
