//! Dense LU factorization with partial pivoting on fixed-size nalgebra
//! matrices: the Newton solver's linear algebra, on the stack, with a
//! singularity test relative to each column's scale.

use crate::system::{Matrix, Vector};

/// An LU factorization `P A = L U` stored in place.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Lu<const D: usize> {
    lu: Matrix<D, D>,
    perm: [usize; D],
}

/// A pivot that is zero or negligible relative to its column's magnitude.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Singular {
    pub(crate) column: usize,
    pub(crate) pivot: f64,
}

impl<const D: usize> Lu<D> {
    pub(crate) fn new() -> Self {
        Lu { lu: Matrix::<D, D>::zeros(), perm: [0; D] }
    }

    /// Factors `a`. A pivot below `64 ε · max_i |a_ij|` of its original
    /// column counts as singular: column scales differ by orders of
    /// magnitude in the SPARK matrix, so a global threshold would be wrong.
    ///
    /// Works on the column-major storage as slices (right-looking, column
    /// by column) so the inner loops are bounds-check free and vectorize.
    pub(crate) fn factor(&mut self, a: &Matrix<D, D>) -> Result<(), Singular> {
        self.lu.copy_from(a);
        let lu = self.lu.as_mut_slice();
        for k in 0..D {
            let scale = a.column(k).amax();
            let col_k = &lu[k * D..(k + 1) * D];
            let mut p = k;
            let mut best = col_k[k].abs();
            for (i, x) in col_k.iter().enumerate().skip(k + 1) {
                if x.abs() > best {
                    best = x.abs();
                    p = i;
                }
            }
            self.perm[k] = p;
            // Written to be true for NaN pivots too.
            if best.is_nan() || best <= 64.0 * f64::EPSILON * scale {
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

    /// Overwrites `b` with `A⁻¹ b`.
    pub(crate) fn solve_in_place(&self, b: &mut Vector<D>) {
        let b = b.as_mut_slice();
        for k in 0..D {
            let p = self.perm[k];
            if p != k {
                b.swap(k, p);
            }
        }
        let lu = self.lu.as_slice();
        for j in 0..D {
            let bj = b[j];
            if bj != 0.0 {
                let col = &lu[j * D + j + 1..(j + 1) * D];
                for (x, l) in b[j + 1..].iter_mut().zip(col) {
                    *x -= l * bj;
                }
            }
        }
        for j in (0..D).rev() {
            b[j] /= lu[j * D + j];
            let bj = b[j];
            if bj != 0.0 {
                let col = &lu[j * D..j * D + j];
                for (x, u) in b[..j].iter_mut().zip(col) {
                    *x -= u * bj;
                }
            }
        }
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
}
