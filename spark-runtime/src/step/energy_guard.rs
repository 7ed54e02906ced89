//! The energy guard: refuses a step that violates a first integral the
//! structure facts guarantee (a sanity bound against unstable discrete
//! maps, not an accuracy control).

use crate::system::{ConstraintForm, NonholonomicSystem};
use crate::State;

/// Whether the energy `E = ∇_vL·v − L` is a first integral of the exact
/// flow, by the structure facts: `L` autonomous, constraints absent or
/// linear homogeneous in `v` (`k = K(t,q)v`, possibly rheonomic: the ideal
/// constraint force `−Kᵀψ` then does the work `−ψᵀk = 0`), no external force
/// and no non-ideal constraint force.
pub(crate) const fn energy_is_invariant<Sys, const N: usize, const M: usize>() -> bool
where
    Sys: NonholonomicSystem<N, M>,
{
    let st = Sys::STRUCTURE;
    st.lagrangian_autonomous
        && matches!(st.constraint_form, ConstraintForm::None | ConstraintForm::Linear)
        && !Sys::HAS_FORCING
        && !Sys::HAS_NONIDEAL_FORCE
}

/// The energy at the start of a chain of continued steps, against which the
/// guard measures drift.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct EnergyAnchor<const N: usize> {
    /// The end of the last accepted step of the chain (a step continues the
    /// chain when it starts there).
    pub(crate) end: State<N>,
    /// `E` there.
    pub(crate) energy: f64,
    /// `|E| + |p·v|` there: the energy's own size (`p·v = 2T` for a
    /// quadratic kinetic energy), the unit in which drift is measured.
    pub(crate) scale: f64,
}

impl<const N: usize> EnergyAnchor<N> {
    /// Whether the energy `e1` at the end of a step is within `limit` of
    /// this anchor's (with the round-off floor of [`check_energy`]); a NaN
    /// energy is not.
    #[inline(always)]
    pub(crate) fn holds(&self, e1: f64, limit: f64) -> bool {
        (e1 - self.energy).abs() <= limit * self.scale + 64.0 * f64::EPSILON * e1.abs()
    }

    /// An anchor at `state`.
    pub(crate) fn at<Sys, const M: usize>(sys: &Sys, state: &State<N>) -> Self
    where
        Sys: NonholonomicSystem<N, M>,
    {
        let energy = sys.energy(state.t, &state.q, &state.v);
        let pv = sys.momentum(state.t, &state.q, &state.v).dot(&state.v);
        EnergyAnchor { end: *state, energy, scale: energy.abs() + pv.abs() }
    }
}

/// Outcome of the energy guard for one step.
pub(crate) enum EnergyCheck<const N: usize> {
    /// Within the limit; the anchor to keep for the next step.
    Accept(EnergyAnchor<N>),
    /// `|E₁ − E_anchor| > limit · scale`: the anchor and `E₁`.
    Drift(EnergyAnchor<N>, f64),
}

/// Checks the end `end` of a step from `start` against the anchor of the
/// chain it continues (a new anchor at `start` when it continues none).
///
/// An anchor whose scale is zero (at rest where `E = 0`) measures nothing,
/// so the chain re-anchors at the next state instead. A round-off floor of
/// `64 ε |E₁|` keeps huge energy offsets from tripping the test.
///
/// `e1` is the energy at `end` when the caller has it already (as
/// [`NonholonomicSystem::energy`] computes it); `None` computes it here.
pub(crate) fn check_energy<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    anchor: Option<&EnergyAnchor<N>>,
    start: &State<N>,
    end: &State<N>,
    e1: Option<f64>,
    limit: f64,
) -> EnergyCheck<N>
where
    Sys: NonholonomicSystem<N, M>,
{
    let a = match anchor.filter(|a| a.end == *start && a.scale > 0.0) {
        Some(a) => *a,
        None => EnergyAnchor::at::<Sys, M>(sys, start),
    };
    if a.scale == 0.0 {
        return EnergyCheck::Accept(EnergyAnchor::at::<Sys, M>(sys, end));
    }
    let e1 = e1.unwrap_or_else(|| sys.energy(end.t, &end.q, &end.v));
    if a.holds(e1, limit) {
        EnergyCheck::Accept(EnergyAnchor { end: *end, ..a })
    } else {
        EnergyCheck::Drift(a, e1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::system::Vector;

    /// Lobatto IIIA-B treats `F` explicitly (Störmer–Verlet in the `p`
    /// part): on the particle (`ω = √2`) its map is unstable for `ω·h > 2`.
    #[test]
    fn energy_guard_refuses_an_unstable_map_and_nothing_else() {
        use crate::fixtures::paper::Particle;
        use crate::{Method, NewtonOptions, StepError, Stepper, Tableau};
        let start = State::new(0.0, Vector::<3>::new(1.0, 0.5, 0.0), Vector::<3>::zeros());
        let tab = Tableau::<2>::new(Method::LobattoIIIAB).unwrap();
        let e0 = Particle.energy(0.0, &start.q, &start.v);
        // ω·h = 4.2: refused within a few steps, with the drift in the error.
        let mut st = Stepper::<_, 3, 1, 2, 11>::new(Particle, tab);
        let mut s = start;
        let err = (0..10).find_map(|_| st.step(&s, 3.0).map(|r| s = r.state).err()).expect("refused");
        let StepError::EnergyDrift { energy, energy0, bound, .. } = err else { panic!("{err}") };
        let pv: f64 = 0.0; // v0 = 0
        assert!((energy - energy0).abs() > bound && bound == e0.abs() + pv && energy0 == e0, "{err}");
        // The same step with the guard off is a "success" with a blown-up energy.
        let off = NewtonOptions { energy_drift_limit: None, ..NewtonOptions::default() };
        let mut st = Stepper::<_, 3, 1, 2, 11>::new(Particle, tab).with_options(off);
        let s = st.step(&start, 3.0).unwrap().state;
        assert!(Particle.energy(s.t, &s.q, &s.v) > 10.0 * e0);
        // A stable step size runs 2000 steps without a refusal.
        let mut st = Stepper::<_, 3, 1, 2, 11>::new(Particle, tab);
        let mut s = start;
        for _ in 0..2000 {
            s = st.step(&s, 0.1).unwrap().state;
        }
        assert!((Particle.energy(s.t, &s.q, &s.v) - e0).abs() < 1e-2 * e0);
    }
}
