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
/// guard measures drift. It belongs to the chain that ends where the
/// stepper's latest step ended (the stepper keeps that end once, for
/// everything a continuing step takes over); a step that does not continue
/// that chain starts a new one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct EnergyAnchor {
    /// `E` where the chain began.
    pub(crate) energy: f64,
    /// `|E| + |p·v|` there: the energy's own size (`p·v = 2T` for a
    /// quadratic kinetic energy), the unit in which drift is measured.
    pub(crate) scale: f64,
}

impl EnergyAnchor {
    /// Whether the energy `e1` at the end of a step is within `limit` of
    /// this anchor's (with the round-off floor of [`check_energy`]); a NaN
    /// energy is not.
    #[inline(always)]
    pub(crate) fn holds(&self, e1: f64, limit: f64) -> bool {
        (e1 - self.energy).abs() <= limit * self.scale + 64.0 * f64::EPSILON * e1.abs()
    }

    /// An anchor at `state`.
    pub(crate) fn at<Sys, const N: usize, const M: usize>(sys: &Sys, state: &State<N>) -> Self
    where
        Sys: NonholonomicSystem<N, M>,
    {
        let energy = sys.energy(state.t, &state.q, &state.v);
        let pv = sys.momentum(state.t, &state.q, &state.v).dot(&state.v);
        EnergyAnchor { energy, scale: energy.abs() + pv.abs() }
    }
}

/// A step the guard refuses: the anchor of its chain and the energy `E₁` at
/// its end, `|E₁ − E_anchor| > limit · scale`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct EnergyDrift {
    pub(crate) anchor: EnergyAnchor,
    pub(crate) energy: f64,
}

/// Checks the end `end` of a step from `start` against `anchor`, the anchor
/// of the chain the step continues (`None`: it continues none, and a new
/// chain begins at `start`). On success `anchor` is the anchor of the chain
/// that now ends at `end`; after a refusal the caller keeps the anchor it
/// had (a new chain may have been written to `anchor`).
///
/// An anchor whose scale is zero (at rest where `E = 0`) measures nothing,
/// so the chain re-anchors at the next state instead. A round-off floor of
/// `64 ε |E₁|` keeps huge energy offsets from tripping the test.
///
/// `e1` is the energy at `end` (as [`NonholonomicSystem::energy`]
/// computes it). Inlined: a continued chain costs the test and nothing
/// else; a new chain is made out of line.
#[inline(always)]
pub(crate) fn check_energy<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    anchor: &mut Option<EnergyAnchor>,
    start: &State<N>,
    end: &State<N>,
    e1: f64,
    limit: f64,
) -> Result<(), EnergyDrift>
where
    Sys: NonholonomicSystem<N, M>,
{
    let a = match anchor {
        Some(a) if a.scale > 0.0 => *a,
        _ => match begin_chain::<Sys, N, M>(sys, anchor, start, end) {
            Some(a) => a,
            None => return Ok(()),
        },
    };
    if a.holds(e1, limit) {
        Ok(())
    } else {
        Err(EnergyDrift { anchor: a, energy: e1 })
    }
}

/// The anchor of a new chain at `start`, also kept in `anchor`; when its
/// scale is zero, `anchor` becomes one at `end` instead and there is
/// nothing to check (`None`).
#[cold]
#[inline(never)]
fn begin_chain<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    anchor: &mut Option<EnergyAnchor>,
    start: &State<N>,
    end: &State<N>,
) -> Option<EnergyAnchor>
where
    Sys: NonholonomicSystem<N, M>,
{
    let a = EnergyAnchor::at::<Sys, N, M>(sys, start);
    if a.scale == 0.0 {
        *anchor = Some(EnergyAnchor::at::<Sys, N, M>(sys, end));
        return None;
    }
    *anchor = Some(a);
    Some(a)
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

    /// The anchor belongs to the chain that ends where the stepper's latest
    /// step ended: continued steps keep it, a step the guard does not check
    /// ends the chain, and a step from another state begins a new one at
    /// its start, even after the driver's retargeting of the latest end.
    #[test]
    fn the_anchor_follows_the_chain_of_the_latest_step() {
        use crate::fixtures::paper::Particle;
        use crate::{NewtonOptions, Stepper, Tableau};
        let start = State::new(0.0, Vector::<3>::new(1.0, 0.5, 0.0), Vector::<3>::new(0.0, 0.3, 0.0));
        let mut st = Stepper::<_, 3, 1, 2, 11>::new(Particle, Tableau::new(crate::Method::LobattoIIIAB).unwrap());
        let energy = |s: &State<3>| Particle.energy(s.t, &s.q, &s.v);
        let mut s = start;
        for _ in 0..5 {
            s = st.step(&s, 0.3).unwrap().state;
        }
        // The energy drifts from step to step at this h, so anchors at
        // different states hold different energies.
        assert_ne!(energy(&s), energy(&start));
        assert_eq!(st.anchor.map(|a| a.energy), Some(energy(&start)));
        // Unchecked: no chain ends here.
        st.options_mut().energy_drift_limit = None;
        s = st.step(&s, 0.3).unwrap().state;
        assert_eq!(st.anchor, None);
        // Checked again: a new chain from this step's start, which the
        // retargeted end (the time pinned) continues.
        *st.options_mut() = NewtonOptions::default();
        let begun = s;
        s = st.step(&s, 0.3).unwrap().state;
        assert_eq!(st.anchor.map(|a| a.energy), Some(energy(&begun)));
        s.t = 2.1;
        st.retarget_warm_start(&s);
        st.step(&s, 0.3).unwrap();
        assert_eq!(st.anchor.map(|a| a.energy), Some(energy(&begun)));
        // A step from elsewhere begins its own chain.
        st.step(&start, 0.3).unwrap();
        assert_eq!(st.anchor.map(|a| a.energy), Some(energy(&start)));
    }
}
