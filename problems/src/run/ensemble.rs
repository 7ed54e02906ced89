//! Ensembles: one run per initial state of one spec, the members stepped in
//! SIMD lane groups of the lane stepper ([`spark_runtime::LaneStepper`]),
//! the groups in parallel (rayon), every step observed as [`run`] observes
//! it.

use super::*;
pub use spark_runtime::MAX_ENSEMBLE_THREADS;

/// Errors of an ensemble ([`run_ensemble`]); each says what to change.
#[derive(Debug, thiserror::Error)]
pub enum EnsembleError {
    /// No initial state was given.
    #[error("an ensemble needs at least one member")]
    NoMembers,
    /// A thread count of zero.
    #[error("threads must be at least 1")]
    NoThreads,
    /// More worker threads than an ensemble starts ([`MAX_ENSEMBLE_THREADS`]).
    #[error("threads = {threads} is more than {MAX_ENSEMBLE_THREADS}, the most an ensemble starts; use at most the number of cores")]
    TooManyThreads {
        /// Threads asked for.
        threads: usize,
    },
    /// The worker threads could not be started.
    #[error("could not start {threads} worker threads: {reason}")]
    ThreadPool {
        /// Threads asked for.
        threads: usize,
        /// What the operating system said.
        reason: String,
    },
    /// The members' recorded samples together would not fit in memory.
    #[error("{0}")]
    Record(RunError),
    /// One member's run failed (bad initial state, failed step).
    #[error("member {member}: {source}")]
    Member {
        /// The member's index in the list of initial states.
        member: usize,
        /// Why its run failed.
        source: RunError,
    },
}

/// An ensemble: `spec` run from every initial state `(q0, v0)` of `members`
/// (`spec.q0` and `spec.v0` are not used) on `threads` worker threads
/// (`None`: rayon's global pool, all cores or `RAYON_NUM_THREADS`). Each
/// member's result is what [`run`] returns for it alone, up to the Newton
/// tolerance of its steps and apart from the times; see
/// [`run_ensemble_with`] for the lane stepper and the rule for the runs that
/// bypass it.
pub fn run_ensemble(
    spec: &RunSpec,
    members: &[(Vec<f64>, Vec<f64>)],
    threads: Option<usize>,
) -> Result<Vec<RunResult>, EnsembleError> {
    run_ensemble_with(spec, members, threads, &|_| true)
}

/// [`run_ensemble`], calling `tick` with the member steps done (every few
/// thousand and at the end), for progress bars; when it answers `false`
/// the members still running stop with [`IntegrationError::Stopped`](spark_runtime::IntegrationError::Stopped)
/// ([`EnsembleError::Member`] names the first).
///
/// # Lanes
/// The members run in SIMD lane groups of [`LANES`] on the lane stepper of
/// [`integrate_ensemble`](spark_runtime::integrate_ensemble)
/// ([`LaneStepper`]), the groups in parallel (rayon). A member's steps agree
/// with those of its solo [`run`] to the Newton tolerance per step. Its
/// samples are taken at the steps [`run`] records (every
/// [`RunSpec::record_every`]-th and the last), and its energy, constraint
/// residual `|k|`, holonomic residual, their extremes (over every step, as
/// [`run`] takes them) and its Newton iteration mean are computed as
/// [`run`] computes them, from its states.
///
/// The lanes take fixed steps and report failures; anything more goes
/// through [`run`] per member (in parallel over members):
/// - systems the catalogue does not mark `ensemble: lanes` (the lane kernel
///   is compiled per system and stage count, so only for the systems whose
///   ensembles the project runs: the McLachlan–Perlmutter particles);
/// - [`RunSpec::multipliers`] (the lanes do not solve for `ψ` at the
///   samples) and `steps = 0`: every member runs through [`run`];
/// - a spec [`run`] rejects before stepping (step size, initial time, stage
///   count, parameter names): every member runs through [`run`] and reports
///   that error;
/// - a member whose lane fails runs again alone through [`run`], so that it
///   reports [`run`]'s error. (A lane retries a failed step from the cold
///   starting guess and halves it up to [`RunSpec::max_halvings`] levels, as
///   [`run`]'s driver does, and counts its halvings as [`run`] counts them.)
///
/// Before any member steps, every initial state is checked (and `v0`
/// projected when [`RunSpec::consistency`] asks for it) as [`run`] checks
/// it; the first member that fails is reported with its index.
///
/// # Times
/// On the lane path a lane group's wall and thread-CPU times are
/// apportioned equally among its members: summed over the members they give
/// the time the ensemble took on the cores, not the time each member would
/// take alone.
pub fn run_ensemble_with(
    spec: &RunSpec,
    members: &[(Vec<f64>, Vec<f64>)],
    threads: Option<usize>,
    tick: Tick<'_>,
) -> Result<Vec<RunResult>, EnsembleError> {
    if members.is_empty() {
        return Err(EnsembleError::NoMembers);
    }
    check_record_size(spec, members.len()).map_err(EnsembleError::Record)?;
    let work = || -> Result<Vec<RunResult>, EnsembleError> {
        // The lanes take fixed steps recorded at the steps; tolerance-driven
        // runs, output times and events run member by member.
        let lanes_take = spec.tolerance.is_none() && spec.times.is_none() && !spec.events;
        if spec.multipliers || spec.steps == 0 || !lanes_take || check_spec(spec).is_err() {
            return each_member(spec, members, tick);
        }
        crate::catalog::visit_system(spec.system, EnsembleSystem { spec, members, tick })
    };
    match threads {
        None => work(),
        Some(0) => Err(EnsembleError::NoThreads),
        Some(t) if t > MAX_ENSEMBLE_THREADS => Err(EnsembleError::TooManyThreads { threads: t }),
        Some(t) => rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .map_err(|e| EnsembleError::ThreadPool { threads: t, reason: e.to_string() })?
            .install(work),
    }
}

/// The per-member path of [`run_ensemble_with`]: one [`run`] per member,
/// in parallel over members.
fn each_member(
    spec: &RunSpec,
    members: &[(Vec<f64>, Vec<f64>)],
    tick: Tick<'_>,
) -> Result<Vec<RunResult>, EnsembleError> {
    use rayon::prelude::*;
    members
        .par_iter()
        .enumerate()
        .map(|(member, (q0, v0))| {
            let one = RunSpec { q0: q0.clone(), v0: v0.clone(), ..spec.clone() };
            run(&one, tick).map_err(|source| EnsembleError::Member { member, source })
        })
        .collect()
}

/// System dispatch of the lane path of [`run_ensemble_with`].
struct EnsembleSystem<'a> {
    spec: &'a RunSpec,
    members: &'a [(Vec<f64>, Vec<f64>)],
    tick: Tick<'a>,
}

impl SystemVisitor for EnsembleSystem<'_> {
    type Output = Result<Vec<RunResult>, EnsembleError>;
    fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
        self,
        _: &'static SystemEntry,
    ) -> Self::Output {
        let (method, stages) = (self.spec.method, self.spec.stages);
        let visitor = EnsembleStages::<Sys> {
            spec: self.spec,
            members: self.members,
            tick: self.tick,
            system: std::marker::PhantomData,
        };
        match Sys::with_lane_stages(stages, visitor) {
            Some(result) => result.map_err(|e| EnsembleError::Member {
                member: 0,
                source: RunError::StagesNotCompiled { method, stages, max: e.max },
            })?,
            None => each_member(self.spec, self.members, self.tick),
        }
    }
}

struct EnsembleStages<'a, Sys> {
    spec: &'a RunSpec,
    members: &'a [(Vec<f64>, Vec<f64>)],
    tick: Tick<'a>,
    system: std::marker::PhantomData<Sys>,
}

impl<Sys: Dispatch<N, M>, const N: usize, const M: usize> StageVisitor<Sys, N, M> for EnsembleStages<'_, Sys> {
    type Output = Result<Vec<RunResult>, EnsembleError>;
    fn visit<const S: usize, const D: usize>(self) -> Self::Output {
        ensemble_lanes::<Sys, N, M, S, D>(self.spec, self.members, self.tick)
    }
}

/// The lane path of [`run_ensemble_with`] for one stepper type: the checked
/// starts, then lane groups of [`LANES`] in parallel (rayon).
fn ensemble_lanes<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    spec: &RunSpec,
    members: &[(Vec<f64>, Vec<f64>)],
    tick: Tick<'_>,
) -> Result<Vec<RunResult>, EnsembleError>
where
    Sys: NonholonomicSystem<N, M> + Default + Clone + Send + Sync,
{
    use rayon::prelude::*;
    let entry = spec.system.entry();
    let at = |member: usize| move |source: RunError| EnsembleError::Member { member, source };
    let probe = configured::<Sys, N, M>(spec).map_err(at(0))?;
    let tableau = Tableau::<S>::new(spec.method).map_err(|e| at(0)(e.into()))?;
    let starts = members
        .iter()
        .enumerate()
        .map(|(j, (q0, v0))| {
            let q0 = vector::<N>("q0", entry, q0).map_err(at(j))?;
            let v0 = vector::<N>("v0", entry, v0).map_err(at(j))?;
            let v0 = checked_start::<Sys, N, M, S>(spec, &probe, &q0, &v0).map_err(at(j))?;
            Ok(State::new(spec.t0, q0, v0))
        })
        .collect::<Result<Vec<State<N>>, EnsembleError>>()?;
    let groups = starts
        .par_chunks(LANES)
        .enumerate()
        .map(|(g, chunk)| {
            lane_group::<Sys, N, M, S, D>(spec, &probe, tableau, chunk, tick)
                .into_iter()
                .enumerate()
                .map(|(j, r)| r.map_err(at(g * LANES + j)))
                .collect::<Result<Vec<RunResult>, EnsembleError>>()
        })
        .collect::<Result<Vec<_>, EnsembleError>>()?;
    Ok(groups.into_iter().flatten().collect())
}

/// One member's observations on the lane path: the columns at its samples
/// and the extremes over every step.
struct LaneRecord<const N: usize> {
    samples: Vec<State<N>>,
    energy: Vec<f64>,
    constraint: Vec<f64>,
    holonomic: Vec<f64>,
    e0: f64,
    max_energy_error: f64,
    max_constraint_residual: f64,
    max_holonomic_drift: f64,
    /// Its lane stopped at a failed step.
    failed: bool,
}

/// One lane group: the members `starts` (at most [`LANES`]) stepped in
/// lock-step by a [`LaneStepper`], every step of every member observed; a
/// member whose lane fails runs again through [`run`].
fn lane_group<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    spec: &RunSpec,
    probe: &Sys,
    tableau: Tableau<S>,
    starts: &[State<N>],
    tick: Tick<'_>,
) -> Vec<Result<RunResult, RunError>>
where
    Sys: NonholonomicSystem<N, M> + Default + Clone,
{
    let key = spec.system.entry().name;
    let drift = |t: f64, q: &Vector<N>| if Sys::HAS_HOLONOMIC { probe.holonomic_residual(t, q).amax() } else { 0.0 };
    let residual = |s: &State<N>| probe.constraint(s.t, &s.q, &s.v).amax();
    let wall_start = Instant::now();
    let cpu_start = thread_cpu_time();
    let mut lanes = LaneStepper::<Sys, N, M, S, D, LANES>::new(probe.clone(), tableau, spec.newton)
        .with_max_halvings(spec.max_halvings);
    if let Err(e) = lanes.start(starts, spec.h) {
        return starts.iter().map(|_| Err(RunError::Invalid(e.to_string()))).collect();
    }
    let mut records: Vec<LaneRecord<N>> = starts
        .iter()
        .map(|s| {
            let (e0, k0, g0) = (probe.energy(s.t, &s.q, &s.v), residual(s), drift(s.t, &s.q));
            LaneRecord {
                samples: vec![*s],
                energy: vec![e0],
                constraint: vec![k0],
                holonomic: if Sys::HAS_HOLONOMIC { vec![g0] } else { Vec::new() },
                e0,
                max_energy_error: 0.0,
                max_constraint_residual: k0,
                max_holonomic_drift: g0,
                failed: false,
            }
        })
        .collect();
    let mut done = 0usize;
    for k in 0..spec.steps {
        let running = lanes.advance_by(1);
        let recorded = k + 1 == spec.steps || (spec.record_every != 0 && (k + 1) % spec.record_every == 0);
        for (j, r) in records.iter_mut().enumerate() {
            if r.failed {
                continue;
            }
            let (Some(LaneStatus::Running), Some(s)) = (lanes.status(j), lanes.state(j)) else {
                r.failed = true;
                continue;
            };
            // What the driver observes after an accepted step of `run`.
            let (e, c, g) = (probe.energy(s.t, &s.q, &s.v), residual(s), drift(s.t, &s.q));
            r.max_energy_error = r.max_energy_error.max((e - r.e0).abs());
            r.max_constraint_residual = r.max_constraint_residual.max(c);
            r.max_holonomic_drift = r.max_holonomic_drift.max(g);
            if recorded {
                r.samples.push(*s);
                r.energy.push(e);
                r.constraint.push(c);
                if Sys::HAS_HOLONOMIC {
                    r.holonomic.push(g);
                }
            }
        }
        done += running;
        if done >= TICK_EVERY {
            let go_on = tick(done as u64);
            done = 0;
            if !go_on {
                // Every member still running stops here, as its solo run would.
                let stopped = |j: usize| {
                    let t = lanes.state(j).map_or(spec.t0, |s| s.t);
                    let source = IntegrationError::Stopped { steps: k + 1, t, partial: Box::default() };
                    RunError::Integration { system: key, method: spec.method, stages: S, source }
                };
                return (0..starts.len()).map(|j| Err(stopped(j))).collect();
            }
        }
        if running == 0 {
            break;
        }
    }
    let _ = tick(done as u64);
    let share = starts.len() as u32;
    let wall_time = wall_start.elapsed() / share;
    let cpu_time = match (cpu_start, thread_cpu_time()) {
        (Some(a), Some(b)) if b >= a => Some((b - a) / share),
        _ => None,
    };
    records
        .into_iter()
        .enumerate()
        .map(|(j, r)| {
            if r.failed {
                let q0 = starts[j].q.as_slice().to_vec();
                let v0 = starts[j].v.as_slice().to_vec();
                // Alone it reports no progress (its steps are counted) but
                // still stops when asked.
                return run(&RunSpec { q0, v0, ..spec.clone() }, &|_| tick(0));
            }
            let steps = spec.steps;
            let iterations = lanes.total_iterations(j).unwrap_or(0);
            let recovery = lanes.recovery(j).copied().unwrap_or_default();
            let column = |f: &dyn Fn(&State<N>) -> f64| r.samples.iter().map(f).collect::<Vec<f64>>();
            Ok(RunResult {
                system: key,
                coordinates: Sys::SOURCE.coordinates.iter().map(|c| c.to_string()).collect(),
                method: spec.method,
                stages: S,
                h: spec.h,
                t: column(&|s| s.t),
                q: (0..N).map(|i| column(&|s| s.q[i])).collect(),
                v: (0..N).map(|i| column(&|s| s.v[i])).collect(),
                energy: r.energy,
                constraint: r.constraint,
                holonomic: r.holonomic,
                psi: Vec::new(),
                stats: RunStats {
                    steps,
                    e0: r.e0,
                    max_energy_error: r.max_energy_error,
                    max_constraint_residual: r.max_constraint_residual,
                    max_holonomic_drift: Sys::HAS_HOLONOMIC.then_some(r.max_holonomic_drift),
                    newton_iterations_mean: iterations as f64 / steps as f64,
                    rejected_steps: recovery.rejected_steps,
                    steps_with_rejections: recovery.steps_with_rejections,
                    substeps: steps + recovery.extra_substeps,
                    smallest_step: recovery.smallest_step(spec.h),
                    wall_time,
                    cpu_time,
                },
                events: Vec::new(),
                controller: None,
            })
        })
        .collect()
}
