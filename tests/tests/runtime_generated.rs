//! The stepper on the systems `nonholonomic_system!` generates
//! (`problems::systems`): agreement with the hand-written implementations of
//! the paper's systems, and the general code path (time-dependent, affine
//! and nonlinear constraints, configuration-dependent mass, no constraints)
//! checked for order, constraint residual and reversibility against the
//! reference integrator.

use problems::systems::{
    AppellHamel, ChaplyginSleigh, DoublePendulum, McLachlanPerlmutter7, MobileRobot, NonholonomicParticle, Skate,
    TurntableSkate,
};
use spark_runtime::fixtures::paper;
use spark_runtime::reference::{integrate_at, ReferenceOptions};
use spark_runtime::{
    consistent_velocity, ConsistencyPolicy, Method, NonholonomicSystem, State, Stepper, Tableau, Vector,
};

fn trajectory<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    start: &State<N>,
    h: f64,
    steps: usize,
) -> Vec<State<N>>
where
    Sys: NonholonomicSystem<N, M>,
{
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap());
    let mut s = *start;
    (0..steps)
        .map(|_| {
            s = st.step(&s, h).unwrap().state;
            s
        })
        .collect()
}

fn max_diff<const N: usize>(a: &[State<N>], b: &[State<N>]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x.q - y.q).amax().max((x.v - y.v).amax())).fold(0.0, f64::max)
}

#[test]
fn generated_and_hand_written_paper_systems_agree() {
    let p0 = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let s0 = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let r0 = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    let m0 = State::new(
        0.0,
        Vector::<7>::from_row_slice(&[0.8, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]),
        Vector::<7>::from_row_slice(&[0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0]),
    );
    let mut report = Vec::new();
    for m in [Method::Gauss, Method::LobattoIIIABD] {
        let d = max_diff(
            &trajectory::<_, 3, 1, 3, 15>(NonholonomicParticle::default(), m, &p0, 0.2, 200),
            &trajectory::<_, 3, 1, 3, 15>(paper::Particle, m, &p0, 0.2, 200),
        );
        report.push(("particle", m, d));
        let d = max_diff(
            &trajectory::<_, 3, 1, 3, 15>(Skate::default(), m, &s0, 0.1, 200),
            &trajectory::<_, 3, 1, 3, 15>(paper::Skate::default(), m, &s0, 0.1, 200),
        );
        report.push(("skate", m, d));
        let d = max_diff(
            &trajectory::<_, 4, 2, 3, 22>(MobileRobot::default(), m, &r0, 0.2, 200),
            &trajectory::<_, 4, 2, 3, 22>(paper::MobileRobot::default(), m, &r0, 0.2, 200),
        );
        report.push(("robot", m, d));
        let d = max_diff(
            &trajectory::<_, 7, 1, 2, 23>(McLachlanPerlmutter7::default(), m, &m0, 0.05, 200),
            &trajectory::<_, 7, 1, 2, 23>(paper::MpParticles, m, &m0, 0.05, 200),
        );
        report.push(("MP particles", m, d));
    }
    println!("{report:?}");
    assert!(report.iter().all(|r| r.2 <= 1e-12), "generated vs hand-written: {report:?}");
}

/// Max errors over outputs every 0.5 up to 2.5 against the reference, with
/// `steps` steps per output; returns (err_q, err_v, max constraint residual).
fn errors<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: &Sys,
    method: Method,
    start: &State<N>,
    steps: usize,
) -> (f64, f64, f64)
where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let times: Vec<f64> = (1..=5).map(|k| start.t + 0.5 * k as f64).collect();
    let r = integrate_at(sys, start.t, &start.q, &start.v, &times, &ReferenceOptions::default()).unwrap();
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys.clone(), Tableau::new(method).unwrap());
    let h = 0.5 / steps as f64;
    let mut s = *start;
    let (mut eq, mut ev, mut res) = (0.0f64, 0.0f64, 0.0f64);
    for (qr, vr) in r.q.iter().zip(&r.v) {
        for _ in 0..steps {
            s = st.step(&s, h).unwrap().state;
            res = res.max(sys.constraint(s.t, &s.q, &s.v).amax());
        }
        eq = eq.max((s.q - qr).amax());
        ev = ev.max((s.v - vr).amax());
    }
    (eq, ev, res)
}

fn order_check<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    start: State<N>,
    steps: usize,
    failures: &mut Vec<String>,
) where
    Sys: NonholonomicSystem<N, M> + Clone,
{
    let name = Sys::SOURCE.name;
    let (q1, v1, r1) = errors::<Sys, N, M, S, D>(&sys, method, &start, steps);
    let (q2, v2, r2) = errors::<Sys, N, M, S, D>(&sys, method, &start, 2 * steps);
    let (oq, ov) = ((q1 / q2).log2(), (v1 / v2).log2());
    let p = method.order(S) as f64;
    println!("{name:22} {method:18} s={S}: q {q1:.2e}->{q2:.2e} order {oq:.3}, v {v1:.2e}->{v2:.2e} order {ov:.3}, |k| {:.1e}", r1.max(r2));
    // Appell–Hamel's falling particle moves with constant acceleration along
    // a fixed direction: every method here integrates it exactly (errors at
    // round-off), so there is no order to measure, only residual and reversibility.
    let exact = q1.max(v1) < 1e-12;
    if exact {
        println!("{name}: integrated to round-off, no order to measure");
    } else if (oq - p).abs() > 0.2 || (ov - p).abs() > 0.2 {
        failures.push(format!("{name} {method} s={S}: orders {oq:.3}/{ov:.3}, expected {p}"));
    }
    if r1.max(r2) > 1e-14 {
        failures.push(format!("{name} {method} s={S}: constraint residual {:.2e}", r1.max(r2)));
    }
    // Reversibility of the symmetric methods, on the general path too.
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap());
    let mut s = start;
    for _ in 0..50 {
        s = st.step(&s, 0.05).unwrap().state;
    }
    for _ in 0..50 {
        s = st.step(&s, -0.05).unwrap().state;
    }
    let back = (s.q - start.q).amax().max((s.v - start.v).amax());
    if back > 1e-12 {
        failures.push(format!("{name} {method} s={S}: forward-backward deviation {back:.2e}"));
    }
}

fn consistent<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize>(
    sys: &Sys,
    q: Vector<N>,
    v: Vector<N>,
) -> State<N> {
    let v = consistent_velocity(sys, 0.0, &q, &v, ConsistencyPolicy::Project { tolerance: 0.0 }).unwrap();
    State::new(0.0, q, v)
}

#[test]
fn general_code_path_orders_residual_and_reversibility() {
    let mut f = Vec::new();
    let tt = TurntableSkate::default();
    let tt0 = consistent(&tt, Vector::<3>::new(0.5, 0.0, 0.2), Vector::<3>::new(0.3, 0.1, 1.0));
    let ah = AppellHamel::default();
    // Falling (ż < 0) so that |ż| = a|(ẋ, ẏ)| grows: at ż = 0 the constraint
    // forces ẋ = ẏ = 0 and K = k_v vanishes (a genuine singularity).
    let ah0 = consistent(&ah, Vector::<3>::zeros(), Vector::<3>::new(1.0, 0.0, -0.5));
    let cs = ChaplyginSleigh::default();
    let cs0 = consistent(&cs, Vector::<3>::zeros(), Vector::<3>::new(1.0, 0.0, 0.5));
    let dp = DoublePendulum::default();
    let dp0 = State::new(0.0, Vector::<2>::new(0.5, 1.0), Vector::<2>::zeros());
    for m in [Method::Gauss, Method::LobattoIIIAB, Method::LobattoIIIABD] {
        if m == Method::Gauss {
            order_check::<_, 3, 1, 2, 11>(tt, m, tt0, 10, &mut f);
            order_check::<_, 3, 1, 2, 11>(ah, m, ah0, 10, &mut f);
            order_check::<_, 3, 1, 2, 11>(cs, m, cs0, 10, &mut f);
            order_check::<_, 2, 0, 2, 6>(dp, m, dp0, 20, &mut f);
        } else {
            order_check::<_, 3, 1, 3, 15>(tt, m, tt0, 10, &mut f);
            order_check::<_, 3, 1, 3, 15>(ah, m, ah0, 10, &mut f);
            order_check::<_, 3, 1, 3, 15>(cs, m, cs0, 10, &mut f);
            order_check::<_, 2, 0, 3, 8>(dp, m, dp0, 20, &mut f);
        }
    }
    assert!(f.is_empty(), "{}", f.join("\n"));
}

#[test]
fn stepper_macro_names_generated_systems() {
    let mut st: spark_runtime::Stepper![Skate, 3] =
        Stepper::new(Skate::default(), Tableau::new(Method::Gauss).unwrap());
    let r = st.step(&State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0)), 0.1).unwrap();
    assert!(r.iterations >= 1);
    let _: spark_runtime::Stepper![McLachlanPerlmutter7, 2] =
        Stepper::new(McLachlanPerlmutter7::default(), Tableau::new(Method::LobattoIIIBALda).unwrap());
    let _: spark_runtime::Stepper![DoublePendulum, 4] =
        Stepper::new(DoublePendulum::default(), Tableau::new(Method::LobattoIIIABD).unwrap());
}
