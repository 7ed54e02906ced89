//! What a run returns: the recorded [`Sample`]s, the [`RunReport`] over
//! every step and the serializable [`Trajectory`] (JSON, CSV).

use super::{Observe, StepCounts};
use crate::error::Sci;
use crate::events::EventRecord;
use crate::initial::consistent_acceleration;
use crate::step::{State, Stepper};
use crate::system::{NonholonomicSystem, Vector};
use crate::tableau::Method;

/// The most memory the recorded samples of one request may take before a
/// front end (the `spark` CLI, the Python package) refuses it up front:
/// 4 GiB, lowered to half of the memory the system reports available
/// (`MemAvailable` in `/proc/meminfo`) when that is less. A run that
/// records more ends in an allocation failure, which aborts the process;
/// [`Stepper::integrate`] itself records what it is asked to.
pub fn record_memory_limit() -> u64 {
    const CAP: u64 = 4 << 30;
    let half_available = || -> Option<u64> {
        let text = std::fs::read_to_string("/proc/meminfo").ok()?;
        let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
        let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kib.saturating_mul(1024) / 2)
    };
    half_available().map_or(CAP, |a| a.min(CAP))
}

/// A request whose recorded samples would not fit in memory (see
/// [`check_record_size`]).
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error(
    "the run records {} samples ({} bytes in memory), more than the limit of {} bytes (4 GiB or half the \
     available memory); record every {every}-th step or fewer, or take fewer steps",
    Sci(*samples as f64),
    Sci(*bytes),
    Sci(*limit as f64)
)]
pub struct RecordTooLarge {
    /// Samples the request would record.
    pub samples: u64,
    /// Their bytes (a float: the product can exceed `u64`).
    pub bytes: f64,
    /// [`record_memory_limit`].
    pub limit: u64,
    /// The smallest record interval that fits.
    pub every: u64,
}

/// Checks that `members` runs of `steps` steps, each recording every
/// `every`-th step and both endpoints at `bytes_per_sample` bytes a sample,
/// fit within [`record_memory_limit`].
pub fn check_record_size(
    steps: usize,
    every: usize,
    members: usize,
    bytes_per_sample: u64,
) -> Result<(), RecordTooLarge> {
    let (steps, every) = (steps as u64, every.max(1) as u64);
    let samples = (steps / every).saturating_add(2).saturating_mul(members as u64);
    let bytes = samples as f64 * bytes_per_sample as f64;
    let limit = record_memory_limit();
    if bytes <= limit as f64 {
        return Ok(());
    }
    // Samples per member that fit, the two endpoints among them: an
    // interval above `steps / room` records at most `room + 1`.
    let fits = limit / bytes_per_sample.max(1) / members.max(1) as u64;
    let room = fits.saturating_sub(2).max(1);
    Err(RecordTooLarge { samples, bytes, limit, every: steps / room + 1 })
}

/// Whether a run of `steps` fixed steps records the end of step `k`
/// (counted from 0) when it records every `record_every`-th step: the
/// `record_every`-th, `2·record_every`-th, … and always the last
/// (`record_every = 0`: the last only). The driver's rule, per step.
#[inline]
pub(crate) fn records_step(k: usize, steps: usize, record_every: usize) -> bool {
    k + 1 == steps || (record_every != 0 && (k + 1).is_multiple_of(record_every))
}

/// The steps, in order, whose ends [`records_step`] records, without
/// visiting the others: what a caller that lays runs on their common time
/// axis counts, for step counts up to `usize::MAX`.
pub(crate) fn recorded_steps(steps: usize, record_every: usize) -> impl Iterator<Item = usize> {
    let regular = steps.checked_div(record_every).unwrap_or(0);
    let ends_between = record_every == 0 || !steps.is_multiple_of(record_every);
    (1..=regular).map(move |j| j * record_every - 1).chain((ends_between && steps > 0).then(|| steps - 1))
}

/// One recorded point of a trajectory.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sample<const N: usize, const M: usize> {
    /// Time.
    pub t: f64,
    /// Coordinates.
    pub q: Vector<N>,
    /// Velocities.
    pub v: Vector<N>,
    /// Energy, when observed.
    pub energy: Option<f64>,
    /// `max_i |k_i(t,q,v)|`, when observed.
    pub constraint_residual: Option<f64>,
    /// `ψ(t,q,v)`, when observed (`None` also if the saddle matrix was singular).
    pub multipliers: Option<Vector<M>>,
    /// Newton iterations of the step that produced this point (0 at the start).
    pub newton_iterations: usize,
}

/// Statistics of one run.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RunReport {
    /// Accepted steps.
    pub steps: usize,
    /// Newton iterations over all accepted steps.
    pub newton_iterations_total: usize,
    /// Mean Newton iterations per accepted step.
    pub newton_iterations_mean: f64,
    /// Largest Newton iteration count of one step.
    pub newton_iterations_max: usize,
    /// Rejected (sub-)steps: each Newton failure followed by smaller
    /// sub-steps (a halving, or a rejection under [`FailurePolicy::Reject`](crate::FailurePolicy::Reject)).
    pub rejected_steps: usize,
    /// Accepted sub-steps: one per scheduled step that succeeds at once,
    /// more where failures cut it.
    #[serde(default)]
    pub substeps: usize,
    /// Scheduled steps that needed at least one rejected sub-step.
    #[serde(default)]
    pub steps_with_rejections: usize,
    /// Smallest magnitude of an accepted sub-step (0 before the first).
    #[serde(default)]
    pub smallest_step: f64,
    /// Steps started cold (no usable previous step to extrapolate from),
    /// retried cold or halved.
    pub cold_starts: usize,
    /// Warm-started (sub-)steps whose Newton failed and that were retried
    /// once from the cold starting guess (the consistent acceleration) before
    /// any halving: an extrapolated guess can lie outside Newton's basin
    /// where the cold one does not.
    #[serde(default)]
    pub cold_retries: usize,
    /// Largest `max_i |k_i|` over the initial point, every accepted step
    /// (recorded or not) and the samples (0 if not observed: see
    /// [`Observe::constraint_residual`]).
    pub max_constraint_residual: f64,
    /// Largest `|E − E₀|` over the initial point, every accepted step
    /// (recorded or not) and the samples (0 if not observed: see
    /// [`Observe::energy`]).
    pub max_energy_error: f64,
    /// Whether `v₀` was projected onto the constraints.
    pub projected_initial_velocity: bool,
    /// Events located (see [`Trajectory::events`]).
    #[serde(default)]
    pub events: usize,
    /// The terminal event that ended the run, by index, if any.
    #[serde(default)]
    pub terminal_event: Option<usize>,
}

/// A recorded solution with its provenance; serializes to JSON (serde) and CSV.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Trajectory<const N: usize, const M: usize> {
    /// The system's type name.
    pub system: String,
    /// Coordinate names.
    pub coordinates: Vec<String>,
    /// The method.
    pub method: Method,
    /// Number of stages.
    pub stages: usize,
    /// The recorded points.
    pub samples: Vec<Sample<N, M>>,
    /// Run statistics.
    pub report: RunReport,
    /// The located events in time order (empty for systems without events).
    #[serde(default = "Vec::new")]
    pub events: Vec<EventRecord<N>>,
}

/// Largest sample storage (bytes) `integrate` reserves before the run.
const RESERVE_BYTES: usize = 1 << 20;

impl<const N: usize, const M: usize> Trajectory<N, M> {
    /// A trajectory of `Sys` (its name and coordinate names from the
    /// system's source) taken with `method` of `stages` stages.
    pub(crate) fn of<Sys: NonholonomicSystem<N, M>>(
        method: Method,
        stages: usize,
        samples: Vec<Sample<N, M>>,
        report: RunReport,
        events: Vec<EventRecord<N>>,
    ) -> Self {
        let source = Sys::SOURCE;
        Trajectory {
            system: source.name.to_string(),
            coordinates: source.coordinates.iter().map(|c| c.to_string()).collect(),
            method,
            stages,
            samples,
            report,
            events,
        }
    }

    /// The last recorded state.
    pub fn last(&self) -> Option<State<N>> {
        self.samples.last().map(|s| State { t: s.t, q: s.q, v: s.v })
    }

    /// CSV with a header `t, q_<name>…, v_<name>…, energy, constraint_residual, psi_1…, newton_iterations`
    /// (unobserved columns are empty).
    pub fn write_csv<W: std::io::Write>(&self, writer: W) -> Result<(), csv::Error> {
        let mut w = csv::Writer::from_writer(writer);
        let mut header = vec!["t".to_string()];
        header.extend(self.coordinates.iter().map(|c| format!("q_{c}")));
        header.extend(self.coordinates.iter().map(|c| format!("v_{c}")));
        header.push("energy".into());
        header.push("constraint_residual".into());
        header.extend((1..=M).map(|i| format!("psi_{i}")));
        header.push("newton_iterations".into());
        w.write_record(&header)?;
        let opt = |x: Option<f64>| x.map(|v| format!("{v:e}")).unwrap_or_default();
        for s in &self.samples {
            let mut rec = Vec::with_capacity(header.len());
            rec.push(format!("{:e}", s.t));
            rec.extend(s.q.iter().chain(s.v.iter()).map(|x| format!("{x:e}")));
            rec.push(opt(s.energy));
            rec.push(opt(s.constraint_residual));
            for i in 0..M {
                rec.push(opt(s.multipliers.map(|p| p[i])));
            }
            rec.push(s.newton_iterations.to_string());
            w.write_record(&rec)?;
        }
        w.flush()?;
        Ok(())
    }

    /// The CSV text (see [`Trajectory::write_csv`]).
    pub fn to_csv_string(&self) -> Result<String, csv::Error> {
        let mut buf = Vec::new();
        self.write_csv(&mut buf)?;
        Ok(String::from_utf8_lossy(&buf).into_owned())
    }

    /// Pretty JSON of the whole trajectory.
    pub fn to_json_string(&self) -> Result<String, serde_json::Error> {
        serde_json::to_string_pretty(self)
    }
}

impl RunReport {
    /// Takes sample `s` into the run's extremes of the constraint residual
    /// and of the energy error against `e0`.
    pub(crate) fn track<const N: usize, const M: usize>(&mut self, s: &Sample<N, M>, e0: Option<f64>) {
        if let Some(r) = s.constraint_residual {
            self.max_constraint_residual = self.max_constraint_residual.max(r);
        }
        if let (Some(e), Some(e0)) = (s.energy, e0) {
            self.max_energy_error = self.max_energy_error.max((e - e0).abs());
        }
    }

    /// Counts one scheduled step taken as `counts`.
    pub(super) fn count<const N: usize>(&mut self, counts: &StepCounts<N>) {
        if !counts.warm || counts.rejected > 0 || counts.cold_retries > 0 {
            self.cold_starts += 1;
        }
        self.steps += 1;
        self.rejected_steps += counts.rejected;
        self.substeps += counts.substeps;
        self.steps_with_rejections += usize::from(counts.rejected > 0);
        if self.smallest_step == 0.0 || counts.smallest < self.smallest_step {
            self.smallest_step = counts.smallest;
        }
        self.cold_retries += counts.cold_retries;
        self.newton_iterations_total += counts.iterations;
        self.newton_iterations_max = self.newton_iterations_max.max(counts.iterations);
    }
}

/// Storage for the samples of a run of `steps` steps recording every
/// `every`-th (or at the `sampled` times): reserved for the expected samples
/// up to a bounded size; beyond it the storage grows as samples arrive
/// (amortized, only when recording).
pub(crate) fn sample_storage<const N: usize, const M: usize>(
    sampled: Option<&[f64]>,
    steps: usize,
    every: usize,
) -> Vec<Sample<N, M>> {
    let expected = match sampled {
        Some(times) => times.len() + 1,
        None => steps.checked_div(every).map_or(2, |n| n.saturating_add(2)),
    };
    let bound = (RESERVE_BYTES / std::mem::size_of::<Sample<N, M>>().max(1)).max(2);
    Vec::with_capacity(expected.min(bound))
}

/// The recorded point at `state`.
pub(crate) fn sample_of<Sys, const N: usize, const M: usize>(
    sys: &Sys,
    state: &State<N>,
    observe: &Observe,
    iterations: usize,
) -> Sample<N, M>
where
    Sys: NonholonomicSystem<N, M>,
{
    Sample {
        t: state.t,
        q: state.q,
        v: state.v,
        energy: observe.energy.then(|| sys.energy(state.t, &state.q, &state.v)),
        constraint_residual: observe.constraint_residual.then(|| sys.constraint(state.t, &state.q, &state.v).amax()),
        multipliers: if observe.multipliers {
            consistent_acceleration(sys, state.t, &state.q, &state.v).map(|(_, psi)| psi)
        } else {
            None
        },
        newton_iterations: iterations,
    }
}

impl<Sys, const N: usize, const M: usize, const S: usize, const D: usize> Stepper<Sys, N, M, S, D>
where
    Sys: NonholonomicSystem<N, M>,
{
    pub(crate) fn sample(&self, state: &State<N>, observe: &Observe, iterations: usize) -> Sample<N, M> {
        sample_of(self.system(), state, observe, iterations)
    }
}

#[cfg(test)]
mod tests {
    use super::{recorded_steps, records_step};

    /// The two forms of the recording rule name the same steps, and the
    /// iterator reaches the last step of a count no loop could visit.
    #[test]
    fn recorded_steps_are_the_steps_records_step_records() {
        for steps in 0..40 {
            for every in 0..45 {
                let by_rule: Vec<usize> = (0..steps).filter(|&k| records_step(k, steps, every)).collect();
                let listed: Vec<usize> = recorded_steps(steps, every).collect();
                assert_eq!(listed, by_rule, "{steps} steps, every {every}");
            }
        }
        let huge = usize::MAX;
        assert_eq!(recorded_steps(huge, 0).collect::<Vec<_>>(), [huge - 1]);
        assert_eq!(recorded_steps(huge, huge / 2).collect::<Vec<_>>(), [huge / 2 - 1, 2 * (huge / 2) - 1, huge - 1]);
    }
}
