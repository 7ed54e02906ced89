//! The end-point functions `nonholonomic_system!` generates — the momentum
//! and the constraint alone, with and without the constraint Jacobians and
//! the parameter terms — return the bits the full stage functions write
//! there, whether an angle pairs its sine and cosine in the full body and
//! not in the end point's (the force holds the sine, the constraint the
//! cosine), and the lane kernel, which evaluates the end point with the full
//! lane body, still steps each member as its stepper does alone.

use spark_runtime::{
    integrate_ensemble, nonholonomic_system, LaneStepper, Matrix, Method, NewtonMode, NewtonOptions, NoObserver,
    NonholonomicSystem, RunOptions, Schedule, StageValues, State, Stepper, Tableau, Vector,
};

nonholonomic_system! {
    /// A sleigh on a corrugated floor: the potential `−cos θ` puts `sin θ`
    /// into the force, the blade's constraint has `cos θ` alone, so the
    /// full stage body pairs the two and the end point's has a lone cosine.
    pub struct CorrugatedSleigh {
        coordinates: [x, y, theta],
        parameters: { m = 1.2, inertia = 0.4, depth = 0.8, g = 1.0 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + inertia/2*dot(theta)^2 + depth*g*m*cos(theta) - x^2/2,
        constraints: [ cos(theta)*dot(y) - dot(x)*exp(-y^2/4) ],
    }
}

// The paper's skate (its parameter term `m g sin β` enters the force alone)
// and mobile robot (its force's `cos φ` enters no end point), as the
// examples declare them.
#[path = "../../examples/common/paper_systems.rs"]
mod paper_systems;
use paper_systems::{MobileRobot, Skate};

/// Points spread over several periods of the angles, with ψ ≠ 0 for the
/// full functions (the end point's values do not depend on it).
fn points<const N: usize, const M: usize>() -> Vec<(f64, Vector<N>, Vector<N>, Vector<M>)> {
    (0..200)
        .map(|k| {
            let x = |i: usize, scale: f64| ((k * 7 + i * 13) as f64 * 0.61).sin() * scale;
            let q = Vector::<N>::from_fn(|i, _| x(i, 9.0));
            let v = Vector::<N>::from_fn(|i, _| x(i + N, 2.0));
            let psi = Vector::<M>::from_fn(|i, _| x(i + 2 * N, 3.0));
            (0.1 * k as f64, q, v, psi)
        })
        .collect()
}

fn bits<const R: usize, const C: usize>(m: &Matrix<R, C>) -> Vec<u64> {
    m.iter().map(|x| x.to_bits()).collect()
}

/// Every end-point function against the full stage functions, bit for bit,
/// in the momentum, the constraint and the constraint Jacobians.
fn end_point_values_equal_the_stage_values<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize>(sys: &Sys) {
    let mut terms = vec![0.0; Sys::PARAMETER_TERMS];
    sys.parameter_terms(&mut terms);
    for (t, q, v, psi) in points::<N, M>() {
        let mut full = StageValues::<N, M>::zeros();
        let (mut kq, mut kv) = (Matrix::<M, N>::zeros(), Matrix::<M, N>::zeros());
        sys.stage_values_and_constraint_jacobians(t, &q, &v, &psi, &mut full, &mut kq, &mut kv);
        let want = (bits(&full.momentum), bits(&full.constraint), bits(&kq), bits(&kv));
        let at = format!("{} at t = {t}, q = {q:?}, v = {v:?}", Sys::SOURCE.name);
        let mut end = StageValues::<N, M>::zeros();
        sys.end_point_values_into(t, &q, &v, &mut end);
        assert_eq!((bits(&end.momentum), bits(&end.constraint)), (want.0.clone(), want.1.clone()), "{at}");
        let mut end = StageValues::<N, M>::zeros();
        sys.end_point_values_with_terms(&terms, t, &q, &v, &mut end);
        assert_eq!((bits(&end.momentum), bits(&end.constraint)), (want.0.clone(), want.1.clone()), "{at}, terms");
        for with_terms in [false, true] {
            let mut end = StageValues::<N, M>::zeros();
            let (mut eq, mut ev) = (Matrix::<M, N>::zeros(), Matrix::<M, N>::zeros());
            if with_terms {
                sys.end_point_values_and_constraint_jacobians_with_terms(&terms, t, &q, &v, &mut end, &mut eq, &mut ev);
            } else {
                sys.end_point_values_and_constraint_jacobians(t, &q, &v, &mut end, &mut eq, &mut ev);
            }
            let got = (bits(&end.momentum), bits(&end.constraint), bits(&eq), bits(&ev));
            assert_eq!(got, want, "{at}, with the constraint Jacobians (terms: {with_terms})");
        }
    }
}

#[test]
fn end_point_functions_return_the_full_stage_functions_bits() {
    end_point_values_equal_the_stage_values::<_, 3, 1>(&CorrugatedSleigh::default());
    end_point_values_equal_the_stage_values::<_, 4, 2>(&MobileRobot::default());
    end_point_values_equal_the_stage_values::<_, 3, 1>(&Skate::default());
    const { assert!(Skate::PARAMETER_TERMS > 0 && CorrugatedSleigh::PARAMETER_TERMS > 0) };
}

/// A sleigh whose end point has a lone cosine where its stages pair it:
/// six members in lanes (which evaluate the end point with the full lane
/// body) end bit for bit where each ends alone, Lobatto IIIA-B s = 2 with
/// simplified Newton on the stage-decoupled matrix, the kernel taking every
/// step after the first two.
#[test]
fn members_in_lanes_match_their_solo_runs_with_a_lone_cosine_at_the_end_point() {
    let sys = CorrugatedSleigh::default();
    let starts: Vec<State<3>> = (0..6)
        .map(|j| {
            let theta = 0.4 * j as f64 - 1.0;
            let v = Vector::<3>::new(0.5 * theta.cos(), 0.3, 0.2 + 0.1 * j as f64);
            let mut start = State::new(0.0, Vector::<3>::new(0.2, 0.0, theta), v);
            // Consistent: ẋ = cos θ ẏ at y = 0.
            start.v[0] = theta.cos() * start.v[1];
            start
        })
        .collect();
    let opts = NewtonOptions { mode: NewtonMode::Simplified, ..NewtonOptions::default() };
    let (h, steps) = (0.05, 200);
    let method = Method::LobattoIIIAB;
    {
        let tab = Tableau::<2>::new(method).unwrap();
        let runs = integrate_ensemble::<_, 3, 1, 2, 11>(&sys, tab, opts, &starts, h, steps, 0).unwrap();
        let mut lanes = LaneStepper::<CorrugatedSleigh, 3, 1, 2, 11, 8>::new(sys, tab, opts);
        lanes.start(&starts, h).unwrap();
        lanes.advance_by(steps);
        for (j, (run, start)) in runs.iter().zip(&starts).enumerate() {
            let mut alone = Stepper::<CorrugatedSleigh, 3, 1, 2, 11>::new(sys, tab).with_options(opts);
            let record = RunOptions { record_every: steps, ..RunOptions::default() };
            let schedule = Schedule::Fixed { h, steps };
            let traj = alone.integrate(start.t, &start.q, &start.v, schedule, &record, &mut NoObserver).unwrap();
            let (a, b) = (run.samples.last().unwrap(), traj.samples.last().unwrap());
            let bits = |q: &Vector<3>, v: &Vector<3>| (q.map(f64::to_bits), v.map(f64::to_bits));
            assert!(bits(&a.q, &a.v) == bits(&b.q, &b.v), "{method:?} member {j}: {a:?} in lanes, {b:?} alone");
            assert_eq!(lanes.kernel_steps(j), Some(steps - 2), "{method:?} member {j}");
        }
    }
}
