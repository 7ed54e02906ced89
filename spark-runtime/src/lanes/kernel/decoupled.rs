//! The kernel's stage-decoupled Newton matrix, in lanes: its factors from
//! the constraint Jacobians and the solve with them
//! (`linalg::decoupled::DecoupledMatrix`, operation for operation; the
//! Schur complement is factored by `lanes::lane_lu`).

// Stage and lane loops index several parallel arrays with one index.
#![allow(clippy::needless_range_loop)]

use super::{Kernel, MassSolve, Outcome, L};
use crate::lanes::lane_lu;
use crate::linalg::solve_in_place;
use crate::tableau::{ConditionRows, Tableau};

impl<const N: usize, const M: usize, const S: usize, const D: usize, const W: usize> Kernel<N, M, S, D, W> {
    /// One row of lane values times a diagonal mass matrix's reciprocal.
    #[inline(always)]
    fn scaled(mut x: L<W>, reciprocal: f64) -> L<W> {
        for xw in x.iter_mut() {
            *xw *= reciprocal;
        }
        x
    }

    /// `x ← W⁻¹ x` for the `N` lane values at `at` of `x`.
    #[inline(always)]
    pub(super) fn solve_mass(mass: &MassSolve, x: &mut [L<W>], at: usize) {
        match mass {
            MassSolve::Diagonal(r) => {
                for n in 0..N {
                    x[at + n] = Self::scaled(x[at + n], r[n]);
                }
            }
            MassSolve::Lu { lu, perm } => {
                for w in 0..W {
                    let mut col = [0.0; N];
                    for n in 0..N {
                        col[n] = x[at + n][w];
                    }
                    solve_in_place::<N>(lu, perm, &mut col);
                    for n in 0..N {
                        x[at + n][w] = col[n];
                    }
                }
            }
        }
    }

    /// Factors the stage-decoupled matrix of every iterating lane from the
    /// constraint Jacobians of the latest evaluation
    /// (`DecoupledMatrix::factor` with a shared mass block); a lane whose
    /// Schur complement is singular is handed back.
    #[inline(always)]
    pub(super) fn factor(&mut self, tab: &Tableau<S>, iterating: &mut [bool; W], out: &mut [Outcome; W]) {
        let sm = Self::SM;
        // X[i][l] = coef_il · W⁻¹ K_lᵀ.
        let kt = &mut self.kt;
        for l in 0..S {
            if let Some(g) = self.stiff.columns() {
                // A constant stiffness by coordinate: X[i][l][n, e] = g[n][l][i] · K_l[e, n].
                for i in 0..=S {
                    for e in 0..M {
                        for n in 0..N {
                            let (gi, k) = (g[(n * S + l) * (S + 1) + i], self.jacobians[l].constraint_v[n][e]);
                            let mut x = [0.0; W];
                            for w in 0..W {
                                x[w] = gi * k[w];
                            }
                            self.x[i * S + l][e][n] = x;
                        }
                    }
                }
                continue;
            }
            for e in 0..M {
                for n in 0..N {
                    kt[e * N + n] = self.jacobians[l].constraint_v[n][e];
                }
                Self::solve_mass(&self.mass, kt, e * N);
            }
            for i in 0..=S {
                let coef = if i < S { tab.a_tilde[i][l] } else { tab.b_tilde[l] };
                for e in 0..M {
                    for n in 0..N {
                        let k = kt[e * N + n];
                        let mut x = [0.0; W];
                        for w in 0..W {
                            x[w] = coef * k[w];
                        }
                        self.x[i * S + l][e][n] = x;
                    }
                }
            }
        }
        self.constraint_blocks(tab);
        // Σ = E − Σ_i C[r][i] X[i][l].
        let schur = &mut self.schur;
        schur.fill([0.0; W]);
        if tab.conditions == ConditionRows::EqualMultipliers {
            for r in 0..S.saturating_sub(1) {
                for d in 0..M {
                    schur[(r * M + d) * sm + r * M + d] = [1.0; W];
                    schur[((r + 1) * M + d) * sm + r * M + d] = [-1.0; W];
                }
            }
        }
        for r in 0..S {
            for i in 0..=S {
                if !self.c_nonzero[r * (S + 1) + i] {
                    continue;
                }
                let c = &self.c[r * (S + 1) + i];
                for l in 0..S {
                    let x = &self.x[i * S + l];
                    for e in 0..M {
                        for m in 0..M {
                            let at = (l * M + e) * sm + r * M + m;
                            let mut acc = schur[at];
                            for k in 0..N {
                                let (xk, ck) = (x[e][k], c[k][m]);
                                for w in 0..W {
                                    // The scalar assembly skips a zero `X` entry:
                                    // the product is formed in every lane and
                                    // selected (a conditional product is
                                    // compiled to a branch per lane).
                                    let updated = acc[w] - ck[w] * xk[w];
                                    acc[w] = if xk[w] != 0.0 { updated } else { acc[w] };
                                }
                            }
                            schur[at] = acc;
                        }
                    }
                }
            }
        }
        let mut live = *iterating;
        lane_lu::factor(&mut self.schur, sm, &mut self.schur_perm, &mut self.schur_scale, &mut live);
        for w in 0..W {
            if iterating[w] && !live[w] {
                (iterating[w], out[w]) = (false, Outcome::HandBack);
            }
        }
    }

    /// `C[r][i]`, as `DecoupledMatrix::write_constraint_blocks` writes them.
    #[inline(always)]
    pub(super) fn constraint_blocks(&mut self, tab: &Tableau<S>) {
        let (mn, h) = (M * N, self.h);
        self.c_nonzero.fill(false);
        let jac = &self.jacobians;
        let kv = |p: usize, e: usize| jac[p].constraint_v[e / M][e % M];
        let kq = |p: usize, e: usize| jac[p].constraint_q[e / M][e % M];
        let (c, nonzero) = (&mut self.c, &mut self.c_nonzero);
        let mut put = |r: usize, i: usize, e: usize, x: L<W>| {
            c[r * (S + 1) + i][e / M][e % M] = x;
            nonzero[r * (S + 1) + i] = true;
        };
        match tab.conditions {
            ConditionRows::Omega => {
                for r in 0..S.saturating_sub(1) {
                    for l in 0..S {
                        for e in 0..mn {
                            let (mut blk, k) = ([0.0; W], kv(l, e));
                            for w in 0..W {
                                blk[w] = tab.omega[r][l] * k[w];
                            }
                            for m in 0..S {
                                let cm = tab.omega[r][m] * tab.a[m][l];
                                let (hc, k) = (h * cm, kq(m, e));
                                for w in 0..W {
                                    blk[w] += hc * k[w];
                                }
                            }
                            put(r, l, e, blk);
                        }
                    }
                }
            }
            ConditionRows::MidpointConstraint => {
                let half = 0.5 * h;
                for e in 0..mn {
                    let mut blk = [0.0; W];
                    let (kve, kqe) = (kv(S + 1, e), kq(S + 1, e));
                    for w in 0..W {
                        blk[w] = kve[w] + half * kqe[w];
                    }
                    put(0, 0, e, blk);
                }
            }
            ConditionRows::EqualMultipliers => {}
        }
        for l in 0..S {
            let hb = h * tab.b[l];
            for e in 0..mn {
                let mut blk = [0.0; W];
                let k = kq(S, e);
                for w in 0..W {
                    blk[w] = hb * k[w];
                }
                put(S - 1, l, e, blk);
            }
        }
        for e in 0..mn {
            put(S - 1, S, e, kv(S, e));
        }
    }

    /// The update `Δz = J̃⁻¹ g` of the residual `g`
    /// (`DecoupledMatrix::solve_in_place`), applied to `z` row by row as
    /// the solve produces it (`Kernel::update_row`); returns each lane's
    /// scaled update norm (not finite for a lane whose update is not).
    #[inline(always)]
    pub(super) fn solve_and_update(&mut self, iterating: &[bool; W], first: bool) -> L<W> {
        // The iterating lanes as a bit mask, formed once (a select on the
        // `bool`s forms the vector mask again at every row).
        let applies: [u64; W] = iterating.map(|i| if i { u64::MAX } else { 0 });
        let sm = Self::SM;
        let base = (S + 1) * N;
        // `y = W⁻¹ g` on the momentum rows, `g` on the constraint rows: a
        // diagonal mass matrix scales as it copies.
        match &self.mass {
            MassSolve::Diagonal(r) if self.stiff.columns().is_some() => {
                // The stage blocks of a constant stiffness and the end row,
                // lane by lane with the steppers' own solve.
                let col = &mut self.stiff_column;
                for w in 0..W {
                    for d in 0..base {
                        col[d] = self.g[d][w];
                    }
                    let (stages, end) = col.split_at_mut(S * N);
                    self.stiff.solve_stages(stages, end);
                    for (x, rn) in end.iter_mut().zip(r.iter()) {
                        *x *= rn;
                    }
                    for d in 0..base {
                        self.y[d][w] = col[d];
                    }
                }
                for d in base..D {
                    self.y[d] = self.g[d];
                }
            }
            MassSolve::Diagonal(r) => {
                // Constant lengths: no bounds test or reload per row.
                let y: &mut [L<W>; D] = (&mut self.y[..D]).try_into().expect("D rows");
                let r: &[f64; N] = r[..N].try_into().expect("N reciprocals");
                for i in 0..=S {
                    for n in 0..N {
                        y[i * N + n] = Self::scaled(self.g[i * N + n], r[n]);
                    }
                }
                y[base..].copy_from_slice(&self.g[base..]);
            }
            MassSolve::Lu { .. } => {
                self.y.copy_from_slice(&self.g[..]);
                for i in 0..=S {
                    Self::solve_mass(&self.mass, &mut self.y, i * N);
                }
            }
        }
        let (vel, con) = self.y.split_at_mut(base);
        // Each entry of `con` takes its products in the order of the
        // stage-decoupled solve (point `i`, then coordinate `k`).
        for r in 0..S {
            for m in 0..M {
                let mut acc = con[r * M + m];
                for i in 0..=S {
                    if !self.c_nonzero[r * (S + 1) + i] {
                        continue;
                    }
                    let c = &self.c[r * (S + 1) + i];
                    for k in 0..N {
                        let (yk, ck) = (vel[i * N + k], c[k][m]);
                        for w in 0..W {
                            acc[w] -= ck[w] * yk[w];
                        }
                    }
                }
                con[r * M + m] = acc;
            }
        }
        lane_lu::solve(&self.schur, sm, &self.schur_perm, &mut con[..sm]);
        let mut norm = [0.0f64; W];
        let (z, weights) = (&mut self.z, &mut self.weights);
        // The first update, for the affine acceptance (`first_update_lands`).
        let keep = first && !self.first_update.is_empty();
        for i in 0..=S {
            let out_at = if i < S { i * N } else { S * (N + M) };
            for n in 0..N {
                let mut acc = vel[i * N + n];
                for l in 0..S {
                    let x = &self.x[i * S + l];
                    for e in 0..M {
                        let (mu, xe) = (con[l * M + e], x[e][n]);
                        for w in 0..W {
                            acc[w] -= xe[w] * mu[w];
                        }
                    }
                }
                let d = out_at + n;
                Self::update_row(&mut z[d], &mut weights[d], &acc, &applies, first, &mut norm);
                if keep {
                    self.first_update[d] = acc;
                }
            }
        }
        for e in 0..sm {
            let d = S * N + e;
            Self::update_row(&mut z[d], &mut weights[d], &con[e], &applies, first, &mut norm);
            if keep {
                self.first_update[d] = con[e];
            }
        }
        norm
    }
}
