//! The padded, swap-free LU kernel [`PaddedLu`] of the small Newton
//! matrices (`PADDED_MIN ≤ D ≤ PADDED_MAX`), written with AVX2+FMA
//! intrinsics. Every `unsafe` of the kernel is here, behind [`PaddedLu`]:
//! holding one proves the CPU check.

use super::Singular;

/// Rows per lane of the padded kernel (columns are padded to whole lanes
/// and lane-aligned; a cache line).
const LANE: usize = 8;

/// The smallest `D` for which [`PaddedLu`] is used: below it the row-swapping
/// [`factor_in_place`] is faster (D = 11: 241 ns vs 296 ns factor + solve,
/// its scalar solve's dependency chain is shorter).
pub(crate) const PADDED_MIN: usize = 12;

/// The largest `D` [`PaddedLu`] handles: its pivot search tags rows with six
/// bits, and from here on [`factor_in_place`]'s triangular loops are long
/// enough to vectorize well on their own.
pub(crate) const PADDED_MAX: usize = 64;

/// Eight rows of one column, aligned so that a lane is one aligned vector load.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(64))]
struct Lane([f64; LANE]);

/// LU factors of a `D × D` matrix (`PADDED_MIN ≤ D ≤ PADDED_MAX`) in padded
/// column-major lanes, for the small Newton matrices of a step; x86-64 with
/// AVX2 and FMA only ([`PaddedLu::new`] says whether it can be used).
///
/// Why not [`factor_in_place`] at these sizes: its loops have lengths
/// `D − k` that change every column (vector prologues and epilogues around
/// a few vector iterations), rows are swapped with strided accesses, and
/// rustc's default target is SSE2. Here rows are never moved: column `k`
/// picks its pivot row `p_k` among the rows not yet pivotal (`active`) of
/// its row block, the multipliers of the other active rows go to `l` (zero
/// on every other row), and the update `a_j ← a_j − l_k a_{p_k j}` leaves
/// used rows alone because their multiplier is zero. What stays in `u` is
/// `U` scattered over the pivot rows (zero on rows pivotal later), so both
/// triangular solves are unmasked multiply-subtracts over whole aligned
/// vectors, from the lane of the lowest active row on. Pivoting is the
/// same partial pivoting within row blocks as [`factor_in_place`]; exact
/// ties between pivot candidates go to the lowest row in the original
/// order (after swaps, [`factor_in_place`] may pick another), and the
/// updates are fused multiply-adds, so results agree with it to rounding,
/// not bit for bit.
#[derive(Clone, Debug)]
pub(crate) struct PaddedLu<const D: usize> {
    /// The matrix being factored, then `U` (rows in original positions).
    u: Box<[Lane]>,
    /// Multipliers: column `k` nonzero only on rows still active after step `k`.
    l: Box<[Lane]>,
    /// `p_k`: the row that was pivotal for column `k`.
    perm: Box<[usize]>,
    /// `1 / u_{p_k k}`.
    rdiag: Box<[f64]>,
    /// `(lo_k, hi_k)`: every row below `lo_k` was pivotal before step `k`
    /// (so `l_k` is zero there and loops start at its lane), and `u_k` is
    /// zero below row `hi_k = max(p_0..p_k)`. With pivots on or near the
    /// diagonal this gives back the triangular saving of a row-swapping LU.
    rows: Box<[(usize, usize)]>,
}

impl<const D: usize> PaddedLu<D> {
    /// Column stride: `D` rounded up to whole lanes.
    const DP: usize = D.div_ceil(LANE) * LANE;

    /// Zero buffers (`2 · D · ⌈D/8⌉` lanes), or `None` when `D` is outside
    /// `PADDED_MIN..=PADDED_MAX` or the CPU lacks AVX2 or FMA. Holding a
    /// `PaddedLu` is what makes [`factor`](Self::factor) and
    /// [`solve`](Self::solve) sound.
    pub(crate) fn new() -> Option<Self> {
        #[cfg(target_arch = "x86_64")]
        if (PADDED_MIN..=PADDED_MAX).contains(&D) && super::avx2_fma_available() {
            let n = D * Self::DP / LANE;
            return Some(PaddedLu {
                u: vec![Lane::default(); n].into_boxed_slice(),
                l: vec![Lane::default(); n].into_boxed_slice(),
                perm: vec![0; D].into_boxed_slice(),
                rdiag: vec![0.0; D].into_boxed_slice(),
                rows: vec![(0, 0); D].into_boxed_slice(),
            });
        }
        None
    }

    /// Factors the `D × D` column-major matrix `a` with its columns taken in
    /// the order `columns` (column `k` of the factors is column
    /// `columns[k]` of `a`), pivots confined to row blocks as in
    /// [`factor_in_place`] and the same singularity test. A NaN or infinity
    /// anywhere in `a` fails at the first column holding one (pivot NaN),
    /// as does one produced during the elimination among a column's pivot
    /// candidates.
    pub(crate) fn factor(&mut self, a: &[f64], columns: &[usize; D], block_ends: &[usize]) -> Result<(), Singular> {
        let a = &a[..D * D];
        let u = &mut flat_mut(&mut self.u)[..D * Self::DP];
        let l = &mut flat_mut(&mut self.l)[..D * Self::DP];
        let (perm, rdiag, rows) = (&mut self.perm[..D], &mut self.rdiag[..D], &mut self.rows[..D]);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `new` made `self` only on a CPU with AVX2 and FMA and for
        // `D ≤ PADDED_MAX`; the buffers are `D` columns of `DP` (a multiple
        // of 8) entries, each 64-byte aligned (`Lane`), zero on padding rows.
        return unsafe { x86::factor::<D>(a, columns, block_ends, u, l, Self::DP, perm, rdiag, rows) };
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!("PaddedLu is only constructed on x86-64")
    }

    /// Overwrites `b` with `A⁻¹ b` (entries in the column order of the
    /// factors); meaningless before a successful [`factor`](Self::factor).
    pub(crate) fn solve(&self, b: &mut [f64]) {
        let (u, l) = (&flat(&self.u)[..D * Self::DP], &flat(&self.l)[..D * Self::DP]);
        let (perm, rdiag, rows) = (&self.perm[..D], &self.rdiag[..D], &self.rows[..D]);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as in `factor`.
        return unsafe { x86::solve::<D>(u, l, Self::DP, perm, rdiag, rows, &mut b[..D]) };
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!("PaddedLu is only constructed on x86-64")
    }
}

/// The entries of `lanes`, in order.
fn flat(lanes: &[Lane]) -> &[f64] {
    // SAFETY: `Lane` is `repr(C)` around `[f64; LANE]` with size
    // `8 · LANE` (its alignment 64 equals its size), so a slice of lanes is
    // `lanes.len() · LANE` contiguous, initialized `f64`s.
    unsafe { std::slice::from_raw_parts(lanes.as_ptr().cast::<f64>(), lanes.len() * LANE) }
}

/// The entries of `lanes`, in order, mutably.
fn flat_mut(lanes: &mut [Lane]) -> &mut [f64] {
    // SAFETY: as in `flat`; the borrow of `lanes` is exclusive.
    unsafe { std::slice::from_raw_parts_mut(lanes.as_mut_ptr().cast::<f64>(), lanes.len() * LANE) }
}

/// The padded kernel compiled for AVX2 and FMA, chosen at run time: without
/// a global `target-cpu` rustc targets SSE2. It is written with
/// intrinsics (four `f64` per vector): left to itself, LLVM fully unrolls
/// its constant-length loops and then keeps most of them scalar.
#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{Lane, Singular, LANE, PADDED_MAX};
    use std::arch::x86_64::*;

    const W: usize = 4;

    /// `x[i]` in every lane, read as the whole aligned vector holding it (the
    /// vectors were just stored whole; a scalar load of one entry would miss
    /// store-to-load forwarding) and broadcast with a lane permutation.
    #[inline(always)]
    unsafe fn broadcast(x: *const f64, i: usize) -> __m256d {
        let v = _mm256_load_pd(x.add(i / W * W));
        let t = (2 * (i % W)) as i32;
        let sel = _mm256_setr_epi32(t, t + 1, t, t + 1, t, t + 1, t, t + 1);
        _mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(v), sel))
    }

    /// The largest lane of `x`, in every lane.
    #[inline(always)]
    unsafe fn hmax(x: __m256d) -> __m256d {
        let m = _mm256_max_pd(x, _mm256_permute2f128_pd::<1>(x, x));
        _mm256_max_pd(m, _mm256_permute_pd::<0b0101>(m))
    }

    /// # Safety
    /// AVX2 must be available; `u` and `l` hold `D` columns of `dp` entries
    /// (`dp` a multiple of 8, `D ≤ dp ≤ PADDED_MAX`), 32-byte aligned, zero
    /// on the padding rows `D..dp` of `u`.
    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn factor<const D: usize>(
        a: &[f64],
        columns: &[usize; D],
        block_ends: &[usize],
        u: &mut [f64],
        l: &mut [f64],
        dp: usize,
        perm: &mut [usize],
        rdiag: &mut [f64],
        rows: &mut [(usize, usize)],
    ) -> Result<(), Singular> {
        let nv = dp / W;
        let u = u.as_mut_ptr();
        let l = l.as_mut_ptr();
        let sign = _mm256_set1_pd(-0.0);
        let huge = _mm256_set1_pd(f64::MAX);
        // Load the columns (aligned, padded) and their scales in one pass.
        let (full, rem) = (D / W, D % W);
        let r = rem as i64;
        let tail = _mm256_setr_epi64x(-i64::from(r > 0), -i64::from(r > 1), -i64::from(r > 2), 0);
        let mut scale = [0.0f64; PADDED_MAX];
        for (k, &j) in columns.iter().enumerate() {
            let src = a.as_ptr().add(j * D);
            let dst = u.add(k * dp);
            let mut m = _mm256_setzero_pd();
            let mut bad = _mm256_setzero_pd();
            for c in 0..full {
                let x = _mm256_loadu_pd(src.add(c * W));
                _mm256_store_pd(dst.add(c * W), x);
                let ax = _mm256_andnot_pd(sign, x);
                m = _mm256_max_pd(m, ax);
                bad = _mm256_or_pd(bad, _mm256_cmp_pd::<_CMP_NLE_UQ>(ax, huge));
            }
            if rem > 0 {
                let x = _mm256_maskload_pd(src.add(full * W), tail);
                _mm256_store_pd(dst.add(full * W), x);
                let ax = _mm256_andnot_pd(sign, x);
                m = _mm256_max_pd(m, ax);
                bad = _mm256_or_pd(bad, _mm256_cmp_pd::<_CMP_NLE_UQ>(ax, huge));
            }
            if _mm256_movemask_pd(bad) != 0 {
                return Err(Singular { column: k, pivot: f64::NAN });
            }
            scale[k] = _mm256_cvtsd_f64(hmax(m));
        }
        // All-ones bits on rows not yet pivotal.
        let mut active_buf = [Lane::default(); PADDED_MAX / LANE];
        let active = active_buf.as_mut_ptr().cast::<f64>();
        for i in 0..D {
            *active.add(i) = f64::from_bits(u64::MAX);
        }
        let step = _mm256_set1_pd(W as f64);
        let four = _mm256_set1_epi64x(W as i64);
        let high = _mm256_castsi256_pd(_mm256_set1_epi64x(!63));
        let (mut block, mut lo, mut hi) = (0, 0, 0);
        for k in 0..D {
            while block_ends[block] <= k {
                lo = lo.max(block_ends[block]);
                block += 1;
            }
            let end = block_ends[block].min(D);
            while (*active.add(lo)).to_bits() == 0 {
                lo += 1;
            }
            let col = u.add(k * dp);
            let (c0, c1) = (lo / W, end.div_ceil(W));
            // Argmax over the candidates (active rows below `end`) as one
            // max: the key of row `i` is |x| with its six lowest mantissa
            // bits replaced by `63 − i` (non-negative doubles order like
            // their bit patterns), so the largest key is the largest
            // magnitude, ties (to 2⁻⁴⁶ relative) going to the smallest row,
            // and non-candidates are keyed 0. One `max` per vector keeps
            // this chain short; an index-tracking argmax is ~20 cycles
            // longer per column.
            let endv = _mm256_set1_pd(end as f64);
            let mut idx = _mm256_add_pd(_mm256_setr_pd(0.0, 1.0, 2.0, 3.0), _mm256_set1_pd((c0 * W) as f64));
            let r0 = 63 - (c0 * W) as i64;
            let mut tag = _mm256_setr_epi64x(r0, r0 - 1, r0 - 2, r0 - 3);
            let mut best = _mm256_setzero_pd();
            let mut bad = _mm256_setzero_pd();
            for c in c0..c1 {
                let x = _mm256_andnot_pd(sign, _mm256_load_pd(col.add(c * W)));
                let cand = _mm256_and_pd(_mm256_load_pd(active.add(c * W)), _mm256_cmp_pd::<_CMP_LT_OQ>(idx, endv));
                // NaN or ±∞ made by the elimination (not ≤ f64::MAX).
                bad = _mm256_or_pd(bad, _mm256_and_pd(cand, _mm256_cmp_pd::<_CMP_NLE_UQ>(x, huge)));
                let key = _mm256_or_pd(_mm256_and_pd(x, high), _mm256_castsi256_pd(tag));
                best = _mm256_max_pd(best, _mm256_and_pd(cand, key));
                idx = _mm256_add_pd(idx, step);
                tag = _mm256_sub_epi64(tag, four);
            }
            if _mm256_movemask_pd(bad) != 0 {
                return Err(Singular { column: k, pivot: f64::NAN });
            }
            let key = _mm256_cvtsd_f64(hmax(best)).to_bits();
            let pivot = f64::from_bits(key & !63);
            if pivot <= 64.0 * f64::EPSILON * scale[k] {
                return Err(Singular { column: k, pivot });
            }
            let p = 63 - (key & 63) as usize;
            perm[k] = p;
            hi = hi.max(p);
            rows[k] = (lo, hi);
            *active.add(p) = 0.0;
            let inv = 1.0 / _mm256_cvtsd_f64(broadcast(col, p));
            rdiag[k] = inv;
            let invv = _mm256_set1_pd(inv);
            let lk = l.add(k * dp);
            // Lanes below `c0` hold used rows only: their multipliers are
            // never read (loops start at `c0`), their U entries stay.
            for c in c0..nv {
                let x = _mm256_load_pd(col.add(c * W));
                let act = _mm256_load_pd(active.add(c * W));
                _mm256_store_pd(lk.add(c * W), _mm256_and_pd(act, _mm256_mul_pd(x, invv)));
                _mm256_store_pd(col.add(c * W), _mm256_andnot_pd(act, x));
            }
            for j in k + 1..D {
                let colj = u.add(j * dp);
                let s = broadcast(colj, p);
                // Structural zeros (v₁ columns in stage rows) skip the update.
                if _mm256_cvtsd_f64(s) != 0.0 {
                    for c in c0..nv {
                        let x = _mm256_load_pd(colj.add(c * W));
                        let m = _mm256_load_pd(lk.add(c * W));
                        _mm256_store_pd(colj.add(c * W), _mm256_fnmadd_pd(m, s, x));
                    }
                }
            }
        }
        Ok(())
    }

    /// # Safety
    /// As for [`factor`], with factors written by it.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn solve<const D: usize>(
        u: &[f64],
        l: &[f64],
        dp: usize,
        perm: &[usize],
        rdiag: &[f64],
        rows: &[(usize, usize)],
        b: &mut [f64],
    ) {
        let nv = dp / W;
        let mut w_buf = [Lane::default(); PADDED_MAX / LANE];
        let w = w_buf.as_mut_ptr().cast::<f64>();
        std::ptr::copy_nonoverlapping(b.as_ptr(), w, D);
        let (u, l) = (u.as_ptr(), l.as_ptr());
        for k in 0..D {
            let c0 = rows[k].0 / W;
            let s = broadcast(w, perm[k]);
            let lk = l.add(k * dp);
            for c in c0..nv {
                let x = _mm256_load_pd(w.add(c * W));
                _mm256_store_pd(w.add(c * W), _mm256_fnmadd_pd(_mm256_load_pd(lk.add(c * W)), s, x));
            }
        }
        for k in (0..D).rev() {
            let c1 = rows[k].1 / W + 1;
            let s = _mm256_mul_pd(broadcast(w, perm[k]), _mm256_set1_pd(rdiag[k]));
            b[k] = _mm256_cvtsd_f64(s);
            let uk = u.add(k * dp);
            for c in 0..c1 {
                let y = _mm256_load_pd(w.add(c * W));
                _mm256_store_pd(w.add(c * W), _mm256_fnmadd_pd(_mm256_load_pd(uk.add(c * W)), s, y));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::test_matrices::{nalgebra_solve, random_matrix};
    use crate::linalg::{column_scales, factor_in_place, solve_in_place};
    use crate::system::{Matrix, Vector};

    /// Padded factor + solve of `a x = b`, columns in natural order.
    fn padded_solve<const D: usize>(a: &Matrix<D, D>, b: &Vector<D>, ends: &[usize]) -> Result<Vector<D>, Singular> {
        let mut lu = PaddedLu::<D>::new().expect("padded kernel available");
        lu.factor(a.as_slice(), &std::array::from_fn(|c| c), ends)?;
        let mut x = *b;
        lu.solve(x.as_mut_slice());
        Ok(x)
    }

    /// Random matrices (rows permuted so pivoting is required, some
    /// ill-conditioned) vs nalgebra's LU at every padded size class.
    fn agrees_with_nalgebra<const D: usize>(seed: u64, diag: f64) {
        if PaddedLu::<D>::new().is_none() {
            return;
        }
        let mut a = random_matrix::<D>(seed);
        for i in 0..D {
            a[(i, i)] += diag;
        }
        // Reverse the rows: the dominant entries leave the diagonal.
        let a = Matrix::<D, D>::from_fn(|i, j| a[(D - 1 - i, j)]);
        let x = Vector::<D>::from_fn(|i, _| 1.0 + i as f64 * 0.25);
        let b = a * x;
        let reference = nalgebra_solve(&a, &b);
        let got = padded_solve::<D>(&a, &b, &[D]).unwrap();
        let err = (got - reference).amax() / reference.amax();
        // Normwise backward error (‖r‖∞ / (‖A‖∞ ‖x‖∞ + ‖b‖∞)) within D·ε:
        // what partial pivoting guarantees up to the (small) growth factor.
        let norm_a = a.row_iter().map(|r| r.iter().map(|x| x.abs()).sum::<f64>()).fold(0.0, f64::max);
        let eta = (a * got - b).amax() / (norm_a * got.amax() + b.amax());
        assert!(eta < D as f64 * f64::EPSILON, "D = {D}, seed {seed}: backward error {eta:e}");
        // Two backward-stable solutions differ by at most ~ D ε κ(A).
        let sv = nalgebra::DMatrix::from_column_slice(D, D, a.as_slice()).singular_values();
        let kappa = sv.max() / sv.min();
        let tol = 10.0 * D as f64 * f64::EPSILON * kappa;
        assert!(err < tol, "D = {D}, seed {seed}: differs from nalgebra by {err:e} (κ = {kappa:e})");
        // The row-swapping kernel agrees too.
        let mut lu = a;
        let mut perm = [0; D];
        factor_in_place::<D>(lu.as_mut_slice(), &mut perm, &column_scales::<D>(a.as_slice()), &[D]).unwrap();
        let mut y = b;
        solve_in_place::<D>(lu.as_slice(), &perm, y.as_mut_slice());
        assert!((got - y).amax() / y.amax() < tol, "D = {D}, seed {seed}");
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]
        #[test]
        fn padded_kernel_matches_nalgebra(seed in proptest::prelude::any::<u64>(), diag in 0.0f64..4.0) {
            agrees_with_nalgebra::<12>(seed, diag);
            agrees_with_nalgebra::<13>(seed, diag);
            agrees_with_nalgebra::<17>(seed, diag);
            agrees_with_nalgebra::<23>(seed, diag);
            agrees_with_nalgebra::<32>(seed, diag);
            agrees_with_nalgebra::<47>(seed, diag);
            agrees_with_nalgebra::<64>(seed, diag);
        }

        #[test]
        fn padded_pivots_stay_in_their_blocks(seed in proptest::prelude::any::<u64>(), e1 in 1usize..10, e2 in 1usize..10) {
            const D: usize = 20;
            let Some(mut lu) = PaddedLu::<D>::new() else { return Ok(()) };
            let mut a = random_matrix::<D>(seed);
            for i in 0..D {
                a[(i, i)] += 3.0;
            }
            let ends = [e1, e1 + e2, D];
            let x = Vector::<D>::from_fn(|i, _| (i as f64).sin());
            let b = a * x;
            lu.factor(a.as_slice(), &std::array::from_fn(|c| c), &ends).unwrap();
            let mut start = 0;
            for &end in &ends {
                for k in start..end {
                    proptest::prop_assert!((start..end).contains(&lu.perm[k]), "column {k} pivoted on row {}", lu.perm[k]);
                }
                start = end;
            }
            let mut y = b;
            lu.solve(y.as_mut_slice());
            // Pivots confined to blocks may grow the factors: the normwise
            // backward error is within D·ε times the growth factor ρ (Wilkinson's
            // bound), with ρ from the row-swapping kernel's factors under the
            // same confinement.
            let mut f = a;
            let mut perm = [0; D];
            factor_in_place::<D>(f.as_mut_slice(), &mut perm, &column_scales::<D>(a.as_slice()), &ends).unwrap();
            let growth = (0..D).flat_map(|j| (0..=j).map(move |i| (i, j))).fold(0.0f64, |m, (i, j)| m.max(f[(i, j)].abs()))
                / a.amax();
            let norm_a = a.row_iter().map(|r| r.iter().map(|v| v.abs()).sum::<f64>()).fold(0.0, f64::max);
            let eta = (a * y - b).amax() / (norm_a * y.amax() + b.amax());
            proptest::prop_assert!(
                eta < D as f64 * f64::EPSILON * growth.max(1.0),
                "backward error {eta:e}, growth {growth:e}, error {:e}",
                (y - x).amax()
            );
        }
    }

    #[test]
    fn padded_kernel_needs_and_does_pivoting() {
        // A zero diagonal: without row interchanges the first pivot is 0.
        const D: usize = 14;
        if PaddedLu::<D>::new().is_none() {
            return;
        }
        let a = Matrix::<D, D>::from_fn(|i, j| {
            if (i + 1) % D == j {
                2.0 + i as f64
            } else if i == j {
                0.0
            } else {
                0.01
            }
        });
        let x = Vector::<D>::from_fn(|i, _| i as f64 - 3.0);
        let got = padded_solve::<D>(&a, &(a * x), &[D]).unwrap();
        assert!((got - x).amax() < 1e-13);
    }

    #[test]
    fn padded_kernel_reports_singular_and_nonfinite_columns() {
        const D: usize = 16;
        if PaddedLu::<D>::new().is_none() {
            return;
        }
        let base = {
            let mut a = random_matrix::<D>(7);
            for i in 0..D {
                a[(i, i)] += 4.0;
            }
            a
        };
        let b = Vector::<D>::from_element(1.0);
        // Column 5 a combination of columns 2 and 3: exactly singular.
        let mut a = base;
        let c = a.column(2) * 0.5 - a.column(3) * 2.0;
        a.set_column(5, &c);
        let err = padded_solve::<D>(&a, &b, &[D]).unwrap_err();
        assert!(err.column <= 5, "{err:?}");
        // Nearly singular: a relative perturbation of 1e-17 is below the
        // 64 ε threshold, one of 1e-9 is not.
        let mut near = a;
        near[(0, 5)] += 1e-17 * near.column(5).amax();
        assert!(padded_solve::<D>(&near, &b, &[D]).is_err());
        let mut regular = a;
        regular[(0, 5)] += 1e-9 * regular.column(5).amax();
        let x = padded_solve::<D>(&regular, &b, &[D]).unwrap();
        assert!((regular * x - b).amax() < 1e-5, "{}", (regular * x - b).amax());
        // A zero column fails at that column.
        let mut z = base;
        z.set_column(9, &Vector::<D>::zeros());
        assert_eq!(padded_solve::<D>(&z, &b, &[D]).unwrap_err().column, 9);
        // NaN or infinity anywhere (also off the pivot rows) fails with a NaN pivot.
        for (i, j, v) in [(15, 3, f64::NAN), (0, 12, f64::INFINITY), (7, 7, f64::NEG_INFINITY)] {
            let mut n = base;
            n[(i, j)] = v;
            let err = padded_solve::<D>(&n, &b, &[D]).unwrap_err();
            assert!(err.pivot.is_nan() && err.column == j, "({i}, {j}) = {v}: {err:?}");
        }
    }

    #[test]
    fn padded_kernel_is_reusable() {
        // Factors of one matrix are fully replaced by the next (stale
        // multipliers below a later column's first active lane are never read).
        const D: usize = 18;
        let Some(mut lu) = PaddedLu::<D>::new() else { return };
        for seed in 1..6u64 {
            let a = random_matrix::<D>(seed);
            // Alternate between a matrix needing row interchanges and one that does not.
            let a = if seed % 2 == 0 { Matrix::<D, D>::from_fn(|i, j| a[(D - 1 - i, j)]) } else { a };
            let a = {
                let mut a = a;
                for i in 0..D {
                    a[(i, i)] += 2.0;
                }
                a
            };
            let x = Vector::<D>::from_fn(|i, _| seed as f64 - i as f64);
            lu.factor(a.as_slice(), &std::array::from_fn(|c| c), &[D]).unwrap();
            let mut y = a * x;
            lu.solve(y.as_mut_slice());
            assert!((y - x).amax() < 1e-11 * x.amax(), "seed {seed}: {}", (y - x).amax());
        }
    }
}
