//! Time per step of `Stepper::integrate` on the paper's four systems, for
//! runs with no events, no dense output and no sampling, against a bare
//! loop of `Stepper::step` over the same steps: 200 fixed Gauss `s = 2`
//! steps at h = 0.05 (full Newton, default options), nothing observed and
//! only the endpoints recorded. The two alternate in rounds of `CALLS` runs
//! each (the first of a round swapped every round) for `seconds` per
//! system. It prints one line per system: `<system> <integrate ns/step>
//! <step loop ns/step> <median per-round ratio integrate / loop> <Newton
//! updates per step>`, medians over the rounds.
//!
//! The file uses only API that predates dense output and events, and
//! declares its systems itself, so it builds at any commit of the
//! workspace: `benches/two_binaries.sh` builds it at two
//! commits and runs the two binaries alternately (the step time with and
//! without a feature, side by side). Run alone:
//!
//! ```sh
//! cargo run --release -p spark-runtime --example driver_cost -- 0.5
//! ```

use std::io::Write;
use std::time::Instant;

use spark_runtime::{
    Method, NoObserver, NonholonomicSystem, Observe, RunOptions, Schedule, State, Stepper, Tableau, Vector,
};

#[path = "common/paper_systems.rs"]
mod paper_systems;
use paper_systems::{McLachlanPerlmutter7, MobileRobot, NonholonomicParticle, Skate};

/// Steps per run and their size.
const STEPS: usize = 200;
const H: f64 = 0.05;
/// Runs per timed sample.
const CALLS: usize = 5;

/// The median of `x`.
fn median(mut x: Vec<f64>) -> f64 {
    x.sort_by(f64::total_cmp);
    x[x.len() / 2]
}

/// Times `integrate` and the bare step loop from `(q0, v0)` alternately for
/// about `seconds`; returns ns per step of each, the median per-round ratio
/// and Newton updates per step of `integrate`.
fn time<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize, const D: usize>(
    sys: Sys,
    q0: Vector<N>,
    v0: Vector<N>,
    seconds: f64,
) -> Result<[f64; 4], String> {
    let tableau = Tableau::new(Method::Gauss).map_err(|e| e.to_string())?;
    let mut stepper = Stepper::<Sys, N, M, 2, D>::new(sys, tableau);
    let options = RunOptions {
        observe: Observe { energy: false, constraint_residual: false, multipliers: false },
        record_every: 0,
        ..RunOptions::default()
    };
    let schedule = Schedule::Fixed { h: H, steps: STEPS };
    let start = State::new(0.0, q0, v0);
    let mut updates = 0.0;
    let mut sample = |integrate: bool| -> Result<f64, String> {
        let clock = Instant::now();
        for _ in 0..CALLS {
            if integrate {
                let run =
                    stepper.integrate(0.0, &q0, &v0, schedule, &options, &mut NoObserver).map_err(|e| e.to_string())?;
                updates = run.report.newton_iterations_total as f64 / run.report.steps as f64;
            } else {
                stepper.reset_warm_start();
                let mut state = start;
                for _ in 0..STEPS {
                    state = stepper.step(&state, H).map_err(|e| e.to_string())?.state;
                }
            }
        }
        Ok(clock.elapsed().as_nanos() as f64 / (CALLS * STEPS) as f64)
    };
    let (mut driven, mut bare, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
    let clock = Instant::now();
    while clock.elapsed().as_secs_f64() < seconds || ratios.is_empty() {
        let first = ratios.len() % 2 == 0;
        let a = sample(first)?;
        let b = sample(!first)?;
        let (i, l) = if first { (a, b) } else { (b, a) };
        driven.push(i);
        bare.push(l);
        ratios.push(i / l);
    }
    Ok([median(driven), median(bare), median(ratios), updates])
}

fn main() -> Result<(), String> {
    let seconds: f64 = match std::env::args().nth(1) {
        Some(s) => s.parse().map_err(|e| format!("seconds per system: {e}"))?,
        None => 0.5,
    };
    let mp_q = Vector::<7>::from_column_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
    let mp_v = Vector::<7>::from_column_slice(&[0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let rows = [
        (
            "particle",
            time::<_, 3, 1, 11>(
                NonholonomicParticle::default(),
                Vector::<3>::new(1.0, 0.0, 0.0),
                Vector::<3>::new(0.0, 1.0, 0.0),
                seconds,
            )?,
        ),
        (
            "skate",
            time::<_, 3, 1, 11>(Skate::default(), Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0), seconds)?,
        ),
        (
            "robot",
            time::<_, 4, 2, 16>(
                MobileRobot::default(),
                Vector::<4>::zeros(),
                Vector::<4>::new(1.0, 0.0, 0.5, 1.0),
                seconds,
            )?,
        ),
        ("mp7", time::<_, 7, 1, 23>(McLachlanPerlmutter7::default(), mp_q, mp_v, seconds)?),
    ];
    // Written, not printed: a closed pipe is an error to report, not a panic.
    let mut out = std::io::stdout().lock();
    for (name, [driven, bare, ratio, updates]) in rows {
        writeln!(out, "{name} {driven:.1} {bare:.1} {ratio:.4} {updates:.3}").map_err(|e| e.to_string())?;
    }
    Ok(())
}
