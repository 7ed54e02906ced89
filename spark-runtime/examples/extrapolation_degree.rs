//! Updates per step and contraction rates of the stage-decoupled iteration
//! with the starting guess extrapolated across steps at degree 3 and at
//! degree 5, over a range of step sizes: the skate (Gauss s = 1, Lobatto
//! IIIA-B s = 2), the particle (Gauss s = 1) and
//! the McLachlan–Perlmutter particles (n = 7, Gauss and Lobatto IIIA-B
//! s = 2), over `t ∈ [0, 10]` from the paper's initial values. For each
//! run it prints the Newton updates and factorizations per step and the
//! quantiles over the steps of the largest ratio of consecutive updates a
//! step took, the rate the next step's choice of degree reads
//! (docs/performance/README.md, "The starting guess"):
//!
//! ```sh
//! cargo run --release -p spark-runtime --example extrapolation_degree
//! ```

use spark_runtime::{Jacobian, Method, NewtonMode, NewtonOptions, NonholonomicSystem, State, Stepper, Tableau};

#[path = "common/paper_systems.rs"]
mod paper_systems;
use paper_systems::{mp7_start, particle_start, skate_start, McLachlanPerlmutter7, NonholonomicParticle, Skate};

fn report<Sys, const N: usize, const S: usize, const D: usize>(
    name: &str,
    sys: &Sys,
    start: State<N>,
    h: f64,
    method: Method,
) -> Result<(), String>
where
    Sys: NonholonomicSystem<N, 1> + Clone,
{
    for degree in [3, 5] {
        let options = NewtonOptions {
            mode: NewtonMode::Simplified,
            jacobian: Jacobian::StageDecoupled,
            extrapolation_degree: degree,
            ..NewtonOptions::default()
        };
        let tableau = Tableau::new(method).map_err(|e| e.to_string())?;
        let mut stepper = Stepper::<Sys, N, 1, S, D>::new(sys.clone(), tableau).with_options(options);
        let (mut state, mut rates, mut updates, mut factorizations) = (start, Vec::new(), 0, 0);
        let steps = (10.0 / h).round() as usize;
        for _ in 0..steps {
            let r = stepper.step(&state, h).map_err(|e| format!("{name}, h = {h}, degree {degree}: {e}"))?;
            let records = stepper.last_history().iterations();
            rates.push(records.iter().map(|x| x.rate).filter(|x| !x.is_nan()).fold(0.0f64, f64::max));
            (updates, factorizations, state) = (updates + r.iterations, factorizations + r.factorizations, r.state);
        }
        rates.sort_by(f64::total_cmp);
        let quantile = |f: f64| rates[((rates.len() - 1) as f64 * f) as usize];
        println!(
            "{name}, h = {h}, degree {degree}: {:.2} updates, {:.2} factorizations per step; rate 10 % {:.1e}, \
             median {:.1e}, 90 % {:.1e}, largest {:.1e}",
            updates as f64 / steps as f64,
            factorizations as f64 / steps as f64,
            quantile(0.1),
            quantile(0.5),
            quantile(0.9),
            quantile(1.0),
        );
    }
    Ok(())
}

fn main() -> Result<(), String> {
    let particle = particle_start();
    let mp7 = mp7_start();
    let skate = skate_start();
    for h in [0.05, 0.1, 0.2] {
        report::<_, 3, 1, 7>("skate, Gauss s = 1", &Skate::default(), skate, h, Method::Gauss)?;
        report::<_, 3, 2, 11>("skate, Lobatto IIIA-B s = 2", &Skate::default(), skate, h, Method::LobattoIIIAB)?;
    }
    for h in [0.1, 0.2, 0.4, 0.7] {
        report::<_, 3, 1, 7>("particle, Gauss s = 1", &NonholonomicParticle::default(), particle, h, Method::Gauss)?;
    }
    for h in [0.05, 0.1, 0.3, 0.6] {
        report::<_, 7, 2, 23>("mp7, Gauss s = 2", &McLachlanPerlmutter7::default(), mp7, h, Method::Gauss)?;
    }
    for h in [0.05, 0.3, 0.6] {
        report::<_, 7, 2, 23>(
            "mp7, Lobatto IIIA-B s = 2",
            &McLachlanPerlmutter7::default(),
            mp7,
            h,
            Method::LobattoIIIAB,
        )?;
    }
    Ok(())
}
