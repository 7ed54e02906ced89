//! A lane-group loop to profile: the eight McLachlan–Perlmutter members of
//! `benches/runtime/lanes.rs` (n = 7, Lobatto IIIA-B s = 2, h = 0.05,
//! simplified Newton on the stage-decoupled matrix, 500 steps each),
//! stepped `repeats` times either in one `LaneStepper` of eight lanes
//! (`lanes`) or by eight steppers one member after another (`sequential`);
//! prints the wall time per repeat in milliseconds and the sum of the
//! members' end `q₁` over the repeats (the same bits in both modes).
//!
//! Built for alternated timing runs of two builds (release) and for
//! `valgrind --tool=callgrind` (the profiling build; instruction counts
//! compare two builds of the kernel exactly, and valgrind runs the
//! kernel's AVX2 build):
//!
//! ```sh
//! cargo build --release -p spark-runtime --example lanes_profile
//! target/release/examples/lanes_profile lanes 10
//! target/release/examples/lanes_profile sequential 4
//! cargo build --profile profiling -p spark-runtime --example lanes_profile
//! valgrind --tool=callgrind target/profiling/examples/lanes_profile lanes 20
//! ```

use spark_runtime::{Jacobian, LaneStepper, Method, NewtonMode, NewtonOptions, State, Stepper, Tableau, Vector};

#[path = "common/paper_systems.rs"]
mod paper_systems;
use paper_systems::McLachlanPerlmutter7;

const H: f64 = 0.05;
const STEPS: usize = 500;

fn main() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let mode = args.next().unwrap_or_else(|| "lanes".into());
    let repeats: usize = match args.next() {
        Some(r) => r.parse().map_err(|e| format!("repeats `{r}`: {e}"))?,
        None => 10,
    };
    let options = NewtonOptions { mode: NewtonMode::Simplified, jacobian: Jacobian::Auto, ..NewtonOptions::default() };
    let tableau = || Tableau::<2>::new(Method::LobattoIIIAB).map_err(|e| e.to_string());
    let q0 = Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
    let starts: Vec<State<7>> = (0..8)
        .map(|j| {
            let mut v0 = Vector::<7>::zeros();
            v0[1] = 0.05 * j as f64;
            State::new(0.0, q0, v0)
        })
        .collect();
    let clock = std::time::Instant::now();
    let mut check = 0.0;
    match mode.as_str() {
        "lanes" => {
            let mut lanes = LaneStepper::<_, 7, 1, 2, 23, 8>::new(McLachlanPerlmutter7::default(), tableau()?, options);
            for _ in 0..repeats {
                lanes.start(&starts, H).map_err(|e| e.to_string())?;
                lanes.advance_by(STEPS);
                for member in 0..starts.len() {
                    check += lanes.state(member).ok_or("a member failed")?.q[0];
                }
            }
        }
        "sequential" => {
            let mut steppers = Vec::new();
            for _ in 0..starts.len() {
                steppers.push(
                    Stepper::<_, 7, 1, 2, 23>::new(McLachlanPerlmutter7::default(), tableau()?).with_options(options),
                );
            }
            for _ in 0..repeats {
                for (stepper, start) in steppers.iter_mut().zip(&starts) {
                    stepper.reset_warm_start();
                    let mut state = *start;
                    for _ in 0..STEPS {
                        state = stepper.step(&state, H).map_err(|e| e.to_string())?.state;
                    }
                    check += state.q[0];
                }
            }
        }
        other => return Err(format!("mode `{other}`: expected `lanes` or `sequential`")),
    }
    println!("{:.3} ms per repeat (check {check})", clock.elapsed().as_secs_f64() * 1e3 / repeats.max(1) as f64);
    Ok(())
}
