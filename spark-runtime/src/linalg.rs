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
    pub(crate) fn factor(&mut self, a: &Matrix<D, D>) -> Result<(), Singular> {
        self.lu.copy_from(a);
        for k in 0..D {
            let scale = a.column(k).amax();
            let mut p = k;
            let mut best = self.lu[(k, k)].abs();
            for i in k + 1..D {
                let v = self.lu[(i, k)].abs();
                if v > best {
                    best = v;
                    p = i;
                }
            }
            self.perm[k] = p;
            // Written to be true for NaN pivots too.
            if best.is_nan() || best <= 64.0 * f64::EPSILON * scale {
                return Err(Singular { column: k, pivot: best });
            }
            if p != k {
                self.lu.swap_rows(k, p);
            }
            let inv = 1.0 / self.lu[(k, k)];
            for i in k + 1..D {
                self.lu[(i, k)] *= inv;
            }
            for j in k + 1..D {
                let ukj = self.lu[(k, j)];
                if ukj != 0.0 {
                    for i in k + 1..D {
                        let lik = self.lu[(i, k)];
                        self.lu[(i, j)] -= lik * ukj;
                    }
                }
            }
        }
        Ok(())
    }

    /// Overwrites `b` with `A⁻¹ b`.
    pub(crate) fn solve_in_place(&self, b: &mut Vector<D>) {
        for k in 0..D {
            let p = self.perm[k];
            if p != k {
                b.swap_rows(k, p);
            }
        }
        for j in 0..D {
            let bj = b[j];
            if bj != 0.0 {
                for i in j + 1..D {
                    b[i] -= self.lu[(i, j)] * bj;
                }
            }
        }
        for j in (0..D).rev() {
            b[j] /= self.lu[(j, j)];
            let bj = b[j];
            if bj != 0.0 {
                for i in 0..j {
                    b[i] -= self.lu[(i, j)] * bj;
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
