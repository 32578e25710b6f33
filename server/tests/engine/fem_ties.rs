//! Ties in the contact problem ([`fissure_server::fem::ties`]): a tie is a
//! tension-only spring, `T = k max(0, L - L0)`, between two tissue nodes.
//!
//! The laws checked, on two blocks facing each other across a gap, each
//! held at its far face, with `compliance` (rows on the Delassus operator)
//! and `direct` (sparse elimination and load responses):
//! * a stretched tie pulls with `k` times its stretch at the solution;
//! * the solution equals a fresh dense factorization of the stiffness with
//!   the ties' springs `k B B^T` added (an independent formulation: springs
//!   in the operator, not rows beside it), for soft and stiff ties, and
//!   after some ties are cut, a factorization with the remaining ones;
//! * a slack tie carries nothing and moves nothing;
//! * strategies without nodal loads refuse ties with an error naming them.

use fissure_server::fem::lcp::RowKind;
use fissure_server::fem::{
    ContactAnswer, ContactRow, DeformationSolver, Material, SolverOptions, Strategy, build_solver,
};
use fissure_server::mesh::TetMesh;
use fissure_server::mesh::blocks::cube;
use nalgebra::{DMatrix, DVector, Vector3};

const L: f64 = 0.01;
const GAP: f64 = 0.003;
const E: f64 = 3000.0;

/// Two cubes of side `L` (`n` cells), the lower one on `z in [0, L]` held
/// at `z = 0`, the upper one on `z in [L + GAP, 2 L + GAP]` held at its
/// top; the nodes of the lower top face and of the upper bottom face.
fn two_blocks(n: usize) -> (TetMesh, Vec<u32>, Vec<u32>, Vec<u32>) {
    let a = cube(L, n);
    let na = a.nodes.len() as u32;
    let mut nodes = a.nodes.clone();
    nodes.extend(a.nodes.iter().map(|p| p + Vector3::new(0.0, 0.0, L + GAP)));
    let mut tets = a.tets.clone();
    tets.extend(a.tets.iter().map(|t| t.map(|v| v + na)));
    let mesh = TetMesh::new(nodes, tets).unwrap();
    let on = |z: f64| -> Vec<u32> {
        (0..mesh.nodes.len() as u32)
            .filter(|&i| (mesh.nodes[i as usize].z - z).abs() < 1e-12)
            .collect()
    };
    let mut fixed = on(0.0);
    fixed.extend(on(2.0 * L + GAP));
    (mesh.clone(), fixed, on(L), on(L + GAP))
}

fn solver(s: Strategy, mesh: &TetMesh, fixed: &[u32]) -> Box<dyn DeformationSolver> {
    let m = Material {
        youngs_modulus_pa: E,
        poisson_ratio: 0.3,
    };
    build_solver(s, mesh, m, fixed, &SolverOptions::default()).unwrap()
}

/// A tie from lower node `a` to upper node `b` of rest length `l0`, as a
/// row at rest (free gap `L0 - |X_b - X_a|`).
fn tie_row(mesh: &TetMesh, a: u32, b: u32, l0: f64, k: f64) -> ContactRow {
    let d = mesh.nodes[b as usize] - mesh.nodes[a as usize];
    let len = d.norm();
    ContactRow::between(a, b, d / len, l0 - len, RowKind::Unilateral, 1.0 / k)
}

/// The dense reference: `(K + sum_t k_t B_t B_t^T) u = -sum_t k_t (L_t -
/// L0_t) B_t` on the free DOFs, `B_t = -n` at `a`, `+n` at `b` (the
/// gradient of `k/2 (L - L0 + n . (u_b - u_a))^2`).
fn dense_reference(
    mesh: &TetMesh,
    fixed: &[u32],
    ties: &[(u32, u32, f64, f64)],
) -> Vec<Vector3<f64>> {
    let m = Material {
        youngs_modulus_pa: E,
        poisson_ratio: 0.3,
    };
    let model = fissure_server::fem::model::Model::new(mesh, m, fixed, &[]).unwrap();
    let nd = 3 * mesh.nodes.len();
    let mut k = DMatrix::zeros(nd, nd);
    let mut e = vec![0.0; nd];
    let mut col = vec![0.0; nd];
    for j in 0..nd {
        e.fill(0.0);
        e[j] = 1.0;
        model.matvec(&e, &mut col);
        for i in 0..nd {
            k[(i, j)] = col[i];
        }
    }
    let mut f = DVector::zeros(nd);
    for &(a, b, l0, kt) in ties {
        let d = mesh.nodes[b as usize] - mesh.nodes[a as usize];
        let len = d.norm();
        let n = d / len;
        let mut bv = DVector::zeros(nd);
        for c in 0..3 {
            bv[3 * a as usize + c] = -n[c];
            bv[3 * b as usize + c] = n[c];
        }
        k += kt * &bv * bv.transpose();
        f -= kt * (len - l0) * &bv;
    }
    let free: Vec<usize> = (0..nd).filter(|&i| !model.support[i]).collect();
    let kf = DMatrix::from_fn(free.len(), free.len(), |i, j| k[(free[i], free[j])]);
    let ff = DVector::from_fn(free.len(), |i, _| f[free[i]]);
    let uf = kf
        .cholesky()
        .expect("K + ties is positive definite")
        .solve(&ff);
    let mut u = vec![Vector3::zeros(); mesh.nodes.len()];
    for (i, &dof) in free.iter().enumerate() {
        u[dof / 3][dof % 3] = uf[i];
    }
    u
}

fn max_norm(u: &[Vector3<f64>]) -> f64 {
    u.iter().map(|v| v.norm()).fold(0.0, f64::max)
}

/// The node of `nodes` nearest `(x, y)` in the plane.
fn near(mesh: &TetMesh, nodes: &[u32], x: f64, y: f64) -> u32 {
    *nodes
        .iter()
        .min_by(|&&p, &&q| {
            let d = |v: u32| {
                let r = mesh.nodes[v as usize];
                (r.x - x).powi(2) + (r.y - y).powi(2)
            };
            d(p).total_cmp(&d(q))
        })
        .unwrap()
}

#[test]
fn a_stretched_tie_pulls_with_k_times_its_stretch_as_a_fresh_factorization_with_its_spring() {
    let (mesh, fixed, lower, upper) = two_blocks(3);
    let a = near(&mesh, &lower, 0.5 * L, 0.5 * L);
    let b = near(&mesh, &upper, 0.5 * L, 0.5 * L);
    // Rest length 1 mm short of the gap: the tie starts stretched by 1 mm.
    let l0 = GAP - 0.001;
    // Very soft, comparable to the tissue (E L ~ 30 N/m), very stiff.
    for k in [1e-3, 30.0, 1e5] {
        for s in [Strategy::Compliance, Strategy::Direct] {
            let mut solver = solver(s, &mesh, &fixed);
            let row = tie_row(&mesh, a, b, l0, k);
            let mut ans = ContactAnswer::default();
            solver.solve_contact(&[row], &mut ans).unwrap();
            let u = solver.last_solution().unwrap().displacements.clone();
            let stretch = GAP - l0 + row.dir.dot(&(u[b as usize] - u[a as usize]));
            let t = ans.multipliers[0];
            assert!(stretch > 0.0, "{} k {k}: stretch {stretch}", s.name());
            // T = k s, checked as T / k = s to 1e-8 of the initial
            // stretch: a stiff tie's stretch is the small difference of two
            // displacements, and the contact solver softens every row by
            // REGULARIZATION = 1e-9 of its diagonal.
            assert!(
                (t / k - stretch).abs() <= 1e-8 * (GAP - l0),
                "{} k {k}: tension {t} N, k * stretch {} N",
                s.name(),
                k * stretch
            );
            let want = dense_reference(&mesh, &fixed, &[(a, b, l0, k)]);
            let err = u
                .iter()
                .zip(&want)
                .map(|(p, q)| (p - q).norm())
                .fold(0.0, f64::max);
            assert!(
                err <= 1e-8 * max_norm(&want),
                "{} k {k}: displacement error {err} m against {} m",
                s.name(),
                max_norm(&want)
            );
            // The tie pulls the lower block up and the upper one down.
            assert!(u[a as usize].z > 0.0 && u[b as usize].z < 0.0);
        }
    }
}

#[test]
fn a_slack_tie_carries_nothing_and_moves_nothing() {
    let (mesh, fixed, lower, upper) = two_blocks(2);
    let a = near(&mesh, &lower, 0.5 * L, 0.5 * L);
    let b = near(&mesh, &upper, 0.5 * L, 0.5 * L);
    for l0 in [GAP, GAP + 0.001] {
        for s in [Strategy::Compliance, Strategy::Direct] {
            let mut solver = solver(s, &mesh, &fixed);
            let mut ans = ContactAnswer::default();
            solver
                .solve_contact(&[tie_row(&mesh, a, b, l0, 50.0)], &mut ans)
                .unwrap();
            // At L0 = GAP the tie is just taut: rounding of the rest
            // length (1e-18 m) may leave it 1e-16 N.
            let t = ans.multipliers[0];
            assert!(t.abs() <= 1e-15, "{} L0 {l0}: {t} N", s.name());
            let u = &solver.last_solution().unwrap().displacements;
            assert!(max_norm(u) <= 1e-15, "{}: {} m", s.name(), max_norm(u));
        }
    }
}

#[test]
fn after_cuts_the_solution_equals_a_fresh_factorization_with_the_remaining_ties() {
    let (mesh, fixed, lower, upper) = two_blocks(3);
    // Nine ties on a grid of the facing faces, some slanted, of different
    // stiffnesses, each stretched at rest.
    let mut ties = Vec::new();
    for (i, &(x, y)) in [
        (0.2, 0.2),
        (0.5, 0.2),
        (0.8, 0.2),
        (0.2, 0.5),
        (0.5, 0.5),
        (0.8, 0.5),
        (0.2, 0.8),
        (0.5, 0.8),
        (0.8, 0.8),
    ]
    .iter()
    .enumerate()
    {
        let a = near(&mesh, &lower, x * L, y * L);
        let b = near(&mesh, &upper, (1.0 - y) * L, x * L);
        let len = (mesh.nodes[b as usize] - mesh.nodes[a as usize]).norm();
        ties.push((a, b, len - 0.0005, 5.0 + 3.0 * i as f64));
    }
    let rows: Vec<ContactRow> = ties
        .iter()
        .map(|&(a, b, l0, k)| tie_row(&mesh, a, b, l0, k))
        .collect();
    for s in [Strategy::Compliance, Strategy::Direct] {
        let mut solver = solver(s, &mesh, &fixed);
        for cut in [vec![], vec![4], vec![0, 2, 7], vec![1, 3, 5, 6, 8]] {
            let kept: Vec<usize> = (0..ties.len()).filter(|i| !cut.contains(i)).collect();
            let these: Vec<ContactRow> = kept.iter().map(|&i| rows[i]).collect();
            let mut ans = ContactAnswer::default();
            solver.solve_contact(&these, &mut ans).unwrap();
            assert!(
                ans.multipliers.iter().all(|&t| t > 0.0),
                "{} cut {cut:?}: every kept tie stays stretched: {:?}",
                s.name(),
                ans.multipliers
            );
            let want: Vec<_> = kept.iter().map(|&i| ties[i]).collect();
            let want = dense_reference(&mesh, &fixed, &want);
            let u = &solver.last_solution().unwrap().displacements;
            let err = u
                .iter()
                .zip(&want)
                .map(|(p, q)| (p - q).norm())
                .fold(0.0, f64::max);
            assert!(
                err <= 1e-8 * max_norm(&want),
                "{} cut {cut:?}: error {err} m of {} m",
                s.name(),
                max_norm(&want)
            );
        }
    }
}

#[test]
fn strategies_without_nodal_loads_refuse_ties_naming_them() {
    let (mesh, fixed, lower, upper) = two_blocks(2);
    let a = near(&mesh, &lower, 0.5 * L, 0.5 * L);
    let b = near(&mesh, &upper, 0.5 * L, 0.5 * L);
    for s in [Strategy::Corotational, Strategy::NeoHookean] {
        let mut solver = solver(s, &mesh, &fixed);
        let mut ans = ContactAnswer::default();
        let err = solver
            .solve_contact(&[tie_row(&mesh, a, b, GAP - 0.001, 10.0)], &mut ans)
            .unwrap_err()
            .to_string();
        assert!(err.contains("ties"), "{}: {err}", s.name());
    }
}

#[test]
fn a_negative_tie_compliance_is_refused() {
    let (mesh, fixed, lower, upper) = two_blocks(2);
    let a = near(&mesh, &lower, 0.5 * L, 0.5 * L);
    let b = near(&mesh, &upper, 0.5 * L, 0.5 * L);
    let mut row = tie_row(&mesh, a, b, GAP, 10.0);
    row.compliance_m_per_n = -0.1;
    let mut solver = solver(Strategy::Compliance, &mesh, &fixed);
    let err = solver
        .solve_contact(&[row], &mut ContactAnswer::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("compliance"), "{err}");
}
