//! Dense output: measured order of the continuous extension between grid
//! points, against the independent reference integrator, on the paper's four
//! systems for every family of `Method::ALL`: Gauss (s = 1..4), symplectic
//! Euler I and II (s = 1), modified Lobatto IIIA-B and Lobatto IIIB-A LDA
//! (s = 2), Lobatto IIIA-B and IIIA-B-D (s = 2..4), and the constraint
//! residual `max |k|` between grid points.
//!
//! `Schedule::Sampled` keeps `h` fixed and samples off-grid times (fractions
//! 0.17, 0.45 and 0.83 of a step, shifted per output interval), so every error
//! comes from the interpolants, not from the step's end points. The order is
//! `log₂` of the error ratio from `h` to `h/2`. The documented lower bounds
//! (docs/dense-output-and-events.md, derived in [`documented`]), each at
//! most the global order:
//! - positions: `s` (the stage order) for every family;
//! - velocities: `s` for Gauss, `s − 1` for Lobatto IIIA-B and IIIA-B-D with
//!   `s ≥ 3`, 2 for the families without an interior node (symplectic Euler
//!   I, II, and every `s = 2` Lobatto family: a straight line through the
//!   end velocities),
//!
//! and the test requires every measured order to be at least its bound minus
//! 0.3 (the printed table is the one in the docs).

use spark_runtime::dense::DenseBasis;
use spark_runtime::fixtures::paper::{MobileRobot, MpParticles, Particle, Skate};
use spark_runtime::reference::{integrate_at, ReferenceOptions};
use spark_runtime::{Method, NoObserver, NonholonomicSystem, RunOptions, Schedule, State, Stepper, Tableau, Vector};

/// Sample times: three per output interval of length `span / outputs`.
fn sample_times(t_end: f64, outputs: usize, h_coarse: f64) -> Vec<f64> {
    let mut times = Vec::new();
    for k in 0..outputs {
        let base = t_end * k as f64 / outputs as f64;
        for f in [0.17, 0.45, 0.83] {
            // Inside a coarse step, and never on a grid point of h or h/2.
            times.push(base + f * h_coarse);
        }
    }
    times
}

struct Measured {
    q: f64,
    v: f64,
    residual: f64,
}

fn dense_errors<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: &Sys,
    method: Method,
    start: &State<N>,
    h: f64,
    times: &[f64],
    reference: &[(Vector<N>, Vector<N>)],
) -> Measured
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys.clone(), Tableau::new(method).unwrap());
    let traj = st
        .integrate(start.t, &start.q, &start.v, Schedule::Sampled { h, times }, &RunOptions::default(), &mut NoObserver)
        .unwrap();
    assert_eq!(traj.samples.len(), times.len() + 1);
    let (mut q, mut v, mut residual) = (0.0f64, 0.0f64, 0.0f64);
    for (s, (qr, vr)) in traj.samples[1..].iter().zip(reference) {
        q = q.max((s.q - qr).amax());
        v = v.max((s.v - vr).amax());
        residual = residual.max(s.constraint_residual.unwrap());
    }
    Measured { q, v, residual }
}

/// Documented lower bounds of the dense-output orders (positions,
/// velocities), derived from the interpolants of `basis` and each at most the
/// global order `p` (the interpolants start from grid states accurate to `p`
/// only):
/// - positions: `q₀ + h Σ β_j(θ) V_j` with the stage velocities, accurate to
///   the stage order `s` of every family;
/// - velocities: the polynomial of degree `d = basis.velocity_degree()`
///   through `v₀`, the `d − 1` interior stage velocities and `v₁`. Its
///   interpolation error is `O(h^{d+1})`; with interior nodes, their stage
///   velocities' accuracy bounds it too (stage order `s` for Gauss, `s − 1`
///   for the Lobatto IIIA-B and IIIA-B-D stage velocities). Without interior
///   nodes (`d = 1`: symplectic Euler, every `s = 2` Lobatto family) it is
///   the straight line through the grid velocities, order `min(2, p)`.
fn documented<const S: usize>(method: Method, basis: &DenseBasis<S>) -> (f64, f64) {
    let (s, p) = (S as f64, method.order(S) as f64);
    let degree = basis.velocity_degree();
    let interpolation = (degree + 1) as f64;
    let stages = match method {
        Method::Gauss => s,
        Method::LobattoIIIAB | Method::LobattoIIIABD => s - 1.0,
        // Only the end nodes (s = 1 at c = 0 or 1, or the nodes 0, 1 at
        // s = 2): no stage velocity enters the velocity interpolant.
        Method::SymplecticEulerI
        | Method::SymplecticEulerII
        | Method::ModifiedLobattoIIIAB
        | Method::LobattoIIIBALda => interpolation,
    };
    let v = if degree == 1 { interpolation } else { stages.min(interpolation) };
    (s.min(p), v.min(p))
}

#[allow(clippy::too_many_arguments)]
fn row<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: &Sys,
    method: Method,
    start: &State<N>,
    t_end: f64,
    steps: usize,
    failures: &mut Vec<String>,
    rows: &mut Vec<String>,
) where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let outputs = 10;
    let h = t_end / (outputs * steps) as f64;
    let times = sample_times(t_end, outputs, h);
    let r = integrate_at(sys, start.t, &start.q, &start.v, &times, &ReferenceOptions::default()).unwrap();
    let reference: Vec<_> = r.q.into_iter().zip(r.v).collect();
    let coarse = dense_errors::<Sys, N, M, S, D>(sys, method, start, h, &times, &reference);
    let fine = dense_errors::<Sys, N, M, S, D>(sys, method, start, h / 2.0, &times, &reference);
    let (oq, ov) = ((coarse.q / fine.q).log2(), (coarse.v / fine.v).log2());
    let (dq, dv) = documented(method, &DenseBasis::new(&Tableau::<S>::new(method).unwrap()));
    rows.push(format!(
        "| {} | {} | {S} | {h:.4} | {:.2e} | {oq:.2} ({dq}) | {:.2e} | {ov:.2} ({dv}) | {:.1e} |",
        Sys::SOURCE.name,
        method.name(),
        fine.q,
        fine.v,
        coarse.residual.max(fine.residual)
    ));
    for (what, o, d) in [("q", oq, dq), ("v", ov, dv)] {
        if o < d - 0.3 || o.is_nan() {
            failures.push(format!("{} {method} s={S} dense {what}: order {o:.2}, documented {d}", Sys::SOURCE.name));
        }
    }
}

macro_rules! families {
    ($sys:expr, $n:literal, $m:literal, $start:expr, $t:expr, $steps:expr, $f:expr, $rows:expr) => {{
        let sys = $sys;
        let start = $start;
        let st = $steps;
        row::<_, $n, $m, 1, { 1 * ($n + $m) + $n }>(&sys, Method::Gauss, &start, $t, st, $f, $rows);
        row::<_, $n, $m, 2, { 2 * ($n + $m) + $n }>(&sys, Method::Gauss, &start, $t, st, $f, $rows);
        row::<_, $n, $m, 3, { 3 * ($n + $m) + $n }>(&sys, Method::Gauss, &start, $t, st, $f, $rows);
        row::<_, $n, $m, 4, { 4 * ($n + $m) + $n }>(&sys, Method::Gauss, &start, $t, st, $f, $rows);
        for method in [Method::SymplecticEulerI, Method::SymplecticEulerII] {
            row::<_, $n, $m, 1, { 1 * ($n + $m) + $n }>(&sys, method, &start, $t, st, $f, $rows);
        }
        for method in [Method::ModifiedLobattoIIIAB, Method::LobattoIIIBALda] {
            row::<_, $n, $m, 2, { 2 * ($n + $m) + $n }>(&sys, method, &start, $t, st, $f, $rows);
        }
        for method in [Method::LobattoIIIAB, Method::LobattoIIIABD] {
            row::<_, $n, $m, 2, { 2 * ($n + $m) + $n }>(&sys, method, &start, $t, st, $f, $rows);
            row::<_, $n, $m, 3, { 3 * ($n + $m) + $n }>(&sys, method, &start, $t, st, $f, $rows);
            row::<_, $n, $m, 4, { 4 * ($n + $m) + $n }>(&sys, method, &start, $t, st, $f, $rows);
        }
    }};
}

#[test]
fn dense_output_orders_on_the_paper_systems() {
    let mut failures = Vec::new();
    let mut rows = vec![
        "| system | method | s | h | err q | order q (doc) | err v | order v (doc) | max abs k between grid points |"
            .to_string(),
        "|---|---|---|---|---|---|---|---|---|".to_string(),
    ];
    let particle = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    families!(Particle, 3, 1, particle, 5.0, 8, &mut failures, &mut rows);
    let skate = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    families!(Skate::default(), 3, 1, skate, 5.0, 8, &mut failures, &mut rows);
    let robot = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    families!(MobileRobot::default(), 4, 2, robot, 5.0, 8, &mut failures, &mut rows);
    let mp = State::new(
        0.0,
        Vector::<7>::from_row_slice(&[0.8, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]),
        Vector::<7>::from_row_slice(&[0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0]),
    );
    families!(MpParticles, 7, 1, mp, 5.0, 8, &mut failures, &mut rows);
    println!("{}", rows.join("\n"));
    assert!(failures.is_empty(), "dense-output orders below the documented ones:\n{}", failures.join("\n"));
}

/// Records every dense step's ends and a midpoint sample.
struct Dense {
    steps: Vec<(State<3>, State<3>, State<3>)>,
}

impl spark_runtime::Observer<3, 1> for Dense {
    const DENSE: bool = true;
    fn observe<Sys: spark_runtime::NonholonomicSystem<3, 1>>(&mut self, _: &Sys, _: &State<3>, _: usize) {}
    fn observe_dense<const S: usize>(&mut self, step: &spark_runtime::DenseStep<'_, 3, S>) {
        let mid = 0.5 * (step.start.t + step.end.t);
        self.steps.push((step.state_at(step.start.t), step.state_at(step.end.t), step.state_at(mid)));
    }
}

#[test]
fn sampled_schedules_keep_h_and_agree_with_the_grid() {
    let start = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let mut st = Stepper::<Particle, 3, 1, 2, 11>::new(Particle, Tableau::new(Method::Gauss).unwrap());
    let fixed = st
        .integrate(
            0.0,
            &start.q,
            &start.v,
            Schedule::Fixed { h: 0.1, steps: 10 },
            &RunOptions::default(),
            &mut NoObserver,
        )
        .unwrap();
    // Grid times sampled through the dense output are the grid states, bit for bit.
    let times: Vec<f64> = (1..=10).map(|k| k as f64 * 0.1).collect();
    let sampled = st
        .integrate(
            0.0,
            &start.q,
            &start.v,
            Schedule::Sampled { h: 0.1, times: &times },
            &RunOptions::default(),
            &mut NoObserver,
        )
        .unwrap();
    assert_eq!(sampled.report.steps, 10);
    for (a, b) in fixed.samples.iter().zip(&sampled.samples) {
        assert_eq!((a.t, a.q, a.v), (b.t, b.q, b.v));
    }
    // Off-grid times do not change the steps: the run takes ⌈0.95/0.1⌉ = 10 steps of 0.1.
    let off = [0.05, 0.33, 0.95];
    let traj = st
        .integrate(
            0.0,
            &start.q,
            &start.v,
            Schedule::Sampled { h: 0.1, times: &off },
            &RunOptions::default(),
            &mut NoObserver,
        )
        .unwrap();
    assert_eq!(traj.report.steps, 10);
    let got: Vec<f64> = traj.samples.iter().map(|s| s.t).collect();
    assert_eq!(got, [0.0, 0.05, 0.33, 0.95]);
    // Backward.
    let back = [-0.05, -0.25];
    let traj = st
        .integrate(
            0.0,
            &start.q,
            &start.v,
            Schedule::Sampled { h: -0.1, times: &back },
            &RunOptions::default(),
            &mut NoObserver,
        )
        .unwrap();
    assert_eq!(traj.report.steps, 3);
    assert_eq!(traj.samples.len(), 3);
    // Unusable schedules are errors, not panics.
    for (h, times) in [(0.1, &[0.3, 0.2][..]), (0.1, &[-0.1][..]), (0.0, &[0.1][..]), (0.1, &[f64::NAN][..])] {
        let r = st.integrate(
            0.0,
            &start.q,
            &start.v,
            Schedule::Sampled { h, times },
            &RunOptions::default(),
            &mut NoObserver,
        );
        assert!(matches!(r, Err(spark_runtime::IntegrationError::InvalidSchedule(_))), "h = {h}, times = {times:?}");
    }
}

#[test]
fn dense_observers_see_every_step_continuously() {
    let start = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    for method in [Method::Gauss, Method::LobattoIIIAB] {
        let mut st = Stepper::<Particle, 3, 1, 2, 11>::new(Particle, Tableau::new(method).unwrap());
        let mut obs = Dense { steps: Vec::new() };
        let traj = st
            .integrate(0.0, &start.q, &start.v, Schedule::Fixed { h: 0.2, steps: 5 }, &RunOptions::default(), &mut obs)
            .unwrap();
        assert_eq!(obs.steps.len(), 5);
        for (k, (a, b, mid)) in obs.steps.iter().enumerate() {
            let (s0, s1) = (&traj.samples[k], &traj.samples[k + 1]);
            assert_eq!((a.q, a.v), (s0.q, s0.v), "{method}: start of step {k}");
            assert_eq!((b.q, b.v), (s1.q, s1.v), "{method}: end of step {k}");
            // The midpoint lies between, close to both ends' average.
            assert!((mid.q - 0.5 * (a.q + b.q)).amax() < 0.05, "{method}: midpoint of step {k}");
        }
    }
}

/// The steps of a `Sampled` schedule end at `t₀ + k·h` as rounded, so
/// `⌈(t_last − t₀)/h⌉` steps can end just short of the last time: with
/// `h = 0.2`, `(30.000000000000004 − 0)/0.2` rounds to 150 and 150 steps end
/// at 30.0. The run takes one step more and samples every requested time
/// (the last one included), forward and backward, and times
/// whose gaps times `h` underflow to 0 are still seen as monotone.
#[test]
fn sampled_schedules_sample_a_last_time_the_rounded_step_count_falls_short_of() {
    let start = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let mut st = Stepper::<Particle, 3, 1, 2, 11>::new(Particle, Tableau::new(Method::Gauss).unwrap());
    for (h, times) in [(0.2, [1.0, 30.000000000000004]), (-0.2, [-1.0, -30.000000000000004])] {
        let traj = st
            .integrate(
                0.0,
                &start.q,
                &start.v,
                Schedule::Sampled { h, times: &times },
                &RunOptions::default(),
                &mut NoObserver,
            )
            .unwrap();
        let got: Vec<f64> = traj.samples.iter().map(|s| s.t).collect();
        assert_eq!(got, [0.0, times[0], times[1]], "h = {h}");
        assert_eq!(traj.report.steps, 151, "h = {h}");
    }
    // (t − t₀)·h and (t₂ − t₁)·h underflow to 0 here; the times are increasing.
    let times = [1e-175, 2e-175];
    let traj = st
        .integrate(
            0.0,
            &start.q,
            &start.v,
            Schedule::Sampled { h: 1e-150, times: &times },
            &RunOptions::default(),
            &mut NoObserver,
        )
        .unwrap();
    let got: Vec<f64> = traj.samples.iter().map(|s| s.t).collect();
    assert_eq!(got, [0.0, 1e-175, 2e-175]);
}

/// The samples of a `Sampled` run are the initial point and one per
/// requested time, a time at `t₀` included: with later times the first
/// step's extension records it; alone it takes no step, and the run still
/// records it beside the initial point (two samples for one time, not one).
#[test]
fn a_sampled_time_at_the_start_is_a_sample_of_its_own() {
    let start = State::new(0.5, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let mut st = Stepper::<Particle, 3, 1, 2, 11>::new(Particle, Tableau::new(Method::Gauss).unwrap());
    for (h, times) in [(0.1, vec![0.5]), (0.1, vec![0.5, 0.62]), (-0.1, vec![0.5]), (-0.1, vec![0.5, 0.3])] {
        let schedule = Schedule::Sampled { h, times: &times };
        let traj = st.integrate(0.5, &start.q, &start.v, schedule, &RunOptions::default(), &mut NoObserver).unwrap();
        let got: Vec<f64> = traj.samples.iter().map(|s| s.t).collect();
        let expected: Vec<f64> = std::iter::once(0.5).chain(times.iter().copied()).collect();
        assert_eq!(got, expected, "h = {h}, times = {times:?}");
        assert_eq!((traj.samples[1].q, traj.samples[1].v), (start.q, start.v), "h = {h}, times = {times:?}");
    }
}
