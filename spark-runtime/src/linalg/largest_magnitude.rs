//! The largest magnitude of a vector, each entry optionally weighted, and
//! whether any entry is NaN: the residual's and the update's norms that
//! every Newton iteration takes.
//!
//! On x86-64 two entries at a time with SSE2, which every x86-64 CPU has:
//! `maxpd` keeps the larger magnitude and `cmpunordpd` flags a NaN, a few
//! instructions per pair where the scalar form ([`super::largest_and_nan`])
//! takes a comparison, a select and a NaN test per entry. A maximum is
//! exact, so both forms return the same value.

/// `(max_i |x_i|·w_i, whether any |x_i|·w_i is NaN)` for `w` of at least the
/// length of `x` (`w_i = 1` without weights); 0 for an empty `x`. A NaN
/// never counts as the largest: with the flag raised, the value is
/// meaningless (the callers then report a NaN). An infinity is the largest.
#[inline(always)]
pub(crate) fn largest_magnitude(x: &[f64], w: Option<&[f64]>) -> (f64, bool) {
    let w = w.map(|w| &w[..x.len()]);
    #[cfg(target_arch = "x86_64")]
    {
        sse2(x, w)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        super::largest_and_nan(x.len(), |i| match w {
            Some(w) => x[i].abs() * w[i],
            None => x[i].abs(),
        })
    }
}

/// [`largest_magnitude`] with SSE2: two running maxima of two lanes each
/// (four entries per round, so that no single `maxpd` chain carries the
/// whole vector), then a pair and a last entry.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn sse2(x: &[f64], w: Option<&[f64]>) -> (f64, bool) {
    use std::arch::x86_64::*;
    let n = x.len();
    // SAFETY: SSE2 is part of the x86-64 baseline. Every load reads entries
    // below `n` of `x` and of `w`, which is `n` long (`largest_magnitude`).
    unsafe {
        let abs = _mm_castsi128_pd(_mm_set1_epi64x(i64::MAX));
        let pair = |i: usize| {
            let v = _mm_and_pd(_mm_loadu_pd(x.as_ptr().add(i)), abs);
            match w {
                Some(w) => _mm_mul_pd(v, _mm_loadu_pd(w.as_ptr().add(i))),
                None => v,
            }
        };
        let (mut a0, mut a1) = (_mm_setzero_pd(), _mm_setzero_pd());
        let (mut n0, mut n1) = (_mm_setzero_pd(), _mm_setzero_pd());
        let mut i = 0;
        while i + 4 <= n {
            let (v0, v1) = (pair(i), pair(i + 2));
            n0 = _mm_or_pd(n0, _mm_cmpunord_pd(v0, v0));
            n1 = _mm_or_pd(n1, _mm_cmpunord_pd(v1, v1));
            a0 = _mm_max_pd(a0, v0);
            a1 = _mm_max_pd(a1, v1);
            i += 4;
        }
        if i + 2 <= n {
            let v = pair(i);
            n0 = _mm_or_pd(n0, _mm_cmpunord_pd(v, v));
            a0 = _mm_max_pd(a0, v);
            i += 2;
        }
        if i < n {
            // The last entry in the low lane, zero in the high one.
            let mut v = _mm_and_pd(_mm_load_sd(x.as_ptr().add(i)), abs);
            if let Some(w) = w {
                v = _mm_mul_pd(v, _mm_load_sd(w.as_ptr().add(i)));
            }
            n1 = _mm_or_pd(n1, _mm_cmpunord_pd(v, v));
            a1 = _mm_max_pd(a1, v);
        }
        let a = _mm_max_pd(a0, a1);
        let largest = _mm_max_sd(a, _mm_unpackhi_pd(a, a));
        (_mm_cvtsd_f64(largest), _mm_movemask_pd(_mm_or_pd(n0, n1)) != 0)
    }
}

#[cfg(test)]
mod tests {
    use super::largest_magnitude;
    use crate::linalg::largest_and_nan;
    use crate::linalg::test_matrices::random_values;

    /// The same value as the scalar form at every length, weighted or not,
    /// whichever entry is the largest, an infinity included; a NaN at any
    /// place raises the flag.
    #[test]
    fn largest_magnitude_matches_the_scalar_form_and_sees_every_nan() {
        for n in 0..=41 {
            let x: Vec<f64> = random_values(3 + n as u64, n).iter().map(|r| (r - 0.5) * 1e3).collect();
            let w: Vec<f64> = random_values(101 + n as u64, n).iter().map(|r| 1.0 / (1.0 + r)).collect();
            let scalar =
                |x: &[f64], w: Option<&[f64]>| largest_and_nan(x.len(), |i| x[i].abs() * w.map_or(1.0, |w| w[i]));
            for weights in [None, Some(&w[..])] {
                assert_eq!(largest_magnitude(&x, weights), scalar(&x, weights), "n = {n}");
                for at in 0..n {
                    let mut y = x.clone();
                    y[at] = -1e300;
                    assert_eq!(largest_magnitude(&y, weights), scalar(&y, weights), "n = {n}, largest at {at}");
                    y[at] = f64::NEG_INFINITY;
                    assert_eq!(largest_magnitude(&y, weights), (f64::INFINITY, false), "n = {n}, infinity at {at}");
                    y[at] = f64::NAN;
                    assert!(largest_magnitude(&y, weights).1, "n = {n}, NaN at {at} hidden");
                }
            }
        }
        assert_eq!(largest_magnitude(&[], None), (0.0, false));
    }
}
