//! The peers: dual-number twins and central differences against the
//! generated derivatives, and DOP853 against the reference solution.

mod dual {
    use problems::catalog::{Dispatch, SystemEntry};
    use problems::peers::dual::*;
    use problems::systems::{McLachlanPerlmutter7, MobileRobot, NonholonomicParticle, Skate};
    use spark_runtime::{NonholonomicSystem, Vector};

    /// The twin dispatch covers exactly the catalogue's paper systems (the
    /// ones with the CasADi C and SciPy peers), each with its own type.
    #[test]
    fn twins_are_the_catalogues_paper_systems() {
        struct TypeName;
        impl TwinVisitor for TypeName {
            type Output = (&'static str, usize, usize);
            fn visit<Sys: Dispatch<N, M> + DualTwin<N, M>, const N: usize, const M: usize, const Y: usize>(
                self,
                _: &'static SystemEntry,
            ) -> Self::Output {
                (Sys::SOURCE.name, N, M)
            }
        }
        for e in problems::catalog::entries() {
            match visit_twin(e.kind, TypeName) {
                Ok(got) => {
                    assert!(e.paper, "{} has a num-dual twin but is not marked as a paper system", e.name);
                    assert_eq!(got, (e.type_name, e.n, e.m), "{}", e.name);
                }
                Err(_) => assert!(!e.paper, "{} is a paper system without a num-dual twin", e.name),
            }
        }
    }

    /// Every output of the dual adapter equals the generated code's at a
    /// generic point (ψ ≠ 0, v off the constraint).
    fn agrees<Sys, const N: usize, const M: usize>(sys: Sys)
    where
        Sys: NonholonomicSystem<N, M> + DualTwin<N, M>,
    {
        let ad = AutoDiff(<Sys as DualTwin<N, M>>::Twin::default());
        let q = Vector::<N>::from_fn(|i, _| 0.3 + 0.17 * i as f64);
        let v = Vector::<N>::from_fn(|i, _| -0.4 + 0.23 * i as f64);
        let psi = Vector::<M>::from_fn(|i, _| 0.7 - 0.5 * i as f64);
        let (gv, gj) = sys.stage_jacobians(0.3, &q, &v, &psi);
        let (av, aj) = ad.stage_jacobians(0.3, &q, &v, &psi);
        let close = |a: &[f64], b: &[f64], what: &str| {
            for (x, y) in a.iter().zip(b) {
                assert!((x - y).abs() <= 1e-13 * (1.0 + x.abs()), "{what}: generated {x} vs num-dual {y}");
            }
        };
        close(gv.momentum.as_slice(), av.momentum.as_slice(), "momentum");
        close(gv.force.as_slice(), av.force.as_slice(), "force");
        close(gv.constraint.as_slice(), av.constraint.as_slice(), "constraint");
        close(gv.constraint_force.as_slice(), av.constraint_force.as_slice(), "constraint force");
        close(gj.mass.as_slice(), aj.mass.as_slice(), "mass");
        close(gj.momentum_q.as_slice(), aj.momentum_q.as_slice(), "momentum_q");
        close(gj.force_q.as_slice(), aj.force_q.as_slice(), "force_q");
        close(gj.force_v.as_slice(), aj.force_v.as_slice(), "force_v");
        close(gj.constraint_q.as_slice(), aj.constraint_q.as_slice(), "constraint_q");
        close(gj.constraint_v.as_slice(), aj.constraint_v.as_slice(), "constraint_v");
        close(gj.constraint_force_q.as_slice(), aj.constraint_force_q.as_slice(), "constraint_force_q");
        close(gj.constraint_force_v.as_slice(), aj.constraint_force_v.as_slice(), "constraint_force_v");
        let sv = ad.stage_values(0.3, &q, &v, &psi);
        close(sv.constraint_force.as_slice(), av.constraint_force.as_slice(), "stage_values");
        assert!((sys.energy(0.3, &q, &v) - ad.energy(0.3, &q, &v)).abs() < 1e-13);
    }

    #[test]
    fn dual_twins_match_generated_code() {
        agrees(NonholonomicParticle::default());
        agrees(Skate::default());
        agrees(MobileRobot::default());
        agrees(McLachlanPerlmutter7::default());
    }
}

mod ode {
    use problems::peers::ode::*;
    use problems::systems::Skate;
    use spark_runtime::reference::{self, ReferenceOptions};
    use spark_runtime::Vector;

    #[test]
    fn dop853_reaches_the_reference_on_the_skate() {
        let sys = Skate::default();
        let (q0, v0) = (Vector::<3>::zeros(), Vector::<3>::new(0.0, 0.0, 1.0));
        let run = dop853::<Skate, 3, 1, 6>(&sys, 0.0, &q0, &v0, 2.0, 1e-12, 1e-12).unwrap();
        let exact = reference::integrate(&sys, 0.0, &q0, &v0, 2.0, &ReferenceOptions::default()).unwrap();
        let err = (run.q - exact.q[0]).amax().max((run.v - exact.v[0]).amax());
        assert!(err < 1e-9, "DOP853 error {err}");
        assert!(run.steps > 0 && run.evaluations > run.steps);
        assert!(dop853::<Skate, 3, 1, 5>(&sys, 0.0, &q0, &v0, 2.0, 1e-8, 1e-8).is_err());
    }
}

mod finite_difference {
    use problems::peers::finite_difference::*;
    use problems::systems::{MobileRobot, Skate};
    use spark_runtime::{NonholonomicSystem, Vector};

    fn agrees<Sys: NonholonomicSystem<N, M> + Copy, const N: usize, const M: usize>(sys: Sys) {
        let q = Vector::<N>::from_fn(|i, _| 0.3 + 0.17 * i as f64);
        let v = Vector::<N>::from_fn(|i, _| -0.4 + 0.23 * i as f64);
        let psi = Vector::<M>::from_fn(|i, _| 0.7 - 0.5 * i as f64);
        let (_, exact) = sys.stage_jacobians(0.1, &q, &v, &psi);
        let (_, fd) = FiniteDifference(sys).stage_jacobians(0.1, &q, &v, &psi);
        let pairs = [
            (exact.mass.as_slice(), fd.mass.as_slice()),
            (exact.force_q.as_slice(), fd.force_q.as_slice()),
            (exact.constraint_q.as_slice(), fd.constraint_q.as_slice()),
            (exact.constraint_v.as_slice(), fd.constraint_v.as_slice()),
            (exact.constraint_force_q.as_slice(), fd.constraint_force_q.as_slice()),
        ];
        for (a, b) in pairs {
            for (x, y) in a.iter().zip(b) {
                assert!((x - y).abs() < 1e-8 * (1.0 + x.abs()), "exact {x} vs central difference {y}");
            }
        }
    }

    #[test]
    fn central_differences_match_generated_jacobians() {
        agrees(Skate::default());
        agrees(MobileRobot::default());
    }
}
