//! Dense LU factorization with partial pivoting on column-major slices: the
//! linear algebra under the Newton matrix ([`crate::newton`]) and the
//! consistent-acceleration solves ([`crate::initial`]).
//!
//! Pivots may be confined to row blocks ("block pivoting"): column `k` looks
//! for its pivot only in rows `k..end`, where `end` is the end of the block
//! holding `k`. With the SPARK unknowns ordered so that each block of
//! columns meets a block of rows whose diagonal block is invertible, this is
//! block elimination (a Schur complement) done in place, and the structural
//! zeros it preserves are skipped by the `u_kj == 0` test of the update.

use crate::system::{Matrix, Vector};

/// A pivot that is zero or negligible relative to its column's magnitude.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Singular {
    pub(crate) column: usize,
    pub(crate) pivot: f64,
}

/// Factors the `D × D` column-major matrix in `lu` in place (`P A = L U`),
/// recording the row interchanges in `perm`. Column `k` pivots among rows
/// `k..e` where `e` is the first entry of `block_ends` above `k` (the last
/// entry must be `D`). A pivot below `64 ε · scale[k]` counts as singular:
/// column scales differ by orders of magnitude in the SPARK matrix, so a
/// global threshold would be wrong.
///
/// Right-looking, column by column, on slices so the inner loops are
/// bounds-check free and vectorize; `D` is a constant so the loop bounds are
/// known after monomorphization.
#[inline]
pub(crate) fn factor_in_place<const D: usize>(
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
                    *x -= l * ukj;
                }
            }
        }
    }
    Ok(())
}

/// Overwrites `b` with `A⁻¹ b` from the factors of [`factor_in_place`].
#[inline]
pub(crate) fn solve_in_place<const D: usize>(lu: &[f64], perm: &[usize], b: &mut [f64]) {
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
            *x -= l * bj;
        }
    }
    for j in (0..D).rev() {
        b[j] /= lu[j * D + j];
        let bj = b[j];
        let col = &lu[j * D..j * D + j];
        for (x, u) in b[..j].iter_mut().zip(col) {
            *x -= u * bj;
        }
    }
}

/// The largest magnitude of each column of a `D × D` column-major matrix.
#[inline]
pub(crate) fn column_scales<const D: usize>(a: &[f64]) -> [f64; D] {
    let mut s = [0.0; D];
    for (sk, col) in s.iter_mut().zip(a[..D * D].chunks_exact(D)) {
        *sk = col.iter().fold(0.0, |m: f64, x| m.max(x.abs()));
    }
    s
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
