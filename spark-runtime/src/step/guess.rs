//! The starting guess of a step's Newton iteration: extrapolated from the
//! solutions of the previous steps when the step continues them, otherwise
//! from the consistent acceleration at the step's start.

use super::Stepper;
use crate::initial::consistent_acceleration_in;
use crate::system::{NonholonomicSystem, StageValues, Vector};
use crate::tableau::{Method, Tableau};
use crate::State;

/// The highest degree of the extrapolation across steps.
pub(crate) const MAX_EXTRAPOLATION_DEGREE: usize = 5;

/// How many previous solutions the starting-guess ring holds: at least the
/// `d + 1` it extrapolates at degree `d ≤ MAX_EXTRAPOLATION_DEGREE` and the
/// one before them, whose end velocity is the oldest one's start velocity;
/// rounded up to a power of two, so that an index into the ring is a mask
/// (a remainder by 7 cost the skate's Gauss s = 1 step ≈ 110 instructions
/// of its 3244).
pub(crate) const PAST: usize = (MAX_EXTRAPOLATION_DEGREE + 2).next_power_of_two();

/// The degree a step falls back to when Newton fails from a guess of higher
/// degree (`Stepper::step`): the highest that no measured step size made
/// worse than a lower one (docs/performance/README.md, "The starting
/// guess").
pub(crate) const SAFE_EXTRAPOLATION_DEGREE: usize = 3;

/// The contraction rates (`Warm::rate`, the largest ratio of consecutive
/// updates a step took on its final factors) after which the next step of
/// the same size extrapolates above [`SAFE_EXTRAPOLATION_DEGREE`]. Above
/// the bound the guess across steps is poor: the rate grows with `h` as
/// the extrapolation's quality falls, and on the McLachlan–Perlmutter
/// particles degree 5 takes more updates than degree 3 where the
/// stage-decoupled rates run at 2e-2 to 0.3 (h = 0.3, 0.6), fewer where
/// they stay below 1e-2 (h ≤ 0.1; the particle at h ≤ 0.2). No lower
/// bound: a step that converged in one update has a round-off rate (the
/// skate's are 1e-16 to 1e-11) and a closer guess saves it nothing, but
/// members of one lane group whose rates straddle such a bound would
/// extrapolate at different degrees, which the lane kernel does lane by
/// lane (Fig. 8.4's LDA ensembles took half as long again). NaN (no rate
/// earned, or a step that ended on fresh factors) is outside.
pub(crate) const HIGH_DEGREE_RATES: std::ops::RangeInclusive<f64> = 0.0..=1e-2;

/// The degree of the extrapolation across steps from `depth` solutions in
/// the ring: at most `configured`, and at most
/// [`SAFE_EXTRAPOLATION_DEGREE`] unless the previous step's rate
/// `prior_rate` is in [`HIGH_DEGREE_RATES`]. The lane kernel chooses its
/// lanes' degrees with this function too.
#[inline(always)]
pub(crate) fn extrapolation_degree(depth: usize, configured: usize, prior_rate: f64) -> usize {
    let limit =
        if HIGH_DEGREE_RATES.contains(&prior_rate) { configured } else { configured.min(SAFE_EXTRAPOLATION_DEGREE) };
    (depth - 2).min(limit.clamp(1, MAX_EXTRAPOLATION_DEGREE))
}

/// Newton backward differences: the extrapolation of degree `d` from the
/// `d + 1` latest solutions takes row `d`, most recent solution first.
pub(crate) const EXTRAPOLATION: [[f64; MAX_EXTRAPOLATION_DEGREE + 1]; MAX_EXTRAPOLATION_DEGREE + 1] = [
    [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [2.0, -1.0, 0.0, 0.0, 0.0, 0.0],
    [3.0, -3.0, 1.0, 0.0, 0.0, 0.0],
    [4.0, -6.0, 4.0, -1.0, 0.0, 0.0],
    [5.0, -10.0, 10.0, -5.0, 1.0, 0.0],
    [6.0, -15.0, 20.0, -15.0, 6.0, -1.0],
];

/// The starting guess of a Gauss step that continues a step of the same
/// size: the polynomial through the previous step's start velocity `v₀`, its
/// stage velocities `V_j` and end velocity `v₁` (nodes `0, c_1…c_S, 1`, in
/// units of `h`), evaluated at the new nodes `1 + c_i` and the new end `2`;
/// the multipliers `μ_i` from the polynomial through the previous `μ_j` at
/// `c_j`. It uses `S + 2` velocities of one step where extrapolation across
/// steps uses one value per step: on the McLachlan–Perlmutter particles at
/// h = 0.05 it is 51× (s = 3) and 1100× (s = 4) closer to the solution than
/// extrapolating the velocities at degree 2 (docs/performance/README.md,
/// "The starting guess"). Only Gauss methods with `S ≥ 3`:
/// there `V_i` approximates
/// `v(t₀ + c_i h)` and the nodes are distinct; the Lobatto families' stage
/// velocities are not velocities at their nodes.
///
/// The weights are computed once per tableau and applied in one fixed
/// order, which the lane kernel repeats operation for operation.
#[derive(Clone, Copy, Debug)]
pub(crate) struct StepPolynomial<const S: usize> {
    /// Weights of the increments `v₀ − v₁` and `V_j − v₁` of the previous
    /// step (from its end velocity `v₁`, the new step's start) in the new
    /// `V_i − v₁`: the Lagrange basis at `1 + c_i` of the nodes `0`, the
    /// `c_j` and `1` (whose own increment is 0).
    pub(crate) stage_from_start: [f64; S],
    pub(crate) stage_from_stages: [[f64; S]; S],
    /// The same for the new end velocity, at `2`.
    pub(crate) end_from_start: f64,
    pub(crate) end_from_stages: [f64; S],
    /// Weights of the previous `μ_j` in the new `μ_i`.
    pub(crate) multipliers: [[f64; S]; S],
}

impl<const S: usize> StepPolynomial<S> {
    /// The weights for `tab`, or `None` unless it is a Gauss method with
    /// `S ≥ 3` distinct nodes inside `(0, 1)`. For `S ≤ 2` the polynomial
    /// (a cubic at most) is no closer than extrapolating the increments
    /// across steps at degree 3: on the particle at h = 0.2, Gauss s = 2
    /// takes 4.62 stage-decoupled updates per step from it against 4.10.
    pub(crate) fn new(tab: &Tableau<S>) -> Option<Self> {
        let c = &tab.c;
        let inside = c.iter().all(|&ci| ci > 0.0 && ci < 1.0);
        let distinct = (0..S).all(|j| (0..j).all(|k| c[k] != c[j]));
        if tab.method != Method::Gauss || S < 3 || !inside || !distinct {
            return None;
        }
        // Nodes 0, c_1…c_S, 1; node k's Lagrange basis polynomial at θ.
        let node = |k: usize| match k {
            0 => 0.0,
            k if k <= S => c[k - 1],
            _ => 1.0,
        };
        let basis = |theta: f64, k: usize| {
            (0..S + 2).filter(|&m| m != k).fold(1.0, |l, m| l * (theta - node(m)) / (node(k) - node(m)))
        };
        let stage_basis =
            |theta: f64, j: usize| (0..S).filter(|&m| m != j).fold(1.0, |l, m| l * (theta - c[m]) / (c[j] - c[m]));
        let mut p = StepPolynomial {
            stage_from_start: [0.0; S],
            stage_from_stages: [[0.0; S]; S],
            end_from_start: basis(2.0, 0),
            end_from_stages: [0.0; S],
            multipliers: [[0.0; S]; S],
        };
        for i in 0..S {
            let theta = 1.0 + c[i];
            p.stage_from_start[i] = basis(theta, 0);
            for j in 0..S {
                p.stage_from_stages[i][j] = basis(theta, j + 1);
                p.multipliers[i][j] = stage_basis(theta, j);
            }
            p.end_from_stages[i] = basis(2.0, i + 1);
        }
        Some(p)
    }

    /// The starting guess after the solution `last`, whose step began with
    /// the end velocity of the solution `before` (`D = S(N+M)+N`, laid out
    /// as `z`).
    pub(crate) fn predict<const N: usize, const M: usize, const D: usize>(
        &self,
        last: &Vector<D>,
        before: &Vector<D>,
        z: &mut Vector<D>,
    ) {
        let end = S * (N + M);
        let (last, before, out) = (last.as_slice(), before.as_slice(), z.as_mut_slice());
        for i in 0..=S {
            let (from_start, from_stages, at) = if i < S {
                (self.stage_from_start[i], &self.stage_from_stages[i], i * N)
            } else {
                (self.end_from_start, &self.end_from_stages, end)
            };
            // As increments from the new start velocity `v₀ = last[end..]`
            // (the basis sums to 1): a velocity constant across the steps is
            // predicted exactly, so that an update can find the equations
            // affine along it (`convergence::affine_along`).
            for n in 0..N {
                let v0 = last[end + n];
                let mut acc = from_start * (before[end + n] - v0);
                for j in 0..S {
                    acc += from_stages[j] * (last[j * N + n] - v0);
                }
                out[at + n] = v0 + acc;
            }
        }
        for i in 0..S {
            for m in 0..M {
                let mut acc = 0.0;
                for j in 0..S {
                    acc += self.multipliers[i][j] * last[S * N + j * M + m];
                }
                out[S * N + i * M + m] = acc;
            }
        }
    }
}

/// The previous steps, kept for extrapolating the next starting guess: the
/// steps of the chain that ends where the stepper's latest step ended.
///
/// Updated in place after every step (a ring of the last solutions, not a
/// shifted array rebuilt per step: that copy would be `PAST·D` doubles).
#[derive(Clone, Copy, Debug)]
pub(super) struct Warm<const D: usize> {
    pub(super) h: f64,
    /// Solutions `z` of the last `depth` consecutive steps of size `h`; the
    /// most recent is `past[head]`, the one before `past[(head + 1) % PAST]`.
    pub(super) past: [Vector<D>; PAST],
    pub(super) head: usize,
    pub(super) depth: usize,
    /// The largest ratio of consecutive updates on the latest step's final
    /// factors (NaN for none, or for full Newton), and whether those were
    /// the stage-decoupled matrix's: the next step's floor under its
    /// contraction estimate ([`Contraction`](super::Contraction)).
    pub(super) rate: (f64, bool),
}

impl<const D: usize> Warm<D> {
    /// The `k`-th most recent solution (`k < depth`).
    pub(super) fn back(&self, k: usize) -> &Vector<D> {
        &self.past[(self.head + k) % PAST]
    }

    /// Keeps the solution `z` of a step of size `h`: in the ring of `warm`
    /// when the step `continues` its chain with the same `h`, otherwise as
    /// the first solution of a new ring.
    /// `rate`: what the step's solve earned on its final factors, and
    /// whether they were the stage-decoupled matrix's.
    #[inline(always)]
    pub(super) fn remember(warm: &mut Option<Self>, continues: bool, h: f64, z: Vector<D>, rate: (f64, bool)) {
        match warm.as_mut().filter(|w| continues && w.h == h) {
            Some(w) => {
                w.head = (w.head + PAST - 1) % PAST;
                w.past[w.head] = z;
                w.depth = (w.depth + 1).min(PAST);
                w.rate = rate;
            }
            None => {
                let mut past = [Vector::<D>::zeros(); PAST];
                past[0] = z;
                *warm = Some(Warm { h, past, head: 0, depth: 1, rate });
            }
        }
    }
}

/// A step's starting guess.
pub(super) struct Guess<const D: usize> {
    pub(super) z: Vector<D>,
    /// Whether it came from previous steps.
    pub(super) warm: bool,
    /// What the step it continues with the same `h` earned on its final
    /// factors and whether they were the stage-decoupled matrix's
    /// (`Warm::rate`; NaN when it continues none): simplified Newton's
    /// floor under its contraction estimate.
    pub(super) prior: (f64, bool),
    /// The degree of the extrapolation across steps it came from (0: none).
    pub(super) degree: usize,
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// The starting guess. When this step continues earlier steps of the
    /// same size, a Gauss step with `S ≥ 3` starts from the step polynomial
    /// ([`StepPolynomial`]); the other methods extrapolate across steps by
    /// the polynomial through the last solutions (the stage values are
    /// smooth functions of `t₀` for fixed `h`, whatever the method's stage
    /// order: for Lobatto IIIA-B, `V₁ = V₂ ≈ v(t₀ + h/2)` is not `v` at the
    /// nodes), the velocities as increments from the known start velocity
    /// (the multipliers `μ = hΨ` as they are).
    /// After a change of step size, the interpolating polynomial through the
    /// previous stage values at the nodes `c_j` is evaluated at the new nodes.
    /// Without a previous step: `V_i = v₀ + c_i h a₀`, `Ψ_i = ψ₀` from the
    /// consistent acceleration and multiplier.
    /// `continues`: the step starts where the latest one ended
    /// ([`Stepper::continues`]).
    pub(super) fn starting_guess(&mut self, state: &State<N>, h: f64, continues: bool) -> Guess<D> {
        self.starting_guess_up_to(state, h, self.options.extrapolation_degree, continues)
    }

    /// The guess of degree [`SAFE_EXTRAPOLATION_DEGREE`] at most, for a
    /// step solved again after Newton failed from a higher one
    /// (`Stepper::step`): out of line and cold, so that the hot path keeps
    /// the one inlined copy of the guess.
    #[cold]
    #[inline(never)]
    pub(super) fn safe_degree_guess(&mut self, state: &State<N>, h: f64, continues: bool) -> Guess<D> {
        self.starting_guess_up_to(state, h, SAFE_EXTRAPOLATION_DEGREE, continues)
    }

    /// The starting guess again, for a step solved again by full Newton
    /// after simplified Newton's factors at it contracted too slowly
    /// (`Stepper::step`): out of line and cold, as
    /// [`safe_degree_guess`](Self::safe_degree_guess).
    #[cold]
    #[inline(never)]
    pub(super) fn repeated_guess(&mut self, state: &State<N>, h: f64, continues: bool) -> Guess<D> {
        self.starting_guess_up_to(state, h, self.options.extrapolation_degree, continues)
    }

    /// The guess of a step that continues none, from the consistent
    /// acceleration at its start, for a step solved again after Newton
    /// failed from a guess extrapolated across steps (`Stepper::step`): out
    /// of line and cold, as [`safe_degree_guess`](Self::safe_degree_guess).
    #[cold]
    #[inline(never)]
    pub(super) fn cold_guess(&mut self, state: &State<N>, h: f64) -> Guess<D> {
        self.starting_guess_up_to(state, h, SAFE_EXTRAPOLATION_DEGREE, false)
    }

    /// [`starting_guess`](Self::starting_guess) with the extrapolation
    /// across steps at degree `max_degree` at most. Inlined into both its
    /// callers (a second, cold caller would otherwise leave it out of line,
    /// its `D`-vector result copied on every step).
    #[inline(always)]
    pub(super) fn starting_guess_up_to(
        &mut self,
        state: &State<N>,
        h: f64,
        max_degree: usize,
        continues: bool,
    ) -> Guess<D> {
        let c = &self.tableau.c;
        let mut z = Vector::<D>::zeros();
        if let Some(w) = self.warm.as_ref().filter(|_| continues && self.options.warm_start) {
            let prior = if w.h == h { w.rate } else { (f64::NAN, false) };
            if w.h == h && w.depth >= 2 {
                if let Some(poly) = &self.step_polynomial {
                    poly.predict::<N, M, D>(w.back(0), w.back(1), &mut z);
                    return Guess { z, warm: true, prior, degree: 0 };
                }
                // The velocities' increments from the start velocity,
                // `V_i − v₀` and `v₁ − v₀`, are `O(h)`: extrapolated and added
                // to the known `v₀` they gain a power of `h` over the
                // velocities themselves. Step k's `v₀` is step k+1's `v₁`.
                let degree = extrapolation_degree(w.depth, max_degree, w.rate.0);
                let end = S * (N + M);
                let mut start = state.v;
                for (k, coef) in EXTRAPOLATION[degree].iter().enumerate().take(degree + 1) {
                    z += *coef * w.back(k);
                    start -= *coef * w.back(k + 1).fixed_rows::<N>(end);
                }
                for at in (0..S).map(|i| i * N).chain([end]) {
                    let mut v = z.fixed_rows_mut::<N>(at);
                    v += &start;
                }
                return Guess { z, warm: true, prior, degree };
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
                return Guess { z, warm: true, prior, degree: 0 };
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
        Guess { z, warm: false, prior: (f64::NAN, false), degree: 0 }
    }
}

#[cfg(test)]
mod tests {
    use super::{Warm, PAST};
    use crate::fixtures::paper::Particle;
    use crate::step::compensation::Compensation;
    use crate::tableau::{Method, Tableau};
    use crate::{State, Stepper, Vector};

    const N: usize = 3;
    const S: usize = 3;
    const D: usize = S * (N + 1) + N;

    /// A stepper of `method` whose warm start holds `past` (most recent
    /// first), the chain ending at velocity `v`.
    fn warm_stepper(method: Method, h: f64, v: Vector<N>, past: [Vector<D>; PAST]) -> Stepper<Particle, N, 1, S, D> {
        let mut stepper = Stepper::<Particle, N, 1, S, D>::new(Particle, Tableau::new(method).unwrap());
        let end = State::new(0.0, Vector::zeros(), v);
        stepper.warm = Some(Warm { h, past, head: 0, depth: PAST, rate: (f64::NAN, false) });
        stepper.compensation = Some(Compensation { end, carry: Vector::zeros() });
        stepper
    }

    fn assert_close(guess: &Vector<D>, expected: &Vector<D>) {
        for (g, x) in guess.iter().zip(expected.iter()) {
            assert!((g - x).abs() <= 1e-12 * (1.0 + x.abs()), "guess {guess:?}\nexpected {expected:?}");
        }
    }

    /// Extrapolation across steps (degree 2, Lobatto IIIA-B): exact when
    /// the velocities' increments from the start velocity and the
    /// multipliers are quadratic in the step index, although the start
    /// velocities themselves are cubic (so extrapolating the velocities
    /// themselves at degree 2 would not be).
    #[test]
    fn extrapolated_increments_are_exact_for_quadratic_increments() {
        let start = |m: f64| Vector::<N>::from_fn(|n, _| (n as f64 + 1.0) * m * m * m - 0.5 * m + n as f64);
        let increment = |i: usize, m: f64| 0.3 * (i as f64 + 1.0) * m * m - 0.2 * m + 0.1 * i as f64;
        let multiplier = |i: usize, m: f64| 0.05 * m * m + 0.7 * m - (i as f64);
        // The solution of the step with index m, which starts at start(m).
        let z = |m: f64| {
            let mut z = Vector::<D>::zeros();
            for i in 0..S {
                for n in 0..N {
                    z[i * N + n] = start(m)[n] + increment(i, m) * (n as f64 + 1.0);
                }
                z[S * N + i] = multiplier(i, m);
            }
            z.fixed_rows_mut::<N>(S * (N + 1)).copy_from(&start(m + 1.0));
            z
        };
        let past = std::array::from_fn(|k| z(-1.0 - k as f64));
        let mut stepper = warm_stepper(Method::LobattoIIIAB, 0.1, start(0.0), past);
        let super::Guess { z: guess, warm, .. } =
            stepper.starting_guess(&State::new(0.0, Vector::zeros(), start(0.0)), 0.1, true);
        assert!(warm);
        assert_close(&guess, &z(0.0));
    }

    /// The step polynomial (Gauss): exact when the velocities are a
    /// polynomial of degree `S + 1` in time and the multipliers one of
    /// degree `S − 1`.
    #[test]
    fn the_step_polynomial_is_exact_for_polynomial_velocities() {
        let h = 0.2;
        let tableau = Tableau::<S>::new(Method::Gauss).unwrap();
        let c = tableau.c;
        // Time in units of h, the new step on [0, 1].
        let velocity = |theta: f64| Vector::<N>::from_fn(|n, _| (theta + n as f64 * 0.3).powi(S as i32 + 1) - theta);
        let multiplier = |theta: f64| 0.4 * theta * theta - theta + 2.0;
        let z = |m: f64| {
            let mut z = Vector::<D>::zeros();
            for i in 0..S {
                z.fixed_rows_mut::<N>(i * N).copy_from(&velocity(m + c[i]));
                z[S * N + i] = multiplier(m + c[i]);
            }
            z.fixed_rows_mut::<N>(S * (N + 1)).copy_from(&velocity(m + 1.0));
            z
        };
        let past = std::array::from_fn(|k| z(-1.0 - k as f64));
        let mut stepper = warm_stepper(Method::Gauss, h, velocity(0.0), past);
        let super::Guess { z: guess, warm, .. } =
            stepper.starting_guess(&State::new(0.0, Vector::zeros(), velocity(0.0)), h, true);
        assert!(warm);
        assert_close(&guess, &z(0.0));
    }
}
