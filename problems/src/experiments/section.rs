//! Poincaré sections: the states where an ensemble of trajectories crosses
//! an event surface `g(t, q, v) = 0` declared by the system.
//!
//! Each member of the ensemble is integrated with fixed steps; the crossings
//! of the chosen event are located on the dense output of each step
//! ([`spark_runtime::events`]), so a section point lies on the surface to the
//! event location's tolerance (`|g| ≈ 1e-14`), not only to the step size.
//! Only the chosen event is evaluated during the run; an event declared
//! `terminal` is treated as non-terminal here, so every crossing is recorded.
//! Members run in parallel (rayon).
//!
//! Members: for the McLachlan–Perlmutter particles (both readings of §8.4)
//! member `j` of `J` is the paper's initial state `j` of the ensemble with
//! `J` members ([`crate::systems::mp7_initial_values`]), all on the energy
//! level 3.06. For every other system member `j` starts from the registered
//! `(q0, v0)` with `v0` scaled by `1 + j/J` (the constraints, linear in `v`
//! for the systems that declare section events, stay satisfied; otherwise
//! the scaled velocity is projected onto them).

use crate::catalog::{
    declared_events, did_you_mean, nearest, systems_with_events, Dispatch, StageVisitor, SystemEntry, SystemKind,
    SystemVisitor,
};
use crate::run::{check_parameters, RunError};
use crate::systems::mp7_initial_values;
use rayon::prelude::*;
use spark_runtime::{
    ConsistencyPolicy, Direction, EventFunctions, EventGradient, EventRecord, EventSpec, IntegrationError, Method,
    NewtonOptions, NonholonomicSystem, Observer, RunOptions, Schedule, State, Stepper, Tableau, Vector,
};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Most members one section may have.
pub const MAX_SECTION_MEMBERS: usize = 10_000;

/// Bytes one crossing of a system with `n` coordinates takes while a
/// section is computed and written, bounded from above: the run's event
/// record, the section point, its CSV columns and its marker in the figure
/// (PNG and SVG text).
pub fn bytes_per_point(n: usize) -> u64 {
    48 * n as u64 + 400
}

/// Most crossings one section of a system with `n` coordinates collects:
/// what fits in [`spark_runtime::record_memory_limit`] (4 GiB, or half the
/// available memory). The number of crossings is not known before the
/// members run (an event can cross up to `EVENT_SUBINTERVALS` times a
/// step), so the members stop once they have found more.
pub fn max_section_points(n: usize) -> usize {
    usize::try_from(spark_runtime::record_memory_limit() / bytes_per_point(n)).unwrap_or(usize::MAX)
}

/// What to integrate for a section.
#[derive(Clone, Debug, PartialEq)]
pub struct SectionSpec {
    /// The system.
    pub system: SystemKind,
    /// The name of one of the system's declared events.
    pub event: String,
    /// Ensemble size `J` (members `0..J`).
    pub members: usize,
    /// The method.
    pub method: Method,
    /// Stage count `s`.
    pub stages: usize,
    /// Step size.
    pub h: f64,
    /// Steps per member (final time `t0 + steps·h`).
    pub steps: usize,
    /// Initial time.
    pub t0: f64,
    /// Parameter overrides `(name, value)`.
    pub parameters: Vec<(String, f64)>,
    /// Newton settings.
    pub newton: NewtonOptions,
    /// How deep a member's step whose Newton iteration fails may be halved
    /// (`RunOptions::max_halvings`; `0` makes it an error). Each member's
    /// halvings are in [`Section::rejected_steps`].
    pub max_halvings: u32,
}

/// One crossing of the event surface.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SectionPoint {
    /// Ensemble member.
    pub member: usize,
    /// Time of the crossing.
    pub t: f64,
    /// Coordinates there.
    pub q: Vec<f64>,
    /// Velocities there.
    pub v: Vec<f64>,
    /// The event function's value there (`≈ 0`).
    pub residual: f64,
}

/// A computed section.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Section {
    /// System name.
    pub system: &'static str,
    /// Event name.
    pub event: &'static str,
    /// The event's declared direction.
    pub direction: Direction,
    /// The event function in the system's source text.
    pub source: &'static str,
    /// Coordinate names.
    pub coordinates: Vec<String>,
    /// Crossings, by member and then in time order.
    pub points: Vec<SectionPoint>,
    /// Crossings per member.
    pub counts: Vec<usize>,
    /// Initial `(q0, v0)` of each member, as integrated.
    pub initial: Vec<(Vec<f64>, Vec<f64>)>,
    /// Each member's halvings of steps whose Newton iteration failed at `h`
    /// (all 0 for runs of fixed steps `h` alone).
    pub rejected_steps: Vec<usize>,
}

impl Section {
    /// `max |g|` over the section points (0 without points).
    pub fn max_residual(&self) -> f64 {
        self.points.iter().map(|p| p.residual.abs()).fold(0.0, f64::max)
    }
}

/// One axis of a section plot: a coordinate or a velocity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    /// Coordinate `q_i`.
    Q(usize),
    /// Velocity `v_i`.
    V(usize),
}

impl Axis {
    /// The value of this axis at a point.
    pub fn value(self, p: &SectionPoint) -> f64 {
        match self {
            Axis::Q(i) => p.q[i],
            Axis::V(i) => p.v[i],
        }
    }
    /// The column name (`q_<name>` or `v_<name>`).
    pub fn label(self, coordinates: &[&str]) -> String {
        match self {
            Axis::Q(i) => format!("q_{}", coordinates[i]),
            Axis::V(i) => format!("v_{}", coordinates[i]),
        }
    }
}

/// Errors of a section; each says what to change.
#[derive(Debug, thiserror::Error)]
pub enum SectionError {
    /// The system declares no events.
    #[error(
        "system `{system}` declares no events, so it has no section; systems with events: {with_events} \
         (declare one with `events: {{ name: rising(expr) }}` in its nonholonomic_system! block)"
    )]
    NoEvents {
        /// The system.
        system: &'static str,
        /// The registered systems that declare events, comma-separated.
        with_events: String,
    },
    /// The event name is not declared by the system.
    #[error("system `{system}` has no event `{name}`{}; its events: {known}", did_you_mean(.suggestion))]
    UnknownEvent {
        /// The system.
        system: &'static str,
        /// The name given.
        name: String,
        /// The closest declared name, if one is close.
        suggestion: Option<&'static str>,
        /// The declared events with their functions.
        known: String,
    },
    /// An axis name that is neither a coordinate nor a velocity.
    #[error(
        "{flag} `{name}` is not a coordinate or velocity of `{system}`; use one of {known} \
         (a bare coordinate name means q_<name>)"
    )]
    UnknownAxis {
        /// `--x` or `--y`.
        flag: &'static str,
        /// The system.
        system: &'static str,
        /// The name given.
        name: String,
        /// The accepted names, comma-separated.
        known: String,
    },
    /// A setting that cannot work.
    #[error("invalid section: {0}")]
    Invalid(String),
    /// The setting of the runs is rejected (parameters, method, stages).
    #[error(transparent)]
    Run(Box<RunError>),
    /// The members crossed the event more often than a section can keep.
    #[error(
        "the members crossed `{event}` more than {limit} times before t = {t:.3e} (the most crossings a section \
         keeps in memory: {bytes} bytes of 4 GiB or half the available memory); use fewer --members, a shorter \
         --t-end, or a step that is not close to a multiple of the crossings' period (a larger --h can cross \
         several times a step)",
        bytes = crate::report::format::sci(*.limit as f64 * *.bytes_per_point as f64)
    )]
    TooManyCrossings {
        /// The event.
        event: &'static str,
        /// Most crossings kept.
        limit: usize,
        /// Bytes per crossing ([`bytes_per_point`]).
        bytes_per_point: u64,
        /// The time the member that found the one too many had reached.
        t: f64,
    },
    /// One member's integration failed.
    #[error("member {member} (q0 = {q0:?}, v0 = {v0:?}): {source}")]
    Member {
        /// The member.
        member: usize,
        /// Its initial coordinates.
        q0: Vec<f64>,
        /// Its initial velocities.
        v0: Vec<f64>,
        /// What went wrong.
        source: Box<RunError>,
    },
}

impl From<RunError> for SectionError {
    fn from(e: RunError) -> Self {
        SectionError::Run(Box::new(e))
    }
}

/// The index of event `name` among the events of `kind`, or an error that
/// lists the declared events (or the systems that have some).
pub fn find_event(kind: SystemKind, name: &str) -> Result<usize, SectionError> {
    let events = declared_events(kind);
    let system = kind.key();
    if events.is_empty() {
        return Err(SectionError::NoEvents { system, with_events: systems_with_events().join(", ") });
    }
    events.iter().position(|e| e.name == name).ok_or_else(|| {
        let known: Vec<String> =
            events.iter().map(|e| format!("{} ({:?}: {})", e.name, e.direction, e.source)).collect();
        SectionError::UnknownEvent {
            system,
            name: name.to_string(),
            suggestion: nearest(name, events.iter().map(|e| e.name)),
            known: known.join(", "),
        }
    })
}

/// Parses an axis name: `q_<name>`, `v_<name>` or a bare coordinate name.
pub fn parse_axis(entry: &'static SystemEntry, flag: &'static str, name: &str) -> Result<Axis, SectionError> {
    let position = |c: &str| entry.coordinates.iter().position(|x| *x == c);
    let axis = if let Some(i) = position(name) {
        Some(Axis::Q(i))
    } else if let Some(i) = name.strip_prefix("q_").and_then(position) {
        Some(Axis::Q(i))
    } else {
        name.strip_prefix("v_").and_then(position).map(Axis::V)
    };
    axis.ok_or_else(|| {
        let known: Vec<String> = entry
            .coordinates
            .iter()
            .map(|c| format!("q_{c}"))
            .chain(entry.coordinates.iter().map(|c| format!("v_{c}")))
            .collect();
        SectionError::UnknownAxis { flag, system: entry.name, name: name.to_string(), known: known.join(", ") }
    })
}

/// The default plot axes of a section of `kind`: a pair that spreads the
/// section points of the examples (`q_3, v_3` for the McLachlan–Perlmutter
/// particles, `θ, ẋ` for the sleigh, `x, y` for the vertical disk), else the
/// first coordinate and its velocity.
pub fn default_axes(kind: SystemKind) -> (Axis, Axis) {
    match kind {
        SystemKind::McLachlanPerlmutter7 | SystemKind::McLachlanPerlmutter7Nonholonomic => (Axis::Q(2), Axis::V(2)),
        SystemKind::Sleigh => (Axis::Q(2), Axis::V(0)),
        SystemKind::VerticalDisk => (Axis::Q(0), Axis::Q(1)),
        _ => (Axis::Q(0), Axis::V(0)),
    }
}

/// Initial `(q0, v0)` of member `j` of `members` (see the module docs).
pub fn member_initial_values(kind: SystemKind, j: usize, members: usize) -> (Vec<f64>, Vec<f64>) {
    match kind {
        SystemKind::McLachlanPerlmutter7 | SystemKind::McLachlanPerlmutter7Nonholonomic => {
            mp7_initial_values(j, members.saturating_sub(1))
        }
        _ => {
            let e = kind.entry();
            let scale = 1.0 + j as f64 / members.max(1) as f64;
            (e.q0.to_vec(), e.v0.iter().map(|v| v * scale).collect())
        }
    }
}

/// Integrates every member of `spec` (in parallel) and collects the
/// crossings of its event.
pub fn run_section(spec: &SectionSpec) -> Result<Section, SectionError> {
    run_section_with_limit(spec, max_section_points(spec.system.entry().n))
}

/// [`run_section`] keeping at most `max_points` crossings: the members stop
/// once they have found more, and the section is
/// [`SectionError::TooManyCrossings`].
pub fn run_section_with_limit(spec: &SectionSpec, max_points: usize) -> Result<Section, SectionError> {
    let entry = spec.system.entry();
    if spec.members == 0 || spec.members > MAX_SECTION_MEMBERS {
        return Err(SectionError::Invalid(format!(
            "--members must lie in 1..={MAX_SECTION_MEMBERS}, got {}",
            spec.members
        )));
    }
    if !(spec.h.is_finite() && spec.h > 0.0) {
        return Err(SectionError::Invalid(format!("step size h = {:.3e} must be a positive number", spec.h)));
    }
    if !spec.t0.is_finite() {
        return Err(SectionError::Invalid(format!("initial time t0 = {:.3e} must be finite", spec.t0)));
    }
    spark_runtime::check_step_size(spec.t0, spec.h).map_err(|why| {
        SectionError::Invalid(format!("step size h = {:.3e} from t0 = {:.3e}: {why}", spec.h, spec.t0))
    })?;
    if spec.steps == 0 {
        return Err(SectionError::Invalid("a section needs at least one step".into()));
    }
    let (min, max) = spec.method.stage_range();
    if spec.stages < min || spec.stages > max {
        return Err(RunError::from(spark_runtime::TableauError::UnsupportedStages {
            method: spec.method,
            s: spec.stages,
            min,
            max,
        })
        .into());
    }
    check_parameters(entry, &spec.parameters)?;
    let index = find_event(spec.system, &spec.event)?;
    let declared = declared_events(spec.system)[index];
    let initial: Vec<(Vec<f64>, Vec<f64>)> =
        (0..spec.members).map(|j| member_initial_values(spec.system, j, spec.members)).collect();
    let found = AtomicUsize::new(0);
    let budget = Budget { found: &found, limit: max_points };
    let too_many = |t: f64| SectionError::TooManyCrossings {
        event: declared.name,
        limit: max_points,
        bytes_per_point: bytes_per_point(entry.n),
        t,
    };
    let runs: Vec<Result<(Vec<SectionPoint>, usize), SectionError>> = initial
        .par_iter()
        .enumerate()
        .map(|(member, (q0, v0))| {
            let visitor = MemberRun { spec, index, member, q0, v0, budget };
            crate::catalog::visit_system(spec.system, visitor).map_err(|source| match source {
                RunError::Integration { source: IntegrationError::Stopped { t, .. }, .. } => too_many(t),
                source => SectionError::Member { member, q0: q0.clone(), v0: v0.clone(), source: Box::new(source) },
            })
        })
        .collect();
    // A member stopped by the budget is an error only after every member
    // has ended, so that a failure of another member is reported as such.
    let mut points = Vec::new();
    let mut counts = Vec::with_capacity(spec.members);
    let mut rejected_steps = Vec::with_capacity(spec.members);
    let mut stopped = None;
    for run in runs {
        match run {
            Ok((member_points, rejected)) => {
                counts.push(member_points.len());
                rejected_steps.push(rejected);
                points.extend(member_points);
            }
            Err(e @ SectionError::TooManyCrossings { .. }) => stopped = stopped.or(Some(e)),
            Err(e) => return Err(e),
        }
    }
    if let Some(e) = stopped {
        return Err(e);
    }
    // A member whose last step went over the limit ends its run normally.
    if points.len() > max_points {
        return Err(too_many(points.iter().map(|p| p.t).fold(f64::NEG_INFINITY, f64::max)));
    }
    Ok(Section {
        system: entry.name,
        event: declared.name,
        direction: declared.direction,
        source: declared.source,
        coordinates: entry.coordinates.iter().map(|c| c.to_string()).collect(),
        points,
        counts,
        initial,
        rejected_steps,
    })
}

/// One declared event of a system, non-terminal, as the only event of a run.
struct OneEvent<const M: usize> {
    index: usize,
    spec: [EventSpec; 1],
}

impl<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize> EventFunctions<Sys, N> for OneEvent<M> {
    fn specs(&self) -> &[EventSpec] {
        &self.spec
    }
    fn value(&self, system: &Sys, _: usize, t: f64, q: &Vector<N>, v: &Vector<N>) -> f64 {
        system.event_value(self.index, t, q, v)
    }
    fn gradient(&self, system: &Sys, _: usize, t: f64, q: &Vector<N>, v: &Vector<N>) -> EventGradient<N> {
        system.event_gradient(self.index, t, q, v)
    }
}

struct MemberRun<'a> {
    spec: &'a SectionSpec,
    index: usize,
    member: usize,
    q0: &'a [f64],
    v0: &'a [f64],
    budget: Budget<'a>,
}

/// The crossings every member has found so far against the most a section
/// keeps: an observer that counts each located event and asks its run to
/// stop once the members together have found more than `limit`.
#[derive(Clone, Copy)]
struct Budget<'a> {
    found: &'a AtomicUsize,
    limit: usize,
}

impl<const N: usize, const M: usize> Observer<N, M> for Budget<'_> {
    fn observe<Sys: NonholonomicSystem<N, M>>(&mut self, _: &Sys, _: &State<N>, _: usize) {}
    fn observe_event(&mut self, _: &EventRecord<N>) {
        self.found.fetch_add(1, Ordering::Relaxed);
    }
    fn stop_requested(&mut self) -> bool {
        self.found.load(Ordering::Relaxed) > self.limit
    }
}

impl SystemVisitor for MemberRun<'_> {
    type Output = Result<(Vec<SectionPoint>, usize), RunError>;
    fn visit<Sys: Dispatch<N, M>, const N: usize, const M: usize, const Y: usize>(
        self,
        _: &'static SystemEntry,
    ) -> Self::Output {
        // A section needs an event ([`find_event`] checked that there is
        // one); the branch is on a constant, so the runs are compiled only
        // for the systems that declare events.
        if const { Sys::EVENTS.is_empty() } {
            return Err(RunError::Invalid(format!("`{}` declares no events", self.spec.system.key())));
        }
        let (method, stages) = (self.spec.method, self.spec.stages);
        Sys::with_stages(stages, MemberStages::<Sys> { run: self, system: std::marker::PhantomData })
            .map_err(|e| RunError::StagesNotCompiled { method, stages, max: e.max })?
    }
}

struct MemberStages<'a, Sys> {
    run: MemberRun<'a>,
    system: std::marker::PhantomData<Sys>,
}

impl<Sys: Dispatch<N, M>, const N: usize, const M: usize> StageVisitor<Sys, N, M> for MemberStages<'_, Sys> {
    type Output = Result<(Vec<SectionPoint>, usize), RunError>;
    fn visit<const S: usize, const D: usize>(self) -> Self::Output {
        let MemberRun { spec, index, member, q0, v0, mut budget } = self.run;
        let entry = spec.system.entry();
        let mut system = Sys::default();
        for (name, value) in &spec.parameters {
            system.set_parameter(name, *value)?;
        }
        let vector = |what: &'static str, x: &[f64]| -> Result<Vector<N>, RunError> {
            if x.len() != N || x.iter().any(|x| !x.is_finite()) {
                return Err(RunError::Dimension {
                    what,
                    system: entry.name,
                    got: x.len(),
                    expected: N,
                    coordinates: entry.coordinates.join(", "),
                });
            }
            Ok(Vector::<N>::from_column_slice(x))
        };
        let (q0, v0) = (vector("q0", q0)?, vector("v0", v0)?);
        // As in `spark run`: a negative mass or inertia from `--param` is
        // refused, not integrated.
        spark_runtime::check_positive_kinetic_energy(&system, spec.t0, &q0, &v0)
            .map_err(|source| RunError::KineticEnergy { system: entry.name, source })?;
        let tableau = Tableau::<S>::new(spec.method)?;
        let mut stepper = Stepper::<Sys, N, M, S, D>::new(system, tableau).with_options(spec.newton);
        let mut declared = Sys::EVENTS[index];
        declared.terminal = false;
        let events = OneEvent::<M> { index, spec: [declared] };
        let options = RunOptions {
            record_every: 0,
            consistency: ConsistencyPolicy::Project { tolerance: 1e-12 },
            max_halvings: spec.max_halvings,
            ..RunOptions::default()
        };
        let schedule = Schedule::Fixed { h: spec.h, steps: spec.steps };
        let traj = stepper.integrate_with_events(spec.t0, &q0, &v0, schedule, &options, &mut budget, &events).map_err(
            |source: IntegrationError| RunError::Integration {
                system: entry.name,
                method: spec.method,
                stages: S,
                source,
            },
        )?;
        let points = traj
            .events
            .iter()
            .map(|r| SectionPoint {
                member,
                t: r.t,
                q: r.q.iter().copied().collect(),
                v: r.v.iter().copied().collect(),
                residual: r.residual,
            })
            .collect();
        Ok((points, traj.report.rejected_steps))
    }
}

/// Stages the section's files in `out`: `<stem>.csv` (columns `member, t,
/// q_<name>…, v_<name>…, event_value`), the scatter plot `<stem>.{png,svg}`
/// of `axes` (one colour per member) and `section.json` (setting, crossings
/// per member, `max |g|`). `<stem>` is `<system>_<event>`. Returns the
/// staged final paths.
pub fn write_section(
    section: &Section,
    spec: &SectionSpec,
    axes: (Axis, Axis),
    out: &mut crate::report::files::OutputDir,
) -> Result<Vec<std::path::PathBuf>, crate::report::files::OutputError> {
    use crate::report::plot::{Scatter, Series};
    let stem = format!("{}_{}", section.system, section.event);
    let n = section.coordinates.len();
    let mut names = vec!["member".to_string(), "t".to_string()];
    names.extend(section.coordinates.iter().map(|c| format!("q_{c}")));
    names.extend(section.coordinates.iter().map(|c| format!("v_{c}")));
    names.push("event_value".into());
    let p = &section.points;
    if p.is_empty() {
        return Err(crate::report::files::OutputError::from(crate::report::plot::PlotError::Empty {
            figure: stem.clone(),
            panel: "section".into(),
            hint: " (no crossing of the event: integrate longer with --t-end, or choose another event)",
        }));
    }
    let mut columns: Vec<Vec<f64>> = vec![p.iter().map(|x| x.member as f64).collect(), p.iter().map(|x| x.t).collect()];
    columns.extend((0..n).map(|i| p.iter().map(|x| x.q[i]).collect::<Vec<f64>>()));
    columns.extend((0..n).map(|i| p.iter().map(|x| x.v[i]).collect::<Vec<f64>>()));
    columns.push(p.iter().map(|x| x.residual).collect());
    let named: Vec<(&str, &[f64])> = names.iter().map(String::as_str).zip(columns.iter().map(Vec::as_slice)).collect();
    let mut files = vec![out.write_columns(&format!("{stem}.csv"), &named)?];
    let coordinates: Vec<&str> = section.coordinates.iter().map(String::as_str).collect();
    let series: Vec<Series> = (0..spec.members)
        .map(|j| {
            let pts = p.iter().filter(|x| x.member == j).map(|x| (axes.0.value(x), axes.1.value(x))).collect();
            Series::new(format!("member {j}"), pts)
        })
        .collect();
    let t_end = spec.t0 + spec.steps as f64 * spec.h;
    let figure = Scatter {
        title: format!(
            "{}: section {} = 0 ({:?}), {} member(s), t ≤ {t_end}",
            section.system, section.source, section.direction, spec.members
        ),
        x_label: axes.0.label(&coordinates),
        y_label: axes.1.label(&coordinates),
        series,
        size: (900, 760),
    };
    files.extend(out.render_scatter(&figure, &stem)?);
    let summary = serde_json::json!({
        "system": section.system, "event": section.event, "function": section.source,
        "direction": section.direction, "method": spec.method.name(), "stages": spec.stages, "h": spec.h,
        "t0": spec.t0, "t_end": t_end, "members": spec.members, "parameters": spec.parameters,
        "initial": section.initial, "crossings_per_member": section.counts,
        "max_abs_event_value": section.max_residual(), "max_halvings": spec.max_halvings,
        "rejected_steps_per_member": section.rejected_steps,
        "x": axes.0.label(&coordinates), "y": axes.1.label(&coordinates),
    });
    files.push(out.write_json("section.json", &summary)?);
    Ok(files)
}
