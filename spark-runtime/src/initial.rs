//! Initial values: the consistency check of `(t₀, q₀, v₀)`, the projection of
//! `v₀` onto `{v : k(t₀,q₀,v) = 0}` in the kinetic-energy metric, and the
//! consistent acceleration and multiplier of the ψ-eliminated equations
//! (used for the stepper's cold-start guess and the multiplier observer).

use crate::error::{IterationRecord, NewtonHistory, StepError};
use crate::linalg::{column_scales, factor_in_place, solve_in_place, Lu};
use crate::step::cold_start::inconsistent_row;
use crate::system::{Matrix, NonholonomicSystem, StageJacobians, StageValues, Vector};

/// What to do when a constraint residual `|k_i(t₀, q₀, v₀)|` exceeds the
/// tolerance times the size of the terms it is computed from,
/// `max(1, Σ_j |K_ij v_j| + |k_i − (Kv)_i|)` with `K = ∂k/∂v`: relative for
/// terms above 1 and absolute below, so that a state consistent to
/// round-off passes at any velocity (the test of a step's cold start).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum ConsistencyPolicy {
    /// Return [`StepError::InconsistentInitialState`].
    Error {
        /// Largest accepted `|k_i(t₀,q₀,v₀)|` per unit of the size of its terms.
        tolerance: f64,
    },
    /// Replace `v₀` by the closest consistent velocity in the kinetic-energy
    /// metric `∇²_vv L(t₀,q₀,v₀)`.
    Project {
        /// Largest accepted `|k_i|` per unit of the size of its terms before
        /// projecting.
        tolerance: f64,
    },
}

impl ConsistencyPolicy {
    /// The tolerance of either policy: the largest accepted `|k_i|` per
    /// unit of the size of its terms.
    pub fn tolerance(self) -> f64 {
        match self {
            ConsistencyPolicy::Error { tolerance } | ConsistencyPolicy::Project { tolerance } => tolerance,
        }
    }
}

impl Default for ConsistencyPolicy {
    fn default() -> Self {
        ConsistencyPolicy::Error { tolerance: 1e-12 }
    }
}

/// Why a saddle-point solve failed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum SaddleFailure {
    /// A pivot fell below `64 ε` times its column's largest entry: of the
    /// whole saddle matrix in [`SaddleLu`], of `W` or of the Schur complement
    /// `K W⁻¹ Kᵀ` in [`saddle_solve_in_place`].
    Singular {
        /// Column of the factored matrix.
        column: usize,
        /// The pivot.
        pivot: f64,
        /// The column's largest magnitude.
        scale: f64,
    },
    /// The matrix or the solution is not finite.
    NonFinite,
}

/// LU factors, with partial pivoting over all rows, of the saddle-point
/// matrix `[[A, Kᵀ],[K, 0]]` (`A` is `N × N`, `K` is `M × N`), stored
/// column-major on the heap.
///
/// The whole matrix is factored, not `A` first and then the Schur
/// complement `K A⁻¹ Kᵀ`: it succeeds whenever the saddle matrix is regular,
/// also when `A` itself is singular (a coordinate without mass that the
/// constraints tie to others). The storage, `(N + M)²` numbers, is
/// allocated once per [`SaddleLu::new`], so no `N × N` matrix goes on the
/// stack.
pub(crate) struct SaddleLu<const N: usize, const M: usize> {
    lu: Vec<f64>,
    perm: Vec<usize>,
    scale: Vec<f64>,
}

impl<const N: usize, const M: usize> SaddleLu<N, M> {
    const DIM: usize = N + M;

    pub(crate) fn new() -> Self {
        SaddleLu { lu: vec![0.0; Self::DIM * Self::DIM], perm: vec![0; Self::DIM], scale: vec![0.0; Self::DIM] }
    }

    /// Assembles `[[a, kᵀ],[k, 0]]` and factors it (`P S = L U`). A pivot
    /// below `64 ε` times its column's largest entry counts as singular,
    /// as in the stepper's factorization.
    pub(crate) fn factor(&mut self, a: &Matrix<N, N>, k: &Matrix<M, N>) -> Result<(), SaddleFailure> {
        let d = Self::DIM;
        let lu = &mut self.lu[..d * d];
        for j in 0..N {
            let col = &mut lu[j * d..(j + 1) * d];
            col[..N].copy_from_slice(&a.as_slice()[j * N..(j + 1) * N]);
            for r in 0..M {
                col[N + r] = k[(r, j)];
            }
        }
        for r in 0..M {
            let col = &mut lu[(N + r) * d..(N + r + 1) * d];
            for j in 0..N {
                col[j] = k[(r, j)];
            }
            col[N..].fill(0.0);
        }
        if !lu.iter().all(|x| x.is_finite()) {
            return Err(SaddleFailure::NonFinite);
        }
        for (j, s) in self.scale.iter_mut().enumerate() {
            *s = lu[j * d..(j + 1) * d].iter().fold(0.0, |m: f64, x| m.max(x.abs()));
        }
        for c in 0..d {
            let col_c = &lu[c * d..(c + 1) * d];
            let (mut p, mut best) = (c, col_c[c].abs());
            for (i, x) in col_c.iter().enumerate().skip(c + 1) {
                if x.abs() > best {
                    (p, best) = (i, x.abs());
                }
            }
            self.perm[c] = p;
            if best <= 64.0 * f64::EPSILON * self.scale[c] {
                return Err(SaddleFailure::Singular { column: c, pivot: best, scale: self.scale[c] });
            }
            if p != c {
                for j in 0..d {
                    lu.swap(j * d + c, j * d + p);
                }
            }
            let (left, right) = lu.split_at_mut((c + 1) * d);
            let col_c = &mut left[c * d..];
            let inv = 1.0 / col_c[c];
            for x in &mut col_c[c + 1..] {
                *x *= inv;
            }
            let lower = &col_c[c + 1..];
            for col_j in right.chunks_exact_mut(d) {
                let ucj = col_j[c];
                if ucj != 0.0 {
                    for (x, l) in col_j[c + 1..].iter_mut().zip(lower) {
                        *x -= l * ucj;
                    }
                }
            }
        }
        Ok(())
    }

    /// Solves `[[A, Kᵀ],[K, 0]] [x; y] = [r1; r2]` with the factors of the
    /// last successful [`factor`](Self::factor).
    pub(crate) fn solve(&self, r1: &Vector<N>, r2: &Vector<M>) -> Result<(Vector<N>, Vector<M>), SaddleFailure> {
        let d = Self::DIM;
        let lu = &self.lu[..d * d];
        let mut b: Vec<f64> = r1.iter().chain(r2.iter()).copied().collect();
        for (c, &p) in self.perm.iter().enumerate() {
            b.swap(c, p);
        }
        for j in 0..d {
            let bj = b[j];
            for (x, l) in b[j + 1..].iter_mut().zip(&lu[j * d + j + 1..(j + 1) * d]) {
                *x -= l * bj;
            }
        }
        for j in (0..d).rev() {
            b[j] /= lu[j * d + j];
            let bj = b[j];
            for (x, u) in b[..j].iter_mut().zip(&lu[j * d..j * d + j]) {
                *x -= u * bj;
            }
        }
        if !b.iter().all(|x| x.is_finite()) {
            return Err(SaddleFailure::NonFinite);
        }
        Ok((Vector::<N>::from_column_slice(&b[..N]), Vector::<M>::from_column_slice(&b[N..])))
    }
}

/// `a x` for an `N × N` column-major matrix `a` given as a slice.
fn mul_columns<const N: usize>(a: &[f64], x: &Vector<N>) -> Vector<N> {
    let mut y = Vector::<N>::zeros();
    for (j, &xj) in x.iter().enumerate() {
        if xj != 0.0 {
            for (yi, aij) in y.iter_mut().zip(&a[j * N..(j + 1) * N]) {
                *yi += aij * xj;
            }
        }
    }
    y
}

/// Solves `[[W, Kᵀ],[K, 0]] [x; y] = [r1; r2]` by the Schur complement
/// `K W⁻¹ Kᵀ`, factoring `w` in place (it holds the LU factors afterwards),
/// without allocating: the stepper's cold start passes its heap stage
/// Jacobian work storage, so no `N × N` matrix goes on the stack. Needs `W`
/// regular; [`SaddleLu`] needs only the saddle matrix regular.
pub(crate) fn saddle_solve_in_place<const N: usize, const M: usize>(
    w: &mut Matrix<N, N>,
    k: &Matrix<M, N>,
    r1: &Vector<N>,
    r2: &Vector<M>,
) -> Result<(Vector<N>, Vector<M>), SaddleFailure> {
    let scale = column_scales::<N>(w.as_slice());
    let mut perm = [0usize; N];
    factor_in_place::<N>(w.as_mut_slice(), &mut perm, &scale, &[N]).map_err(|e| SaddleFailure::Singular {
        column: e.column,
        pivot: e.pivot,
        scale: scale[e.column],
    })?;
    let wlu = |b: &mut Vector<N>| solve_in_place::<N>(w.as_slice(), &perm, b.as_mut_slice());
    let mut winv_r1 = *r1;
    wlu(&mut winv_r1);
    if M == 0 {
        return Ok((winv_r1, Vector::<M>::zeros()));
    }
    let mut winv_kt = k.transpose();
    for mut col in winv_kt.column_iter_mut() {
        let mut c: Vector<N> = col.clone_owned();
        wlu(&mut c);
        col.copy_from(&c);
    }
    let schur = k * winv_kt;
    let mut slu = Lu::<M>::new();
    slu.factor(&schur).map_err(|e| SaddleFailure::Singular {
        column: e.column,
        pivot: e.pivot,
        scale: schur.column(e.column).amax(),
    })?;
    let mut y = k * winv_r1 - r2;
    slu.solve_in_place(&mut y);
    let x = winv_r1 - winv_kt * y;
    if x.iter().chain(y.iter()).all(|v| v.is_finite()) {
        Ok((x, y))
    } else {
        Err(SaddleFailure::NonFinite)
    }
}

/// The acceleration `a = v̇` and multiplier `ψ` of the constrained equations
/// at `(t, q, v)`, from
/// `W a + Kᵀψ = ∇_q L − (∂p/∂q) v − ∂p/∂t` and `K a = −(k_q v + k_t)`.
///
/// The saddle-point matrix `[[W, Kᵀ],[K, 0]]` is factored as a whole, so a
/// singular mass matrix `W` is fine as long as the saddle matrix is regular
/// (the condition under which the equations have a unique solution).
/// Returns `None` when it is singular. The Jacobians and the factors live
/// on the heap (allocated once per call), so the stack use is `O(N)`.
pub fn consistent_acceleration<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
) -> Option<(Vector<N>, Vector<M>)>
where
    Sys: NonholonomicSystem<N, M>,
{
    let (mut vals, mut jac) = (StageValues::zeros(), StageJacobians::boxed_zeros());
    let (r1, r2) = acceleration_rhs(sys, t, q, v, &mut vals, &mut jac);
    let mut lu = SaddleLu::<N, M>::new();
    lu.factor(&jac.mass, &jac.constraint_v).ok()?;
    lu.solve(&r1, &r2).ok()
}

/// Evaluates the stage Jacobians at `(t, q, v, ψ = 0)` into `vals`, `jac`
/// and returns the right-hand sides `(∇_q L − (∂p/∂q) v − ∂p/∂t + f,
/// −(k_q v + k_t))` of the consistent-acceleration equations.
fn acceleration_rhs<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
    vals: &mut StageValues<N, M>,
    jac: &mut StageJacobians<N, M>,
) -> (Vector<N>, Vector<M>)
where
    Sys: NonholonomicSystem<N, M>,
{
    sys.stage_jacobians_into(t, q, v, &Vector::<M>::zeros(), vals, jac);
    let (mut r1, mut r2) = (vals.force - jac.momentum_q * v, -(jac.constraint_q * v));
    if !Sys::STRUCTURE.autonomous() {
        let td = sys.time_derivatives(t, q, v);
        r1 -= td.momentum_t;
        r2 -= td.constraint_t;
    }
    if Sys::HAS_FORCING {
        r1 += sys.external_force(t, q, v);
    }
    // A non-ideal force N(ψ) is left out: this is a starting guess and an
    // observer of the ideal multiplier; Newton on the step equations
    // accounts for it.
    (r1, r2)
}

/// [`consistent_acceleration`] with caller-provided scratch storage for the
/// stage values and Jacobians (overwritten; `jac.mass` ends up holding LU
/// factors), by the Schur complement through `W` (allocation-free; `None`
/// also when `W` is singular). With heap storage no `N × N` matrix goes on
/// the stack: the stepper's cold start uses its own work storage.
pub(crate) fn consistent_acceleration_in<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
    vals: &mut StageValues<N, M>,
    jac: &mut StageJacobians<N, M>,
) -> Option<(Vector<N>, Vector<M>)>
where
    Sys: NonholonomicSystem<N, M>,
{
    let (r1, r2) = acceleration_rhs(sys, t, q, v, vals, jac);
    saddle_solve_in_place(&mut jac.mass, &jac.constraint_v, &r1, &r2).ok()
}

/// Checks `(t₀, q₀, v₀)` against the constraints and, by `policy`, returns
/// `v₀` unchanged, returns the projected velocity, or fails.
///
/// At the state it returns it also checks that the equations of motion are
/// defined and determine the accelerations, so that a run from a state
/// where no step can succeed is refused up front with the cause instead of
/// failing in its first step: the energy, the Lagrangian, the momentum, the
/// force, the mass matrix and the constraint rows must be finite
/// ([`StepError::NonFiniteInitialValue`] names the first that is not), and
/// the saddle matrix `[[W, Kᵀ],[K, 0]]` must be regular
/// ([`StepError::SingularInitialState`], naming the coordinate or
/// constraint of the singular column and the parameters that are zero).
/// The check costs one evaluation of the stage Jacobians and one LU
/// factorization of the `(N + M)²` saddle matrix on the heap, once per run.
///
/// # The projection
/// With `W = ∇²_vv L(t₀, q₀, v₀)` and `K(v) = ∂k/∂v(t₀, q₀, v)`, the
/// projected velocity `v` and a multiplier `λ` solve the first-order
/// conditions of minimizing `½(v − v₀)ᵀ W (v − v₀)` subject to
/// `k(t₀, q₀, v) = 0`:
///
/// ```text
/// W (v − v₀) + K(v)ᵀ λ = 0,    k(t₀, q₀, v) = 0,
/// ```
///
/// by Newton's method from `(v₀, 0)`, whose matrix is the saddle matrix
/// `[[W + ∂(K(v)ᵀλ)/∂v, K(v)ᵀ],[K(v), 0]]`, factored as a whole (LU with
/// partial pivoting, on the heap). For `k` linear or affine in `v` one
/// Newton step solves the conditions exactly (a second confirms it), and the
/// solution is unique whenever `[[W, Kᵀ],[K, 0]]` is regular, also when `W`
/// is singular (a coordinate without mass, such as the mobile robot's
/// position with `m = 0`; a step from there is refused all the same, since
/// the integrators need a regular `W`: [`StepError::SingularInitialState`]).
/// For a positive semidefinite `W` regularity means
/// that `W` is positive definite on `ker K`; since the difference of two
/// consistent velocities lies in `ker K`, `(v − v₀)ᵀW(v − v₀)` is then a
/// norm on the feasible set, and `v` is the closest consistent velocity in
/// it (the kinetic-energy metric). For `k` nonlinear in `v`, Newton
/// converges from a `v₀` near the constraint surface.
///
/// The Jacobians and factors live on the heap (allocated once per call), so
/// the stack use is `O(N)` for systems whose `stage_jacobians_into` writes
/// in place (generated ones do).
pub fn consistent_velocity<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
    policy: ConsistencyPolicy,
) -> Result<Vector<N>, StepError>
where
    Sys: NonholonomicSystem<N, M>,
{
    if !t0.is_finite() || q0.iter().chain(v0.iter()).any(|x| !x.is_finite()) {
        return Err(StepError::InvalidStep { t: t0, h: 0.0, reason: "initial state is not finite" });
    }
    let k0 = sys.constraint(t0, q0, v0);
    // A NaN residual would otherwise compare as "inconsistent" and blame the
    // velocity; the cause is a non-finite parameter or constraint value.
    if k0.iter().any(|x| !x.is_finite()) {
        return Err(StepError::NonFinite { t: t0, h: 0.0, stage: "constraint k(t0, q0, v0)", history: Box::default() });
    }
    let rows = sys.constraint_v(t0, q0, v0);
    if rows.iter().any(|x| !x.is_finite()) {
        // The rows scale the test: `check_start` names the quantity.
        check_start(sys, t0, q0, v0)?;
    }
    let v = match inconsistent_row(&k0, &rows, v0, policy.tolerance()) {
        None => *v0,
        Some(allowed) => match policy {
            ConsistencyPolicy::Error { .. } => {
                return Err(StepError::InconsistentInitialState { residual: k0.amax(), tolerance: allowed })
            }
            ConsistencyPolicy::Project { .. } => project(sys, t0, q0, v0)?,
        },
    };
    check_start(sys, t0, q0, &v)?;
    Ok(v)
}

/// The first entry of `x` that is not finite.
fn first_non_finite(x: &[f64]) -> Option<f64> {
    x.iter().copied().find(|x| !x.is_finite())
}

/// The checks of [`consistent_velocity`] at the state a run starts from:
/// the equations of motion are finite there, and the saddle matrix
/// `[[W, Kᵀ],[K, 0]]` is regular.
pub(crate) fn check_start<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
) -> Result<(), StepError>
where
    Sys: NonholonomicSystem<N, M>,
{
    let non_finite = |quantity, value| StepError::NonFiniteInitialValue { t: t0, quantity, value };
    let energy = sys.energy(t0, q0, v0);
    if !energy.is_finite() {
        return Err(non_finite("energy E = dL/dv·v − L", energy));
    }
    let lagrangian = sys.lagrangian(t0, q0, v0);
    if !lagrangian.is_finite() {
        return Err(non_finite("Lagrangian L", lagrangian));
    }
    let (mut vals, mut jac) = (StageValues::<N, M>::zeros(), StageJacobians::<N, M>::boxed_zeros());
    sys.stage_jacobians_into(t0, q0, v0, &Vector::<M>::zeros(), &mut vals, &mut jac);
    let quantities: [(&'static str, &[f64]); 4] = [
        ("momentum dL/dv", vals.momentum.as_slice()),
        ("force dL/dq", vals.force.as_slice()),
        ("mass matrix d²L/dv²", jac.mass.as_slice()),
        ("constraint Jacobian dk/dv", jac.constraint_v.as_slice()),
    ];
    for (quantity, x) in quantities {
        if let Some(value) = first_non_finite(x) {
            return Err(non_finite(quantity, value));
        }
    }
    let mut lu = SaddleLu::<N, M>::new();
    match lu.factor(&jac.mass, &jac.constraint_v) {
        Ok(()) => Ok(()),
        Err(SaddleFailure::Singular { column, pivot, scale }) => Err(StepError::SingularInitialState {
            t: t0,
            detail: match saddle_out_of_range(&jac.mass, &jac.constraint_v, q0, v0) {
                Some(detail) => detail,
                None => singular_start_detail(sys, column, pivot, scale),
            }
            .into(),
        }),
        // Not reached: the entries were checked above.
        Err(SaddleFailure::NonFinite) => Err(non_finite("mass matrix d²L/dv²", f64::NAN)),
    }
}

/// What [`StepError::SingularInitialState`] says when the saddle matrix
/// `[[W, Kᵀ],[K, 0]]` is singular to working precision as given but regular
/// once its rows and columns are scaled to unit size: its entries lie too
/// far apart for elimination in double precision (a velocity of 1e150
/// against a constraint quadratic in it), so the cause is the magnitude of
/// the state, not a mass or a constraint. `None` for a matrix singular at
/// any scale. The scaling keeps the saddle form: `W` divided by its
/// largest entry, each constraint row by its largest entry and each
/// multiplier column by that entry over `W`'s (so `Kᵀ` scales as `K`),
/// which changes neither regularity nor the solution's meaning.
fn saddle_out_of_range<const N: usize, const M: usize>(
    w: &Matrix<N, N>,
    k: &Matrix<M, N>,
    q0: &Vector<N>,
    v0: &Vector<N>,
) -> Option<String> {
    use crate::error::Sci;
    let d = N + M;
    let mut a = vec![0.0; d * d];
    for j in 0..N {
        for i in 0..N {
            a[j * d + i] = w[(i, j)];
        }
        for r in 0..M {
            a[j * d + N + r] = k[(r, j)];
            a[(N + r) * d + j] = k[(r, j)];
        }
    }
    let (smallest, largest) = crate::linalg::magnitude_range(&a);
    let w_largest = w.amax();
    if w_largest == 0.0 || crate::linalg::regular(&a, d) {
        return None;
    }
    let mut scaled = a.clone();
    for j in 0..N {
        for i in 0..N {
            scaled[j * d + i] /= w_largest;
        }
    }
    for r in 0..M {
        let k_largest = k.row(r).amax();
        if k_largest == 0.0 {
            return None;
        }
        for j in 0..N {
            scaled[j * d + N + r] /= k_largest;
            scaled[(N + r) * d + j] /= k_largest;
        }
    }
    if !crate::linalg::regular(&scaled, d) {
        return None;
    }
    Some(format!(
        "the magnitudes at the initial state are out of the range double precision resolves: the saddle matrix \
         [[W, K^T],[K, 0]] of the mass matrix W = d²L/dv² and the constraint rows K = dk/dv is regular once its \
         rows and columns are scaled to unit size, but its entries span {} to {}, too far apart for elimination in \
         double precision, so it is singular to working precision as given (max |q0| = {}, max |v0| = {}), and so \
         is a step's Newton matrix, which holds the same entries. Rescale the units so that q0 and v0 are nearer 1, \
         or start from a smaller state.",
        Sci(smallest),
        Sci(largest),
        Sci(q0.amax()),
        Sci(v0.amax())
    ))
}

/// What [`StepError::SingularInitialState`] says about the singular column
/// `column` of the saddle matrix: its coordinate or constraint, the pivot,
/// and the parameters that are zero (the usual cause).
fn singular_start_detail<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    column: usize,
    pivot: f64,
    scale: f64,
) -> String
where
    Sys: NonholonomicSystem<N, M>,
{
    use crate::error::Sci;
    let source = Sys::SOURCE;
    let suspects = zero_parameters(sys);
    let pivot = format!("pivot {} is below 64 eps x its column's largest entry {}", Sci(pivot), Sci(scale));
    let saddle = "the accelerations are not determined there: the saddle matrix [[W, K^T],[K, 0]] of the mass \
                  matrix W = d²L/dv² and the constraint rows K = dk/dv is singular; ";
    if column < N {
        let name = source.coordinates.get(column).map_or_else(|| format!("{column}"), |c| format!("`{c}`"));
        format!(
            "{saddle}the mass matrix d²L/dv² is singular on the velocities the constraints leave free, at the \
             velocity of coordinate {name} (column {column}: {pivot}). Likely a parameter that makes it degenerate, \
             such as a zero mass or inertia, or a velocity that L does not contain.{suspects} Give the mass matrix \
             full rank on the motions the constraints allow."
        )
    } else {
        format!(
            "{saddle}the constraint rows dk/dv are dependent or vanish, or the mass matrix d²L/dv² is singular on \
             the velocities the constraints leave free (column of constraint {} of {M}: {pivot}).{suspects} Start \
             where the constraints are independent, remove a redundant constraint, or give the mass matrix full \
             rank.",
            column - N + 1
        )
    }
}

/// " Parameters that are 0 here: …." naming the parameters of `sys` that
/// are 0 (the usual cause of a singular mass matrix), or nothing.
fn zero_parameters<Sys, const N: usize, const M: usize>(sys: &Sys) -> String
where
    Sys: NonholonomicSystem<N, M>,
{
    let zero: Vec<&str> = Sys::SOURCE
        .parameters
        .iter()
        .zip(sys.parameter_values())
        .filter(|(_, value)| *value == 0.0)
        .map(|(name, _)| *name)
        .collect();
    if zero.is_empty() {
        String::new()
    } else {
        format!(" Parameters that are 0 here: {}.", zero.join(", "))
    }
}

/// What [`StepError::SingularInitialState`] says when the saddle matrix is
/// regular but the mass matrix `W` is singular at the velocity of
/// coordinate `column` (a cold start's check): the constraints determine
/// the accelerations, but not a step.
pub(crate) fn singular_mass_detail<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    column: usize,
    pivot: f64,
    scale: f64,
) -> String
where
    Sys: NonholonomicSystem<N, M>,
{
    use crate::error::Sci;
    let name = Sys::SOURCE.coordinates.get(column).map_or_else(|| format!("{column}"), |c| format!("`{c}`"));
    format!(
        "the mass matrix W = d²L/dv² is singular at the velocity of coordinate {name} (column {column}: pivot {} is \
         below 64 eps x its column's largest entry {}), and the constraints fix that velocity: the saddle matrix \
         [[W, K^T],[K, 0]] is regular and determines the accelerations, but the integrators need a regular \
         Lagrangian (W nonsingular, paper §2). Along the velocities W leaves without inertia the momentum \
         equations of a step at its stages and at its end are dependent, so Newton fails or lands on a wrong step. \
         Likely a zero mass or inertia parameter, or a velocity that L holds only linearly or in a combination \
         such as (dot(x) + dot(y))^2.{} Give the mass matrix full rank.",
        Sci(pivot),
        Sci(scale),
        zero_parameters(sys)
    )
}

/// The projection of [`consistent_velocity`].
fn project<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    t0: f64,
    q0: &Vector<N>,
    v0: &Vector<N>,
) -> Result<Vector<N>, StepError>
where
    Sys: NonholonomicSystem<N, M>,
{
    let (mut vals, mut jac) = (StageValues::<N, M>::zeros(), StageJacobians::<N, M>::boxed_zeros());
    // W = ∇²_vv L(t0, q0, v0), kept for the whole iteration.
    let mut w0 = vec![0.0; N * N];
    let mut lu = SaddleLu::<N, M>::new();
    let mut v = *v0;
    let mut lambda = Vector::<M>::zeros();
    let mut history = NewtonHistory::default();
    let mut prev = f64::NAN;
    let non_finite = |history: NewtonHistory| StepError::NonFinite {
        t: t0,
        h: 0.0,
        stage: "projection of the initial velocity onto the constraints (at q0 and the velocities it visits)",
        history: Box::new(history),
    };
    for iteration in 0..crate::error::HISTORY_CAPACITY {
        sys.stage_jacobians_into(t0, q0, &v, &lambda, &mut vals, &mut jac);
        if iteration == 0 {
            w0.copy_from_slice(jac.mass.as_slice());
        }
        // Residual: W(v − v0) − R(λ) with R = −Kᵀλ, and k(v).
        let g1 = mul_columns(&w0, &(v - v0)) - vals.constraint_force;
        let g2 = vals.constraint;
        let res = g1.amax().max(g2.amax());
        // Jacobian [[W − ∂R/∂v, Kᵀ],[K, 0]]: W − ∂R/∂v is formed in place
        // of ∂R/∂v (heap storage, rewritten by the next evaluation).
        for (x, w) in jac.constraint_force_v.as_mut_slice().iter_mut().zip(&w0) {
            *x = w - *x;
        }
        let step = lu.factor(&jac.constraint_force_v, &jac.constraint_v).and_then(|()| lu.solve(&g1, &g2));
        let (dv, dl) = match step {
            Ok(x) => x,
            Err(SaddleFailure::Singular { column, pivot, scale }) => {
                // At the first iterate (v = v0, λ = 0, so ∂R/∂v = 0) this is
                // the saddle matrix [[W, Kᵀ],[K, 0]] of the initial state,
                // which `check_start` factors too: its error names the
                // coordinate or constraint of the singular column and the
                // parameters that are 0, where the message below can only
                // give a column number.
                if iteration == 0 {
                    check_start(sys, t0, q0, v0)?;
                }
                history.push(IterationRecord { residual: res, update: f64::NAN, rate: f64::NAN });
                let which = if column < N {
                    match Sys::SOURCE.coordinates.get(column) {
                        Some(name) => format!("velocity column {column} (coordinate `{name}`)"),
                        None => format!("velocity column {column}"),
                    }
                } else {
                    format!("multiplier column {} (constraint {} of {M})", column - N, column - N + 1)
                };
                return Err(StepError::SingularMatrix {
                    t: t0,
                    h: 0.0,
                    detail: format!(
                        "{which} of the saddle matrix \
                         [[W − ∂R/∂v, Kᵀ],[K, 0]] at (t0, q0, v): pivot {pivot:.3e} is below 64 eps x its largest \
                         entry {scale:.3e}. Either the constraint rows K = ∂k/∂v are dependent or vanish there, or \
                         the mass matrix W = ∇²_vv L is singular on the velocities the constraints leave free \
                         (ker K): is the mass or inertia of a coordinate that no constraint ties to the others \
                         zero? For constraints nonlinear in v, start from a v0 near the constraint surface."
                    )
                    .into(),
                    history: Box::new(history),
                });
            }
            Err(SaddleFailure::NonFinite) => {
                history.push(IterationRecord { residual: res, update: f64::NAN, rate: f64::NAN });
                return Err(non_finite(history));
            }
        };
        v -= dv;
        lambda -= dl;
        let upd = crate::linalg::scaled_update_norm(&dv, &v);
        let rate = upd / prev;
        history.push(IterationRecord { residual: res, update: upd, rate });
        if !upd.is_finite() {
            return Err(non_finite(history));
        }
        if upd <= 4.0 * f64::EPSILON || (rate < 1.0 && rate * upd <= 4.0 * f64::EPSILON) {
            return Ok(v);
        }
        if rate >= 1.0 && history.len() > 2 {
            return Err(StepError::Diverged { t: t0, h: 0.0, history: Box::new(history) });
        }
        prev = upd;
    }
    Err(StepError::MaxIterations { t: t0, h: 0.0, history: Box::new(history) })
}

/// The kinetic energy of a state is not positive on the velocities the
/// constraints allow ([`check_positive_kinetic_energy`]).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error(
    "the kinetic energy is not positive at the initial state (t0 = {}): the mass matrix W = d²L/dv² has {negative} \
     direction{} of negative kinetic energy among the velocities the constraints allow, so the equations describe \
     no mechanical motion (a negative mass or inertia?).{}",
    crate::error::Sci(*t),
    if *negative == 1 { "" } else { "s" },
    suspects(parameters)
)]
pub struct IndefiniteKineticEnergy {
    /// The initial time.
    pub t: f64,
    /// How many independent admissible velocities have `vᵀWv < 0`.
    pub negative: usize,
    /// The parameters that are negative, with their values (the usual cause).
    pub parameters: Vec<(String, f64)>,
}

fn suspects(parameters: &[(String, f64)]) -> String {
    if parameters.is_empty() {
        return " Give W positive definite on those velocities.".into();
    }
    let each: Vec<String> = parameters.iter().map(|(n, v)| format!("{n} = {}", crate::error::Sci(*v))).collect();
    format!(" Parameters that are negative here: {}; give them physical (positive) values.", each.join(", "))
}

/// Checks that the kinetic energy is positive at `(t, q, v)` on the
/// velocities the constraints allow: the mass matrix `W = ∇²_vv L` is
/// positive definite on `ker K`, `K = ∂k/∂v`. A negative mass or inertia
/// makes it indefinite (or negative definite) there; the step equations
/// are still regular, so a run would go on and return a motion no
/// mechanical system has. [`consistent_velocity`] does not require it
/// (a Lagrangian need not be mechanical); the front ends, where a user
/// types parameter values (`spark run --param`, the Python package), call
/// it after that check.
///
/// It counts the negative eigenvalues of the saddle matrix
/// `[[W, Kᵀ],[K, 0]]`: with `K` of full row rank `M` (which the regular
/// saddle matrix of [`consistent_velocity`] implies), that matrix has `M`
/// negative eigenvalues plus as many as `W` restricted to `ker K` (Haynsworth
/// inertia additivity). One symmetric eigendecomposition of size `N + M`
/// on the heap, once per run.
pub fn check_positive_kinetic_energy<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    t: f64,
    q: &Vector<N>,
    v: &Vector<N>,
) -> Result<(), IndefiniteKineticEnergy>
where
    Sys: NonholonomicSystem<N, M>,
{
    let (mut vals, mut jac) = (StageValues::<N, M>::zeros(), StageJacobians::<N, M>::boxed_zeros());
    sys.stage_jacobians_into(t, q, v, &Vector::<M>::zeros(), &mut vals, &mut jac);
    let mut saddle = nalgebra::DMatrix::<f64>::zeros(N + M, N + M);
    for i in 0..N {
        for j in 0..N {
            saddle[(i, j)] = 0.5 * (jac.mass[(i, j)] + jac.mass[(j, i)]);
        }
        for r in 0..M {
            saddle[(N + r, i)] = jac.constraint_v[(r, i)];
            saddle[(i, N + r)] = jac.constraint_v[(r, i)];
        }
    }
    if saddle.iter().any(|x| !x.is_finite()) {
        // `consistent_velocity` names the quantity that is not finite.
        return Ok(());
    }
    let eigenvalues = nalgebra::SymmetricEigen::new(saddle).eigenvalues;
    let largest = eigenvalues.amax();
    // Eigenvalues within round-off of 0 belong to a singular saddle matrix,
    // which `consistent_velocity` refuses with its cause.
    let negative = eigenvalues.iter().filter(|&&x| x < -1e-12 * largest).count();
    if negative <= M {
        return Ok(());
    }
    let parameters = Sys::SOURCE
        .parameters
        .iter()
        .zip(sys.parameter_values())
        .filter(|(_, value)| *value < 0.0)
        .map(|(name, value)| (name.to_string(), value))
        .collect();
    Err(IndefiniteKineticEnergy { t, negative: negative - M, parameters })
}
