//! The CasADi export: every declared system and scene is exported, every
//! catalogue entry takes every checked step from its own state, and the
//! effect flags agree with the sources.

use problems::crosscheck::*;

/// Names declared with `nonholonomic_system!` in `systems.rs`.
fn declared_systems() -> Vec<String> {
    let text = include_str!("../src/systems/paper.rs");
    let mut names = Vec::new();
    for chunk in text.split("nonholonomic_system! {").skip(1) {
        let after = chunk.split("struct").nth(1).expect("a struct in every invocation");
        let name: String = after.trim_start().chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        names.push(name);
    }
    names
}

/// The type names (`SystemSource::name`) of every exported system.
fn exported_types() -> Vec<String> {
    export_all_systems(1).unwrap().into_iter().map(|s| s.source.name).collect()
}

#[test]
fn every_declared_system_is_exported() {
    let exported = exported_types();
    let declared = declared_systems();
    assert!(declared.len() >= 8, "found only {declared:?}");
    for name in &declared {
        assert!(exported.contains(name), "{name} is declared in systems.rs but not exported for CasADi");
    }
}

/// Scene names declared in `scenes.rs` (`scenes: { A = [..], B = [..] }`)
/// and the structs declared there.
fn declared_scene_types() -> Vec<String> {
    let text = include_str!("../src/systems/scenes.rs");
    let mut names = Vec::new();
    for chunk in text.split("nonholonomic_system! {").skip(1) {
        let body = chunk.split("\n}").next().unwrap_or("");
        if let Some(scenes) = body.split("scenes: {").nth(1) {
            let list = scenes.split('}').next().unwrap_or("");
            for entry in list.split(']') {
                if let Some((name, _)) = entry.split_once('=') {
                    let name = name.trim().trim_start_matches(',').trim();
                    if !name.is_empty() {
                        names.push(name.to_owned());
                    }
                }
            }
        } else {
            let after = body.split("struct").nth(1).expect("a struct in every invocation");
            names.push(after.trim_start().chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect());
        }
    }
    names
}

#[test]
fn every_scene_is_exported() {
    let exported = exported_types();
    let declared = declared_scene_types();
    assert!(declared.len() >= 16, "found only {declared:?}");
    for name in &declared {
        assert!(exported.contains(name), "{name} is declared in scenes.rs but not exported for CasADi");
    }
}

#[test]
fn every_system_takes_every_step() {
    let cold = cold::COLD_CASES.map(|c| c.name);
    let systems = export_all_systems(1)
        .unwrap()
        .iter()
        .filter(|s| !s.name.contains("varied") && !cold.contains(&s.name.as_str()))
        .count();
    let steps = export_all_steps().expect("all steps succeed");
    // Gauss 1..3, IIIA-B 2..3, IIIA-B-D 2..3, Euler I, II, modified Lobatto, LDA.
    assert_eq!(checked_methods().len(), 11);
    assert_eq!(steps.len(), 11 * systems);
    for st in &steps {
        assert_eq!(st.psi.len(), st.method.stages);
        assert_eq!(st.method.conditions.len(), st.method.stages - 1);
    }
}

#[test]
fn effect_systems_export_their_effects_and_flags_match_sources() {
    let systems = export_all_systems(1).unwrap();
    for s in &systems {
        assert_eq!(s.effects.forcing, !s.source.external_force.is_empty(), "{}", s.name);
        assert_eq!(s.effects.nonideal, !s.source.nonideal_force.is_empty(), "{}", s.name);
        assert_eq!(s.effects.holonomic, !s.source.holonomic.is_empty(), "{}", s.name);
        for p in &s.points {
            assert_eq!(p.outputs.external_force.is_some(), s.effects.forcing);
            assert_eq!(p.outputs.nonideal_force.is_some(), s.effects.nonideal);
            assert_eq!(p.outputs.holonomic_residual.is_some(), s.effects.holonomic);
        }
    }
    let by = |name: &str| systems.iter().find(|s| s.name == name).expect(name);
    assert!(by("driven-skate").effects.forcing);
    let friction = by("friction-skate");
    assert!(friction.effects.nonideal);
    assert!(friction.source.nonideal_force[0].contains("(psi 0)"));
    let n = friction.points[0].outputs.nonideal_force.as_ref().unwrap();
    assert_eq!((n.jacobians.psi.len(), n.jacobians.psi[0].len()), (3, 1));
    assert!(by("rod-pendulum-hand").effects.holonomic);
    let steps = export_all_steps().unwrap();
    for st in steps.iter().filter(|st| st.system == "rod-pendulum-hand") {
        let g = st.holonomic_residual.as_ref().expect("holonomic residual after the step");
        assert!(g[0].abs() < 1e-2, "{}: drift {:.3e}", st.method.label, g[0]);
    }
}

/// Export names of the systems with their default parameters, in order.
fn exported_names() -> Vec<String> {
    export_all_systems(1).unwrap().into_iter().map(|s| s.name).filter(|n| !n.contains("varied")).collect()
}

#[test]
fn every_catalogue_entry_is_exported_under_its_command_line_name() {
    let exported = exported_names();
    let mut expected: Vec<String> = problems::catalog::entries().iter().map(|e| e.name.to_owned()).collect();
    expected.extend(["rheonomic-hand", "appell-hamel-sprung"].map(String::from));
    expected.extend(cold::COLD_CASES.map(|c| c.name.to_owned()));
    assert_eq!(exported, expected);
}

/// Every hard cold case takes every cold method in every Newton mode from
/// its own state, and each step is either solved or refused with the
/// stepper's error (the export itself does not fail on a refused step).
#[test]
fn cold_cases_take_every_method_in_every_mode() {
    let steps = cold::export_cold_steps().expect("the cold export records refusals instead of failing");
    let mut want = Vec::new();
    for case in cold::COLD_CASES {
        for (method, stages) in cold::COLD_METHODS {
            for (mode, _, _) in cold::NEWTON_MODES {
                want.push((case.name, method.key(), stages, mode));
            }
        }
    }
    let taken: Vec<_> =
        steps.iter().map(|st| (st.system.as_str(), st.method.key, st.method.stages, st.newton)).collect();
    assert_eq!(taken, want);
    for st in &steps {
        let case = cold::COLD_CASES.into_iter().find(|c| c.name == st.system).unwrap();
        assert!(st.t0 == case.t0 && st.h == case.h && st.q0 == case.q0, "{}", st.system);
        assert_eq!(st.solved.is_some(), st.error.is_none(), "{} {}: {:?}", st.system, st.method.label, st.error);
        if let Some(sol) = &st.solved {
            assert_eq!((sol.psi.len(), sol.stage_velocities.len()), (st.method.stages, st.method.stages));
        }
    }
}

#[test]
fn steps_start_from_the_catalogue_state_and_step_size() {
    let steps = export_all_steps().unwrap();
    for e in problems::catalog::entries() {
        let mine: Vec<_> = steps.iter().filter(|st| st.system == e.name).collect();
        assert_eq!(mine.len(), 11, "{}: steps", e.name);
        for st in mine {
            assert_eq!((st.t0, st.h, st.q0.as_slice()), (e.t0, e.h, e.q0), "{}", e.name);
            // v0 is projected onto the constraints; the catalogue's is consistent.
            for (got, want) in st.v0.iter().zip(e.v0) {
                assert!((got - want).abs() <= 1e-12 * want.abs().max(1.0), "{}: v0 {got:.3e} vs {want:.3e}", e.name);
            }
        }
    }
}

#[test]
fn extras_take_every_step_from_their_own_state() {
    let steps = export_all_steps().unwrap();
    for case in [RHEONOMIC, APPELL_HAMEL_SPRUNG] {
        let mine: Vec<_> = steps.iter().filter(|st| st.system == case.name).collect();
        let taken: Vec<_> = mine.iter().map(|st| (st.method.key, st.method.stages)).collect();
        let want: Vec<_> = checked_methods().into_iter().map(|(m, s)| (m.key(), s)).collect();
        assert_eq!(taken, want, "{}", case.name);
        assert!(mine.iter().all(|st| st.t0 == case.t0 && st.q0 == case.q0 && st.h == case.h));
    }
}

#[test]
fn a_case_with_a_wrong_state_length_is_an_error() {
    let case = Case { q0: &[0.0], ..RHEONOMIC };
    let err = case.state::<2>().unwrap_err();
    assert!(matches!(err, CrosscheckError::StateLength { q: 1, v: 2, n: 2, .. }), "{err}");
    assert!(err.to_string().starts_with("rheonomic-hand: "), "{err}");
}

#[test]
fn steps_carry_the_method_key_and_label() {
    let steps = export_all_steps().unwrap();
    let json = serde_json::to_value(&steps[0]).unwrap();
    assert_eq!(json["method"]["key"], "gauss");
    assert_eq!(json["method"]["label"], "Gauss s=1");
    assert!(json["method"].get("name").is_none());
}

#[test]
fn splitmix_is_reproducible_and_in_range() {
    let mut a = SplitMix64::new(7);
    let mut b = SplitMix64::new(7);
    for _ in 0..1000 {
        let x = a.symmetric();
        assert_eq!(x, b.symmetric());
        assert!((-1.0..1.0).contains(&x));
    }
}

#[test]
fn export_records_every_point_of_a_finite_system() {
    let sys = handwritten::Rheonomic::default();
    let e = export_system("rheonomic", &sys, 1);
    let expected: usize = CLASSES.iter().map(|c| c.2).sum();
    assert_eq!(e.points.len() + e.skipped_points, expected);
    assert_eq!(e.skipped_points, 0);
    assert_eq!(e.points[0].outputs.constraint_v.len(), 1);
    assert_eq!(e.points[0].outputs.constraint_v[0].len(), 2);
}

#[test]
fn floats_round_trip_through_json() {
    let sys = handwritten::Rheonomic::default();
    let e = export_system("rheonomic", &sys, 3);
    let text = serde_json::to_string(&e).unwrap();
    let back: serde_json::Value = serde_json::from_str(&text).unwrap();
    for (i, p) in e.points.iter().enumerate() {
        let bp = &back["points"][i];
        assert_eq!(bp["outputs"]["lagrangian"].as_f64().unwrap().to_bits(), p.outputs.lagrangian.to_bits());
        for (j, x) in p.q.iter().enumerate() {
            assert_eq!(bp["q"][j].as_f64().unwrap().to_bits(), x.to_bits());
        }
    }
}
