//! Units far from 1. Newton's tolerance is on the scaled update
//! `|Δz_i| / (1 + |z_i|)`: relative for unknowns above 1 and absolute
//! below. The elastic skate of `examples/common/elastic_skate.rs` with every
//! length scaled by `λ` is the same motion in other units; each of its steps
//! is compared with the same step solved to round-off, lengths relative to
//! `λ` (`docs/guarantees.md`, "Units").

use spark_runtime::{Jacobian, Method, NewtonMode, NewtonOptions};

#[path = "../../examples/common/elastic_skate.rs"]
mod elastic_skate;
use elastic_skate::distance_to_tight;

const MODES: [(NewtonMode, Jacobian); 3] = [
    (NewtonMode::Full, Jacobian::Auto),
    (NewtonMode::Simplified, Jacobian::Exact),
    (NewtonMode::Simplified, Jacobian::StageDecoupled),
];

/// Lengths of 1 and above: the default tolerance is relative there, and
/// every mode's steps equal the tight ones to 1e-14 relative.
#[test]
fn large_units_keep_the_relative_accuracy_of_the_default_tolerance() {
    for method in [Method::Gauss, Method::LobattoIIIAB] {
        for lambda in [1.0, 1e3, 1e6] {
            for (mode, jacobian) in MODES {
                let options = NewtonOptions { mode, jacobian, ..NewtonOptions::default() };
                let (worst, _) = distance_to_tight(lambda, method, options, 0.1, 100).unwrap();
                assert!(worst <= 1e-14, "{method:?} λ = {lambda:e} {mode:?} {jacobian:?}: {worst:e}");
            }
        }
    }
}

/// Lengths below 1: the default tolerance is absolute there. It keeps the
/// steps within `tolerance / λ` relative (the guarantee in scaled units),
/// and the tolerance scaled by `λ` gives back 1e-14 relative in every mode,
/// with about as many updates per step as at `λ = 1`.
#[test]
fn small_units_keep_the_relative_accuracy_of_a_tolerance_scaled_to_them() {
    for method in [Method::Gauss, Method::LobattoIIIAB] {
        for (mode, jacobian) in MODES {
            let default = NewtonOptions { mode, jacobian, ..NewtonOptions::default() };
            let (_, unit_updates) = distance_to_tight(1.0, method, default, 0.1, 100).unwrap();
            for lambda in [1e-3, 1e-6, 1e-9] {
                let (worst, _) = distance_to_tight(lambda, method, default, 0.1, 100).unwrap();
                assert!(worst <= default.tolerance / lambda, "{method:?} λ = {lambda:e} {mode:?}: default {worst:e}");
                let scaled = NewtonOptions { tolerance: default.tolerance * lambda, ..default };
                let (worst, updates) = distance_to_tight(lambda, method, scaled, 0.1, 100).unwrap();
                assert!(worst <= 1e-14, "{method:?} λ = {lambda:e} {mode:?} {jacobian:?}: scaled {worst:e}");
                assert!(
                    updates <= unit_updates + 0.5,
                    "{method:?} λ = {lambda:e} {mode:?} {jacobian:?}: {updates} updates a step against {unit_updates} at λ = 1"
                );
            }
        }
    }
}
