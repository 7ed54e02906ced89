//! The structure-of-arrays kernel of a lane group: the steps of up to `W`
//! members in one Newton iteration, every array laid out `[entry][lane]`
//! so that one instruction advances every lane (four `f64` per AVX2
//! register; the kernel is compiled for AVX2 where the CPU has it).
//!
//! # What it computes
//! The kernel repeats, operation for operation and in the same order, the
//! path of [`Stepper::step`](crate::Stepper::step) that an ensemble of a
//! system with a constant mass matrix takes at almost every step: the
//! starting guess extrapolated from the latest solutions, simplified Newton
//! on the stage-decoupled matrix refreshed at the step's first iterate with
//! the constraint Jacobians alone (`linalg::decoupled`, the lean refresh),
//! the residual of eq. (6.1), the stopping rule of
//! [`Contraction`](crate::step::Contraction), the compensated `q₁`, the
//! energy guard. So a lane's states are bit for bit those of its member
//! stepped alone. Only the system's own functions run lane by lane.
//!
//! Where the stepper would decide something the kernel does not repeat — a
//! contraction too slow for the stage-decoupled matrix, a singular matrix,
//! a non-finite residual, the iteration limit, an energy drift — the
//! kernel hands the lane's step back ([`Outcome::HandBack`]): its
//! [`Stepper`](crate::Stepper) computes that step from the same
//! continuation (`step::lane_handover`), and so reaches the same decision.

// Stage and lane loops index several parallel arrays with one index.
#![allow(clippy::needless_range_loop)]

use super::lane_lu;
use crate::error::HISTORY_CAPACITY;
use crate::linalg::{column_scales, factor_in_place, solve_in_place};
use crate::step::{
    check_energy, energy_is_invariant, too_slow, Contraction, EnergyAnchor, EnergyCheck, LaneContinuation,
    NewtonOptions, State, EXTRAPOLATION, PAST,
};
use crate::system::{Matrix, NonholonomicSystem, StageJacobians, StageValues, Vector};
use crate::tableau::{ConditionRows, Tableau};

/// One `f64` per lane.
type L<const W: usize> = [f64; W];

/// `n` zeroed lane values on the heap.
fn lanes<const W: usize>(n: usize) -> Box<[L<W>]> {
    vec![[0.0; W]; n].into_boxed_slice()
}

/// `K` zeroed lane values on the heap, as an array (built on the heap: no
/// `K·W` value goes on the stack).
fn fixed<const W: usize, const K: usize>() -> Box<[L<W>; K]> {
    match lanes::<W>(K).try_into() {
        Ok(a) => a,
        Err(_) => unreachable!("a slice of K entries converts to [_; K]"),
    }
}

/// How one lane's step ended in the kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Outcome {
    /// The kernel does not hold the lane.
    Idle,
    /// Converged and committed, with its Newton iterations.
    Stepped(usize),
    /// Handed back: the lane's stepper computes this step (see the module docs).
    HandBack,
}

/// The solve with the constant mass matrix, shared by every lane and block.
#[derive(Clone, Debug)]
enum MassSolve {
    /// Reciprocals of a diagonal mass matrix.
    Diagonal(Box<[f64]>),
    /// LU factors of a full one.
    Lu { lu: Box<[f64]>, perm: Box<[usize]> },
}

/// The kernel's storage for `W` lanes of a system with `N` coordinates and
/// `M` constraints stepped with `S` stages (`D = S(N+M)+N` unknowns); all of
/// it allocated once by [`Kernel::new`].
#[derive(Clone, Debug)]
pub(super) struct Kernel<const N: usize, const M: usize, const S: usize, const D: usize, const W: usize> {
    avx2: bool,
    mass: MassSolve,
    h: f64,
    /// Which lanes the kernel holds.
    held: [bool; W],
    /// The state where each lane's latest step ended, and its carry.
    q: Box<[L<W>; N]>,
    v: Box<[L<W>; N]>,
    carry: Box<[L<W>; N]>,
    anchor: [Option<EnergyAnchor<N>>; W],
    /// Ring of the latest solutions: slot `k` at `k·D`; lane `w`'s most
    /// recent is slot `head[w]`.
    past: Box<[L<W>]>,
    head: [usize; W],
    depth: [usize; W],
    /// The unknowns, the residual (then the update) and the solve's scratch.
    z: Box<[L<W>; D]>,
    g: Box<[L<W>; D]>,
    y: Box<[L<W>]>,
    p0: Box<[L<W>; N]>,
    /// Positions of the evaluation points: stages `0..S`, the end `S`, the
    /// midpoint `S + 1` (`N` each).
    points: Box<[[L<W>; N]]>,
    /// Stage values at the points.
    momentum: Box<[[L<W>; N]]>,
    force: Box<[[L<W>; N]]>,
    constraint_force: Box<[[L<W>; N]]>,
    constraint: Box<[[L<W>; M]]>,
    /// `K = k_v` and `k_q` at the points (`M × N` column-major each).
    constraint_v: Box<[L<W>]>,
    constraint_q: Box<[L<W>]>,
    /// `X[i][l] = W⁻¹ ã_il K_lᵀ` and the constraint rows' blocks `C[r][i]`,
    /// laid out as in `linalg::decoupled`.
    x: Box<[[[L<W>; N]; M]]>,
    c: Box<[[[L<W>; M]; N]]>,
    c_nonzero: Box<[bool]>,
    /// The lanes' Schur complements `Σ` (`SM × SM`) and their factors.
    schur: Box<[L<W>]>,
    schur_perm: Box<[[usize; W]]>,
    schur_scale: Box<[L<W>]>,
    /// Scratch for `K_lᵀ` (`N × M`).
    kt: Box<[L<W>]>,
}

impl<const N: usize, const M: usize, const S: usize, const D: usize, const W: usize> Kernel<N, M, S, D, W> {
    const SM: usize = S * M;
    const POINTS: usize = S + 2;

    /// A kernel for steps of size `h` of `system`, whose constant mass
    /// matrix is evaluated at `at`; `None` when that matrix is singular
    /// (the steppers then report it themselves).
    pub(super) fn new<Sys: NonholonomicSystem<N, M>>(system: &Sys, at: &State<N>, h: f64) -> Option<Self> {
        let mut vals = StageValues::zeros();
        let mut jac = StageJacobians::<N, M>::boxed_zeros();
        system.stage_jacobians_into(at.t, &at.q, &at.v, &Vector::zeros(), &mut vals, &mut jac);
        let mass = jac.mass.as_slice();
        // The same tests and arithmetic as the stage-decoupled matrix's
        // shared mass block (`DecoupledMatrix::factor_shared`).
        let mass = if (0..N * N).all(|k| k % (N + 1) == 0 || mass[k] == 0.0) {
            let mut r = vec![0.0; N].into_boxed_slice();
            for (k, rk) in r.iter_mut().enumerate() {
                let d = mass[k * (N + 1)];
                if d == 0.0 || !d.is_finite() {
                    return None;
                }
                *rk = 1.0 / d;
            }
            MassSolve::Diagonal(r)
        } else {
            let mut lu: Box<[f64]> = mass.into();
            let mut perm = vec![0; N].into_boxed_slice();
            let scale = column_scales::<N>(&lu);
            factor_in_place::<N>(&mut lu, &mut perm, &scale, &[N]).ok()?;
            MassSolve::Lu { lu, perm }
        };
        let (p, sm) = (Self::POINTS, Self::SM);
        Some(Kernel {
            #[cfg(target_arch = "x86_64")]
            avx2: crate::linalg::avx2_fma_available(),
            #[cfg(not(target_arch = "x86_64"))]
            avx2: false,
            mass,
            h,
            held: [false; W],
            q: fixed(),
            v: fixed(),
            carry: fixed(),
            anchor: [None; W],
            past: lanes(PAST * D),
            head: [0; W],
            depth: [0; W],
            z: fixed(),
            g: fixed(),
            y: lanes(D),
            p0: fixed(),
            points: vec![[[0.0; W]; N]; p].into_boxed_slice(),
            momentum: vec![[[0.0; W]; N]; p].into_boxed_slice(),
            force: vec![[[0.0; W]; N]; p].into_boxed_slice(),
            constraint_force: vec![[[0.0; W]; N]; p].into_boxed_slice(),
            constraint: vec![[[0.0; W]; M]; p].into_boxed_slice(),
            constraint_v: lanes(p * M * N),
            constraint_q: lanes(p * M * N),
            x: vec![[[[0.0; W]; N]; M]; (S + 1) * S].into_boxed_slice(),
            c: vec![[[[0.0; W]; M]; N]; S * (S + 1)].into_boxed_slice(),
            c_nonzero: vec![false; S * (S + 1)].into_boxed_slice(),
            schur: lanes(sm * sm),
            schur_perm: vec![[0; W]; sm].into_boxed_slice(),
            schur_scale: lanes(sm),
            kt: lanes(N * M),
        })
    }

    /// Whether the kernel holds lane `w`.
    pub(super) fn holds(&self, w: usize) -> bool {
        self.held[w]
    }

    /// Takes lane `w` over from the continuation of its stepper.
    pub(super) fn take(&mut self, w: usize, c: &LaneContinuation<N, D>) {
        for n in 0..N {
            self.q[n][w] = c.end.q[n];
            self.v[n][w] = c.end.v[n];
            self.carry[n][w] = c.carry[n];
        }
        for k in 0..PAST {
            for d in 0..D {
                self.past[k * D + d][w] = c.past[k][d];
            }
        }
        self.anchor[w] = c.anchor;
        (self.head[w], self.depth[w], self.held[w]) = (0, c.depth, true);
    }

    /// The state of lane `w` at time `t`.
    pub(super) fn state(&self, w: usize, t: f64) -> State<N> {
        State::new(t, Vector::from_fn(|n, _| self.q[n][w]), Vector::from_fn(|n, _| self.v[n][w]))
    }

    /// Gives lane `w` back: the continuation of its latest step, which
    /// ended at time `t`.
    pub(super) fn give(&mut self, w: usize, t: f64) -> LaneContinuation<N, D> {
        self.held[w] = false;
        let past = std::array::from_fn(|k| {
            let slot = (self.head[w] + k) % PAST;
            Vector::from_fn(|d, _| self.past[slot * D + d][w])
        });
        LaneContinuation {
            end: self.state(w, t),
            h: self.h,
            carry: Vector::from_fn(|n, _| self.carry[n][w]),
            anchor: self.anchor[w],
            past,
            depth: self.depth[w],
        }
    }

    /// One step of size `h` of every held lane from time `t`, the lanes'
    /// steps ending at the pinned time `t_next`. A lane handed back keeps
    /// its state, and the kernel still holds it (take it with [`Self::give`]).
    pub(super) fn step<Sys: NonholonomicSystem<N, M>>(
        &mut self,
        sys: &Sys,
        tab: &Tableau<S>,
        opts: &NewtonOptions,
        t: f64,
        t_next: f64,
    ) -> [Outcome; W] {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only where the CPU has AVX2 and FMA.
            return unsafe { self.step_avx2(sys, tab, opts, t, t_next) };
        }
        self.step_body(sys, tab, opts, t, t_next)
    }

    /// [`Self::step`] compiled for AVX2.
    ///
    /// # Safety
    /// AVX2 and FMA must be available.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn step_avx2<Sys: NonholonomicSystem<N, M>>(
        &mut self,
        sys: &Sys,
        tab: &Tableau<S>,
        opts: &NewtonOptions,
        t: f64,
        t_next: f64,
    ) -> [Outcome; W] {
        self.step_body(sys, tab, opts, t, t_next)
    }

    #[inline(always)]
    fn step_body<Sys: NonholonomicSystem<N, M>>(
        &mut self,
        sys: &Sys,
        tab: &Tableau<S>,
        opts: &NewtonOptions,
        t: f64,
        t_next: f64,
    ) -> [Outcome; W] {
        let h = self.h;
        let mut out = [Outcome::Idle; W];
        let mut iterating = self.held;
        if !(t + h).is_finite() || t + h == t {
            // The stepper refuses such a step; let it say so.
            return self.held.map(|held| if held { Outcome::HandBack } else { Outcome::Idle });
        }
        self.starting_guess(opts);
        for w in (0..W).filter(|&w| self.held[w]) {
            let p0 = sys.momentum(t, &self.lane_vector(&self.q[..], 0, w), &self.lane_vector(&self.v[..], 0, w));
            for n in 0..N {
                self.p0[n][w] = p0[n];
            }
        }
        let max_iter = opts.max_iterations.clamp(1, HISTORY_CAPACITY);
        let mut monitor = [Contraction::FRESH; W];
        let mut prev_update = [f64::NAN; W];
        for k in 0..max_iter {
            self.stage_points(tab);
            self.evaluate(sys, tab, t, &iterating, k == 0);
            self.residual(tab);
            let mut finite = [true; W];
            for d in 0..D {
                let g = self.g[d];
                for w in 0..W {
                    finite[w] &= g[w].is_finite();
                }
            }
            for w in 0..W {
                if iterating[w] && !finite[w] {
                    (iterating[w], out[w]) = (false, Outcome::HandBack);
                }
            }
            if k == 0 {
                self.factor(tab, &mut iterating, &mut out);
            }
            self.solve();
            let update = self.apply_update(&iterating);
            for w in 0..W {
                if !iterating[w] {
                    continue;
                }
                let update = update[w];
                let rate = update / prev_update[w];
                monitor[w].record(update);
                let converged = monitor[w].converged(update, opts.tolerance);
                if k > 0 {
                    let remaining = (max_iter - 1 - k) as i32;
                    let slow = too_slow(&monitor[w], true, update, rate, remaining, opts.tolerance);
                    if slow && !converged && update > opts.stagnation_level {
                        (iterating[w], out[w]) = (false, Outcome::HandBack);
                        continue;
                    }
                }
                let stop = if !update.is_finite() {
                    Some(Outcome::HandBack)
                } else if converged {
                    Some(Outcome::Stepped(k + 1))
                } else if k > 0 && rate >= 1.0 {
                    Some(if update <= opts.stagnation_level { Outcome::Stepped(k + 1) } else { Outcome::HandBack })
                } else {
                    None
                };
                match stop {
                    Some(o) => (iterating[w], out[w]) = (false, o),
                    None => prev_update[w] = update,
                }
            }
            if !iterating.iter().any(|&i| i) {
                break;
            }
        }
        for w in 0..W {
            if iterating[w] {
                // The iteration limit: the stepper reports it.
                out[w] = Outcome::HandBack;
            }
        }
        self.commit(sys, tab, opts, t, t_next, &mut out);
        out
    }

    /// Lane `w` of the `N` values at `at` of `x`.
    #[inline(always)]
    fn lane_vector<const K: usize>(&self, x: &[L<W>], at: usize, w: usize) -> Vector<K> {
        Vector::from_fn(|n, _| x[at + n][w])
    }

    /// The extrapolated starting guess of every held lane
    /// (`Stepper::starting_guess` on a continuing step of equal size).
    #[inline(always)]
    fn starting_guess(&mut self, opts: &NewtonOptions) {
        let degree = |w: usize| (self.depth[w] - 1).min(opts.extrapolation_degree.clamp(1, PAST - 1));
        let first = (0..W).find(|&w| self.held[w]);
        let uniform = first
            .is_some_and(|f| (0..W).all(|w| !self.held[w] || (degree(w) == degree(f) && self.head[w] == self.head[f])));
        if let (Some(f), true) = (first, uniform) {
            // Every held lane extrapolates alike: whole rows at once (the
            // lanes not held compute garbage nobody reads).
            let (degree, head) = (degree(f), self.head[f]);
            for d in 0..D {
                let mut z = [0.0; W];
                for (k, coef) in EXTRAPOLATION[degree - 1].iter().enumerate().take(degree + 1) {
                    let past = self.past[((head + k) % PAST) * D + d];
                    for w in 0..W {
                        z[w] += *coef * past[w];
                    }
                }
                self.z[d] = z;
            }
            return;
        }
        for w in 0..W {
            if !self.held[w] {
                continue;
            }
            let degree = degree(w);
            for d in 0..D {
                self.z[d][w] = 0.0;
            }
            for (k, coef) in EXTRAPOLATION[degree - 1].iter().enumerate().take(degree + 1) {
                let slot = (self.head[w] + k) % PAST;
                for d in 0..D {
                    self.z[d][w] += *coef * self.past[slot * D + d][w];
                }
            }
        }
    }

    /// `carry + Σ_j (h c_j) V_j` added to `q`, into point `p`
    /// (`equations::increment`).
    #[inline(always)]
    fn point_from(&mut self, p: usize, weights: &[f64; S]) {
        let h = self.h;
        for n in 0..N {
            let mut d = self.carry[n];
            for j in 0..S {
                if weights[j] != 0.0 {
                    let c = h * weights[j];
                    for w in 0..W {
                        d[w] += c * self.z[j * N + n][w];
                    }
                }
            }
            let q = self.q[n];
            let mut point = [0.0; W];
            for w in 0..W {
                point[w] = q[w] + d[w];
            }
            self.points[p][n] = point;
        }
    }

    /// Positions of the stage points, the end point and the midpoint.
    #[inline(always)]
    fn stage_points(&mut self, tab: &Tableau<S>) {
        for i in 0..S {
            self.point_from(i, &tab.a[i]);
        }
        self.point_from(S, &tab.b);
        if tab.conditions == ConditionRows::MidpointConstraint {
            let half = 0.5 * self.h;
            for n in 0..N {
                let (carry, q, v) = (self.carry[n], self.q[n], self.z[n]);
                let mut point = [0.0; W];
                for w in 0..W {
                    point[w] = q[w] + (carry[w] + half * v[w]);
                }
                self.points[S + 1][n] = point;
            }
        }
    }

    /// The system's stage values at every point of the iterating lanes,
    /// with the constraint Jacobians when `refresh` (the lean refresh).
    #[inline(always)]
    fn evaluate<Sys: NonholonomicSystem<N, M>>(
        &mut self,
        sys: &Sys,
        tab: &Tableau<S>,
        t: f64,
        iterating: &[bool; W],
        refresh: bool,
    ) {
        let h = self.h;
        let points = if tab.conditions == ConditionRows::MidpointConstraint { S + 2 } else { S + 1 };
        let mut kq = Matrix::<M, N>::zeros();
        let mut kv = Matrix::<M, N>::zeros();
        for w in 0..W {
            if !iterating[w] {
                continue;
            }
            for p in 0..points {
                let (tp, v_at) = match p {
                    p if p < S => (t + tab.c[p] * h, p * N),
                    p if p == S => (t + h, S * (N + M)),
                    _ => (t + 0.5 * h, 0),
                };
                let q = Vector::<N>::from_fn(|n, _| self.points[p][n][w]);
                let v = self.lane_vector::<N>(&self.z[..], v_at, w);
                let psi =
                    if p < S { Vector::<M>::from_fn(|m, _| self.z[S * N + p * M + m][w] / h) } else { Vector::zeros() };
                let vals = if refresh {
                    let mut vals = StageValues::zeros();
                    sys.stage_values_and_constraint_jacobians(tp, &q, &v, &psi, &mut vals, &mut kq, &mut kv);
                    for e in 0..M * N {
                        self.constraint_q[p * M * N + e][w] = kq.as_slice()[e];
                        self.constraint_v[p * M * N + e][w] = kv.as_slice()[e];
                    }
                    vals
                } else {
                    sys.stage_values(tp, &q, &v, &psi)
                };
                for n in 0..N {
                    self.momentum[p][n][w] = vals.momentum[n];
                    self.force[p][n][w] = vals.force[n];
                    self.constraint_force[p][n][w] = vals.constraint_force[n];
                }
                for m in 0..M {
                    self.constraint[p][m][w] = vals.constraint[m];
                }
            }
        }
    }

    /// The residual of eq. (6.1) into `g` (`Stepper::residual`).
    #[inline(always)]
    fn residual(&mut self, tab: &Tableau<S>) {
        let h = self.h;
        for i in 0..=S {
            let (hat, tilde) = if i < S { (&tab.a_hat[i], &tab.a_tilde[i]) } else { (&tab.b_hat, &tab.b_tilde) };
            for n in 0..N {
                let (momentum, p0) = (self.momentum[i][n], self.p0[n]);
                let mut r = [0.0; W];
                for w in 0..W {
                    r[w] = momentum[w] - p0[w];
                }
                for j in 0..S {
                    if hat[j] != 0.0 {
                        let (c, f) = (h * hat[j], self.force[j][n]);
                        for w in 0..W {
                            r[w] -= c * f[w];
                        }
                    }
                    if tilde[j] != 0.0 {
                        let (c, f) = (h * tilde[j], self.constraint_force[j][n]);
                        for w in 0..W {
                            r[w] -= c * f[w];
                        }
                    }
                }
                self.g[i * N + n] = r;
            }
        }
        let base = S * N + N;
        match tab.conditions {
            ConditionRows::Omega => {
                for r in 0..S.saturating_sub(1) {
                    for m in 0..M {
                        let mut k = [0.0; W];
                        for j in 0..S {
                            let (c, con) = (tab.omega[r][j], self.constraint[j][m]);
                            for w in 0..W {
                                k[w] += c * con[w];
                            }
                        }
                        self.g[base + r * M + m] = k;
                    }
                }
            }
            ConditionRows::MidpointConstraint => {
                for r in 0..S.saturating_sub(1) {
                    for m in 0..M {
                        self.g[base + r * M + m] = if r == 0 { self.constraint[S + 1][m] } else { [0.0; W] };
                    }
                }
            }
            ConditionRows::EqualMultipliers => {
                for r in 0..S.saturating_sub(1) {
                    for m in 0..M {
                        for w in 0..W {
                            self.g[base + r * M + m][w] =
                                self.z[S * N + r * M + m][w] - self.z[S * N + (r + 1) * M + m][w];
                        }
                    }
                }
            }
        }
        for m in 0..M {
            self.g[D - M + m] = self.constraint[S][m];
        }
    }

    /// `x ← W⁻¹ x` for the `N` lane values at `at` of `x`.
    #[inline(always)]
    fn solve_mass(mass: &MassSolve, x: &mut [L<W>], at: usize) {
        match mass {
            MassSolve::Diagonal(r) => {
                for n in 0..N {
                    let (mut xn, rn) = (x[at + n], r[n]);
                    for w in 0..W {
                        xn[w] *= rn;
                    }
                    x[at + n] = xn;
                }
            }
            MassSolve::Lu { lu, perm } => {
                for w in 0..W {
                    let mut col = [0.0; N];
                    for n in 0..N {
                        col[n] = x[at + n][w];
                    }
                    solve_in_place::<N>(lu, perm, &mut col);
                    for n in 0..N {
                        x[at + n][w] = col[n];
                    }
                }
            }
        }
    }

    /// Factors the stage-decoupled matrix of every iterating lane from the
    /// constraint Jacobians of the latest evaluation
    /// (`DecoupledMatrix::factor` with a shared mass block); a lane whose
    /// Schur complement is singular is handed back.
    #[inline(always)]
    fn factor(&mut self, tab: &Tableau<S>, iterating: &mut [bool; W], out: &mut [Outcome; W]) {
        let (nm, sm) = (N * M, Self::SM);
        // X[i][l] = coef_il · W⁻¹ K_lᵀ.
        let kt = &mut self.kt;
        for l in 0..S {
            for e in 0..M {
                for n in 0..N {
                    kt[e * N + n] = self.constraint_v[l * nm + n * M + e];
                }
                Self::solve_mass(&self.mass, kt, e * N);
            }
            for i in 0..=S {
                let coef = if i < S { tab.a_tilde[i][l] } else { tab.b_tilde[l] };
                for e in 0..M {
                    for n in 0..N {
                        let k = kt[e * N + n];
                        let mut x = [0.0; W];
                        for w in 0..W {
                            x[w] = coef * k[w];
                        }
                        self.x[i * S + l][e][n] = x;
                    }
                }
            }
        }
        self.constraint_blocks(tab);
        // Σ = E − Σ_i C[r][i] X[i][l].
        let schur = &mut self.schur;
        schur.fill([0.0; W]);
        if tab.conditions == ConditionRows::EqualMultipliers {
            for r in 0..S.saturating_sub(1) {
                for d in 0..M {
                    schur[(r * M + d) * sm + r * M + d] = [1.0; W];
                    schur[((r + 1) * M + d) * sm + r * M + d] = [-1.0; W];
                }
            }
        }
        for r in 0..S {
            for i in 0..=S {
                if !self.c_nonzero[r * (S + 1) + i] {
                    continue;
                }
                let c = &self.c[r * (S + 1) + i];
                for l in 0..S {
                    let x = &self.x[i * S + l];
                    for e in 0..M {
                        for m in 0..M {
                            let at = (l * M + e) * sm + r * M + m;
                            let mut acc = schur[at];
                            for k in 0..N {
                                let (xk, ck) = (x[e][k], c[k][m]);
                                for w in 0..W {
                                    // The scalar assembly skips a zero `X` entry.
                                    acc[w] = if xk[w] != 0.0 { acc[w] - ck[w] * xk[w] } else { acc[w] };
                                }
                            }
                            schur[at] = acc;
                        }
                    }
                }
            }
        }
        let mut live = *iterating;
        lane_lu::factor(&mut self.schur, sm, &mut self.schur_perm, &mut self.schur_scale, &mut live);
        for w in 0..W {
            if iterating[w] && !live[w] {
                (iterating[w], out[w]) = (false, Outcome::HandBack);
            }
        }
    }

    /// `C[r][i]`, as `DecoupledMatrix::write_constraint_blocks` writes them.
    #[inline(always)]
    fn constraint_blocks(&mut self, tab: &Tableau<S>) {
        let (mn, h) = (M * N, self.h);
        self.c_nonzero.fill(false);
        let (kv, kq) = (&self.constraint_v, &self.constraint_q);
        let (c, nonzero) = (&mut self.c, &mut self.c_nonzero);
        let mut put = |r: usize, i: usize, e: usize, x: L<W>| {
            c[r * (S + 1) + i][e / M][e % M] = x;
            nonzero[r * (S + 1) + i] = true;
        };
        match tab.conditions {
            ConditionRows::Omega => {
                for r in 0..S.saturating_sub(1) {
                    for l in 0..S {
                        for e in 0..mn {
                            let mut blk = [0.0; W];
                            for w in 0..W {
                                blk[w] = tab.omega[r][l] * kv[l * mn + e][w];
                            }
                            for m in 0..S {
                                let cm = tab.omega[r][m] * tab.a[m][l];
                                if cm != 0.0 {
                                    let (hc, k) = (h * cm, kq[m * mn + e]);
                                    for w in 0..W {
                                        blk[w] += hc * k[w];
                                    }
                                }
                            }
                            put(r, l, e, blk);
                        }
                    }
                }
            }
            ConditionRows::MidpointConstraint => {
                let half = 0.5 * h;
                for e in 0..mn {
                    let mut blk = [0.0; W];
                    let (kve, kqe) = (kv[(S + 1) * mn + e], kq[(S + 1) * mn + e]);
                    for w in 0..W {
                        blk[w] = kve[w] + half * kqe[w];
                    }
                    put(0, 0, e, blk);
                }
            }
            ConditionRows::EqualMultipliers => {}
        }
        for l in 0..S {
            let hb = h * tab.b[l];
            for e in 0..mn {
                let mut blk = [0.0; W];
                let k = kq[S * mn + e];
                for w in 0..W {
                    blk[w] = hb * k[w];
                }
                put(S - 1, l, e, blk);
            }
        }
        for e in 0..mn {
            put(S - 1, S, e, kv[S * mn + e]);
        }
    }

    /// Overwrites the residual `g` with the update `J̃⁻¹ g`
    /// (`DecoupledMatrix::solve_in_place`).
    #[inline(always)]
    fn solve(&mut self) {
        let sm = Self::SM;
        let base = (S + 1) * N;
        self.y.copy_from_slice(&self.g[..]);
        for i in 0..=S {
            Self::solve_mass(&self.mass, &mut self.y, i * N);
        }
        let (vel, con) = self.y.split_at_mut(base);
        // Each entry of `con` takes its products in the order of the
        // stage-decoupled solve (point `i`, then coordinate `k`).
        for r in 0..S {
            for m in 0..M {
                let mut acc = con[r * M + m];
                for i in 0..=S {
                    if !self.c_nonzero[r * (S + 1) + i] {
                        continue;
                    }
                    let c = &self.c[r * (S + 1) + i];
                    for k in 0..N {
                        let (yk, ck) = (vel[i * N + k], c[k][m]);
                        for w in 0..W {
                            acc[w] -= ck[w] * yk[w];
                        }
                    }
                }
                con[r * M + m] = acc;
            }
        }
        lane_lu::solve(&self.schur, sm, &self.schur_perm, &mut con[..sm]);
        for i in 0..=S {
            let out_at = if i < S { i * N } else { S * (N + M) };
            for n in 0..N {
                let mut acc = vel[i * N + n];
                for l in 0..S {
                    let x = &self.x[i * S + l];
                    for e in 0..M {
                        let (mu, xe) = (con[l * M + e], x[e][n]);
                        for w in 0..W {
                            acc[w] -= xe[w] * mu[w];
                        }
                    }
                }
                self.g[out_at + n] = acc;
            }
        }
        for e in 0..sm {
            self.g[S * N + e] = con[e];
        }
    }

    /// `z ← z − Δz` in the iterating lanes; each lane's scaled update norm
    /// (`linalg::scaled_update_norm`).
    #[inline(always)]
    fn apply_update(&mut self, iterating: &[bool; W]) -> L<W> {
        let mut norm = [0.0f64; W];
        let mut nan = [false; W];
        for d in 0..D {
            let (mut z, g) = (self.z[d], self.g[d]);
            for w in 0..W {
                z[w] = if iterating[w] { z[w] - g[w] } else { z[w] };
                let r = g[w].abs() / (1.0 + z[w].abs());
                nan[w] |= r.is_nan();
                norm[w] = if r > norm[w] { r } else { norm[w] };
            }
            self.z[d] = z;
        }
        std::array::from_fn(|w| if nan[w] { f64::NAN } else { norm[w] })
    }

    /// Ends the converged lanes' steps (`Stepper::step` after Newton): the
    /// compensated `q₁`, `v₁`, the finiteness check, the energy guard and
    /// the ring of solutions. A lane that fails a check is handed back
    /// with its state as it was.
    #[inline(always)]
    fn commit<Sys: NonholonomicSystem<N, M>>(
        &mut self,
        sys: &Sys,
        tab: &Tableau<S>,
        opts: &NewtonOptions,
        t: f64,
        t_next: f64,
        out: &mut [Outcome; W],
    ) {
        let h = self.h;
        for w in 0..W {
            if !matches!(out[w], Outcome::Stepped(_)) {
                continue;
            }
            let carry = self.lane_vector::<N>(&self.carry[..], 0, w);
            let mut dq = carry;
            for j in 0..S {
                if tab.b[j] != 0.0 {
                    let c = h * tab.b[j];
                    for n in 0..N {
                        dq[n] += c * self.z[j * N + n][w];
                    }
                }
            }
            let q0 = self.lane_vector::<N>(&self.q[..], 0, w);
            let q1 = q0 + dq;
            let v1 = self.lane_vector::<N>(&self.z[..], S * (N + M), w);
            if !q1.iter().chain(v1.iter()).all(|x| x.is_finite()) {
                out[w] = Outcome::HandBack;
                continue;
            }
            if let (Some(limit), true) = (opts.energy_drift_limit, energy_is_invariant::<Sys, N, M>()) {
                let start = State::new(t, q0, self.lane_vector::<N>(&self.v[..], 0, w));
                let end = State::new(t + h, q1, v1);
                match check_energy::<Sys, N, M>(sys, self.anchor[w].as_ref(), &start, &end, limit) {
                    EnergyCheck::Accept(a) => {
                        self.anchor[w] = Some(EnergyAnchor { end: State { t: t_next, ..end }, ..a })
                    }
                    EnergyCheck::Drift(..) => {
                        out[w] = Outcome::HandBack;
                        continue;
                    }
                }
            }
            let carry = crate::step::two_sum_error(&q0, &dq, &q1);
            for n in 0..N {
                self.q[n][w] = q1[n];
                self.v[n][w] = v1[n];
                self.carry[n][w] = carry[n];
            }
            self.head[w] = (self.head[w] + PAST - 1) % PAST;
            self.depth[w] = (self.depth[w] + 1).min(PAST);
            let slot = self.head[w] * D;
            for d in 0..D {
                self.past[slot + d][w] = self.z[d][w];
            }
        }
    }
}
