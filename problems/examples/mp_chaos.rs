//! Why Fig. 8.4 (McLachlan–Perlmutter particles, paper §8.4) showed a
//! bounded energy error for the Lobatto methods: the experiments behind
//! `docs/stress/chaos.md`.
//!
//! ```text
//! cargo run --release -p problems --example mp_chaos -- <experiment> [t_end] [printed|nonholonomic]
//! ```
//!
//! The last argument restricts `readings`, `steps` and `gauss` to one
//! reading of the constraint (default: both).
//!
//! Experiments (each prints a table; `all` runs every one):
//! - `holonomy`: the printed constraint `v1 + Σ_{i≥m+2} q_i v_i = 0` is the time
//!   derivative of `φ(q) = q1 + ½(q5² + q6² + q7²)`; prints how far each method
//!   moves `φ` and compares Lobatto IIIA-B SPARK with an independent RATTLE
//!   step for the holonomic constraint `φ(q) = φ(q0)`.
//! - `readings`: the Fig. 8.4 statistic and its fitted exponent for the printed
//!   constraint and for the nonholonomic reading `v1 + Σ_{i≥m+2} q_{i−m} v_i = 0`.
//! - `steps`: the statistic for h = 0.1, 0.05, 0.025 (both readings).
//! - `lyapunov`: finite-time largest Lyapunov exponents of the ensemble.
//! - `reverse`: forward n steps, then n steps with −h, distance to the start.
//! - `gauss`: Gauss s = 2 with two Newton tolerances, simplified Newton and
//!   three step sizes (truncation or solver/round-off?).
//! - `structure FILE…`: the structure function `S(Δ)` of the energy error
//!   from `spark paper`'s `fig8_4*_energy_errors.csv` (linear growth in `Δ`
//!   is a random walk, a plateau a bounded error).
//!
//! This is an investigation tool, not part of the test suite; it runs the
//! steppers directly (full Newton, tolerance 16ε unless stated).

use nalgebra::SVector;
use problems::report::stats::fit_power;
use problems::report::stats::{energy_structure_function, structure_slope};
use problems::systems::{mp7_initial_values, mp7_phi, mp7_rattle};
use problems::systems::{McLachlanPerlmutter7, McLachlanPerlmutter7Nonholonomic as Mp7Nonholonomic};
use rayon::prelude::*;
use spark_runtime::{Method, NewtonMode, NewtonOptions, NonholonomicSystem, State, Stepper, Tableau};

type V7 = SVector<f64, 7>;

/// The four methods of the investigation.
const METHODS: [(Method, &str); 4] = [
    (Method::LobattoIIIAB, "Lobatto IIIA-B"),
    (Method::ModifiedLobattoIIIAB, "modified IIIA-B"),
    (Method::LobattoIIIBALda, "MP IIIB-A LDA"),
    (Method::Gauss, "Gauss s=2"),
];

/// Which constraint the system uses.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Reading {
    /// As printed: `v1 + q5 v5 + q6 v6 + q7 v7 = 0` (holonomic).
    Printed,
    /// `v1 + q2 v5 + q3 v6 + q4 v7 = 0` (nonholonomic).
    Nonholonomic,
}

impl Reading {
    fn name(self) -> &'static str {
        match self {
            Reading::Printed => "printed (holonomic)",
            Reading::Nonholonomic => "q_{i-m} v_i (nonholonomic)",
        }
    }
}

fn phi(q: &V7) -> f64 {
    mp7_phi(q.as_slice())
}

/// One ensemble member: energy error `E_k − E_0` every `every` steps and the
/// largest `|φ(q_k) − φ(q_0)|`.
struct Member {
    de: Vec<f64>,
    max_phi: f64,
}

fn integrate<Sys: NonholonomicSystem<7, 1> + Default>(
    method: Method,
    h: f64,
    steps: usize,
    every: usize,
    q0: V7,
    v0: V7,
    newton: NewtonOptions,
) -> Result<Member, String> {
    let sys = Sys::default();
    let tab = Tableau::<2>::new(method).map_err(|e| e.to_string())?;
    let mut st = Stepper::<Sys, 7, 1, 2, 23>::new(Sys::default(), tab).with_options(newton);
    let e0 = sys.energy(0.0, &q0, &v0);
    let p0 = phi(&q0);
    let mut s = State::new(0.0, q0, v0);
    let mut de = vec![0.0];
    let mut max_phi: f64 = 0.0;
    for k in 1..=steps {
        s = st.step(&s, h).map_err(|e| e.to_string())?.state;
        max_phi = max_phi.max((phi(&s.q) - p0).abs());
        if k % every == 0 {
            de.push(sys.energy(s.t, &s.q, &s.v) - e0);
        }
    }
    Ok(Member { de, max_phi })
}

fn initial(j: usize) -> (V7, V7) {
    let (q, v) = mp7_initial_values(j, 9);
    (V7::from_column_slice(&q), V7::from_column_slice(&v))
}

/// The Fig. 8.4 statistic `(1/h⁴)·mean_j (E_jk − E_j0)²` of a 10-member ensemble.
fn ensemble(reading: Reading, method: Method, h: f64, t_end: f64, newton: NewtonOptions) -> (Vec<f64>, Vec<f64>, f64) {
    let steps = (t_end / h).round() as usize;
    let every = ((5.0 / h).round() as usize).max(1); // sample every 5 time units
    let members: Vec<Member> = (0..10)
        .into_par_iter()
        .map(|j| {
            let (q, v) = initial(j);
            match reading {
                Reading::Printed => integrate::<McLachlanPerlmutter7>(method, h, steps, every, q, v, newton),
                Reading::Nonholonomic => integrate::<Mp7Nonholonomic>(method, h, steps, every, q, v, newton),
            }
            .expect("integration failed")
        })
        .collect();
    let n = members[0].de.len();
    let t: Vec<f64> = (0..n).map(|k| (k * every) as f64 * h).collect();
    let stat: Vec<f64> =
        (0..n).map(|k| members.iter().map(|m| m.de[k].powi(2)).sum::<f64>() / 10.0 / h.powi(4)).collect();
    let max_phi = members.iter().map(|m| m.max_phi).fold(0.0, f64::max);
    (t, stat, max_phi)
}

/// Mean of the statistic over the first and the last tenth of the run.
fn early_late(t: &[f64], stat: &[f64]) -> (f64, f64) {
    let t_end = *t.last().unwrap();
    let mean = |lo: f64, hi: f64| {
        let v: Vec<f64> = t.iter().zip(stat).filter(|(t, _)| **t >= lo && **t <= hi).map(|(_, s)| *s).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    (mean(0.05 * t_end, 0.15 * t_end), mean(0.9 * t_end, t_end))
}

fn statistic_row(reading: Reading, method: Method, label: &str, h: f64, t_end: f64, newton: NewtonOptions) {
    let (t, stat, max_phi) = ensemble(reading, method, h, t_end, newton);
    let fit = fit_power(&t, &stat, 50.0, 100);
    let (early, late) = early_late(&t, &stat);
    let (p, se) = fit.map(|f| (f.exponent, f.exponent_std_error)).unwrap_or((f64::NAN, f64::NAN));
    println!(
        "| {} | {label} | {h} | {t_end} | {p:.3} ± {se:.3} | {early:.3e} | {late:.3e} | {:.2} | {max_phi:.1e} |",
        reading.name(),
        late / early
    );
}

fn statistic_header() {
    println!("| constraint | method | h | t_end | exponent p (t ≥ 50) | stat, t ∈ [0.05,0.15]·T | stat, t ∈ [0.9,1]·T | late/early | max |φ−φ0| |");
    println!("|---|---|---|---|---|---|---|---|---|");
}

fn readings(t_end: f64, which: &[Reading]) {
    println!("\n## Fig. 8.4 statistic, both readings of the constraint (h = 0.05)\n");
    statistic_header();
    for &reading in which {
        for (m, label) in METHODS {
            statistic_row(reading, m, label, 0.05, t_end, NewtonOptions::default());
        }
    }
}

fn steps(t_end: f64, which: &[Reading]) {
    println!("\n## Step size (statistic is scaled by 1/h⁴)\n");
    statistic_header();
    for &reading in which {
        for (m, label) in [METHODS[0], METHODS[3]] {
            for h in [0.1, 0.05, 0.025] {
                statistic_row(reading, m, label, h, t_end, NewtonOptions::default());
            }
        }
    }
}

fn gauss(t_end: f64, which: &[Reading]) {
    println!("\n## Gauss s = 2: Newton settings and step size (truncation or solver/round-off?)\n");
    println!("Truncation error of order 4 makes the h⁻⁴-scaled statistic shrink like h⁴ as h decreases;");
    println!("errors made once per step (round-off, Newton stopping) make it grow like h⁻⁵.\n");
    statistic_header();
    let full = NewtonOptions::default();
    let simplified = NewtonOptions { mode: NewtonMode::Simplified, ..full };
    let loose = NewtonOptions { tolerance: 1e-10, stagnation_level: 1e-10, ..full };
    for &reading in which {
        for (label, newton, h) in [
            ("Gauss, full Newton 16ε", full, 0.1),
            ("Gauss, full Newton 16ε", full, 0.05),
            ("Gauss, full Newton 16ε", full, 0.025),
            ("Gauss, simplified Newton 16ε", simplified, 0.05),
            ("Gauss, full Newton 1e-10", loose, 0.05),
        ] {
            statistic_row(reading, Method::Gauss, label, h, t_end, newton);
        }
    }
}

fn rattle(q0: &V7, v0: &V7, h: f64) -> (V7, V7) {
    mp7_rattle(q0, v0, h)
}

fn holonomy(t_end: f64) {
    let h = 0.05;
    println!("\n## φ(q) = q1 + ½(q5² + q6² + q7²) along each method (printed constraint, h = {h}, t ≤ {t_end})\n");
    println!("| method | max over members of max_k |φ(q_k) − φ(q_0)| |");
    println!("|---|---|");
    for (m, label) in METHODS {
        let (_, _, max_phi) = ensemble(Reading::Printed, m, h, t_end, NewtonOptions::default());
        println!("| {label} | {max_phi:.2e} |");
    }
    println!("\n## Lobatto IIIA-B SPARK vs an independent RATTLE step (member j = 3, h = {h})\n");
    let (q0, v0) = initial(3);
    let tab = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
    let mut st = Stepper::<McLachlanPerlmutter7, 7, 1, 2, 23>::new(McLachlanPerlmutter7::default(), tab);
    let mut one_step_max: f64 = 0.0;
    // Per step from the same state: the maps agree to round-off.
    let mut s = State::new(0.0, q0, v0);
    for _ in 0..2000 {
        let spark = st.step(&s, h).unwrap().state;
        let (q1, v1) = rattle(&s.q, &s.v, h);
        one_step_max = one_step_max.max((spark.q - q1).amax().max((spark.v - v1).amax()));
        s = spark;
    }
    println!("max over 2000 steps of |SPARK step − RATTLE step| from the same state: {one_step_max:.2e}");
    // Whole trajectories: the difference grows only through the dynamics.
    let mut a = State::new(0.0, q0, v0);
    let (mut bq, mut bv) = (q0, v0);
    let mut st = Stepper::<McLachlanPerlmutter7, 7, 1, 2, 23>::new(McLachlanPerlmutter7::default(), tab);
    for k in 1..=4000usize {
        a = st.step(&a, h).unwrap().state;
        (bq, bv) = rattle(&bq, &bv, h);
        if k.is_power_of_two() || k == 4000 {
            println!(
                "  t = {:7.2}: |Δq|∞ = {:.2e}, |Δv|∞ = {:.2e}",
                k as f64 * h,
                (a.q - bq).amax(),
                (a.v - bv).amax()
            );
        }
    }
}

/// Largest Lyapunov exponent estimate (Benettin, two trajectories, Gauss s = 2, h = 0.01).
fn lyapunov_member<Sys: NonholonomicSystem<7, 1> + Default>(j: usize, t_end: f64) -> f64 {
    let h: f64 = 0.01;
    let (q0, v0) = initial(j);
    let tab = Tableau::<2>::new(Method::Gauss).unwrap();
    let mut a_st = Stepper::<Sys, 7, 1, 2, 23>::new(Sys::default(), tab);
    let mut b_st = Stepper::<Sys, 7, 1, 2, 23>::new(Sys::default(), tab);
    let d0 = 1e-8;
    let mut a = State::new(0.0, q0, v0);
    // Perturb q3 (no constraint row depends on q3 for the printed reading,
    // and the coefficient of v6 is 0 at the start for the other), so the
    // perturbed velocity stays consistent.
    let mut qb = q0;
    qb[2] += d0;
    let mut b = State::new(0.0, qb, v0);
    let renorm = (1.0_f64 / h).round() as usize;
    let steps = (t_end / h).round() as usize;
    let mut sum = 0.0;
    for k in 1..=steps {
        a = a_st.step(&a, h).unwrap().state;
        b = b_st.step(&b, h).unwrap().state;
        if k % renorm == 0 {
            let dq = b.q - a.q;
            let dv = b.v - a.v;
            let d = (dq.norm_squared() + dv.norm_squared()).sqrt();
            sum += (d / d0).ln();
            // Rescale the separation back to d0 (the small constraint
            // violation this introduces is O(d0²)).
            let f = d0 / d;
            b = State::new(b.t, a.q + f * dq, a.v + f * dv);
            b_st = Stepper::<Sys, 7, 1, 2, 23>::new(Sys::default(), tab);
        }
    }
    sum / (steps as f64 * h)
}

fn lyapunov(t_end: f64) {
    println!("\n## Finite-time largest Lyapunov exponent (Gauss s = 2, h = 0.01, t ≤ {t_end}, δ0 = 1e-8)\n");
    println!("| constraint | λ per member j = 0..9 | mean |");
    println!("|---|---|---|");
    for reading in [Reading::Printed, Reading::Nonholonomic] {
        let lam: Vec<f64> = (0..10)
            .into_par_iter()
            .map(|j| match reading {
                Reading::Printed => lyapunov_member::<McLachlanPerlmutter7>(j, t_end),
                Reading::Nonholonomic => lyapunov_member::<Mp7Nonholonomic>(j, t_end),
            })
            .collect();
        let list: Vec<String> = lam.iter().map(|l| format!("{l:.3}")).collect();
        println!("| {} | {} | {:.3} |", reading.name(), list.join(", "), lam.iter().sum::<f64>() / 10.0);
    }
}

fn reverse_one<Sys: NonholonomicSystem<7, 1> + Default>(method: Method, n: usize) -> f64 {
    let h = 0.05;
    let (q0, v0) = initial(3);
    let tab = Tableau::<2>::new(method).unwrap();
    let mut st = Stepper::<Sys, 7, 1, 2, 23>::new(Sys::default(), tab);
    let mut s = State::new(0.0, q0, v0);
    for _ in 0..n {
        s = st.step(&s, h).unwrap().state;
    }
    for _ in 0..n {
        s = st.step(&s, -h).unwrap().state;
    }
    (s.q - q0).amax().max((s.v - v0).amax())
}

fn reverse() {
    println!("\n## Reversibility: n steps of h = 0.05, then n steps of −h (member j = 3)\n");
    println!("| constraint | method | n = 1 | n = 10 | n = 100 |");
    println!("|---|---|---|---|---|");
    for reading in [Reading::Printed, Reading::Nonholonomic] {
        for (m, label) in METHODS {
            let r: Vec<String> = [1, 10, 100]
                .iter()
                .map(|&n| match reading {
                    Reading::Printed => reverse_one::<McLachlanPerlmutter7>(m, n),
                    Reading::Nonholonomic => reverse_one::<Mp7Nonholonomic>(m, n),
                })
                .map(|x| format!("{x:.1e}"))
                .collect();
            println!("| {} | {label} | {} |", reading.name(), r.join(" | "));
        }
    }
}

/// Structure function of the energy error from a `spark paper` members file
/// (`fig8_4_energy_errors.csv` or `fig8_4_printed_energy_errors.csv`):
/// `S(Δ) = (1/h⁴)·mean_{j,t} (E_j(t+Δ) − E_j(t))²`. Averaging over every
/// start time uses the whole run, so it is far less noisy than the ensemble
/// statistic at one time. A random walk gives `S(Δ) ≈ 2σ² + DΔ` (growing
/// linearly), a bounded error `S(Δ) → 2σ²` (flat).
fn structure(path: &str) {
    let (header, cols) = match problems::report::files::read_columns(std::path::Path::new(path)) {
        Ok(x) => x,
        Err(e) => {
            eprintln!("{e}");
            return;
        }
    };
    let t = &cols[0];
    let dt = t[1] - t[0];
    let mut methods: Vec<String> =
        header[1..].iter().filter_map(|c| c.split("_member").next().map(String::from)).collect();
    methods.dedup();
    println!("\n## Structure function S(Δ) = (1/h⁴)·mean_(j,t) (E_j(t+Δ) − E_j(t))², {path}\n");
    let mut printed_header = false;
    for m in &methods {
        let members: Vec<&[f64]> = header
            .iter()
            .zip(&cols)
            .filter(|(c, _)| c.starts_with(&format!("{m}_member")))
            .map(|(_, v)| v.as_slice())
            .collect();
        let sf = energy_structure_function(&members, dt, 0.05);
        if !printed_header {
            let head: Vec<String> = sf.iter().map(|(d, _)| format!("Δ = {d}")).collect();
            println!("| method | {} | log–log slope of S − plateau (Δ ≤ 50), last 5 lags |", head.join(" | "));
            println!("|---|{}---|", "---|".repeat(sf.len()));
            printed_header = true;
        }
        let slope = structure_slope(&sf, 50.0, 5)
            .map_or("—".into(), |f| format!("{:.2} ± {:.2}", f.slope, f.slope_std_error));
        let row: Vec<String> = sf.iter().map(|(_, v)| format!("{v:.3}")).collect();
        println!("| {m} | {} | {slope} |", row.join(" | "));
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let what = args.get(1).map(String::as_str).unwrap_or("all");
    let t_end: Option<f64> = args.get(2).and_then(|s| s.parse().ok());
    let which: Vec<Reading> = match args.get(3).map(String::as_str) {
        Some("printed") => vec![Reading::Printed],
        Some("nonholonomic") => vec![Reading::Nonholonomic],
        _ => vec![Reading::Printed, Reading::Nonholonomic],
    };
    match what {
        "holonomy" => holonomy(t_end.unwrap_or(1000.0)),
        "readings" => readings(t_end.unwrap_or(5000.0), &which),
        "steps" => steps(t_end.unwrap_or(2000.0), &which),
        "lyapunov" => lyapunov(t_end.unwrap_or(500.0)),
        "reverse" => reverse(),
        "gauss" => gauss(t_end.unwrap_or(2000.0), &which),
        "structure" => {
            for path in args.iter().skip(2) {
                structure(path);
            }
        }
        "all" => {
            holonomy(t_end.unwrap_or(1000.0));
            reverse();
            lyapunov(500.0);
            readings(t_end.unwrap_or(5000.0), &which);
            steps(2000.0, &which);
            gauss(2000.0, &which);
        }
        other => {
            eprintln!("unknown experiment `{other}`: holonomy | readings | steps | lyapunov | reverse | gauss | all")
        }
    }
}
