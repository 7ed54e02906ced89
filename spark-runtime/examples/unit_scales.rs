//! How Newton's tolerance meets units: the elastic skate of
//! `common/elastic_skate.rs` with every length scaled by λ (the same motion
//! in other units), stepped 200 times by h = 0.1 with Gauss and Lobatto
//! IIIA-B s = 2 in the three Newton modes, each step against the same step
//! solved to round-off. Prints, per λ and mode, the largest relative
//! difference of q₁ and v₁ and the updates per step, with the default
//! tolerance and with the tolerance scaled by min(1, λ):
//!
//! ```sh
//! cargo run --release -p spark-runtime --example unit_scales
//! ```

use spark_runtime::{Jacobian, Method, NewtonMode, NewtonOptions};

#[path = "common/elastic_skate.rs"]
mod elastic_skate;

fn main() -> Result<(), String> {
    let modes = [
        ("full Newton", NewtonMode::Full, Jacobian::Auto),
        ("simplified, exact matrix", NewtonMode::Simplified, Jacobian::Exact),
        ("simplified, stage-decoupled", NewtonMode::Simplified, Jacobian::StageDecoupled),
    ];
    println!("| method | λ | Newton | default tolerance: relative difference (updates) | tolerance × min(1, λ) |");
    println!("|---|---|---|---|---|");
    for method in [Method::Gauss, Method::LobattoIIIAB] {
        for lambda in [1e3f64, 1.0, 1e-3, 1e-6, 1e-9] {
            for (name, mode, jacobian) in modes {
                let default = NewtonOptions { mode, jacobian, ..NewtonOptions::default() };
                let scaled = NewtonOptions { tolerance: default.tolerance * lambda.min(1.0), ..default };
                let (a, a_updates) = elastic_skate::distance_to_tight(lambda, method, default, 0.1, 200)?;
                let (b, b_updates) = elastic_skate::distance_to_tight(lambda, method, scaled, 0.1, 200)?;
                println!(
                    "| {} | {lambda:.0e} | {name} | {a:.1e} ({a_updates:.2}) | {b:.1e} ({b_updates:.2}) |",
                    method.label(2)
                );
            }
        }
    }
    Ok(())
}
