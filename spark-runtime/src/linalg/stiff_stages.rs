//! The velocity blocks of the stage-decoupled Newton matrix for a system
//! with a constant stiffness `F_q = ∂(∇_q L)/∂q` (a quadratic potential) and
//! a constant mass matrix `W`: the stage rows' block
//! `T = I ⊗ W − h² (ÂA) ⊗ F_q` (`S·N` square, every stage coupled to every
//! other through `Q_j = q₀ + h Σ_k a_jk V_k`) and the end row's coupling
//! `−h² (b̂ᵀA)_k F_q` to stage `k` beside `W` on `v₁`. The blocks depend on
//! `h` only, so they are factored once per step size and kept.
//!
//! Two forms: when `W` and `F_q` are both diagonal (a potential that is a
//! sum of squares of the coordinates), `T` splits into one `S × S` block
//! `W_cc I − h² F_q,cc ÂA` per coordinate, kept as its inverse (an
//! `S × S` product per coordinate and solve; a coordinate without stiffness
//! is its reciprocal mass); otherwise `T` is one dense LU, used up to
//! `S·N = DENSE_MAX`. Beyond it the couplings are dropped as for any other
//! system: a run whose `h` changes at every step (error control) factors
//! `T` at every step, `⅔(S·N)³` flops, where the dropped form's refresh
//! costs a few products of `S·N·M` (the per-coordinate form's factors cost
//! `N·S³`).
//!
//! A diagonal stiffness that depends on the configuration (the mobile
//! robot's `10 sin φ`) is kept per stage point instead: with a diagonal `W`,
//! coordinate `c`'s block is `W_cc I − h² Â diag(F_q,cc(Q_j)) A` and the end
//! row's coupling `h² Σ_j b̂_j F_q,cc(Q_j) a_jk`, made again at every
//! refresh from the stiffness at that iterate's stage points
//! ([`kept_stiffness_points`] says which points enter).

use super::{factor_runtime, is_diagonal, solve_runtime, Singular};
use crate::tableau::Tableau;

/// The largest `S·N` for which a non-diagonal `T` is kept as a dense LU.
pub(crate) const DENSE_MAX: usize = 16;

/// Whether the stiffness at each stage point `j` is kept (a diagonal,
/// point-dependent stiffness): it enters stage row `i`'s block on stage `k`
/// as `h² â_ij F_q(Q_j) a_jk` and the end row's as `h² b̂_j F_q(Q_j) a_jk`,
/// so only through a nonzero row `j` of `A` and a nonzero column `j` of `Â`
/// or entry `b̂_j`. Lobatto IIIA-B's first point (`Q₁ = q₀`, row 1 of IIIA
/// zero) never enters. When `ÂA = 0` (Lobatto IIIA-B s = 2) the stiffness
/// couples no two stages, only the end row to them, and none is kept: with
/// it the robot's step takes as many updates (2.98) and 20 % more instructions.
/// A point not kept is not evaluated for its stiffness.
pub(crate) fn kept_stiffness_points<const S: usize>(tab: &Tableau<S>) -> [bool; S] {
    let couples_stages = (0..S).any(|i| (0..S).any(|k| (0..S).any(|l| tab.a_hat[i][l] * tab.a[l][k] != 0.0)));
    std::array::from_fn(|j| {
        couples_stages
            && tab.a[j].iter().any(|&a| a != 0.0)
            && ((0..S).any(|i| tab.a_hat[i][j] != 0.0) || tab.b_hat[j] != 0.0)
    })
}

/// The stage blocks of a constant stiffness (see the module docs); empty
/// storage when the system has none.
#[derive(Clone, Debug)]
pub(crate) struct StiffStages<const N: usize, const S: usize> {
    /// `F_q` (`N × N`, column-major) and whether it holds the system's.
    stiffness: Box<[f64]>,
    set: bool,
    /// The stiffness is diagonal and taken at each stage point: stage `j`'s
    /// diagonal at `j·N` of `stage_stiffness` (set by [`Self::set_stage`]).
    per_stage: bool,
    stage_stiffness: Box<[f64]>,
    /// Per stage stiffness, the end row's coefficient on stage `k` in
    /// coordinate `c` (at `c·S + k`): `h² Σ_j b̂_j F_q,cc(Q_j) a_jk`.
    end_by_coordinate: Box<[f64]>,
    /// The step size of the kept factors (NaN: none).
    h: f64,
    /// `h² (b̂ᵀA)_k`: the end row's coefficient on stage `k`.
    end_coupling: Box<[f64]>,
    /// `W` and `F_q` are diagonal: per coordinate `c`, the inverse of its
    /// `S × S` block (row-major, at `c·S·S`) when `F_q,cc ≠ 0`, else the
    /// coordinate's reciprocal mass in `rmass[c]`.
    by_coordinate: bool,
    inverse: Box<[f64]>,
    /// Per coordinate: `g[c][l][i]` (at `(c·S + l)·(S+1) + i`) with
    /// `(A⁻¹B)[i][l][c, e] = g[c][l][i] · K_l[e, c]` — point `i`'s velocity
    /// response in coordinate `c` to multiplier `l` — so a refresh forms
    /// `A⁻¹B` by products, without solves.
    columns: Box<[f64]>,
    stiff: Box<[bool]>,
    rmass: Box<[f64]>,
    /// Otherwise: the LU factors of `T`.
    lu: Box<[f64]>,
    perm: Box<[usize]>,
    scale: Box<[f64]>,
}

impl<const N: usize, const S: usize> StiffStages<N, S> {
    /// Storage (heap, allocated once); empty unless `keep`.
    pub(crate) fn new(keep: bool) -> Self {
        let sn = if keep { S * N } else { 0 };
        let dense = if sn <= DENSE_MAX { sn } else { 0 };
        let (n, s) = if keep { (N, S) } else { (0, 0) };
        StiffStages {
            stiffness: vec![0.0; n * n].into_boxed_slice(),
            set: false,
            per_stage: false,
            stage_stiffness: vec![0.0; s * n].into_boxed_slice(),
            end_by_coordinate: vec![0.0; n * s].into_boxed_slice(),
            h: f64::NAN,
            end_coupling: vec![0.0; s].into_boxed_slice(),
            by_coordinate: false,
            inverse: vec![0.0; n * s * s].into_boxed_slice(),
            columns: vec![0.0; n * s * (s + 1)].into_boxed_slice(),
            stiff: vec![false; n].into_boxed_slice(),
            rmass: vec![0.0; n].into_boxed_slice(),
            lu: vec![0.0; dense * dense].into_boxed_slice(),
            perm: vec![0; dense].into_boxed_slice(),
            scale: vec![0.0; dense].into_boxed_slice(),
        }
    }

    /// Sets the system's stiffness `F_q` (ignored without storage); the
    /// factors are made again only when it changed.
    pub(crate) fn set(&mut self, stiffness: &[f64]) {
        if self.stiffness.is_empty() {
            return;
        }
        if !(self.set && *self.stiffness == *stiffness) {
            self.stiffness.copy_from_slice(stiffness);
            self.h = f64::NAN;
        }
        self.set = true;
    }

    /// Sets the diagonal `F_q,cc` (`N` entries) of the stiffness at stage
    /// point `stage`, ignored without storage. The blocks then use each
    /// stage's own stiffness, and the factors are made again only when one
    /// changed.
    pub(crate) fn set_stage(&mut self, stage: usize, diagonal_of_stiffness: &[f64]) {
        if self.stage_stiffness.is_empty() {
            return;
        }
        let diagonal = &mut self.stage_stiffness[stage * N..(stage + 1) * N];
        for (d, &f) in diagonal.iter_mut().zip(diagonal_of_stiffness) {
            if d.to_bits() != f.to_bits() || !self.per_stage {
                *d = f;
                self.h = f64::NAN;
            }
        }
        self.per_stage = true;
        self.set = true;
    }

    /// Forgets the stiffness and the factors (the system changed).
    pub(crate) fn invalidate(&mut self) {
        self.set = false;
        self.per_stage = false;
        self.h = f64::NAN;
    }

    /// Forgets the factors (the mass matrix changed).
    pub(crate) fn mass_changed(&mut self) {
        self.h = f64::NAN;
    }

    /// Makes the blocks of step size `h` with the constant mass matrix `w`
    /// (`N × N`, column-major, regular; `w_diagonal`: whether it is
    /// diagonal, which its factorization found), unless they are kept.
    /// `Ok(false)`: no stiffness is set or a non-diagonal `T` is too large
    /// to keep, and the couplings are dropped.
    pub(crate) fn factor(&mut self, tab: &Tableau<S>, h: f64, w: &[f64], w_diagonal: bool) -> Result<bool, Singular> {
        if !self.set {
            return Ok(false);
        }
        if self.h.to_bits() == h.to_bits() {
            return Ok(true);
        }
        self.h = f64::NAN;
        let h2 = h * h;
        // (ÂA)_ik and h² (b̂ᵀA)_k.
        let aa = |i: usize, k: usize| -> f64 { (0..S).map(|j| tab.a_hat[i][j] * tab.a[j][k]).sum() };
        for k in 0..S {
            self.end_coupling[k] = h2 * (0..S).map(|j| tab.b_hat[j] * tab.a[j][k]).sum::<f64>();
        }
        let fq = &self.stiffness;
        // The per-coordinate blocks live in fixed arrays of 8 × 8.
        self.by_coordinate = S <= 8 && w_diagonal && (self.per_stage || is_diagonal::<N>(fq));
        if self.per_stage && !self.by_coordinate {
            // A stiffness per stage is kept by coordinate only.
            return Ok(false);
        }
        if self.by_coordinate {
            let mut block = [0.0; 64];
            let (mut perm, mut scale) = ([0usize; 8], [0.0; 8]);
            for c in 0..N {
                let (wc, fc) = (w[c * (N + 1)], fq[c * (N + 1)]);
                // Coordinate `c`'s stiffness at stage point `j`.
                let stage_f = |j: usize| if self.per_stage { self.stage_stiffness[j * N + c] } else { fc };
                self.stiff[c] = (0..S).any(|j| stage_f(j) != 0.0);
                if wc == 0.0 || !wc.is_finite() {
                    return Err(Singular { column: c, pivot: wc.abs() });
                }
                self.rmass[c] = 1.0 / wc;
                if !self.stiff[c] {
                    // T's block is `W_cc I`: `g[c][l] = (ã_il / W_cc)_i, b̃_l / W_cc`.
                    for l in 0..S {
                        let g = &mut self.columns[(c * S + l) * (S + 1)..][..S + 1];
                        for (i, x) in g.iter_mut().enumerate() {
                            *x = if i < S { tab.a_tilde[i][l] } else { tab.b_tilde[l] } * self.rmass[c];
                        }
                    }
                    continue;
                }
                // Column-major S × S block, factored, then its inverse
                // column by column (row-major in `inverse`: row i is
                // contiguous for the products of `solve`).
                for k in 0..S {
                    for i in 0..S {
                        let mass = if i == k { wc } else { 0.0 };
                        block[k * S + i] = if self.per_stage {
                            // ∂F(Q_j)/∂V_k = h a_jk F_q(Q_j), weighed by â_ij.
                            mass - h2 * (0..S).map(|j| tab.a_hat[i][j] * stage_f(j) * tab.a[j][k]).sum::<f64>()
                        } else {
                            mass - h2 * aa(i, k) * fc
                        };
                    }
                }
                if self.per_stage {
                    for k in 0..S {
                        self.end_by_coordinate[c * S + k] =
                            h2 * (0..S).map(|j| tab.b_hat[j] * stage_f(j) * tab.a[j][k]).sum::<f64>();
                    }
                }
                factor_runtime(&mut block[..S * S], S, &mut perm[..S], &mut scale[..S])
                    .map_err(|e| Singular { column: e.column * N + c, ..e })?;
                for k in 0..S {
                    let mut e = [0.0; 8];
                    e[k] = 1.0;
                    solve_runtime(&block[..S * S], S, &perm[..S], &mut e[..S]);
                    for (i, x) in e[..S].iter().enumerate() {
                        self.inverse[(c * S + i) * S + k] = *x;
                    }
                }
                // g[c][l] = T_c⁻¹ (ã_il)_i, and the end point's
                // (b̃_l + F_q,cc Σ_k h² (b̂ᵀA)_k g[c][l][k]) / W_cc.
                for l in 0..S {
                    let inv = &self.inverse[c * S * S..(c + 1) * S * S];
                    let g = &mut self.columns[(c * S + l) * (S + 1)..][..S + 1];
                    let mut coupling = 0.0;
                    for i in 0..S {
                        g[i] = (0..S).map(|k| inv[i * S + k] * tab.a_tilde[k][l]).sum();
                        coupling += if self.per_stage {
                            self.end_by_coordinate[c * S + i] * g[i]
                        } else {
                            self.end_coupling[i] * g[i]
                        };
                    }
                    let end = if self.per_stage { coupling } else { fc * coupling };
                    g[S] = (tab.b_tilde[l] + end) * self.rmass[c];
                }
            }
        } else {
            let sn = S * N;
            if sn > DENSE_MAX {
                return Ok(false);
            }
            for k in 0..S {
                for i in 0..S {
                    let coef = h2 * aa(i, k);
                    for c in 0..N {
                        let col = &mut self.lu[(k * N + c) * sn + i * N..][..N];
                        for (r, x) in col.iter_mut().enumerate() {
                            let mass = if i == k { w[c * N + r] } else { 0.0 };
                            *x = mass - coef * fq[c * N + r];
                        }
                    }
                }
            }
            factor_runtime(&mut self.lu, sn, &mut self.perm, &mut self.scale)?;
        }
        self.h = h;
        Ok(true)
    }

    /// The coefficients `g` of `A⁻¹B` (see the field), when `T` splits by
    /// coordinate.
    pub(crate) fn columns(&self) -> Option<&[f64]> {
        self.by_coordinate.then_some(&self.columns[..])
    }

    /// `y ← T⁻¹ y` for the stage part `y` (`S·N`, stage by stage), then
    /// `end += Σ_k h² (b̂ᵀA)_k F_q y_k`: the end row's right-hand side once
    /// the stages are solved (`W` then gives `v₁`'s part).
    #[inline]
    pub(crate) fn solve_stages(&self, y: &mut [f64], end: &mut [f64]) {
        if !self.by_coordinate {
            solve_runtime(&self.lu, S * N, &self.perm, y);
            let fq = &self.stiffness;
            for (k, &ck) in self.end_coupling.iter().enumerate() {
                if ck == 0.0 {
                    continue;
                }
                for (c, yc) in y[k * N..(k + 1) * N].iter().enumerate() {
                    let s = ck * yc;
                    for (d, f) in end.iter_mut().zip(&fq[c * N..(c + 1) * N]) {
                        *d += f * s;
                    }
                }
            }
            return;
        }
        // Slices of constant length: the indexing below is then within
        // bounds by construction, and the loops unroll (at S = 1, N = 3 the
        // checked form cost a third of a stage-decoupled update's solve).
        let (y, end) = (&mut y[..S * N], &mut end[..N]);
        let (stiff, rmass, stiffness) = (&self.stiff[..N], &self.rmass[..N], &self.stiffness[..N * N]);
        let (coupling_of, inverse) = (&self.end_coupling[..S], &self.inverse[..N * S * S]);
        for c in 0..N {
            if !stiff[c] {
                // No stiffness on `c`: its mass alone, no end coupling.
                let r = rmass[c];
                for i in 0..S {
                    y[i * N + c] *= r;
                }
                continue;
            }
            let inv = &inverse[c * S * S..(c + 1) * S * S];
            // The end row's coefficients: per stage point they hold the
            // stiffness already; a constant one multiplies their sum.
            if self.per_stage {
                end[c] += solve_coordinate::<N, S>(inv, c, y, &self.end_by_coordinate[c * S..(c + 1) * S]);
            } else {
                end[c] += stiffness[c * (N + 1)] * solve_coordinate::<N, S>(inv, c, y, coupling_of);
            }
        }
    }
}

/// `y_c ← T_c⁻¹ y_c` for coordinate `c` of the stage part `y` (stage by
/// stage, `inv` the block's inverse, row-major), returning
/// `Σ_i coupling_of[i] y_i,c`.
#[inline(always)]
fn solve_coordinate<const N: usize, const S: usize>(inv: &[f64], c: usize, y: &mut [f64], coupling_of: &[f64]) -> f64 {
    let x: [f64; S] = std::array::from_fn(|i| y[i * N + c]);
    let mut coupling = 0.0;
    for i in 0..S {
        let row = &inv[i * S..(i + 1) * S];
        let yi: f64 = row.iter().zip(&x).map(|(a, b)| a * b).sum();
        y[i * N + c] = yi;
        coupling += coupling_of[i] * yi;
    }
    coupling
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::test_matrices::random_values;
    use crate::tableau::Method;
    use nalgebra::{DMatrix, DVector};

    /// The stage solve and the end row's coupling with a stiffness per stage
    /// point, against `T` assembled densely from its definition
    /// `T_ik = δ_ik W − h² Σ_j â_ij F_q(Q_j) a_jk` and the end row's
    /// `Σ_k h² Σ_j b̂_j F_q(Q_j) a_jk y_k`.
    fn per_stage_solve_matches_dense<const S: usize>(method: Method) {
        const N: usize = 3;
        let tab = Tableau::<S>::new(method).unwrap();
        let h = 0.2;
        let w = [2.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.5];
        let r = random_values(7 + S as u64, S * N + S * N + N);
        // Coordinate 1 has no stiffness at any point.
        let f = |j: usize, c: usize| if c == 1 { 0.0 } else { 40.0 * r[j * N + c] };
        let mut stiff = StiffStages::<N, S>::new(true);
        for j in 0..S {
            let diagonal: [f64; N] = std::array::from_fn(|c| f(j, c));
            stiff.set_stage(j, &diagonal);
        }
        assert!(stiff.factor(&tab, h, &w, is_diagonal::<N>(&w)).unwrap());
        let mut t = DMatrix::<f64>::zeros(S * N, S * N);
        for i in 0..S {
            for k in 0..S {
                for c in 0..N {
                    let coupling: f64 = (0..S).map(|j| tab.a_hat[i][j] * f(j, c) * tab.a[j][k]).sum();
                    let mass = if i == k { w[c * (N + 1)] } else { 0.0 };
                    t[(i * N + c, k * N + c)] = mass - h * h * coupling;
                }
            }
        }
        let y0 = &r[S * N..2 * S * N];
        let end0 = &r[2 * S * N..];
        let expected = t.lu().solve(&DVector::from_column_slice(y0)).unwrap();
        let mut y = y0.to_vec();
        let mut end = end0.to_vec();
        stiff.solve_stages(&mut y, &mut end);
        for (a, b) in y.iter().zip(expected.iter()) {
            assert!((a - b).abs() <= 1e-13 * b.abs().max(1.0), "{method:?} s = {S}: {a} vs {b}");
        }
        for c in 0..N {
            let coupling: f64 = (0..S)
                .map(|k| {
                    (0..S).map(|j| h * h * tab.b_hat[j] * f(j, c) * tab.a[j][k]).sum::<f64>() * expected[k * N + c]
                })
                .sum();
            let want = end0[c] + coupling;
            assert!((end[c] - want).abs() <= 1e-13 * want.abs().max(1.0), "{method:?} s = {S}, end {c}");
        }
    }

    #[test]
    fn a_stiffness_per_stage_point_solves_as_its_assembled_blocks() {
        per_stage_solve_matches_dense::<1>(Method::Gauss);
        per_stage_solve_matches_dense::<2>(Method::Gauss);
        per_stage_solve_matches_dense::<4>(Method::Gauss);
        per_stage_solve_matches_dense::<3>(Method::LobattoIIIAB);
        per_stage_solve_matches_dense::<4>(Method::LobattoIIIAB);
    }

    #[test]
    fn lobatto_s2_keeps_no_stiffness_point_and_gauss_keeps_every_one() {
        let l2 = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
        assert_eq!(kept_stiffness_points(&l2), [false, false]);
        let l3 = Tableau::<3>::new(Method::LobattoIIIAB).unwrap();
        assert_eq!(kept_stiffness_points(&l3), [false, true, true]);
        let g3 = Tableau::<3>::new(Method::Gauss).unwrap();
        assert_eq!(kept_stiffness_points(&g3), [true, true, true]);
    }
}
