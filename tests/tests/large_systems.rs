//! Large systems on a small stack. The McLachlan–Perlmutter particles with
//! `n = 129` (`D = 389` for Gauss `s = 2`; one `StageJacobians` value is
//! 800 KiB) are stepped on a thread with rayon's default 2 MiB stack: the
//! stepper writes the generated `stage_jacobians_into` straight into its heap
//! work storage and cold-starts from it, so a step's stack use is `O(D)`.
//! The by-value `stage_jacobians` and a cold start's consistent
//! acceleration computed from them would need ≈ 6 MiB of stack here and
//! abort the process.
//!
//! With `n = 201` and `n = 401` (the hand-written [`MpLarge`]), the public
//! paths of a run go through rayon workers with 2 MiB stacks, two sizes at
//! once: `Stepper::integrate` with `ConsistencyPolicy::Project` from an
//! inconsistent `v₀` and the multiplier observer, and `consistent_velocity`,
//! `consistent_acceleration` and `reference::integrate` on their own, each
//! checked against a closed form. They run in a child process of the test
//! binary, so that a stack overflow (which aborts the process) is reported
//! as a failure of the parent test.
//!
//! Also checked: the in-place forms (`stage_jacobians_into`,
//! `add_external_force_jacobians`, `add_nonideal_force_jacobians`) give
//! exactly the by-value results whatever the destination held before.

use problems::systems::scaling::McLachlanPerlmutter129;
use problems::systems::scenes::{SkateWithFriction, SleighDrivenDampedByHand};
use spark_runtime::reference::{self, ReferenceOptions};
use spark_runtime::{
    consistent_acceleration, consistent_velocity, ConsistencyPolicy, ConstraintForm, Matrix, Method, NoObserver,
    NonholonomicSystem, Observe, OperationCounts, RunOptions, Schedule, StageJacobians, StageValues, State, Stepper,
    Structure, SystemError, SystemSource, Tableau, TimeDerivatives, Vector,
};

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

// ------------------------------------------------ n = 201 and n = 401 on rayon workers

/// McLachlan–Perlmutter particles with `n = 2m + 1` coordinates for any `N`,
/// written by hand (a macro-declared `n = 401` system takes long to compile;
/// the point here is the runtime's stack use, not the generated code):
/// `L = ½|v|² − ½(|q|² + q_{m+1}²q_{m+2}² + Σ_{i=1..m} q_i² q_{m+i}²)`
/// (0-based indices), `k = v₀ + Σ_{i>m} qᵢvᵢ`: the same system as
/// `McLachlanPerlmutter129` at `N = 129`. `stage_jacobians_into` writes
/// entry by entry, as generated code does; the by-value forms are only
/// there because the trait requires them.
#[derive(Clone, Copy, Debug, Default)]
struct MpLarge<const N: usize>;

impl<const N: usize> MpLarge<N> {
    const HALF: usize = (N - 1) / 2;

    /// The coupled pairs `(a, b)` of the quartic terms `q_a² q_b²`.
    fn pairs() -> impl Iterator<Item = (usize, usize)> {
        let m = Self::HALF;
        std::iter::once((m + 1, m + 2)).chain((1..=m).map(move |i| (i, m + i)))
    }

    fn potential(q: &Vector<N>) -> f64 {
        0.5 * (q.norm_squared() + Self::pairs().map(|(a, b)| q[a] * q[a] * q[b] * q[b]).sum::<f64>())
    }

    fn force_of(q: &Vector<N>) -> Vector<N> {
        let mut f = -q;
        for (a, b) in Self::pairs() {
            f[a] -= q[a] * q[b] * q[b];
            f[b] -= q[a] * q[a] * q[b];
        }
        f
    }

    fn constraint_row(q: &Vector<N>, row: &mut [f64]) {
        row.fill(0.0);
        row[0] = 1.0;
        row[Self::HALF + 1..].copy_from_slice(&q.as_slice()[Self::HALF + 1..]);
    }
}

impl<const N: usize> NonholonomicSystem<N, 1> for MpLarge<N> {
    const STRUCTURE: Structure = Structure {
        lagrangian_autonomous: true,
        constraints_autonomous: true,
        constant_mass_matrix: true,
        separable: true,
        constraint_form: ConstraintForm::Linear,
    };
    const SOURCE: SystemSource = SystemSource {
        name: "MpLarge",
        coordinates: &[],
        parameters: &[],
        lagrangian: "0",
        constraints: &[],
        external_force: &[],
        nonideal_force: &[],
        holonomic: &[],
    };
    const OPERATIONS: OperationCounts = OperationCounts { stage_values: 0, stage_jacobians: 0, bundle: 0 };

    fn parameter_values(&self) -> Vec<f64> {
        Vec::new()
    }
    fn set_parameter(&mut self, name: &str, _: f64) -> Result<(), SystemError> {
        Err(SystemError::UnknownParameter { name: name.into(), known: String::new() })
    }
    fn lagrangian(&self, _: f64, q: &Vector<N>, v: &Vector<N>) -> f64 {
        0.5 * v.norm_squared() - Self::potential(q)
    }
    fn energy(&self, _: f64, q: &Vector<N>, v: &Vector<N>) -> f64 {
        0.5 * v.norm_squared() + Self::potential(q)
    }
    fn momentum(&self, _: f64, _: &Vector<N>, v: &Vector<N>) -> Vector<N> {
        *v
    }
    fn force(&self, _: f64, q: &Vector<N>, _: &Vector<N>) -> Vector<N> {
        Self::force_of(q)
    }
    fn mass_matrix(&self, _: f64, _: &Vector<N>, _: &Vector<N>) -> Matrix<N, N> {
        Matrix::identity()
    }
    fn constraint(&self, _: f64, q: &Vector<N>, v: &Vector<N>) -> Vector<1> {
        Vector::<1>::new(v[0] + (Self::HALF + 1..N).map(|i| q[i] * v[i]).sum::<f64>())
    }
    fn constraint_q(&self, _: f64, _: &Vector<N>, v: &Vector<N>) -> Matrix<1, N> {
        Matrix::<1, N>::from_fn(|_, j| if j > Self::HALF { v[j] } else { 0.0 })
    }
    fn constraint_v(&self, _: f64, q: &Vector<N>, _: &Vector<N>) -> Matrix<1, N> {
        let mut k = Matrix::<1, N>::zeros();
        Self::constraint_row(q, k.as_mut_slice());
        k
    }
    fn time_derivatives(&self, _: f64, _: &Vector<N>, _: &Vector<N>) -> TimeDerivatives<N, 1> {
        TimeDerivatives {
            lagrangian_t: 0.0,
            momentum_t: Vector::zeros(),
            force_t: Vector::zeros(),
            constraint_t: Vector::zeros(),
        }
    }
    fn stage_values(&self, t: f64, q: &Vector<N>, v: &Vector<N>, psi: &Vector<1>) -> StageValues<N, 1> {
        let mut r = Vector::<N>::zeros();
        Self::constraint_row(q, r.as_mut_slice());
        StageValues {
            momentum: *v,
            force: Self::force_of(q),
            constraint: self.constraint(t, q, v),
            constraint_force: -psi[0] * r,
            ..StageValues::zeros()
        }
    }
    fn stage_jacobians(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<1>,
    ) -> (StageValues<N, 1>, StageJacobians<N, 1>) {
        let (mut values, mut jac) = (StageValues::zeros(), StageJacobians::boxed_zeros());
        self.stage_jacobians_into(t, q, v, psi, &mut values, &mut jac);
        (values, *jac)
    }
    fn stage_jacobians_into(
        &self,
        t: f64,
        q: &Vector<N>,
        v: &Vector<N>,
        psi: &Vector<1>,
        values: &mut StageValues<N, 1>,
        jac: &mut StageJacobians<N, 1>,
    ) {
        *values = self.stage_values(t, q, v, psi);
        jac.momentum_q.fill(0.0);
        jac.mass.fill_with_identity();
        jac.force_v.fill(0.0);
        jac.constraint_force_v.fill(0.0);
        jac.force_q.fill_with_identity();
        jac.force_q.neg_mut();
        for (a, b) in Self::pairs() {
            jac.force_q[(a, a)] -= q[b] * q[b];
            jac.force_q[(b, b)] -= q[a] * q[a];
            jac.force_q[(a, b)] -= 2.0 * q[a] * q[b];
            jac.force_q[(b, a)] -= 2.0 * q[a] * q[b];
        }
        for j in 0..N {
            jac.constraint_q[(0, j)] = if j > Self::HALF { v[j] } else { 0.0 };
        }
        Self::constraint_row(q, jac.constraint_v.as_mut_slice());
        jac.constraint_force_q.fill(0.0);
        for i in Self::HALF + 1..N {
            jac.constraint_force_q[(i, i)] = -psi[0];
        }
    }
}

/// A state of [`MpLarge`] violating the constraint (`k ≈ 0.3 + …`).
fn inconsistent_start<const N: usize>() -> (Vector<N>, Vector<N>) {
    let q = Vector::<N>::from_fn(|i, _| 0.5 + 0.3 * ((i + 1) as f64).sin());
    let v = Vector::<N>::from_fn(|i, _| 0.2 * ((i + 1) as f64).cos() + if i == 0 { 0.3 } else { 0.0 });
    (q, v)
}

/// The projection of `v0` onto `k = 0` for `W = I` and `k` linear in `v`:
/// `v0 − Kᵀ k(v0)/|K|²` (written out, independently of the runtime).
fn projected<const N: usize>(q: &Vector<N>, v0: &Vector<N>) -> Vector<N> {
    let mut row = Vector::<N>::zeros();
    MpLarge::<N>::constraint_row(q, row.as_mut_slice());
    v0 - row * (row.dot(v0) / row.norm_squared())
}

/// `Stepper::integrate` with `ConsistencyPolicy::Project` from an
/// inconsistent `v₀`, observing the multipliers: the projection, the
/// stepper's cold start, the steps and the multiplier observer all run.
fn integrate_projected<const N: usize, const D: usize>() -> Result<(), String> {
    let (q, v0) = inconsistent_start::<N>();
    let sys = MpLarge::<N>;
    let mut st = Stepper::<_, N, 1, 2, D>::new(sys, Tableau::new(Method::Gauss).unwrap());
    let opts = RunOptions {
        consistency: ConsistencyPolicy::Project { tolerance: 1e-12 },
        observe: Observe { multipliers: true, ..Observe::default() },
        ..RunOptions::default()
    };
    let tr = st
        .integrate(0.0, &q, &v0, Schedule::Fixed { h: 0.02, steps: 2 }, &opts, &mut NoObserver)
        .map_err(|e| format!("n = {N}: {e}"))?;
    let expect = projected(&q, &v0);
    let first = tr.samples[0];
    let off = (first.v - expect).amax();
    let multipliers_ok = tr.samples.iter().all(|s| s.multipliers.is_some_and(|p| p[0].is_finite()));
    println!("n = {N}: projection off by {off:.1e}, max |k| {:.1e}", tr.report.max_constraint_residual);
    if !(tr.report.projected_initial_velocity && off <= 1e-15 * (1.0 + expect.amax())) {
        return Err(format!("n = {N}: projected v₀ off the closed form by {off:e}"));
    }
    if tr.report.steps != 2 || tr.report.max_constraint_residual > 1e-13 || !multipliers_ok {
        return Err(format!("n = {N}: {:?}", tr.report));
    }
    Ok(())
}

/// The public initial-value and reference paths at `(q, v)` of [`MpLarge`].
fn public_paths<const N: usize>() -> Result<(), String> {
    let (q, v0) = inconsistent_start::<N>();
    let sys = MpLarge::<N>;
    let v = consistent_velocity(&sys, 0.0, &q, &v0, ConsistencyPolicy::Project { tolerance: 0.0 })
        .map_err(|e| format!("n = {N}: projection: {e}"))?;
    let off = (v - projected(&q, &v0)).amax();
    if off > 1e-15 * (1.0 + v.amax()) {
        return Err(format!("n = {N}: projection off the closed form by {off:e}"));
    }
    let (a, psi) = consistent_acceleration(&sys, 0.0, &q, &v).ok_or(format!("n = {N}: no consistent acceleration"))?;
    // W = I: a = F − Kᵀψ, and K a + k_q v = 0.
    let k = sys.constraint_v(0.0, &q, &v);
    let momentum_balance = (a - sys.force(0.0, &q, &v) + k.transpose() * psi).amax();
    let hidden = (k * a + sys.constraint_q(0.0, &q, &v) * v)[0].abs();
    if momentum_balance > 1e-13 || hidden > 1e-13 {
        return Err(format!("n = {N}: acceleration residuals {momentum_balance:e}, {hidden:e}"));
    }
    let opts = ReferenceOptions { rtol: 1e-8, atol: 1e-8, ..ReferenceOptions::default() };
    let sol = reference::integrate::<_, N, 1>(&sys, 0.0, &q, &v, 0.01, &opts).map_err(|e| format!("n = {N}: {e}"))?;
    let (q1, v1) = (sol.q[0], sol.v[0]);
    let residual = sys.constraint(0.01, &q1, &v1)[0].abs();
    // The reference follows v̇ ≈ a over the short interval.
    let drift = (v1 - v - 0.01 * a).amax();
    if residual > 1e-9 || drift > 1e-3 {
        return Err(format!("n = {N}: reference |k| {residual:e}, v₁ − v − h a = {drift:e}"));
    }
    Ok(())
}

/// Runs `f201` and `f401` on the two workers of a rayon pool with 2 MiB
/// worker stacks (rayon's default), concurrently.
fn on_rayon_workers(f201: fn() -> Result<(), String>, f401: fn() -> Result<(), String>) {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).stack_size(SMALL_STACK).build().expect("pool");
    let (a, b) = pool.install(|| rayon::join(f201, f401));
    a.unwrap();
    b.unwrap();
}

/// Runs the ignored test `name` of this binary in a child process and
/// fails with its output unless it passed: a stack overflow aborts the
/// whole process, so the checks that would overflow run in a child, and
/// the parent reports the overflow as an ordinary test failure.
fn in_child_process(name: &str) {
    // Test names are paths within the test binary: this module's path
    // without the crate's own name.
    let module = module_path!().split_once("::").map_or("", |(_, rest)| rest);
    let name = if module.is_empty() { name.to_owned() } else { format!("{module}::{name}") };
    let out = std::process::Command::new(std::env::current_exe().expect("test binary"))
        .args([name.as_str(), "--exact", "--ignored", "--nocapture", "--test-threads=1"])
        .output()
        .expect("spawn the test binary");
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    println!("{stdout}");
    assert!(
        out.status.success() && stdout.contains("1 passed"),
        "{name} in a child process: {}\n{stdout}\n{stderr}",
        out.status
    );
}

#[test]
#[ignore = "run by integrate_projects_n201_and_n401_on_rayon_workers in a child process"]
fn child_integrate_projected_on_rayon_workers() {
    on_rayon_workers(integrate_projected::<201, { 2 * 202 + 201 }>, integrate_projected::<401, { 2 * 402 + 401 }>);
}

#[test]
#[ignore = "run by public_paths_n201_and_n401_on_rayon_workers in a child process"]
fn child_public_paths_on_rayon_workers() {
    on_rayon_workers(public_paths::<201>, public_paths::<401>);
}

/// `Stepper::integrate` with `ConsistencyPolicy::Project`, an inconsistent
/// `v₀` and the multiplier observer, for `n = 201` and `n = 401` at once on
/// the two 2 MiB workers of a rayon pool: no public path of a run puts an
/// `n × n` matrix on the stack.
#[test]
fn integrate_projects_n201_and_n401_on_rayon_workers() {
    in_child_process("child_integrate_projected_on_rayon_workers");
}

/// `consistent_velocity`, `consistent_acceleration` and
/// `reference::integrate` for `n = 201` and `n = 401` on 2 MiB rayon
/// workers, checked against closed forms.
#[test]
fn public_paths_n201_and_n401_on_rayon_workers() {
    in_child_process("child_public_paths_on_rayon_workers");
}

/// A probe for measuring stack use by bisection on the thread's stack size:
/// with `SPARK_STACK_PROBE=<n>:<bytes>` (`n` one of 129, 201, 401) it runs
/// the projected `integrate` of [`integrate_projects_n201_and_n401_on_rayon_workers`]
/// on one thread with a stack of `bytes`; the process aborts when that is too
/// small. Without the variable it does nothing.
#[test]
#[ignore = "a stack-size probe: SPARK_STACK_PROBE=<n>:<bytes>"]
fn stack_probe() {
    let Ok(spec) = std::env::var("SPARK_STACK_PROBE") else { return };
    let (n, bytes) = spec.split_once(':').expect("SPARK_STACK_PROBE=<n>:<bytes>");
    let bytes: usize = bytes.parse().expect("a stack size in bytes");
    let run: fn() -> Result<(), String> = match n {
        "129" => integrate_projected::<129, { 2 * 130 + 129 }>,
        "201" => integrate_projected::<201, { 2 * 202 + 201 }>,
        "401" => integrate_projected::<401, { 2 * 402 + 401 }>,
        _ => panic!("n must be 129, 201 or 401"),
    };
    std::thread::Builder::new().stack_size(bytes).spawn(run).expect("spawn").join().expect("join").unwrap();
}
