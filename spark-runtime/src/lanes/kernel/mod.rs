//! The structure-of-arrays kernel of a lane group: the steps of up to `W`
//! members in one Newton iteration, every array laid out `[entry][lane]`
//! so that one instruction advances every lane (eight `f64` per AVX-512
//! register, four per AVX2 one; the kernel is compiled for the widest of
//! the two that the CPU has).
//!
//! # What it computes
//! The kernel repeats, operation for operation and in the same order, the
//! path of [`Stepper::step`](crate::Stepper::step) that an ensemble of a
//! system with a constant mass matrix takes at almost every step: the
//! starting guess extrapolated from the latest solutions, simplified Newton
//! on the stage-decoupled matrix refreshed at the step's first iterate with
//! the constraint Jacobians alone (`linalg::decoupled`, the lean refresh),
//! the residual of eq. (6.1),
//! the stopping rules of [`Contraction`](crate::step::Contraction) and of
//! `step::affine_along`, the compensated `q₁`, the
//! energy guard. So a lane's states are bit for bit those of its member
//! stepped alone. Only the system's own functions run lane by lane.
//!
//! Where the stepper would decide something the kernel does not repeat — a
//! contraction too slow for the stage-decoupled matrix, a singular matrix,
//! a non-finite residual, the iteration limit, an energy drift, the
//! refresh after a first update of a closed affine cover
//! ([`Nonlinearity`](crate::Nonlinearity)) that did not land — the
//! kernel hands the lane's step back ([`Outcome::HandBack`]): its
//! [`Stepper`](crate::Stepper) computes that step from the same
//! continuation (`step::lane_handover`), and so reaches the same decision.

// Stage and lane loops index several parallel arrays with one index.
#![allow(clippy::needless_range_loop)]

mod decoupled;
mod equations;

use super::values::{LaneConstraintJacobians, LaneStageValues};
use crate::error::HISTORY_CAPACITY;
use crate::linalg::decoupled::factor_mass;
use crate::linalg::stiff_stages::{kept_stiffness_points, StiffStages};
use crate::step::{
    affine_along_lanes, check_energy, energy_is_invariant, moved_beyond, rounding_moved, too_slow, two_sum_error_of,
    AffinePlan, Contraction, EnergyAnchor, LaneContinuation, NewtonOptions, State, StepPolynomial, Stepper,
    LANDING_LIMIT, PAST,
};
use crate::system::{NonholonomicSystem, StageJacobians, StageValues, Vector};
use crate::tableau::Tableau;

/// One `f64` per lane.
type L<const W: usize> = [f64; W];

/// The instruction set a kernel step is compiled for, chosen once per
/// lane group from what the CPU has (ordered from the narrowest).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(super) enum Simd {
    /// The build's baseline.
    Baseline,
    /// AVX2 and FMA.
    Avx2,
    /// AVX-512 F, VL, DQ (with AVX2 and FMA): a row of eight lanes is one register.
    Avx512,
}

impl Simd {
    /// The widest set this CPU has.
    pub(super) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if crate::linalg::avx512_available() {
                return Simd::Avx512;
            }
            if crate::linalg::avx2_fma_available() {
                return Simd::Avx2;
            }
        }
        Simd::Baseline
    }
}

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
    simd: Simd,
    mass: MassSolve,
    h: f64,
    /// The stage blocks of a constant stiffness, made as the steppers make
    /// them (`linalg::stiff_stages`; kept exactly when their per-coordinate
    /// coefficients exist), and one lane's velocity rows for their solve.
    stiff: StiffStages<N, S>,
    stiff_column: Box<[f64]>,
    /// The stepper's plan of the affine acceptance on this matrix, which
    /// keeps the stiffness when `stiff` does
    /// (`Stepper::affine_plan`, `DecoupledMatrix::keeps_stiffness`).
    affine_plan: AffinePlan,
    /// Which lanes the kernel holds.
    held: [bool; W],
    /// The state where each lane's latest step ended, and its carry.
    q: Box<[L<W>; N]>,
    v: Box<[L<W>; N]>,
    carry: Box<[L<W>; N]>,
    /// Each lane's energy anchor, of the chain that ends at the lane's
    /// state (`None` after a step the guard did not check), and the time of
    /// that state (meaningful with the anchor only): the energy guard
    /// continues the chain without comparing states.
    anchor: [Option<EnergyAnchor>; W],
    anchor_t: [f64; W],
    /// Ring of the latest solutions: slot `k` at `k·D`; lane `w`'s most
    /// recent is slot `head[w]`.
    past: Box<[L<W>]>,
    head: [usize; W],
    depth: [usize; W],
    /// The unknowns, the residual and the solve's scratch (the update is
    /// applied to `z` as the solve produces it).
    z: Box<[L<W>; D]>,
    g: Box<[L<W>; D]>,
    /// The update norm's weights `1/(1 + |z_i|)` at the iterate the step's
    /// first update leads to.
    weights: Box<[L<W>; D]>,
    /// The latest update on fresh factors, kept when the system's
    /// nonlinearity may accept it (`step::affine_along`; empty otherwise).
    first_update: Box<[L<W>]>,
    y: Box<[L<W>]>,
    p0: Box<[L<W>; N]>,
    /// Positions of the evaluation points: stages `0..S`, the end `S`, the
    /// midpoint `S + 1` (`N` each).
    points: Box<[[L<W>; N]]>,
    /// Stage values at the points.
    values: Box<[LaneStageValues<N, M, W>]>,
    /// `k_q` and `K = k_v` at the points.
    jacobians: Box<[LaneConstraintJacobians<N, M, W>]>,
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
    /// The starting guess of Gauss steps (`Stepper`'s, from the same tableau).
    step_polynomial: Option<StepPolynomial<S>>,
    /// Each lane's prior for its contraction estimate: the largest ratio
    /// its latest step earned and whether on the stage-decoupled matrix
    /// (`Warm::rate`; the kernel's own steps always are, a step its stepper
    /// took may have ended on the exact matrix, whose prior goes back with
    /// the lane), and what the step being committed earned.
    rate: [(f64, bool); W],
    solved_rate: L<W>,
}

impl<const N: usize, const M: usize, const S: usize, const D: usize, const W: usize> Kernel<N, M, S, D, W> {
    const SM: usize = S * M;
    const POINTS: usize = S + 2;

    /// A kernel for steps of size `h` of `system`, whose constant mass
    /// matrix is evaluated at `at`; `None` when that matrix is singular
    /// (the steppers then report it themselves).
    pub(super) fn new<Sys: NonholonomicSystem<N, M>>(
        system: &Sys,
        tab: &Tableau<S>,
        at: &State<N>,
        h: f64,
        simd: Simd,
    ) -> Option<Self> {
        let mut vals = StageValues::zeros();
        let mut jac = StageJacobians::<N, M>::boxed_zeros();
        system.stage_jacobians_into(at.t, &at.q, &at.v, &Vector::zeros(), &mut vals, &mut jac);
        let (mut rdiag, mut lu, mut perm) = (vec![0.0; N], vec![0.0; N * N], vec![0; N]);
        let diagonal_mass = factor_mass::<N>(jac.mass.as_slice(), &mut rdiag, &mut lu, &mut perm).ok()?;
        let mass = match diagonal_mass {
            true => MassSolve::Diagonal(rdiag.into()),
            false => MassSolve::Lu { lu: lu.into(), perm: perm.into() },
        };
        // A stiffness per stage point, which the steppers keep with a
        // diagonal mass matrix at the tableau's coupling points, is not
        // repeated: the members step alone.
        if Sys::DIAGONAL_STIFFNESS && diagonal_mass && kept_stiffness_points(tab).iter().any(|&kept| kept) {
            return None;
        }
        // A constant stiffness is kept as the steppers keep it; the kernel
        // repeats only its per-coordinate form (a diagonal mass matrix).
        let mut stiff = StiffStages::new(Sys::CONSTANT_STIFFNESS);
        stiff.set(jac.force_q.as_slice());
        let coupled = stiff.factor(tab, h, jac.mass.as_slice(), diagonal_mass).ok()?;
        if coupled && stiff.columns().is_none() {
            return None;
        }
        let (p, sm) = (Self::POINTS, Self::SM);
        Some(Kernel {
            simd,
            mass,
            h,
            stiff,
            stiff_column: vec![0.0; (S + 1) * N].into_boxed_slice(),
            affine_plan: *Stepper::<Sys, N, M, S, D>::affine_plan(true, coupled),
            held: [false; W],
            q: fixed(),
            v: fixed(),
            carry: fixed(),
            anchor: [None; W],
            anchor_t: [0.0; W],
            past: lanes(PAST * D),
            head: [0; W],
            depth: [0; W],
            z: fixed(),
            g: fixed(),
            weights: fixed(),
            first_update: lanes(if Stepper::<Sys, N, M, S, D>::affine_rule(true).is_some() { D } else { 0 }),
            y: lanes(D),
            p0: fixed(),
            points: vec![[[0.0; W]; N]; p].into_boxed_slice(),
            values: vec![LaneStageValues::zeros(); p].into_boxed_slice(),
            jacobians: vec![LaneConstraintJacobians::zeros(); p].into_boxed_slice(),
            x: vec![[[[0.0; W]; N]; M]; (S + 1) * S].into_boxed_slice(),
            c: vec![[[[0.0; W]; M]; N]; S * (S + 1)].into_boxed_slice(),
            c_nonzero: vec![false; S * (S + 1)].into_boxed_slice(),
            schur: lanes(sm * sm),
            schur_perm: vec![[0; W]; sm].into_boxed_slice(),
            schur_scale: lanes(sm),
            kt: lanes(N * M),
            step_polynomial: StepPolynomial::new(tab),
            rate: [(f64::NAN, false); W],
            solved_rate: [f64::NAN; W],
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
        // The continuation's anchor belongs to the chain ending at `c.end`.
        self.anchor[w] = c.anchor;
        self.anchor_t[w] = c.end.t;
        self.rate[w] = c.rate;
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
            anchor: self.anchor[w].filter(|_| self.anchor_t[w] == t),
            past,
            depth: self.depth[w],
            rate: self.rate[w],
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
        match self.simd {
            // SAFETY: `Simd::detect` chose these only where the CPU has them.
            Simd::Avx512 => return unsafe { self.step_avx512(sys, tab, opts, t, t_next) },
            Simd::Avx2 => return unsafe { self.step_avx2(sys, tab, opts, t, t_next) },
            Simd::Baseline => {}
        }
        self.step_body(sys, tab, opts, t, t_next)
    }

    /// [`Self::step`] compiled for AVX-512 (the same operations: no
    /// contraction into fused multiply-adds, so every lane is bit for bit
    /// the scalar stepper).
    ///
    /// # Safety
    /// AVX-512 F, VL, DQ, AVX2 and FMA must be available.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma,avx512f,avx512vl,avx512dq")]
    unsafe fn step_avx512<Sys: NonholonomicSystem<N, M>>(
        &mut self,
        sys: &Sys,
        tab: &Tableau<S>,
        opts: &NewtonOptions,
        t: f64,
        t_next: f64,
    ) -> [Outcome; W] {
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
        let affine = Stepper::<Sys, N, M, S, D>::affine_rule(true);
        // The prior of the stage-decoupled matrix only, as in `Stepper::newton`.
        let mut monitor: [Contraction; W] =
            std::array::from_fn(|w| Contraction::fresh(if self.rate[w].1 { self.rate[w].0 } else { f64::NAN }));
        let mut prev_update = [f64::NAN; W];
        // A closed affine cover's first update that does not end the solve
        // makes the stepper refresh its factors, and start its next step
        // from them (`Stepper::starts_stale`): such a lane goes back to its
        // stepper, which takes that step and the next ones alone.
        let cover = affine.is_some_and(|n| n.closed_affine_cover);
        for k in 0..max_iter {
            let fresh = k == 0;
            self.stage_points(tab);
            self.evaluate(sys, tab, t, &iterating, fresh);
            self.residual(tab);
            if fresh {
                self.factor(tab, &mut iterating, &mut out);
            }
            let update = self.solve_and_update(&iterating, fresh);
            let lands =
                if fresh { self.first_updates_land(affine.as_ref(), opts.tolerance, &update) } else { [false; W] };
            for w in 0..W {
                if !iterating[w] {
                    continue;
                }
                let update = update[w];
                let rate = update / prev_update[w];
                monitor[w].record(update);
                let converged = monitor[w].converged(update, opts.tolerance);
                // The stepper's test, asked only of a lane it could stop.
                if !fresh && !converged && update > opts.stagnation_level {
                    let remaining = (max_iter - 1 - k) as i32;
                    if too_slow(&monitor[w], true, update, rate, remaining, opts.tolerance) {
                        (iterating[w], out[w]) = (false, Outcome::HandBack);
                        continue;
                    }
                }
                let stop = if !update.is_finite() {
                    Some(Outcome::HandBack)
                } else if converged || (lands[w] && self.end_point_stays(tab, w, opts.tolerance)) {
                    Some(Outcome::Stepped(k + 1))
                } else if k > 0 && rate >= 1.0 {
                    Some(if update <= opts.stagnation_level { Outcome::Stepped(k + 1) } else { Outcome::HandBack })
                } else {
                    None
                };
                match stop {
                    Some(o) => (iterating[w], out[w]) = (false, o),
                    None if fresh && cover => (iterating[w], out[w]) = (false, Outcome::HandBack),
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
        self.solved_rate = monitor.map(|m| m.observed());
        self.commit(sys, tab, opts, t, t_next, &mut out);
        out
    }

    /// Whether each lane's first update, on factors evaluated at the iterate
    /// it started from, passes `step::affine_along` on the stage-decoupled
    /// matrix, the stepper's first test of whether that update ends its
    /// solve ([`Self::end_point_stays`] is the second, asked lane by lane
    /// of the lanes that pass).
    #[inline(always)]
    fn first_updates_land(&self, affine: Option<&crate::Nonlinearity>, tolerance: f64, norm: &L<W>) -> [bool; W] {
        let Some(nonlinearity) = affine else { return [false; W] };
        let moved_at = |d: usize| -> [bool; W] {
            std::array::from_fn(|w| moved_beyond(self.first_update[d][w], self.weights[d][w], tolerance))
        };
        let affine = affine_along_lanes::<N, M, S, W>(moved_at, nonlinearity, &self.affine_plan);
        // `norm`: each lane's largest scaled entry of this update, with
        // the weights `moved_at` reads.
        std::array::from_fn(|w| norm[w] <= LANDING_LIMIT && affine[w])
    }

    /// `Stepper::end_point_stays` for lane `w`, whose `z` holds the updated
    /// iterate and `points[S]` the end point it was evaluated at: the same
    /// operations in the same order.
    #[inline(always)]
    fn end_point_stays(&self, tab: &Tableau<S>, w: usize, tolerance: f64) -> bool {
        let h = self.h;
        let moves =
            |c: usize| self.affine_plan.keeps_position(c) && (0..S).any(|j| self.first_update[j * N + c][w] != 0.0);
        (0..N).filter(|&c| moves(c)).all(|c| {
            let (mut new, mut shift, mut weight) = (self.carry[c][w], 0.0, 0.0f64);
            for j in 0..S {
                let k = h * tab.b[j];
                new += k * self.z[j * N + c][w];
                shift += k * self.first_update[j * N + c][w];
                weight = weight.max(self.weights[j * N + c][w]);
            }
            !rounding_moved(self.points[S][c][w], self.q[c][w] + new, shift, weight, tolerance)
        })
    }

    /// Lane `w` of the `N` values at `at` of `x`.
    #[inline(always)]
    fn lane_vector<const K: usize>(&self, x: &[L<W>], at: usize, w: usize) -> Vector<K> {
        Vector::from_fn(|n, _| x[at + n][w])
    }

    /// One row of the update, `Δz_d`: `z_d ← z_d − Δz_d` in the lanes whose
    /// `applies` bits are all set (the iterating ones), its scaled size
    /// folded into each lane's `norm`, with the weight taken at the new `z_d` when `first`
    /// (`linalg::weigh_and_norm`) and kept for the later updates
    /// (`linalg::weighted_update_norm`). A maximum and a NaN test do not
    /// depend on the order of the rows, so the solve applies each row as it
    /// produces it.
    #[inline(always)]
    fn update_row(z: &mut L<W>, weight: &mut L<W>, update: &L<W>, applies: &[u64; W], first: bool, norm: &mut L<W>) {
        let mut next = *z;
        for w in 0..W {
            // The update's bits in an iterating lane, `+0` in the others:
            // `z − 0` is `z` bit for bit (signed zeros and NaN included),
            // and the whole row is stored (no masked store).
            next[w] -= f64::from_bits(update[w].to_bits() & applies[w]);
        }
        if first {
            for w in 0..W {
                weight[w] = 1.0 / (1.0 + next[w].abs());
            }
        }
        for w in 0..W {
            // The largest scaled entry, NaN from the first NaN on (no
            // later entry compares above it), as `linalg::weighted_update_norm`:
            // a lane whose update is not finite goes back to its stepper.
            let r = update[w].abs() * weight[w];
            norm[w] = if r > norm[w] || r.is_nan() { r } else { norm[w] };
        }
        *z = next;
    }

    /// Ends the converged lanes' steps (`Stepper::step` after Newton): the
    /// compensated `q₁`, `v₁`, the finiteness check, the energy guard, the
    /// ring of solutions and the prior of the next step (`solved_rate`, what
    /// each lane's iteration earned). A lane that fails a check is handed
    /// back with its state as it was.
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
        let stepped: [bool; W] = std::array::from_fn(|w| matches!(out[w], Outcome::Stepped(_)));
        if !stepped.contains(&true) {
            return;
        }
        // Δq = carry + Σ_j (h b_j) V_j and q₁ = q₀ + Δq in every lane, in
        // the stepper's order of operations.
        // Row by row, each row in flight and stored once (a copy of the
        // whole carry block is a `memcpy` call).
        let (mut dq_lanes, mut q1_lanes) = ([[0.0; W]; N], [[0.0; W]; N]);
        for n in 0..N {
            let mut dq = self.carry[n];
            for j in 0..S {
                let (c, z) = (h * tab.b[j], self.z[j * N + n]);
                for w in 0..W {
                    dq[w] += c * z[w];
                }
            }
            let q = self.q[n];
            dq_lanes[n] = dq;
            q1_lanes[n] = std::array::from_fn(|w| q[w] + dq[w]);
        }
        let end = S * (N + M);
        let v1_lanes: &[L<W>; N] = self.z[end..end + N].try_into().expect("z holds the end velocity's N rows");
        // A lane whose `q₁` or `v₁` is not finite goes back (`0 · x` is NaN
        // exactly for those, as in the residual's test).
        let mut poison = [0.0f64; W];
        for n in 0..N {
            for w in 0..W {
                poison[w] += 0.0 * q1_lanes[n][w] + 0.0 * v1_lanes[n][w];
            }
        }
        let guard = opts.energy_drift_limit.filter(|_| energy_is_invariant::<Sys, N, M>());
        let e1 = guard.map(|_| sys.energy_in_lanes(t + h, &q1_lanes, v1_lanes, &stepped));
        let mut kept = [false; W];
        for w in 0..W {
            if !stepped[w] {
                continue;
            }
            if poison[w] != 0.0 {
                out[w] = Outcome::HandBack;
                continue;
            }
            if let (Some(limit), Some(e1)) = (guard, e1.map(|e| e[w])) {
                // The chain the kernel continues, checked in place: what
                // `check_energy` decides for an anchor at the step's start.
                let mut anchor = self.anchor[w].filter(|_| self.anchor_t[w] == t);
                if let Some(a) = anchor.filter(|a| a.scale > 0.0) {
                    if !a.holds(e1, limit) {
                        out[w] = Outcome::HandBack;
                        continue;
                    }
                } else {
                    let q1 = self.lane_vector::<N>(&q1_lanes[..], 0, w);
                    let v1 = self.lane_vector::<N>(&v1_lanes[..], 0, w);
                    let q0 = self.lane_vector::<N>(&self.q[..], 0, w);
                    let start = State::new(t, q0, self.lane_vector::<N>(&self.v[..], 0, w));
                    let end = State::new(t + h, q1, v1);
                    if check_energy::<Sys, N, M>(sys, &mut anchor, &start, &end, e1, limit).is_err() {
                        out[w] = Outcome::HandBack;
                        continue;
                    }
                    self.anchor[w] = anchor;
                }
                self.anchor_t[w] = t_next;
            } else {
                // No chain ends here: the next checked step begins one.
                self.anchor[w] = None;
            }
            kept[w] = true;
            self.head[w] = (self.head[w] + PAST - 1) % PAST;
            self.depth[w] = (self.depth[w] + 1).min(PAST);
            self.rate[w] = (self.solved_rate[w], true);
        }
        // The kept lanes' new state and carry (the stepper's TwoSum), and
        // their solutions into the ring: whole rows where every kept lane
        // writes the same slot.
        if kept.iter().all(|&k| k) {
            // Every lane kept (the usual step): whole rows, vectorized. A
            // select on the `bool`s compiles to a branch per lane (LLVM
            // unswitches the row loop on each), and scalar code.
            for n in 0..N {
                let (q0, dq, q1) = (self.q[n], dq_lanes[n], q1_lanes[n]);
                self.carry[n] = std::array::from_fn(|w| two_sum_error_of(q0[w], dq[w], q1[w]));
                (self.q[n], self.v[n]) = (q1, v1_lanes[n]);
            }
        } else {
            for n in 0..N {
                let (q0, dq, q1, v1) = (self.q[n], dq_lanes[n], q1_lanes[n], v1_lanes[n]);
                let (mut q, mut v, mut carry) = (q0, self.v[n], self.carry[n]);
                for w in 0..W {
                    let err = two_sum_error_of(q0[w], dq[w], q1[w]);
                    q[w] = if kept[w] { q1[w] } else { q[w] };
                    v[w] = if kept[w] { v1[w] } else { v[w] };
                    carry[w] = if kept[w] { err } else { carry[w] };
                }
                (self.q[n], self.v[n], self.carry[n]) = (q, v, carry);
            }
        }
        let first = (0..W).find(|&w| kept[w]);
        if let Some(f) = first.filter(|&f| (0..W).all(|w| !kept[w] || self.head[w] == self.head[f])) {
            let slot = self.head[f] * D;
            if kept.iter().all(|&k| k) {
                // Every lane kept (the usual step): whole rows copied. The
                // select below, stored back where it was read, compiles to
                // a masked store (`vmaskmovpd`), which Zen 3 runs as a
                // microcoded sequence: 4 % of the mp7 kernel in a `perf`
                // profile.
                self.past[slot..slot + D].copy_from_slice(&self.z[..]);
            } else {
                for d in 0..D {
                    let (z, mut past) = (self.z[d], self.past[slot + d]);
                    for w in 0..W {
                        past[w] = if kept[w] { z[w] } else { past[w] };
                    }
                    self.past[slot + d] = past;
                }
            }
        } else {
            for w in (0..W).filter(|&w| kept[w]) {
                let slot = self.head[w] * D;
                for d in 0..D {
                    self.past[slot + d][w] = self.z[d][w];
                }
            }
        }
    }
}
