//! The equations of one SPARK step, paper eq. (6.1): the stage points of
//! the unknowns `z` (`evaluate`), the residual `G(z)` and the
//! Newton matrices — the exact Jacobian `∂G/∂z` and the factors of the
//! stage-decoupled matrix. The row layout is in the docs of the `step`
//! module.

// Stage loops index several parallel arrays (c, a, b, stage values) with one index.
#![allow(clippy::needless_range_loop)]

use super::Stepper;
use crate::linalg::decoupled::{DecoupledMatrix, Masses};
use crate::linalg::newton_matrix::NewtonMatrix;
use crate::system::{Matrix, NonholonomicSystem, StageJacobians, StageValues, Vector};
use crate::tableau::{ConditionRows, Tableau};
use crate::State;

/// Everything one residual evaluation produced. The stepper keeps one and
/// every evaluation overwrites it in place (returned by value, its copies
/// would cost a few per cent of a step).
#[derive(Clone, Copy, Debug)]
pub(super) struct Eval<const N: usize, const M: usize, const S: usize> {
    pub(super) stages: [StageValues<N, M>; S],
    pub(super) end: StageValues<N, M>,
    pub(super) mid: Option<StageValues<N, M>>,
}

impl<const N: usize, const M: usize, const S: usize> Eval<N, M, S> {
    pub(super) fn zeros() -> Self {
        Eval { stages: [StageValues::zeros(); S], end: StageValues::zeros(), mid: None }
    }
}

/// What one evaluation computes besides the stage values.
pub(super) enum Derivatives<'a, const N: usize, const M: usize, const S: usize> {
    /// Nothing: a residual alone.
    None,
    /// Every stage Jacobian, for the exact Newton matrix (or a stage-decoupled
    /// one with point-dependent masses).
    Full(&'a mut EvalJac<N, M, S>),
    /// The constraint Jacobians `k_v`, `k_q` at the stages (`0..S`), the end
    /// point (`S`) and the midpoint (`S + 1`), for a refresh of the
    /// stage-decoupled matrix of a system with a constant mass matrix.
    Constraint { constraint_v: &'a mut [Matrix<M, N>], constraint_q: &'a mut [Matrix<M, N>] },
}

/// Jacobians of one evaluation (only for full-Jacobian iterations).
/// Every `StageJacobians` is its own heap allocation made zeroed by
/// [`StageJacobians::boxed_zeros`] and written in place by
/// `stage_jacobians_into`, so neither building nor filling one puts its
/// `≈ 48·N²` bytes on the stack (n = 65, s = 2 overflows a 2 MiB thread when
/// the stage arrays are built before boxing; n ≈ 120 does when the system
/// returns them by value).
#[derive(Clone, Debug)]
pub(super) struct EvalJac<const N: usize, const M: usize, const S: usize> {
    pub(super) stages: Box<[Box<StageJacobians<N, M>>]>,
    pub(super) end: Box<StageJacobians<N, M>>,
    pub(super) mid: Option<Box<StageJacobians<N, M>>>,
    /// `∂N/∂ψ` at the stages (only written when `Sys::HAS_NONIDEAL_FORCE`).
    pub(super) nonideal_psi: Box<[Matrix<N, M>]>,
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// The Newton matrix of a step of size `h` from `state`, evaluated and
    /// assembled at the step's starting guess, with that guess's residual.
    ///
    /// For benchmarks and diagnostics of the linear algebra alone: time
    /// [`NewtonMatrix::factor`] and [`NewtonMatrix::solve_in_place`] on a
    /// clone. The stepper's warm start is left as it was.
    pub fn newton_matrix(&mut self, state: &State<N>, h: f64) -> (&NewtonMatrix<N, M, S, D>, Vector<D>) {
        let z = self.starting_guess(state, h, self.continues(state)).z;
        let p0 = self.system.momentum(state.t, &state.q, &state.v);
        let carry = self.carry_for(state);
        let mut ev = Eval::zeros();
        let terms = super::usable_terms(&self.terms, self.terms_stale);
        Self::evaluate(
            &self.system,
            terms,
            &self.tableau,
            state,
            &carry,
            h,
            &z,
            Derivatives::Full(&mut *self.work),
            &mut ev,
        );
        let mut g = Vector::<D>::zeros();
        Self::residual(&self.tableau, &p0, h, &z, &ev, &mut g);
        self.assemble_jacobian(h);
        self.reusable = None;
        (&self.newton, g)
    }

    /// Evaluates the stage points of `z` into `ev`, with the derivatives
    /// `jac` asks for.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn evaluate(
        system: &Sys,
        terms: &[f64],
        tab: &Tableau<S>,
        state: &State<N>,
        carry: &Vector<N>,
        h: f64,
        z: &Vector<D>,
        jac: Derivatives<'_, N, M, S>,
        ev: &mut Eval<N, M, S>,
    ) {
        let (v, mu) = split::<N, M, S, D>(z);
        let v1 = z.fixed_rows::<N>(S * (N + M)).into_owned();
        let zero_m = Vector::<M>::zeros();
        if tab.conditions != ConditionRows::MidpointConstraint {
            ev.mid = None;
        }
        let q1 = state.q + increment(carry, h, &tab.b, &v);
        let t1 = state.t + h;
        let mid_point = || {
            let tm = state.t + 0.5 * h;
            (tm, state.q + (carry + (0.5 * h) * v[0]))
        };
        let stage_q = |i: usize| state.q + increment(carry, h, &tab.a[i], &v);
        match jac {
            Derivatives::Full(jac) => {
                for i in 0..S {
                    // `Ψ = μ/h` as a product with `1/h`, one rounding more
                    // than the quotient and no division per entry (the lane
                    // kernel forms it alike).
                    let psi = mu[i] * (1.0 / h);
                    let (ti, qi) = (state.t + tab.c[i] * h, stage_q(i));
                    // In place, into the heap work storage: no N×N value on the stack.
                    let (vals, jac_i) = (&mut ev.stages[i], &mut *jac.stages[i]);
                    system.stage_jacobians_with_terms(terms, ti, &qi, &v[i], &psi, vals, jac_i);
                    if Sys::HAS_FORCING {
                        system.add_external_force_jacobians(ti, &qi, &v[i], vals, jac_i);
                    }
                    if Sys::HAS_NONIDEAL_FORCE {
                        let psi_jac = &mut jac.nonideal_psi[i];
                        system.add_nonideal_force_jacobians(ti, &qi, &v[i], &psi, vals, jac_i, psi_jac);
                    }
                }
                system.stage_jacobians_with_terms(terms, t1, &q1, &v1, &zero_m, &mut ev.end, &mut jac.end);
                if tab.conditions == ConditionRows::MidpointConstraint {
                    let (tm, qm) = mid_point();
                    let mj = jac.mid.get_or_insert_with(StageJacobians::boxed_zeros);
                    let mv = ev.mid.insert(StageValues::zeros());
                    system.stage_jacobians_with_terms(terms, tm, &qm, &v[0], &zero_m, mv, mj);
                }
            }
            values_only => {
                // The stage values at point `p` (stages `0..S`, the end point
                // `S`, the midpoint `S + 1`), with the constraint Jacobians
                // there when a lean refresh asks for them.
                let mut constraint_jacobians = match values_only {
                    Derivatives::Constraint { constraint_v, constraint_q } => Some((constraint_v, constraint_q)),
                    _ => None,
                };
                let mut values_at =
                    |p: usize, t: f64, q: &Vector<N>, v: &Vector<N>, psi: &Vector<M>, out: &mut StageValues<N, M>| {
                        match &mut constraint_jacobians {
                            Some((kv, kq)) => system.stage_values_and_constraint_jacobians_with_terms(
                                terms, t, q, v, psi, out, &mut kq[p], &mut kv[p],
                            ),
                            None => system.stage_values_with_terms(terms, t, q, v, psi, out),
                        }
                    };
                for i in 0..S {
                    let psi = mu[i] * (1.0 / h);
                    let (ti, qi) = (state.t + tab.c[i] * h, stage_q(i));
                    values_at(i, ti, &qi, &v[i], &psi, &mut ev.stages[i]);
                    if Sys::HAS_FORCING {
                        ev.stages[i].force += system.external_force(ti, &qi, &v[i]);
                    }
                    if Sys::HAS_NONIDEAL_FORCE {
                        ev.stages[i].constraint_force += system.nonideal_force(ti, &qi, &v[i], &psi);
                    }
                }
                // At the end point and the midpoint the residual reads the
                // momentum and the constraint alone.
                let mut end_values_at =
                    |p: usize, t: f64, q: &Vector<N>, v: &Vector<N>, out: &mut StageValues<N, M>| {
                        match &mut constraint_jacobians {
                            Some((kv, kq)) => system.end_point_values_and_constraint_jacobians_with_terms(
                                terms, t, q, v, out, &mut kq[p], &mut kv[p],
                            ),
                            None => system.end_point_values_with_terms(terms, t, q, v, out),
                        }
                    };
                end_values_at(S, t1, &q1, &v1, &mut ev.end);
                if tab.conditions == ConditionRows::MidpointConstraint {
                    let (tm, qm) = mid_point();
                    end_values_at(S + 1, tm, &qm, &v[0], ev.mid.insert(StageValues::zeros()));
                }
            }
        }
    }

    /// The SPARK residual `G(z)` (see the module docs for the row layout),
    /// written into `g` (every entry; returned by value, the `D`-vector
    /// would be copied into place by a `memcpy` call).
    pub(super) fn residual(
        tab: &Tableau<S>,
        p0: &Vector<N>,
        h: f64,
        z: &Vector<D>,
        ev: &Eval<N, M, S>,
        g: &mut Vector<D>,
    ) {
        // Every row is written below (the methods with a midpoint
        // constraint have S = 2: one condition row block), so `g` is not
        // cleared first.
        let mut row = |i: usize, weights_hat: &[f64; S], weights_tilde: &[f64; S], momentum: &Vector<N>| {
            let mut r = momentum - p0;
            // Zero weights (Lobatto IIIB's last column) included, as in
            // `increment`.
            for j in 0..S {
                r -= (h * weights_hat[j]) * ev.stages[j].force;
                r -= (h * weights_tilde[j]) * ev.stages[j].constraint_force;
            }
            g.fixed_rows_mut::<N>(i * N).copy_from(&r);
        };
        for i in 0..S {
            row(i, &tab.a_hat[i], &tab.a_tilde[i], &ev.stages[i].momentum);
        }
        row(S, &tab.b_hat, &tab.b_tilde, &ev.end.momentum);
        let base = S * N + N;
        match tab.conditions {
            ConditionRows::Omega => {
                for r in 0..S.saturating_sub(1) {
                    let mut k = Vector::<M>::zeros();
                    for j in 0..S {
                        k += tab.omega[r][j] * ev.stages[j].constraint;
                    }
                    g.fixed_rows_mut::<M>(base + r * M).copy_from(&k);
                }
            }
            ConditionRows::MidpointConstraint => match &ev.mid {
                Some(mid) => g.fixed_rows_mut::<M>(base).copy_from(&mid.constraint),
                None => g.fixed_rows_mut::<M>(base).fill(0.0),
            },
            ConditionRows::EqualMultipliers => {
                for r in 0..S.saturating_sub(1) {
                    let d = z.fixed_rows::<M>(S * N + r * M) - z.fixed_rows::<M>(S * N + (r + 1) * M);
                    g.fixed_rows_mut::<M>(base + r * M).copy_from(&d);
                }
            }
        }
        g.fixed_rows_mut::<M>(D - M).copy_from(&ev.end.constraint);
    }

    /// The exact Jacobian `∂G/∂z`, skipping blocks the structure facts prove zero.
    pub(super) fn assemble_jacobian(&mut self, h: f64) {
        let jac = &self.work;
        let tab = self.tableau;
        let st = Sys::STRUCTURE;
        // L = T(v) − U(q): ∂P/∂q = 0 and ∂F/∂v = 0 (unless a force f(t,q,v)
        // is added to F).
        let separable = st.separable && !Sys::HAS_FORCING;
        // K independent of v and no non-ideal force: ∂R/∂v = 0.
        let k_velocity_free = st.constraint_matrix_velocity_free() && !Sys::HAS_NONIDEAL_FORCE;
        if !self.pattern_written {
            // Which blocks are written below depends only on the tableau and
            // the structure facts, both fixed for this stepper: the structural
            // zeros and the constant entries are written once, and every later
            // assembly overwrites exactly the blocks that change (zeroing the
            // whole D×D matrix per iteration costs more than the blocks).
            self.newton.clear();
            if tab.conditions == ConditionRows::EqualMultipliers {
                let mut j = self.newton.matrix_mut();
                let base = S * N + N;
                for r in 0..S.saturating_sub(1) {
                    for d in 0..M {
                        j[(base + r * M + d, S * N + r * M + d)] = 1.0;
                        j[(base + r * M + d, S * N + (r + 1) * M + d)] = -1.0;
                    }
                }
            }
            self.pattern_written = true;
        }
        let mut j = self.newton.matrix_mut();
        let h2 = h * h;
        // Momentum rows: stage rows i < S use (a_i, â_i, ã_i); the p₁ row uses
        // (b, b̂, b̃) with its momentum evaluated at the end point. Each block
        // is accumulated in a contiguous local N×N matrix and stored once
        // (nalgebra's `zip_apply` on the strided D×D view goes entry by entry:
        // ≈ 12 % of all instructions of an mp7 Gauss s = 4 step). Every entry
        // sees the same operations in the same order as an accumulation in
        // the D×D view, so the matrix is bit for bit the same.
        for i in 0..=S {
            let (a_row, ah_row, at_row) =
                if i < S { (&tab.a[i], &tab.a_hat[i], &tab.a_tilde[i]) } else { (&tab.b, &tab.b_hat, &tab.b_tilde) };
            let pq = if i < S { &jac.stages[i].momentum_q } else { &jac.end.momentum_q };
            for l in 0..S {
                // Small blocks accumulate in a fixed 2 KiB stack array: LLVM sees
                // that it aliases nothing and vectorizes the axpys (measured: with
                // the heap scratch alone a step at N ≤ 7 is ≈ 5 % slower). Larger
                // blocks use the heap scratch, so a step's stack stays
                // independent of N.
                let mut local = [0.0f64; SMALL_BLOCK];
                let blk: &mut [f64] = if N * N <= SMALL_BLOCK { &mut local[..N * N] } else { &mut self.block[..N * N] };
                if i == l {
                    blk.copy_from_slice(jac.stages[l].mass.as_slice());
                } else {
                    blk.fill(0.0);
                }
                if !separable {
                    if a_row[l] != 0.0 {
                        axpy(blk, h * a_row[l], pq);
                    }
                    if ah_row[l] != 0.0 {
                        axpy(blk, -h * ah_row[l], &jac.stages[l].force_v);
                    }
                }
                if !k_velocity_free && at_row[l] != 0.0 {
                    axpy(blk, -h * at_row[l], &jac.stages[l].constraint_force_v);
                }
                for m in 0..S {
                    let aml = tab.a[m][l];
                    if aml == 0.0 {
                        continue;
                    }
                    if ah_row[m] != 0.0 {
                        axpy(blk, -h2 * ah_row[m] * aml, &jac.stages[m].force_q);
                    }
                    if at_row[m] != 0.0 {
                        axpy(blk, -h2 * at_row[m] * aml, &jac.stages[m].constraint_force_q);
                    }
                }
                for c in 0..N {
                    j.fixed_view_mut::<N, 1>(i * N, l * N + c).as_mut_slice().copy_from_slice(&blk[c * N..(c + 1) * N]);
                }
                // ∂(−h ã_il R_l)/∂μ_l = ã_il K_lᵀ (R_l = −K_lᵀ μ_l / h);
                // with N(ψ = μ/h) also −ã_il ∂N_l/∂ψ.
                if at_row[l] != 0.0 {
                    let mut kt = j.fixed_view_mut::<N, M>(i * N, S * N + l * M);
                    kt.tr_copy_from(&jac.stages[l].constraint_v);
                    if Sys::HAS_NONIDEAL_FORCE {
                        kt -= &jac.nonideal_psi[l];
                    }
                    kt *= at_row[l];
                }
            }
        }
        // ∂p₁/∂v₁.
        j.fixed_view_mut::<N, N>(S * N, S * (N + M)).copy_from(&jac.end.mass);
        let base = S * N + N;
        match tab.conditions {
            ConditionRows::Omega => {
                for r in 0..S.saturating_sub(1) {
                    for l in 0..S {
                        let mut blk = tab.omega[r][l] * jac.stages[l].constraint_v;
                        for m in 0..S {
                            let c = tab.omega[r][m] * tab.a[m][l];
                            if c != 0.0 {
                                blk += (h * c) * jac.stages[m].constraint_q;
                            }
                        }
                        j.fixed_view_mut::<M, N>(base + r * M, l * N).copy_from(&blk);
                    }
                }
            }
            ConditionRows::MidpointConstraint => {
                if let Some(mj) = &jac.mid {
                    let blk = mj.constraint_v + (0.5 * h) * mj.constraint_q;
                    j.fixed_view_mut::<M, N>(base, 0).copy_from(&blk);
                }
            }
            // Constant ±1 entries, written with the structural zeros.
            ConditionRows::EqualMultipliers => {}
        }
        for l in 0..S {
            j.fixed_view_mut::<M, N>(D - M, l * N).copy_from(&((h * tab.b[l]) * jac.end.constraint_q));
        }
        j.fixed_view_mut::<M, N>(D - M, S * (N + M)).copy_from(&jac.end.constraint_v);
    }

    /// Factors the stage-decoupled matrix at `z`. `lean`: the latest
    /// evaluation wrote the constraint Jacobians into the decoupled matrix
    /// ([`Derivatives::Constraint`]) and no stage Jacobians, so the constant
    /// mass matrix is evaluated here once, while its factors are not kept;
    /// otherwise everything is copied from `self.work`.
    pub(super) fn factor_decoupled(
        &mut self,
        state: &State<N>,
        carry: &Vector<N>,
        h: f64,
        z: &Vector<D>,
        lean: bool,
    ) -> Result<(), crate::linalg::Singular> {
        let tab = &self.tableau;
        let dec = &mut self.decoupled;
        let work = &mut *self.work;
        if !lean {
            copy_constraint_jacobians(work, dec);
            if Sys::CONSTANT_STIFFNESS {
                dec.set_stiffness(&work.stages[0].force_q);
            } else if Sys::DIAGONAL_STIFFNESS {
                for (j, stage) in work.stages.iter().enumerate() {
                    if self.stiffness_points[j] {
                        dec.set_stage_stiffness(j, &stage.force_q.diagonal());
                    }
                }
            }
            let masses = Masses::PerPoint { stages: &work.stages, end: &work.end };
            let nonideal = Sys::HAS_NONIDEAL_FORCE.then_some(&work.nonideal_psi[..]);
            return dec.factor(tab, h, masses, nonideal);
        }
        let sys = &self.system;
        // A full mass matrix keeps no stiffness per stage point: after the
        // first refresh has factored it, none is evaluated.
        let kept = self.stiffness_points;
        if Sys::DIAGONAL_STIFFNESS && kept.contains(&true) && dec.may_keep_stage_stiffness() {
            // The stiffness at each kept stage point of this iterate, from
            // the stage Jacobians into the heap work storage.
            let (v, mu) = split::<N, M, S, D>(z);
            let mut vals = StageValues::zeros();
            for (j, stage) in work.stages.iter_mut().enumerate() {
                if !kept[j] {
                    continue;
                }
                let (tj, qj) = (state.t + tab.c[j] * h, state.q + increment(carry, h, &tab.a[j], &v));
                if let Some(diagonal) = sys.stiffness_diagonal(tj, &qj, &v[j]) {
                    dec.set_stage_stiffness(j, &diagonal);
                    continue;
                }
                let psi = mu[j] * (1.0 / h);
                sys.stage_jacobians_into(tj, &qj, &v[j], &psi, &mut vals, stage);
                dec.set_stage_stiffness(j, &stage.force_q.diagonal());
            }
        }
        if dec.has_constant_mass() {
            return dec.factor(tab, h, Masses::Cached, None);
        }
        // The mass matrix is constant: one evaluation into the heap work
        // storage (no N×N value on the stack) gives it for every block.
        let (v, _) = split::<N, M, S, D>(z);
        let v1 = z.fixed_rows::<N>(S * (N + M)).into_owned();
        let (t1, q1) = (state.t + h, state.q + increment(carry, h, &tab.b, &v));
        let mut vals = StageValues::zeros();
        sys.stage_jacobians_into(t1, &q1, &v1, &Vector::zeros(), &mut vals, &mut work.end);
        if Sys::CONSTANT_STIFFNESS {
            dec.set_stiffness(&work.end.force_q);
        }
        dec.factor(tab, h, Masses::Constant(&work.end.mass), None)
    }
}

#[cfg(test)]
impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// The residual and the assembled Jacobian at `z` (for derivative tests).
    pub(crate) fn residual_and_jacobian(
        &mut self,
        state: &State<N>,
        h: f64,
        z: &Vector<D>,
    ) -> (Vector<D>, Matrix<D, D>) {
        let p0 = self.system.momentum(state.t, &state.q, &state.v);
        let carry = self.carry_for(state);
        let mut ev = Eval::zeros();
        let terms = super::usable_terms(&self.terms, self.terms_stale);
        Self::evaluate(
            &self.system,
            terms,
            &self.tableau,
            state,
            &carry,
            h,
            z,
            Derivatives::Full(&mut *self.work),
            &mut ev,
        );
        let mut g = Vector::<D>::zeros();
        Self::residual(&self.tableau, &p0, h, z, &ev, &mut g);
        self.assemble_jacobian(h);
        (g, self.newton.matrix().into_owned())
    }

    /// For the stage-decoupled matrix's tests: the residual `g` at `z`, the
    /// stage-decoupled matrix written out densely from the exact Jacobian
    /// (velocity blocks between different stages zeroed, each stage's own
    /// velocity block replaced by its mass matrix), and the solve of `g` by
    /// [`DecoupledMatrix`] (`lean`: from the constraint Jacobians alone).
    pub(crate) fn decoupled_solve(
        &mut self,
        state: &State<N>,
        h: f64,
        z: &Vector<D>,
        lean: bool,
    ) -> Result<(Vector<D>, Matrix<D, D>, Vector<D>), crate::linalg::Singular> {
        let (g, mut approx) = self.residual_and_jacobian(state, h, z);
        let work = &self.work;
        decouple_velocity_blocks::<N, M, S, D>(
            &mut approx,
            |i| if i < S { work.stages[i].mass } else { work.end.mass },
        );
        if Sys::CONSTANT_STIFFNESS {
            keep_stiffness_blocks::<N, M, S, D>(&mut approx, &self.tableau, h, &work.stages[0].force_q);
        }
        if lean {
            // A lean refresh takes the constraint Jacobians its evaluation
            // wrote (here: those of the full evaluation at the same `z`).
            self.decoupled.invalidate();
            copy_constraint_jacobians(&self.work, &mut self.decoupled);
        }
        let carry = self.carry_for(state);
        self.factor_decoupled(state, &carry, h, z, lean)?;
        let mut x = g;
        self.decoupled.solve_in_place(&mut x);
        Ok((g, approx, x))
    }

    /// For the stage-decoupled matrix's tests: the residual `g` at `z`, the
    /// stage-decoupled matrix written out densely with every velocity block
    /// replaced by the constant `mass` (which need not be the system's), and
    /// the solve of `g` by [`DecoupledMatrix`] factored with that mass
    /// matrix.
    pub(crate) fn decoupled_solve_with_mass(
        &mut self,
        state: &State<N>,
        h: f64,
        z: &Vector<D>,
        mass: &Matrix<N, N>,
    ) -> Result<(Vector<D>, Matrix<D, D>, Vector<D>), crate::linalg::Singular> {
        let (g, mut approx) = self.residual_and_jacobian(state, h, z);
        decouple_velocity_blocks::<N, M, S, D>(&mut approx, |_| *mass);
        self.decoupled.invalidate();
        copy_constraint_jacobians(&self.work, &mut self.decoupled);
        self.decoupled.factor(&self.tableau, h, Masses::Constant(mass), None)?;
        let mut x = g;
        self.decoupled.solve_in_place(&mut x);
        Ok((g, approx, x))
    }

    /// Steps left on the exact matrix after the stage-decoupled one failed.
    pub(crate) fn exact_steps_left(&self) -> u32 {
        self.exact_steps_left
    }

    /// The residual at `z`.
    pub(crate) fn residual_at(&self, state: &State<N>, h: f64, z: &Vector<D>) -> Vector<D> {
        let p0 = self.system.momentum(state.t, &state.q, &state.v);
        let mut ev = Eval::zeros();
        let carry = self.carry_for(state);
        Self::evaluate(
            &self.system,
            super::usable_terms(&self.terms, self.terms_stale),
            &self.tableau,
            state,
            &carry,
            h,
            z,
            Derivatives::None,
            &mut ev,
        );
        let mut g = Vector::<D>::zeros();
        Self::residual(&self.tableau, &p0, h, z, &ev, &mut g);
        g
    }
}

/// The stage-decoupled matrix from the exact Jacobian `j`: the velocity
/// blocks between different points zeroed and point `i`'s own block (stages
/// `0..S`, the end point `S`) replaced by `mass(i)`.
#[cfg(test)]
fn decouple_velocity_blocks<const N: usize, const M: usize, const S: usize, const D: usize>(
    j: &mut Matrix<D, D>,
    mass: impl Fn(usize) -> Matrix<N, N>,
) {
    for i in 0..=S {
        for l in 0..=S {
            let col = if l < S { l * N } else { S * (N + M) };
            let block = if i == l { mass(i) } else { Matrix::<N, N>::zeros() };
            j.fixed_view_mut::<N, N>(i * N, col).copy_from(&block);
        }
    }
}

/// Adds to the stage-decoupled matrix `j` the couplings of a constant
/// stiffness `F_q`: `−h² (ÂA)_ik F_q` in stage row `i`, velocity column `k`,
/// and `−h² (b̂ᵀA)_k F_q` in the end row.
#[cfg(test)]
fn keep_stiffness_blocks<const N: usize, const M: usize, const S: usize, const D: usize>(
    j: &mut Matrix<D, D>,
    tab: &Tableau<S>,
    h: f64,
    fq: &Matrix<N, N>,
) {
    for k in 0..S {
        for i in 0..=S {
            let coef: f64 = if i < S {
                (0..S).map(|m| tab.a_hat[i][m] * tab.a[m][k]).sum()
            } else {
                (0..S).map(|m| tab.b_hat[m] * tab.a[m][k]).sum()
            };
            let mut blk = j.fixed_view_mut::<N, N>(i * N, k * N);
            blk -= (h * h * coef) * fq;
        }
    }
}

/// Copies the constraint Jacobians of a full evaluation into the
/// stage-decoupled matrix.
fn copy_constraint_jacobians<const N: usize, const M: usize, const S: usize>(
    work: &EvalJac<N, M, S>,
    dec: &mut DecoupledMatrix<N, M, S>,
) {
    for i in 0..S {
        dec.constraint_v[i] = work.stages[i].constraint_v;
        dec.constraint_q[i] = work.stages[i].constraint_q;
    }
    dec.constraint_v[S] = work.end.constraint_v;
    dec.constraint_q[S] = work.end.constraint_q;
    if let Some(mj) = &work.mid {
        dec.constraint_v[S + 1] = mj.constraint_v;
        dec.constraint_q[S + 1] = mj.constraint_q;
    }
}

/// Largest `N·N` whose Newton-matrix blocks are accumulated on the stack.
const SMALL_BLOCK: usize = 256;

/// `acc += coef · x`, entry by entry on contiguous storage (nalgebra's
/// `zip_apply` on a strided view of the D×D matrix does not vectorize);
/// `acc` is an `N·N` block scratch (column-major).
#[inline(always)]
fn axpy<const N: usize>(acc: &mut [f64], coef: f64, x: &Matrix<N, N>) {
    for (a, x) in acc[..N * N].iter_mut().zip(x.as_slice()) {
        *a += coef * x;
    }
}

/// `carry + Σ_j (h c_j) V_j`: the increment of `q` summed on its own (at
/// the size of `hV`), so that adding it to `q₀` rounds once at the size of
/// `q` instead of once per stage — `S` roundings of nearly the same
/// increments every step would be the systematic part of the drift.
///
/// A zero coefficient (Lobatto IIIA's first row) adds its product too: the
/// exact zero `0·V_j` leaves a finite sum as it is, and a test of every
/// coefficient at every evaluation costs more than the products it saves
/// (with the same test dropped from the residual's rows, 2–3 % of the
/// skate's and the particle's stage-decoupled steps at s = 1, 2: docs/performance,
/// "Instructions per step").
#[inline(always)]
pub(super) fn increment<const N: usize, const S: usize>(
    carry: &Vector<N>,
    h: f64,
    c: &[f64; S],
    v: &[Vector<N>; S],
) -> Vector<N> {
    let mut d = *carry;
    for j in 0..S {
        d += (h * c[j]) * v[j];
    }
    d
}

/// Splits `z` into stage velocities and scaled multipliers `μ_i = hΨ_i`.
/// Inlined: returned from a call, the arrays would be copied into place by
/// a `memcpy` call at every residual evaluation.
#[inline(always)]
pub(super) fn split<const N: usize, const M: usize, const S: usize, const D: usize>(
    z: &Vector<D>,
) -> ([Vector<N>; S], [Vector<M>; S]) {
    let mut v = [Vector::<N>::zeros(); S];
    let mut mu = [Vector::<M>::zeros(); S];
    for i in 0..S {
        v[i] = z.fixed_rows::<N>(i * N).into_owned();
        mu[i] = z.fixed_rows::<M>(S * N + i * M).into_owned();
    }
    (v, mu)
}
