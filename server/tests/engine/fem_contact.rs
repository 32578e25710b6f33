//! The contact problem of a step, solved by every strategy: the Delassus
//! solve of `compliance` and the active set of `direct` (an independent
//! path: sparse elimination of the working set's rows, no compliance
//! columns) give the same multipliers; the answers meet the Signorini
//! conditions; a frictionless press of a block with `nu = 0` gives exactly
//! `E A d / L`; Coulomb friction holds `|F_t| <= mu F_n`, with equality
//! once sliding.

use fissure_engine::fem::lcp::RowKind;
use fissure_engine::fem::{
    ContactAnswer, ContactRow, DeformationSolver, Material, SolverOptions, Strategy, build_solver,
};
use fissure_engine::mesh::TetMesh;
use fissure_engine::mesh::blocks::cube;
use nalgebra::Vector3;

const L: f64 = 0.02;

/// A cube of side `L` (`n` cells), its bottom fixed; the top nodes.
fn block(n: usize) -> (TetMesh, Vec<u32>, Vec<u32>) {
    let mesh = cube(L, n);
    let fixed = (0..mesh.nodes.len() as u32)
        .filter(|&i| mesh.nodes[i as usize].z < 1e-12)
        .collect();
    let top = (0..mesh.nodes.len() as u32)
        .filter(|&i| (mesh.nodes[i as usize].z - L).abs() < 1e-12)
        .collect();
    (mesh, fixed, top)
}

/// Rows of a rigid plane pressing the top: face normal `-z` tilted by
/// `slope` (rad) about the y axis, its plane through `(L/2, y, L - depth)`.
fn plane_rows(mesh: &TetMesh, top: &[u32], depth: f64, slope: f64) -> Vec<ContactRow> {
    let n = Vector3::new(slope.sin(), 0.0, -slope.cos());
    let p = nalgebra::Point3::new(0.5 * L, 0.0, L - depth);
    top.iter()
        .map(|&node| {
            ContactRow::at_node(
                node,
                n,
                n.dot(&(mesh.nodes[node as usize] - p)),
                RowKind::Unilateral,
            )
        })
        .collect()
}

fn solver(s: Strategy, mesh: &TetMesh, fixed: &[u32], nu: f64) -> Box<dyn DeformationSolver> {
    let m = Material {
        youngs_modulus_pa: 3000.0,
        poisson_ratio: nu,
    };
    build_solver(s, mesh, m, fixed, &SolverOptions::default()).unwrap()
}

/// Uniform frictionless press with nu = 0: the block is in uniaxial
/// strain, exact for linear tetrahedra, and the force is E A d / L.
#[test]
fn frictionless_uniform_press_gives_e_a_d_over_l() {
    let (mesh, fixed, top) = block(4);
    let d = 1e-3;
    let want = 3000.0 * L * L * d / L;
    for s in [Strategy::Compliance, Strategy::Direct] {
        let mut solver = solver(s, &mesh, &fixed, 0.0);
        let rows = plane_rows(&mesh, &top, d, 0.0);
        let mut ans = ContactAnswer::default();
        solver.solve_contact(&rows, &mut ans).unwrap();
        let f: f64 = ans.multipliers.iter().sum();
        assert!(
            (f - want).abs() < 1e-9 * want,
            "{}: {f} N, want {want} N",
            s.name()
        );
        // Every top node is in contact, the gaps closed.
        let u = &solver.last_solution().unwrap().displacements;
        for (r, l) in rows.iter().zip(&ans.multipliers) {
            assert!(*l > 0.0);
            let g = r.gap_free_m + r.dir.dot(&u[r.node as usize]);
            assert!(g.abs() < 1e-12, "{g}");
        }
    }
}

/// A tilted plane touches part of the top: both strategies find the same
/// contact set and forces, every gap is non-negative, every force pushes,
/// and they are complementary.
#[test]
fn tilted_press_compliance_equals_direct_and_is_complementary() {
    let (mesh, fixed, top) = block(6);
    for (depth, slope) in [(0.8e-3, 0.08), (0.3e-3, 0.05), (1.5e-3, -0.12)] {
        let rows = plane_rows(&mesh, &top, depth, slope);
        let mut answers = Vec::new();
        for s in [Strategy::Compliance, Strategy::Direct] {
            let mut solver = solver(s, &mesh, &fixed, 0.45);
            let mut ans = ContactAnswer::default();
            solver.solve_contact(&rows, &mut ans).unwrap();
            let u = &solver.last_solution().unwrap().displacements;
            let scale = ans.multipliers.iter().fold(0.0f64, |m, v| m.max(*v));
            let mut active = 0;
            for (r, l) in rows.iter().zip(&ans.multipliers) {
                let g = r.gap_free_m + r.dir.dot(&u[r.node as usize]);
                assert!(*l >= 0.0, "the tissue never pulls the plate");
                assert!(g >= -1e-12, "gap {g}");
                assert!((l * g).abs() <= 1e-12 * scale, "complementarity");
                if *l > 0.0 {
                    active += 1;
                }
            }
            assert!(active > 0 && active < rows.len(), "partial contact");
            answers.push(ans.multipliers);
        }
        let scale = answers[0].iter().fold(0.0f64, |m, v| m.max(*v));
        for (a, b) in answers[0].iter().zip(&answers[1]) {
            assert!((a - b).abs() < 1e-8 * scale, "{a} vs {b}");
        }
    }
}

/// Coulomb friction: the plate pressed then dragged along +x. A small drag
/// sticks (the tangential force stays inside the cone and the tangential
/// gap closes); a large one slides: |F_t| = mu F_n, opposing the drag.
#[test]
fn coulomb_friction_sticks_then_slides() {
    let (mesh, fixed, top) = block(4);
    let mu = 0.3;
    let depth = 1e-3;
    let mut solver = solver(Strategy::Compliance, &mesh, &fixed, 0.45);
    for (drag, slides) in [(2e-5, false), (5e-3, true)] {
        // Per top node: normal row then two tangent rows; the anchor (the
        // point of the plate the node stuck to) moved by `drag` along +x.
        let mut rows = Vec::new();
        for &node in &top {
            let x = mesh.nodes[node as usize];
            let first = rows.len() as u32;
            rows.push(ContactRow::at_node(
                node,
                -Vector3::z(),
                -depth,
                RowKind::Unilateral,
            ));
            // Tangential gap: (x - anchor) . t, anchor = x + drag e_x.
            let _ = x;
            rows.push(ContactRow::at_node(
                node,
                Vector3::x(),
                -drag,
                RowKind::Tangent { normal: first, mu },
            ));
            rows.push(ContactRow::at_node(
                node,
                Vector3::y(),
                0.0,
                RowKind::Tangent { normal: first, mu },
            ));
        }
        let mut ans = ContactAnswer::default();
        solver.solve_contact(&rows, &mut ans).unwrap();
        let (mut fnorm, mut ft) = (0.0, Vector3::zeros());
        for (r, l) in rows.iter().zip(&ans.multipliers) {
            match r.kind {
                RowKind::Unilateral => fnorm += l,
                _ => ft += r.dir * *l,
            }
        }
        assert!(fnorm > 0.0);
        if slides {
            assert!(
                (ft.norm() - mu * fnorm).abs() < 0.02 * mu * fnorm,
                "sliding: |F_t| = {} vs mu F_n = {}",
                ft.norm(),
                mu * fnorm
            );
            assert!(ft.x > 0.0, "the plate drags the tissue along +x");
        } else {
            assert!(ft.norm() < mu * fnorm, "sticking: inside the cone");
        }
        assert!(ans.report.max_cone_excess_n <= 1e-9 * fnorm);
    }
}

/// Rows on points of the top's triangles (a plate edge in triangles larger
/// than the contact) with rows on vertices: `direct` (which superposes the
/// responses to the point loads on its elimination) gives the multipliers
/// of the Delassus solve of `compliance`, and the point gaps it closes are
/// closed.
#[test]
fn point_rows_compliance_equals_direct() {
    let (mesh, fixed, top) = block(4);
    let boundary = mesh.boundary();
    // Top triangles: all three vertices on the top face.
    let tops: Vec<[u32; 3]> = boundary
        .triangles
        .iter()
        .map(|t| t.map(|v| boundary.to_volume[v as usize]))
        .filter(|t| t.iter().all(|v| top.contains(v)))
        .collect();
    assert!(tops.len() >= 8);
    let n = -Vector3::z();
    let plane = L - 0.4e-3;
    let mut rows = Vec::new();
    for (k, t) in tops.iter().enumerate().step_by(3) {
        let a = 0.2 + 0.1 * (k % 4) as f64;
        let w = [a, 0.5 * (1.0 - a), 0.5 * (1.0 - a)];
        let x: Vector3<f64> = (0..3)
            .map(|i| mesh.nodes[t[i] as usize].coords * w[i])
            .sum();
        rows.push(ContactRow::at_point(
            *t,
            w,
            n,
            plane - x.z,
            RowKind::Unilateral,
        ));
    }
    // A few vertex rows of a deeper plane elsewhere.
    for &v in top.iter().step_by(7) {
        rows.push(ContactRow::at_node(
            v,
            n,
            (L - 0.7e-3) - mesh.nodes[v as usize].z,
            RowKind::Unilateral,
        ));
    }
    let mut out = Vec::new();
    for s in [Strategy::Compliance, Strategy::Direct] {
        let mut solver = solver(s, &mesh, &fixed, 0.45);
        let mut ans = ContactAnswer::default();
        solver.solve_contact(&rows, &mut ans).unwrap();
        let u = &solver.last_solution().unwrap().displacements;
        for (r, l) in rows.iter().zip(&ans.multipliers) {
            let g = r.gap_free_m + r.normal_motion(u);
            assert!(*l >= 0.0 && g >= -1e-12, "{}: l {l} g {g}", s.name());
        }
        out.push(ans.multipliers);
    }
    let scale = out[0].iter().fold(0.0f64, |m, v| m.max(*v));
    assert!(scale > 0.0);
    for (a, b) in out[0].iter().zip(&out[1]) {
        assert!((a - b).abs() < 1e-8 * scale, "{a} vs {b}");
    }
}

/// The cube's side nodes off the fixed bottom, with their unit outward
/// normals (the sum of the normals of the side faces they lie on).
fn sides(mesh: &TetMesh) -> Vec<(u32, Vector3<f64>)> {
    (0..mesh.nodes.len() as u32)
        .filter_map(|i| {
            let p = mesh.nodes[i as usize];
            if p.z < 1e-12 {
                return None;
            }
            let mut n = Vector3::zeros();
            for (c, axis) in [(p.x, Vector3::x()), (p.y, Vector3::y())] {
                if c.abs() < 1e-12 {
                    n -= axis;
                } else if (c - L).abs() < 1e-12 {
                    n += axis;
                }
            }
            (n != Vector3::zeros()).then(|| (i, n.normalize()))
        })
        .collect()
}

/// The skull's held normal compliance (`Compliance::hold_normals`) is the
/// on-demand columns' `n_i^T C[i][j] n_j` to 1e-12 of the largest entry,
/// and costs no column: a patch over the held nodes solves none.
#[test]
fn held_normals_equal_the_on_demand_columns_and_solve_none() {
    let (mesh, fixed, _) = block(4);
    let held = sides(&mesh);
    let nodes: Vec<u32> = held.iter().map(|h| h.0).collect();
    let mut on_demand = solver(Strategy::Compliance, &mesh, &fixed, 0.45);
    let mut holding = solver(Strategy::Compliance, &mesh, &fixed, 0.45);
    assert!(holding.hold_normals(&held).unwrap());
    let mut a = fissure_engine::fem::CompliancePatch::default();
    let mut b = fissure_engine::fem::CompliancePatch::default();
    assert!(on_demand.compliance_patch(&nodes, &mut a));
    assert!(holding.compliance_patch(&nodes, &mut b));
    assert_eq!(on_demand.columns_solved(), nodes.len() as u64);
    assert_eq!(holding.columns_solved(), 0, "the held nodes need no column");
    assert_eq!(a.nodes, b.nodes);
    let normal = |v: u32| held.iter().find(|h| h.0 == v).unwrap().1;
    assert!(b.axes.iter().zip(&b.nodes).all(|(x, &v)| *x == normal(v)));
    let mut largest: f64 = 0.0;
    let mut worst: f64 = 0.0;
    for i in 0..a.nodes.len() {
        for j in 0..a.nodes.len() {
            let (ni, nj) = (normal(a.nodes[i]), normal(a.nodes[j]));
            let want = ni.dot(&(a.block(i, j) * nj));
            let got = ni.dot(&(b.block(i, j) * nj));
            largest = largest.max(want.abs());
            worst = worst.max((got - want).abs());
        }
    }
    assert!(largest > 0.0);
    assert!(worst <= 1e-12 * largest, "{worst} m/N of {largest} m/N");
}

/// A press of the cube with the skull's rows on its bulging sides: the
/// solver holding the sides' normal compliance gives the multipliers and
/// displacements of the solver that computes every row's columns (to
/// 1e-12 of the largest), and solves columns for the plate's nodes only.
#[test]
fn skull_rows_on_held_normals_solve_as_on_demand_columns_without_a_column() {
    let (mesh, fixed, top) = block(4);
    let held = sides(&mesh);
    let gap = 2e-5;
    let mut rows = plane_rows(&mesh, &top, 2e-3, 0.0);
    // Top nodes on the sides are the plate's; the skull holds the others.
    let skull: Vec<(u32, Vector3<f64>)> = held
        .iter()
        .copied()
        .filter(|h| !top.contains(&h.0))
        .collect();
    rows.extend(
        skull
            .iter()
            .map(|&(v, n)| ContactRow::at_node(v, -n, gap, RowKind::Unilateral)),
    );
    let mut on_demand = solver(Strategy::Compliance, &mesh, &fixed, 0.45);
    let mut holding = solver(Strategy::Compliance, &mesh, &fixed, 0.45);
    assert!(holding.hold_normals(&held).unwrap());
    let (mut a, mut b) = (ContactAnswer::default(), ContactAnswer::default());
    on_demand.solve_contact(&rows, &mut a).unwrap();
    holding.solve_contact(&rows, &mut b).unwrap();
    assert!(b.pending.is_empty());
    let pushing = a.multipliers[top.len()..]
        .iter()
        .filter(|&&l| l > 0.0)
        .count();
    assert!(
        pushing > 4,
        "the skull holds the bulge: {pushing} rows push"
    );
    let largest = a.multipliers.iter().fold(0.0f64, |m, l| m.max(l.abs()));
    for (x, y) in a.multipliers.iter().zip(&b.multipliers) {
        assert!((x - y).abs() <= 1e-12 * largest, "{x} N against {y} N");
    }
    let ua = &on_demand.last_solution().unwrap().displacements;
    let ub = &holding.last_solution().unwrap().displacements;
    let umax = ua.iter().fold(0.0f64, |m, u| m.max(u.norm()));
    for (x, y) in ua.iter().zip(ub) {
        assert!((x - y).norm() <= 1e-12 * umax, "{x:?} m against {y:?} m");
    }
    assert_eq!(on_demand.columns_solved(), (top.len() + skull.len()) as u64);
    assert_eq!(holding.columns_solved(), top.len() as u64);
}
