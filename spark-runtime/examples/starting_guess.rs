//! How close the starting guesses of a continuing Gauss step come to the
//! solution: extrapolation of the previous solutions across steps (degree
//! 1, 2, 3) against the step polynomial through the previous step's
//! velocities `v₀, V₁…V_s, v₁` (the stepper's guess for `s ≥ 2`), on the
//! McLachlan–Perlmutter particles (n = 7) over `T = 10` from the paper's
//! state. Each step is solved to round-off (full Newton, tolerance 0); the
//! guesses are formed here from the converged steps alone, so every guess
//! is measured against the same solutions. Prints the geometric mean over
//! the steps of the largest scaled error `|ẑ_i − z_i|/(1 + |z_i|)` of the
//! velocities `V, v₁` and, separately, of the multipliers `μ = hΨ`. A second
//! table does the same for Lobatto IIIA-B, whose stage velocities are not
//! velocities at the nodes: extrapolation across steps of the velocities
//! themselves against that of their increments `V_i − v₀`, `v₁ − v₀` added
//! to the known start velocity (the stepper's guess for the families
//! without the step polynomial).
//! `cargo run --release -p spark-runtime --example starting_guess -- [steps...]`.

use spark_runtime::fixtures::paper::MpParticles;
use spark_runtime::{Method, NewtonMode, NewtonOptions, State, Stepper, Tableau, Vector};

/// One converged step: the start velocity, the stage velocities followed
/// by the end velocity, and the scaled multipliers.
struct Solved {
    start: Vec<f64>,
    velocities: Vec<f64>,
    multipliers: Vec<f64>,
}

fn velocities(x: &Solved) -> &[f64] {
    &x.velocities
}

fn multipliers(x: &Solved) -> &[f64] {
    &x.multipliers
}

/// The Lagrange basis polynomial `k` of `nodes` at `theta`.
fn basis(nodes: &[f64], k: usize, theta: f64) -> f64 {
    (0..nodes.len()).filter(|&m| m != k).fold(1.0, |l, m| l * (theta - nodes[m]) / (nodes[k] - nodes[m]))
}

/// The largest scaled error of `guess` against `exact`.
fn scaled_error(guess: &[f64], exact: &[f64]) -> f64 {
    guess.iter().zip(exact).map(|(g, x)| (g - x).abs() / (1.0 + x.abs())).fold(0.0, f64::max)
}

const N: usize = 7;

/// `steps` steps of `method` over `T = 10`, each solved to round-off.
fn solve<const S: usize, const D: usize>(method: Method, steps: usize) -> Result<Vec<Solved>, String> {
    let h = 10.0 / steps as f64;
    let tableau = Tableau::<S>::new(method).map_err(|e| e.to_string())?;
    let tight =
        NewtonOptions { mode: NewtonMode::Full, tolerance: 0.0, max_iterations: 32, ..NewtonOptions::default() };
    let mut stepper = Stepper::<MpParticles, N, 1, S, D>::new(MpParticles, tableau).with_options(tight);
    let q0 = Vector::<N>::from_column_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
    let mut state = State::new(0.0, q0, Vector::zeros());
    let mut solved: Vec<Solved> = Vec::with_capacity(steps);
    for _ in 0..steps {
        let r = stepper.step(&state, h).map_err(|e| e.to_string())?;
        let mut velocities: Vec<f64> = r.stage_velocities.iter().flat_map(|v| v.iter().copied()).collect();
        velocities.extend(r.state.v.iter());
        let multipliers = r.stage_multipliers.iter().map(|m| h * m[0]).collect();
        solved.push(Solved { start: state.v.iter().copied().collect(), velocities, multipliers });
        state = r.state;
    }
    Ok(solved)
}

/// Newton backward differences of degree 1, 2, 3, most recent step first.
const ACROSS: [&[f64]; 3] = [&[2.0, -1.0], &[3.0, -3.0, 1.0], &[4.0, -6.0, 4.0, -1.0]];

/// Gauss: extrapolation across steps against the step polynomial.
fn study<const S: usize, const D: usize>(steps: usize) -> Result<(), String> {
    let h = 10.0 / steps as f64;
    let c = Tableau::<S>::new(Method::Gauss).map_err(|e| e.to_string())?.c;
    let solved = solve::<S, D>(Method::Gauss, steps)?;
    // Velocity guesses: degree 1..3 across steps, then the step polynomial;
    // multiplier guesses: degree 2 across steps, then the polynomial through
    // the previous stage multipliers.
    let (mut log_v, mut log_mu) = ([0.0f64; 4], [0.0f64; 2]);
    let mut counted = 0;
    let step_nodes: Vec<f64> = std::iter::once(0.0).chain(c.iter().copied()).chain(std::iter::once(1.0)).collect();
    let targets: Vec<f64> = c.iter().map(|ci| 1.0 + ci).chain(std::iter::once(2.0)).collect();
    for k in 4..steps {
        let now = &solved[k];
        let across = |coefs: &[f64], pick: fn(&Solved) -> &[f64]| -> Vec<f64> {
            let len = pick(now).len();
            (0..len).map(|e| coefs.iter().enumerate().map(|(j, cf)| cf * pick(&solved[k - 1 - j])[e]).sum()).collect()
        };
        let extrapolated = ACROSS.map(|coefs| across(coefs, velocities));
        let prev = &solved[k - 1];
        let value = |node: usize, n: usize| if node == 0 { prev.start[n] } else { prev.velocities[(node - 1) * N + n] };
        let mut polynomial = Vec::with_capacity((S + 1) * N);
        for &theta in &targets {
            for n in 0..N {
                polynomial.push((0..S + 2).map(|j| basis(&step_nodes, j, theta) * value(j, n)).sum::<f64>());
            }
        }
        for (slot, guess) in extrapolated.iter().chain(std::iter::once(&polynomial)).enumerate() {
            log_v[slot] += scaled_error(guess, &now.velocities).ln();
        }
        let mu_across = across(ACROSS[1], multipliers);
        let mu_polynomial: Vec<f64> =
            (0..S).map(|i| (0..S).map(|j| basis(&c, j, 1.0 + c[i]) * prev.multipliers[j]).sum()).collect();
        log_mu[0] += scaled_error(&mu_across, &now.multipliers).ln();
        log_mu[1] += scaled_error(&mu_polynomial, &now.multipliers).ln();
        counted += 1;
    }
    let mean = |x: f64| (x / counted as f64).exp();
    println!(
        "| {S} | {steps} | {h:.4} | {:.1e} | {:.1e} | {:.1e} | {:.1e} | {:.1e} | {:.1e} |",
        mean(log_v[0]),
        mean(log_v[1]),
        mean(log_v[2]),
        mean(log_v[3]),
        mean(log_mu[0]),
        mean(log_mu[1])
    );
    Ok(())
}

/// Lobatto IIIA-B: extrapolation across steps of the velocities against
/// that of their increments from the start velocity.
fn increments<const S: usize, const D: usize>(steps: usize) -> Result<(), String> {
    let h = 10.0 / steps as f64;
    let solved = solve::<S, D>(Method::LobattoIIIAB, steps)?;
    let mut log = [0.0f64; 6];
    let mut counted = 0;
    for k in 5..steps {
        let now = &solved[k];
        for (slot, coefs) in ACROSS.iter().enumerate() {
            let value = |e: usize, increment: bool| {
                let base = if increment { now.start[e % N] } else { 0.0 };
                base + coefs
                    .iter()
                    .enumerate()
                    .map(|(j, cf)| {
                        let past = &solved[k - 1 - j];
                        cf * (past.velocities[e] - if increment { past.start[e % N] } else { 0.0 })
                    })
                    .sum::<f64>()
            };
            for (offset, increment) in [(0, false), (3, true)] {
                let guess: Vec<f64> = (0..now.velocities.len()).map(|e| value(e, increment)).collect();
                log[offset + slot] += scaled_error(&guess, &now.velocities).ln();
            }
        }
        counted += 1;
    }
    let mean: Vec<String> = log.iter().map(|x| format!("{:.1e}", (x / counted as f64).exp())).collect();
    println!("| {S} | {steps} | {h:.4} | {} |", mean.join(" | "));
    Ok(())
}

fn main() -> Result<(), String> {
    let steps: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let steps = if steps.is_empty() { vec![16, 32, 64, 200] } else { steps };
    println!(
        "| s | steps | h | V, v₁: degree 1 | degree 2 | degree 3 | step polynomial | μ: degree 2 | stage polynomial |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for &n in &steps {
        study::<2, 23>(n)?;
        study::<3, 31>(n)?;
        study::<4, 39>(n)?;
    }
    println!();
    println!("Lobatto IIIA-B, V and v₁:");
    println!();
    println!(
        "| s | steps | h | velocities: degree 1 | degree 2 | degree 3 | increments: degree 1 | degree 2 | degree 3 |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for &n in &steps {
        increments::<2, 23>(n)?;
        increments::<3, 31>(n)?;
        increments::<4, 39>(n)?;
    }
    Ok(())
}
