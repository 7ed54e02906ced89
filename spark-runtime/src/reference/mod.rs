//! Independent high-accuracy reference solutions.
//!
//! This module owns a solver that shares nothing with the SPARK stepper except
//! the [`NonholonomicSystem`] trait: it integrates the ψ-eliminated ODE of the
//! system (DESIGN.md §1, paper eq. 2.3),
//!
//! ```text
//! q̇ = v,
//! [ ∇²_vv L   Kᵀ ] [ v̇ ]   [ ∇_q L − ∂(∇_v L)/∂q · v − ∂(∇_v L)/∂t ]
//! [ K         0  ] [ ψ  ] = [ −k_t − k_q v                          ],
//! ```
//!
//! with a Gragg–Bulirsch–Stoer extrapolation method: Gragg's modified midpoint
//! rule with the step-number sequence `n_j = 2j`, Aitken–Neville polynomial
//! extrapolation in `h²`, and the order-and-step-size control of Hairer,
//! Nørsett & Wanner (*Solving ODEs I*, §II.9, the code ODEX). The saddle-point
//! system is solved by an LU decomposition with full pivoting at every
//! right-hand-side evaluation.
//!
//! # Accuracy
//!
//! With `rtol = atol = 1e-14` and at most 7 tableau rows (order ≤ 14; the
//! defaults of [`ReferenceOptions::default`]) the tests of this module measure,
//! against closed-form solutions:
//! - harmonic oscillator, `t ∈ [0, 20]`: error `< 5e-14` (measured 1.2e-14);
//! - the paper's skate on an inclined plane (a nonholonomic system with a
//!   `q`-dependent constraint matrix), `t ∈ [0, 10]`: error `< 1e-13`
//!   (measured ≈ 4e-15 with outputs every 0.2, ≈ 1.2e-14 in one long run to
//!   `t = 7`), constraint residual `|k| < 1e-14` at every output (measured
//!   ≈ 2e-15), and forward-then-backward integration back to the start within
//!   `2e-13` (measured ≈ 5e-14);
//! - a rheonomic, time-dependent, non-separable system (polar coordinates,
//!   time-dependent mass): its exact invariants to `< 1e-14`.
//!
//! Two choices buy these digits: the midpoint rule and the extrapolation work
//! on *increments* `y(t+H) − y(t)`, so rounding errors scale with the increment
//! rather than with `|y|`; and the tableau is capped at 7 rows, because the
//! Aitken–Neville weights of higher rows amplify rounding errors (12 rows gave
//! 10–20× larger errors at the same tolerance). The error of each step is
//! measured in the maximum norm over all components.
//!
//! The index-1 formulation does not enforce `k = 0` itself; the constraint
//! residual grows only with the global error of the integration (no
//! projection is applied, so the solution stays independent of the SPARK
//! code's constraint handling). Over long chaotic runs errors grow with the
//! dynamics like those of any one-step method.
//!
//! Tolerances below about `1e-15` cannot be met in double precision; the
//! solver then reports [`ReferenceError::StepSizeTooSmall`] or
//! [`ReferenceError::TooManySteps`] rather than returning an unverified answer.

mod acceleration;
mod gbs;
#[cfg(test)]
mod tests;

pub use acceleration::acceleration;

use crate::error::{Exact, Sci};
use crate::system::{NonholonomicSystem, Vector};
use gbs::{Gbs, State};

/// Settings of the extrapolation solver.
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceOptions {
    /// Relative tolerance of the local error (per component, RMS norm).
    pub rtol: f64,
    /// Absolute tolerance of the local error (per component, RMS norm).
    pub atol: f64,
    /// First step size tried (magnitude); `None` estimates one from the
    /// initial derivative.
    pub initial_step: Option<f64>,
    /// Largest step size allowed (magnitude); `None` means the whole interval.
    pub max_step: Option<f64>,
    /// Largest number of rows of the extrapolation tableau (the method order
    /// reaches `2·max_rows`); between 3 and 16.
    pub max_rows: usize,
    /// Give up after this many step attempts (accepted and rejected).
    pub max_steps: usize,
}

impl Default for ReferenceOptions {
    fn default() -> Self {
        Self { rtol: 1e-14, atol: 1e-14, initial_step: None, max_step: None, max_rows: 7, max_steps: 1_000_000 }
    }
}

/// Errors of the reference solver; each says what to change.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ReferenceError {
    /// An option is out of range.
    #[error("invalid reference option: {0}")]
    InvalidOptions(String),
    /// Output times must be finite and ordered in the direction of integration.
    #[error("output times must be finite and monotone away from t0 = {}; offending time {}", Exact(*t0), Exact(*time))]
    InvalidTimes {
        /// Initial time.
        t0: f64,
        /// The first offending output time.
        time: f64,
    },
    /// The saddle-point matrix `[[∇²_vv L, Kᵀ],[K, 0]]` is singular: the
    /// system violates assumption (2.4) of the paper at this point.
    #[error("the matrix [[∇²_vv L, Kᵀ],[K, 0]] is singular at t = {} (paper assumption 2.4 violated)", Sci(*t))]
    SingularSaddle {
        /// Time of the evaluation.
        t: f64,
    },
    /// Newton's method for `(v̇, ψ)` with a non-ideal constraint force
    /// `N(ψ)` did not converge: `N` is too strongly nonlinear in `ψ` there
    /// (e.g. a friction law too sharp near `ψ = 0`).
    #[error("the multiplier equations with the non-ideal force did not converge at t = {}; smooth N(ψ)", Sci(*t))]
    NonidealNotConverged {
        /// Time of the evaluation.
        t: f64,
    },
    /// An entry of the initial state is NaN or infinite.
    #[error("initial state: {which}[{index}] = {value:.3e} is not finite")]
    NonFiniteInitialState {
        /// `"q0"` or `"v0"`.
        which: &'static str,
        /// The entry's index.
        index: usize,
        /// Its value.
        value: f64,
    },
    /// The solution left the finite numbers (it overflows or blows up)
    /// although every right-hand side evaluated was finite.
    #[error("the solution is not finite at t = {t:.3e}; it overflows or blows up before the end time")]
    NonFiniteState {
        /// Time at which the state became non-finite.
        t: f64,
    },
    /// The right-hand side produced NaN or infinity.
    #[error("non-finite accelerations at t = {}; check the initial values and parameters", Sci(*t))]
    NonFinite {
        /// Time of the evaluation.
        t: f64,
    },
    /// The error control asked for a step below the resolution of `t`:
    /// the tolerance is too tight for double precision or the solution blows up.
    #[error(
        "step size {} too small at t = {}; loosen rtol/atol (≥ 1e-15) or check for a singularity",
        Sci(*h),
        Sci(*t)
    )]
    StepSizeTooSmall {
        /// Time reached.
        t: f64,
        /// The step size asked for.
        h: f64,
    },
    /// More step attempts than [`ReferenceOptions::max_steps`].
    #[error("gave up after {steps} step attempts at t = {}; raise max_steps or loosen the tolerances", Sci(*t))]
    TooManySteps {
        /// Time reached.
        t: f64,
        /// Attempts made.
        steps: usize,
    },
}

/// Counters of one integration.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReferenceStats {
    /// Accepted extrapolation steps.
    pub accepted_steps: usize,
    /// Rejected extrapolation steps.
    pub rejected_steps: usize,
    /// Right-hand-side evaluations (each one saddle-point solve).
    pub rhs_evaluations: usize,
}

/// States at the requested output times.
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceSolution<const N: usize> {
    /// Output times, as requested.
    pub times: Vec<f64>,
    /// Coordinates at each output time.
    pub q: Vec<Vector<N>>,
    /// Velocities at each output time.
    pub v: Vec<Vector<N>>,
    /// Work done.
    pub stats: ReferenceStats,
}

/// Integrates from `(t0, q0, v0)` to `t1` (either direction) and returns the
/// state at `t1`.
pub fn integrate<S, const N: usize, const M: usize>(
    sys: &S,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    t1: f64,
    options: &ReferenceOptions,
) -> Result<ReferenceSolution<N>, ReferenceError>
where
    S: NonholonomicSystem<N, M> + ?Sized,
{
    integrate_at(sys, t0, q0, v0, &[t1], options)
}

/// Integrates from `(t0, q0, v0)` and returns the state at each of `times`,
/// which must be monotone in the direction of integration (a time equal to
/// `t0` returns the initial state). The steps end exactly on the output times,
/// so every output has the full accuracy of the method.
pub fn integrate_at<S, const N: usize, const M: usize>(
    sys: &S,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    times: &[f64],
    options: &ReferenceOptions,
) -> Result<ReferenceSolution<N>, ReferenceError>
where
    S: NonholonomicSystem<N, M> + ?Sized,
{
    validate(options)?;
    if !t0.is_finite() {
        return Err(ReferenceError::InvalidTimes { t0, time: t0 });
    }
    for (which, x) in [("q0", q0), ("v0", v0)] {
        if let Some((index, &value)) = x.iter().enumerate().find(|(_, x)| !x.is_finite()) {
            return Err(ReferenceError::NonFiniteInitialState { which, index, value });
        }
    }
    let direction = times.iter().find(|&&t| t != t0).map_or(1.0, |&t| (t - t0).signum());
    let mut previous = t0;
    for &time in times {
        if !time.is_finite() || (time - previous) * direction < 0.0 {
            return Err(ReferenceError::InvalidTimes { t0, time });
        }
        previous = time;
    }

    let mut solver = Gbs::<S, N, M>::new(sys, options);
    let mut state = State { q: *q0, v: *v0 };
    let mut t = t0;
    let mut solution =
        ReferenceSolution { times: times.to_vec(), q: Vec::new(), v: Vec::new(), stats: ReferenceStats::default() };
    for &time in times {
        if time != t {
            state = solver.advance(t, state, time)?;
            t = time;
        }
        solution.q.push(state.q);
        solution.v.push(state.v);
    }
    solution.stats = solver.stats;
    Ok(solution)
}

fn validate(o: &ReferenceOptions) -> Result<(), ReferenceError> {
    let bad = |m: &str| Err(ReferenceError::InvalidOptions(m.to_string()));
    if !(o.rtol.is_finite() && o.rtol >= 0.0 && o.atol.is_finite() && o.atol >= 0.0) || o.rtol + o.atol <= 0.0 {
        return bad("rtol and atol must be finite, non-negative, and not both zero");
    }
    if let Some(h) = o.initial_step {
        if !(h.is_finite() && h > 0.0) {
            return bad("initial_step must be positive and finite");
        }
    }
    if let Some(h) = o.max_step {
        if !(h.is_finite() && h > 0.0) {
            return bad("max_step must be positive and finite");
        }
    }
    if !(3..=16).contains(&o.max_rows) {
        return bad("max_rows must lie in 3..=16");
    }
    if o.max_steps == 0 {
        return bad("max_steps must be positive");
    }
    Ok(())
}
