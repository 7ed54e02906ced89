//! The starting guess of a step's Newton iteration: extrapolated from the
//! solutions of the previous steps when the step continues them, otherwise
//! from the consistent acceleration at the step's start.

use super::Stepper;
use crate::initial::consistent_acceleration_in;
use crate::system::{NonholonomicSystem, StageValues, Vector};
use crate::State;

/// How many previous solutions the starting-guess extrapolation keeps.
pub(crate) const PAST: usize = 4;

/// Newton backward differences: the extrapolation of degree `d` from the
/// `d + 1` latest solutions takes row `d − 1`, most recent solution first.
pub(crate) const EXTRAPOLATION: [[f64; PAST]; PAST - 1] =
    [[2.0, -1.0, 0.0, 0.0], [3.0, -3.0, 1.0, 0.0], [4.0, -6.0, 4.0, -1.0]];

/// The previous steps, kept for extrapolating the next starting guess.
///
/// Updated in place after every step (a ring of the last solutions, not a
/// shifted array rebuilt per step: that copy was `PAST·D` doubles).
#[derive(Clone, Copy, Debug)]
pub(super) struct Warm<const N: usize, const D: usize> {
    pub(super) h: f64,
    /// Where the latest of these steps ended.
    pub(super) end: State<N>,
    /// Solutions `z` of the last `depth` consecutive steps of size `h`; the
    /// most recent is `past[head]`, the one before `past[(head + 1) % PAST]`.
    pub(super) past: [Vector<D>; PAST],
    pub(super) head: usize,
    pub(super) depth: usize,
}

impl<const N: usize, const D: usize> Warm<N, D> {
    /// The `k`-th most recent solution (`k < depth`).
    pub(super) fn back(&self, k: usize) -> &Vector<D> {
        &self.past[(self.head + k) % PAST]
    }

    /// Keeps the solution `z` of the step of size `h` from `start` to `end`:
    /// in the ring of `warm` when the step continues it with the same `h`,
    /// otherwise as the first solution of a new ring.
    pub(super) fn remember(warm: &mut Option<Self>, start: &State<N>, end: State<N>, h: f64, z: Vector<D>) {
        match warm.as_mut().filter(|w| w.end == *start && w.h == h) {
            Some(w) => {
                w.head = (w.head + PAST - 1) % PAST;
                w.past[w.head] = z;
                w.depth = (w.depth + 1).min(PAST);
                w.end = end;
            }
            None => {
                let mut past = [Vector::<D>::zeros(); PAST];
                past[0] = z;
                *warm = Some(Warm { h, end, past, head: 0, depth: 1 });
            }
        }
    }
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// The starting guess. When this step continues earlier steps of the
    /// same size, the stage unknowns are extrapolated across steps by the
    /// polynomial through the last solutions (the stage values are smooth
    /// functions of `t₀` for fixed `h`, whatever the method's stage order:
    /// for Lobatto IIIA-B, `V₁ = V₂ ≈ v(t₀ + h/2)` is not `v` at the nodes).
    /// After a change of step size, the interpolating polynomial through the
    /// previous stage values at the nodes `c_j` is evaluated at the new nodes.
    /// Without a previous step: `V_i = v₀ + c_i h a₀`, `Ψ_i = ψ₀` from the
    /// consistent acceleration and multiplier.
    pub(super) fn starting_guess(&mut self, state: &State<N>, h: f64) -> (Vector<D>, bool) {
        let c = &self.tableau.c;
        let mut z = Vector::<D>::zeros();
        if let Some(w) = self.warm.as_ref().filter(|w| self.options.warm_start && w.end == *state) {
            if w.h == h && w.depth >= 2 {
                let degree = (w.depth - 1).min(self.options.extrapolation_degree.clamp(1, PAST - 1));
                for (k, coef) in EXTRAPOLATION[degree - 1].iter().enumerate().take(degree + 1) {
                    z += *coef * w.back(k);
                }
                return (z, true);
            }
            let r = h / w.h;
            if r.abs() <= 4.0 {
                // Interpolating polynomial through the previous stage values
                // (nodes c_j in units of the previous step), evaluated at the
                // new stage times θ = 1 + c_i r and at the new end θ = 1 + r.
                let lagrange = |theta: f64, j: usize| -> f64 {
                    let mut l = 1.0;
                    for k in 0..S {
                        if k != j {
                            l *= (theta - c[k]) / (c[j] - c[k]);
                        }
                    }
                    l
                };
                let distinct = (0..S).all(|j| (0..j).all(|k| c[k] != c[j]));
                let last = w.back(0);
                for i in 0..=S {
                    let theta = if i < S { 1.0 + c[i] * r } else { 1.0 + r };
                    let mut vi = Vector::<N>::zeros();
                    let mut mi = Vector::<M>::zeros();
                    for j in 0..S {
                        let l = if distinct { lagrange(theta, j) } else { 1.0 / S as f64 };
                        vi += l * last.fixed_rows::<N>(j * N);
                        mi += l * last.fixed_rows::<M>(S * N + j * M);
                    }
                    if i < S {
                        z.fixed_rows_mut::<N>(i * N).copy_from(&vi);
                        // μ = hΨ: rescale to the new step size.
                        z.fixed_rows_mut::<M>(S * N + i * M).copy_from(&(mi * r));
                    } else {
                        z.fixed_rows_mut::<N>(S * (N + M)).copy_from(&vi);
                    }
                }
                return (z, true);
            }
        }
        // Scratch: the work storage's end-point Jacobians (heap, so no N×N
        // matrix goes on the stack); every full evaluation rewrites them
        // before the Newton matrix reads them.
        let mut vals = StageValues::zeros();
        let (a0, psi0) =
            consistent_acceleration_in(&self.system, state.t, &state.q, &state.v, &mut vals, &mut self.work.end)
                .unwrap_or((Vector::zeros(), Vector::zeros()));
        for i in 0..S {
            z.fixed_rows_mut::<N>(i * N).copy_from(&(state.v + (c[i] * h) * a0));
            z.fixed_rows_mut::<M>(S * N + i * M).copy_from(&(psi0 * h));
        }
        z.fixed_rows_mut::<N>(S * (N + M)).copy_from(&(state.v + h * a0));
        (z, false)
    }
}
