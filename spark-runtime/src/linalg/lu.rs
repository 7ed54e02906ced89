//! The row-swapping LU kernels: [`factor_in_place`] and
//! [`solve_in_place`] for a size `D` fixed at compile time (the scalar
//! build, or the same code compiled for AVX2+FMA when `D > PADDED_MAX` and
//! the CPU has them), [`factor_runtime`] and [`solve_runtime`] for sizes
//! known only at run time, and [`Lu`], a small factorization on the stack.

use super::padded_lu::PADDED_MAX;
use super::{column_scales, Singular};
use crate::system::{Matrix, Vector};

/// Factors the `D × D` column-major matrix in `lu` in place (`P A = L U`),
/// recording the row interchanges in `perm`. Column `k` pivots among rows
/// `k..e` where `e` is the first entry of `block_ends` above `k` (the last
/// entry must be `D`). A pivot below `64 ε · scale[k]` counts as singular:
/// column scales differ by orders of magnitude in the SPARK matrix, so a
/// global threshold would be wrong.
///
/// Right-looking, column by column, on slices so the inner loops are
/// bounds-check free and vectorize; `D` is a constant so the loop bounds are
/// known after monomorphization. For `D > PADDED_MAX` on a CPU with AVX2
/// and FMA the same code runs compiled for those (fused `a − l u`, so the
/// last bits differ from the plain build): 1.25–1.35× at D = 101..197.
#[inline]
pub(crate) fn factor_in_place<const D: usize>(
    lu: &mut [f64],
    perm: &mut [usize],
    scale: &[f64; D],
    block_ends: &[usize],
) -> Result<(), Singular> {
    #[cfg(target_arch = "x86_64")]
    if D > PADDED_MAX && super::avx2_fma_available() {
        // SAFETY: the CPU has AVX2 and FMA (checked just above).
        return unsafe { x86::factor_in_place_fma::<D>(lu, perm, scale, block_ends) };
    }
    factor_in_place_body::<D, false>(lu, perm, scale, block_ends)
}

/// [`factor_in_place`]'s body; `FMA` fuses the update's multiply-subtract.
#[inline(always)]
fn factor_in_place_body<const D: usize, const FMA: bool>(
    lu: &mut [f64],
    perm: &mut [usize],
    scale: &[f64; D],
    block_ends: &[usize],
) -> Result<(), Singular> {
    let lu = &mut lu[..D * D];
    let perm = &mut perm[..D];
    let mut block = 0;
    for k in 0..D {
        while block_ends[block] <= k {
            block += 1;
        }
        let end = block_ends[block].min(D);
        let col_k = &lu[k * D..(k + 1) * D];
        let mut p = k;
        let mut best = col_k[k].abs();
        for (i, x) in col_k[..end].iter().enumerate().skip(k + 1) {
            if x.abs() > best {
                best = x.abs();
                p = i;
            }
        }
        perm[k] = p;
        // Written to be true for NaN pivots too.
        if best.is_nan() || best <= 64.0 * f64::EPSILON * scale[k] {
            return Err(Singular { column: k, pivot: best });
        }
        if p != k {
            for j in 0..D {
                lu.swap(j * D + k, j * D + p);
            }
        }
        let (left, right) = lu.split_at_mut((k + 1) * D);
        let col_k = &mut left[k * D..];
        let inv = 1.0 / col_k[k];
        for x in &mut col_k[k + 1..] {
            *x *= inv;
        }
        let lower = &col_k[k + 1..];
        for col_j in right.chunks_exact_mut(D) {
            let ukj = col_j[k];
            if ukj != 0.0 {
                for (x, l) in col_j[k + 1..].iter_mut().zip(lower) {
                    *x = if FMA { (-l).mul_add(ukj, *x) } else { *x - l * ukj };
                }
            }
        }
    }
    Ok(())
}

/// Overwrites `b` with `A⁻¹ b` from the factors of [`factor_in_place`]
/// (compiled for AVX2 and FMA under the same condition).
#[inline]
pub(crate) fn solve_in_place<const D: usize>(lu: &[f64], perm: &[usize], b: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if D > PADDED_MAX && super::avx2_fma_available() {
        // SAFETY: the CPU has AVX2 and FMA (checked just above).
        return unsafe { x86::solve_in_place_fma::<D>(lu, perm, b) };
    }
    solve_in_place_body::<D, false>(lu, perm, b)
}

/// [`solve_in_place`]'s body; `FMA` fuses the multiply-subtracts.
#[inline(always)]
fn solve_in_place_body<const D: usize, const FMA: bool>(lu: &[f64], perm: &[usize], b: &mut [f64]) {
    let lu = &lu[..D * D];
    let b = &mut b[..D];
    for (k, &p) in perm[..D].iter().enumerate() {
        if p != k {
            b.swap(k, p);
        }
    }
    // No zero-skipping here: for the small D of a step the branch costs
    // more than the multiply-adds it saves (measured: 80 → ns per solve at D = 11).
    for j in 0..D {
        let bj = b[j];
        let col = &lu[j * D + j + 1..(j + 1) * D];
        for (x, l) in b[j + 1..].iter_mut().zip(col) {
            *x = if FMA { (-l).mul_add(bj, *x) } else { *x - l * bj };
        }
    }
    // Reciprocals first: independent divisions that overlap the forward
    // sweep, leaving a multiply instead of a division on the back
    // substitution's dependency chain.
    let mut rdiag = [0.0; D];
    for (j, r) in rdiag.iter_mut().enumerate() {
        *r = 1.0 / lu[j * D + j];
    }
    for j in (0..D).rev() {
        b[j] *= rdiag[j];
        let bj = b[j];
        let col = &lu[j * D..j * D + j];
        for (x, u) in b[..j].iter_mut().zip(col) {
            *x = if FMA { (-u).mul_add(bj, *x) } else { *x - u * bj };
        }
    }
}

/// Factors the `n × n` column-major matrix in `lu` in place (`P A = L U`,
/// partial pivoting over all rows), for sizes known only at run time (the
/// Schur complement of the stage-decoupled Newton matrix is `S·M` square);
/// `scale` is scratch of at least `n` entries. The diagonal of the factors
/// holds the reciprocals `1/u_kk` of `U`'s diagonal, which the elimination
/// forms anyway, so that a solve multiplies instead of dividing.
/// The singularity test is [`factor_in_place`]'s: a pivot below `64 ε`
/// times its column's largest magnitude.
#[inline]
pub(crate) fn factor_runtime(lu: &mut [f64], n: usize, perm: &mut [usize], scale: &mut [f64]) -> Result<(), Singular> {
    // The Schur complements met in practice are a few multipliers square:
    // each size up to 8 gets its own copy of the elimination on fixed-size
    // columns (`factor_fixed`), the same operations in the same order as
    // the general one.
    match n {
        0 => Ok(()), // No multipliers (an unconstrained system): nothing to factor.
        1 => factor_fixed::<1>(lu, perm, scale),
        2 => factor_fixed::<2>(lu, perm, scale),
        3 => factor_fixed::<3>(lu, perm, scale),
        4 => factor_fixed::<4>(lu, perm, scale),
        5 => factor_fixed::<5>(lu, perm, scale),
        6 => factor_fixed::<6>(lu, perm, scale),
        7 => factor_fixed::<7>(lu, perm, scale),
        8 => factor_fixed::<8>(lu, perm, scale),
        _ => factor_sized(lu, n, perm, scale),
    }
}

/// [`factor_sized`] for a size known at compile time: the matrix as `K`
/// columns of `K` entries, so every loop has a constant trip count and
/// every index a constant bound (the slice form keeps iterator and
/// bounds-check bookkeeping that costs more than a small matrix's
/// arithmetic). The same operations in the same order.
// Index loops: the iterator forms (`enumerate().skip(k + 1)`, a subslice)
// cost ≈ 190 more instructions a step on the skate at s = 3.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn factor_fixed<const K: usize>(lu: &mut [f64], perm: &mut [usize], scale: &mut [f64]) -> Result<(), Singular> {
    let (cols, _) = lu[..K * K].as_chunks_mut::<K>();
    let cols: &mut [[f64; K]; K] = cols.try_into().expect("K columns of K entries");
    let perm: &mut [usize; K] = (&mut perm[..K]).try_into().expect("K pivots");
    let scale: &mut [f64; K] = (&mut scale[..K]).try_into().expect("K scales");
    for (sk, col) in scale.iter_mut().zip(cols.iter()) {
        *sk = super::column_scale(col);
    }
    for k in 0..K {
        let (mut p, mut best) = (k, cols[k][k].abs());
        for r in k + 1..K {
            if cols[k][r].abs() > best {
                (p, best) = (r, cols[k][r].abs());
            }
        }
        let threshold = 64.0 * f64::EPSILON * scale[k];
        if best.is_nan() || threshold.is_nan() || best <= threshold {
            return Err(Singular { column: k, pivot: best });
        }
        perm[k] = p;
        if p != k {
            for col in cols.iter_mut() {
                col.swap(k, p);
            }
        }
        let rpiv = 1.0 / cols[k][k];
        cols[k][k] = rpiv;
        for r in k + 1..K {
            cols[k][r] *= rpiv;
        }
        let lower = cols[k];
        for col in cols[k + 1..].iter_mut() {
            let ukj = col[k];
            // A zero `u_kj` changes nothing: the products are formed and
            // selected rather than branched around.
            for r in k + 1..K {
                let updated = col[r] - lower[r] * ukj;
                col[r] = if ukj != 0.0 { updated } else { col[r] };
            }
        }
    }
    Ok(())
}

/// The general elimination of [`factor_runtime`], for sizes above 8 (and
/// the reference its fixed-size copies are tested against).
#[inline(always)]
fn factor_sized(lu: &mut [f64], n: usize, perm: &mut [usize], scale: &mut [f64]) -> Result<(), Singular> {
    let lu = &mut lu[..n * n];
    let scale = &mut scale[..n];
    for (sk, col) in scale.iter_mut().zip(lu.chunks_exact(n)) {
        *sk = super::column_scale(col);
    }
    for k in 0..n {
        let col = &lu[k * n..(k + 1) * n];
        let (mut p, mut best) = (k, col[k].abs());
        for (r, x) in col.iter().enumerate().skip(k + 1) {
            if x.abs() > best {
                (p, best) = (r, x.abs());
            }
        }
        let threshold = 64.0 * f64::EPSILON * scale[k];
        if best.is_nan() || threshold.is_nan() || best <= threshold {
            return Err(Singular { column: k, pivot: best });
        }
        perm[k] = p;
        if p != k {
            for j in 0..n {
                lu.swap(j * n + k, j * n + p);
            }
        }
        let rpiv = 1.0 / lu[k * n + k];
        lu[k * n + k] = rpiv;
        for x in lu[k * n + k + 1..(k + 1) * n].iter_mut() {
            *x *= rpiv;
        }
        let (head, tail) = lu.split_at_mut((k + 1) * n);
        let lower = &head[k * n + k + 1..(k + 1) * n];
        for col_j in tail.chunks_exact_mut(n) {
            let ukj = col_j[k];
            if ukj != 0.0 {
                for (x, l) in col_j[k + 1..].iter_mut().zip(lower) {
                    *x -= l * ukj;
                }
            }
        }
    }
    Ok(())
}

/// Overwrites `b` with `A⁻¹ b` from the factors of [`factor_runtime`].
#[inline]
pub(crate) fn solve_runtime(lu: &[f64], n: usize, perm: &[usize], b: &mut [f64]) {
    // Small sizes as in `factor_runtime`: the general loops' slicing and
    // bounds checks cost more than the arithmetic there.
    match n {
        1 => solve_fixed::<1>(lu, perm, b),
        2 => solve_fixed::<2>(lu, perm, b),
        3 => solve_fixed::<3>(lu, perm, b),
        4 => solve_fixed::<4>(lu, perm, b),
        5 => solve_fixed::<5>(lu, perm, b),
        6 => solve_fixed::<6>(lu, perm, b),
        7 => solve_fixed::<7>(lu, perm, b),
        8 => solve_fixed::<8>(lu, perm, b),
        _ => solve_sized(lu, n, perm, b),
    }
}

/// [`solve_sized`] for a size known at compile time, as
/// [`factor_fixed`]: the same operations in the same order.
#[inline(always)]
fn solve_fixed<const K: usize>(lu: &[f64], perm: &[usize], b: &mut [f64]) {
    let (cols, _) = lu[..K * K].as_chunks::<K>();
    let cols: &[[f64; K]; K] = cols.try_into().expect("K columns of K entries");
    let perm: &[usize; K] = perm[..K].try_into().expect("K pivots");
    let b: &mut [f64; K] = (&mut b[..K]).try_into().expect("K entries");
    for (k, &p) in perm.iter().enumerate() {
        if p != k {
            b.swap(k, p);
        }
    }
    for j in 0..K {
        let bj = b[j];
        for r in j + 1..K {
            b[r] -= cols[j][r] * bj;
        }
    }
    for j in (0..K).rev() {
        b[j] *= cols[j][j];
        let bj = b[j];
        for r in 0..j {
            b[r] -= cols[j][r] * bj;
        }
    }
}

/// The general solve of [`solve_runtime`], for sizes above 8 (and the
/// reference its fixed-size copies are tested against).
#[inline(always)]
fn solve_sized(lu: &[f64], n: usize, perm: &[usize], b: &mut [f64]) {
    let lu = &lu[..n * n];
    let b = &mut b[..n];
    for (k, &p) in perm[..n].iter().enumerate() {
        if p != k {
            b.swap(k, p);
        }
    }
    for j in 0..n {
        let bj = b[j];
        for (x, l) in b[j + 1..].iter_mut().zip(&lu[j * n + j + 1..(j + 1) * n]) {
            *x -= l * bj;
        }
    }
    for j in (0..n).rev() {
        b[j] *= lu[j * n + j];
        let bj = b[j];
        for (x, u) in b[..j].iter_mut().zip(&lu[j * n..j * n + j]) {
            *x -= u * bj;
        }
    }
}

/// An LU factorization `P A = L U` of a small fixed-size matrix, stored in
/// place on the stack (partial pivoting over all rows).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Lu<const D: usize> {
    lu: Matrix<D, D>,
    perm: [usize; D],
}

impl<const D: usize> Lu<D> {
    pub(crate) fn new() -> Self {
        Lu { lu: Matrix::<D, D>::zeros(), perm: [0; D] }
    }

    /// Factors `a` (see [`factor_in_place`] for the singularity test).
    pub(crate) fn factor(&mut self, a: &Matrix<D, D>) -> Result<(), Singular> {
        self.lu.copy_from(a);
        let scale = column_scales::<D>(a.as_slice());
        factor_in_place::<D>(self.lu.as_mut_slice(), &mut self.perm, &scale, &[D])
    }

    /// Overwrites `b` with `A⁻¹ b`.
    pub(crate) fn solve_in_place(&self, b: &mut Vector<D>) {
        solve_in_place::<D>(self.lu.as_slice(), &self.perm, b.as_mut_slice());
    }
}

/// The row-swapping kernels compiled for AVX2 and FMA, chosen at run time:
/// without a global `target-cpu` rustc targets SSE2.
#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::Singular;

    /// # Safety
    /// AVX2 and FMA must be available.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn factor_in_place_fma<const D: usize>(
        lu: &mut [f64],
        perm: &mut [usize],
        scale: &[f64; D],
        block_ends: &[usize],
    ) -> Result<(), Singular> {
        super::factor_in_place_body::<D, true>(lu, perm, scale, block_ends)
    }

    /// # Safety
    /// AVX2 and FMA must be available.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn solve_in_place_fma<const D: usize>(lu: &[f64], perm: &[usize], b: &mut [f64]) {
        super::solve_in_place_body::<D, true>(lu, perm, b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::test_matrices::{nalgebra_solve, random_matrix, random_values};

    #[test]
    fn runtime_sized_lu_pivots_refuses_singular_and_accepts_empty() {
        let a = [0.0, 1.0, 3.0, 2.0, 1.0, 0.0, 1.0, 0.0, 1.0]; // column-major, a₀₀ = 0 needs a swap
        let (mut lu, mut perm, mut scale) = (a, [0usize; 3], [0.0; 3]);
        factor_runtime(&mut lu, 3, &mut perm, &mut scale).unwrap();
        let x = [1.0, -2.0, 0.5];
        let mut b = [0.0; 3];
        for (j, xj) in x.iter().enumerate() {
            for i in 0..3 {
                b[i] += a[j * 3 + i] * xj;
            }
        }
        solve_runtime(&lu, 3, &perm, &mut b);
        for (bi, xi) in b.iter().zip(x) {
            assert!((bi - xi).abs() < 1e-15, "{b:?}");
        }
        let mut singular = [1.0, 2.0, 2.0, 4.0];
        assert!(factor_runtime(&mut singular, 2, &mut perm, &mut scale).is_err());
        let mut nan = [f64::NAN, 0.0, 0.0, 1.0];
        assert!(factor_runtime(&mut nan, 2, &mut perm, &mut scale).is_err());
        assert!(factor_runtime(&mut [], 0, &mut [], &mut []).is_ok());
    }

    /// The fixed-size copies (sizes up to 8) perform the general
    /// elimination's operations in the same order: the same factors,
    /// pivots and solutions bit for bit, on matrices with zero entries
    /// (the skipped `u_kj`), a zero leading entry (a row swap), a singular
    /// one and a NaN; sizes 9 and 10 take the general loop. The solutions
    /// also agree with nalgebra's.
    #[test]
    fn fixed_size_copies_equal_the_general_elimination() {
        fn check(n: usize, seed: u64) {
            let mut values = random_values(seed, n * n + n);
            let b = values.split_off(n * n);
            let mut a = values;
            for k in (0..n * n).step_by(3) {
                a[k] = 0.0;
            }
            let (mut lu, mut perm, mut scale) = (a.clone(), vec![0usize; n], vec![0.0; n]);
            let (mut lu_g, mut perm_g, mut scale_g) = (a.clone(), vec![0usize; n], vec![0.0; n]);
            let fixed = factor_runtime(&mut lu, n, &mut perm, &mut scale);
            let general = factor_sized(&mut lu_g, n, &mut perm_g, &mut scale_g);
            assert_eq!(fixed.is_ok(), general.is_ok(), "n = {n}");
            if fixed.is_err() {
                return;
            }
            assert_eq!(perm, perm_g, "n = {n}");
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&lu), bits(&lu_g), "n = {n}: factors");
            let (mut y, mut y_g) = (b.clone(), b.clone());
            solve_runtime(&lu, n, &perm, &mut y);
            solve_sized(&lu_g, n, &perm_g, &mut y_g);
            assert_eq!(bits(&y), bits(&y_g), "n = {n}: solution");
            let dense = nalgebra::DMatrix::from_column_slice(n, n, &a);
            let want = dense.lu().solve(&nalgebra::DVector::from_column_slice(&b)).expect("regular");
            let err = y.iter().zip(want.iter()).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
            assert!(err < 1e-10 * want.amax().max(1.0), "n = {n}: {err:e} from nalgebra");
        }
        for n in 1..=10 {
            for seed in 1..=20 {
                check(n, seed * 7919 + n as u64);
            }
            // A singular matrix and a NaN are refused by both.
            for bad in [0.0, f64::NAN] {
                let mut a = vec![bad; n * n];
                let (mut perm, mut scale) = (vec![0usize; n], vec![0.0; n]);
                assert!(factor_runtime(&mut a, n, &mut perm, &mut scale).is_err(), "n = {n}, {bad}");
            }
        }
    }

    #[test]
    fn solves_a_pivoting_system() {
        let a = Matrix::<3, 3>::new(0.0, 2.0, 1.0, 1.0, 1.0, 0.0, 3.0, 0.0, 1.0);
        let x = Vector::<3>::new(1.0, -2.0, 0.5);
        let mut b = a * x;
        let mut lu = Lu::new();
        lu.factor(&a).unwrap();
        lu.solve_in_place(&mut b);
        assert!((b - x).amax() < 1e-15);
    }

    #[test]
    fn detects_singularity() {
        let a = Matrix::<2, 2>::new(1.0, 2.0, 2.0, 4.0);
        assert!(Lu::new().factor(&a).is_err());
        let nan = Matrix::<2, 2>::new(f64::NAN, 0.0, 0.0, 1.0);
        assert!(Lu::new().factor(&nan).is_err());
    }

    #[test]
    fn block_pivoting_stays_inside_its_blocks() {
        // Column 0 would pivot on row 2 with full pivoting; confined to the
        // first block (rows 0..2) it must pivot on row 1.
        let a = Matrix::<3, 3>::new(0.5, 1.0, 0.0, 1.0, 0.0, 1.0, 4.0, 1.0, 1.0);
        let x = Vector::<3>::new(0.25, -1.0, 2.0);
        let mut lu = a;
        let mut perm = [0; 3];
        let scale = column_scales::<3>(a.as_slice());
        factor_in_place::<3>(lu.as_mut_slice(), &mut perm, &scale, &[2, 3]).unwrap();
        assert_eq!(perm[0], 1);
        let mut b = a * x;
        solve_in_place::<3>(lu.as_slice(), &perm, b.as_mut_slice());
        assert!((b - x).amax() < 1e-15);
        // A singular leading block is reported even though A is regular.
        let a = Matrix::<3, 3>::new(1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 0.0, 1.0, 1.0);
        let mut lu = a;
        let scale = column_scales::<3>(a.as_slice());
        assert!(factor_in_place::<3>(lu.as_mut_slice(), &mut perm, &scale, &[2, 3]).is_err());
    }

    #[test]
    fn fma_build_of_the_swapping_kernel_solves() {
        // D > PADDED_MAX takes the FMA build where available.
        const D: usize = 70;
        let mut a = random_matrix::<D>(11);
        for i in 0..D {
            a[(i, i)] += 1.0;
        }
        let x = Vector::<D>::from_fn(|i, _| (i as f64 * 0.3).cos());
        let b = a * x;
        let mut lu = a;
        let mut perm = [0; D];
        factor_in_place::<D>(lu.as_mut_slice(), &mut perm, &column_scales::<D>(a.as_slice()), &[D]).unwrap();
        let mut y = b;
        solve_in_place::<D>(lu.as_slice(), &perm, y.as_mut_slice());
        let reference = nalgebra_solve(&a, &b);
        assert!((y - reference).amax() < 1e-10 * reference.amax(), "{}", (y - reference).amax());
    }
}
