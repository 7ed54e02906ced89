//! Large systems on a small stack. The McLachlan–Perlmutter particles with
//! `n = 129` (`D = 389` for Gauss `s = 2`; one `StageJacobians` value is
//! 800 KiB) are stepped on a thread with rayon's default 2 MiB stack: the
//! stepper writes the generated `stage_jacobians_into` straight into its heap
//! work storage and cold-starts from it, so a step's stack use is `O(D)`.
//! Before, the by-value `stage_jacobians` and the cold start's consistent
//! acceleration needed ≈ 6 MiB of stack here and the process aborted.
//!
//! Also checked: the in-place forms (`stage_jacobians_into`,
//! `add_external_force_jacobians`, `add_nonideal_force_jacobians`) give
//! exactly the by-value results whatever the destination held before.

use problems::scenes::{SkateWithFriction, SleighDrivenDampedByHand};
use problems::workprecision::scaling_systems::McLachlanPerlmutter129;
use spark_runtime::reference::{self, ReferenceOptions};
use spark_runtime::{Matrix, Method, NonholonomicSystem, StageJacobians, StageValues, State, Stepper, Tableau, Vector};

const N: usize = 129;
const D: usize = 2 * (N + 1) + N;
/// rayon's default worker stack.
const SMALL_STACK: usize = 2 << 20;

/// A consistent state: `k = v₁ + Σ_{i>m+1} qᵢvᵢ = 0` solved for `v₁`.
fn start() -> (Vector<N>, Vector<N>) {
    let q = Vector::<N>::from_fn(|i, _| 0.5 + 0.3 * ((i + 1) as f64).sin());
    let mut v = Vector::<N>::from_fn(|i, _| 0.2 * ((i + 1) as f64).cos());
    let m = (N - 1) / 2;
    v[0] = -(m + 1..N).map(|i| q[i] * v[i]).sum::<f64>();
    (q, v)
}

/// `steps` Gauss s=2 steps of size `h` on a thread with a 2 MiB stack.
fn gauss_steps(h: f64, steps: usize) -> State<N> {
    std::thread::Builder::new()
        .stack_size(SMALL_STACK)
        .spawn(move || {
            let (q, v) = start();
            let sys = McLachlanPerlmutter129::default();
            let mut st = Stepper::<_, N, 1, 2, D>::new(sys, Tableau::new(Method::Gauss).unwrap());
            let mut s = State::new(0.0, q, v);
            for _ in 0..steps {
                s = st.step(&s, h).expect("step").state;
            }
            s
        })
        .expect("spawn")
        .join()
        .expect("the stepping thread finished (no stack overflow)")
}

/// Runs `f` on a thread with a large stack (the by-value comparisons and the
/// reference solver keep `N × N` values on the stack).
fn on_big_stack<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    std::thread::Builder::new().stack_size(64 << 20).spawn(f).expect("spawn").join().expect("join")
}

#[test]
fn mp129_gauss_steps_on_a_2_mib_thread_match_the_reference_at_order_4() {
    let (h, steps) = (0.02, 5);
    let coarse = gauss_steps(h, steps);
    let fine = gauss_steps(h / 2.0, 2 * steps);
    let t1 = h * steps as f64;
    let exact = on_big_stack(move || {
        let (q, v) = start();
        let opts = ReferenceOptions { rtol: 1e-13, atol: 1e-13, ..ReferenceOptions::default() };
        reference::integrate::<_, N, 1>(&McLachlanPerlmutter129::default(), 0.0, &q, &v, t1, &opts).expect("reference")
    });
    let (xq, xv) = (exact.q[0], exact.v[0]);
    let err = |s: &State<N>| (s.q - xq).amax().max((s.v - xv).amax());
    let (e1, e2) = (err(&coarse), err(&fine));
    let (q0, _) = start();
    let sys = McLachlanPerlmutter129::default();
    let (e0, e_end) = (sys.energy(0.0, &q0, &start().1), sys.energy(t1, &coarse.q, &coarse.v));
    let k = sys.constraint(t1, &coarse.q, &coarse.v).amax();
    println!(
        "n = {N}, D = {D}: moved {:.3e}, error h {e1:.3e}, h/2 {e2:.3e} (ratio {:.1}), ΔE {:.2e}, |k| {k:.1e}",
        (coarse.q - q0).amax(),
        e1 / e2,
        e_end - e0
    );
    assert!((coarse.q - q0).amax() > 1e-3, "the particles moved");
    assert!((fine.t - t1).abs() < 1e-15 && (coarse.t - t1).abs() < 1e-15);
    // Gauss s=2 is of order 4: halving h divides the error by ≈ 16.
    // Measured 9.8e-11 (h = 0.02, t = 0.1); the bound leaves a factor 10.
    assert!(e1 < 1e-9, "error {e1:e} at h = {h}");
    assert!(e1 / e2 > 10.0 && e1 / e2 < 24.0, "order-4 ratio {} (errors {e1:e}, {e2:e})", e1 / e2);
    assert!(k < 1e-12, "constraint residual {k:e}");
    assert!((e_end - e0).abs() < 1e-8 * e0.abs().max(1.0), "energy error {:e}", e_end - e0);
}

/// A `StageJacobians` on the heap with every entry NaN.
fn nan_jacobians<const N: usize, const M: usize>() -> Box<StageJacobians<N, M>> {
    let mut j = StageJacobians::<N, M>::boxed_zeros();
    let StageJacobians {
        momentum_q,
        mass,
        force_q,
        force_v,
        constraint_q,
        constraint_v,
        constraint_force_q,
        constraint_force_v,
    } = &mut *j;
    for m in [momentum_q, mass, force_q, force_v, constraint_force_q, constraint_force_v] {
        m.fill(f64::NAN);
    }
    constraint_q.fill(f64::NAN);
    constraint_v.fill(f64::NAN);
    j
}

fn nan_values<const N: usize, const M: usize>() -> StageValues<N, M> {
    let mut v = StageValues::<N, M>::zeros();
    v.momentum.fill(f64::NAN);
    v.force.fill(f64::NAN);
    v.constraint.fill(f64::NAN);
    v.constraint_force.fill(f64::NAN);
    v
}

/// `stage_jacobians_into` over NaN-filled storage equals `stage_jacobians`
/// bit for bit (every entry, structural zeros included, is written).
fn into_matches_by_value<Sys: NonholonomicSystem<N, M>, const N: usize, const M: usize>(
    sys: &Sys,
    q: &Vector<N>,
    v: &Vector<N>,
    psi: &Vector<M>,
) {
    let (values, jac) = sys.stage_jacobians(0.3, q, v, psi);
    let (mut values2, mut jac2) = (nan_values::<N, M>(), nan_jacobians::<N, M>());
    sys.stage_jacobians_into(0.3, q, v, psi, &mut values2, &mut jac2);
    assert_eq!(values, values2, "{}: values", Sys::SOURCE.name);
    assert!(jac == *jac2, "{}: Jacobians differ", Sys::SOURCE.name);
}

#[test]
fn in_place_stage_jacobians_overwrite_everything() {
    on_big_stack(|| {
        let (q, v) = start();
        into_matches_by_value(&McLachlanPerlmutter129::default(), &q, &v, &Vector::<1>::new(0.7));
    });
    let (q, v, psi) = (Vector::<3>::new(0.3, -0.2, 0.9), Vector::<3>::new(0.5, 0.1, -0.4), Vector::<1>::new(0.8));
    into_matches_by_value(&SleighDrivenDampedByHand::default(), &q, &v, &psi);
    into_matches_by_value(&SkateWithFriction::default(), &q, &v, &psi);
}

#[test]
fn in_place_effects_add_what_the_by_value_forms_return() {
    let (q, v, psi) = (Vector::<3>::new(0.3, -0.2, 0.9), Vector::<3>::new(0.5, 0.1, -0.4), Vector::<1>::new(0.8));

    let sleigh = SleighDrivenDampedByHand::default();
    const { assert!(SleighDrivenDampedByHand::HAS_FORCING) };
    let (base_values, base_jac) = sleigh.stage_jacobians(0.3, &q, &v, &psi);
    let (f, fq, fv) = sleigh.external_force_jacobians(0.3, &q, &v);
    let (mut values, mut jac) = (base_values, base_jac);
    sleigh.add_external_force_jacobians(0.3, &q, &v, &mut values, &mut jac);
    assert_eq!(values.force, base_values.force + f);
    assert_eq!(jac.force_q, base_jac.force_q + fq);
    assert_eq!(jac.force_v, base_jac.force_v + fv);
    assert_eq!((values.momentum, jac.mass), (base_values.momentum, base_jac.mass), "other fields untouched");

    let skate = SkateWithFriction::default();
    const { assert!(SkateWithFriction::HAS_NONIDEAL_FORCE) };
    let (base_values, base_jac) = skate.stage_jacobians(0.3, &q, &v, &psi);
    let nj = skate.nonideal_force_jacobians(0.3, &q, &v, &psi);
    let (mut values, mut jac) = (base_values, base_jac);
    let mut psi_jac = Matrix::<3, 1>::from_element(f64::NAN);
    skate.add_nonideal_force_jacobians(0.3, &q, &v, &psi, &mut values, &mut jac, &mut psi_jac);
    assert_eq!(values.constraint_force, base_values.constraint_force + nj.value);
    assert_eq!(jac.constraint_force_q, base_jac.constraint_force_q + nj.q);
    assert_eq!(jac.constraint_force_v, base_jac.constraint_force_v + nj.v);
    assert_eq!(psi_jac, nj.psi);
    assert!(nj.q.amax() > 0.0 && nj.psi.amax() > 0.0, "the friction force has nonzero Jacobians here");
}
