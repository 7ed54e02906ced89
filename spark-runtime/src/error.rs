//! Errors a user can act on.

use std::fmt;

/// Displays a float in compact scientific notation, `{:.3e}` unless the
/// format asks for another precision (`{:.6}` gives `{:.6e}`): every float
/// in an error message goes through it or [`Exact`], so `h = 1e300` prints
/// as `1.000e300` instead of a 301-digit number.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Sci(pub(crate) f64);

impl fmt::Display for Sci {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:.*e}", f.precision().unwrap_or(3), self.0)
    }
}

/// Displays a float with every digit that tells it apart from its
/// neighbours (the shortest form that reads back as the same `f64`), in
/// scientific notation outside `1e-4 ≤ |x| < 1e16` (`1e300`, not 301
/// digits). For the numbers a message compares, such as the ends of an
/// interval or an energy against its start value: three digits print
/// `t0 = 1e17` and `t_end = 1e17 + 16` alike.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Exact(pub f64);

impl fmt::Display for Exact {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let x = self.0;
        if x == 0.0 || !x.is_finite() || (1e-4..1e16).contains(&x.abs()) {
            write!(f, "{x}")
        } else {
            write!(f, "{x:e}")
        }
    }
}

/// An option outside its allowed range, found before any step is taken.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("invalid option {option} = {value}: it must be {allowed}")]
pub struct OptionError {
    /// The option, as a path a user can find (`NewtonOptions::tolerance`).
    pub option: &'static str,
    /// The value given, formatted.
    pub value: Box<str>,
    /// The allowed range.
    pub allowed: &'static str,
}

impl OptionError {
    /// A float option out of range.
    pub(crate) fn float(option: &'static str, value: f64, allowed: &'static str) -> Self {
        OptionError { option, value: Sci(value).to_string().into(), allowed }
    }

    /// An integer option out of range.
    pub(crate) fn integer(option: &'static str, value: u64, allowed: &'static str) -> Self {
        OptionError { option, value: value.to_string().into(), allowed }
    }
}

/// Errors about a system's declaration or parameters.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SystemError {
    /// `set_parameter` was given a name the system does not declare.
    #[error("unknown parameter `{name}`; this system declares: {known}")]
    UnknownParameter {
        /// The name given.
        name: String,
        /// The declared parameters, comma-separated.
        known: String,
    },
    /// A parameter value is NaN or infinite.
    #[error("parameter `{name}` must be finite, got {}", Sci(*value))]
    NonFiniteParameter {
        /// The parameter.
        name: String,
        /// The value given.
        value: f64,
    },
}

/// One Newton iteration, as recorded in a [`NewtonHistory`].
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IterationRecord {
    /// Max-norm of the residual before the update.
    pub residual: f64,
    /// Scaled max-norm of the update (`|Δz_i| / (1 + |z_i|)`, `z` the iterate
    /// after the first update on the current factors).
    pub update: f64,
    /// Contraction rate `‖Δz_k‖ / ‖Δz_{k−1}‖` (NaN on the first iteration).
    pub rate: f64,
}

/// Capacity of a [`NewtonHistory`]; also the hard cap on Newton iterations.
pub const HISTORY_CAPACITY: usize = 32;

/// The iterations of one Newton solve, stored inline (no heap).
///
/// Equality compares the recorded iterations only (a history is reused
/// from step to step, so slots beyond [`len`](Self::len) hold old records).
#[derive(Clone, Copy)]
pub struct NewtonHistory {
    records: [IterationRecord; HISTORY_CAPACITY],
    len: usize,
}

impl Default for NewtonHistory {
    fn default() -> Self {
        NewtonHistory { records: [IterationRecord::default(); HISTORY_CAPACITY], len: 0 }
    }
}

impl NewtonHistory {
    /// The recorded iterations, oldest first.
    pub fn iterations(&self) -> &[IterationRecord] {
        &self.records[..self.len]
    }
    /// Number of recorded iterations.
    pub fn len(&self) -> usize {
        self.len
    }
    /// No iteration recorded.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// Appends a record (ignored beyond [`HISTORY_CAPACITY`]).
    pub fn push(&mut self, r: IterationRecord) {
        if self.len < HISTORY_CAPACITY {
            self.records[self.len] = r;
            self.len += 1;
        }
    }
    /// Forgets all records.
    pub fn clear(&mut self) {
        self.len = 0;
    }
}

impl PartialEq for NewtonHistory {
    fn eq(&self, other: &Self) -> bool {
        self.iterations() == other.iterations()
    }
}

impl std::fmt::Debug for NewtonHistory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.iterations()).finish()
    }
}

impl std::fmt::Display for NewtonHistory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (k, r) in self.iterations().iter().enumerate() {
            if k > 0 {
                f.write_str("; ")?;
            }
            write!(f, "#{}: |G|={} |dz|={} rate={}", k + 1, Sci(r.residual), Sci(r.update), Sci(r.rate))?;
        }
        Ok(())
    }
}

/// Why one SPARK step (or the initial-value check) failed. Newton failures
/// carry the iteration history (boxed: only the failure path allocates).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StepError {
    /// The step size is zero, NaN or infinite, or the input state is not finite.
    #[error("invalid step at t = {}, h = {}: {reason}", Sci(*t), Sci(*h))]
    InvalidStep {
        /// Start time.
        t: f64,
        /// Step size.
        h: f64,
        /// What is wrong.
        reason: &'static str,
    },
    /// Newton updates grew (contraction rate ≥ 1 above round-off level).
    /// `h = 0` marks the projection of the initial velocity, whose message
    /// names its causes instead of a step size.
    #[error("{}", diverged_message(*t, *h, history))]
    Diverged {
        /// Start time.
        t: f64,
        /// Step size.
        h: f64,
        /// The iterations.
        history: Box<NewtonHistory>,
    },
    /// Newton did not reach the tolerance within the iteration limit
    /// (`h = 0`: in the projection of the initial velocity).
    #[error("{}", max_iterations_message(*t, *h, history))]
    MaxIterations {
        /// Start time.
        t: f64,
        /// Step size.
        h: f64,
        /// The iterations.
        history: Box<NewtonHistory>,
    },
    /// The Newton matrix is singular to working precision: a pivot fell
    /// below `64 ε` times the largest entry of its column (e.g. the
    /// Lagrangian is not regular or the constraints are dependent there).
    /// The test is relative to the column, so a matrix evaluated at a
    /// runaway iterate (huge multipliers dominating a column) can fail it
    /// with an unremarkable pivot: `scale` and the history tell the cases apart.
    /// A matrix that is regular once its rows and columns are scaled to
    /// unit size is singular by its magnitudes alone (a state or step too
    /// large for double precision to resolve the equations), and `detail`
    /// says so instead of pointing at a mass or a constraint.
    /// `h = 0` marks the projection of the initial velocity, whose matrix is
    /// the saddle matrix and whose message names no step.
    #[error("{}", singular_message(*t, *h, detail, history))]
    SingularMatrix {
        /// Start time.
        t: f64,
        /// Step size.
        h: f64,
        /// The offending column, its unknown (with the coordinate of a
        /// velocity), the pivot and the column's largest magnitude (the
        /// pivot's yardstick) and the likely cause, e.g. ``column 5 (V_2[3],
        /// the velocity of `theta`): pivot 1.000e0 is below 64 eps x its
        /// largest entry 1.5e14 (…)`` (one boxed `str`, not a field for
        /// each, keeps the error small).
        detail: Box<str>,
        /// The iterations.
        history: Box<NewtonHistory>,
    },
    /// The system produced NaN or infinite values. For a step (`h ≠ 0`) the
    /// message names both causes: the step's equations overflowed, which a
    /// smaller `h` cures (their terms carry `h` and `h²`, `h²·∂²L/∂q²` in the
    /// Newton matrix), or a function of the declaration was evaluated
    /// outside its domain or where its derivative is undefined. `h = 0`
    /// marks the checks before the first step (the constraint at the initial
    /// state, the projection of the initial velocity), whose message names
    /// the causes at the initial state instead of a step size.
    #[error("{}", non_finite_message(*t, *h, stage, history))]
    NonFinite {
        /// Start time.
        t: f64,
        /// Step size, 0 before the first step.
        h: f64,
        /// Where it appeared (residual, Jacobian, update).
        stage: &'static str,
        /// The iterations.
        history: Box<NewtonHistory>,
    },
    /// The step solved its equations, but its end violates the energy
    /// balance the structure facts guarantee (autonomous `L`, constraints
    /// linear homogeneous in `v`, possibly rheonomic, no external or non-ideal
    /// force: `E` is a first integral): since the start of the chain of
    /// continued steps at `since`, `|E − E₀|` exceeds `limit` times the
    /// energy's size `|E₀| + |p₀·v₀|`. The discrete map amplifies something
    /// the flow does not — typically a stiff mode with `ω·h` beyond the
    /// method's stability range — so the result would be garbage. Checked
    /// only when [`NewtonOptions::energy_drift_limit`](crate::NewtonOptions)
    /// is set (the default).
    #[error(
        "energy drift in the step from t = {} with h = {}: E = {} against E0 = {} at \
         the start of the continued steps, |E - E0| = {} > {} = energy_drift_limit x (|E0| + |p0.v0|); E is a first \
         integral of this system, so the discrete map does not keep it at this step size (an unstable map, e.g. \
         a stiff mode beyond the method's stability range, or the drift of a non-reversible system): reduce h, \
         use a method stable there, or set NewtonOptions::energy_drift_limit to None to continue regardless",
        Sci(*t),
        Sci(*h),
        Exact(*energy),
        Exact(*energy0),
        Sci((energy - energy0).abs()),
        Sci(*bound)
    )]
    EnergyDrift {
        /// Start time of the failing step.
        t: f64,
        /// Step size.
        h: f64,
        /// `E₀`, where the chain of continued steps began.
        energy0: f64,
        /// `E` at the end of the failing step.
        energy: f64,
        /// The bound exceeded: `energy_drift_limit · (|E₀| + |p₀·v₀|)`.
        bound: f64,
    },
    /// A residual `|k_i(t₀, q₀, v₀)|` exceeds the tolerance times the size
    /// of its terms ([`ConsistencyPolicy`](crate::ConsistencyPolicy)) and
    /// the policy says not to project.
    #[error(
        "inconsistent initial state: |k(t0,q0,v0)| = {} > {} (the tolerance x the size of the terms of k); \
         choose ConsistencyPolicy::Project to project v0 onto the constraints",
        Sci(*residual),
        Sci(*tolerance)
    )]
    InconsistentInitialState {
        /// `max_i |k_i(t₀,q₀,v₀)|`.
        residual: f64,
        /// The bound of the first row beyond it: the tolerance times the
        /// size of that row's terms (at least 1).
        tolerance: f64,
    },
    /// A [`NewtonOptions`](crate::NewtonOptions) field is out of range
    /// (checked once, before the first step with these options).
    #[error("{0}")]
    InvalidOption(Box<OptionError>),
    /// A step that does not continue the stepper's previous step (a cold
    /// start) begins at a state that violates the constraints:
    /// `|k_i(t,q,v)|` exceeds `NewtonOptions::consistency_tolerance` times
    /// the size of the terms of `k_i` (at least 1). Such a step enforces
    /// `k = 0` at its end at once, an impulse that changes the energy.
    #[error(
        "the step from t = {t:.3e} starts cold (not where the stepper's previous step ended) at a state that \
         violates the constraints: max |k_i(t,q,v)| = {residual:.3e} > {tolerance:.3e} (consistency_tolerance x \
         the size of the terms of k); project v onto the constraints first with \
         spark_runtime::consistent_velocity(.., ConsistencyPolicy::Project {{ .. }}) (integrate does this with \
         RunOptions::consistency), or raise NewtonOptions::consistency_tolerance to accept the state as it is"
    )]
    InconsistentStart {
        /// Start time.
        t: f64,
        /// `max_i |k_i(t,q,v)|`.
        residual: f64,
        /// The tolerance of the offending row.
        tolerance: f64,
    },
    /// A quantity of the equations of motion is NaN or infinite at the
    /// initial state `(t₀, q₀, v₀)` (checked by
    /// [`consistent_velocity`](crate::consistent_velocity) before the first
    /// step): the energy `E`, the Lagrangian `L`, the momentum `∇_v L`, the
    /// force `∇_q L`, the mass matrix `∇²_vv L` or the constraint rows
    /// `∂k/∂v`. The message names every cause a user can act on
    /// ([`INITIAL_STATE_CAUSES`]): a function of `L` or `k` outside its
    /// domain or where it is not differentiable, an overflow, a parameter.
    #[error(
        "the {quantity} is {} at the initial state (t0 = {}): {INITIAL_STATE_CAUSES}; give an initial state and \
         parameters at which it is a finite number (rescale the units if the magnitudes are physical)",
        Sci(*value),
        Sci(*t)
    )]
    NonFiniteInitialValue {
        /// Initial time.
        t: f64,
        /// Which quantity, e.g. `energy E = ∇_v L·v − L`.
        quantity: &'static str,
        /// Its value (for a vector or matrix, the first non-finite entry).
        value: f64,
    },
    /// No step can be solved from the initial state. Either the saddle
    /// matrix `[[W, Kᵀ],[K, 0]]` (`W = ∇²_vv L` the mass matrix,
    /// `K = ∂k/∂v`) is singular there (checked by
    /// [`consistent_velocity`](crate::consistent_velocity) before the first
    /// step), so the equations of motion do not determine the
    /// accelerations: `W` is singular on the velocities the constraints
    /// leave free (a zero mass or inertia parameter, a velocity missing from
    /// `L`), or the constraint rows are dependent or vanish. Or the saddle
    /// matrix is regular but `W` is singular (checked by a step that starts
    /// cold): the constraints fix the velocities `W` leaves without inertia,
    /// but the momentum equations of a step are dependent along them, so
    /// Newton fails or lands on a wrong step. `detail` says which.
    #[error("no step can be solved from the initial state (t0 = {}): {detail}", Sci(*t))]
    SingularInitialState {
        /// Initial time.
        t: f64,
        /// Which column failed, what it points at and the likely cause.
        detail: Box<str>,
    },
    /// A cold start finds the constraint rows `K = ∂k/∂v` dependent or
    /// nearly so: the condition number of `K W⁻¹ Kᵀ` (the Schur complement
    /// of the saddle matrix `[[W, Kᵀ],[K, 0]]`, `W = ∇²_vv L`) exceeds
    /// `limit`, so the accelerations and multipliers are not determined to
    /// working precision there and a step would return a meaningless
    /// constraint force.
    #[error(
        "the constraint rows K = dk/dv are dependent at the start of the step from t = {t:.3e}: condition number \
         of K W^-1 K^T = {condition:.3e} > {limit:.3e} (W = the mass matrix), so the multipliers are not \
         determined there; start from a configuration where the constraints are independent, or remove the \
         redundant constraint"
    )]
    DependentConstraints {
        /// Start time.
        t: f64,
        /// `κ₁(K W⁻¹ Kᵀ)` (infinite when its factorization failed).
        condition: f64,
        /// The largest accepted condition number.
        limit: f64,
    },
}

impl StepError {
    /// The Newton history, when the failure came from a Newton solve.
    pub fn history(&self) -> Option<&NewtonHistory> {
        match self {
            StepError::Diverged { history, .. }
            | StepError::MaxIterations { history, .. }
            | StepError::SingularMatrix { history, .. }
            | StepError::NonFinite { history, .. } => Some(history),
            _ => None,
        }
    }

    /// Whether a smaller step, or another starting guess, may cure the
    /// failure: not for bad input (a zero or non-finite step, a non-finite
    /// or inconsistent state, an invalid option), which fails the same way
    /// at any step size.
    pub(crate) fn is_curable(&self) -> bool {
        !matches!(
            self,
            StepError::InvalidStep { .. }
                | StepError::InconsistentInitialState { .. }
                | StepError::NonFiniteInitialValue { .. }
                | StepError::SingularInitialState { .. }
                | StepError::InvalidOption(_)
                | StepError::InconsistentStart { .. }
                | StepError::DependentConstraints { .. }
        )
    }
}

/// Why a quantity of the equations of motion is NaN or infinite at the
/// initial state, every cause a user can act on: the messages of
/// [`StepError::NonFiniteInitialValue`] and of [`StepError::NonFinite`]
/// before the first step.
const INITIAL_STATE_CAUSES: &str = "at this state a function in L or k is outside its domain (sqrt or ln of a \
     negative number, ln of 0, asin or acos beyond ±1) or not differentiable (sqrt at 0, e.g. of a vanishing \
     speed), a value overflows f64 (|v0|² does for |v0| above 1.3e154), or a parameter makes it undefined";

/// What the projection of the initial velocity (`h = 0` in a Newton
/// failure) says when it finds no consistent velocity: it is no step, so a
/// smaller step cannot help; the constraints may have no solution at `q₀`,
/// or `v₀` is too far from them for Newton.
const PROJECTION_CAUSES: &str = "before the first step, so no step size cures it: the constraints may have no \
     solution at q0 (a constraint nonlinear in v such as dot(x)^2 + dot(y)^2 + c with c > 0 has no real one), or v0 \
     is too far from the constraint surface for Newton; start from a v0 that nearly satisfies the constraints";

/// The message of [`StepError::Diverged`].
fn diverged_message(t: f64, h: f64, history: &NewtonHistory) -> String {
    if h == 0.0 {
        return format!(
            "Newton diverged in the projection of the initial velocity onto the constraints at t0 = {}, \
             {PROJECTION_CAUSES}; history: {history}",
            Sci(t)
        );
    }
    format!(
        "Newton diverged in the step from t = {} with h = {} (try a smaller step; if it diverges at every h, the \
         equations may not be differentiable at this state, e.g. sqrt(...) of a vanishing speed in a constraint); \
         history: {history}",
        Sci(t),
        Sci(h)
    )
}

/// The message of [`StepError::MaxIterations`].
fn max_iterations_message(t: f64, h: f64, history: &NewtonHistory) -> String {
    if h == 0.0 {
        return format!(
            "Newton did not converge in {} iterations in the projection of the initial velocity onto the \
             constraints at t0 = {}, {PROJECTION_CAUSES}; history: {history}",
            history.len(),
            Sci(t)
        );
    }
    format!(
        "Newton did not converge in {} iterations in the step from t = {} with h = {}; history: {history}",
        history.len(),
        Sci(t),
        Sci(h)
    )
}

/// The message of [`StepError::SingularMatrix`].
fn singular_message(t: f64, h: f64, detail: &str, history: &NewtonHistory) -> String {
    if h == 0.0 {
        return format!(
            "numerically singular saddle matrix at iteration {} in the projection of the initial velocity onto \
             the constraints at t0 = {}, before the first step, so no step size cures it: {detail}; history: {history}",
            history.len(),
            Sci(t)
        );
    }
    format!(
        "numerically singular Newton matrix at iteration {} in the step from t = {} with h = {}: {detail}; history: \
         {history}",
        history.len(),
        Sci(t),
        Sci(h)
    )
}

/// The message of [`StepError::NonFinite`]. Before the first step (`h = 0`)
/// it names the causes at the initial state. In a step (`h ≠ 0`) it names
/// both of its causes: the step's equations overflowed, and a smaller `h` is
/// the first thing to try, or a function of the declaration left its domain
/// (`sqrt` or `ln` of a negative number, a speed beyond a limit of `L`) or
/// was evaluated where its derivative is undefined (`sqrt(ψ²)` at `ψ = 0`),
/// which no `h` cures.
fn non_finite_message(t: f64, h: f64, stage: &str, history: &NewtonHistory) -> String {
    if h == 0.0 {
        let history = if history.is_empty() { String::new() } else { format!("; history: {history}") };
        return format!(
            "non-finite value in the {stage} at t0 = {}, before the first step: {INITIAL_STATE_CAUSES}{history}",
            Sci(t)
        );
    }
    format!(
        "non-finite value in the {stage} of the step from t = {} with h = {} (either the step's equations \
         overflowed f64: their terms grow with h and h², e.g. h²·d²L/dq² in the Newton matrix, so reduce h; or a \
         function of the declaration was evaluated outside its domain or where its derivative is undefined, e.g. \
         sqrt or ln of a negative number (a speed beyond a limit of L) or sqrt(psi^2) at psi = 0; if every h fails \
         at this state, check the state and the parameters); history: {history}",
        Sci(t),
        Sci(h)
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adaptive::AdaptiveError;
    use crate::plan::PlanError;

    /// Numbers a message compares print with every digit that tells them
    /// apart: far from t = 0 the two ends of an interval, and an energy
    /// near its start value, differ beyond the fourth digit.
    #[test]
    fn compared_numbers_print_every_digit_that_tells_them_apart() {
        let (t0, t_end) = (1e17, 1e17 + 16.0);
        let interval = AdaptiveError::InvalidInterval { t0, t_end, reason: "r" }.to_string();
        assert!(interval.contains("t0 = 1e17, t_end = 1.0000000000000002e17"), "{interval}");
        let outside = PlanError::TimeOutsideInterval { t: 1e17 + 32.0, t0, t_end }.to_string();
        assert!(outside.contains("t = 1.0000000000000003e17 lies outside the interval from t0 = 1e17"), "{outside}");
        let drift = StepError::EnergyDrift { t: 2.5, h: 0.1, energy0: 0.5, energy: 0.5000001, bound: 1e-8 }.to_string();
        assert!(drift.contains("E = 0.5000001 against E0 = 0.5 at"), "{drift}");
        // Every digit, but not hundreds of them.
        assert_eq!(Exact(1e300).to_string(), "1e300");
        assert_eq!(Exact(-2.5e-7).to_string(), "-2.5e-7");
        assert_eq!((Exact(0.0).to_string(), Exact(f64::NAN).to_string()), ("0".to_string(), "NaN".to_string()));
    }

    /// The other floats of the messages have one style, three decimals.
    #[test]
    fn other_floats_print_with_three_decimals() {
        let cold = StepError::InconsistentStart { t: 1e300, residual: 0.5, tolerance: 1e-12 }.to_string();
        assert!(cold.contains("from t = 1.000e300 starts cold"), "{cold}");
        let dependent = StepError::DependentConstraints { t: 2.0, condition: 1e17, limit: 1e14 }.to_string();
        assert!(dependent.contains("from t = 2.000e0: condition number"), "{dependent}");
    }
}
