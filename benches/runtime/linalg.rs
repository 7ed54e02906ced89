//! The Newton linear algebra of one step, a baseline kernel vs the
//! library's, side by side.
//!
//! `old` is the baseline: the plain scalar right-looking LU on column-major
//! slices with block pivot ranges and physical row swaps, the kernel the
//! library's `NewtonMatrix` improves on. It stays here as a copy of its own
//! (not the library's `linalg::lu`, which differs: padded storage for
//! small D, reciprocal diagonals) so that the comparison keeps a fixed
//! reference. `new` is [`NewtonMatrix::factor`] +
//! [`NewtonMatrix::solve_in_place`]. Matrices are real assembled Newton
//! matrices of the hand-written systems (`Stepper::newton_matrix` at the
//! benchmark's start state and step size), and for D = 101 and 197 (the
//! McLachlan–Perlmutter scaling study's n = 33 and 65, Gauss s = 2)
//! synthetic matrices with the same block pattern.
//!
//! `cargo bench -p spark-benches --bench linalg`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use spark_benches::paper::Starts;
use spark_runtime::fixtures::paper::{MobileRobot, MpParticles, Particle, Skate};
use spark_runtime::NewtonMatrix;
use spark_runtime::{Method, NonholonomicSystem, State, Stepper, Tableau, Vector};
use std::time::Duration;

/// The baseline scalar kernel, free-standing.
mod old {
    /// Factors in place (`P A = L U`), pivoting column `k` among rows up to
    /// the first of `block_ends` above `k`; `Err(k)` on a pivot below
    /// `64 ε · scale[k]`. `FMA` fuses the update's multiply-subtract.
    #[inline(always)]
    fn factor_body<const D: usize, const FMA: bool>(
        lu: &mut [f64],
        perm: &mut [usize],
        scale: &[f64; D],
        block_ends: &[usize],
    ) -> Result<(), usize> {
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
            if best.is_nan() || best <= 64.0 * f64::EPSILON * scale[k] {
                return Err(k);
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

    /// Overwrites `b` with `A⁻¹ b` from the factors of [`factor_body`];
    /// `FMA` fuses the multiply-subtracts.
    #[inline(always)]
    fn solve_body<const D: usize, const FMA: bool>(lu: &[f64], perm: &[usize], b: &mut [f64]) {
        let lu = &lu[..D * D];
        let b = &mut b[..D];
        for (k, &p) in perm[..D].iter().enumerate() {
            if p != k {
                b.swap(k, p);
            }
        }
        for j in 0..D {
            let bj = b[j];
            let col = &lu[j * D + j + 1..(j + 1) * D];
            for (x, l) in b[j + 1..].iter_mut().zip(col) {
                *x = if FMA { (-l).mul_add(bj, *x) } else { *x - l * bj };
            }
        }
        for j in (0..D).rev() {
            b[j] /= lu[j * D + j];
            let bj = b[j];
            let col = &lu[j * D..j * D + j];
            for (x, u) in b[..j].iter_mut().zip(col) {
                *x = if FMA { (-u).mul_add(bj, *x) } else { *x - u * bj };
            }
        }
    }

    #[inline]
    pub fn factor_in_place<const D: usize>(
        lu: &mut [f64],
        perm: &mut [usize],
        scale: &[f64; D],
        block_ends: &[usize],
    ) -> Result<(), usize> {
        factor_body::<D, false>(lu, perm, scale, block_ends)
    }

    #[inline]
    pub fn solve_in_place<const D: usize>(lu: &[f64], perm: &[usize], b: &mut [f64]) {
        solve_body::<D, false>(lu, perm, b)
    }

    #[inline]
    pub fn column_scales<const D: usize>(a: &[f64]) -> [f64; D] {
        let mut s = [0.0; D];
        for (sk, col) in s.iter_mut().zip(a[..D * D].chunks_exact(D)) {
            *sk = col.iter().fold(0.0, |m: f64, x| m.max(x.abs()));
        }
        s
    }

    /// The baseline kernel with fused multiply-adds, compiled for AVX2+FMA (experiment).
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn factor_avx2<const D: usize>(
        lu: &mut [f64],
        perm: &mut [usize],
        scale: &[f64; D],
        block_ends: &[usize],
    ) -> Result<(), usize> {
        factor_body::<D, true>(lu, perm, scale, block_ends)
    }

    /// The baseline solve with FMA, compiled for AVX2+FMA (experiment).
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn solve_avx2<const D: usize>(lu: &[f64], perm: &[usize], b: &mut [f64]) {
        solve_body::<D, true>(lu, perm, b)
    }

    /// The baseline `NewtonMatrix::factor`/`solve_in_place`: the structured
    /// (block-reordered) factorization first, the whole matrix if that one
    /// is singular.
    pub struct OldNewton<const D: usize> {
        pub jacobian: Box<[f64]>,
        lu: Box<[f64]>,
        perm: Box<[usize]>,
        structured: bool,
        sn: usize,
        n: usize,
        sm: usize,
    }

    impl<const D: usize> OldNewton<D> {
        pub fn new(jacobian: &[f64], n: usize, m: usize, s: usize) -> Self {
            OldNewton {
                jacobian: jacobian.into(),
                lu: vec![0.0; D * D].into_boxed_slice(),
                perm: vec![0; D].into_boxed_slice(),
                structured: false,
                sn: s * n,
                n,
                sm: s * m,
            }
        }

        /// `factor` with the factorization kernel `kernel`.
        #[inline(always)]
        fn factor_with(
            &mut self,
            kernel: impl Fn(&mut [f64], &mut [usize], &[f64; D], &[usize]) -> Result<(), usize>,
        ) -> Result<(), usize> {
            let (sn, sm, n) = (self.sn, self.sm, self.n);
            self.lu[..sn * D].copy_from_slice(&self.jacobian[..sn * D]);
            self.lu[sn * D..(sn + n) * D].copy_from_slice(&self.jacobian[(sn + sm) * D..]);
            self.lu[(sn + n) * D..].copy_from_slice(&self.jacobian[sn * D..(sn + sm) * D]);
            let scale = column_scales::<D>(&self.lu);
            if kernel(&mut self.lu, &mut self.perm, &scale, &[sn, sn + n, D]).is_ok() {
                self.structured = true;
                return Ok(());
            }
            self.structured = false;
            self.lu.copy_from_slice(&self.jacobian);
            let scale = column_scales::<D>(&self.lu);
            kernel(&mut self.lu, &mut self.perm, &scale, &[D])
        }

        /// `solve_in_place` with the solve kernel `kernel`.
        #[inline(always)]
        fn solve_with(&self, b: &mut [f64], kernel: impl Fn(&[f64], &[usize], &mut [f64])) {
            kernel(&self.lu, &self.perm, b);
            if self.structured {
                b[self.sn..].rotate_left(self.n);
            }
        }

        pub fn factor(&mut self) -> Result<(), usize> {
            self.factor_with(factor_in_place::<D>)
        }

        /// `factor` with the kernel compiled for AVX2.
        pub fn factor_avx2(&mut self) -> Result<(), usize> {
            // SAFETY: benchmark machine has AVX2 (checked in `compare`).
            self.factor_with(|lu, perm, scale, ends| unsafe { factor_avx2::<D>(lu, perm, scale, ends) })
        }

        /// `solve_in_place` with the kernel compiled for AVX2.
        pub fn solve_avx2(&self, b: &mut [f64]) {
            // SAFETY: as above.
            self.solve_with(b, |lu, perm, b| unsafe { solve_avx2::<D>(lu, perm, b) })
        }

        pub fn solve_in_place(&self, b: &mut [f64]) {
            self.solve_with(b, solve_in_place::<D>)
        }
    }
}

/// Old vs new, factor + solve and solve alone, on one matrix.
fn compare<const N: usize, const M: usize, const S: usize, const D: usize>(
    c: &mut Criterion,
    label: &str,
    nm: &NewtonMatrix<N, M, S, D>,
    g: &Vector<D>,
) {
    let mut new = nm.clone();
    let mut old = old::OldNewton::<D>::new(&nm.matrix().iter().copied().collect::<Vec<_>>(), N, M, S);
    // Both must solve the system before their times mean anything.
    let (mut xn, mut xo) = (*g, *g);
    new.factor().expect("new kernel: singular");
    new.solve_in_place(&mut xn);
    old.factor().expect("old kernel: singular");
    old.solve_in_place(xo.as_mut_slice());
    let r = (nm.matrix() * xn - g).amax() / g.amax().max(1.0);
    assert!((xn - xo).amax() <= 1e-10 * xo.amax().max(1.0) && r < 1e-10, "{label}: kernels disagree");

    // The timed cases: (what, kernel, needs AVX2, one run on a copy of g).
    type Run<const N: usize, const M: usize, const S: usize, const D: usize> =
        fn(&mut old::OldNewton<D>, &mut NewtonMatrix<N, M, S, D>, &mut Vector<D>);
    let cases: [(&str, &str, bool, Run<N, M, S, D>); 5] = [
        ("factor+solve", "old", false, |old, _, x| {
            old.factor().unwrap();
            old.solve_in_place(x.as_mut_slice());
        }),
        ("factor+solve", "old-fma", true, |old, _, x| {
            old.factor_avx2().unwrap();
            old.solve_avx2(x.as_mut_slice());
        }),
        ("factor+solve", "new", false, |_, new, x| {
            new.factor().unwrap();
            new.solve_in_place(x);
        }),
        ("solve", "old", false, |old, _, x| old.solve_in_place(x.as_mut_slice())),
        ("solve", "new", false, |_, new, x| new.solve_in_place(x)),
    ];
    let mut once = |run: Run<N, M, S, D>| {
        let mut x = *g;
        run(&mut old, &mut new, &mut x);
        x[0]
    };

    if std::env::var_os("LINALG_MIN").is_some() {
        // Quick robust figures on a loaded machine: the fastest of many short
        // batches (preemptions only ever add time).
        let mut fs = |run: Run<N, M, S, D>| {
            let reps = (20_000 / D.pow(2)).max(4);
            let mut best = f64::INFINITY;
            for _ in 0..300 {
                let t = std::time::Instant::now();
                for _ in 0..reps {
                    std::hint::black_box(once(run));
                }
                best = best.min(t.elapsed().as_secs_f64() * 1e9 / reps as f64);
            }
            best
        };
        let [o, of, n, os, ns] = cases.map(|(_, _, _, run)| fs(run));
        println!(
            "D={D:3} {label:32} f+s old {o:8.0} old-fma {of:8.0} new {n:8.0} ({:.2}x) | solve old {os:7.0} new {ns:7.0} ({:.2}x)",
            o / n,
            os / ns
        );
        return;
    }
    let mut group = c.benchmark_group(format!("linalg D={D:03} {label}"));
    group.warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(2));
    for (what, kernel, avx2, run) in cases {
        if !avx2 || std::arch::is_x86_feature_detected!("avx2") {
            group.bench_function(BenchmarkId::new(what, kernel), |b| b.iter(|| once(run)));
        }
    }
    group.finish();
}

fn real<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    c: &mut Criterion,
    name: &str,
    sys: Sys,
    method: Method,
    start: State<N>,
    h: f64,
) where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap());
    let (nm, g) = st.newton_matrix(&start, h);
    let nm = nm.clone();
    compare(c, &format!("{name} {method} s={S}"), &nm, &g);
}

/// A Gauss s = 2 Newton matrix with the SPARK block pattern for `n`
/// McLachlan–Perlmutter-like coordinates and one constraint: stage blocks
/// `δ_il I + h² c_il F` (F symmetric, small), `a_il Kᵀ` multiplier columns,
/// a `p₁` block row with `M(Q₁) = I` in the `v₁` columns, one condition row
/// and the end constraint.
fn synthetic<const N: usize, const D: usize>(c: &mut Criterion) {
    const S: usize = 2;
    let h = 0.05;
    let r3 = 3f64.sqrt();
    let a = [[0.25, 0.25 - r3 / 6.0], [0.25 + r3 / 6.0, 0.25]];
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let f: Vec<f64> = (0..N * N).map(|_| next()).collect();
    let k: Vec<f64> = (0..N).map(|i| if i == 0 { 1.0 } else { next() }).collect();
    let mut nm = NewtonMatrix::<N, 1, S, D>::new();
    {
        let mut j = nm.matrix_mut();
        let (mu, v1, cond) = (S * N, S * N + S, S * N + N);
        for i in 0..=S {
            let arow = if i < S { a[i] } else { [0.5, 0.5] };
            for l in 0..S {
                for r in 0..N {
                    for col in 0..N {
                        let fr = f[r * N + col] + f[col * N + r];
                        let diag = if i == l && r == col { 1.0 } else { 0.0 };
                        j[(i * N + r, l * N + col)] = diag - h * h * arow[l] * 0.5 * fr;
                    }
                    j[(i * N + r, mu + l)] = arow[l] * k[r];
                }
            }
        }
        for r in 0..N {
            j[(S * N + r, v1 + r)] = 1.0;
        }
        for col in 0..N {
            j[(cond, col)] = k[col];
            j[(cond, N + col)] = -k[col];
            j[(D - 1, col)] = h * 0.5 * k[col] * 0.1;
            j[(D - 1, N + col)] = h * 0.5 * k[col] * 0.1;
            j[(D - 1, v1 + col)] = k[col];
        }
    }
    let g = Vector::<D>::from_fn(|i, _| 1.0 + (i % 7) as f64 * 0.1);
    compare(c, &format!("synthetic MP n={N} Gauss s=2"), &nm, &g);
}

fn benches(c: &mut Criterion) {
    let Starts { particle: p0, skate: s0, robot: r0, .. } = Starts::paper();
    // The McLachlan–Perlmutter particles start in motion here, not at rest
    // as in the step benches.
    let m0 = State::new(
        0.0,
        Vector::<7>::from_row_slice(&[1.0, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]),
        Vector::<7>::from_row_slice(&[0.3, -0.2, 0.1, 0.0, 0.2, -0.1, 0.1]),
    );
    real::<_, 3, 1, 2, 11>(c, "particle", Particle, Method::Gauss, p0, 0.2);
    real::<_, 3, 1, 3, 15>(c, "skate", Skate::default(), Method::LobattoIIIAB, s0, 0.1);
    real::<_, 4, 2, 2, 16>(c, "robot", MobileRobot::default(), Method::Gauss, r0, 0.2);
    real::<_, 3, 1, 4, 19>(c, "skate", Skate::default(), Method::Gauss, s0, 0.1);
    real::<_, 4, 2, 3, 22>(c, "robot", MobileRobot::default(), Method::LobattoIIIAB, r0, 0.2);
    real::<_, 7, 1, 2, 23>(c, "mp7", MpParticles, Method::Gauss, m0, 0.05);
    real::<_, 4, 2, 4, 28>(c, "robot", MobileRobot::default(), Method::Gauss, r0, 0.2);
    real::<_, 7, 1, 3, 31>(c, "mp7", MpParticles, Method::LobattoIIIAB, m0, 0.05);
    real::<_, 7, 1, 4, 39>(c, "mp7", MpParticles, Method::Gauss, m0, 0.05);
    real::<_, 7, 1, 5, 47>(c, "mp7", MpParticles, Method::Gauss, m0, 0.05);
    synthetic::<33, 101>(c);
    synthetic::<65, 197>(c);
}

criterion_group!(linalg, benches);
criterion_main!(linalg);
