//! A step loop to profile: the paper's particle, skate, mobile robot or
//! McLachlan–Perlmutter particles (`mp7`, n = 7, from the j = 5 state of
//! Fig. 8.4), declared with
//! `nonholonomic_system!`, stepped over `t ∈ [0, 10]` from the paper's
//! initial values, `repeats` times, with one Newton mode, and the mean time
//! and Newton updates per step printed. Built for `perf record` and
//! `valgrind --tool=callgrind` (instruction counts are the machine-noise-free
//! way to compare two builds of the step):
//!
//! ```sh
//! cargo build --profile profiling -p spark-runtime --example step_profile
//! valgrind --tool=callgrind target/profiling/examples/step_profile skate decoupled 2 200
//! ```
//!
//! Arguments: `particle|skate|robot|mp7`, `full|simplified|decoupled` (full
//! Newton, simplified Newton on the exact Jacobian, on the stage-decoupled
//! matrix), stages (`1..=5` for the particle and mp7, `1..=4` for the skate
//! and the robot: Gauss, or
//! Lobatto IIIA-B with an `L` before the count, as in `L3`),
//! repeats, `loop|integrate`, the step `h` (default: the paper's) and the
//! starting guess's extrapolation degree (default: `NewtonOptions`'s). `loop`
//! is a bare loop of `Stepper::step` (the default, which also prints the
//! factorizations per step), `integrate` one `Stepper::integrate` call per repeat
//! with the same steps, nothing observed and only the endpoints recorded
//! (the driver's own cost is the difference of the two). With `SPARK_PRINT_END=1` it also prints
//! the end state of the last repeat in full precision (to check that two
//! builds step bit for bit alike).

use std::io::Write;

use spark_runtime::{
    Jacobian, Method, NewtonMode, NewtonOptions, NoObserver, NonholonomicSystem, Observe, RunOptions, Schedule, State,
    Stepper, Tableau,
};

#[path = "common/paper_systems.rs"]
mod paper_systems;
use paper_systems::{
    mp7_start, particle_start, robot_start, skate_start, McLachlanPerlmutter7, MobileRobot, NonholonomicParticle, Skate,
};

fn run<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    start: State<N>,
    h: f64,
    method: Method,
    options: NewtonOptions,
    repeats: usize,
    driver: Driver,
) -> Result<(), String> {
    let tableau = Tableau::new(method).map_err(|e| e.to_string())?;
    let mut stepper = Stepper::<Sys, N, M, S, D>::new(sys, tableau).with_options(options);
    let (mut updates, mut factorizations, mut steps, mut end) = (0usize, 0usize, 0usize, start);
    let run_options = RunOptions {
        observe: Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        ..RunOptions::default()
    };
    let per_run = (10.0 / h).round() as usize;
    let clock = std::time::Instant::now();
    for _ in 0..repeats {
        match driver {
            Driver::Loop => {
                let mut state = start;
                stepper.reset_warm_start();
                for _ in 0..per_run {
                    let r = stepper.step(&state, h).map_err(|e| e.to_string())?;
                    (state, updates, steps) = (r.state, updates + r.iterations, steps + 1);
                    factorizations += r.factorizations;
                }
                end = state;
            }
            Driver::Integrate => {
                let schedule = Schedule::Fixed { h, steps: per_run };
                let run = stepper
                    .integrate(start.t, &start.q, &start.v, schedule, &run_options, &mut NoObserver)
                    .map_err(|e| e.to_string())?;
                let last = run.samples.last().ok_or("a run without samples")?;
                end = State::new(last.t, last.q, last.v);
                (updates, steps) = (updates + run.report.newton_iterations_total, steps + run.report.steps);
            }
        }
    }
    let elapsed = clock.elapsed().as_nanos() as f64;
    // Written, not printed: a closed pipe (`| head -1`) is an error to
    // report, not a panic.
    let mut out = std::io::stdout().lock();
    if std::env::var_os("SPARK_PRINT_END").is_some() {
        writeln!(out, "end q = {:?}, v = {:?}", end.q.as_slice(), end.v.as_slice()).map_err(|e| e.to_string())?;
    }
    let per_step = (elapsed / steps as f64, updates as f64 / steps as f64);
    write!(out, "{:.1} ns/step, {:.2} Newton updates/step", per_step.0, per_step.1).map_err(|e| e.to_string())?;
    if let Driver::Loop = driver {
        // `integrate` reports no factorizations.
        write!(out, ", {:.2} factorizations/step", factorizations as f64 / steps as f64).map_err(|e| e.to_string())?;
    }
    writeln!(out).map_err(|e| e.to_string())
}

/// What advances the steps.
#[derive(Clone, Copy)]
enum Driver {
    /// A bare loop of `Stepper::step`.
    Loop,
    /// One `Stepper::integrate` call per repeat.
    Integrate,
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().collect();
    let arg = |i: usize, default: &str| args.get(i).cloned().unwrap_or_else(|| default.to_string());
    let (mode, jacobian) = match arg(2, "decoupled").as_str() {
        "full" => (NewtonMode::Full, Jacobian::Exact),
        "simplified" => (NewtonMode::Simplified, Jacobian::Exact),
        "decoupled" => (NewtonMode::Simplified, Jacobian::StageDecoupled),
        other => return Err(format!("unknown Newton mode {other:?}: full, simplified or decoupled")),
    };
    let defaults = NewtonOptions::default();
    // The extrapolation degree of the starting guess, when a seventh
    // argument gives one (after the step).
    let extrapolation_degree = match args.get(7) {
        Some(d) => d.parse().map_err(|e| format!("extrapolation degree: {e}"))?,
        None => defaults.extrapolation_degree,
    };
    let options = NewtonOptions { mode, jacobian, extrapolation_degree, ..defaults };
    let stages_arg = arg(3, "2");
    let (method, count) = match stages_arg.strip_prefix('L') {
        Some(count) => (Method::LobattoIIIAB, count),
        None => (Method::Gauss, stages_arg.as_str()),
    };
    let stages: usize = count.parse().map_err(|e| format!("stages: {e}"))?;
    let repeats: usize = arg(4, "2000").parse().map_err(|e| format!("repeats: {e}"))?;
    let driver = match arg(5, "loop").as_str() {
        "loop" => Driver::Loop,
        "integrate" => Driver::Integrate,
        other => return Err(format!("unknown driver {other:?}: loop or integrate")),
    };
    let skate = skate_start();
    let particle = particle_start();
    let mp7 = mp7_start();
    let robot = robot_start();
    // The paper's step unless a sixth argument gives another.
    let step = |paper: f64| -> Result<f64, String> {
        args.get(6).map_or(Ok(paper), |h| h.parse().map_err(|e| format!("step: {e}")))
    };
    match (arg(1, "skate").as_str(), stages) {
        ("skate", 1) => run::<_, 3, 1, 1, 7>(Skate::default(), skate, step(0.1)?, method, options, repeats, driver),
        ("skate", 2) => run::<_, 3, 1, 2, 11>(Skate::default(), skate, step(0.1)?, method, options, repeats, driver),
        ("skate", 3) => run::<_, 3, 1, 3, 15>(Skate::default(), skate, step(0.1)?, method, options, repeats, driver),
        ("skate", 4) => run::<_, 3, 1, 4, 19>(Skate::default(), skate, step(0.1)?, method, options, repeats, driver),
        ("particle", 1) => run::<_, 3, 1, 1, 7>(
            NonholonomicParticle::default(),
            particle,
            step(0.2)?,
            method,
            options,
            repeats,
            driver,
        ),
        ("particle", 2) => run::<_, 3, 1, 2, 11>(
            NonholonomicParticle::default(),
            particle,
            step(0.2)?,
            method,
            options,
            repeats,
            driver,
        ),
        ("particle", 3) => run::<_, 3, 1, 3, 15>(
            NonholonomicParticle::default(),
            particle,
            step(0.2)?,
            method,
            options,
            repeats,
            driver,
        ),
        ("particle", 4) => run::<_, 3, 1, 4, 19>(
            NonholonomicParticle::default(),
            particle,
            step(0.2)?,
            method,
            options,
            repeats,
            driver,
        ),
        ("particle", 5) => run::<_, 3, 1, 5, 23>(
            NonholonomicParticle::default(),
            particle,
            step(0.2)?,
            method,
            options,
            repeats,
            driver,
        ),
        ("robot", 1) => {
            run::<_, 4, 2, 1, 10>(MobileRobot::default(), robot, step(0.2)?, method, options, repeats, driver)
        }
        ("robot", 2) => {
            run::<_, 4, 2, 2, 16>(MobileRobot::default(), robot, step(0.2)?, method, options, repeats, driver)
        }
        ("robot", 3) => {
            run::<_, 4, 2, 3, 22>(MobileRobot::default(), robot, step(0.2)?, method, options, repeats, driver)
        }
        ("robot", 4) => {
            run::<_, 4, 2, 4, 28>(MobileRobot::default(), robot, step(0.2)?, method, options, repeats, driver)
        }
        ("mp7", 1) => {
            run::<_, 7, 1, 1, 15>(McLachlanPerlmutter7::default(), mp7, step(0.05)?, method, options, repeats, driver)
        }
        ("mp7", 2) => {
            run::<_, 7, 1, 2, 23>(McLachlanPerlmutter7::default(), mp7, step(0.05)?, method, options, repeats, driver)
        }
        ("mp7", 3) => {
            run::<_, 7, 1, 3, 31>(McLachlanPerlmutter7::default(), mp7, step(0.05)?, method, options, repeats, driver)
        }
        ("mp7", 4) => {
            run::<_, 7, 1, 4, 39>(McLachlanPerlmutter7::default(), mp7, step(0.05)?, method, options, repeats, driver)
        }
        ("mp7", 5) => {
            run::<_, 7, 1, 5, 47>(McLachlanPerlmutter7::default(), mp7, step(0.05)?, method, options, repeats, driver)
        }
        (system, s) => {
            Err(format!("no case {system} with s = {s}: particle or mp7 with s = 1..=5, skate or robot with s = 1..=4"))
        }
    }
}
