//! Ties in the contact problem ([`fissure_engine::fem::ties`]): a tie is a
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
//! * strategies without nodal loads refuse tie *rows* with an error naming
//!   them; they hold ties as springs of their energy instead
//!   ([`fissure_engine::fem::ties::TieSprings`]), and there:
//!   * a stretched spring pulls with `k` times its true stretch, balanced by
//!     the supports (equilibrium of each block);
//!   * at a small stretch it agrees with the linear strategies' row;
//!   * a slack spring moves nothing;
//!   * the force loop's local model (the tangent compliance) has the
//!     spring in series with the tissue (Sherman-Morrison).

use fissure_engine::fem::corotational::IterativeOptions;
use fissure_engine::fem::lcp::RowKind;
use fissure_engine::fem::ties::{TiePair, TieSprings};
use fissure_engine::fem::{
    CompliancePatch, ContactAnswer, ContactRow, DeformationSolver, Material, SolverOptions,
    Strategy, build_solver,
};
use fissure_engine::mesh::TetMesh;
use fissure_engine::mesh::blocks::cube;
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
    let model = fissure_engine::fem::model::Model::new(mesh, m, fixed, &[]).unwrap();
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

/// Press positions on the lower block's top face, as fractions of `L`.
type Presses = &'static [(f64, f64)];

fn max_norm(u: &[Vector3<f64>]) -> f64 {
    u.iter().map(|v| v.norm()).fold(0.0, f64::max)
}

/// The largest distance between two displacement fields, m.
fn max_diff(u: &[Vector3<f64>], v: &[Vector3<f64>]) -> f64 {
    u.iter()
        .zip(v)
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max)
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
            let err = max_diff(&u, &want);
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
            let err = max_diff(&solver.last_solution().unwrap().displacements, &want);
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

/// `compliance` keeps the rows of `W` and the solver's factor of the rows
/// that lead its problem (the ties) from one contact solve to the next; the
/// law: whatever the solves before, a solve's answer is the one a fresh
/// solver gives on the same rows (to the solver's tolerance, 1e-9 of the
/// diagonal: 1e-8 here), also after a kept row's own compliance changed
/// (a pair of ties that lost one) and with presses before and among them.
#[test]
fn a_contact_solve_after_others_equals_a_fresh_solvers_answer_on_the_same_rows() {
    let (mesh, fixed, lower, upper) = two_blocks(3);
    let mut ties = Vec::new();
    for (i, &(x, y)) in [(0.2, 0.3), (0.5, 0.5), (0.8, 0.4), (0.3, 0.8)]
        .iter()
        .enumerate()
    {
        let a = near(&mesh, &lower, x * L, y * L);
        let b = near(&mesh, &upper, x * L, (1.0 - y) * L);
        let len = (mesh.nodes[b as usize] - mesh.nodes[a as usize]).norm();
        ties.push((a, b, len - 0.0004, 4.0 + 2.0 * i as f64));
    }
    // A press on a node of the lower block's top face: it moves down 0.3 mm
    // (`g = gap_free + dir . u >= 0` with `dir = -z`).
    let press = |x: f64, y: f64| {
        ContactRow::at_node(
            near(&mesh, &lower, x * L, y * L),
            -Vector3::z(),
            -0.0003,
            RowKind::Unilateral,
        )
    };
    // (press positions, stiffness factor of each tie: 0 cuts it)
    let sequence: [(Presses, [f64; 4]); 5] = [
        (&[(0.5, 0.5)], [1.0, 1.0, 1.0, 1.0]),
        (&[(0.2, 0.2), (0.7, 0.6)], [1.0, 1.0, 1.0, 1.0]),
        (&[(0.2, 0.2)], [1.0, 0.5, 1.0, 1.0]),
        (&[], [1.0, 0.5, 0.0, 1.0]),
        (&[(0.4, 0.9), (0.9, 0.1), (0.5, 0.5)], [0.25, 0.5, 0.0, 1.0]),
    ];
    let mut kept = solver(Strategy::Compliance, &mesh, &fixed);
    for (step, (presses, factors)) in sequence.iter().enumerate() {
        let mut rows: Vec<ContactRow> = presses.iter().map(|&(x, y)| press(x, y)).collect();
        for (&(a, b, l0, k), &f) in ties.iter().zip(factors) {
            if f > 0.0 {
                rows.push(tie_row(&mesh, a, b, l0, f * k));
            }
        }
        let mut ans = ContactAnswer::default();
        kept.solve_contact(&rows, &mut ans).unwrap();
        let u = kept.last_solution().unwrap().displacements.clone();
        let mut fresh = solver(Strategy::Compliance, &mesh, &fixed);
        let mut want = ContactAnswer::default();
        fresh.solve_contact(&rows, &mut want).unwrap();
        let v = &fresh.last_solution().unwrap().displacements;
        let scale = want
            .multipliers
            .iter()
            .fold(0.0, |m: f64, l| m.max(l.abs()));
        assert!(scale > 0.0, "step {step}: the rows carry load");
        for (i, (l, m)) in ans.multipliers.iter().zip(&want.multipliers).enumerate() {
            assert!(
                (l - m).abs() <= 1e-8 * scale,
                "step {step} row {i}: {l} N against a fresh solver's {m} N"
            );
        }
        let err = max_diff(&u, v);
        assert!(
            err <= 1e-8 * max_norm(v),
            "step {step}: displacement error {err} m of {} m",
            max_norm(v)
        );
    }
}

/// The force loop's solver ([`ForceSolver`]) keeps its rows of `W` and its
/// factor across frames while the patches are linear. The law: every
/// sample equals a full solve of its rows, whatever the frames before,
/// with each frame's patch listing the nodes in another order, presses
/// coming and going, and a tie pair's own compliance changed (one of its
/// ties cut) with nothing else about the row.
#[test]
fn the_force_loops_solver_keeping_rows_across_frames_equals_a_full_solve_at_every_sample() {
    use fissure_engine::fem::CompliancePatch;
    use fissure_engine::sim::core::local_model::{ForceModel, ForceSolver, SampleAnswer};
    use fissure_engine::sim::core::rows::{self, Anchors, NO_TRIANGLE, Row, TIE_OWNER};
    use nalgebra::Point3;
    use std::sync::Arc;

    let (mesh, fixed, lower, upper) = two_blocks(3);
    let mut ties = Vec::new();
    for (i, &(x, y)) in [(0.2, 0.3), (0.5, 0.5), (0.8, 0.4)].iter().enumerate() {
        let a = near(&mesh, &lower, x * L, y * L);
        let b = near(&mesh, &upper, x * L, (1.0 - y) * L);
        let len = (mesh.nodes[b as usize] - mesh.nodes[a as usize]).norm();
        ties.push((a, b, len - 0.0004, 4.0 + 2.0 * i as f64));
    }
    let row = |key: u64, owner: u16, r: ContactRow| Row {
        key,
        owner,
        row: r,
        point: Point3::origin(),
        triangle: NO_TRIANGLE,
    };
    let press = |x: f64, y: f64| {
        let v = near(&mesh, &lower, x * L, y * L);
        let r = ContactRow::at_node(v, -Vector3::z(), -0.0003, RowKind::Unilateral);
        row(rows::key(v, 0, 0, 0), 0, r)
    };
    // Frames: (presses, stiffness factor of each tie), three samples each
    // (the presses deepen).
    let frames: [(Presses, [f64; 3]); 4] = [
        (&[(0.5, 0.5)], [1.0, 1.0, 1.0]),
        (&[(0.5, 0.5), (0.2, 0.8)], [1.0, 1.0, 1.0]),
        (&[(0.2, 0.8)], [1.0, 0.5, 1.0]),
        (&[(0.9, 0.1), (0.5, 0.5)], [0.25, 0.5, 1.0]),
    ];
    let mut full = solver(Strategy::Compliance, &mesh, &fixed);
    let mut all_nodes: Vec<u32> = ties.iter().flat_map(|&(a, b, _, _)| [a, b]).collect();
    all_nodes.extend(frames.iter().flat_map(|(p, _)| {
        p.iter()
            .map(|&(x, y)| near(&mesh, &lower, x * L, y * L))
            .collect::<Vec<_>>()
    }));
    let mut force = ForceSolver::new();
    let mut answer = SampleAnswer::default();
    for (frame, (presses, factors)) in frames.iter().enumerate() {
        // Each frame's patch lists the nodes in another order.
        all_nodes.rotate_left(2);
        let mut patch = CompliancePatch::default();
        assert!(full.compliance_patch(&all_nodes, &mut patch));
        let mut index = vec![u32::MAX; mesh.nodes.len()];
        for (i, &v) in patch.nodes.iter().enumerate() {
            index[v as usize] = i as u32;
        }
        let model = ForceModel::new(
            frame as u64,
            Arc::new(patch),
            Arc::new(index),
            Vec::new(),
            Vec::new(),
            Anchors::default(),
            true,
            Vec::new(),
        );
        for sample in 0..3 {
            let deeper = 1.0 + 0.5 * sample as f64;
            let mut rs: Vec<Row> = presses
                .iter()
                .map(|&(x, y)| {
                    let mut r = press(x, y);
                    r.row.gap_free_m *= deeper;
                    r
                })
                .collect();
            for (t, (&(a, b, l0, k), &f)) in ties.iter().zip(factors).enumerate() {
                let r = tie_row(&mesh, a, b, l0, f * k);
                rs.push(row(rows::key(t as u32, TIE_OWNER, 8, 0), TIE_OWNER, r));
            }
            force.solve(&model, &rs, &mut answer).unwrap();
            assert!(answer.pending.is_empty());
            let fem_rows: Vec<ContactRow> = rs.iter().map(|r| r.row).collect();
            let mut want = ContactAnswer::default();
            full.solve_contact(&fem_rows, &mut want).unwrap();
            let scale = want
                .multipliers
                .iter()
                .fold(0.0, |m: f64, l| m.max(l.abs()));
            assert!(scale > 0.0);
            for (i, (l, m)) in answer.lambda.iter().zip(&want.multipliers).enumerate() {
                assert!(
                    (l - m).abs() <= 1e-8 * scale,
                    "frame {frame} sample {sample} row {i}: {l} N against a full solve's {m} N"
                );
            }
        }
    }
}

/// A patch that leads with shared nodes (the ties', their blocks among
/// themselves computed once) holds the same compliance as a plain patch:
/// every block, read directly or as a product, equals the plain patch's
/// block of the same two nodes (to round-off: a block and its transpose
/// come from two columns of a symmetric inverse).
#[test]
fn a_patch_sharing_the_ties_blocks_equals_a_plain_patch_block_for_block() {
    use fissure_engine::fem::CompliancePatch;
    let (mesh, fixed, lower, upper) = two_blocks(3);
    let shared: Vec<u32> = vec![
        near(&mesh, &lower, 0.2 * L, 0.2 * L),
        near(&mesh, &upper, 0.2 * L, 0.8 * L),
        near(&mesh, &lower, 0.7 * L, 0.5 * L),
        near(&mesh, &upper, 0.6 * L, 0.4 * L),
    ];
    let asked: Vec<u32> = vec![
        near(&mesh, &lower, 0.5 * L, 0.5 * L),
        shared[2],
        near(&mesh, &lower, 0.9 * L, 0.1 * L),
        near(&mesh, &upper, 0.1 * L, 0.9 * L),
    ];
    let mut with = solver(Strategy::Compliance, &mesh, &fixed);
    with.share_patch_nodes(&shared);
    let mut plain = solver(Strategy::Compliance, &mesh, &fixed);
    let mut p = CompliancePatch::default();
    let mut q = CompliancePatch::default();
    for round in 0..2 {
        assert!(with.compliance_patch(&asked, &mut p));
        let mut all = p.nodes.clone();
        all.sort_unstable();
        assert!(plain.compliance_patch(&all, &mut q));
        assert_eq!(p.shared_nodes(), shared.len(), "round {round}");
        assert_eq!(&p.nodes[..shared.len()], &shared[..]);
        for &n in &asked {
            assert!(p.nodes.contains(&n), "round {round}: node {n} asked");
        }
        let mut distinct: Vec<u32> = shared.iter().chain(&asked).copied().collect();
        distinct.sort_unstable();
        distinct.dedup();
        assert_eq!(
            p.nodes.len(),
            distinct.len(),
            "round {round}: each node once"
        );
        let at = |v: u32| q.nodes.iter().position(|&x| x == v).unwrap();
        let scale = (0..q.nodes.len())
            .map(|i| q.block(i, i).norm())
            .fold(0.0, f64::max);
        let v = Vector3::new(0.3, -1.1, 0.7);
        for i in 0..p.nodes.len() {
            for j in 0..p.nodes.len() {
                let want = q.block(at(p.nodes[i]), at(p.nodes[j]));
                let got = p.block(i, j);
                assert!(
                    (got - want).norm() <= 1e-12 * scale,
                    "round {round} block ({i}, {j}): {got} against {want}"
                );
                let prod = p.block_mul(i, j, &v);
                assert!((prod - want * v).norm() <= 1e-12 * scale * v.norm());
            }
        }
    }
}

/// A nonlinear strategy holding the springs of `pairs` (`(a, b)`), solved
/// to the reference tolerance.
fn spring_solver(
    s: Strategy,
    mesh: &TetMesh,
    fixed: &[u32],
    pairs: &[[u32; 2]],
) -> Box<dyn DeformationSolver> {
    let m = Material {
        youngs_modulus_pa: E,
        poisson_ratio: 0.3,
    };
    let opts = SolverOptions {
        tie_pairs: pairs.to_vec(),
        iterative: IterativeOptions::reference(),
        ..Default::default()
    };
    build_solver(s, mesh, m, fixed, &opts).unwrap()
}

/// One spring from `a` to `b` of rest length `l0` (m) and stiffness `k`
/// (N/m), declared pair 0.
fn one_spring(a: u32, b: u32, l0: f64, k: f64) -> TieSprings {
    TieSprings {
        pairs: vec![(
            0,
            TiePair {
                first_tie: 0,
                a,
                b,
                rest_length_m: l0,
                stiffness_n_per_m: k,
            },
        )],
    }
}

const NONLINEAR: [Strategy; 2] = [Strategy::Corotational, Strategy::NeoHookean];

#[test]
fn a_nonlinear_strategys_tie_pulls_with_k_times_its_true_stretch_balanced_by_the_supports() {
    let (mesh, fixed, lower, upper) = two_blocks(3);
    let a = near(&mesh, &lower, 0.5 * L, 0.5 * L);
    let b = near(&mesh, &upper, 0.5 * L, 0.5 * L);
    // Seeded 0.5 mm short across the 3 mm gap: a 17 % pre-stretch.
    let (l0, k) = (GAP - 0.0005, 2.0);
    for s in NONLINEAR {
        let mut solver = spring_solver(s, &mesh, &fixed, &[[a, b]]);
        assert!(
            solver.set_tie_springs(&one_spring(a, b, l0, k)),
            "{}",
            s.name()
        );
        let u = solver.solve(&[]).unwrap().displacements.clone();
        let xa = mesh.nodes[a as usize] + u[a as usize];
        let xb = mesh.nodes[b as usize] + u[b as usize];
        let len = (xb - xa).norm();
        let n = (xb - xa) / len;
        let tension = k * (len - l0);
        // The walls came together, not all the way.
        assert!(len < GAP && len > l0, "{}: length {len} m", s.name());
        // The lower block is held by its supports alone against the tie's
        // pull `T n` on `a`.
        let reactions = solver.support_reactions();
        let lower_sum: Vector3<f64> = fixed
            .iter()
            .zip(reactions)
            .filter(|(v, _)| mesh.nodes[**v as usize].z < 0.5 * L)
            .map(|(_, r)| *r)
            .sum();
        let err = (lower_sum + tension * n).norm();
        assert!(
            err <= 1e-6 * tension,
            "{}: supports {lower_sum:?} N against the tie's {:?} N",
            s.name(),
            tension * n
        );
    }
}

#[test]
fn at_a_small_stretch_a_nonlinear_strategys_tie_agrees_with_the_linear_row() {
    let (mesh, fixed, lower, upper) = two_blocks(3);
    let a = near(&mesh, &lower, 0.3 * L, 0.6 * L);
    let b = near(&mesh, &upper, 0.4 * L, 0.5 * L);
    let rest = (mesh.nodes[b as usize] - mesh.nodes[a as usize]).norm();
    // A 1 um pre-stretch: displacements of order 1e-7 m over 1 cm blocks,
    // where the geometric nonlinearity is of relative order 1e-5.
    let (l0, k) = (rest - 1e-6, 5.0);
    let mut linear = solver(Strategy::Compliance, &mesh, &fixed);
    linear
        .solve_contact(
            &[tie_row(&mesh, a, b, l0, k)],
            &mut ContactAnswer::default(),
        )
        .unwrap();
    let want = linear.last_solution().unwrap().displacements.clone();
    assert!(max_norm(&want) > 1e-8);
    for s in NONLINEAR {
        let mut solver = spring_solver(s, &mesh, &fixed, &[[a, b]]);
        solver.set_tie_springs(&one_spring(a, b, l0, k));
        let err = max_diff(&solver.solve(&[]).unwrap().displacements, &want);
        assert!(
            err <= 1e-4 * max_norm(&want),
            "{}: error {err:e} m of {:e} m",
            s.name(),
            max_norm(&want)
        );
    }
}

#[test]
fn a_slack_tie_spring_moves_nothing() {
    let (mesh, fixed, lower, upper) = two_blocks(2);
    let a = near(&mesh, &lower, 0.5 * L, 0.5 * L);
    let b = near(&mesh, &upper, 0.5 * L, 0.5 * L);
    for s in NONLINEAR {
        let mut solver = spring_solver(s, &mesh, &fixed, &[[a, b]]);
        solver.set_tie_springs(&one_spring(a, b, GAP + 0.001, 50.0));
        let u = &solver.solve(&[]).unwrap().displacements;
        assert_eq!(max_norm(u), 0.0, "{}", s.name());
    }
}

/// The force loop's local model of a nonlinear strategy is the tangent
/// compliance, the spring's stiffness included: along the tie, the
/// compliance between its nodes `c = n . (C_aa + C_bb - C_ab - C_ba) n`
/// is the tissue's `c0` in series with the spring, `c0 / (1 + k c0)`
/// (Sherman-Morrison for the rank-one `k (e_b - e_a) (e_b - e_a)^T n n^T`;
/// the spring's geometric part `T / L`, of relative order 1e-4 here, and
/// the tissue's change of tangent over 1e-7 m are below the tolerance).
#[test]
fn a_nonlinear_strategys_local_model_has_the_spring_in_series_with_the_tissue() {
    let (mesh, fixed, lower, upper) = two_blocks(3);
    let a = near(&mesh, &lower, 0.5 * L, 0.5 * L);
    let b = near(&mesh, &upper, 0.5 * L, 0.5 * L);
    let rest = mesh.nodes[b as usize] - mesh.nodes[a as usize];
    let n = rest.normalize();
    let along = |patch: &CompliancePatch| {
        let c = patch.block(0, 0) + patch.block(1, 1) - patch.block(0, 1) - patch.block(1, 0);
        n.dot(&(c * n))
    };
    let mut bare = solver(Strategy::Compliance, &mesh, &fixed);
    let mut patch = CompliancePatch::default();
    assert!(bare.compliance_patch(&[a, b], &mut patch));
    let c0 = along(&patch);
    let k = 40.0;
    for s in NONLINEAR {
        let mut solver = spring_solver(s, &mesh, &fixed, &[[a, b]]);
        solver.set_tie_springs(&one_spring(a, b, rest.norm() - 1e-6, k));
        solver.solve(&[]).unwrap();
        let mut patch = CompliancePatch::default();
        assert!(solver.compliance_patch(&[a, b], &mut patch), "{}", s.name());
        let c = along(&patch);
        let want = c0 / (1.0 + k * c0);
        assert!(
            (c - want).abs() <= 1e-3 * want,
            "{}: {c:e} m/N, in series {want:e} m/N (tissue alone {c0:e})",
            s.name()
        );
    }
}
