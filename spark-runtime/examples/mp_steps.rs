//! Runs McLachlan–Perlmutter's particles with the 2-stage Lobatto IIIA-B
//! SPARK method (paper §8.4 settings) for profiling:
//! `cargo run --release --example mp_steps -- [steps] [full|simplified]`.

use spark_runtime::fixtures::paper::MpParticles;
use spark_runtime::{Method, NewtonMode, NewtonOptions, State, Stepper, Tableau, Vector};

fn main() {
    let mut args = std::env::args().skip(1);
    let steps: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(100_000);
    let mode = match args.next().as_deref() {
        Some("simplified") => NewtonMode::Simplified,
        _ => NewtonMode::Full,
    };
    let tab = Tableau::new(Method::LobattoIIIAB).expect("s = 2 is supported");
    let opts = NewtonOptions { mode, ..NewtonOptions::default() };
    let mut st = Stepper::<_, 7, 1, 2, 23>::new(MpParticles, tab).with_options(opts);
    let q0 = Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
    let mut s = State::new(0.0, q0, Vector::<7>::zeros());
    let mut iterations = 0;
    let start = std::time::Instant::now();
    for _ in 0..steps {
        match st.step(&s, 0.05) {
            Ok(r) => {
                iterations += r.iterations;
                s = r.state;
            }
            Err(e) => {
                eprintln!("{e}");
                std::process::exit(1);
            }
        }
    }
    let dt = start.elapsed();
    println!(
        "{steps} steps ({mode:?}): {:.3} µs/step, {:.3} Newton iterations/step, E = {:.6}",
        dt.as_secs_f64() * 1e6 / steps as f64,
        iterations as f64 / steps as f64,
        0.5 * s.v.norm_squared()
    );
}
