//! Zero heap allocations per step: a counting global allocator (per thread,
//! so parallel tests do not disturb each other) watches the stepper and the
//! driver's stepping loop.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use spark_runtime::fixtures::paper::{General, MobileRobot, MpParticles, Skate};
use spark_runtime::{
    consistent_velocity, ConsistencyPolicy, Method, NewtonMode, NewtonOptions, NoObserver, NonholonomicSystem,
    RunOptions, Schedule, State, Stepper, Tableau, Vector,
};

struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> usize {
    ALLOCATIONS.with(|c| c.get())
}

/// Allocations made by `steps` steps after one warm-up step.
fn count_steps<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    mode: NewtonMode,
    start: State<N>,
    h: f64,
    steps: usize,
) -> usize
where
    Sys: NonholonomicSystem<N, M>,
{
    let opts = NewtonOptions { mode, ..NewtonOptions::default() };
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap()).with_options(opts);
    let mut s = st.step(&start, h).unwrap().state;
    let before = allocations();
    let mut iterations = 0;
    for k in 0..steps {
        // Reverse once in the middle, and restart cold once: every guess path.
        let hk = if k < steps / 2 { h } else { -h };
        if k == steps / 4 {
            st.reset_warm_start();
        }
        let r = st.step(&s, hk).unwrap();
        iterations += r.iterations;
        s = r.state;
    }
    let made = allocations() - before;
    assert!(iterations >= steps, "the steps did work");
    made
}

#[test]
fn steps_allocate_nothing() {
    let skate = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let robot = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    let mp = State::new(
        0.0,
        Vector::<7>::from_row_slice(&[0.8, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]),
        Vector::<7>::from_row_slice(&[0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0]),
    );
    let g = General::default();
    let gq = Vector::<2>::new(0.3, -0.2);
    let gv =
        consistent_velocity(&g, 0.0, &gq, &Vector::<2>::new(0.5, 0.0), ConsistencyPolicy::Project { tolerance: 0.0 })
            .unwrap();
    let general = State::new(0.0, gq, gv);
    let mut counts = Vec::new();
    for mode in [NewtonMode::Full, NewtonMode::Simplified] {
        counts.push((
            "skate IIIA-B s=4",
            count_steps::<_, 3, 1, 4, 19>(Skate::default(), Method::LobattoIIIAB, mode, skate, 0.1, 200),
        ));
        counts.push((
            "robot Gauss s=3",
            count_steps::<_, 4, 2, 3, 22>(MobileRobot::default(), Method::Gauss, mode, robot, 0.2, 200),
        ));
        counts.push((
            "robot IIIA-B-D s=5",
            count_steps::<_, 4, 2, 5, 34>(MobileRobot::default(), Method::LobattoIIIABD, mode, robot, 0.2, 200),
        ));
        counts.push((
            "MP modified",
            count_steps::<_, 7, 1, 2, 23>(MpParticles, Method::ModifiedLobattoIIIAB, mode, mp, 0.05, 200),
        ));
        counts
            .push(("MP LDA", count_steps::<_, 7, 1, 2, 23>(MpParticles, Method::LobattoIIIBALda, mode, mp, 0.05, 200)));
        counts.push(("general Gauss s=2", count_steps::<_, 2, 1, 2, 8>(g, Method::Gauss, mode, general, 0.05, 200)));
    }
    println!("{counts:?}");
    assert!(counts.iter().all(|(_, n)| *n == 0), "heap allocations during steps: {counts:?}");
}

#[test]
fn driver_loop_allocates_nothing_per_step() {
    let robot = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    let mut st = Stepper::<_, 4, 2, 3, 22>::new(MobileRobot::default(), Tableau::new(Method::Gauss).unwrap());
    // Record only the endpoints so the output vector does not grow.
    let opts = RunOptions { record_every: 0, ..RunOptions::default() };
    let mut run = |steps: usize| {
        let before = allocations();
        let tr =
            st.integrate(0.0, &robot.q, &robot.v, Schedule::Fixed { h: 0.1, steps }, &opts, &mut NoObserver).unwrap();
        let made = allocations() - before;
        assert_eq!(tr.report.steps, steps);
        drop(tr);
        made
    };
    let (short, long) = (run(10), run(2000));
    println!("driver allocations: 10 steps {short}, 2000 steps {long}");
    assert_eq!(short, long, "allocations must not grow with the number of steps");
}
