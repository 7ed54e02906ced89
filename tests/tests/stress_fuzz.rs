//! Fuzz harness: proptest over the stepper's inputs — system and
//! its parameters, method and stage count, state (t, q, v) and step size,
//! drawn from ordinary values mixed with zeros, huge, tiny, NaN and infinite
//! ones — through `Stepper::step`, the driver `integrate` (with projection of
//! the initial velocity and step halving) and `integrate` under the
//! rejection policy (`FailurePolicy::Reject`).
//!
//! Properties: nothing panics; every `Ok` carries a finite state; every
//! error renders a message.
//!
//! Executions: `FUZZ_CASES` (default 20 000) cases per run of this test, each
//! case exercising one (system, s) pairing with three entry points. A larger
//! run: `FUZZ_CASES=200000 cargo test --release -p spark-tests --test integration stress_fuzz`
//! (documented in docs/stress/README.md with its outcome).

use problems::systems::stress::{NearParallel, NonReversibleOscillator, RollingDisk, StiffSkate};
use problems::systems::{
    AppellHamel, DoublePendulum, McLachlanPerlmutter7, NonholonomicParticle, Skate, TurntableSkate,
};
use proptest::prelude::*;
use spark_runtime::{
    ConsistencyPolicy, FailurePolicy, Method, NoObserver, NonholonomicSystem, RejectionPolicy, RunOptions, Schedule,
    State, Stepper, Tableau, Vector, DEFAULT_MAX_SUBSTEPS,
};

/// A float that is usually ordinary and sometimes hostile.
fn wild() -> impl Strategy<Value = f64> {
    prop_oneof![
        6 => -3.0f64..3.0,
        1 => Just(0.0),
        1 => prop::sample::select(vec![
            f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e300, -1e300, 1e-300, f64::MIN_POSITIVE, 1e150, -1e16, 1e8,
        ]),
        1 => any::<f64>(),
    ]
}

fn step_size() -> impl Strategy<Value = f64> {
    prop_oneof![
        6 => 1e-3f64..2.0,
        2 => -2.0f64..-1e-3,
        1 => prop::sample::select(vec![0.0, -0.0, f64::NAN, f64::INFINITY, 1e-320, 1e-15, 50.0, 1e10, -1e300]),
    ]
}

const METHODS: [Method; 7] = [
    Method::Gauss,
    Method::LobattoIIIAB,
    Method::LobattoIIIABD,
    Method::SymplecticEulerI,
    Method::SymplecticEulerII,
    Method::ModifiedLobattoIIIAB,
    Method::LobattoIIIBALda,
];

#[derive(Clone, Debug)]
struct Input {
    system: usize,
    stages: usize,
    method: Method,
    t0: f64,
    h: f64,
    q: Vec<f64>,
    v: Vec<f64>,
    params: Vec<f64>,
    project: bool,
}

fn input() -> impl Strategy<Value = Input> {
    (
        0usize..10,
        1usize..=3,
        prop::sample::select(METHODS.to_vec()),
        prop_oneof![4 => -10.0f64..10.0, 1 => wild()],
        step_size(),
        prop::collection::vec(wild(), 7),
        prop::collection::vec(wild(), 7),
        prop::collection::vec(prop_oneof![5 => 0.1f64..3.0, 1 => wild()], 5),
        any::<bool>(),
    )
        .prop_map(|(system, stages, method, t0, h, q, v, params, project)| Input {
            system,
            stages,
            method,
            t0,
            h,
            q,
            v,
            params,
            project,
        })
}

/// Runs the three entry points; panics (a proptest failure) only if the
/// library returns a non-finite state as success.
fn exercise<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(mut sys: Sys, x: &Input)
where
    Sys: NonholonomicSystem<N, M>,
{
    for (i, name) in Sys::SOURCE.parameters.iter().enumerate() {
        // Through the API (non-finite values must be refused, not stored).
        let r = sys.set_parameter(name, x.params[i % x.params.len()]);
        if let Err(e) = r {
            assert!(!x.params[i % x.params.len()].is_finite(), "finite parameter refused: {e}");
        }
    }
    let _ = sys.set_parameter("no_such_parameter", 1.0).unwrap_err().to_string();
    let tableau = match Tableau::<S>::new(x.method) {
        Ok(t) => t,
        Err(e) => {
            let _ = e.to_string();
            return;
        }
    };
    let q = Vector::<N>::from_fn(|i, _| x.q[i]);
    let v = Vector::<N>::from_fn(|i, _| x.v[i]);
    let state = State::new(x.t0, q, v);
    let finite = |s: &State<N>| s.t.is_finite() && s.q.iter().chain(s.v.iter()).all(|z| z.is_finite());
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, tableau);
    match st.step(&state, x.h) {
        Ok(r) => assert!(finite(&r.state), "step returned a non-finite state: {:?}", r.state),
        Err(e) => {
            let _ = e.to_string();
        }
    }
    let consistency = if x.project {
        ConsistencyPolicy::Project { tolerance: 1e-12 }
    } else {
        ConsistencyPolicy::Error { tolerance: 1e-12 }
    };
    let opts = RunOptions { consistency, max_halvings: 2, ..RunOptions::default() };
    match st.integrate(x.t0, &q, &v, Schedule::Fixed { h: x.h, steps: 3 }, &opts, &mut NoObserver) {
        Ok(traj) => {
            for s in &traj.samples {
                assert!(
                    s.t.is_finite() && s.q.iter().chain(s.v.iter()).all(|z| z.is_finite()),
                    "integrate returned a non-finite sample"
                );
            }
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
    let policy = RejectionPolicy { max_halvings: 4, ..RejectionPolicy::default() };
    let reject = RunOptions { consistency, on_failure: FailurePolicy::Reject(policy), ..RunOptions::default() };
    match st.integrate(x.t0, &q, &v, Schedule::Fixed { h: x.h, steps: 1 }, &reject, &mut NoObserver) {
        Ok(traj) => {
            let end = traj.last().expect("a run records its end");
            assert!(finite(&end), "a step under the rejection policy returned a non-finite state");
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
}

macro_rules! by_stages {
    ($sys:ty, $make:expr, $x:expr) => {
        match $x.stages {
            1 => exercise::<$sys, { <$sys>::N }, { <$sys>::M }, 1, { 1 * (<$sys>::N + <$sys>::M) + <$sys>::N }>(
                $make, $x,
            ),
            2 => exercise::<$sys, { <$sys>::N }, { <$sys>::M }, 2, { 2 * (<$sys>::N + <$sys>::M) + <$sys>::N }>(
                $make, $x,
            ),
            _ => exercise::<$sys, { <$sys>::N }, { <$sys>::M }, 3, { 3 * (<$sys>::N + <$sys>::M) + <$sys>::N }>(
                $make, $x,
            ),
        }
    };
}

fn dispatch(x: &Input) {
    match x.system {
        0 => by_stages!(NonholonomicParticle, NonholonomicParticle::default(), x),
        1 => by_stages!(Skate, Skate::default(), x),
        2 => by_stages!(McLachlanPerlmutter7, McLachlanPerlmutter7::default(), x),
        3 => by_stages!(TurntableSkate, TurntableSkate::default(), x),
        4 => by_stages!(AppellHamel, AppellHamel::default(), x),
        5 => by_stages!(DoublePendulum, DoublePendulum::default(), x),
        6 => by_stages!(NearParallel, NearParallel { eps: x.params[0] * 1e-7 }, x),
        7 => by_stages!(RollingDisk, RollingDisk::default(), x),
        8 => by_stages!(StiffSkate, StiffSkate { k: x.params[1].abs() * 1e6, ..StiffSkate::default() }, x),
        _ => by_stages!(NonReversibleOscillator, NonReversibleOscillator::default(), x),
    }
}

fn cases() -> u32 {
    std::env::var("FUZZ_CASES").ok().and_then(|s| s.parse().ok()).unwrap_or(20_000)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn stepper_never_panics(x in input()) {
        dispatch(&x);
    }
}

/// Deterministic hostile corner: a NaN field in a system evaluated inside
/// the constraint must come back as an error, not a silent success.
#[test]
fn nan_parameter_in_the_constraint_is_an_error() {
    let sys = NearParallel { eps: f64::NAN };
    let mut st = Stepper::<NearParallel, 3, 2, 2, 13>::new(sys, Tableau::new(Method::Gauss).unwrap());
    let (q, v) = (Vector::<3>::new(1.0, 0.5, 0.0), Vector::<3>::new(0.3, 0.0, 0.15));
    assert!(st.step(&State::new(0.0, q, v), 0.1).is_err());
}

/// The input classes beyond one small system and three steps: larger `n`
/// (McLachlan–Perlmutter particles with n = 17 and 33), step counts from 0
/// to `usize::MAX`, any `max_halvings` up to `u32::MAX` within sub-step
/// budgets from 0 (refused) to the default, sampling intervals
/// from 0 to `usize::MAX`, hostile Newton and consistency options, and the
/// reference solver with hostile times, states and options.
#[derive(Clone, Debug)]
struct Extended {
    base: Input,
    large: Option<usize>,
    steps: usize,
    max_halvings: u32,
    max_substeps: usize,
    record_every: usize,
    consistency_tolerance: f64,
    newton_tolerance: f64,
    max_iterations: usize,
    simplified: bool,
    energy_drift_limit: Option<f64>,
    t_end: f64,
    reference_tolerance: f64,
    reference_max_steps: usize,
}

fn extended() -> impl Strategy<Value = Extended> {
    let counts = prop_oneof![
        4 => 0usize..6,
        1 => Just(17usize),
        1 => prop::sample::select(vec![usize::MAX, usize::MAX / 2, 1usize << 40]),
    ];
    (
        input(),
        prop_oneof![3 => Just(None), 1 => prop::sample::select(vec![17usize, 33]).prop_map(Some)],
        counts,
        (
            prop_oneof![3 => 0u32..=6, 1 => prop::sample::select(vec![60u32, 61, 1075, u32::MAX])],
            prop_oneof![3 => Just(DEFAULT_MAX_SUBSTEPS), 1 => 0usize..=64],
        ),
        prop_oneof![3 => 0usize..4, 1 => prop::sample::select(vec![7usize, usize::MAX])],
        (wild(), wild(), prop_oneof![3 => 1usize..30, 1 => prop::sample::select(vec![0usize, 1000, usize::MAX])]),
        (any::<bool>(), prop_oneof![2 => Just(Some(1.0)), 1 => Just(None), 1 => wild().prop_map(Some)]),
        (wild(), prop_oneof![3 => 1e-10f64..1e-4, 1 => wild()], prop_oneof![3 => 10usize..10_000, 1 => 0usize..3]),
    )
        .prop_map(
            |(
                base,
                large,
                steps,
                (max_halvings, max_substeps),
                record_every,
                (consistency_tolerance, newton_tolerance, max_iterations),
                (simplified, energy_drift_limit),
                (t_end, reference_tolerance, reference_max_steps),
            )| Extended {
                base,
                large,
                steps,
                max_halvings,
                max_substeps,
                record_every,
                consistency_tolerance,
                newton_tolerance,
                max_iterations,
                simplified,
                energy_drift_limit,
                t_end,
                reference_tolerance,
                reference_max_steps,
            },
        )
}

/// The step count a case runs. Counts beyond 64 are kept only where the run
/// must end early (a step size whose accumulated time overflows), so every
/// case stays short while the step-count and reservation arithmetic still
/// meets `usize::MAX`.
fn bounded_steps(x: &Extended) -> usize {
    // A step count beyond a few dozen is only exercised where the run cannot
    // get far: a step size whose accumulated time overflows, or a record
    // interval that makes the reserve arithmetic extreme.
    if x.steps > 64 && x.base.h.is_finite() && x.base.h.abs() <= 1e290 {
        x.steps % 64
    } else {
        x.steps
    }
}

fn exercise_extended<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(sys: Sys, x: &Extended)
where
    Sys: NonholonomicSystem<N, M>,
{
    let b = &x.base;
    let Ok(tableau) = Tableau::<S>::new(b.method) else { return };
    let q = Vector::<N>::from_fn(|i, _| b.q[i % b.q.len()]);
    let v = Vector::<N>::from_fn(|i, _| b.v[i % b.v.len()]);
    let finite = |s: &State<N>| s.t.is_finite() && s.q.iter().chain(s.v.iter()).all(|z| z.is_finite());
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, tableau);
    {
        let o = st.options_mut();
        o.tolerance = x.newton_tolerance;
        o.max_iterations = x.max_iterations;
        o.mode = if x.simplified { spark_runtime::NewtonMode::Simplified } else { spark_runtime::NewtonMode::Full };
        o.energy_drift_limit = x.energy_drift_limit;
    }
    let consistency = if b.project {
        ConsistencyPolicy::Project { tolerance: x.consistency_tolerance }
    } else {
        ConsistencyPolicy::Error { tolerance: x.consistency_tolerance }
    };
    let opts = RunOptions {
        consistency,
        max_halvings: x.max_halvings,
        max_substeps: x.max_substeps,
        record_every: x.record_every,
        ..RunOptions::default()
    };
    let schedule = Schedule::Fixed { h: b.h, steps: bounded_steps(x) };
    match st.integrate(b.t0, &q, &v, schedule, &opts, &mut NoObserver) {
        Ok(traj) => {
            assert!(traj.samples.iter().all(|s| finite(&State::new(s.t, s.q, s.v))), "non-finite sample");
            assert_eq!(traj.report.steps, bounded_steps(x), "a successful run takes every scheduled step");
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
    let sys = st.system();
    let ropts = spark_runtime::reference::ReferenceOptions {
        rtol: x.reference_tolerance,
        atol: x.reference_tolerance,
        max_steps: x.reference_max_steps,
        ..Default::default()
    };
    let t_end = if x.t_end.is_finite() { b.t0 + x.t_end.clamp(-2.0, 2.0) } else { x.t_end };
    match spark_runtime::reference::integrate(sys, b.t0, &q, &v, t_end, &ropts) {
        Ok(sol) => {
            for (qq, vv) in sol.q.iter().zip(&sol.v) {
                assert!(qq.iter().chain(vv.iter()).all(|z| z.is_finite()), "reference returned a non-finite state");
            }
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
}

macro_rules! by_stages_extended {
    ($sys:ty, $make:expr, $x:expr) => {
        match $x.base.stages {
            1 => {
                exercise_extended::<$sys, { <$sys>::N }, { <$sys>::M }, 1, { 1 * (<$sys>::N + <$sys>::M) + <$sys>::N }>(
                    $make, $x,
                )
            }
            _ => {
                exercise_extended::<$sys, { <$sys>::N }, { <$sys>::M }, 2, { 2 * (<$sys>::N + <$sys>::M) + <$sys>::N }>(
                    $make, $x,
                )
            }
        }
    };
}

fn dispatch_extended(x: &Extended) {
    use problems::systems::scaling::{McLachlanPerlmutter17, McLachlanPerlmutter33};
    match (x.large, x.base.system) {
        (Some(17), _) => by_stages_extended!(McLachlanPerlmutter17, McLachlanPerlmutter17::default(), x),
        (Some(_), _) => by_stages_extended!(McLachlanPerlmutter33, McLachlanPerlmutter33::default(), x),
        (None, 0) => by_stages_extended!(NonholonomicParticle, NonholonomicParticle::default(), x),
        (None, 1) => by_stages_extended!(Skate, Skate::default(), x),
        (None, 2) => by_stages_extended!(McLachlanPerlmutter7, McLachlanPerlmutter7::default(), x),
        (None, 3) => by_stages_extended!(TurntableSkate, TurntableSkate::default(), x),
        (None, 4) => by_stages_extended!(RollingDisk, RollingDisk::default(), x),
        (None, _) => by_stages_extended!(NearParallel, NearParallel { eps: x.base.params[0] * 1e-7 }, x),
    }
}

fn extended_cases() -> u32 {
    std::env::var("FUZZ_CASES_EXTENDED").ok().and_then(|s| s.parse().ok()).unwrap_or(1_500)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: extended_cases(), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn every_input_class_is_refused_or_integrated(x in extended()) {
        dispatch_extended(&x);
    }
}
