//! Writes a declaration whose Lagrangian and constraint hold a product of
//! `k` distinct parameter-dependent factors, and runs the macro's work on
//! it in-process: the figures of `docs/compile-cost.md` (long products).
//!
//! ```text
//! cargo build --release -p spark-symbolic --example long_product
//! target/release/examples/long_product dsl 4000      # the declaration
//! /usr/bin/time -v target/release/examples/long_product expand 4000  # the macro's expansion
//! /usr/bin/time -v target/release/examples/long_product check 4000   # spark.compile's check
//! ```

use proc_macro2::TokenStream;
use std::process::ExitCode;
use std::time::Instant;

/// `L = ½ Π_{i=1..k} atan2(m, i) · dot(x)² + ½ dot(y)² − x²`, `k = dot(y) − x dot(x)`.
fn declaration(k: usize) -> String {
    let product: Vec<String> = (1..=k).map(|i| format!("atan2(m, {i})")).collect();
    format!(
        "struct LongProduct {{ coordinates: [x, y], parameters: {{ m = 1.0 }}, \
         lagrangian: {}*dot(x)^2/2 + dot(y)^2/2 - x^2, constraints: [ dot(y) - x*dot(x) ] }}",
        product.join("*")
    )
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    let (Some(mode), Some(Ok(k))) = (args.get(1).cloned(), args.get(2).map(|k| k.parse::<usize>())) else {
        eprintln!("usage: long_product dsl|expand|check K");
        return ExitCode::FAILURE;
    };
    let text = declaration(k);
    if mode == "dsl" {
        println!("{text}");
        return ExitCode::SUCCESS;
    }
    // The stack of a main thread (the compiler's, the Python package's check thread).
    let worker = std::thread::Builder::new().stack_size(8 << 20).spawn(move || {
        let tokens: TokenStream = text.parse().map_err(|e| format!("{e:?}"))?;
        let start = Instant::now();
        let what = match mode.as_str() {
            "expand" => format!("{} bytes of code", spark_symbolic::expand(tokens).to_string().len()),
            "check" => {
                let spec = spark_symbolic::dsl::parse(tokens).map_err(|e| e.message)?;
                spark_symbolic::generate(&spec).map_err(|e| e.message)?;
                let a = spark_symbolic::analyze(&spec).map_err(|e| e.message)?;
                format!("{:?}", a.operations)
            }
            _ => return Err(format!("unknown mode `{mode}`")),
        };
        Ok::<_, String>(format!("{mode} k = {k}: {:.2} s wall; {what}", start.elapsed().as_secs_f64()))
    });
    match worker.map_err(|e| e.to_string()).and_then(|w| w.join().map_err(|_| "panicked".to_string())) {
        Ok(Ok(line)) => {
            println!("{line}");
            ExitCode::SUCCESS
        }
        Ok(Err(e)) | Err(e) => {
            eprintln!("{e}");
            ExitCode::FAILURE
        }
    }
}
