//! Diagnostics of a run that the step does not compute itself: the drift of
//! holonomic constraints imposed at velocity level and the work of the
//! external and non-ideal forces over a step (the right-hand side of the
//! discrete energy balance).

use crate::step::{State, StepResult};
use crate::system::NonholonomicSystem;
use crate::tableau::Tableau;

/// Largest `|g_i(t,q)|` over `states`, the drift of the holonomic
/// constraints of `Sys` imposed at velocity level (`0` when `Sys` has none).
pub fn holonomic_drift<Sys, const N: usize, const M: usize>(sys: &Sys, states: &[State<N>]) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    if !Sys::HAS_HOLONOMIC {
        return 0.0;
    }
    states.iter().map(|s| sys.holonomic_residual(s.t, &s.q).amax()).fold(0.0, f64::max)
}

/// The work `h Σ_j b_j (f_j + N_j)ᵀV_j` of the external and non-ideal forces
/// over one step `step` taken from `start` with size `h`, at the stages
/// `Q_j = q₀ + h Σ_l a_jl V_l`, `T_j = t₀ + c_j h`: the right-hand side of
/// the discrete energy balance `E(t₁) − E(t₀) ≈ ∫ (f + N)ᵀv dt`.
pub fn effect_work<Sys, const N: usize, const M: usize, const S: usize>(
    sys: &Sys,
    tableau: &Tableau<S>,
    start: &State<N>,
    h: f64,
    step: &StepResult<N, M, S>,
) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    let mut work = 0.0;
    for j in 0..S {
        let mut qj = start.q;
        for l in 0..S {
            qj += (h * tableau.a[j][l]) * step.stage_velocities[l];
        }
        let (tj, vj) = (start.t + tableau.c[j] * h, &step.stage_velocities[j]);
        let f = sys.external_force(tj, &qj, vj) + sys.nonideal_force(tj, &qj, vj, &step.stage_multipliers[j]);
        work += h * tableau.b[j] * f.dot(vj);
    }
    work
}
