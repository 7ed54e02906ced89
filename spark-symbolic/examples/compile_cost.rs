//! Helper of `scripts/compile-cost.sh`: writes McLachlan and Perlmutter's
//! particles (paper §8.4) for any odd `n = 2m + 1` as a `nonholonomic_system!`
//! declaration, and measures the macro's own work on it in-process.
//!
//! ```text
//! cargo run --release -p spark-symbolic --example compile_cost -- dsl 51       # the declaration
//! cargo run --release -p spark-symbolic --example compile_cost -- expand 51 5  # timing, 5 repetitions
//! ```
//!
//! `U = ½(|q|² + q_{m+2}² q_{m+3}² + Σ_{i=1..m} q_{1+i}² q_{m+1+i}²)`,
//! `L = ½|v|² − U`, `k = v₁ + Σ_{i=m+2..n} q_i v_i` (1-based indices).

use proc_macro2::TokenStream;
use spark_symbolic::SrcExpr;
use std::process::ExitCode;
use std::time::Instant;

/// The declaration for `n = 2m + 1` coordinates.
fn declaration(n: usize) -> String {
    let m = (n - 1) / 2;
    let q = |i: usize| format!("q{i}");
    let coords: Vec<String> = (1..=n).map(q).collect();
    let kinetic: Vec<String> = (1..=n).map(|i| format!("dot(q{i})^2")).collect();
    let mut potential: Vec<String> = (1..=n).map(|i| format!("q{i}^2")).collect();
    potential.push(format!("q{}^2*q{}^2", m + 2, m + 3));
    potential.extend((1..=m).map(|i| format!("q{}^2*q{}^2", 1 + i, m + 1 + i)));
    let mut constraint = vec!["dot(q1)".to_string()];
    constraint.extend((m + 2..=n).map(|i| format!("q{i}*dot(q{i})")));
    format!(
        "nonholonomic_system! {{\n    /// McLachlan and Perlmutter's particles, n = {n}.\n    pub struct McLachlanPerlmutter{n} {{\n        \
         coordinates: [{}],\n        lagrangian: ({})/2\n            - ({})/2,\n        constraints: [ {} ],\n    }}\n}}\n",
        coords.join(", "),
        kinetic.join(" + "),
        potential.join(" + "),
        constraint.join(" + ")
    )
}

/// Arithmetic operations (binary operators, negations, calls) in a source expression.
fn source_ops(e: &SrcExpr) -> usize {
    match e {
        SrcExpr::Neg(a, _) => 1 + source_ops(a),
        SrcExpr::Binary(_, a, b, _) => 1 + source_ops(a) + source_ops(b),
        SrcExpr::Call(_, args, _) => 1 + args.iter().map(source_ops).sum::<usize>(),
        _ => 0,
    }
}

/// CPU time of this thread in nanoseconds (Linux `schedstat`), so that timings
/// on a shared machine count only our own work; `None` elsewhere.
fn cpu_ns() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    s.split_whitespace().next()?.parse().ok()
}

fn body(decl: &str) -> TokenStream {
    let start = decl.find('{').expect("declaration has a body") + 1;
    let end = decl.rfind('}').expect("declaration has a body");
    decl[start..end].parse().expect("declaration lexes")
}

fn expand(n: usize, reps: usize) -> Result<(), String> {
    let decl = declaration(n);
    let tokens = body(&decl);
    // Wall: the minimum. CPU: the mean, since `schedstat` is only updated at
    // scheduler events and a single short run may read as zero.
    let (mut best, mut total_cpu) = (f64::INFINITY, 0.0);
    let mut lines = 0;
    for _ in 0..reps.max(1) {
        let (start, cpu0) = (Instant::now(), cpu_ns());
        let spec = spark_symbolic::dsl::parse(tokens.clone()).map_err(|e| e.message)?;
        let code = spark_symbolic::generate(&spec).map_err(|e| e.message)?;
        let wall = start.elapsed().as_secs_f64();
        best = best.min(wall);
        let cpu = match (cpu0, cpu_ns()) {
            (Some(a), Some(b)) => b.saturating_sub(a) as f64 * 1e-9,
            _ => wall,
        };
        total_cpu += cpu;
        lines = code.to_string().len();
    }
    let spec = spark_symbolic::dsl::parse(tokens).map_err(|e| e.message)?;
    let analysis = spark_symbolic::analyze(&spec).map_err(|e| e.message)?;
    let src_ops = source_ops(&spec.lagrangian) + spec.constraints.iter().map(|c| source_ops(&c.expr)).sum::<usize>();
    let ops = analysis.operations;
    // One line, key=value, for the script to parse.
    println!(
        "n={n} expand_ms={:.1} expand_cpu_ms={:.1} source_ops={src_ops} stage_values={} stage_jacobians={} bundle={} code_bytes={lines}",
        best * 1e3,
        total_cpu / reps.max(1) as f64 * 1e3,
        ops.stage_values,
        ops.stage_jacobians,
        ops.bundle
    );
    Ok(())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let n = args.get(1).and_then(|s| s.parse::<usize>().ok()).filter(|n| *n >= 5 && n % 2 == 1);
    let result = match (args.first().map(String::as_str), n) {
        (Some("dsl"), Some(n)) => {
            print!("{}", declaration(n));
            Ok(())
        }
        (Some("expand"), Some(n)) => expand(n, args.get(2).and_then(|s| s.parse().ok()).unwrap_or(3)),
        _ => Err("usage: compile_cost (dsl | expand) <n: odd, >= 5> [repetitions]".to_string()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
