//! Parameter terms (`NonholonomicSystem::parameter_terms`): the generated
//! `*_with_terms` functions return the bits of the plain ones, with the
//! terms given and without them, and a stepper whose system changed through
//! `Stepper::system_mut` steps with the new parameters' terms.

use problems::systems::{ChaplyginSleigh, DoublePendulum, MobileRobot, Skate};
use spark_runtime::{
    nonholonomic_system, Matrix, Method, NonholonomicSystem, StageJacobians, StageValues, State, Stepper, Tableau,
    Vector,
};

nonholonomic_system! {
    /// Parameters under functions in every part of the declaration: the
    /// kinetic energy, a time-dependent potential and the constraint.
    pub struct ParameterRich {
        coordinates: [x, y, theta],
        parameters: { m = 1.3, k = 2.0, a = 0.7, w = 1.1 },
        lagrangian: m/2*(dot(x)^2 + dot(y)^2) + sqrt(k/m)*exp(a)*dot(theta)^2/2
            - k*cos(a)*x^2/2 + sin(w*t)*a*y,
        constraints: [ cos(theta)*dot(y) - sin(theta)*dot(x) + sqrt(a)*tanh(k)*dot(theta) ],
    }
}

fn bits(xs: &[f64]) -> Vec<u64> {
    xs.iter().map(|x| x.to_bits()).collect()
}

fn value_bits<const N: usize, const M: usize>(v: &StageValues<N, M>) -> Vec<u64> {
    [v.momentum.as_slice(), v.force.as_slice(), v.constraint.as_slice(), v.constraint_force.as_slice()]
        .iter()
        .flat_map(|x| bits(x))
        .collect()
}

fn jacobian_bits<const N: usize, const M: usize>(j: &StageJacobians<N, M>) -> Vec<u64> {
    [
        j.momentum_q.as_slice(),
        j.mass.as_slice(),
        j.force_q.as_slice(),
        j.force_v.as_slice(),
        j.constraint_q.as_slice(),
        j.constraint_v.as_slice(),
        j.constraint_force_q.as_slice(),
        j.constraint_force_v.as_slice(),
    ]
    .iter()
    .flat_map(|x| bits(x))
    .collect()
}

/// Every `*_with_terms` function against its plain counterpart at 64
/// pseudo-random points, with the system's terms and with none given.
fn check_variants<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize>(sys: &Sys, name: &str) {
    assert!(Sys::PARAMETER_TERMS > 0, "{name}: no parameter terms generated");
    let mut terms = vec![f64::NAN; Sys::PARAMETER_TERMS];
    sys.parameter_terms(&mut terms);
    assert!(terms.iter().all(|x| x.is_finite()), "{name}: terms {terms:?}");
    // A fixed linear congruential sequence in [−2, 2).
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        (seed >> 11) as f64 / (1u64 << 53) as f64 * 4.0 - 2.0
    };
    for _ in 0..64 {
        let t = next();
        let q = Vector::<N>::from_fn(|_, _| next());
        let v = Vector::<N>::from_fn(|_, _| next());
        let psi = Vector::<M>::from_fn(|_, _| next());
        let mut plain = StageValues::zeros();
        sys.stage_values_into(t, &q, &v, &psi, &mut plain);
        let (mut plain_j, mut plain_jv) = (StageJacobians::zeros(), StageValues::zeros());
        sys.stage_jacobians_into(t, &q, &v, &psi, &mut plain_jv, &mut plain_j);
        let (mut plain_kq, mut plain_kv, mut plain_fv) = (Matrix::zeros(), Matrix::zeros(), StageValues::zeros());
        sys.stage_values_and_constraint_jacobians(t, &q, &v, &psi, &mut plain_fv, &mut plain_kq, &mut plain_kv);
        let energy = sys.energy(t, &q, &v);
        for given in [&terms[..], &[]] {
            let mut with = StageValues::zeros();
            sys.stage_values_with_terms(given, t, &q, &v, &psi, &mut with);
            assert_eq!(value_bits(&with), value_bits(&plain), "{name}: stage values");
            let (mut with_j, mut with_jv) = (StageJacobians::zeros(), StageValues::zeros());
            sys.stage_jacobians_with_terms(given, t, &q, &v, &psi, &mut with_jv, &mut with_j);
            assert_eq!(value_bits(&with_jv), value_bits(&plain_jv), "{name}: stage Jacobians' values");
            assert_eq!(jacobian_bits(&with_j), jacobian_bits(&plain_j), "{name}: stage Jacobians");
            let (mut kq, mut kv, mut fv) = (Matrix::zeros(), Matrix::zeros(), StageValues::zeros());
            sys.stage_values_and_constraint_jacobians_with_terms(given, t, &q, &v, &psi, &mut fv, &mut kq, &mut kv);
            assert_eq!(value_bits(&fv), value_bits(&plain_fv), "{name}: fused values");
            assert_eq!(bits(kq.as_slice()), bits(plain_kq.as_slice()), "{name}: k_q");
            assert_eq!(bits(kv.as_slice()), bits(plain_kv.as_slice()), "{name}: K");
            assert_eq!(sys.energy_with_terms(given, t, &q, &v).to_bits(), energy.to_bits(), "{name}: energy");
        }
    }
}

#[test]
fn with_terms_functions_return_the_plain_functions_bits() {
    check_variants(&ParameterRich::default(), "ParameterRich");
    check_variants(&ParameterRich { m: 0.4, k: 5.0, a: 1.9, w: -3.0 }, "ParameterRich, other parameters");
    check_variants(&Skate::default(), "Skate");
    check_variants(&Skate { beta: 0.3, ..Skate::default() }, "Skate, β = 0.3");
    check_variants(&MobileRobot::default(), "MobileRobot");
    check_variants(&ChaplyginSleigh::default(), "ChaplyginSleigh");
    check_variants(&DoublePendulum::default(), "DoublePendulum");
}

/// A parameter changed through `system_mut` between two steps: the next
/// step is bit for bit the step of a new stepper built with that parameter
/// (both start cold, `system_mut` forgets the warm start), not the step of
/// the old parameter's terms.
#[test]
fn a_stepper_steps_with_the_terms_of_its_changed_parameters() {
    let tableau = Tableau::<2>::new(Method::Gauss).unwrap();
    let start = State::new(0.0, Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
    let mut stepper = Stepper::<_, 3, 1, 2, 11>::new(Skate::default(), tableau);
    let mut state = start;
    for _ in 0..5 {
        state = stepper.step(&state, 0.1).unwrap().state;
    }
    stepper.system_mut().beta = 0.3;
    let changed = stepper.step(&state, 0.1).unwrap().state;
    let mut fresh = Stepper::<_, 3, 1, 2, 11>::new(Skate { beta: 0.3, ..Skate::default() }, tableau);
    let expected = fresh.step(&state, 0.1).unwrap().state;
    assert_eq!(bits(changed.q.as_slice()), bits(expected.q.as_slice()));
    assert_eq!(bits(changed.v.as_slice()), bits(expected.v.as_slice()));
    // And the change matters: the old parameter steps elsewhere.
    let mut old = Stepper::<_, 3, 1, 2, 11>::new(Skate::default(), tableau);
    let unchanged = old.step(&state, 0.1).unwrap().state;
    assert!((unchanged.v - expected.v).amax() > 1e-3, "{:?} against {:?}", unchanged.v, expected.v);
}
