//! Dense linear algebra under the step: LU factorizations with partial
//! pivoting on column-major slices ([`lu`]: row-swapping kernels for any
//! size, fixed or known at run time; [`padded_lu`]: the padded, swap-free
//! AVX2+FMA kernel of the small Newton matrices) and the two Newton
//! matrices built on them ([`newton_matrix`]: the exact Jacobian;
//! [`decoupled`]: the stage-decoupled matrix, with `stiff_stages` for the
//! stage blocks it keeps for a constant stiffness), and the largest
//! magnitudes that Newton's residual and update norms take
//! (`largest_magnitude`).
//!
//! Pivots may be confined to row blocks ("block pivoting"): column `k` looks
//! for its pivot only in rows `k..end`, where `end` is the end of the block
//! holding `k`. With the SPARK unknowns ordered so that each block of
//! columns meets a block of rows whose diagonal block is invertible, this is
//! block elimination (a Schur complement) done in place, and the structural
//! zeros it preserves are skipped by the `u_kj == 0` test of the update.
//!
//! Two kernels for the fixed sizes: the row-swapping [`factor_in_place`]
//! (any `D`; compiled for AVX2+FMA when `D > PADDED_MAX` and the CPU has
//! them) and the padded, swap-free [`PaddedLu`] (`PADDED_MIN ≤ D ≤
//! PADDED_MAX`), which is 1.2–1.3× faster at the Newton matrices of the
//! paper's systems (D = 19..47).

pub(crate) mod decoupled;
mod largest_magnitude;
mod lu;
pub(crate) mod newton_matrix;
mod padded_lu;
pub(crate) mod stiff_stages;

pub(crate) use largest_magnitude::largest_magnitude;

pub(crate) use lu::{factor_in_place, factor_runtime, solve_in_place, solve_runtime, Lu};
pub(crate) use padded_lu::PaddedLu;

use crate::system::Vector;

/// Whether the `n × n` column-major matrix `a` is singular to working
/// precision as given (a pivot of the elimination with partial pivoting
/// below `64 ε` times its column's largest entry) but regular once its rows
/// and columns are scaled to unit size: then its entries lie too far apart
/// in magnitude for the elimination to resolve, and the singularity is one
/// of scale, not of structure (a zero mass, dependent constraints). The
/// scaling is Ruiz's equilibration (each row and column divided by the
/// square root of its largest magnitude, repeated). Allocates: for the
/// failure paths only.
pub(crate) fn singular_only_by_scale(a: &[f64], n: usize) -> bool {
    let regular = |m: &[f64]| regular(m, n);
    let a = &a[..n * n];
    if !a.iter().all(|x| x.is_finite()) || regular(a) {
        return false;
    }
    let mut b = a.to_vec();
    let (mut rows, mut cols) = (vec![0.0f64; n], vec![0.0f64; n]);
    for _ in 0..32 {
        rows.fill(0.0);
        cols.fill(0.0);
        for (j, col) in b.chunks_exact(n).enumerate() {
            for (i, x) in col.iter().enumerate() {
                rows[i] = rows[i].max(x.abs());
                cols[j] = cols[j].max(x.abs());
            }
        }
        for (j, col) in b.chunks_exact_mut(n).enumerate() {
            for (i, x) in col.iter_mut().enumerate() {
                if rows[i] > 0.0 && cols[j] > 0.0 {
                    *x /= rows[i].sqrt() * cols[j].sqrt();
                }
            }
        }
    }
    regular(&b)
}

/// Whether the `n × n` column-major matrix `a` passes the factorization's
/// test (every pivot of the elimination with partial pivoting at least
/// `64 ε` times its column's largest entry). Allocates: for the failure
/// paths only.
pub(crate) fn regular(a: &[f64], n: usize) -> bool {
    let mut lu = a[..n * n].to_vec();
    let (mut perm, mut scale) = (vec![0; n], vec![0.0; n]);
    factor_runtime(&mut lu, n, &mut perm, &mut scale).is_ok()
}

/// The smallest nonzero and the largest magnitude among the entries of `a`
/// (`(0, 0)` when every entry is zero).
pub(crate) fn magnitude_range(a: &[f64]) -> (f64, f64) {
    let nonzero = a.iter().map(|x| x.abs()).filter(|x| *x > 0.0);
    let smallest = nonzero.clone().fold(f64::INFINITY, f64::min);
    let largest = nonzero.fold(0.0, f64::max);
    if largest == 0.0 {
        (0.0, 0.0)
    } else {
        (smallest, largest)
    }
}

/// Whether the `N × N` column-major matrix `m` is diagonal (every
/// off-diagonal entry zero).
pub(crate) fn is_diagonal<const N: usize>(m: &[f64]) -> bool {
    (0..N * N).all(|k| k % (N + 1) == 0 || m[k] == 0.0)
}

/// A pivot that is zero or negligible relative to its column's magnitude.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Singular {
    pub(crate) column: usize,
    pub(crate) pivot: f64,
}

/// The largest magnitude of each column of a `D × D` column-major matrix
/// (NaN entries passed over, as `f64::max` would).
#[inline]
pub(crate) fn column_scales<const D: usize>(a: &[f64]) -> [f64; D] {
    let mut s = [0.0; D];
    for (sk, col) in s.iter_mut().zip(a[..D * D].chunks_exact(D)) {
        *sk = column_scale(col);
    }
    s
}

/// The largest magnitude in `col`, NaN entries passed over: a comparison
/// rather than `f64::max`, whose NaN rule costs a blend per entry on a
/// dependency chain.
#[inline(always)]
pub(crate) fn column_scale(col: &[f64]) -> f64 {
    col.iter().fold(0.0, |m: f64, x| if x.abs() > m { x.abs() } else { m })
}

/// The largest of the non-negative `r(0), …, r(n − 1)` (0 when `n = 0`)
/// and whether any was NaN. Four running maxima, merged at the end: one
/// maximum carried through the loop is a chain of dependent `maxsd` (and
/// `f64::max`, which is NaN-aware, adds a blend to each link). A NaN never
/// wins a comparison, so it shows only in the flag; an infinity is the
/// maximum. The result does not depend on the order: a maximum is exact.
#[inline(always)]
pub(crate) fn largest_and_nan(n: usize, r: impl Fn(usize) -> f64) -> (f64, bool) {
    const L: usize = 4;
    let (mut largest, mut nan) = ([0.0f64; L], [false; L]);
    // Short vectors (D = 7 at n = 3, s = 1) in one plain pass: the four
    // maxima cost more than the chain they break (measured: +5 % on a
    // step of the particle).
    if n < 2 * L {
        for i in 0..n {
            let x = r(i);
            nan[0] |= x.is_nan();
            largest[0] = if x > largest[0] { x } else { largest[0] };
        }
        return (largest[0], nan[0]);
    }
    for c in 0..n / L {
        for k in 0..L {
            let x = r(c * L + k);
            nan[k] |= x.is_nan();
            largest[k] = if x > largest[k] { x } else { largest[k] };
        }
    }
    for i in n / L * L..n {
        let x = r(i);
        nan[0] |= x.is_nan();
        largest[0] = if x > largest[0] { x } else { largest[0] };
    }
    let mut best = largest[0];
    for &x in &largest[1..] {
        best = if x > best { x } else { best };
    }
    (best, nan.contains(&true))
}

/// `max_i |Δz_i| / (1 + |z_i|)`, NaN as soon as any component is NaN.
///
/// `f64::max` returns the other operand when one is NaN, so a fold with it
/// would hide a NaN update and a solve could look converged; here a NaN
/// (or infinite) update is reported by the caller at the iteration where it
/// appears.
pub(crate) fn scaled_update_norm<const D: usize>(update: &Vector<D>, z: &Vector<D>) -> f64 {
    let (d, x) = (update.as_slice(), z.as_slice());
    match largest_and_nan(D, |i| d[i].abs() / (1.0 + x[i].abs())) {
        (_, true) => f64::NAN,
        (norm, false) => norm,
    }
}

/// Sets `weights` to `1/(1 + |z_i − Δz_i|)`, the scaled update norm's
/// weights at the iterate `z − update` an update leads to (each
/// `z_i − Δz_i` is the value `z -= update` stores), and returns
/// [`weighted_update_norm`] of `update` with them.
pub(crate) fn weigh_and_norm<const D: usize>(update: &Vector<D>, z: &Vector<D>, weights: &mut Vector<D>) -> f64 {
    let (d, x, w) = (update.as_slice(), z.as_slice(), weights.as_mut_slice());
    for i in 0..D {
        w[i] = 1.0 / (1.0 + (x[i] - d[i]).abs());
    }
    weighted_update_norm(update, weights)
}

/// `max_i |Δz_i| · w_i`, NaN as soon as any product is NaN (a NaN update,
/// or an infinite one with a zero weight); an infinite update with a
/// nonzero weight is infinite.
///
/// Newton's updates are measured with the weights of [`weigh_and_norm`]
/// of the first update on each set of factors: the scale of the unknowns
/// does not change while an iteration converges, and the norm then costs a
/// product per component instead of a division.
pub(crate) fn weighted_update_norm<const D: usize>(update: &Vector<D>, weights: &Vector<D>) -> f64 {
    match largest_magnitude(update.as_slice(), Some(weights.as_slice())) {
        (_, true) => f64::NAN,
        (norm, false) => norm,
    }
}

/// Whether this CPU has AVX2 and FMA (the detection is cached by std): the
/// check every use of the kernels compiled for them rests on.
#[cfg(target_arch = "x86_64")]
pub(crate) fn avx2_fma_available() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// Whether this CPU has AVX-512 F, VL and DQ besides AVX2 and FMA: the
/// check the lane kernel's eight-lane build rests on.
#[cfg(target_arch = "x86_64")]
pub(crate) fn avx512_available() -> bool {
    avx2_fma_available()
        && std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512vl")
        && std::arch::is_x86_feature_detected!("avx512dq")
}

/// Matrices and random values shared by the tests of the kernels (and of
/// `trig`).
#[cfg(test)]
pub(crate) mod test_matrices {
    use crate::system::{Matrix, Vector};

    /// The next entry in `[−1, 1)` of a xorshift sequence with state `x`.
    fn xorshift(x: &mut u64) -> f64 {
        *x ^= *x << 13;
        *x ^= *x >> 7;
        *x ^= *x << 17;
        (*x >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }

    /// A deterministic random matrix (xorshift), entries in `[−1, 1)`.
    pub(crate) fn random_matrix<const D: usize>(seed: u64) -> Matrix<D, D> {
        let mut x = seed | 1;
        Matrix::<D, D>::from_fn(|_, _| xorshift(&mut x))
    }

    /// `count` deterministic random values (the sequence of
    /// [`random_matrix`]), for sizes known at run time.
    pub(crate) fn random_values(seed: u64, count: usize) -> Vec<f64> {
        let mut x = seed | 1;
        (0..count).map(|_| xorshift(&mut x)).collect()
    }

    /// nalgebra's LU solve (dynamic sizes: its static LU needs typenum sizes).
    pub(crate) fn nalgebra_solve<const D: usize>(a: &Matrix<D, D>, b: &Vector<D>) -> Vector<D> {
        let a = nalgebra::DMatrix::from_column_slice(D, D, a.as_slice());
        let x = a.lu().solve(&nalgebra::DVector::from_column_slice(b.as_slice())).expect("nalgebra: singular");
        Vector::<D>::from_column_slice(x.as_slice())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::system::Vector;

    #[test]
    fn update_norm_propagates_nan_wherever_it_is() {
        let z = Vector::<3>::new(1.0, -3.0, 0.0);
        for i in 0..3 {
            let mut d = Vector::<3>::new(1e-3, 2e-3, 4e-3);
            d[i] = f64::NAN;
            assert!(scaled_update_norm(&d, &z).is_nan(), "NaN at {i} hidden");
        }
        let d = Vector::<3>::new(1e-3, -8e-3, 4e-3);
        assert_eq!(scaled_update_norm(&d, &z), 4e-3);
        let mut inf = d;
        inf[1] = f64::INFINITY;
        assert_eq!(scaled_update_norm(&inf, &z), f64::INFINITY);
    }

    #[test]
    fn largest_and_nan_sees_every_entry() {
        // Short (one pass) and long (four maxima and a remainder) lengths,
        // the largest entry and a NaN at every position.
        for n in [0usize, 1, 7, 8, 11, 16, 31] {
            let x: Vec<f64> = (0..n).map(|i| ((i * 7919) % 13) as f64 * 0.25).collect();
            let want = x.iter().fold(0.0f64, |m, &v| m.max(v));
            assert_eq!(largest_and_nan(n, |i| x[i]), (want, false), "n = {n}");
            for at in 0..n {
                let mut y = x.clone();
                y[at] = 1e300;
                assert_eq!(largest_and_nan(n, |i| y[i]), (1e300, false), "n = {n}, largest at {at}");
                y[at] = f64::INFINITY;
                assert_eq!(largest_and_nan(n, |i| y[i]).0, f64::INFINITY, "n = {n}, infinity at {at}");
                y[at] = f64::NAN;
                assert!(largest_and_nan(n, |i| y[i]).1, "n = {n}, NaN at {at} hidden");
            }
        }
    }

    #[test]
    fn weighted_norm_at_the_updated_iterate_is_the_scaled_norm_there() {
        let z = Vector::<5>::new(1.0, -3.0, 0.0, 1e-17, 7.25e3);
        let d = Vector::<5>::new(0.3, -2.0 / 3.0, 1e-9, 1e-17, 1.0 / 7.0);
        let mut weights = Vector::<5>::zeros();
        let norm = weigh_and_norm(&d, &z, &mut weights);
        let x = z - d;
        for i in 0..5 {
            assert_eq!(weights[i].to_bits(), (1.0 / (1.0 + x[i].abs())).to_bits());
        }
        assert_eq!(norm.to_bits(), weighted_update_norm(&d, &weights).to_bits());
        // A product with the reciprocal is the quotient to within one rounding.
        let quotient = scaled_update_norm(&d, &x);
        assert!((norm - quotient).abs() <= 2.0 * f64::EPSILON * quotient, "{norm} against {quotient}");
        for i in 0..5 {
            let mut bad = d;
            bad[i] = f64::NAN;
            assert!(weighted_update_norm(&bad, &weights).is_nan(), "NaN at {i} hidden");
            bad[i] = f64::INFINITY;
            assert!(!weighted_update_norm(&bad, &weights).is_finite(), "infinity at {i} hidden");
            let mut infinite_iterate = weights;
            infinite_iterate[i] = 0.0;
            assert!(weighted_update_norm(&bad, &infinite_iterate).is_nan(), "∞ · 0 at {i} hidden");
        }
    }
}
