//! Whole ensembles: the members split into lane groups of [`LANES`], each
//! group a [`LaneStepper`], the groups run in parallel (rayon).

use rayon::prelude::*;

use super::stepper::{LaneError, LaneFailure, LaneRecovery, LaneStatus, LaneStepper, LANES};
use crate::step::{NewtonOptions, State};
use crate::system::NonholonomicSystem;
use crate::tableau::Tableau;

/// The most worker threads a front end starts for an ensemble
/// (`threads=` in Python, `problems::run::run_ensemble`'s thread count):
/// rayon would start up to 65535, which stalls or exhausts the process.
pub const MAX_ENSEMBLE_THREADS: usize = 1024;

/// One member's run in [`integrate_ensemble`].
#[derive(Clone, Debug, PartialEq)]
pub struct EnsembleRun<const N: usize> {
    /// Its start, its state after every `sample_every`-th step and after
    /// its last step (up to the step before a failure).
    pub samples: Vec<State<N>>,
    /// Steps it completed.
    pub steps: usize,
    /// Newton iterations over those steps.
    pub iterations: usize,
    /// What its failed steps cost: the halvings its solo `integrate`
    /// takes and counts (a step solved by the retry from the cold guess
    /// alone counts nothing here).
    pub recovery: LaneRecovery,
    /// The failed step that stopped it, if one did.
    pub failure: Option<LaneFailure>,
}

/// Integrates every member of `starts` (one start time) with `steps` fixed
/// steps of size `h`, in lane groups of [`LANES`] that run in parallel on
/// rayon's current thread pool. Each member's samples are bit for bit
/// those [`Stepper::integrate`](crate::Stepper::integrate) computes for it
/// alone with a fixed schedule and the default [`RunOptions`](crate::RunOptions)
/// (`t` pinned to `t₀ + k·h`; a step whose Newton iteration fails retried
/// from the cold guess, then halved, counted in [`EnsembleRun::recovery`]),
/// whatever the grouping and the thread count; a member whose step fails
/// even so stops with its [`LaneFailure`], the error of the last attempt,
/// and no other member is affected.
///
/// `sample_every = 0` records the start and the end only. Fails only for a
/// request no member can run: a zero or non-finite `h`, or start times that
/// differ.
pub fn integrate_ensemble<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    system: &Sys,
    tableau: Tableau<S>,
    options: NewtonOptions,
    starts: &[State<N>],
    h: f64,
    steps: usize,
    sample_every: usize,
) -> Result<Vec<EnsembleRun<N>>, LaneError>
where
    Sys: NonholonomicSystem<N, M> + Clone + Send + Sync,
{
    let halvings = crate::DEFAULT_MAX_HALVINGS;
    integrate_ensemble_until::<Sys, N, M, S, D>(
        system,
        tableau,
        options,
        starts,
        h,
        steps,
        sample_every,
        halvings,
        &|| false,
    )
}

/// Steps a lane group takes between two calls of the `stop` of
/// [`integrate_ensemble_until`].
const STOP_CHECK_EVERY: usize = 1024;

/// [`integrate_ensemble`] with failed steps halved at most `max_halvings`
/// levels deep ([`RunOptions::max_halvings`](crate::RunOptions::max_halvings))
/// that asks `stop` (from every lane group's thread) every 1024 steps
/// (`STOP_CHECK_EVERY`) and ends with [`LaneError::Stopped`] once it says
/// so: how a front end lets its user interrupt a long ensemble. The
/// members' samples are those of `integrate` with that `max_halvings` up
/// to there, bit for bit.
#[allow(clippy::too_many_arguments)]
pub fn integrate_ensemble_until<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    system: &Sys,
    tableau: Tableau<S>,
    options: NewtonOptions,
    starts: &[State<N>],
    h: f64,
    steps: usize,
    sample_every: usize,
    max_halvings: u32,
    stop: &(dyn Fn() -> bool + Sync),
) -> Result<Vec<EnsembleRun<N>>, LaneError>
where
    Sys: NonholonomicSystem<N, M> + Clone + Send + Sync,
{
    let Some(first) = starts.first() else { return Ok(Vec::new()) };
    if let Err(reason) = crate::check_step_size(first.t, h) {
        return Err(LaneError::StepSize { h, reason });
    }
    if let Some((member, s)) = starts.iter().enumerate().find(|(_, s)| s.t.to_bits() != first.t.to_bits()) {
        return Err(LaneError::StartTimes { member, t: s.t, t0: first.t });
    }
    let groups = starts
        .par_chunks(LANES)
        .map(|chunk| {
            let mut lanes = LaneStepper::<Sys, N, M, S, D, LANES>::new(system.clone(), tableau, options)
                .with_max_halvings(max_halvings);
            lanes.start(chunk, h)?;
            let mut runs: Vec<EnsembleRun<N>> = chunk
                .iter()
                .map(|s| EnsembleRun {
                    samples: vec![*s],
                    steps: 0,
                    iterations: 0,
                    recovery: LaneRecovery::default(),
                    failure: None,
                })
                .collect();
            // Lane after lane up to the next sample (see `advance_by`), at
            // most `STOP_CHECK_EVERY` steps at a time.
            let mut done = 0;
            while done < steps {
                let chunk = if sample_every == 0 { steps - done } else { sample_every - done % sample_every };
                let chunk = chunk.min(steps - done).min(STOP_CHECK_EVERY);
                let running = lanes.advance_by(chunk);
                done += chunk;
                if stop() {
                    return Err(LaneError::Stopped { steps: done });
                }
                let sampled = crate::driver::records_step(done - 1, steps, sample_every);
                for (j, run) in runs.iter_mut().enumerate() {
                    if run.failure.is_some() {
                        continue;
                    }
                    match lanes.status(j) {
                        Some(LaneStatus::Failed(f)) => {
                            run.steps = f.step;
                            run.iterations = lanes.total_iterations(j).unwrap_or(0);
                            run.recovery = lanes.recovery(j).copied().unwrap_or_default();
                            run.failure = Some((**f).clone());
                        }
                        Some(LaneStatus::Running) => {
                            run.steps = done;
                            run.iterations = lanes.total_iterations(j).unwrap_or(0);
                            run.recovery = lanes.recovery(j).copied().unwrap_or_default();
                            if let Some(s) = lanes.state(j).filter(|_| sampled) {
                                run.samples.push(*s);
                            }
                        }
                        Some(LaneStatus::Empty) | None => {}
                    }
                }
                if running == 0 {
                    break;
                }
            }
            Ok(runs)
        })
        .collect::<Result<Vec<_>, LaneError>>()?;
    Ok(groups.into_iter().flatten().collect())
}
