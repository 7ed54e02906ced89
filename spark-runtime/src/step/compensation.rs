//! Compensated summation of `q₁ = q₀ + hΣ_j b_j V_j` across steps: what a
//! step's `q₁` could not hold of its increment is carried to the next step.

use super::Stepper;
use crate::system::{NonholonomicSystem, Vector};
use crate::State;

/// Compensated summation of `q₁ = q₀ + hΣ_j b_j V_j` across steps (Hairer,
/// Lubich & Wanner, GNI §VIII.5): `carry` is exactly `(q₀ + Δq) − q₁` for the
/// step that ended at `end`, added to the next step's increment when that
/// step starts at `end`.
///
/// Why: with `h` far below `|q|`, the rounding of `q₀ + Δq` has the same
/// sign over long stretches of steps (the increments change slowly), so it
/// accumulates linearly. Measured on the skate (Lobatto IIIA-B s = 3,
/// T = 10): without the compensation and the separate summation of `Δq`
/// the global error grows ≈ 4e-16 per step, to 5e-11 after 131072 steps;
/// with both it stays ≈ 2e-15 to 5e-15 at any step count
/// (`examples/skate_drift.rs`).
#[derive(Clone, Copy, Debug)]
pub(super) struct Compensation<const N: usize> {
    /// The end of the step whose round-off `carry` holds.
    pub(super) end: State<N>,
    /// `(q₀ + Δq) − q₁` of that step.
    pub(super) carry: Vector<N>,
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    /// The compensation `state.q` carries when a step continues the latest
    /// one there, else zero.
    pub(super) fn carry_for(&self, state: &State<N>) -> Vector<N> {
        match self.compensation.as_ref().filter(|c| c.end == *state) {
            Some(c) => c.carry,
            None => Vector::zeros(),
        }
    }
}

/// `(a + b) − s` exactly for `s = fl(a + b)`, per component (Knuth's
/// TwoSum: no assumption on the magnitudes of `a` and `b`).
#[inline(always)]
pub(crate) fn two_sum_error<const N: usize>(a: &Vector<N>, b: &Vector<N>, s: &Vector<N>) -> Vector<N> {
    Vector::<N>::from_fn(|i, _| two_sum_error_of(a[i], b[i], s[i]))
}

/// [`two_sum_error`] of one component (the lane kernel applies it row by
/// row).
#[inline(always)]
pub(crate) fn two_sum_error_of(a: f64, b: f64, s: f64) -> f64 {
    let bb = s - a;
    (a - (s - bb)) + (b - bb)
}

/// Round-off over long runs (see [`Compensation`]).
#[cfg(test)]
mod drift_tests {
    use super::*;
    use crate::fixtures::paper::Skate;
    use crate::{Method, NewtonOptions, NoObserver, Observe, RunOptions, Schedule, Tableau};

    /// The skate from `q = 0`, `v = (0, 0, 1)` (β = π/2, unit parameters):
    /// `θ = t`, speed along the blade `sin t`, so `x = (1 − cos 2t)/4`,
    /// `y = t/2 − sin(2t)/4`.
    fn skate_exact(t: f64) -> (Vector<3>, Vector<3>) {
        let q = Vector::<3>::new((1.0 - (2.0 * t).cos()) / 4.0, t / 2.0 - (2.0 * t).sin() / 4.0, t);
        (q, Vector::<3>::new(t.sin() * t.cos(), t.sin() * t.sin(), 1.0))
    }

    /// 32768 steps of Lobatto IIIA-B s = 3 over T = 10 (truncation error
    /// ≈ 3e-16): the global error must stay at the round-off level of a
    /// random walk, `ε·√n·max|q|` ≈ 4e-13. Without the separate summation
    /// of the increment and its compensation, the rounding of
    /// `q₀ + hΣb_jV_j` accumulates linearly: 1.2e-11 here (measured
    /// 1.8e-15 / 1.6e-15 with them).
    #[test]
    fn long_fixed_step_runs_do_not_drift() {
        let (t_end, steps) = (10.0, 32768);
        let tab = Tableau::<3>::new(Method::LobattoIIIAB).unwrap();
        let mut st = Stepper::<_, 3, 1, 3, 15>::new(Skate::default(), tab);
        let (q0, v0) = skate_exact(0.0);
        let quiet = RunOptions {
            observe: Observe { energy: false, constraint_residual: false, multipliers: false },
            record_every: 0,
            ..RunOptions::default()
        };
        let schedule = Schedule::Fixed { h: t_end / steps as f64, steps };
        let end = st.integrate(0.0, &q0, &v0, schedule, &quiet, &mut NoObserver).unwrap().last().unwrap();
        let (q, v) = skate_exact(t_end);
        let bound = f64::EPSILON * (steps as f64).sqrt() * q.amax();
        let (eq, ev) = ((end.q - q).amax(), (end.v - v).amax());
        assert!(eq <= bound && ev <= bound, "error q {eq:.2e}, v {ev:.2e} above {bound:.2e}");
    }

    /// A step from a state other than the latest end carries nothing: the
    /// same step from the same state gives the same result whatever ran before
    /// (the warm start is off, so only the compensation could differ).
    #[test]
    fn compensation_applies_only_to_the_continued_state() {
        let tab = Tableau::<3>::new(Method::LobattoIIIAB).unwrap();
        let cold = NewtonOptions { warm_start: false, ..NewtonOptions::default() };
        let (q0, v0) = skate_exact(0.0);
        let start = State::new(0.0, q0, v0);
        let mut fresh = Stepper::<_, 3, 1, 3, 15>::new(Skate::default(), tab).with_options(cold);
        let mut used = fresh.clone();
        let mut s = start;
        for _ in 0..100 {
            s = used.step(&s, 0.01).unwrap().state;
        }
        let a = fresh.step(&start, 0.01).unwrap().state;
        let b = used.step(&start, 0.01).unwrap().state;
        assert_eq!(a, b);
    }

    #[test]
    fn two_sum_error_is_exact_whichever_operand_is_larger() {
        let a = Vector::<2>::new(1.0, 1e-17);
        let b = Vector::<2>::new(1e-17, 1.0);
        let s = a + b;
        assert_eq!(s, Vector::<2>::new(1.0, 1.0));
        assert_eq!(two_sum_error(&a, &b, &s), Vector::<2>::new(1e-17, 1e-17));
        // 1 + 2⁻⁵³ + 2⁻⁶⁰ rounds up to 1 + 2⁻⁵²: the error is −2⁻⁵³ + 2⁻⁶⁰.
        let (x, y) = (Vector::<1>::new(1.0), Vector::<1>::new(2f64.powi(-53) + 2f64.powi(-60)));
        let s = x + y;
        assert_eq!(s[0], 1.0 + f64::EPSILON);
        assert_eq!(two_sum_error(&x, &y, &s)[0], -(2f64.powi(-53)) + 2f64.powi(-60));
    }
}
