//! The paper's four experiments (§8.1–8.4) at the paper's step sizes: Newton
//! iterations from a warm start average at most 4 per step, the constraint
//! residual stays ≤ 1e-14 after every step, the energy error stays bounded;
//! and symmetric methods retrace their steps while the Euler methods do not.

use spark_runtime::fixtures::paper::{MobileRobot, MpParticles, Particle, Skate};
use spark_runtime::{
    Method, NewtonOptions, NoObserver, NonholonomicSystem, Observe, RunOptions, RunReport, Schedule, State, Stepper,
    Tableau, Vector,
};

fn run<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    start: &State<N>,
    h: f64,
    t_end: f64,
) -> RunReport
where
    Sys: NonholonomicSystem<N, M>,
{
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap());
    let steps = ((t_end - start.t) / h).round() as usize;
    let opts = RunOptions {
        observe: Observe { energy: true, constraint_residual: true, multipliers: false },
        record_every: 1,
        ..RunOptions::default()
    };
    let tr = st.integrate(start.t, &start.q, &start.v, Schedule::Fixed { h, steps }, &opts, &mut NoObserver).unwrap();
    let r = tr.report;
    println!(
        "{:12} {:26} s={S} h={h}: {} steps, Newton mean {:.3} max {} (cold starts {}), max |k| {:.2e}, max |E-E0| {:.2e}",
        Sys::SOURCE.name,
        method.name(),
        r.steps,
        r.newton_iterations_mean,
        r.newton_iterations_max,
        r.cold_starts,
        r.max_constraint_residual,
        r.max_energy_error
    );
    r
}

fn check(r: &RunReport, what: &str, energy_bound: f64, failures: &mut Vec<String>) {
    if r.newton_iterations_mean > 4.0 {
        failures.push(format!("{what}: mean Newton iterations {:.3} > 4", r.newton_iterations_mean));
    }
    if r.max_constraint_residual > 1e-14 {
        failures.push(format!("{what}: constraint residual {:.2e} > 1e-14", r.max_constraint_residual));
    }
    if r.max_energy_error > energy_bound {
        failures.push(format!("{what}: energy error {:.2e} > {energy_bound:.0e}", r.max_energy_error));
    }
}

#[test]
fn paper_experiments_newton_constraint_and_energy() {
    let mut f = Vec::new();
    // §8.1: Gauss s = 1, 2, 3, h = 0.2 on [0, 250].
    let p0 = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    check(&run::<_, 3, 1, 1, 7>(Particle, Method::Gauss, &p0, 0.2, 250.0), "particle Gauss 1", 1e-1, &mut f);
    check(&run::<_, 3, 1, 2, 11>(Particle, Method::Gauss, &p0, 0.2, 250.0), "particle Gauss 2", 1e-3, &mut f);
    check(&run::<_, 3, 1, 3, 15>(Particle, Method::Gauss, &p0, 0.2, 250.0), "particle Gauss 3", 1e-5, &mut f);
    // §8.2: Lobatto IIIA-B s = 2, 3, 4, h = 0.1 on [0, 100].
    let s0 = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let sk = Skate::default();
    check(&run::<_, 3, 1, 2, 11>(sk, Method::LobattoIIIAB, &s0, 0.1, 100.0), "skate IIIA-B 2", 1e-1, &mut f);
    check(&run::<_, 3, 1, 3, 15>(sk, Method::LobattoIIIAB, &s0, 0.1, 100.0), "skate IIIA-B 3", 1e-3, &mut f);
    check(&run::<_, 3, 1, 4, 19>(sk, Method::LobattoIIIAB, &s0, 0.1, 100.0), "skate IIIA-B 4", 1e-5, &mut f);
    // §8.3: Lobatto IIIA-B-D s = 2, 3, 4, h = 0.2 on [0, 150], the paper's v0.
    let r0 = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.0, 1.0));
    let ro = MobileRobot::default();
    check(&run::<_, 4, 2, 2, 16>(ro, Method::LobattoIIIABD, &r0, 0.2, 150.0), "robot IIIA-B-D 2", 1.0, &mut f);
    check(&run::<_, 4, 2, 3, 22>(ro, Method::LobattoIIIABD, &r0, 0.2, 150.0), "robot IIIA-B-D 3", 1e-2, &mut f);
    check(&run::<_, 4, 2, 4, 28>(ro, Method::LobattoIIIABD, &r0, 0.2, 150.0), "robot IIIA-B-D 4", 1e-3, &mut f);
    // §8.4: the three s = 2 methods, h = 0.05, J + 1 = 10 initial conditions
    // on E0 = 3.06 (shortened to [0, 250]; the CLI runs the full [0, 50000]).
    let j_max = 9;
    for method in [Method::LobattoIIIAB, Method::ModifiedLobattoIIIAB, Method::LobattoIIIBALda] {
        let mut total = RunReport::default();
        for j in 0..=j_max {
            let a = (j as f64 * std::f64::consts::PI / (2.0 * j_max as f64)).cos();
            let b = (j as f64 * std::f64::consts::PI / (2.0 * j_max as f64)).sin();
            let q0 = Vector::<7>::from_row_slice(&[a, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]);
            let v0 = Vector::<7>::from_row_slice(&[0.0, b, 0.0, 0.0, 0.0, 0.0, 0.0]);
            assert!((MpParticles.energy(0.0, &q0, &v0) - 3.06).abs() < 1e-12);
            let r = run::<_, 7, 1, 2, 23>(MpParticles, method, &State::new(0.0, q0, v0), 0.05, 250.0);
            check(&r, &format!("MP particles {method} j={j}"), 1e-2, &mut f);
            total.steps += r.steps;
            total.newton_iterations_total += r.newton_iterations_total;
        }
        println!(
            "MP particles {method}: mean Newton iterations over all 10 runs {:.3}",
            total.newton_iterations_total as f64 / total.steps as f64
        );
    }
    assert!(f.is_empty(), "{}", f.join("\n"));
}

fn round_trip<Sys, const N: usize, const M: usize, const S: usize, const D: usize>(
    sys: Sys,
    method: Method,
    start: &State<N>,
    h: f64,
    steps: usize,
) -> f64
where
    Sys: NonholonomicSystem<N, M>,
{
    // The round trip measures symmetry, not conservation: the Euler methods'
    // backward leg raises the particle's energy to 2.8·E0, which the energy
    // guard (default on) would refuse.
    let options = NewtonOptions { energy_drift_limit: None, ..NewtonOptions::default() };
    let mut st = Stepper::<Sys, N, M, S, D>::new(sys, Tableau::new(method).unwrap()).with_options(options);
    let mut s = *start;
    for _ in 0..steps {
        s = st.step(&s, h).unwrap().state;
    }
    for _ in 0..steps {
        s = st.step(&s, -h).unwrap().state;
    }
    (s.q - start.q).amax().max((s.v - start.v).amax())
}

#[test]
fn symmetric_methods_return_to_the_start_and_euler_methods_do_not() {
    let p0 = State::new(0.0, Vector::<3>::new(1.0, 0.0, 0.0), Vector::<3>::new(0.0, 1.0, 0.0));
    let s0 = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let r0 = State::new(0.0, Vector::<4>::zeros(), Vector::<4>::new(1.0, 0.0, 0.5, 1.0));
    let m0 = State::new(
        0.0,
        Vector::<7>::from_row_slice(&[0.8, 0.6, 0.4, 0.2, 1.0, 1.0, 1.0]),
        Vector::<7>::from_row_slice(&[0.0, 0.6, 0.0, 0.0, 0.0, 0.0, 0.0]),
    );
    let mut bad = Vec::new();
    let mut ok = |what: String, d: f64, symmetric: bool| {
        println!("{what}: forward-backward deviation {d:.2e}");
        if symmetric != (d <= 1e-12) {
            bad.push(format!("{what}: deviation {d:.2e} (symmetric method: {symmetric})"));
        }
    };
    for m in [Method::Gauss, Method::LobattoIIIAB, Method::LobattoIIIABD] {
        ok(format!("particle {m} s=3"), round_trip::<_, 3, 1, 3, 15>(Particle, m, &p0, 0.2, 100), true);
        ok(format!("skate {m} s=2"), round_trip::<_, 3, 1, 2, 11>(Skate::default(), m, &s0, 0.1, 100), true);
        ok(format!("robot {m} s=4"), round_trip::<_, 4, 2, 4, 28>(MobileRobot::default(), m, &r0, 0.2, 100), true);
        ok(format!("MP {m} s=2"), round_trip::<_, 7, 1, 2, 23>(MpParticles, m, &m0, 0.05, 100), true);
    }
    ok("particle Gauss s=1".into(), round_trip::<_, 3, 1, 1, 7>(Particle, Method::Gauss, &p0, 0.2, 100), true);
    for m in [Method::ModifiedLobattoIIIAB, Method::LobattoIIIBALda] {
        ok(format!("MP {m}"), round_trip::<_, 7, 1, 2, 23>(MpParticles, m, &m0, 0.05, 100), true);
    }
    for m in [Method::SymplecticEulerI, Method::SymplecticEulerII] {
        ok(format!("particle {m}"), round_trip::<_, 3, 1, 1, 7>(Particle, m, &p0, 0.2, 100), false);
        ok(format!("skate {m}"), round_trip::<_, 3, 1, 1, 7>(Skate::default(), m, &s0, 0.1, 100), false);
        ok(format!("robot {m}"), round_trip::<_, 4, 2, 1, 10>(MobileRobot::default(), m, &r0, 0.2, 100), false);
        ok(format!("MP {m}"), round_trip::<_, 7, 1, 1, 15>(MpParticles, m, &m0, 0.05, 100), false);
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}
