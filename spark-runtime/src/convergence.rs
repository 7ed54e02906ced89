//! Acceptance tests shared by the Newton solves and the step: the scaled
//! update norm (which must see NaN), the contraction monitor behind
//! Newton's stopping rule, and the energy guard (which refuses a step that
//! violates a first integral the structure facts guarantee).

use crate::error::StepError;
use crate::linalg::{column_scales, factor_in_place, solve_in_place, Lu};
use crate::system::{ConstraintForm, Matrix, NonholonomicSystem, StageJacobians, StageValues, Vector};
use crate::State;

/// `max_i |Δz_i| / (1 + |z_i|)`, NaN as soon as any component is NaN.
///
/// `f64::max` returns the other operand when one is NaN, so a fold with it
/// would hide a NaN update and a solve could look converged; here a NaN
/// (or infinite) update is reported by the caller at the iteration where it
/// appears.
pub(crate) fn scaled_update_norm<const D: usize>(update: &Vector<D>, z: &Vector<D>) -> f64 {
    let mut norm = 0.0f64;
    for (d, x) in update.iter().zip(z.iter()) {
        let r = d.abs() / (1.0 + x.abs());
        if r.is_nan() {
            return f64::NAN;
        }
        norm = norm.max(r);
    }
    norm
}

/// What the updates computed with one set of Newton factors tell about
/// their contraction, and the stopping rule built on it.
///
/// The ratio `ρ_j = ‖Δz_j‖/‖Δz_{j−1}‖` of consecutive updates on the same
/// factors estimates their contraction `θ`, but the first ratio on new
/// factors is not evidence: the first update removes the error components
/// the factors solve exactly (unknowns that enter linearly, the multipliers;
/// for the first update on fresh factors everything to first order), so
/// `ρ₂` measures what is left of a different error than the one the next
/// update faces. Measured on the McLachlan–Perlmutter particles from a cold
/// start (Lobatto IIIA-B-D s = 2, h = 0.1, simplified Newton): `ρ₂ = 1.8e-7`
/// against `θ = 3.5e-3`. A rate is *earned* from the third update on: the
/// largest ratio on these factors so far, so that no fast ratio can stand
/// for the contraction alone. The ratios of one linear iteration need not
/// decrease: on the stage-decoupled matrix (McLachlan–Perlmutter particles,
/// Gauss s = 2, h = 0.2) they ran 6.2e-3, 1.5e-3, 4.4e-2, 9.2e-3, 3.3e-3, and
/// the larger of the last two alone left an error 5× the tolerance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Contraction {
    /// Updates computed with the current factors.
    updates: usize,
    /// The latest of them.
    last: f64,
    /// `ρ` of the latest two (NaN with fewer than two).
    rate: f64,
    /// `ρ` of the two before (NaN with fewer than three updates).
    prev_rate: f64,
    /// The largest `ρ` on these factors (NaN with fewer than two updates).
    max_rate: f64,
}

impl Contraction {
    /// No update on the current factors yet.
    pub(crate) const FRESH: Self =
        Contraction { updates: 0, last: f64::NAN, rate: f64::NAN, prev_rate: f64::NAN, max_rate: f64::NAN };

    /// Records the scaled norm of an update computed with the current
    /// factors; returns its ratio to the previous one on them (NaN for the
    /// first).
    pub(crate) fn record(&mut self, update: f64) -> f64 {
        self.prev_rate = self.rate;
        self.rate = update / self.last;
        // NaN propagates: an iteration that produced one never earns a rate.
        self.max_rate = if self.updates <= 1 || self.rate.is_nan() { self.rate } else { self.max_rate.max(self.rate) };
        self.last = update;
        self.updates += 1;
        self.rate
    }

    /// The earned contraction estimate: the largest ratio on these factors,
    /// once three updates on them exist (NaN before).
    pub(crate) fn earned(&self) -> f64 {
        if self.updates >= 3 {
            self.max_rate
        } else {
            f64::NAN
        }
    }

    /// The contraction per update over the last two, `√(ρ_j ρ_{j−1})`, once
    /// three updates on these factors exist (NaN before): one fast or slow
    /// ratio does not decide it, and the alternating ratios of an iteration
    /// with a complex pair of error modes average out.
    pub(crate) fn sustained(&self) -> f64 {
        if self.updates >= 3 {
            (self.rate * self.prev_rate).sqrt()
        } else {
            f64::NAN
        }
    }

    /// Newton's stopping rule for the latest update `update`: within the
    /// tolerance itself (the error left is `θ/(1−θ)·update`, below it for
    /// `θ ≤ ½`), or the remaining error `θ/(1−θ)·update` estimated with an
    /// earned rate `θ < 1` within it. Written so that NaN never converges.
    pub(crate) fn converged(&self, update: f64, tolerance: f64) -> bool {
        let theta = self.earned();
        update <= tolerance || (theta < 1.0 && update * theta / (1.0 - theta) <= tolerance)
    }
}

/// Largest condition number `κ₁(K W⁻¹ Kᵀ)` a cold start accepts: the
/// reciprocal of the relative pivot size (`64 ε`) below which the LU
/// factorizations of this crate call a matrix singular. Beyond it the
/// multipliers have no correct digit and a step's constraint force is
/// round-off amplified.
pub(crate) const CONSTRAINT_CONDITION_LIMIT: f64 = 1.0 / (64.0 * f64::EPSILON);

/// The checks of a step that starts cold, at a state no earlier step of the
/// stepper ended at: `(t, q, v)` satisfies the constraints, and their rows
/// are independent there.
///
/// - `|k_i(t,q,v)| ≤ tolerance · max(1, Σ_j |K_ij v_j| + |k_i − (Kv)_i|)`:
///   the constraint residual measured against the size of the terms it is
///   computed from (for `k = K(q)v + b` the second sum is `|b|`), so that a
///   state of large velocities that an earlier run left consistent to round
///   off passes, and an inconsistent one does not. A step from an
///   inconsistent state is solved with the end constraint `k(t₁,q₁,v₁) = 0`
///   enforced at once, which removes the inconsistent part of the velocity
///   with an impulse in one step (measured: energy 1.0 → 0.498).
/// - `κ₁(K W⁻¹ Kᵀ) ≤` [`CONSTRAINT_CONDITION_LIMIT`], `W = ∇²_vv L`, the
///   Schur complement of the saddle matrix `[[W, Kᵀ],[K, 0]]` that determines
///   the accelerations and multipliers (index 2 requires it regular). When
///   `W` is singular (a coordinate without kinetic energy whose velocity a
///   constraint fixes) `W + γKᵀK`, `γ = max|W_ij| / max|K_ij|²`, stands in
///   for it: the saddle's solution is unchanged, and that matrix is regular
///   exactly when the saddle is (for positive semi-definite `W`). When both
///   are singular the mass matrix is, and the Newton matrix reports it with
///   its column.
///
/// Costs one stage-Jacobian evaluation and `O(N³ + N²M + M³)` operations,
/// paid only by cold starts; `jac` and `vals` are scratch (heap, so no
/// `N × N` matrix goes on the stack) and are left overwritten.
pub(crate) fn check_cold_start<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    state: &State<N>,
    h: f64,
    tolerance: f64,
    vals: &mut StageValues<N, M>,
    jac: &mut StageJacobians<N, M>,
) -> Result<(), StepError>
where
    Sys: NonholonomicSystem<N, M>,
{
    if M == 0 {
        return Ok(());
    }
    let (t, q, v) = (state.t, &state.q, &state.v);
    let zero = Vector::<M>::zeros();
    sys.stage_jacobians_into(t, q, v, &zero, vals, jac);
    let k = vals.constraint;
    if !k.iter().all(|x| x.is_finite()) {
        return Err(StepError::NonFinite {
            t,
            h,
            stage: "constraints at the start of the step (check the parameters)",
            history: Box::default(),
        });
    }
    let kv = jac.constraint_v * v;
    for i in 0..M {
        let terms: f64 = (0..N).map(|j| (jac.constraint_v[(i, j)] * v[j]).abs()).sum::<f64>() + (k[i] - kv[i]).abs();
        let allowed = tolerance * terms.max(1.0);
        // Written so that a NaN scale fails the test.
        if k[i].abs() <= allowed {
            continue;
        }
        return Err(StepError::InconsistentStart { t, residual: k.amax(), tolerance: allowed });
    }
    let kmax = jac.constraint_v.amax();
    let mut perm = [0usize; N];
    let scale = column_scales::<N>(jac.mass.as_slice());
    if factor_in_place::<N>(jac.mass.as_mut_slice(), &mut perm, &scale, &[N]).is_err() {
        // W is singular: the augmented W + γKᵀK (the evaluation is repeated,
        // the failed factorization overwrote W).
        sys.stage_jacobians_into(t, q, v, &zero, vals, jac);
        let gamma = jac.mass.amax() / (kmax * kmax);
        if !gamma.is_finite() {
            return Ok(());
        }
        let kk = &jac.constraint_v;
        for b in 0..N {
            for a in 0..N {
                let mut s = 0.0;
                for i in 0..M {
                    s += kk[(i, a)] * kk[(i, b)];
                }
                jac.mass[(a, b)] += gamma * s;
            }
        }
        let scale = column_scales::<N>(jac.mass.as_slice());
        if factor_in_place::<N>(jac.mass.as_mut_slice(), &mut perm, &scale, &[N]).is_err() {
            return Ok(());
        }
    }
    // S = K W⁻¹ Kᵀ and κ₁(S) = ‖S‖₁ ‖S⁻¹‖₁, computed exactly (M is small).
    let mut winv_kt = jac.constraint_v.transpose();
    for mut col in winv_kt.column_iter_mut() {
        let mut c: Vector<N> = col.clone_owned();
        solve_in_place::<N>(jac.mass.as_slice(), &perm, c.as_mut_slice());
        col.copy_from(&c);
    }
    let schur: Matrix<M, M> = jac.constraint_v * winv_kt;
    let norm1 = |a: &Matrix<M, M>| a.column_iter().map(|c| c.iter().map(|x| x.abs()).sum::<f64>()).fold(0.0, f64::max);
    let mut lu = Lu::<M>::new();
    let condition = match lu.factor(&schur) {
        Err(_) => f64::INFINITY,
        Ok(()) => {
            let mut inverse = Matrix::<M, M>::identity();
            for mut col in inverse.column_iter_mut() {
                let mut c: Vector<M> = col.clone_owned();
                lu.solve_in_place(&mut c);
                col.copy_from(&c);
            }
            norm1(&schur) * norm1(&inverse)
        }
    };
    // Written so that a NaN condition fails the test.
    if condition <= CONSTRAINT_CONDITION_LIMIT {
        Ok(())
    } else {
        Err(StepError::DependentConstraints { t, condition, limit: CONSTRAINT_CONDITION_LIMIT })
    }
}

/// Whether the energy `E = ∇_vL·v − L` is a first integral of the exact
/// flow, by the structure facts: `L` autonomous, constraints absent or
/// linear homogeneous in `v` (`k = K(t,q)v`, possibly rheonomic: the ideal
/// constraint force `−Kᵀψ` then does the work `−ψᵀk = 0`), no external force
/// and no non-ideal constraint force.
pub(crate) const fn energy_is_invariant<Sys, const N: usize, const M: usize>() -> bool
where
    Sys: NonholonomicSystem<N, M>,
{
    let st = Sys::STRUCTURE;
    st.lagrangian_autonomous
        && matches!(st.constraint_form, ConstraintForm::None | ConstraintForm::Linear)
        && !Sys::HAS_FORCING
        && !Sys::HAS_NONIDEAL_FORCE
}

/// The energy at the start of a chain of continued steps, against which the
/// guard measures drift.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct EnergyAnchor<const N: usize> {
    /// The end of the last accepted step of the chain (a step continues the
    /// chain when it starts there).
    pub(crate) end: State<N>,
    /// `E` there.
    pub(crate) energy: f64,
    /// `|E| + |p·v|` there: the energy's own size (`p·v = 2T` for a
    /// quadratic kinetic energy), the unit in which drift is measured.
    pub(crate) scale: f64,
}

impl<const N: usize> EnergyAnchor<N> {
    /// An anchor at `state`.
    pub(crate) fn at<Sys, const M: usize>(sys: &Sys, state: &State<N>) -> Self
    where
        Sys: NonholonomicSystem<N, M>,
    {
        let energy = sys.energy(state.t, &state.q, &state.v);
        let pv = sys.momentum(state.t, &state.q, &state.v).dot(&state.v);
        EnergyAnchor { end: *state, energy, scale: energy.abs() + pv.abs() }
    }
}

/// Outcome of the energy guard for one step.
pub(crate) enum EnergyCheck<const N: usize> {
    /// Within the limit; the anchor to keep for the next step.
    Accept(EnergyAnchor<N>),
    /// `|E₁ − E_anchor| > limit · scale`: the anchor and `E₁`.
    Drift(EnergyAnchor<N>, f64),
}

/// Checks the end `end` of a step from `start` against the anchor of the
/// chain it continues (a new anchor at `start` when it continues none).
///
/// An anchor whose scale is zero (at rest where `E = 0`) measures nothing,
/// so the chain re-anchors at the next state instead. A round-off floor of
/// `64 ε |E₁|` keeps huge energy offsets from tripping the test.
pub(crate) fn check_energy<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    anchor: Option<&EnergyAnchor<N>>,
    start: &State<N>,
    end: &State<N>,
    limit: f64,
) -> EnergyCheck<N>
where
    Sys: NonholonomicSystem<N, M>,
{
    let a = match anchor.filter(|a| a.end == *start && a.scale > 0.0) {
        Some(a) => *a,
        None => EnergyAnchor::at::<Sys, M>(sys, start),
    };
    if a.scale == 0.0 {
        return EnergyCheck::Accept(EnergyAnchor::at::<Sys, M>(sys, end));
    }
    let e1 = sys.energy(end.t, &end.q, &end.v);
    let drift = (e1 - a.energy).abs();
    // Written so that a NaN energy fails the test.
    if drift <= limit * a.scale + 64.0 * f64::EPSILON * e1.abs() {
        EnergyCheck::Accept(EnergyAnchor { end: *end, ..a })
    } else {
        EnergyCheck::Drift(a, e1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn update_norm_propagates_nan_wherever_it_is() {
        let z = Vector::<3>::new(1.0, -3.0, 0.0);
        for i in 0..3 {
            let mut d = Vector::<3>::new(1e-3, 2e-3, 4e-3);
            d[i] = f64::NAN;
            assert!(scaled_update_norm(&d, &z).is_nan(), "NaN at {i} hidden");
        }
        let d = Vector::<3>::new(1e-3, -8e-3, 4e-3);
        assert_eq!(scaled_update_norm(&d, &z), 4e-3);
        let mut inf = d;
        inf[1] = f64::INFINITY;
        assert_eq!(scaled_update_norm(&inf, &z), f64::INFINITY);
    }

    /// Lobatto IIIA-B treats `F` explicitly (Störmer–Verlet in the `p`
    /// part): on the particle (`ω = √2`) its map is unstable for `ω·h > 2`.
    #[test]
    fn energy_guard_refuses_an_unstable_map_and_nothing_else() {
        use crate::handwritten::Particle;
        use crate::{Method, NewtonOptions, StepError, Stepper, Tableau};
        let start = State::new(0.0, Vector::<3>::new(1.0, 0.5, 0.0), Vector::<3>::zeros());
        let tab = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
        let e0 = Particle.energy(0.0, &start.q, &start.v);
        // ω·h = 4.2: refused within a few steps, with the drift in the error.
        let mut st = Stepper::<_, 3, 1, 2, 11>::new(Particle, tab);
        let mut s = start;
        let err = (0..10).find_map(|_| st.step(&s, 3.0).map(|r| s = r.state).err()).expect("refused");
        let StepError::EnergyDrift { energy, energy0, bound, .. } = err else { panic!("{err}") };
        let pv: f64 = 0.0; // v0 = 0
        assert!((energy - energy0).abs() > bound && bound == e0.abs() + pv && energy0 == e0, "{err}");
        // The same step with the guard off is a "success" with a blown-up energy.
        let off = NewtonOptions { energy_drift_limit: None, ..NewtonOptions::default() };
        let mut st = Stepper::<_, 3, 1, 2, 11>::new(Particle, tab).with_options(off);
        let s = st.step(&start, 3.0).unwrap().state;
        assert!(Particle.energy(s.t, &s.q, &s.v) > 10.0 * e0);
        // A stable step size runs 2000 steps without a refusal.
        let mut st = Stepper::<_, 3, 1, 2, 11>::new(Particle, tab);
        let mut s = start;
        for _ in 0..2000 {
            s = st.step(&s, 0.1).unwrap().state;
        }
        assert!((Particle.energy(s.t, &s.q, &s.v) - e0).abs() < 1e-2 * e0);
    }
}
