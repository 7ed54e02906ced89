//! LU factorization with partial pivoting of `W` small matrices at once,
//! stored `[entry][lane]` (column-major entries): the operations of
//! `linalg::lu::factor_runtime` and `solve_runtime`, lane by lane in the
//! same order, so each lane's factors and solutions are bit for bit those
//! of the scalar kernels. Each lane pivots on its own; the row swaps are
//! the only per-lane loops, the eliminations run on whole rows of lanes.

/// One `f64` per lane.
type L<const W: usize> = [f64; W];

/// Factors the `n × n` matrices of the lanes marked in `live` in place
/// (`P A = L U`, with `1/u_kk` on the diagonal as `factor_runtime` stores
/// it); a lane whose matrix is singular by `factor_runtime`'s test is
/// cleared from `live`. Lanes not live compute values nobody reads.
#[inline(always)]
pub(super) fn factor<const W: usize>(
    lu: &mut [L<W>],
    n: usize,
    perm: &mut [[usize; W]],
    scale: &mut [L<W>],
    live: &mut [bool; W],
) {
    if n == 0 {
        return;
    }
    for k in 0..n {
        let mut s = [0.0f64; W];
        for i in 0..n {
            let x = lu[k * n + i];
            for w in 0..W {
                s[w] = s[w].max(x[w].abs());
            }
        }
        scale[k] = s;
    }
    for k in 0..n {
        // The pivot search, the singularity test and the row exchange of
        // every lane at once, as selects (branches per lane do not
        // vectorize): the first largest `|lu|` in column `k` from row `k`
        // on; a lane already dead keeps row `k` and exchanges nothing.
        let mut p = [k; W];
        let mut best: L<W> = lu[k * n + k].map(f64::abs);
        for r in k + 1..n {
            let x = lu[k * n + r];
            for w in 0..W {
                let better = x[w].abs() > best[w];
                p[w] = if better { r } else { p[w] };
                best[w] = if better { x[w].abs() } else { best[w] };
            }
        }
        for w in 0..W {
            let threshold = 64.0 * f64::EPSILON * scale[k][w];
            let singular = best[w].is_nan() || threshold.is_nan() || best[w] <= threshold;
            live[w] = live[w] && !singular;
            perm[k][w] = if live[w] { p[w] } else { k };
        }
        for r in k + 1..n {
            for j in 0..n {
                let (a, b) = (lu[j * n + k], lu[j * n + r]);
                let (mut x, mut y) = (a, b);
                for w in 0..W {
                    let trade = perm[k][w] == r;
                    x[w] = if trade { b[w] } else { a[w] };
                    y[w] = if trade { a[w] } else { b[w] };
                }
                (lu[j * n + k], lu[j * n + r]) = (x, y);
            }
        }
        let pivot = lu[k * n + k];
        let mut rpiv = [0.0; W];
        for w in 0..W {
            rpiv[w] = 1.0 / pivot[w];
        }
        lu[k * n + k] = rpiv;
        for i in k + 1..n {
            let mut x = lu[k * n + i];
            for w in 0..W {
                x[w] *= rpiv[w];
            }
            lu[k * n + i] = x;
        }
        for j in k + 1..n {
            let ukj = lu[j * n + k];
            for i in k + 1..n {
                let (mut x, l) = (lu[j * n + i], lu[k * n + i]);
                for w in 0..W {
                    // The scalar kernel skips a zero `u_kj`: the update is
                    // formed in every lane and a select keeps that lane's
                    // entry as it was (a conditional product is compiled
                    // to a branch per lane).
                    let updated = x[w] - l[w] * ukj[w];
                    x[w] = if ukj[w] != 0.0 { updated } else { x[w] };
                }
                lu[j * n + i] = x;
            }
        }
    }
}

/// Overwrites `b` with `A⁻¹ b` in every lane from the factors of [`factor`].
#[inline(always)]
pub(super) fn solve<const W: usize>(lu: &[L<W>], n: usize, perm: &[[usize; W]], b: &mut [L<W>]) {
    // Row `k` trades places with row `perm[k][w] ≥ k` in lane `w`: written
    // as a select per candidate row, which vectorizes, where a swap per
    // lane is a branch per lane.
    for k in 0..n {
        for r in k + 1..n {
            let (bk, br) = (b[k], b[r]);
            let (mut nk, mut nr) = (bk, br);
            for w in 0..W {
                let trade = perm[k][w] == r;
                nk[w] = if trade { br[w] } else { bk[w] };
                nr[w] = if trade { bk[w] } else { br[w] };
            }
            (b[k], b[r]) = (nk, nr);
        }
    }
    for j in 0..n {
        let bj = b[j];
        for i in j + 1..n {
            let (mut x, l) = (b[i], lu[j * n + i]);
            for w in 0..W {
                x[w] -= l[w] * bj[w];
            }
            b[i] = x;
        }
    }
    for j in (0..n).rev() {
        let (mut bj, r) = (b[j], lu[j * n + j]);
        for w in 0..W {
            bj[w] *= r[w];
        }
        b[j] = bj;
        for i in 0..j {
            let (mut x, u) = (b[i], lu[j * n + i]);
            for w in 0..W {
                x[w] -= u[w] * bj[w];
            }
            b[i] = x;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::{factor_runtime, solve_runtime};

    /// Every lane's factors and solution equal the scalar kernels' bit for
    /// bit, whatever pivots each lane takes; a singular lane is reported
    /// alone.
    #[test]
    fn lanes_factor_and_solve_like_the_scalar_kernels() {
        const W: usize = 4;
        let n = 5;
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        };
        let mut a = vec![[0.0; W]; n * n];
        for e in a.iter_mut() {
            *e = std::array::from_fn(|_| next());
        }
        // Lane 1 has zeros below the diagonal of column 0 (no swap there,
        // and zero multipliers); lane 3 is singular (two equal columns).
        for e in &mut a[1..n] {
            e[1] = 0.0;
        }
        for i in 0..n {
            a[2 * n + i][3] = a[4 * n + i][3];
        }
        let b: Vec<L<W>> = (0..n).map(|_| std::array::from_fn(|_| next())).collect();
        let (mut lu, mut perm, mut scale, mut live) = (a.clone(), vec![[0; W]; n], vec![[0.0; W]; n], [true; W]);
        factor(&mut lu, n, &mut perm, &mut scale, &mut live);
        assert_eq!(live, [true, true, true, false]);
        let mut x = b.clone();
        solve(&lu, n, &perm, &mut x);
        for w in 0..3 {
            let mut s: Vec<f64> = a.iter().map(|e| e[w]).collect();
            let (mut p, mut sc) = (vec![0; n], vec![0.0; n]);
            factor_runtime(&mut s, n, &mut p, &mut sc).unwrap();
            let mut y: Vec<f64> = b.iter().map(|e| e[w]).collect();
            solve_runtime(&s, n, &p, &mut y);
            for e in 0..n * n {
                assert_eq!(lu[e][w].to_bits(), s[e].to_bits(), "lane {w} entry {e}");
            }
            for i in 0..n {
                assert_eq!(x[i][w].to_bits(), y[i].to_bits(), "lane {w} solution {i}");
                assert_eq!(perm[i][w], p[i], "lane {w} pivot {i}");
            }
        }
        let mut s: Vec<f64> = a.iter().map(|e| e[3]).collect();
        assert!(factor_runtime(&mut s, n, &mut [0; 5], &mut [0.0; 5]).is_err());
    }
}
