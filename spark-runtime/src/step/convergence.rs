//! Newton's stopping rule — the contraction monitor of simplified Newton,
//! full Newton's rule and the acceptance of an update along which the
//! equations are affine ([`affine_along`]) — and the rule that gives up on
//! factors too slow to keep ([`too_slow`]), on the scaled update norms of
//! [`weighted_update_norm`](crate::linalg::weighted_update_norm).

use crate::system::{Nonlinearity, Vector};

/// What the updates computed with one set of Newton factors tell about
/// their contraction, and the stopping rule built on it.
///
/// The ratio `ρ_j = ‖Δz_j‖/‖Δz_{j−1}‖` of consecutive updates on the same
/// factors estimates their contraction `θ`, but the first ratio on new
/// factors is not evidence: the first update removes the error components
/// the factors solve exactly (unknowns that enter linearly, the multipliers;
/// for the first update on fresh factors everything to first order), so
/// `ρ₂` measures what is left of a different error than the one the next
/// update faces. Measured on the McLachlan–Perlmutter particles from a cold
/// start (Lobatto IIIA-B-D s = 2, h = 0.1, simplified Newton): `ρ₂ = 1.8e-7`
/// against `θ = 3.5e-3`. A rate is *earned* from the third update on (the
/// fourth without a prior, see [`Contraction::earned`]): the
/// largest ratio on these factors so far, so that no fast ratio can stand
/// for the contraction alone. The ratios of one linear iteration need not
/// decrease: on the stage-decoupled matrix (McLachlan–Perlmutter particles,
/// Gauss s = 2, h = 0.2) they ran 6.2e-3, 1.5e-3, 4.4e-2, 9.2e-3, 3.3e-3, and
/// the larger of the last two alone left an error 5× the tolerance.
///
/// Nor need the first ratios show the rate the iteration settles to: when
/// the starting guess is close, the error's fast components dominate the
/// first updates and the slow ones surface later. On the stage-decoupled
/// matrix (McLachlan–Perlmutter particles, Gauss s = 2, h = 0.05, from the
/// step polynomial's guess) the ratios ran 4.2e-4, 9.2e-5 and then 3.0e-3:
/// the largest of the first two accepted an iterate 6× the tolerance from
/// the solution. So the rate the previous step of the same size settled to
/// on the same kind of matrix, which changes little from one step to the
/// next, is a floor under the estimate (`prior`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Contraction {
    /// Updates computed with the current factors.
    updates: usize,
    /// The latest of them.
    last: f64,
    /// `ρ` of the latest two (NaN with fewer than two).
    rate: f64,
    /// `ρ` of the two before (NaN with fewer than three updates).
    prev_rate: f64,
    /// The largest `ρ` on these factors (NaN with fewer than two updates).
    max_rate: f64,
    /// The largest `ρ` of the previous step on the same kind of factors
    /// (NaN when there is none to go by).
    prior: f64,
}

impl Contraction {
    /// No update on the current factors yet, and no prior.
    pub(crate) const FRESH: Self = Self::fresh(f64::NAN);

    /// No update on the current factors yet; `prior` is the largest ratio
    /// the previous step of the same size earned on the same kind of
    /// factors (NaN for none).
    pub(crate) const fn fresh(prior: f64) -> Self {
        Contraction { updates: 0, last: f64::NAN, rate: f64::NAN, prev_rate: f64::NAN, max_rate: f64::NAN, prior }
    }

    /// The largest ratio on these factors, for the next step's prior (NaN
    /// with fewer than two updates on them).
    pub(crate) fn observed(&self) -> f64 {
        self.max_rate
    }

    /// Records the scaled norm of an update computed with the current
    /// factors; returns its ratio to the previous one on them (NaN for the
    /// first).
    #[inline]
    pub(crate) fn record(&mut self, update: f64) -> f64 {
        self.prev_rate = self.rate;
        self.rate = update / self.last;
        // NaN propagates: an iteration that produced one never earns a rate.
        self.max_rate = if self.updates <= 1 || self.rate.is_nan() { self.rate } else { self.max_rate.max(self.rate) };
        self.last = update;
        self.updates += 1;
        self.rate
    }

    /// The earned contraction estimate: the largest ratio on these factors,
    /// or the prior when that is larger, once three updates on them exist,
    /// four without a prior (NaN before, and NaN when a ratio was).
    ///
    /// Without a prior (a cold step, the first after a change of `h` or of
    /// the kind of matrix) nothing vouches that a slow error mode has
    /// surfaced in the first two ratios. A cold Lobatto IIIA-B s = 3 step of
    /// a system with a constraint nonlinear in `v` (`OddNames` of the
    /// integration tests, h = 0.25, the exact matrix) runs 1.1e-2, 1.0e-6,
    /// 3.9e-11 (ratios 9.1e-5, 3.8e-5) while its multipliers' error
    /// contracts at 3e-3 an update: stopping there would leave `μ` 1.15e-13
    /// from the tight solve. The fourth update shows that rate.
    #[inline]
    pub(crate) fn earned(&self) -> f64 {
        let needed = if self.prior.is_nan() { 4 } else { 3 };
        if self.updates >= needed {
            if self.prior > self.max_rate {
                self.prior
            } else {
                self.max_rate
            }
        } else {
            f64::NAN
        }
    }

    /// The contraction per update over the last two, `√(ρ_j ρ_{j−1})`, once
    /// three updates on these factors exist (NaN before): one fast or slow
    /// ratio does not decide it, and the alternating ratios of an iteration
    /// with a complex pair of error modes average out.
    pub(crate) fn sustained(&self) -> f64 {
        if self.updates >= 3 {
            (self.rate * self.prev_rate).sqrt()
        } else {
            f64::NAN
        }
    }

    /// Newton's stopping rule for the latest update `update`: within the
    /// tolerance itself (the error left is `θ/(1−θ)·update`, below it for
    /// `θ ≤ ½`), or the remaining error `θ/(1−θ)·update` estimated with an
    /// earned rate `θ < 1` within it. Written so that NaN never converges.
    #[inline]
    pub(crate) fn converged(&self, update: f64, tolerance: f64) -> bool {
        let theta = self.earned();
        update <= tolerance || (theta < 1.0 && update * theta / (1.0 - theta) <= tolerance)
    }

    /// The stopping rule of the solve's mode: [`Self::converged`] for
    /// simplified Newton, [`full_newton_converged`] on the latest ratio
    /// `rate` for full Newton.
    #[inline]
    pub(crate) fn converged_in(&self, simplified: bool, update: f64, rate: f64, tolerance: f64) -> bool {
        if simplified {
            self.converged(update, tolerance)
        } else {
            full_newton_converged(update, rate, tolerance)
        }
    }
}

/// Full Newton's stopping rule: the update itself, or the error left after
/// it estimated as `θ/(1−θ)·‖Δz‖` from the ratio `θ` of the last two updates,
/// is within `tolerance`. Each update of full Newton uses a fresh Jacobian, so
/// the ratio is that of the iteration itself, and it can only overstate the
/// error left by a quadratically converging one; at stiff steps, where the
/// updates reach their round-off floor above the tolerance, it stops before
/// round-off makes them grow. Simplified Newton uses the rate it has earned on
/// its frozen factors instead ([`Contraction::converged`]).
pub(super) fn full_newton_converged(update: f64, rate: f64, tolerance: f64) -> bool {
    update <= tolerance || (rate < 1.0 && update * rate / (1.0 - rate) <= tolerance)
}

/// Full Newton's test of a new iterate before its Jacobian is evaluated:
/// `update` is the scaled norm of `δ = J_k⁻¹ G(z_{k+1})`, the residual at the
/// new iterate `z_{k+1} = z_k − Δz_k` solved with the factors of `J_k`, and
/// `prev_update` the scaled norm of `Δz_k`.
///
/// With `z*` the solution, `e = z_{k+1} − z*` and `J̄` the mean Jacobian
/// between them, `G(z_{k+1}) = J̄ e`, so `δ = J_k⁻¹J̄ e` and the iterate
/// `z_{k+1} − δ` has the error `(I − J_k⁻¹J̄) e`. Its contraction
/// `θ = ‖I − J_k⁻¹J̄‖ ≤ ‖J_k⁻¹‖·L·(‖e_k‖ + ‖e‖)` (`L` a Lipschitz constant
/// of the Jacobian) is of the order of `‖Δz_k‖`: the factors are those of
/// the latest Newton iteration. From `(1 − θ)‖e‖ ≤ ‖δ‖` the error left after
/// applying `δ` is at most `θ/(1 − θ)·‖δ‖`, within the tolerance for
/// `θ ≤ ½` when `‖δ‖` is (the Newton–Kantorovich a-posteriori bound
/// `‖e‖ ≤ ‖J⁻¹‖‖G(z_{k+1})‖`, with `J_k`'s factors standing in for `J`'s).
/// The test reads the update itself, not a ratio of updates, so a first
/// update that removed mostly the multipliers' error (a fast first ratio,
/// see [`Contraction`]) cannot pass for convergence; it also asks that `δ`
/// be at most half of `Δz_k`, so that an iteration that is not contracting
/// never ends here. Written so that NaN never converges.
pub(super) fn full_newton_accepts_residual(update: f64, prev_update: f64, tolerance: f64) -> bool {
    update <= tolerance && update <= 0.5 * prev_update
}

/// Contraction rate above which an iteration on factors from an earlier
/// iterate (simplified Newton) triggers a fresh Jacobian.
const REFRESH_RATE: f64 = 0.5;
/// Contraction rate above which the stage-decoupled matrix gives way to the
/// exact one: a refresh cannot speed it up (the couplings it drops set the
/// rate), and at 1/8 per update it still needs no more iterations than the
/// exact matrix's factorization costs.
const DECOUPLED_RATE: f64 = 0.125;

/// Whether an iteration on factors from an earlier iterate is too slow to
/// keep: it grows, contracts slower than its limit, or too slowly to reach
/// `tolerance` within the `remaining` iterations. The stage-decoupled matrix
/// is judged on the rate it keeps to over two updates (one ratio says
/// little) against `DECOUPLED_RATE`, and gives way to the exact matrix: a
/// refresh of it cannot change the rate its dropped couplings set. A
/// refresh, rather than crawling into `MaxIterations`, keeps simplified
/// Newton from reporting a divergence that full Newton would not have.
pub(crate) fn too_slow(
    monitor: &Contraction,
    decoupled: bool,
    update: f64,
    rate: f64,
    remaining: i32,
    tolerance: f64,
) -> bool {
    let (judged, limit) = if decoupled { (monitor.sustained(), DECOUPLED_RATE) } else { (rate, REFRESH_RATE) };
    // `judged` is NaN until the factors have a rate: then the last test is
    // false, and the power is not worth taking.
    rate.is_nan()
        || rate >= 1.0
        || judged > limit
        || (!judged.is_nan() && update * power(judged, remaining + 1) / (1.0 - judged) > tolerance)
}

/// `x^k` for `k ≥ 0` by repeated squaring, inline: `f64::powi` with an
/// exponent known only at run time is a library call, which the lane
/// kernel would make once per lane and update.
#[inline(always)]
fn power(mut x: f64, mut k: i32) -> f64 {
    let mut r = 1.0;
    while k > 0 {
        if k & 1 == 1 {
            r *= x;
        }
        k >>= 1;
        if k > 0 {
            x *= x;
        }
    }
    r
}

/// Whether an update `update`, computed with factors of the Newton matrix
/// at the iterate it starts from, ends the solve because the step's
/// equations are affine in what it moved: for every pair of
/// [`Nonlinearity::pairs`], the update of one of its two groups is within
/// `tolerance` (scaled by `weights`, as [`weighted_update_norm`](crate::linalg::weighted_update_norm)
/// measures updates). The update of the stage-decoupled matrix
/// (`decoupled`, for a system whose structure facts leave it only the force
/// terms to drop) must also be within it on the coordinates whose columns
/// that matrix approximates: those of [`Nonlinearity::constraint_force_columns`],
/// and of [`Nonlinearity::stiffness_columns`] unless it keeps the stiffness
/// (`stiffness_kept`). The layout of the unknowns is
/// `z = [V_1..V_S | μ_1..μ_S | v₁]`.
///
/// # Why such an update ends the solve
/// Let `C` be the groups whose update is within the tolerance and `A` the
/// rest. No pair lies within `A`, so the residual's second derivative
/// `G''[x, y]` vanishes for `x`, `y` both in `A`, at every point. With
/// `Δ = Δ_C + Δ_A` the update from `z`, Taylor's formula leaves
/// `G(z + Δ) = G(z) + J(z)Δ + R`, `|R| ≤ ½‖G''‖·‖Δ_C‖·(‖Δ_C‖ + 2‖Δ_A‖)`.
/// The matrix `F` of the update has the exact Jacobian's columns in `A`
/// (the exact matrix always; the stage-decoupled one when every column it
/// approximates lies in `C`), so `JΔ = FΔ + (J − F)Δ_C = −G(z) + (J − F)Δ_C`
/// and the new iterate's error is `J⁻¹G(z + Δ) = J⁻¹(R + (J − F)Δ_C)`:
/// at most `θ·‖Δ_C‖` with `θ = O(‖J⁻¹‖‖G''‖‖Δ‖)` Newton's contraction (and,
/// for the stage-decoupled matrix, its own `O(h²)` one). So the error left
/// is below the tolerance whenever the iteration contracts, by the same
/// argument that lets an update within the tolerance end the solve — but
/// here only the curved part of the update has to be that small: the
/// affine part is solved exactly, up to round-off.
///
/// That round-off is the rounding of `G(z)`, whose terms are as large as
/// the iterate `z` the update starts from, carried through `J⁻¹`. An update
/// that moves the unknowns by more than their own size (a scaled entry
/// above [`LANDING_LIMIT`]) starts where those terms are larger than at the
/// solution, and `J⁻¹` amplifies their rounding by up to `J`'s condition
/// number, which grows like `h²`: the belt skate of
/// `spark-runtime/tests/integration/landing.rs`, one cold Gauss step with
/// a first update of 11 at `h = 30`, landed `3.5e-12` from the root of its
/// equations and, with an update of 5.8e3 at `h = 1e4`, `2.5e-6` from it;
/// a confirming update, which evaluates `G` at the new iterate, reaches
/// the root to round-off. Such an update does not end the solve: the next
/// one confirms it.
///
/// Such updates occur where the starting guess is within round-off in the
/// groups the equations are curved in: the heading of the skate (§8.2) and
/// of a rolling disk, whose rates are constant, or every group of a system
/// whose equations are affine altogether (no pairs).
#[inline]
pub(crate) fn affine_along<const N: usize, const M: usize, const S: usize, const D: usize>(
    (update, norm): (&Vector<D>, f64),
    weights: &Vector<D>,
    tolerance: f64,
    nonlinearity: &Nonlinearity,
    plan: &AffinePlan,
) -> bool {
    // `norm` is the update's largest scaled entry, `max_i |Δz_i|·w_i` with
    // these weights (NaN if any is), which the iteration has measured
    // already: within the limit exactly when every entry is.
    norm <= LANDING_LIMIT
        && affine_along_by::<N, M, S>(|i| moved_beyond(update[i], weights[i], tolerance), nonlinearity, plan)
}

/// Largest scaled entry `|Δz_i|·w_i` of an update that [`affine_along`]
/// lets end a solve: beyond it the rounding of the residual at the
/// iterate the update starts from, whose terms grow with the distance to
/// the solution, is no longer that of a converged iterate (see
/// [`affine_along`]).
pub(crate) const LANDING_LIMIT: f64 = 1.0;

/// Whether an update entry `delta` with weight `weight` moved its unknown
/// beyond `tolerance` ([`affine_along`]'s measure; NaN counts as moved).
#[inline(always)]
pub(crate) fn moved_beyond(delta: f64, weight: f64, tolerance: f64) -> bool {
    let scaled = delta.abs() * weight;
    scaled > tolerance || scaled.is_nan()
}

/// [`affine_along`] with the update read through `moved_at(i)`: whether
/// unknown `i` moved beyond the tolerance ([`moved_beyond`]). The lane
/// kernel reads its lanes' updates in place through it. `plan` is
/// [`AffinePlan::new`] of the same `nonlinearity` and matrix.
#[inline]
pub(crate) fn affine_along_by<const N: usize, const M: usize, const S: usize>(
    moved_at: impl Fn(usize) -> bool,
    nonlinearity: &Nonlinearity,
    plan: &AffinePlan,
) -> bool {
    let moved = |group: u32| {
        let group = group as usize;
        if group < N {
            (0..S).any(|i| moved_at(i * N + group)) || moved_at(S * (N + M) + group)
        } else {
            let j = group - N;
            j >= M || (0..S).any(|i| moved_at(S * N + i * M + j))
        }
    };
    let Some(required) = plan.required else {
        let still = |columns: &[u32]| columns.iter().all(|&c| !moved(c));
        return nonlinearity.pairs.iter().all(|&(a, b)| !moved(a) || !moved(b))
            && (!plan.decoupled
                || (still(nonlinearity.constraint_force_columns)
                    && (plan.stiffness_kept || still(nonlinearity.stiffness_columns))));
    };
    // The required groups one by one (a constant of the stepper, so the
    // loop unrolls), then the pairs none of them holds.
    let mut left = required;
    while left != 0 {
        if moved(left.trailing_zeros()) {
            return false;
        }
        left &= left - 1;
    }
    let held = |group: u32| (required >> group) & 1 == 1;
    !plan.free_pairs || nonlinearity.pairs.iter().all(|&(a, b)| held(a) || held(b) || !moved(a) || !moved(b))
}

/// [`affine_along_by`] for `W` lanes at once: `moved_at(i)` gives, lane by
/// lane, whether unknown `i` moved beyond the tolerance, and lane `w` of
/// the result is `affine_along_by` of lane `w`'s entries. The lane kernel
/// asks it of every lane after its first update; the masks of a group's
/// rows combine as vectors, and the test ends at the first required group
/// that every lane moved (on a system curved in every coordinate, the
/// first one read), where a lane-by-lane test pays its calls and branches
/// in each lane.
#[inline(always)]
pub(crate) fn affine_along_lanes<const N: usize, const M: usize, const S: usize, const W: usize>(
    moved_at: impl Fn(usize) -> [bool; W],
    nonlinearity: &Nonlinearity,
    plan: &AffinePlan,
) -> [bool; W] {
    let Some(required) = plan.required else {
        return std::array::from_fn(|w| affine_along_by::<N, M, S>(|i| moved_at(i)[w], nonlinearity, plan));
    };
    let either = |a: [bool; W], b: [bool; W]| -> [bool; W] { std::array::from_fn(|w| a[w] | b[w]) };
    let moved = |group: u32| -> [bool; W] {
        let group = group as usize;
        if group < N {
            (0..S).fold(moved_at(S * (N + M) + group), |m, i| either(m, moved_at(i * N + group)))
        } else {
            let j = group - N;
            if j >= M {
                [true; W]
            } else {
                (0..S).fold([false; W], |m, i| either(m, moved_at(S * N + i * M + j)))
            }
        }
    };
    let mut lands = [true; W];
    let mut left = required;
    while left != 0 {
        let m = moved(left.trailing_zeros());
        for w in 0..W {
            lands[w] &= !m[w];
        }
        if !lands.contains(&true) {
            return lands;
        }
        left &= left - 1;
    }
    if plan.free_pairs {
        let held = |group: u32| (required >> group) & 1 == 1;
        for &(a, b) in nonlinearity.pairs.iter().filter(|&&(a, b)| !held(a) && !held(b)) {
            let (ma, mb) = (moved(a), moved(b));
            for w in 0..W {
                lands[w] &= !(ma[w] & mb[w]);
            }
        }
    }
    lands
}

/// [`affine_along`]'s test worked out from the pairs and columns alone,
/// once per system and matrix (the stepper keeps it as a constant): the
/// groups whose update must be within the tolerance — both groups of a pair
/// `(a, a)`, and the columns the stage-decoupled matrix approximates — and
/// whether some pair holds none of them and is tested as a pair. Any pair
/// with a required group is met exactly when that group is still, so the
/// test reads each required group once instead of once per pair (the
/// skate's heading is in four pairs and the matrix's one column).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct AffinePlan {
    /// Bit `g` for each required group; `None` when a group lies outside
    /// `N + M ≤ 64` bits or outside the layout, and the pairs and columns
    /// are tested as they are.
    required: Option<u64>,
    /// Some pair holds no required group.
    free_pairs: bool,
    /// The matrix is the stage-decoupled one.
    decoupled: bool,
    /// The stage-decoupled matrix keeps the stiffness.
    stiffness_kept: bool,
    /// Bit `c` for each coordinate whose rounded positions an update that
    /// lands must not move by more than it accounts for
    /// ([`Self::keeps_position`]).
    positions: u64,
}

impl AffinePlan {
    /// For a system without a declared nonlinearity, which never asks.
    pub(crate) const UNUSED: Self =
        AffinePlan { required: None, free_pairs: true, decoupled: false, stiffness_kept: false, positions: u64::MAX };

    /// The plan for `nonlinearity` on the exact matrix or (`decoupled`) the
    /// stage-decoupled one, which keeps the stiffness when `stiffness_kept`.
    pub(crate) const fn new<const N: usize, const M: usize>(
        nonlinearity: &Nonlinearity,
        decoupled: bool,
        stiffness_kept: bool,
    ) -> Self {
        let general = AffinePlan { required: None, free_pairs: true, decoupled, stiffness_kept, positions: u64::MAX };
        let groups = N + M;
        if groups > 64 {
            return general;
        }
        let pairs = nonlinearity.pairs;
        // The groups curved in themselves.
        let mut self_pairs = 0u64;
        let mut k = 0;
        while k < pairs.len() {
            let (a, b) = pairs[k];
            if a as usize >= groups || b as usize >= groups {
                return general;
            }
            if a == b {
                self_pairs |= 1 << a;
            }
            k += 1;
        }
        let (Some(constraint_force), Some(stiffness)) = (
            column_bits(nonlinearity.constraint_force_columns, groups),
            column_bits(nonlinearity.stiffness_columns, groups),
        ) else {
            return general;
        };
        let approximated = if !decoupled {
            0
        } else if stiffness_kept {
            constraint_force
        } else {
            constraint_force | stiffness
        };
        let required = self_pairs | approximated;
        let mut free_pairs = false;
        let mut k = 0;
        while k < pairs.len() {
            let (a, b) = pairs[k];
            if (required >> a) & 1 == 0 && (required >> b) & 1 == 0 {
                free_pairs = true;
            }
            k += 1;
        }
        // The coordinates curved in themselves and those whose positions
        // enter the forces or the constraint forces (and so, for `k`
        // linear in `v`, the constraints): groups `0..N` only.
        let coordinates = if N >= 64 { u64::MAX } else { (1 << N) - 1 };
        let positions = (self_pairs | constraint_force | stiffness) & coordinates;
        AffinePlan { required: Some(required), free_pairs, decoupled, stiffness_kept, positions }
    }

    /// Whether an update that lands must be checked for how it moved the
    /// rounded positions of coordinate `c` ([`rounding_moved`]): `c` is
    /// curved in itself (a pair `(c, c)`) or its position enters the forces
    /// or the constraint forces ([`Nonlinearity::stiffness_columns`],
    /// [`Nonlinearity::constraint_force_columns`]); every coordinate when
    /// the plan tests the pairs as they are.
    #[inline(always)]
    pub(crate) fn keeps_position(&self, c: usize) -> bool {
        c >= 64 || (self.positions >> c) & 1 == 1
    }
}

/// The bits of the groups in `columns`, `None` when one lies outside
/// `groups`.
const fn column_bits(columns: &[u32], groups: usize) -> Option<u64> {
    let mut bits = 0u64;
    let mut k = 0;
    while k < columns.len() {
        if columns[k] as usize >= groups {
            return None;
        }
        bits |= 1 << columns[k];
        k += 1;
    }
    Some(bits)
}

/// Whether an update that [`affine_along`] lets land moved a rounded
/// position by more than it accounts for, beyond the tolerance: `old` and
/// `new` are a coordinate's position at one evaluated point before and
/// after the update, `shift = Σ_j (h c_j) Δ_j` the update's exact shift of
/// it (`new ≈ old − shift`), and `weight` the largest weight of the
/// coordinate's stage velocities, with which the difference is scaled like
/// an update entry.
///
/// [`affine_along`] bounds the new iterate's error in exact arithmetic. A
/// stage velocity that moved far below the tolerance still shifts the
/// points `Q_j = q₀ + hΣa_jk V_k` and `q₁`, and a shift of 1e-17 can move a
/// rounded coordinate by a whole ulp, which the update did not account
/// for. The constraints see positions at their points with coefficients of
/// the size of the velocities' (`∂k/∂q` against `∂k/∂v`), so such a move
/// leaves the stored state off the solution by about an ulp of the
/// coordinate in the velocities: at a rolling disk's heading θ ≈ 5·10⁴
/// (ulp 7e-12) such a move leaves its constraint at `|φ̇|·ulp(θ) ≈ 1e-11`.
/// A coordinate below about 16 moves by an ulp within the tolerance
/// (16ε), so the test lets its update land.
#[inline(always)]
pub(crate) fn rounding_moved(old: f64, new: f64, shift: f64, weight: f64, tolerance: f64) -> bool {
    if old.to_bits() == new.to_bits() {
        return false;
    }
    let scaled = ((new - old) + shift).abs() * weight;
    scaled > tolerance || scaled.is_nan()
}
