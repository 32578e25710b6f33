//! FEM at the extremes: nu -> 0.5 (locking), E over four decades, slivers,
//! enforced displacements larger than an element, inverted elements, skull.

use fissure_engine::fem::compliance::{Compliance, Recover};
use fissure_engine::fem::model::Model;
use fissure_engine::fem::skull::{Skull, Sphere};
use fissure_engine::fem::{
    DeformationSolver, Material, Prescribed, SolveError, SolverOptions, Strategy, build_solver,
};
use fissure_engine::mesh::TetMesh;
use fissure_engine::mesh::blocks::{cube, cuboid};
use nalgebra::{Point3, Vector3};

fn nodes_where(mesh: &TetMesh, f: impl Fn(&Point3<f64>) -> bool) -> Vec<u32> {
    (0..mesh.nodes.len() as u32)
        .filter(|&i| f(&mesh.nodes[i as usize]))
        .collect()
}

fn node_at(mesh: &TetMesh, p: Point3<f64>) -> u32 {
    (0..mesh.nodes.len() as u32)
        .min_by(|&a, &b| {
            (mesh.nodes[a as usize] - p)
                .norm()
                .total_cmp(&(mesh.nodes[b as usize] - p).norm())
        })
        .unwrap()
}

fn finite(v: &[Vector3<f64>]) -> bool {
    v.iter().all(|x| x.iter().all(|c| c.is_finite()))
}

#[test]
fn poisson_ratio_sweep_shows_locking_and_stays_consistent() {
    // Cantilever clamped at x = 0; tip compliance under a unit z force at the
    // tip centre (the compliance block of that node). Beam theory barely
    // depends on nu; linear tets lock as nu -> 0.5.
    let (len, side) = (0.04, 0.01);
    let mesh = cuboid([len, side, side], [8, 2, 2]);
    let fixed = nodes_where(&mesh, |p| p.x < 1e-12);
    let tip = node_at(&mesh, Point3::new(len, 0.5 * side, 0.5 * side));
    let mut tip_compliance = Vec::new();
    for nu in [0.3, 0.4, 0.45, 0.49, 0.499] {
        let mat = Material {
            youngs_modulus_pa: 3000.0,
            poisson_ratio: nu,
        };
        let model = Model::new(&mesh, mat, &fixed, &[]).unwrap();
        let mut comp = Compliance::new(model, Recover::All).unwrap();
        let w = Vector3::new(0.0, 0.0, 1e-6);
        comp.solve(&[Prescribed {
            node: tip,
            displacement: w,
        }])
        .unwrap();
        let c = comp.local_model().unwrap().compliance[(2, 2)];
        // The same problem by direct elimination and by the iterative strategies.
        let reference = comp
            .solve(&[Prescribed {
                node: tip,
                displacement: w,
            }])
            .unwrap()
            .clone();
        let mut report = format!("nu {nu}: tip compliance {c:.4e} m/N");
        for strategy in [
            Strategy::Direct,
            Strategy::Corotational,
            Strategy::NeoHookean,
        ] {
            let mut s =
                build_solver(strategy, &mesh, mat, &fixed, &SolverOptions::default()).unwrap();
            let sol = s
                .solve(&[Prescribed {
                    node: tip,
                    displacement: w,
                }])
                .unwrap();
            let err =
                (sol.reactions[0] - reference.reactions[0]).norm() / reference.reactions[0].norm();
            report += &format!(
                ", {} {} it, force diff {err:.1e}",
                strategy.name(),
                sol.iterations
            );
            let tol = if strategy == Strategy::Direct {
                1e-8
            } else {
                1e-2
            };
            assert!(err < tol, "{strategy:?} at nu {nu}: {err}");
        }
        eprintln!("{report}");
        tip_compliance.push(c);
    }
    assert!(
        tip_compliance.windows(2).all(|w| w[1] < w[0]),
        "{tip_compliance:?}"
    );
    assert!(
        tip_compliance[4] < 0.5 * tip_compliance[0],
        "locking: {tip_compliance:?}"
    );
}

#[test]
fn forces_scale_linearly_with_youngs_modulus() {
    let mesh = cube(0.02, 3);
    let fixed = nodes_where(&mesh, |p| p.z < 1e-12);
    let top = node_at(&mesh, Point3::new(0.0133, 0.0133, 0.02));
    let pres = [Prescribed {
        node: top,
        displacement: Vector3::new(1e-4, 0.0, -5e-4),
    }];
    for strategy in Strategy::ALL {
        let mut base: Option<(Vec<Vector3<f64>>, Vector3<f64>)> = None;
        for e in [100.0, 3e3, 1e5, 1e6] {
            let mat = Material {
                youngs_modulus_pa: e,
                poisson_ratio: 0.45,
            };
            let mut s =
                build_solver(strategy, &mesh, mat, &fixed, &SolverOptions::default()).unwrap();
            let sol = s.solve(&pres).unwrap();
            let r = sol.reactions[0] / e;
            match &base {
                None => base = Some((sol.displacements.clone(), r)),
                Some((u0, r0)) => {
                    assert!(
                        (r - r0).norm() < 1e-6 * r0.norm(),
                        "{strategy:?} E {e}: {r} vs {r0}"
                    );
                    for (a, b) in u0.iter().zip(&sol.displacements) {
                        assert!((a - b).norm() < 1e-6 * 5e-4);
                    }
                }
            }
        }
    }
}

#[test]
fn sliver_elements_solve_consistently() {
    // Move the centre node of a 2-cell cube to 1 % of a cell from a face:
    // the tets between it and that face become slivers.
    let mut mesh = cube(0.01, 2);
    let c = node_at(&mesh, Point3::new(0.005, 0.005, 0.005));
    mesh.nodes[c as usize].x = 0.01 - 0.00005;
    let mesh = TetMesh::new(mesh.nodes, mesh.tets).unwrap();
    let vmin = (0..mesh.tets.len())
        .map(|t| mesh.signed_volume(t))
        .fold(f64::INFINITY, f64::min);
    assert!(vmin < 0.02 * 0.01f64.powi(3) / 48.0);
    let fixed = nodes_where(&mesh, |p| p.z < 1e-12);
    let top = node_at(&mesh, Point3::new(0.005, 0.005, 0.01));
    let pres = [Prescribed {
        node: top,
        displacement: Vector3::new(0.0, 0.0, -2e-4),
    }];
    let mat = Material {
        youngs_modulus_pa: 3000.0,
        poisson_ratio: 0.45,
    };
    let mut sols = Vec::new();
    for strategy in Strategy::ALL {
        let mut s = build_solver(strategy, &mesh, mat, &fixed, &SolverOptions::default()).unwrap();
        let sol = s.solve(&pres).unwrap().clone();
        assert!(finite(&sol.displacements) && finite(&sol.reactions));
        sols.push(sol);
    }
    let r = sols[0].reactions[0].norm();
    assert!((sols[0].reactions[0] - sols[1].reactions[0]).norm() < 1e-8 * r);
    for s in &sols[2..] {
        assert!((sols[0].reactions[0] - s.reactions[0]).norm() < 0.05 * r);
    }
}

#[test]
fn enforced_displacement_larger_than_an_element() {
    let mesh = cube(0.02, 4);
    let h = 0.005;
    let fixed = nodes_where(&mesh, |p| p.z < 1e-12);
    let top = node_at(&mesh, Point3::new(0.01, 0.01, 0.02));
    let mat = Material {
        youngs_modulus_pa: 3000.0,
        poisson_ratio: 0.45,
    };
    // Sideways by 1.5 elements: large, but no element has to invert.
    let pres = [Prescribed {
        node: top,
        displacement: Vector3::new(1.5 * h, 0.0, 0.0),
    }];
    for strategy in Strategy::ALL {
        let mut s = build_solver(strategy, &mesh, mat, &fixed, &SolverOptions::default()).unwrap();
        match s.solve(&pres) {
            Ok(sol) => {
                assert!(
                    finite(&sol.displacements) && finite(&sol.reactions),
                    "{strategy:?}"
                );
                assert!((sol.displacements[top as usize] - pres[0].displacement).norm() < 1e-9);
                // The force opposes... the constraint pulls the tissue along +x.
                assert!(sol.reactions[0].x > 0.0, "{strategy:?}");
                eprintln!(
                    "{strategy:?}: {} iterations, reaction {:?}",
                    sol.iterations, sol.reactions[0]
                );
            }
            Err(e) => {
                assert!(
                    matches!(
                        e,
                        SolveError::Inverted { .. } | SolveError::NotConverged { .. }
                    ),
                    "{strategy:?}: {e}"
                );
                assert!(
                    s.last_solution()
                        .unwrap()
                        .displacements
                        .iter()
                        .all(|u| u.norm() == 0.0)
                );
                eprintln!("{strategy:?}: {e}");
            }
        }
    }
}

#[test]
fn inverted_elements_are_reported_and_the_last_good_state_kept() {
    // One cell layer on a fixed bottom: pushing a top node below the bottom
    // plane inverts the tetrahedra it shares with three bottom nodes.
    let (w, h) = (0.02, 0.005);
    let mesh = cuboid([w, w, h], [4, 4, 1]);
    let fixed = nodes_where(&mesh, |p| p.z < 1e-12);
    let top = node_at(&mesh, Point3::new(0.01, 0.01, h));
    let mat = Material {
        youngs_modulus_pa: 3000.0,
        poisson_ratio: 0.45,
    };
    for strategy in [Strategy::Corotational, Strategy::NeoHookean] {
        let mut s = build_solver(strategy, &mesh, mat, &fixed, &SolverOptions::default()).unwrap();
        let small = [Prescribed {
            node: top,
            displacement: Vector3::new(0.0, 0.0, -0.1 * h),
        }];
        let good = s.solve(&small).unwrap().clone();
        let through = [Prescribed {
            node: top,
            displacement: Vector3::new(0.0, 0.0, -1.5 * h),
        }];
        let err = s.solve(&through).unwrap_err();
        assert!(
            matches!(err, SolveError::Inverted { .. }),
            "{strategy:?}: {err}"
        );
        assert_eq!(s.last_solution().unwrap(), &good, "{strategy:?}");
        // The solver recovers: the next sensible step works and matches.
        let again = s.solve(&small).unwrap();
        assert!((again.reactions[0] - good.reactions[0]).norm() < 1e-6 * good.reactions[0].norm());
        eprintln!("{strategy:?}: {err}");
    }
}

#[test]
fn skull_sphere_keeps_the_surface_out() {
    // An excluding sphere (a bony bump) half a millimetre above the top
    // face; pulling the top centre up 2 mm lifts its neighbours into it.
    let l = 0.02;
    let mesh = cube(l, 4);
    let fixed = nodes_where(&mesh, |p| p.z < 1e-12);
    let pulled = node_at(&mesh, Point3::new(0.01, 0.01, l));
    let (r0, gap) = (0.003, 0.0005);
    let centre = Point3::new(0.015, 0.01, l + gap + r0);
    let pres = [Prescribed {
        node: pulled,
        displacement: Vector3::new(0.0, 0.0, 2e-3),
    }];
    let mat = Material {
        youngs_modulus_pa: 3000.0,
        poisson_ratio: 0.45,
    };
    let skull = Skull {
        containing: None,
        excluding: Some(Sphere { centre, radius: r0 }),
    };
    let depth = |u: &[Vector3<f64>]| {
        mesh.boundary()
            .to_volume
            .iter()
            .filter(|&&n| n != pulled)
            .map(|&n| r0 - ((mesh.nodes[n as usize] + u[n as usize]) - centre).norm())
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let mut free = build_solver(
        Strategy::Direct,
        &mesh,
        mat,
        &fixed,
        &SolverOptions::default(),
    )
    .unwrap();
    let free_sol = free.solve(&pres).unwrap().clone();
    assert!(
        depth(&free_sol.displacements) > 1e-4,
        "{}",
        depth(&free_sol.displacements)
    );
    let mut results = Vec::new();
    for (strategy, recover) in [
        (Strategy::Direct, Recover::All),
        (Strategy::Compliance, Recover::Surface),
    ] {
        let opts = SolverOptions {
            skull: Some(skull),
            recover,
            ..Default::default()
        };
        let mut s = build_solver(strategy, &mesh, mat, &fixed, &opts).unwrap();
        let sol = s.solve(&pres).unwrap().clone();
        assert!(
            depth(&sol.displacements) < 1e-7 * r0,
            "{strategy:?}: {}",
            depth(&sol.displacements)
        );
        results.push(sol);
    }
    for &n in &mesh.boundary().to_volume {
        let (a, b) = (
            results[0].displacements[n as usize],
            results[1].displacements[n as usize],
        );
        assert!((a - b).norm() < 1e-8 * 2e-3);
    }
    // Held down by the skull, the tissue resists the pull more.
    assert!(results[0].reactions[0].z > free_sol.reactions[0].z);
}
