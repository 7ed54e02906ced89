//! The stage-decoupled Newton matrix: the SPARK Jacobian with the couplings
//! between the velocity unknowns of different stages dropped, solved by
//! block elimination down to a Schur complement in the multipliers.
//!
//! # The approximation
//! With the unknowns `z = [V | μ | v₁]` and the rows `[stage momentum (S·N) |
//! p₁ (N) | constraint rows (S·M)]`, the exact Jacobian is
//! `[[A, B], [C, E]]`: `A` couples the momentum rows to the velocity unknowns
//! `X = (V₁…V_S, v₁)`, `B` to the multipliers, `C` is the constraint rows'
//! derivative in `X`, and `E` their derivative in `μ` (zero, or the constant
//! `±I` of equal-multiplier rows). When `L = T(t,v) − U(t,q)` and the
//! constraint matrix `K` does not depend on `v` (no forcing, no non-ideal
//! force), `A = diag(W₁,…,W_S, W₁') + O(h²)`, with `W_i` the mass matrix at
//! stage `i` and `W₁'` at the end point: stage `i`'s velocity enters another
//! stage's momentum only through `Q_j = q₀ + hΣa_jk V_k` inside the force
//! and constraint-force terms, which carry another factor `h`.
//!
//! [`DecoupledMatrix`] keeps `B`, `C` and `E` exact and replaces `A` by the
//! block diagonal `W = diag(W_i)`; for a constant stiffness (below) it keeps
//! that part of the `O(h²)` terms too. Then `W⁻¹B` costs `S+1` solves with
//! `N × N` factors (one factor shared by every block when the mass matrix
//! is constant, and kept until it changes), and what is left to factor is
//! the Schur complement `Σ = E − C W⁻¹ B` on the `S·M` multipliers. The
//! iteration built on these factors contracts at a rate `O(h²‖W⁻¹∂F/∂q‖)`
//! for such systems; the stepper watches the rate and falls back to the
//! exact matrix when it is slow (see [`Jacobian`](crate::Jacobian)).
//!
//! # A constant stiffness
//! When the system declares `CONSTANT_STIFFNESS` (a quadratic potential:
//! `F_q = ∂(∇_q L)/∂q` constant) and the mass matrix `W` is constant, the
//! force terms of `A` are a constant matrix for a given `h`: the stage rows'
//! velocity block is `T = I ⊗ W − h² (ÂA) ⊗ F_q` (`S·N` square, coupling
//! every stage through `Q_j`), and the end row has `−h² (b̂ᵀA)_k F_q` on
//! stage `k` beside `W` on `v₁`. The matrix then keeps them: `T` is factored
//! once per step size and the solves use it in place of the blocks `W_i`,
//! so what is left out is only the constraint forces' `∂(Kᵀψ)/∂q`. The
//! particle of §8.1 (`U = q₁² + q₂²`) takes 3–5 updates per step on it
//! instead of 5–8 with the force terms dropped.
//!
//! # Storage
//! Every array is allocated once, on the heap, by [`DecoupledMatrix::new`]:
//! a step allocates nothing, and no `N × N` value goes on the stack.

use super::stiff_stages::{StiffStages, DENSE_MAX};
use super::{column_scales, factor_in_place, factor_runtime, is_diagonal, solve_in_place, solve_runtime, Singular};
use crate::system::{Matrix, StageJacobians, Vector};
use crate::tableau::{ConditionRows, Tableau};

/// Factors of the stage-decoupled Newton matrix of an `S`-stage step for a
/// system with `N` coordinates and `M` constraints.
#[derive(Clone, Debug)]
pub(crate) struct DecoupledMatrix<const N: usize, const M: usize, const S: usize> {
    /// LU factors of the velocity blocks `W_0 … W_S` (`N × N`, column-major);
    /// only block 0 when `shared`.
    w: Box<[f64]>,
    w_perm: Box<[usize]>,
    /// All `S + 1` mass matrices of the latest factorization are equal (a
    /// constant mass matrix): block 0 stands for every block.
    shared: bool,
    /// The mass matrix whose factors block 0 holds when `shared` (compared
    /// bit for bit, so a constant mass matrix is factored once).
    w_source: Box<[f64]>,
    /// The shared mass matrix is diagonal (every off-diagonal entry zero, as
    /// for most mechanical systems in Cartesian or angle coordinates): its
    /// solves are the products with `w_rdiag`, the reciprocals of its
    /// diagonal — the same operations as the LU solve of a diagonal matrix,
    /// without the triangular sweeps over zeros.
    diagonal: bool,
    w_rdiag: Box<[f64]>,
    /// The shared mass matrix is the identity (every reciprocal exactly 1,
    /// as for unit masses and inertias): its solves change no bit, and are
    /// skipped.
    identity: bool,
    w_valid: bool,
    /// `K = k_v` and `k_q` at the stages (`0..S`), the end point (`S`) and
    /// the midpoint (`S + 1`), written by the caller before
    /// [`factor`](Self::factor).
    pub(crate) constraint_v: Box<[Matrix<M, N>]>,
    pub(crate) constraint_q: Box<[Matrix<M, N>]>,
    /// `X = W⁻¹B`, `(S+1)·N × S·M`, by rows: entry `(k, e)` of block
    /// `X[i][l] = W_i⁻¹ B[i][l]` (`N × M`) at `(i·N + k)·S·M + l·M + e`, so
    /// that the Schur complement's rows and the solve's velocity rows are
    /// sums of whole rows of `X`.
    x: Box<[f64]>,
    /// `C[r][i]` (`M × N`), at `(r·(S+1) + i)·M·N`, and which are nonzero.
    c: Box<[f64]>,
    c_nonzero: Box<[bool]>,
    /// Every written entry of `C` is finite (see `factor`).
    c_finite: bool,
    /// Each stage's `W⁻¹ (K_lᵀ − ∂N_l/∂ψ)` (`N × M`, at `l·N·M`) for a
    /// shared mass matrix, or its `K_lᵀ` for a stiffness kept by
    /// coordinate: what the rows of `X` are written from.
    kt: Box<[f64]>,
    /// LU factors of `Σ = E − C X` (`S·M` square) and its scratch; `rows`
    /// holds `Σ` by rows while it is assembled.
    schur: Box<[f64]>,
    rows: Box<[f64]>,
    schur_perm: Box<[usize]>,
    schur_scale: Box<[f64]>,
    factored: bool,
    /// The stage blocks of a constant stiffness (empty storage unless the
    /// system declares `CONSTANT_STIFFNESS`), and a scratch vector of `S·N`
    /// for the columns of `T⁻¹ B` in their dense form.
    stiff: StiffStages<N, S>,
    coupled_rhs: Box<[f64]>,
    /// The latest factorization keeps the stiffness couplings (a shared
    /// mass matrix and a stiffness set).
    coupled: bool,
}

/// Where a factorization takes the velocity blocks `W_i` from.
pub(crate) enum Masses<'a, const N: usize, const M: usize> {
    /// The mass matrices of one full evaluation at the stages and the end
    /// point.
    PerPoint { stages: &'a [Box<StageJacobians<N, M>>], end: &'a StageJacobians<N, M> },
    /// One mass matrix for every block (a constant mass matrix).
    Constant(&'a Matrix<N, N>),
    /// The constant mass matrix of the previous factorization, whose factors
    /// are kept ([`DecoupledMatrix::has_constant_mass`]).
    Cached,
}

/// Factors a mass matrix shared by every velocity block: a diagonal one
/// (every off-diagonal entry zero, as for most mechanical systems in
/// Cartesian or angle coordinates) as the reciprocals of its diagonal in
/// `rdiag` — the same operations as the LU solve of a diagonal matrix,
/// without the triangular sweeps over zeros — and any other one as LU
/// factors in `lu`, `perm`. Returns whether it is diagonal. The lane
/// kernel (`crate::lanes`) factors its mass matrix with this function too,
/// so its solves are the stepper's bit for bit.
pub(crate) fn factor_mass<const N: usize>(
    mass: &[f64],
    rdiag: &mut [f64],
    lu: &mut [f64],
    perm: &mut [usize],
) -> Result<bool, Singular> {
    if !is_diagonal::<N>(mass) {
        DecoupledMatrix::<N, 0, 1>::factor_block(lu, perm, mass)?;
        return Ok(false);
    }
    for (k, r) in rdiag[..N].iter_mut().enumerate() {
        let d = mass[k * (N + 1)];
        // The LU's singularity test on a diagonal matrix: a zero or
        // non-finite pivot.
        if d == 0.0 || !d.is_finite() {
            return Err(Singular { column: k, pivot: d.abs() });
        }
        *r = 1.0 / d;
    }
    Ok(true)
}

impl<const N: usize, const M: usize, const S: usize> DecoupledMatrix<N, M, S> {
    const SM: usize = S * M;

    /// Storage for one factorization (heap, allocated once); with
    /// `keep_stiffness` also for the coupled stage block of a constant
    /// stiffness.
    pub(crate) fn new(keep_stiffness: bool) -> Self {
        let sm = Self::SM;
        let sn = if keep_stiffness && S * N <= DENSE_MAX { S * N } else { 0 };
        DecoupledMatrix {
            w: vec![0.0; (S + 1) * N * N].into_boxed_slice(),
            w_perm: vec![0; (S + 1) * N].into_boxed_slice(),
            shared: false,
            w_source: vec![0.0; N * N].into_boxed_slice(),
            diagonal: false,
            w_rdiag: vec![0.0; N].into_boxed_slice(),
            identity: false,
            w_valid: false,
            constraint_v: vec![Matrix::zeros(); S + 2].into_boxed_slice(),
            constraint_q: vec![Matrix::zeros(); S + 2].into_boxed_slice(),
            x: vec![0.0; (S + 1) * S * N * M].into_boxed_slice(),
            c: vec![0.0; S * (S + 1) * M * N].into_boxed_slice(),
            c_nonzero: vec![false; S * (S + 1)].into_boxed_slice(),
            c_finite: true,
            kt: vec![0.0; S * N * M].into_boxed_slice(),
            schur: vec![0.0; sm * sm].into_boxed_slice(),
            rows: vec![0.0; sm * sm].into_boxed_slice(),
            schur_perm: vec![0; sm].into_boxed_slice(),
            schur_scale: vec![0.0; sm].into_boxed_slice(),
            factored: false,
            stiff: StiffStages::new(keep_stiffness),
            coupled_rhs: vec![0.0; sn].into_boxed_slice(),
            coupled: false,
        }
    }

    /// Sets the constant stiffness `F_q` whose couplings later
    /// factorizations keep (ignored unless made with `keep_stiffness`).
    pub(crate) fn set_stiffness(&mut self, stiffness: &Matrix<N, N>) {
        self.stiff.set(stiffness.as_slice());
    }

    /// Sets the diagonal of the stiffness `F_q` at stage point `stage` (a
    /// system with a diagonal, point-dependent stiffness), whose couplings
    /// later factorizations keep (ignored unless made with `keep_stiffness`).
    pub(crate) fn set_stage_stiffness(&mut self, stage: usize, diagonal: &Vector<N>) {
        self.stiff.set_stage(stage, diagonal.as_slice());
    }

    /// Forgets the cached mass-matrix factors (the system may have changed).
    pub(crate) fn invalidate(&mut self) {
        self.w_valid = false;
        self.factored = false;
        self.stiff.invalidate();
    }

    /// Whether a stiffness per stage point can be kept: by coordinate only,
    /// so not once a kept constant mass matrix is known to be full.
    pub(crate) fn may_keep_stage_stiffness(&self) -> bool {
        !self.w_valid || self.diagonal
    }

    /// Whether the factors of a constant mass matrix are kept, so that
    /// [`Masses::Cached`] may stand for it.
    pub(crate) fn has_constant_mass(&self) -> bool {
        self.w_valid
    }

    /// Whether the latest factors keep the stiffness's couplings exactly
    /// (a constant stiffness, or a diagonal one at every stage point that
    /// enters, with a constant mass matrix): then the force terms of the
    /// exact Jacobian are all in the matrix, and only the constraint
    /// force's are dropped.
    pub(crate) fn keeps_stiffness(&self) -> bool {
        self.coupled
    }

    /// Factors the stage-decoupled matrix of a step of size `h`, from the
    /// constraint Jacobians in `constraint_v` / `constraint_q`, the velocity
    /// blocks `masses` and, for a non-ideal force, `∂N/∂ψ` at the stages.
    /// Fails when a mass matrix or the Schur complement is singular (the
    /// caller then uses the exact matrix).
    pub(crate) fn factor(
        &mut self,
        tab: &Tableau<S>,
        h: f64,
        masses: Masses<'_, N, M>,
        nonideal_psi: Option<&[Matrix<N, M>]>,
    ) -> Result<(), Singular> {
        self.factored = false;
        let nn = N * N;
        // Velocity blocks W_i.
        match masses {
            Masses::Cached if self.w_valid => self.shared = true,
            Masses::Cached => return Err(Singular { column: 0, pivot: f64::NAN }),
            Masses::Constant(m0) => self.factor_shared(m0.as_slice())?,
            Masses::PerPoint { stages, end } => {
                let mass = |i: usize| if i < S { stages[i].mass.as_slice() } else { end.mass.as_slice() };
                if (1..=S).all(|i| mass(i) == mass(0)) {
                    self.factor_shared(mass(0))?;
                } else {
                    self.shared = false;
                    self.diagonal = false;
                    self.identity = false;
                    self.w_valid = false;
                    for i in 0..=S {
                        let (lu, perm) = (&mut self.w[i * nn..(i + 1) * nn], &mut self.w_perm[i * N..(i + 1) * N]);
                        Self::factor_block(lu, perm, mass(i))?;
                    }
                }
            }
        }
        self.coupled = self.shared && self.stiff.factor(tab, h, &self.w_source, self.diagonal)?;
        if Self::SM == 0 {
            // No multipliers (an unconstrained system): the velocity blocks
            // are the whole matrix.
            self.factored = true;
            return Ok(());
        }
        // X[i][l] = coef_il · W_i⁻¹ (K_lᵀ − ∂N_l/∂ψ), coef = ã_il (b̃_l for i = S);
        // with the stiffness kept, X = A⁻¹ B of the coupled blocks instead.
        let (nm, sm) = (N * M, Self::SM);
        for l in 0..S {
            let mut kt = self.constraint_v[l].transpose();
            if let Some(np) = nonideal_psi {
                kt -= &np[l];
            }
            if self.coupled && self.stiff.columns().is_some() {
                // By coordinate (below, with every stage's `K_lᵀ`).
                self.kt[l * nm..(l + 1) * nm].copy_from_slice(kt.as_slice());
                continue;
            }
            if self.coupled {
                self.coupled_columns(tab, l, &kt);
                continue;
            }
            if self.shared {
                for col in kt.as_mut_slice().chunks_exact_mut(N) {
                    self.solve_block(0, col);
                }
                self.kt[l * nm..(l + 1) * nm].copy_from_slice(kt.as_slice());
                continue;
            }
            for i in 0..=S {
                let coef = if i < S { tab.a_tilde[i][l] } else { tab.b_tilde[l] };
                for (e, ke) in kt.as_slice().chunks_exact(N).enumerate() {
                    let mut col = [0.0; N];
                    for (d, k) in col.iter_mut().zip(ke) {
                        *d = coef * k;
                    }
                    if coef != 0.0 {
                        solve_in_place::<N>(&self.w[i * nn..(i + 1) * nn], &self.w_perm[i * N..(i + 1) * N], &mut col);
                    }
                    let x_all = &mut self.x[..(S + 1) * N * sm];
                    for (k, v) in col.into_iter().enumerate() {
                        x_all[(i * N + k) * sm + l * M + e] = v;
                    }
                }
            }
        }
        if self.shared && !self.coupled {
            shared_mass_rows::<N, M, S>(&mut self.x[..(S + 1) * N * sm], &self.kt[..S * nm], tab);
        } else if let (true, Some(g)) = (self.coupled, self.stiff.columns()) {
            coordinate_rows::<N, M, S>(&mut self.x[..(S + 1) * N * sm], &self.kt[..S * nm], g);
        }
        self.write_constraint_blocks(tab, h);
        // Σ = E − Σ_i C[r][i] X[i][·], row by row: row (r, d) less
        // C[r][i][d, k] times row (i, k) of X, in the order i, then k, for
        // every entry (the order of the block form). Slices of constant
        // length: inline stores, not a `memset` call, and row indexing
        // without bounds checks.
        let (c_all, c_nonzero) = (&self.c[..S * (S + 1) * nm], &self.c_nonzero[..S * (S + 1)]);
        let x_all = &self.x[..(S + 1) * N * sm];
        let rows = &mut self.rows[..sm * sm];
        rows.fill(0.0);
        if tab.conditions == ConditionRows::EqualMultipliers {
            for r in 0..S.saturating_sub(1) {
                for d in 0..M {
                    rows[(r * M + d) * sm + r * M + d] = 1.0;
                    rows[(r * M + d) * sm + (r + 1) * M + d] = -1.0;
                }
            }
        }
        if sm <= 2 {
            // One or two multipliers: inline (the out-of-line call lengthens
            // the short steps' chain more than the kernel saves).
            schur_rows_inline::<N, M, S>(rows, c_all, c_nonzero, x_all, self.c_finite);
        } else {
            schur_rows::<N, M, S>(rows, c_all, c_nonzero, x_all, self.c_finite);
        }
        // The LU factors Σ by columns.
        let schur = &mut self.schur[..sm * sm];
        for (j, col) in schur.chunks_exact_mut(sm).enumerate() {
            for (a, row) in col.iter_mut().zip(rows.chunks_exact(sm)) {
                *a = row[j];
            }
        }
        factor_runtime(&mut self.schur, sm, &mut self.schur_perm, &mut self.schur_scale)?;
        self.factored = true;
        Ok(())
    }

    /// Columns `l` of `X = A⁻¹ B` for the coupled blocks: with `kt = K_lᵀ`
    /// (`N × M`), the stage part solves `T x = (ã_il kt)_i` and the end
    /// point's is `W⁻¹ (b̃_l kt + Σ_k h² (b̂ᵀA)_k F_q x_k)`.
    fn coupled_columns(&mut self, tab: &Tableau<S>, l: usize, kt: &Matrix<N, M>) {
        let sm = Self::SM;
        for e in 0..M {
            let col = &kt.as_slice()[e * N..(e + 1) * N];
            for i in 0..S {
                for (d, k) in self.coupled_rhs[i * N..(i + 1) * N].iter_mut().zip(col) {
                    *d = tab.a_tilde[i][l] * k;
                }
            }
            let mut end = [0.0; N];
            for (d, k) in end.iter_mut().zip(col) {
                *d = tab.b_tilde[l] * k;
            }
            self.stiff.solve_stages(&mut self.coupled_rhs, &mut end);
            self.solve_block(0, &mut end);
            for (q, &v) in self.coupled_rhs[..S * N].iter().chain(&end).enumerate() {
                self.x[q * sm + l * M + e] = v;
            }
        }
    }

    /// Factors `mass` as the one block of every stage, unless its factors
    /// are already kept.
    fn factor_shared(&mut self, mass: &[f64]) -> Result<(), Singular> {
        self.shared = true;
        if !(self.w_valid && &*self.w_source == mass) {
            self.w_valid = false;
            self.stiff.mass_changed();
            self.diagonal = factor_mass::<N>(mass, &mut self.w_rdiag, &mut self.w[..N * N], &mut self.w_perm[..N])?;
            self.identity = self.diagonal && self.w_rdiag[..N].iter().all(|&r| r == 1.0);
            self.w_source.copy_from_slice(mass);
            self.w_valid = true;
        }
        Ok(())
    }

    /// `x ← W_b⁻¹ x` with the factors of velocity block `b` (block 0 stands
    /// for every block when `shared`).
    #[inline(always)]
    fn solve_block(&self, b: usize, x: &mut [f64]) {
        if self.identity {
            // `x · 1` is `x`, NaN and signed zeros included.
            return;
        }
        if self.diagonal {
            for (xi, r) in x[..N].iter_mut().zip(self.w_rdiag.iter()) {
                *xi *= r;
            }
        } else {
            let nn = N * N;
            solve_in_place::<N>(&self.w[b * nn..(b + 1) * nn], &self.w_perm[b * N..(b + 1) * N], x);
        }
    }

    /// LU factors of one `N × N` mass matrix.
    pub(crate) fn factor_block(lu: &mut [f64], perm: &mut [usize], mass: &[f64]) -> Result<(), Singular> {
        // Scales from the source: scanning the fresh copy would wait on its stores.
        let scale = column_scales::<N>(mass);
        lu.copy_from_slice(mass);
        factor_in_place::<N>(lu, perm, &scale, &[N])
    }

    /// `C[r][i]`: the constraint rows' derivatives in the velocity unknowns,
    /// written exactly as the exact Newton matrix has them.
    fn write_constraint_blocks(&mut self, tab: &Tableau<S>, h: f64) {
        let mn = M * N;
        self.c_nonzero[..S * (S + 1)].fill(false);
        let (kv, kq) = (&self.constraint_v, &self.constraint_q);
        // NaN exactly when a written entry is not finite (`x·0` is NaN for
        // an infinite or NaN `x`, 0 otherwise).
        let mut probe = 0.0;
        let mut put = |r: usize, i: usize, blk: &Matrix<M, N>| {
            let at = (r * (S + 1) + i) * mn;
            self.c[at..at + mn].copy_from_slice(blk.as_slice());
            self.c_nonzero[r * (S + 1) + i] = true;
            probe += blk.sum() * 0.0;
        };
        match tab.conditions {
            ConditionRows::Omega => {
                for r in 0..S.saturating_sub(1) {
                    for l in 0..S {
                        let mut blk = tab.omega[r][l] * kv[l];
                        // Every term, a zero product `ω_rm a_ml` too (see
                        // `step::equations::increment`).
                        for m in 0..S {
                            let c = tab.omega[r][m] * tab.a[m][l];
                            blk += (h * c) * kq[m];
                        }
                        put(r, l, &blk);
                    }
                }
            }
            ConditionRows::MidpointConstraint => {
                put(0, 0, &(kv[S + 1] + (0.5 * h) * kq[S + 1]));
            }
            ConditionRows::EqualMultipliers => {}
        }
        for l in 0..S {
            put(S - 1, l, &((h * tab.b[l]) * kq[S]));
        }
        put(S - 1, S, &kv[S]);
        self.c_finite = probe == 0.0;
    }

    /// Overwrites `g` (a residual, rows in the stepper's order) with the
    /// update `J̃⁻¹ g` in the order of the unknowns `z = [V | μ | v₁]`.
    /// Leaves `g` unchanged unless [`factor`](Self::factor) succeeded.
    pub(crate) fn solve_in_place<const D: usize>(&self, g: &mut Vector<D>) {
        if !self.factored {
            return;
        }
        let (nm, sm) = (N * M, Self::SM);
        let base = (S + 1) * N;
        // In place, in the row order `[V | p₁ | constraint rows]` (a copy of
        // `g` as scratch would be a `memcpy` call per update at D ≥ 17); one
        // rotation at the end gives the order of `z`.
        let g = g.as_mut_slice();
        if self.coupled {
            // y_V = T⁻¹ g_V, then y₁ = W⁻¹ (g₁ + Σ_k h² (b̂ᵀA)_k F_q y_k).
            let (stages, end) = g.split_at_mut(S * N);
            self.stiff.solve_stages(stages, &mut end[..N]);
            self.solve_block(0, &mut end[..N]);
        } else {
            // y_i = W_i⁻¹ g_i for the S + 1 velocity blocks.
            for i in 0..=S {
                let b = if self.shared { 0 } else { i };
                self.solve_block(b, &mut g[i * N..(i + 1) * N]);
            }
        }
        let (vel, con) = g.split_at_mut(base);
        let (c, c_nonzero, x) = (&self.c[..S * (S + 1) * nm], &self.c_nonzero[..S * (S + 1)], &self.x[..base * sm]);
        if sm > 0 {
            solve_multipliers::<N, M, S>(
                &mut vel[..base],
                &mut con[..sm],
                c,
                c_nonzero,
                x,
                &self.schur,
                &self.schur_perm,
            );
        }
        // `[v₁ | δμ]` → `[δμ | v₁]`: the order of `z`.
        g[S * N..].rotate_left(N);
    }
}

/// The rows of `X` for a shared mass matrix: `X[i][l] = coef_il · kt_l`,
/// `coef = ã_il` (`b̃_l` for `i = S`), with `kt_l = W⁻¹ (K_lᵀ − ∂N_l/∂ψ)` at
/// `l·N·M` of `kt`; row `(i, k)` at a time. Out of line, so that the rows
/// written are known not to overlap what is read.
#[inline(never)]
fn shared_mass_rows<const N: usize, const M: usize, const S: usize>(x: &mut [f64], kt: &[f64], tab: &Tableau<S>) {
    let (nm, sm) = (N * M, S * M);
    let (x, kt) = (&mut x[..(S + 1) * N * sm], &kt[..S * nm]);
    for (i, rows) in x.chunks_exact_mut(N * sm).enumerate() {
        let coefs = if i < S { &tab.a_tilde[i] } else { &tab.b_tilde };
        for (k, row) in rows.chunks_exact_mut(sm).enumerate() {
            for (l, coef) in coefs.iter().enumerate() {
                for e in 0..M {
                    row[l * M + e] = coef * kt[l * nm + e * N + k];
                }
            }
        }
    }
}

/// The rows of `X` for a constant stiffness kept by coordinate:
/// `X[i][l][c, e] = g[c][l][i] · K_lᵀ[c, e]`, with `K_lᵀ` (`N × M`) at
/// `l·N·M` of `kt` and `g` the coordinates' stage columns
/// (`StiffStages::columns`); row `(i, c)` at a time, out of line as
/// [`shared_mass_rows`].
#[inline(never)]
fn coordinate_rows<const N: usize, const M: usize, const S: usize>(x: &mut [f64], kt: &[f64], g: &[f64]) {
    let (nm, sm) = (N * M, S * M);
    let (x, kt, g) = (&mut x[..(S + 1) * N * sm], &kt[..S * nm], &g[..N * S * (S + 1)]);
    for (i, rows) in x.chunks_exact_mut(N * sm).enumerate() {
        for (c, row) in rows.chunks_exact_mut(sm).enumerate() {
            for l in 0..S {
                let gi = g[(c * S + l) * (S + 1) + i];
                for e in 0..M {
                    row[l * M + e] = gi * kt[l * nm + e * N + c];
                }
            }
        }
    }
}

/// Calls `f(r, i, C[r][i])` for every nonzero block of `C` (`M × N`,
/// column-major), row block `r` by row block, point `i` by point: the
/// order every product with `C` keeps.
#[inline(always)]
fn for_each_constraint_block<const N: usize, const M: usize, const S: usize>(
    c: &[f64],
    c_nonzero: &[bool],
    mut f: impl FnMut(usize, usize, &[f64]),
) {
    let nm = N * M;
    for r in 0..S {
        for i in 0..=S {
            if c_nonzero[r * (S + 1) + i] {
                f(r, i, &c[(r * (S + 1) + i) * nm..(r * (S + 1) + i + 1) * nm]);
            }
        }
    }
}

/// The constraint rows of the stage-decoupled solve, after the velocity
/// blocks: `con ← Σ⁻¹ (con − C vel)`, then `vel ← vel − X con`; each entry's
/// products in the order of the block forms (point i, then coordinate k;
/// multiplier l, then e). Slices of constant length, so that the block
/// indexing needs no bounds checks. Inline: every Newton update waits on
/// this solve, and out of line (where the slices would be known not to
/// overlap, 1–5 % fewer instructions a step at s ≥ 3) its call and the
/// reloads of what the caller just stored make the short steps slower
/// (the particle's Gauss s = 1 348 → 389 ns a step).
#[inline(always)]
fn solve_multipliers<const N: usize, const M: usize, const S: usize>(
    vel: &mut [f64],
    con: &mut [f64],
    c: &[f64],
    c_nonzero: &[bool],
    x: &[f64],
    schur: &[f64],
    schur_perm: &[usize],
) {
    let sm = S * M;
    for_each_constraint_block::<N, M, S>(c, c_nonzero, |r, i, c| {
        let yi = &vel[i * N..(i + 1) * N];
        let out = &mut con[r * M..(r + 1) * M];
        for (k, yk) in yi.iter().enumerate() {
            for (o, ck) in out.iter_mut().zip(&c[k * M..(k + 1) * M]) {
                *o -= ck * yk;
            }
        }
    });
    solve_runtime(schur, sm, schur_perm, con);
    for (o, x) in vel.iter_mut().zip(x.chunks_exact(sm)) {
        for (xk, mu) in x.iter().zip(&*con) {
            *o -= xk * mu;
        }
    }
}

/// Subtracts `C X` from the Schur complement held by rows in `rows`: row
/// `(r, d)` less `C[r][i][d, k]` times row `(i, k)` of `X`, in the order i,
/// then k, for every entry (the order of the block form `Σ_i C[r][i]
/// X[i][l]`). Its own function, out of line, so that the slices are known
/// not to overlap: the rows stay in registers between their products.
#[inline(never)]
fn schur_rows<const N: usize, const M: usize, const S: usize>(
    rows: &mut [f64],
    c: &[f64],
    c_nonzero: &[bool],
    x: &[f64],
    c_finite: bool,
) {
    schur_rows_inline::<N, M, S>(rows, c, c_nonzero, x, c_finite);
}

/// [`schur_rows`]' body, inlined where the complement is at most 2 × 2.
#[inline(always)]
fn schur_rows_inline<const N: usize, const M: usize, const S: usize>(
    rows: &mut [f64],
    c: &[f64],
    c_nonzero: &[bool],
    x: &[f64],
    c_finite: bool,
) {
    let (sm, nm) = (S * M, N * M);
    // The blocks of `for_each_constraint_block`, walked here rather than
    // through its closure: the loop over the blocks unrolls into one call
    // per block, and in a binary with many steppers LLVM leaves the closure
    // out of line (a call and its reloads per block).
    for r in 0..S {
        for i in 0..=S {
            if !c_nonzero[r * (S + 1) + i] {
                continue;
            }
            let c = &c[(r * (S + 1) + i) * nm..(r * (S + 1) + i + 1) * nm];
            for (k, x) in x[i * N * sm..(i + 1) * N * sm].chunks_exact(sm).enumerate() {
                for d in 0..M {
                    let (ck, row) = (c[k * M + d], &mut rows[(r * M + d) * sm..(r * M + d + 1) * sm]);
                    if c_finite {
                        // A zero entry of X (a structural zero of K) subtracts a
                        // zero product: the entry, never −0 (it starts at +0 or
                        // ±1, and a difference is −0 only from −0), keeps its
                        // bits.
                        for (s, xk) in row.iter_mut().zip(x) {
                            *s -= ck * xk;
                        }
                    } else {
                        // An infinite entry of C times a zero entry of X would
                        // be NaN: those products are left out.
                        for (s, &xk) in row.iter_mut().zip(x) {
                            let updated = *s - ck * xk;
                            *s = if xk != 0.0 { updated } else { *s };
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    //! The stage-decoupled solve against the dense solve of the same matrix,
    //! and the steps it converges to against tightly converged full Newton.

    // Stage loops index several parallel arrays with one index.
    #![allow(clippy::needless_range_loop)]

    use crate::fixtures::effects::{DrivenSkate, FrictionSkate};
    use crate::fixtures::paper::{General, MobileRobot, MpParticles, Particle, Skate};
    use crate::tests::{on_general_for_every_family, probe};
    use crate::*;

    const JAC: Jacobian = Jacobian::StageDecoupled;
    const PROJECT: ConsistencyPolicy = ConsistencyPolicy::Project { tolerance: 0.0 };

    /// The decoupled solve equals nalgebra's LU solve of the dense
    /// stage-decoupled matrix, with the full and (for a constant mass
    /// matrix) the lean evaluation of its blocks.
    fn check_solve<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
        sys: Sys,
        method: Method,
        state: State<N>,
        h: f64,
    ) where
        Sys: NonholonomicSystem<N, M>,
    {
        let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap());
        let z = probe::<D>();
        let lean_too = Sys::STRUCTURE.constant_mass_matrix && !Sys::HAS_NONIDEAL_FORCE;
        for lean in [false, true].into_iter().filter(|&l| !l || lean_too) {
            let (g, approx, x) = st.decoupled_solve(&state, h, &z, lean).unwrap();
            let dense = nalgebra::DMatrix::from_column_slice(D, D, approx.as_slice())
                .lu()
                .solve(&nalgebra::DVector::from_column_slice(g.as_slice()))
                .expect("the dense stage-decoupled matrix is regular");
            let err = (nalgebra::DVector::from_column_slice(x.as_slice()) - &dense).amax() / dense.amax();
            let name = Sys::SOURCE.name;
            assert!(err < 1e-12, "{name} {method} s={S} lean={lean}: decoupled vs dense solve {err:.3e}");
        }
    }

    /// A constant mass matrix is solved with its LU factors, or, when it is
    /// diagonal, with the reciprocals of its diagonal: both equal the dense
    /// solve of the same matrix, and a zero on the diagonal is singular.
    #[test]
    fn constant_mass_matrices_full_and_diagonal_solve_like_the_dense_matrix() {
        let k = State::new(0.0, Vector::<3>::new(0.1, 0.2, 0.3), Vector::<3>::new(0.4, -0.3, 1.0));
        let full = Matrix::<3, 3>::new(2.0, 0.3, 0.1, 0.3, 1.5, 0.2, 0.1, 0.2, 1.0);
        let diagonal = Matrix::<3, 3>::from_diagonal(&Vector::<3>::new(2.0, 1.5, 0.5));
        for method in [Method::Gauss, Method::LobattoIIIAB, Method::LobattoIIIABD] {
            let mut st = Stepper::<_, 3, 1, 2, 11>::new(Skate::default(), Tableau::new(method).unwrap());
            let z = probe::<11>();
            for mass in [full, diagonal] {
                let (g, approx, x) = st.decoupled_solve_with_mass(&k, 0.1, &z, &mass).unwrap();
                let dense = nalgebra::DMatrix::from_column_slice(11, 11, approx.as_slice())
                    .lu()
                    .solve(&nalgebra::DVector::from_column_slice(g.as_slice()))
                    .expect("regular");
                let err = (nalgebra::DVector::from_column_slice(x.as_slice()) - &dense).amax() / dense.amax();
                assert!(err < 1e-12, "{method} mass {mass}: decoupled vs dense solve {err:.3e}");
            }
            let singular = Matrix::<3, 3>::from_diagonal(&Vector::<3>::new(2.0, 0.0, 0.5));
            let err = st.decoupled_solve_with_mass(&k, 0.1, &z, &singular).unwrap_err();
            assert_eq!(err.column, 1, "{err:?}");
        }
    }

    #[test]
    fn the_schur_complement_solve_equals_the_dense_solve_of_the_same_matrix() {
        let g = State::new(0.4, Vector::<2>::new(0.3, -0.2), Vector::<2>::new(0.5, 0.1));
        on_general_for_every_family!(check_solve, g, 0.3);
        let r = State::new(0.0, Vector::<4>::new(0.1, 0.2, 0.7, 0.3), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
        check_solve::<_, 4, 2, 2, 16>(MobileRobot::default(), Method::Gauss, r, 0.2);
        check_solve::<_, 4, 2, 3, 22>(MobileRobot::default(), Method::LobattoIIIAB, r, 0.2);
        let m = State::new(0.0, Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]), Vector::zeros());
        check_solve::<_, 7, 1, 2, 23>(MpParticles, Method::Gauss, m, 0.1);
        check_solve::<_, 7, 1, 4, 39>(MpParticles, Method::LobattoIIIABD, m, 0.1);
        let k = State::new(0.0, Vector::<3>::new(0.1, 0.2, 0.3), Vector::<3>::new(0.4, -0.3, 1.0));
        check_solve::<_, 3, 1, 2, 11>(Skate::default(), Method::Gauss, k, 0.1);
        check_solve::<_, 3, 1, 2, 11>(FrictionSkate::default(), Method::Gauss, k, 0.1);
        check_solve::<_, 3, 1, 3, 15>(DrivenSkate::default(), Method::LobattoIIIAB, k, 0.1);
        // A constant stiffness: the stage blocks are coupled.
        check_solve::<_, 3, 1, 2, 11>(Particle, Method::Gauss, k, 0.2);
        check_solve::<_, 3, 1, 4, 19>(Particle, Method::Gauss, k, 0.2);
        check_solve::<_, 3, 1, 3, 15>(Particle, Method::LobattoIIIAB, k, 0.2);
        check_solve::<_, 3, 1, 3, 15>(Particle, Method::LobattoIIIABD, k, 0.2);
    }

    /// Steps from `state` with simplified Newton on the stage-decoupled
    /// matrix equal tightly converged full Newton steps; returns how many
    /// steps were left on the exact matrix after the run.
    fn check_steps<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
        sys: Sys,
        method: Method,
        state: State<N>,
        h: f64,
        steps: usize,
    ) -> u32
    where
        Sys: NonholonomicSystem<N, M> + Clone,
    {
        let tableau = Tableau::new(method).unwrap();
        let opts = NewtonOptions { mode: NewtonMode::Simplified, jacobian: JAC, ..NewtonOptions::default() };
        let mut st = Stepper::<Sys, N, M, S, D>::new(sys.clone(), tableau).with_options(opts);
        let tight =
            NewtonOptions { tolerance: 0.0, max_iterations: 32, energy_drift_limit: None, ..NewtonOptions::default() };
        let mut reference = Stepper::<Sys, N, M, S, D>::new(sys, tableau).with_options(tight);
        let mut s = state;
        let mut worst = 0.0f64;
        for _ in 0..steps {
            let a = st.step(&s, h).unwrap();
            let b = reference.step(&s, h).unwrap();
            let scale = |x: f64| 1.0 + x.abs();
            for (x, y) in a.state.q.iter().zip(b.state.q.iter()).chain(a.state.v.iter().zip(b.state.v.iter())) {
                worst = worst.max((x - y).abs() / scale(*y));
            }
            // The multipliers as the unknowns μ = hΨ they are solved for.
            for (pa, pb) in a.stage_multipliers.iter().zip(b.stage_multipliers.iter()) {
                for (x, y) in pa.iter().zip(pb.iter()) {
                    worst = worst.max(h * (x - y).abs() / scale(h * y));
                }
            }
            // The stepper under test continues its own steps (warm starts);
            // the reference solves each of them again from the same state.
            s = a.state;
        }
        let name = Sys::SOURCE.name;
        assert!(worst <= 1e-14, "{name} {method} s={S} h={h}: decoupled vs tight step {worst:.3e}");
        st.exact_steps_left()
    }

    #[test]
    fn decoupled_steps_equal_the_tight_solve() {
        let m = State::new(0.0, Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]), Vector::zeros());
        let r = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0));
        let k = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
        for h in [0.05, 0.2] {
            assert_eq!(check_steps::<_, 7, 1, 2, 23>(MpParticles, Method::Gauss, m, h, 20), 0);
            assert_eq!(check_steps::<_, 7, 1, 4, 39>(MpParticles, Method::Gauss, m, h, 20), 0);
            assert_eq!(check_steps::<_, 7, 1, 3, 31>(MpParticles, Method::LobattoIIIAB, m, h, 20), 0);
            assert_eq!(check_steps::<_, 7, 1, 3, 31>(MpParticles, Method::LobattoIIIABD, m, h, 20), 0);
            assert_eq!(check_steps::<_, 4, 2, 2, 16>(MobileRobot::default(), Method::Gauss, r, h, 20), 0);
            assert_eq!(check_steps::<_, 3, 1, 3, 15>(Skate::default(), Method::LobattoIIIAB, k, h, 20), 0);
        }
        let p = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
        for h in [0.05, 0.2] {
            assert_eq!(check_steps::<_, 3, 1, 1, 7>(Particle, Method::Gauss, p, h, 20), 0);
            assert_eq!(check_steps::<_, 3, 1, 3, 15>(Particle, Method::Gauss, p, h, 20), 0);
            assert_eq!(check_steps::<_, 3, 1, 4, 19>(Particle, Method::LobattoIIIAB, p, h, 20), 0);
            assert_eq!(check_steps::<_, 3, 1, 2, 11>(Particle, Method::LobattoIIIABD, p, h, 20), 0);
        }
        check_steps::<_, 3, 1, 2, 11>(FrictionSkate::default(), Method::Gauss, k, 0.1, 20);
        check_steps::<_, 3, 1, 2, 11>(DrivenSkate::default(), Method::Gauss, k, 0.1, 20);
        let g = State::new(0.0, Vector::<2>::new(0.3, -0.2), Vector::<2>::new(0.5, 0.0));
        let g = State { v: consistent_velocity(&General::default(), g.t, &g.q, &g.v, PROJECT).unwrap(), ..g };
        check_steps::<_, 2, 1, 2, 8>(General::default(), Method::Gauss, g, 0.05, 20);
        check_steps::<_, 2, 1, 2, 8>(General::default(), Method::ModifiedLobattoIIIAB, g, 0.05, 20);
    }

    #[test]
    fn a_slow_decoupled_iteration_falls_back_to_the_exact_matrix() {
        // At h = 0.6 the dropped couplings h²·∂F/∂q of the
        // McLachlan–Perlmutter potential are of order one: the
        // stage-decoupled iteration is too slow to keep.
        let m = State::new(0.0, Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]), Vector::zeros());
        let left = check_steps::<_, 7, 1, 2, 23>(MpParticles, Method::Gauss, m, 0.6, 3);
        assert!(left > 0, "the stage-decoupled matrix was kept at a slow rate");
    }

    #[test]
    fn full_newton_refuses_the_stage_decoupled_matrix() {
        let opts = NewtonOptions { jacobian: Jacobian::StageDecoupled, ..NewtonOptions::default() };
        let err = opts.validate().unwrap_err();
        assert_eq!(err.option, "NewtonOptions::jacobian");
        type Skate2 = Stepper![Skate, 2];
        let mut st = Skate2::new(Skate::default(), Tableau::new(Method::Gauss).unwrap()).with_options(opts);
        let k = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
        assert!(matches!(st.step(&k, 0.1), Err(StepError::InvalidOption(_))));
    }

    /// An identity mass matrix skips its solves, bit for bit what the
    /// products with its reciprocals give; a diagonal one a rounding away
    /// from it does not.
    #[test]
    fn an_identity_mass_matrix_skips_its_solves_bit_for_bit() {
        use super::{DecoupledMatrix, Masses};
        let tab = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
        let factored = |mass: &nalgebra::Matrix3<f64>| {
            let mut m = DecoupledMatrix::<3, 1, 2>::new(false);
            for p in 0..4 {
                m.constraint_v[p] = nalgebra::Matrix1x3::new(1.0, -0.5, 0.25);
                m.constraint_q[p] = nalgebra::Matrix1x3::new(0.5, 2.0, -1.0);
            }
            m.factor(&tab, 0.1, Masses::Constant(mass), None).expect("regular");
            m
        };
        let identity = factored(&nalgebra::Matrix3::identity());
        assert!(identity.identity);
        let mut products = identity.clone();
        products.identity = false;
        let g = Vector::<11>::from_fn(|i, _| [-0.0, 1.5, f64::NAN, 3.25e-300, -7.0][i % 5]);
        let (mut a, mut b) = (g, g);
        identity.solve_in_place(&mut a);
        products.solve_in_place(&mut b);
        let bits = |v: &Vector<11>| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a), bits(&b));
        let near = nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0 + f64::EPSILON, 1.0));
        assert!(!factored(&near).identity);
    }

    /// A system without constraints has no multipliers: the matrix is its
    /// velocity blocks, and the solve divides by the mass.
    #[test]
    fn an_unconstrained_system_solves_by_its_mass_alone() {
        use super::{DecoupledMatrix, Masses};
        let tab = Tableau::<2>::new(Method::Gauss).unwrap();
        let mass = nalgebra::Matrix3::<f64>::from_diagonal(&nalgebra::Vector3::new(2.0, 4.0, 8.0));
        let mut m = DecoupledMatrix::<3, 0, 2>::new(false);
        m.factor(&tab, 0.1, Masses::Constant(&mass), None).expect("a regular mass matrix");
        let mut g = Vector::<9>::from_fn(|i, _| i as f64 + 1.0);
        m.solve_in_place(&mut g);
        let expected = Vector::<9>::from_fn(|i, _| (i as f64 + 1.0) / mass[(i % 3, i % 3)]);
        assert_eq!(g, expected);
    }

    /// An infinite entry of `k_q` where `K` has a structural zero (a
    /// constraint not differentiable in a coordinate its velocity leaves
    /// out) multiplies zero entries of `X` only: the products are left out,
    /// as the block form leaves them, and the Schur complement stays finite.
    /// The same matrix with that entry finite takes the path without the
    /// exclusion and gives the same factors bit for bit.
    #[test]
    fn an_infinite_constraint_derivative_against_a_structural_zero_is_left_out() {
        use super::{DecoupledMatrix, Masses};
        let tab = Tableau::<2>::new(Method::Gauss).unwrap();
        let identity = nalgebra::Matrix3::<f64>::identity();
        let factors = |kq_y: f64| {
            let mut m = DecoupledMatrix::<3, 1, 2>::new(false);
            for p in 0..4 {
                m.constraint_v[p] = nalgebra::Matrix1x3::new(1.0, 0.0, 0.5);
                m.constraint_q[p] = nalgebra::Matrix1x3::new(0.25, kq_y, 0.0);
            }
            m.factor(&tab, 0.1, Masses::Constant(&identity), None).map(|()| (m.c_finite, m.schur.to_vec()))
        };
        let (finite, exact) = factors(0.0).expect("a regular Schur complement");
        assert!(finite);
        let (finite, excluded) = factors(f64::INFINITY).expect("the infinite entry is left out");
        assert!(!finite);
        assert!(excluded.iter().all(|x| x.is_finite()), "{excluded:?}");
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&excluded), bits(&exact));
    }
}
