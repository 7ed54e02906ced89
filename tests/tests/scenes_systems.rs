//! Systems declared with effects and scenes on the stepper: a
//! holonomic scene against the hand-written system, the vertical rolling disk
//! against its exact solution, the ball on a turntable against its exact
//! invariant (constant Ω) and the reference ODE (Ω(t)), and the scenes of
//! `Body` (constraint count, energy).

use problems::systems::scenes::{BallOnTurntable, BodyRailed, BodySkating, BodySprung, RodPendulum, VerticalDisk};
use spark_runtime::fixtures::effects::RodPendulum as HandRod;
use spark_runtime::reference::{integrate_at, ReferenceOptions};
use spark_runtime::{Method, NonholonomicSystem, State, Stepper, Tableau, Vector};

fn run<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    start: State<N>,
    h: f64,
    steps: usize,
) -> Vec<State<N>>
where
    Sys: NonholonomicSystem<N, M>,
{
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap());
    let mut out = vec![start];
    for _ in 0..steps {
        let next = st.step(out.last().unwrap(), h).unwrap().state;
        out.push(next);
    }
    out
}

#[test]
fn holonomic_scene_matches_the_hand_written_pendulum_and_its_drift_is_measured() {
    let p = State::new(0.0, Vector::<2>::new(0.6, -0.8), Vector::<2>::new(0.8, 0.6));
    let dsl = run::<_, 2, 1, 2, 8>(RodPendulum::default(), Method::Gauss, p, 0.1, 50);
    let hand = run::<_, 2, 1, 2, 8>(HandRod::default(), Method::Gauss, p, 0.1, 50);
    let diff = dsl.iter().zip(&hand).map(|(a, b)| (a.q - b.q).amax().max((a.v - b.v).amax())).fold(0.0, f64::max);
    assert!(diff < 1e-12, "scene vs hand-written: {diff:e}");
    // Drift of g = ½(|q|² − ℓ²) with a method that does not conserve it: O(h).
    let rod = HandRod::default();
    let drift = |h: f64, n: usize| {
        let states = run::<_, 2, 1, 1, 5>(RodPendulum::default(), Method::SymplecticEulerI, p, h, n);
        states.iter().map(|s| rod.holonomic_residual(s.t, &s.q).amax()).fold(0.0, f64::max)
    };
    let (d1, d2) = (drift(0.02, 250), drift(0.01, 500));
    assert!(d1 > 1e-6 && d1 / d2 > 1.6 && d1 / d2 < 2.5, "drift {d1:e} (h), {d2:e} (h/2)");
}

#[test]
fn vertical_disk_follows_its_exact_solution() {
    let disk = VerticalDisk::default();
    let (theta_dot, phi_dot, r) = (0.7, 1.3, disk.radius);
    let th0: f64 = 0.4;
    let q0 = Vector::<4>::new(0.2, -0.1, th0, 0.0);
    let v0 = Vector::<4>::new(r * th0.cos() * phi_dot, r * th0.sin() * phi_dot, theta_dot, phi_dot);
    let error = |h: f64, n: usize| {
        let end = *run::<_, 4, 2, 2, 16>(disk, Method::Gauss, State::new(0.0, q0, v0), h, n).last().unwrap();
        let th = th0 + theta_dot * end.t;
        let rho = r * phi_dot / theta_dot;
        let exact = Vector::<4>::new(
            q0[0] + rho * (th.sin() - th0.sin()),
            q0[1] - rho * (th.cos() - th0.cos()),
            th,
            phi_dot * end.t,
        );
        (end.q - exact).amax()
    };
    let (e1, e2) = (error(0.2, 20), error(0.1, 40));
    // Measured: 1.5e-6 and 9.6e-8 (order 4).
    assert!(e1 < 1e-5 && e1 / e2 > 12.0, "disk: {e1:e}, {e2:e}");
}

#[test]
fn ball_on_a_turntable_circles_at_the_predicted_rate_and_matches_the_reference() {
    let mut ball = BallOnTurntable { eps: 0.0, ..BallOnTurntable::default() };
    let (x, y) = (0.5, 0.2);
    let q0 = Vector::<5>::new(x, y, 0.1, 1.4, 0.3);
    // Choose θ̇, ψ̇ (φ̇ = 0.2) so the constraints hold: solve for ω_x, ω_y.
    let (phi, theta) = (q0[2], q0[3]);
    let (vx, vy) = (0.3, -0.1);
    let wy = (vx + ball.omega * y) / ball.r;
    let wx = (ball.omega * x - vy) / ball.r;
    // [wx; wy] = [[cos φ, sin θ sin φ], [sin φ, −sin θ cos φ]] [θ̇; ψ̇].
    let det = -theta.sin();
    let td = (-theta.sin() * phi.cos() * wx - theta.sin() * phi.sin() * wy) / det;
    let pd = (phi.cos() * wy - phi.sin() * wx) / det;
    let v0 = Vector::<5>::new(vx, vy, 0.2, td, pd);
    let start = State::new(0.0, q0, v0);
    assert!(ball.constraint(0.0, &q0, &v0).amax() < 1e-14);
    let rate = ball.omega * ball.inertia / (ball.inertia + ball.m * ball.r * ball.r);
    let angle = |v: &Vector<5>| v[1].atan2(v[0]);
    let speed = |v: &Vector<5>| v[0].hypot(v[1]);
    // Angle the center's velocity turned vs Ω I/(I + m r²)·t and the change
    // of its speed (exactly 0), at h and h/2.
    let rate_error = |h: f64, n: usize| {
        let end = *run::<_, 5, 2, 2, 19>(ball, Method::Gauss, start, h, n).last().unwrap();
        let turned = angle(&end.v) - angle(&v0);
        let speed_error = (speed(&end.v) - speed(&v0)).abs();
        (turned - rate * end.t).abs().max(speed_error)
    };
    let (r1, r2) = (rate_error(0.05, 100), rate_error(0.025, 200));
    // Measured: 1.1e-5 at h = 0.05 over t = 5.
    assert!(r1 < 3e-5 && r1 / r2 > 12.0, "turning-rate/speed errors {r1:e} (h), {r2:e} (h/2)");
    // Ω(t) varying: against the reference ODE, error falling at order 4.
    ball.eps = 0.3;
    let v0 = spark_runtime::consistent_velocity(
        &ball,
        0.0,
        &q0,
        &v0,
        spark_runtime::ConsistencyPolicy::Project { tolerance: 1.0 },
    )
    .unwrap();
    let start = State::new(0.0, q0, v0);
    let reference = integrate_at(&ball, 0.0, &q0, &v0, &[2.0], &ReferenceOptions::default()).unwrap();
    let err = |h: f64, n: usize| {
        let end = *run::<_, 5, 2, 2, 19>(ball, Method::Gauss, start, h, n).last().unwrap();
        (end.q - reference.q[0]).amax().max((end.v - reference.v[0]).amax())
    };
    let (e1, e2) = (err(0.1, 20), err(0.05, 40));
    // Measured: 2.7e-4 and 1.7e-5 (ratio 15.5, order 4).
    assert!(e1 < 5e-4 && e1 / e2 > 12.0, "ball vs reference: {e1:e}, {e2:e}");
}

#[test]
fn body_scenes_carry_only_their_constraints_and_conserve_what_they_should() {
    assert_eq!((BodySprung::M, BodySkating::M, BodyRailed::M), (0, 1, 2));
    assert!(BodySkating::STRUCTURE.autonomous() && !BodyRailed::STRUCTURE.autonomous());
    let sys = BodySkating::default();
    let th: f64 = 0.3;
    let start = State::new(0.0, Vector::<3>::new(0.5, 0.0, th), Vector::<3>::new(th.cos(), th.sin(), 0.7));
    let states = run::<_, 3, 1, 2, 11>(sys, Method::Gauss, start, 0.05, 200);
    let e0 = sys.energy(0.0, &start.q, &start.v);
    let drift = states.iter().map(|s| (sys.energy(s.t, &s.q, &s.v) - e0).abs()).fold(0.0, f64::max);
    assert!(drift < 1e-6, "energy drift {drift:e}");
}

#[test]
fn a_scene_has_the_operation_counts_of_its_hand_declaration() {
    use problems::systems::scenes::{body_scene_table, BodySkatingByHand};
    assert_eq!(BodySkating::OPERATIONS, BodySkatingByHand::OPERATIONS);
    let table = body_scene_table();
    let jac: Vec<usize> = table.iter().map(|r| r.3.stage_jacobians).collect();
    // Free ≤ Sprung < Skating < Railed: each added effect costs.
    assert!(jac[0] <= jac[1] && jac[1] < jac[2] && jac[2] < jac[3], "{table:?}");
}
