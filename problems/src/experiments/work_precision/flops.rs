//! What a step's Newton solve costs in floating-point operations, counted
//! from the algorithm: the three solves the per-step table and the scaling
//! study compare ([`NewtonPath`]) and the count of [`flops_per_step`], so a
//! measured time per step can be read as a rate against the core's
//! arithmetic limit.

use spark_runtime::{Jacobian, NewtonMode, NewtonOptions, NonholonomicSystem, State, StepError, Stepper};

/// The three ways a step can solve its Newton equations, as the scaling
/// study compares them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum NewtonPath {
    /// Full Newton on the exact `D × D` Jacobian (a block LU of the dense
    /// matrix per factorization).
    Dense,
    /// Simplified Newton on the exact Jacobian: the same factorization, kept
    /// for the step.
    DenseSimplified,
    /// Simplified Newton on the stage-decoupled matrix: the constant mass
    /// matrix solved by its reciprocal diagonal and an `S·M` Schur
    /// complement in the multipliers (`Jacobian::StageDecoupled`).
    Structured,
}

impl NewtonPath {
    /// Every path, in table order.
    pub const ALL: [NewtonPath; 3] = [NewtonPath::Dense, NewtonPath::DenseSimplified, NewtonPath::Structured];

    /// Column and legend text.
    pub fn label(self) -> &'static str {
        match self {
            NewtonPath::Dense => "dense, full Newton",
            NewtonPath::DenseSimplified => "dense, simplified Newton",
            NewtonPath::Structured => "structured (stage-decoupled)",
        }
    }

    /// The Newton options that select this path.
    pub fn options(self) -> NewtonOptions {
        let (mode, jacobian) = match self {
            NewtonPath::Dense => (NewtonMode::Full, Jacobian::Exact),
            NewtonPath::DenseSimplified => (NewtonMode::Simplified, Jacobian::Exact),
            NewtonPath::Structured => (NewtonMode::Simplified, Jacobian::StageDecoupled),
        };
        NewtonOptions { mode, jacobian, ..NewtonOptions::default() }
    }
}

/// Floating-point operations of one step that makes `iterations` updates
/// and `factorizations` factorizations on `path` for `Sys` with `S`
/// stages, counted from the algorithm (`n`, `m`, `s`, `D = s(n+m)+n`, `V`,
/// `J` the operations of the generated `stage_values` and
/// `stage_jacobians`):
///
/// - every update evaluates the residual: `(s+1)·V` at the stage points and
///   the end point, `2s(s+1)n` to form the stage points and `4s(s+1)n` for
///   the force and constraint-force sums;
/// - dense paths: a factorization evaluates `(s+1)·J`, assembles the
///   momentum blocks by the chain rule (`2s(s+1)n²`) and factors `⅔D³`
///   (counted dense, although the block elimination skips the structural
///   zeros); an update solves with `2D²`;
/// - structured path: a factorization evaluates `(s+1)·J` (an upper bound:
///   the refresh evaluates the values and the constraint Jacobians only),
///   forms `W⁻¹Kᵀ` with the reciprocal diagonal (`2s(s+1)nm`), the
///   constraint blocks and the Schur complement (`2s²(s+1)nm²`) and factors
///   it (`⅔(sm)³`); an update costs `(s+1)n` for `W⁻¹`, `4s(s+1)nm` for the
///   two block products and `2(sm)²` for the Schur solve. With a kept
///   constant stiffness (`CONSTANT_STIFFNESS`, counted in its
///   per-coordinate form with every coordinate stiff) an update solves the
///   stage blocks with one `s × s` inverse per coordinate and forms the end
///   row's coupling (`2s²n + 2sn + n`), and a factorization forms
///   `A⁻¹Kᵀ` from the kept coefficients (`s(s+1)nm`). A stiffness kept at
///   each stage point (`DIAGONAL_STIFFNESS`) is solved alike, and each
///   factorization also forms its blocks `Â diag(F_q,cc) A` and their
///   inverses (`4s³n`).
pub fn flops_per_step<Sys, const N: usize, const M: usize, const S: usize>(
    path: NewtonPath,
    iterations: f64,
    factorizations: f64,
) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    let (values, jacobians) = (Sys::OPERATIONS.stage_values, Sys::OPERATIONS.stage_jacobians);
    let per_stage = Sys::DIAGONAL_STIFFNESS;
    let stiff = Sys::CONSTANT_STIFFNESS || per_stage;
    let (n, m, s) = (N as f64, M as f64, S as f64);
    let d = s * (n + m) + n;
    let residual = (s + 1.0) * values as f64 + 6.0 * s * (s + 1.0) * n;
    let (factor, solve) = match path {
        NewtonPath::Dense | NewtonPath::DenseSimplified => {
            ((s + 1.0) * jacobians as f64 + 2.0 * s * (s + 1.0) * n * n + 2.0 / 3.0 * d * d * d, 2.0 * d * d)
        }
        NewtonPath::Structured => {
            let sm = s * m;
            // `W⁻¹` of one vector of all points, and of the `sm` columns of `Kᵀ`.
            let (velocity, columns) = if stiff {
                (2.0 * s * s * n + 2.0 * s * n + n, s * (s + 1.0) * n * m)
            } else {
                ((s + 1.0) * n, 2.0 * s * (s + 1.0) * n * m)
            };
            let blocks = if per_stage { 4.0 * s * s * s * n } else { 0.0 };
            (
                (s + 1.0) * jacobians as f64
                    + columns
                    + blocks
                    + 2.0 * s * s * (s + 1.0) * n * m * m
                    + 2.0 / 3.0 * sm * sm * sm,
                velocity + 4.0 * s * (s + 1.0) * n * m + 2.0 * sm * sm,
            )
        }
    };
    iterations * (residual + solve) + factorizations * factor
}

/// The Newton work of `steps` steps of size `h` from `start`, taken one by
/// one with `stepper` (the driver's report does not keep factorizations):
/// mean updates and mean factorizations per step.
pub fn newton_work<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    stepper: &mut Stepper<Sys, N, M, S, D>,
    start: State<N>,
    h: f64,
    steps: usize,
) -> Result<(f64, f64), StepError>
where
    Sys: NonholonomicSystem<N, M>,
{
    let mut state = start;
    let (mut iterations, mut factorizations) = (0usize, 0usize);
    for _ in 0..steps {
        let r = stepper.step(&state, h)?;
        (state, iterations, factorizations) = (r.state, iterations + r.iterations, factorizations + r.factorizations);
    }
    let per_step = |x: usize| x as f64 / steps.max(1) as f64;
    Ok((per_step(iterations), per_step(factorizations)))
}
