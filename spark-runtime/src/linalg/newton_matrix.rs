//! The Newton matrix of the SPARK equations and its block factorization.
//!
//! Public (narrowly) so that benchmarks can time the linear algebra of one
//! Newton iteration apart from the derivative evaluations: get an assembled
//! matrix from [`Stepper::newton_matrix`](crate::Stepper::newton_matrix),
//! then time [`NewtonMatrix::factor`] and [`NewtonMatrix::solve_in_place`].
//!
//! # Block structure
//! With the stepper's unknowns `z = [V | μ | v₁]` and rows `[stage momentum
//! (S·N) | p₁ (N) | constraint rows (S·M)]`, the velocity unknowns
//! `X = (V, v₁)` meet the momentum rows in the block lower-triangular
//! `[[A_VV, 0], [P_V, M(Q₁)]]` (`v₁` enters only the `p₁` rows and the last
//! constraint rows), whose diagonal blocks are the stage mass matrices plus
//! `O(h)` and the end-point mass matrix. [`NewtonMatrix::factor`] therefore
//! orders the columns `(V, v₁, μ)` and confines each column's pivot search to
//! its own row block: an in-place Schur complement in the multipliers that
//! never touches the `v₁` columns of the stage rows (structural zeros) and
//! pivots within `S·N`, `N` and `S·M` rows instead of `D`. When a diagonal
//! block is (numerically) singular — large steps, degenerate mass
//! matrices — it falls back to partial pivoting over the whole matrix, so
//! the structured path never turns a solvable system into a failure.
//!
//! # Kernels
//! For `12 ≤ D ≤ 64` on x86-64 CPUs with AVX2 and FMA the factors use the
//! padded, swap-free kernel of `linalg` (chosen once, in
//! [`NewtonMatrix::new`]); otherwise the row-swapping one. Both follow the
//! same pivoting and singularity rules.
//!
//! # Storage
//! The matrix and its factors live on the heap, allocated once in
//! [`NewtonMatrix::new`] (a step allocates nothing). A stack matrix of
//! `8·D²` bytes overflowed a 2 MiB rayon worker stack from `D ≈ 250` on;
//! boxed, the stepper's own size is `O(S·D)` whatever `D`.

use super::{column_scale, factor_in_place, solve_in_place, PaddedLu};
use crate::system::{Matrix, Vector};
use nalgebra::{Const, MatrixView, MatrixViewMut};

/// Which elimination [`NewtonMatrix::factor`] used.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Factorization {
    /// Block elimination: columns `(V, v₁, μ)`, pivots confined to the stage,
    /// `p₁` and constraint row blocks (the Schur complement in `μ`).
    Structured,
    /// Partial pivoting over all rows (the structured path met a singular
    /// diagonal block).
    Dense,
}

/// The Newton matrix was singular: a pivot of the dense elimination was zero
/// or below `64 ε` times its column's magnitude.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("Newton matrix is singular at column {column} (pivot {})", crate::error::Sci(*pivot))]
pub struct SingularMatrix {
    /// Column (in the order of the unknowns `z = [V | μ | v₁]`) whose pivot failed.
    pub column: usize,
    /// The offending pivot magnitude.
    pub pivot: f64,
}

/// The `D × D` Newton matrix `∂G/∂z` of an `S`-stage SPARK step for a system
/// with `N` coordinates and `M` constraints (`D = S(N+M)+N`), with its LU
/// factors. Heap storage, allocated once.
#[derive(Clone, Debug)]
pub struct NewtonMatrix<const N: usize, const M: usize, const S: usize, const D: usize> {
    /// `∂G/∂z`, column-major, unknowns and rows in the stepper's order.
    jacobian: Box<[f64]>,
    /// LU factors of the row-swapping kernel (columns permuted to
    /// `(V, v₁, μ)` on the structured path); empty when `padded` is used.
    lu: Box<[f64]>,
    /// Row interchanges of `lu`.
    perm: Box<[usize]>,
    /// The padded kernel's factors (same column order), when `D` and the
    /// CPU suit it (see `linalg::PaddedLu`).
    padded: Option<PaddedLu<D>>,
    factored: Option<Factorization>,
}

impl<const N: usize, const M: usize, const S: usize, const D: usize> Default for NewtonMatrix<N, M, S, D> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const M: usize, const S: usize, const D: usize> NewtonMatrix<N, M, S, D> {
    /// First stage-row / `V` index past the stage velocities.
    const SN: usize = S * N;

    /// A zero matrix (allocates its two `D × D` buffers; fails to compile
    /// unless `D == S·(N+M)+N`).
    pub fn new() -> Self {
        const { assert!(D == S * (N + M) + N, "NewtonMatrix: D must equal S*(N+M)+N") };
        let padded = PaddedLu::new();
        let n = if padded.is_some() { 0 } else { D };
        NewtonMatrix {
            jacobian: vec![0.0; D * D].into_boxed_slice(),
            lu: vec![0.0; n * n].into_boxed_slice(),
            perm: vec![0; n].into_boxed_slice(),
            padded,
            factored: None,
        }
    }

    /// The matrix (as last assembled or set).
    pub fn matrix(&self) -> MatrixView<'_, f64, Const<D>, Const<D>> {
        MatrixView::from_slice_generic(&self.jacobian, Const::<D>, Const::<D>)
    }

    /// Mutable access to the matrix; invalidates the factorization.
    pub fn matrix_mut(&mut self) -> MatrixViewMut<'_, f64, Const<D>, Const<D>> {
        self.factored = None;
        MatrixViewMut::from_slice_generic(&mut self.jacobian, Const::<D>, Const::<D>)
    }

    /// Sets every entry to zero (a `memset`; nalgebra's element iterator
    /// for `fill` cost a fifth of a step).
    pub fn clear(&mut self) {
        self.factored = None;
        self.jacobian.fill(0.0);
    }

    /// Copies `a` into the matrix; invalidates the factorization.
    pub fn set(&mut self, a: &Matrix<D, D>) {
        self.factored = None;
        self.jacobian.copy_from_slice(a.as_slice());
    }

    /// The elimination of the current factors, `None` before [`factor`](Self::factor).
    pub fn factorization(&self) -> Option<Factorization> {
        self.factored
    }

    /// Factors the matrix: the structured block elimination when its
    /// diagonal blocks are regular, else partial pivoting over all rows.
    pub fn factor(&mut self) -> Result<Factorization, SingularMatrix> {
        let result = match &mut self.padded {
            Some(lu) => Self::factor_padded(lu, &self.jacobian),
            None => self.factor_swapping(),
        };
        self.factored = result.ok();
        result
    }

    /// The column of the assembled matrix at column `c` of the structured
    /// factors, whose columns are ordered `(V, v₁, μ)`.
    fn structured_column(c: usize) -> usize {
        let (sn, sm) = (Self::SN, S * M);
        if c < sn {
            c
        } else if c < sn + N {
            c + sm
        } else {
            c - N
        }
    }

    /// [`factor`](Self::factor) with the padded kernel.
    fn factor_padded(lu: &mut PaddedLu<D>, jacobian: &[f64]) -> Result<Factorization, SingularMatrix> {
        let sn = Self::SN;
        if lu.factor(jacobian, &std::array::from_fn(Self::structured_column), &[sn, sn + N, D]).is_ok() {
            return Ok(Factorization::Structured);
        }
        match lu.factor(jacobian, &std::array::from_fn(|c| c), &[D]) {
            Ok(()) => Ok(Factorization::Dense),
            Err(s) => Err(SingularMatrix { column: s.column, pivot: s.pivot }),
        }
    }

    /// [`factor`](Self::factor) with the row-swapping kernel.
    fn factor_swapping(&mut self) -> Result<Factorization, SingularMatrix> {
        let sn = Self::SN;
        // Each column is copied with its scale taken from the assembled
        // matrix: scanning the freshly copied factors instead waits on the
        // copy's stores (docs/performance/README.md, "The LU kernels").
        let scale = copy_columns::<D>(&self.jacobian, &mut self.lu, Self::structured_column);
        if factor_in_place::<D>(&mut self.lu, &mut self.perm, &scale, &[sn, sn + N, D]).is_ok() {
            return Ok(Factorization::Structured);
        }
        let scale = copy_columns::<D>(&self.jacobian, &mut self.lu, |c| c);
        match factor_in_place::<D>(&mut self.lu, &mut self.perm, &scale, &[D]) {
            Ok(()) => Ok(Factorization::Dense),
            Err(s) => Err(SingularMatrix { column: s.column, pivot: s.pivot }),
        }
    }

    /// Overwrites `b` with `A⁻¹ b` using the current factors. Leaves `b`
    /// unchanged when the matrix has not been factored successfully.
    pub fn solve_in_place(&self, b: &mut Vector<D>) {
        let b = b.as_mut_slice();
        match self.factored {
            None => {}
            Some(Factorization::Dense) => self.solve_factors(b),
            Some(Factorization::Structured) => {
                self.solve_factors(b);
                // The solution came out in column order (V, v₁, μ); back to (V, μ, v₁).
                b[Self::SN..].rotate_left(N);
            }
        }
    }

    /// `b ← A⁻¹ b` in the column order of the factors.
    fn solve_factors(&self, b: &mut [f64]) {
        match &self.padded {
            Some(lu) => lu.solve(b),
            None => solve_in_place::<D>(&self.lu, &self.perm, b),
        }
    }
}

/// Copies the columns `source(c)` of the `D × D` column-major `from` to
/// columns `c` of `to` and returns the largest magnitude of each (the
/// [`column_scales`](super::column_scales) of `to`, read from `from`).
#[inline(always)]
fn copy_columns<const D: usize>(from: &[f64], to: &mut [f64], source: impl Fn(usize) -> usize) -> [f64; D] {
    let mut scale = [0.0; D];
    for (c, (dst, sc)) in to[..D * D].chunks_exact_mut(D).zip(scale.iter_mut()).enumerate() {
        let src = &from[source(c) * D..][..D];
        dst.copy_from_slice(src);
        *sc = column_scale(src);
    }
    scale
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A matrix with the SPARK zero pattern (no v₁ in stage or condition
    /// rows) and a dominant diagonal, for N = 2, M = 1, S = 2 (D = 8).
    fn spark_like() -> Matrix<8, 8> {
        let mut a = Matrix::<8, 8>::from_fn(|i, j| ((i * 7 + j * 3) % 5) as f64 * 0.1 - 0.2);
        for i in 0..8 {
            a[(i, i)] += 2.0;
        }
        for i in (0..4).chain(6..7) {
            for j in 6..8 {
                a[(i, j)] = 0.0;
            }
        }
        // Multiplier columns (4, 5) need their pivots in the constraint rows (6, 7).
        a[(6, 4)] = 1.0;
        a[(7, 5)] = -1.5;
        a[(6, 6)] = 0.0;
        a[(7, 6)] = 0.7;
        a
    }

    #[test]
    fn structured_and_dense_solve_agree() {
        let a = spark_like();
        let x = Vector::<8>::from_fn(|i, _| 0.5 - i as f64 * 0.3);
        let mut nm = NewtonMatrix::<2, 1, 2, 8>::new();
        nm.set(&a);
        assert_eq!(nm.factor(), Ok(Factorization::Structured));
        let mut b = a * x;
        nm.solve_in_place(&mut b);
        assert!((b - x).amax() < 1e-13, "{}", (b - x).amax());
    }

    #[test]
    fn falls_back_to_dense_pivoting() {
        // A singular stage block (rows 0..4 × V columns 0..4) in a regular matrix.
        let mut a = spark_like();
        for j in 0..4 {
            a[(1, j)] = a[(0, j)];
        }
        a[(1, 4)] = 3.0;
        let x = Vector::<8>::from_fn(|i, _| 1.0 + i as f64);
        let mut nm = NewtonMatrix::<2, 1, 2, 8>::new();
        nm.set(&a);
        assert_eq!(nm.factor(), Ok(Factorization::Dense));
        let mut b = a * x;
        nm.solve_in_place(&mut b);
        assert!((b - x).amax() < 1e-12, "{}", (b - x).amax());
        nm.matrix_mut().fill(0.0);
        assert!(nm.factor().is_err());
    }

    #[test]
    fn stepper_matrices_take_the_structured_path() {
        use crate::fixtures::paper::{MobileRobot, Skate};
        use crate::{Method, State, Stepper, Tableau};
        let robot = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
        for m in [Method::Gauss, Method::LobattoIIIAB, Method::LobattoIIIABD] {
            let mut st = Stepper::<_, 4, 2, 3, 22>::new(MobileRobot::default(), Tableau::new(m).unwrap());
            let (nm, g) = st.newton_matrix(&robot, 0.2);
            let mut nm = nm.clone();
            assert_eq!(nm.factor(), Ok(Factorization::Structured), "{m}");
            let mut x = g;
            nm.solve_in_place(&mut x);
            let reference = nm.matrix().into_owned().lu().solve(&g).unwrap();
            assert!((x - reference).amax() <= 1e-12 * reference.amax().max(1.0), "{m}");
        }
        let skate = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
        let mut st =
            Stepper::<_, 3, 1, 2, 11>::new(Skate::default(), Tableau::new(Method::ModifiedLobattoIIIAB).unwrap());
        let mut nm = st.newton_matrix(&skate, 0.1).0.clone();
        assert_eq!(nm.factor(), Ok(Factorization::Structured));
    }

    #[test]
    fn reused_factorization_reaches_the_same_solution() {
        use crate::fixtures::paper::Skate;
        use crate::{Method, NewtonMode, NewtonOptions, State, Stepper, Tableau};
        let start = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
        let tab = Tableau::new(Method::Gauss).unwrap();
        let opts = NewtonOptions { mode: NewtonMode::Simplified, ..NewtonOptions::default() };
        let mut plain = Stepper::<_, 3, 1, 2, 11>::new(Skate::default(), tab).with_options(opts);
        let reuse = NewtonOptions { reuse_factorization: true, ..opts };
        let mut reusing = Stepper::<_, 3, 1, 2, 11>::new(Skate::default(), tab).with_options(reuse);
        let (mut a, mut b, mut ia, mut ib) = (start, start, 0, 0);
        for _ in 0..50 {
            let (ra, rb) = (plain.step(&a, 0.05).unwrap(), reusing.step(&b, 0.05).unwrap());
            (a, b, ia, ib) = (ra.state, rb.state, ia + ra.iterations, ib + rb.iterations);
        }
        assert!((a.q - b.q).amax() < 1e-13 && (a.v - b.v).amax() < 1e-13);
        // Reusing an earlier step's factors contracts more slowly: it did reuse.
        assert!(ib > ia, "reuse {ib} vs fresh {ia} iterations");
    }

    /// Factor + solve of a real step's Newton matrix against nalgebra's LU.
    fn check_real<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
        sys: Sys,
        method: crate::Method,
        start: crate::State<N>,
        h: f64,
    ) where
        Sys: crate::NonholonomicSystem<N, M> + Clone,
    {
        let mut st = crate::Stepper::<Sys, N, M, S, D>::new(sys, crate::Tableau::new(method).unwrap());
        let (nm, g) = st.newton_matrix(&start, h);
        let mut nm = nm.clone();
        assert_eq!(nm.factor(), Ok(Factorization::Structured), "D = {D} {method}");
        let mut x = g;
        nm.solve_in_place(&mut x);
        let a = nalgebra::DMatrix::from_column_slice(D, D, nm.matrix().into_owned().as_slice());
        let reference = a.lu().solve(&nalgebra::DVector::from_column_slice(g.as_slice())).unwrap();
        let err = x.iter().zip(reference.iter()).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(err <= 1e-12 * reference.amax().max(1.0), "D = {D} {method}: {err:e}");
        // Simplified Newton solves again with the same factors.
        let mut y = g * 2.0;
        nm.solve_in_place(&mut y);
        assert!((y - x * 2.0).amax() <= 1e-12 * x.amax().max(1.0), "D = {D} {method}");
    }

    #[test]
    fn every_paper_size_solves_like_nalgebra() {
        use crate::fixtures::paper::{MobileRobot, MpParticles, Particle, Skate};
        use crate::{Method, State};
        let p0 = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
        let s0 = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
        let r0 = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0));
        let m0 = State::new(
            0.0,
            Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]),
            Vector::<7>::from_row_slice(&[0.3, -0.2, 0.1, 0.0, 0.2, -0.1, 0.1]),
        );
        check_real::<_, 3, 1, 2, 11>(Particle, Method::Gauss, p0, 0.2);
        check_real::<_, 3, 1, 3, 15>(Skate::default(), Method::LobattoIIIAB, s0, 0.1);
        check_real::<_, 4, 2, 2, 16>(MobileRobot::default(), Method::Gauss, r0, 0.2);
        check_real::<_, 3, 1, 4, 19>(Skate::default(), Method::Gauss, s0, 0.1);
        check_real::<_, 4, 2, 3, 22>(MobileRobot::default(), Method::LobattoIIIABD, r0, 0.2);
        check_real::<_, 7, 1, 2, 23>(MpParticles, Method::Gauss, m0, 0.05);
        check_real::<_, 4, 2, 4, 28>(MobileRobot::default(), Method::Gauss, r0, 0.2);
        check_real::<_, 7, 1, 3, 31>(MpParticles, Method::LobattoIIIAB, m0, 0.05);
        check_real::<_, 7, 1, 4, 39>(MpParticles, Method::Gauss, m0, 0.05);
        check_real::<_, 7, 1, 5, 47>(MpParticles, Method::Gauss, m0, 0.05);
        // Large steps: the stage blocks are far from the mass matrices.
        check_real::<_, 7, 1, 2, 23>(MpParticles, Method::Gauss, m0, 1.5);
        check_real::<_, 4, 2, 3, 22>(MobileRobot::default(), Method::LobattoIIIAB, r0, 2.0);
    }

    #[test]
    fn padded_range_falls_back_to_dense_pivoting() {
        // N = 3, M = 1, S = 3 (D = 15, the padded kernel where available):
        // a singular stage block in a regular matrix.
        const D: usize = 15;
        let mut a = Matrix::<D, D>::from_fn(|i, j| ((i * 7 + j * 3) % 5) as f64 * 0.1 - 0.2);
        for i in 0..D {
            a[(i, i)] += 2.0;
        }
        for j in 0..9 {
            a[(1, j)] = a[(0, j)];
        }
        a[(1, 10)] = 3.0;
        let x = Vector::<D>::from_fn(|i, _| 1.0 + i as f64);
        let mut nm = NewtonMatrix::<3, 1, 3, D>::new();
        #[cfg(target_arch = "x86_64")]
        assert_eq!(
            nm.padded.is_some(),
            std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        );
        nm.set(&a);
        assert_eq!(nm.factor(), Ok(Factorization::Dense));
        let mut b = a * x;
        nm.solve_in_place(&mut b);
        assert!((b - x).amax() < 1e-12, "{}", (b - x).amax());
        // Singular: reported with the column of the dense elimination.
        a.set_column(4, &(a.column(2) + a.column(3)));
        nm.set(&a);
        let err = nm.factor().unwrap_err();
        assert!(err.column <= 4 && nm.factorization().is_none(), "{err:?}");
        // NaN: reported, and a later regular matrix factors again.
        let mut n = a;
        n[(14, 0)] = f64::NAN;
        nm.set(&n);
        assert!(nm.factor().unwrap_err().pivot.is_nan());
        nm.set(&spark_like_15());
        assert_eq!(nm.factor(), Ok(Factorization::Structured));
    }

    /// A regular D = 15 matrix with the SPARK zero pattern (N = 3, M = 1, S = 3).
    fn spark_like_15() -> Matrix<15, 15> {
        let mut a = Matrix::<15, 15>::from_fn(|i, j| ((i * 5 + j * 2) % 7) as f64 * 0.05 - 0.1);
        for i in 0..15 {
            a[(i, i)] += 2.0;
        }
        // v₁ (columns 12..15) only in the p₁ rows (9..12) and the last constraint row.
        for i in (0..9).chain(12..14) {
            for j in 12..15 {
                a[(i, j)] = 0.0;
            }
        }
        // Multipliers (columns 9..12) pivot in the constraint rows (12..15).
        for (r, c) in [(12, 9), (13, 10), (14, 11)] {
            a[(r, c)] = 1.5;
        }
        a
    }
}
