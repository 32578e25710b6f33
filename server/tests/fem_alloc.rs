//! Steps with an unchanged contact set allocate nothing in `compliance`,
//! `direct` and `corotational` (a counting global allocator, `stats_alloc`; its own test binary
//! with one test, so that no other test allocates while counting).

use fissure_server::fem::{Material, Par, Prescribed, SolverOptions, Strategy, build_solver};
use fissure_server::mesh::blocks::cube;
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

#[test]
fn steps_with_the_same_contact_set_do_not_allocate() {
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
            let s: &mut Box<dyn fissure_server::fem::DeformationSolver> = solver;
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
            let s: &mut Box<dyn fissure_server::fem::DeformationSolver> = &mut solver;
            s.solve(&pres[..5]).expect("subset step");
        });
        assert_eq!(
            n, 0,
            "{strategy:?} with {par:?}: {n} allocations on a subset"
        );
    }
}
