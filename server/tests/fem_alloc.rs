//! Steps with an unchanged contact set allocate nothing in `compliance`,
//! `direct` and `corotational`, and neither do the force samples of two
//! instruments pressing one body at once (each sample's collision query and
//! the coupled contact problem with the other's rows) between two steps (a
//! counting global allocator, `stats_alloc`; its own test binary with one
//! test, so that no other test allocates while counting).

use fissure_engine::fem::{Material, Par, Prescribed, SolverOptions, Strategy, build_solver};
use fissure_engine::mesh::blocks::cube;
use nalgebra::{Point3, Vector3};
use stats_alloc::{INSTRUMENTED_SYSTEM, Region, StatsAlloc};
use std::alloc::System;

#[global_allocator]
static GLOBAL: &StatsAlloc<System> = &INSTRUMENTED_SYSTEM;

/// Allocations and reallocations made while `f` runs.
fn count(f: impl FnOnce()) -> usize {
    let region = Region::new(GLOBAL);
    f();
    let c = region.change();
    c.allocations + c.reallocations
}

/// Both spatulas of the `cube` scene pressing its top 1 mm: the force
/// samples of both, coupled, at poses moving 1 um a sample within one
/// frame, once their workspaces have seen those contact sets.
fn coupled_force_samples_do_not_allocate() {
    use fissure_engine::fem::compliance::ColumnPolicy;
    use fissure_engine::scene::Scene;
    use fissure_engine::sim::core::engine::{Model, StepEngine};
    use fissure_engine::sim::core::force_loop::ForceLoop;
    use fissure_engine::sim::core::stepped::home_pose;
    use nalgebra::{Isometry3, Translation3};
    use std::sync::Arc;

    let (scene, _) = Scene::load("cube").unwrap();
    let model = Arc::new(Model::build(&scene).unwrap());
    let mut engine =
        StepEngine::new(&scene, model.clone(), ColumnPolicy::Compute, None, None).unwrap();
    let rest = engine.rest(0.0);
    // The plates' bottom faces 1.75 mm above the top at home: 2.75 mm down
    // presses 1 mm.
    let pose = |i: usize, k: usize| -> Isometry3<f64> {
        Translation3::new(0.0, 1e-6 * k as f64, -0.00275) * home_pose(&scene, i)
    };
    let poses = [pose(0, 0), pose(1, 0)];
    let (snap, _) = engine.step(&rest, 0.02, &poses, vec![None, None]);
    assert!(snap.solver_error.is_none(), "{:?}", snap.solver_error);
    let mut loops: Vec<ForceLoop> = (0..2)
        .map(|i| ForceLoop::new(&scene, &model, i, None))
        .collect();
    let sample = |loops: &mut Vec<ForceLoop>, k: usize| -> [f64; 2] {
        for (i, l) in loops.iter_mut().enumerate() {
            l.query(&model, &snap, &pose(i, k));
        }
        let mut fz = [0.0; 2];
        for i in 0..2 {
            let (a, b) = loops.split_at_mut(1);
            let (me, other) = if i == 0 {
                (&mut a[0], &b[0])
            } else {
                (&mut b[0], &a[0])
            };
            let others = |j: usize| (j != i).then(|| other.rows());
            let f = me.solve(&model, &snap, &others, &pose(i, k).translation.vector);
            fz[i] = f.force_n.z;
        }
        fz
    };
    // Warm-up over the same poses: sizes the rows, the history and the
    // contact solver for the largest contact set among them (a set larger
    // than any before grows them, once).
    for k in 0..15 {
        sample(&mut loops, k);
    }
    let mut forces = [0.0; 2];
    let n = count(|| {
        for k in 5..15 {
            forces = sample(&mut loops, k);
        }
    });
    // Both pressed: the tissue pushes each plate up.
    assert!(forces.iter().all(|&f| f > 1e-4), "forces {forces:?}");
    assert_eq!(
        n, 0,
        "{n} allocations in 10 coupled force samples of two instruments"
    );
}

#[test]
fn steps_and_force_samples_with_the_same_contact_set_do_not_allocate() {
    coupled_force_samples_do_not_allocate();
    let l = 0.02;
    let mesh = cube(l, 5);
    let fixed: Vec<u32> = (0..mesh.nodes.len() as u32)
        .filter(|&i| mesh.nodes[i as usize].z < 1e-12)
        .collect();
    let top = Point3::new(0.5 * l, 0.5 * l, l);
    let mut surface = mesh.boundary().to_volume;
    surface.retain(|&n| mesh.nodes[n as usize].z > 1e-12);
    surface.sort_by(|&a, &b| {
        (mesh.nodes[a as usize] - top)
            .norm()
            .total_cmp(&(mesh.nodes[b as usize] - top).norm())
    });
    let mat = Material {
        youngs_modulus_pa: 3000.0,
        poisson_ratio: 0.45,
    };
    let mut pres: Vec<Prescribed> = surface[..12]
        .iter()
        .map(|&node| Prescribed {
            node,
            displacement: Vector3::zeros(),
        })
        .collect();
    for (strategy, par) in [
        (Strategy::Compliance, Par::Seq),
        (Strategy::Compliance, Par::rayon(2)),
        (Strategy::Direct, Par::Seq),
        (Strategy::Corotational, Par::Seq),
        (Strategy::Corotational, Par::rayon(2)),
    ] {
        let opts = SolverOptions {
            parallelism: par,
            ..Default::default()
        };
        let mut solver = build_solver(strategy, &mesh, mat, &fixed, &opts).unwrap();
        let mut depth = 0.0;
        let mut step = |pres: &mut Vec<Prescribed>, solver: &mut Box<_>| {
            depth += 1e-5;
            for p in pres.iter_mut() {
                p.displacement = Vector3::new(1e-6, 0.0, -depth);
            }
            let s: &mut Box<dyn fissure_engine::fem::DeformationSolver> = solver;
            let sol = s.solve(pres).expect("step");
            assert!(sol.reactions.iter().all(|r| r.z < 0.0), "{strategy:?}");
            if strategy == Strategy::Compliance {
                assert_eq!(s.local_model().unwrap().nodes.len(), pres.len());
            }
        };
        // Warm-up: caches columns and sizes the workspaces.
        for _ in 0..3 {
            step(&mut pres, &mut solver);
        }
        let n = count(|| {
            for _ in 0..5 {
                step(&mut pres, &mut solver);
            }
        });
        assert_eq!(
            n, 0,
            "{strategy:?} with {par:?}: {n} allocations in 5 steps"
        );
        // A smaller subset of the same nodes needs nothing new either.
        let n = count(|| {
            let s: &mut Box<dyn fissure_engine::fem::DeformationSolver> = &mut solver;
            s.solve(&pres[..5]).expect("subset step");
        });
        assert_eq!(
            n, 0,
            "{strategy:?} with {par:?}: {n} allocations on a subset"
        );
    }
}
