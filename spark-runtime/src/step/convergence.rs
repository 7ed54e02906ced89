//! Newton's stopping rule: the contraction monitor of simplified Newton
//! and full Newton's rule, on the scaled update norms of
//! [`scaled_update_norm`](crate::linalg::scaled_update_norm).

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
/// against `θ = 3.5e-3`. A rate is *earned* from the third update on: the
/// largest ratio on these factors so far, so that no fast ratio can stand
/// for the contraction alone. The ratios of one linear iteration need not
/// decrease: on the stage-decoupled matrix (McLachlan–Perlmutter particles,
/// Gauss s = 2, h = 0.2) they ran 6.2e-3, 1.5e-3, 4.4e-2, 9.2e-3, 3.3e-3, and
/// the larger of the last two alone left an error 5× the tolerance.
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
}

impl Contraction {
    /// No update on the current factors yet.
    pub(crate) const FRESH: Self =
        Contraction { updates: 0, last: f64::NAN, rate: f64::NAN, prev_rate: f64::NAN, max_rate: f64::NAN };

    /// Records the scaled norm of an update computed with the current
    /// factors; returns its ratio to the previous one on them (NaN for the
    /// first).
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
    /// once three updates on them exist (NaN before).
    pub(crate) fn earned(&self) -> f64 {
        if self.updates >= 3 {
            self.max_rate
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
    pub(crate) fn converged(&self, update: f64, tolerance: f64) -> bool {
        let theta = self.earned();
        update <= tolerance || (theta < 1.0 && update * theta / (1.0 - theta) <= tolerance)
    }

    /// The stopping rule of the solve's mode: [`Self::converged`] for
    /// simplified Newton, [`full_newton_converged`] on the latest ratio
    /// `rate` for full Newton.
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
