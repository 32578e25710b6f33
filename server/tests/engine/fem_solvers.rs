//! Solver behaviour every strategy shares: non-finite input is rejected with
//! the last good state kept, an empty step returns to rest and clears warm
//! starts, the compliance cache stays bounded (LRU), parallel and sequential
//! runs agree, and the cost of the interactive tolerance of `corotational`.

use fissure_engine::fem::compliance::{Compliance, Recover};
use fissure_engine::fem::corotational::IterativeOptions;
use fissure_engine::fem::model::Model;
use fissure_engine::fem::skull::{Skull, Sphere};
use fissure_engine::fem::{
    DeformationSolver, Material, Par, SolveError, SolverOptions, Strategy, build_solver,
};
use fissure_engine::mesh::TetMesh;
use nalgebra::{Point3, Vector3};

use crate::common::{block, push};

const BRAIN: Material = Material {
    youngs_modulus_pa: 3000.0,
    poisson_ratio: 0.45,
};

fn all_finite(v: &[Vector3<f64>]) -> bool {
    v.iter().all(|x| x.iter().all(|c| c.is_finite()))
}

/// Every strategy, plus `compliance` wrapped with a (far) skull.
fn solvers(mesh: &TetMesh, fixed: &[u32]) -> Vec<(String, Box<dyn DeformationSolver>)> {
    let mut out: Vec<(String, Box<dyn DeformationSolver>)> = Strategy::ALL
        .iter()
        .map(|&s| {
            (
                s.name().to_string(),
                build_solver(s, mesh, BRAIN, fixed, &SolverOptions::default()).unwrap(),
            )
        })
        .collect();
    let skull = Skull {
        containing: Some(Sphere {
            centre: Point3::new(0.01, 0.01, 0.01),
            radius: 0.05,
        }),
        excluding: None,
    };
    out.push((
        "compliance+skull".into(),
        build_solver(
            Strategy::Compliance,
            mesh,
            BRAIN,
            fixed,
            &SolverOptions {
                skull: Some(skull),
                ..Default::default()
            },
        )
        .unwrap(),
    ));
    out
}

#[test]
fn non_finite_input_is_rejected_and_the_last_good_state_kept() {
    let (mesh, fixed, top) = block(4, 6);
    let good = push(&top, Vector3::new(2e-4, 0.0, -1e-3));
    for (name, mut s) in solvers(&mesh, &fixed) {
        let before = s.solve(&good).unwrap().clone();
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let mut p = good.clone();
            p[3].displacement.y = bad;
            match s.solve(&p) {
                Err(SolveError::NonFinite(msg)) => {
                    assert!(msg.contains(&format!("node {}", top[3])), "{name}: {msg}")
                }
                other => panic!("{name}: {bad} gave {other:?}"),
            }
            assert_eq!(s.last_solution().unwrap(), &before, "{name}");
        }
        // Finite but absurd input: an error, or a finite answer; never NaN.
        let huge = push(&top, Vector3::new(0.0, 0.0, -1e300));
        match s.solve(&huge) {
            Ok(sol) => {
                assert!(all_finite(&sol.displacements), "{name}");
                assert!(all_finite(&sol.reactions), "{name}");
            }
            Err(e) => {
                eprintln!("{name}: huge input: {e}");
                assert_eq!(s.last_solution().unwrap(), &before, "{name}");
            }
        }
        if let Some(local) = s.local_model() {
            assert!(local.compliance.iter().all(|c| c.is_finite()), "{name}");
        }
        // The solver still works afterwards.
        let again = s.solve(&good).unwrap();
        assert!(all_finite(&again.displacements), "{name}");
    }
}

#[test]
fn an_empty_step_returns_to_rest_and_clears_warm_starts() {
    let (mesh, fixed, top) = block(4, 6);
    let first = push(&top, Vector3::new(5e-4, 0.0, -1.5e-3));
    let second = push(&top, Vector3::new(-5e-4, 3e-4, -2.5e-3));
    for (name, mut s) in solvers(&mesh, &fixed) {
        let cold = s.solve(&second).unwrap().clone();
        s.solve(&first).unwrap();
        let rest = s.solve(&[]).unwrap();
        assert!(rest.reactions.is_empty(), "{name}");
        assert!(
            rest.displacements.iter().all(|d| *d == Vector3::zeros()),
            "{name}: not at rest"
        );
        assert!(
            s.support_reactions().iter().all(|r| r.norm() == 0.0),
            "{name}"
        );
        // After a reset the next step starts cold: the very same numbers as
        // the first step of a fresh solver.
        let after = s.solve(&second).unwrap();
        assert_eq!(after, &cold, "{name}: a warm start survived the reset");
    }
}

#[test]
fn compliance_cache_is_bounded_least_recently_used() {
    let (mesh, fixed, top) = block(4, 8);
    let model = Model::new(&mesh, BRAIN, &fixed, &[]).unwrap();
    let mut c = Compliance::new(model.clone(), Recover::All).unwrap();
    let reference = |nodes: &[u32], d: Vector3<f64>| {
        let mut fresh = Compliance::new(model.clone(), Recover::All).unwrap();
        fresh.solve(&push(nodes, d)).unwrap().clone()
    };
    c.set_cache_limit(4);
    let d = Vector3::new(1e-4, -2e-4, -1e-3);
    let (a, b, cc, dd, e, f) = (top[0], top[1], top[2], top[3], top[4], top[5]);
    c.solve(&push(&[a, b, cc], d)).unwrap();
    assert_eq!(c.cached_nodes(), 3);
    c.solve(&push(&[dd, e], d)).unwrap();
    // One new slot, then the least recently used (a, first of the oldest).
    assert_eq!(c.cached_nodes(), 4);
    assert!(!c.is_cached(a));
    assert!([b, cc, dd, e].iter().all(|&n| c.is_cached(n)));
    c.solve(&push(&[b, f], d)).unwrap();
    // b was used again: c (the oldest left) goes.
    assert_eq!(c.cached_nodes(), 4);
    assert!(!c.is_cached(cc) && c.is_cached(b) && c.is_cached(f));
    // Evicted and refilled columns give the exact answer.
    let sol = c.solve(&push(&[a, cc, e], d)).unwrap().clone();
    let want = reference(&[a, cc, e], d);
    let scale = want
        .displacements
        .iter()
        .map(|v| v.norm())
        .fold(0.0, f64::max);
    for (x, y) in sol.displacements.iter().zip(&want.displacements) {
        assert!((x - y).norm() < 1e-12 * scale);
    }
    for (x, y) in sol.reactions.iter().zip(&want.reactions) {
        assert!((x - y).norm() < 1e-9 * y.norm().max(1e-12));
    }
    assert_eq!(c.cached_nodes(), 4);
    // A step larger than the bound still solves (the cache holds it all).
    let big = push(&top[..6], d);
    let sol = c.solve(&big).unwrap().clone();
    assert_eq!(c.cached_nodes(), 6);
    let want = reference(&top[..6], d);
    for (x, y) in sol.reactions.iter().zip(&want.reactions) {
        assert!((x - y).norm() < 1e-9 * y.norm().max(1e-12));
    }
    // The default bound is the memory budget, at least 256 nodes.
    let fresh = Compliance::new(model, Recover::All).unwrap();
    assert!(fresh.cache_limit() >= 256);
}

#[test]
fn parallel_and_sequential_runs_agree() {
    let (mesh, fixed, top) = block(5, 12);
    for strategy in [Strategy::Compliance, Strategy::Corotational] {
        let run = |par: Par| {
            let opts = SolverOptions {
                parallelism: par,
                ..Default::default()
            };
            let mut s = build_solver(strategy, &mesh, BRAIN, &fixed, &opts).unwrap();
            let mut out = Vec::new();
            for k in 1..=3 {
                let d = Vector3::new(1e-3, 0.0, -1.5e-3) * k as f64;
                out.push(s.solve(&push(&top, d)).unwrap().clone());
            }
            out
        };
        let (seq, par) = (run(Par::Seq), run(Par::rayon(3)));
        for (a, b) in seq.iter().zip(&par) {
            assert_eq!(a.iterations, b.iterations, "{strategy:?}");
            let scale = a.displacements.iter().map(|v| v.norm()).fold(0.0, f64::max);
            for (x, y) in a.displacements.iter().zip(&b.displacements) {
                assert!((x - y).norm() <= 1e-12 * scale, "{strategy:?}");
            }
        }
    }
}

#[test]
fn interactive_tolerance_costs_little_accuracy() {
    // A deep, sheared indentation (3 mm down, 2 mm sideways on a 2 cm cube:
    // rotations of the contact elements of order 0.1 rad).
    let (mesh, fixed, top) = block(5, 9);
    let build = |opts: IterativeOptions| {
        build_solver(
            Strategy::Corotational,
            &mesh,
            BRAIN,
            &fixed,
            &SolverOptions {
                iterative: opts,
                ..Default::default()
            },
        )
        .unwrap()
    };
    let (mut fast, mut tight) = (
        build(IterativeOptions::default()),
        build(IterativeOptions::reference()),
    );
    let mut worst_u: f64 = 0.0;
    let mut worst_f: f64 = 0.0;
    let (mut it_fast, mut it_tight) = (0, 0);
    for k in 1..=3 {
        let pres = push(&top, Vector3::new(2e-3, 0.0, -3e-3) * (k as f64 / 3.0));
        let a = fast.solve(&pres).unwrap().clone();
        let b = tight.solve(&pres).unwrap().clone();
        it_fast += a.iterations;
        it_tight += b.iterations;
        let umax = b.displacements.iter().map(|v| v.norm()).fold(0.0, f64::max);
        let du = a
            .displacements
            .iter()
            .zip(&b.displacements)
            .map(|(x, y)| (x - y).norm())
            .fold(0.0, f64::max);
        let fsum: Vector3<f64> = b.reactions.iter().sum();
        let df: Vector3<f64> = a
            .reactions
            .iter()
            .zip(&b.reactions)
            .map(|(x, y)| x - y)
            .sum();
        worst_u = worst_u.max(du / umax);
        worst_f = worst_f.max(df.norm() / fsum.norm());
    }
    eprintln!(
        "tolerance {:e}: displacement error {worst_u:.1e} of max, net force error \
         {worst_f:.1e}; {it_fast} vs {it_tight} outer iterations over 3 steps",
        IterativeOptions::INTERACTIVE_TOLERANCE
    );
    assert!(worst_u < 1e-3 && worst_f < 1e-3, "{worst_u} {worst_f}");
    assert!(it_fast < it_tight, "{it_fast} vs {it_tight}");
}
