//! Time per SPARK step for each scene of `problems::systems::scenes::Body`, `Sleigh`
//! (drive and damping forces) and `IceSkate` (dry friction as a non-ideal
//! force), and for the same systems declared by hand
//! (`BodySkatingByHand` = scene `BodySkating`, `SleighDrivenDampedByHand` =
//! scene `SleighDrivenDamped`): the cost follows the effects a scene calls
//! for. Gauss s = 2, full Newton, warm-started, h = 0.05. Run with
//! `cargo bench -p spark-benches --bench scenes`.

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use problems::systems::scenes::{
    BodyFree, BodyRailed, BodySkating, BodySkatingByHand, BodySprung, BodyTethered, SkateOnBlade, SkateWithFriction,
    SleighDamped, SleighDriven, SleighDrivenDamped, SleighDrivenDampedByHand, SleighFree,
};
use spark_runtime::{
    consistent_velocity, ConsistencyPolicy, Method, NonholonomicSystem, State, Stepper, Tableau, Vector,
};
use std::time::Duration;

fn step<Sys, const N: usize, const M: usize, const D: usize>(c: &mut Criterion, name: &str)
where
    Sys: NonholonomicSystem<N, M> + Default,
{
    let sys = Sys::default();
    let q0 = Vector::<N>::from_fn(|i, _| [0.6, -0.8, 0.3][i % 3]);
    let v0 = Vector::<N>::from_fn(|i, _| [0.8, 0.6, 0.7][i % 3]);
    let v0 = consistent_velocity(&sys, 0.0, &q0, &v0, ConsistencyPolicy::Project { tolerance: 10.0 }).unwrap();
    let s0 = State::new(0.0, q0, v0);
    let mut st = Stepper::<Sys, N, M, 2, D>::new(sys, Tableau::new(Method::Gauss).unwrap());
    let mut s = s0;
    c.bench_function(&format!("scene-step/{name}"), |b| {
        b.iter(|| {
            if s.t > 5.0 {
                s = s0;
                st.reset_warm_start();
            }
            s = st.step(&s, 0.05).unwrap().state;
            black_box(s.q[0])
        })
    });
}

fn scenes(c: &mut Criterion) {
    step::<BodyFree, 3, 0, 9>(c, "BodyFree");
    step::<BodySprung, 3, 0, 9>(c, "BodySprung");
    step::<BodySkating, 3, 1, 11>(c, "BodySkating");
    step::<BodySkatingByHand, 3, 1, 11>(c, "BodySkatingByHand");
    step::<BodyRailed, 3, 2, 13>(c, "BodyRailed");
    step::<BodyTethered, 3, 1, 11>(c, "BodyTethered");
    step::<SleighFree, 3, 1, 11>(c, "SleighFree");
    step::<SleighDriven, 3, 1, 11>(c, "SleighDriven");
    step::<SleighDamped, 3, 1, 11>(c, "SleighDamped");
    step::<SleighDrivenDamped, 3, 1, 11>(c, "SleighDrivenDamped");
    step::<SleighDrivenDampedByHand, 3, 1, 11>(c, "SleighDrivenDampedByHand");
    step::<SkateOnBlade, 3, 1, 11>(c, "SkateOnBlade");
    step::<SkateWithFriction, 3, 1, 11>(c, "SkateWithFriction");
}

criterion_group! {
    name = benches;
    config = Criterion::default().warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(2));
    targets = scenes
}
criterion_main!(benches);
