//! An elastic (Winkler) foundation on the outer surface: normal springs of
//! stiffness `k` per area (Pa/m) between the tissue and a fixed support
//! (the skull through the CSF layer and the meninges), DESIGN.md section 3c.
//!
//! **Method.** On a flat P1 surface triangle `T` of area `A` and outward unit
//! normal `n`, the spring energy of a displacement `u` is
//! `1/2 k integral_T (n . u)^2 dA`, so the triangle adds to the stiffness
//! the 9 x 9 matrix
//!
//! `K_ij = k (integral_T N_i N_j dA) n n^T = k A / 12 (1 + delta_ij) n n^T`
//!
//! (the consistent matrix: the integral is exact for the linear shape
//! functions). Consistent rather than lumped: the three nodes of a surface
//! triangle already share a tetrahedron, so the coupling costs no new
//! entry of the sparsity pattern, and the consistent form reproduces the
//! work of any linear normal displacement exactly (a lumped `k A / 3 n n^T`
//! per node reproduces only the uniform one). Only the normal component is
//! held: a tangential displacement stores no energy, so the tissue slides
//! freely along the support.
//!
//! The springs enter the stiffness once: [`fold_into`] adds each triangle's
//! matrix to the element matrix of the tetrahedron the triangle bounds, so
//! every strategy that assembles `K` from the element matrices (`direct`,
//! `compliance`: factor-once, its condensed compliance stays exact) sees
//! them with no change to its solve, and the reactions (`K u` at a
//! constrained node) include the springs' force there.
//!
//! The nonlinear strategies (`corotational`, `neo-hookean`) evaluate their
//! internal force from the stress, not from the element matrices, so
//! [`fold_into`] also keeps the springs apart ([`FoundationSprings`], the
//! model's [`Model::foundation`]): a linear spring energy
//! `1/2 u^T K_f u` about the rest shape (fixed support, fixed rest normals,
//! whatever the tissue's rotation), which adds `K_f u` to their internal
//! force, `K_f` to their tangent and `1/2 u^T K_f u` to the energy of
//! their line search. Where they use the rest stiffness `kel` itself (the
//! corotational preconditioner, the neo-Hookean fallback when the tangent
//! is not positive definite) the springs are in it already and are not
//! added again.

use super::SolveError;
use super::assembly::{gather, scatter_add};
use super::element::ElementMatrix;
use super::model::Model;
use nalgebra::{Point3, SMatrix, Vector3};
use std::collections::{BTreeMap, HashMap};

/// The springs of an elastic foundation.
#[derive(Debug, Clone, PartialEq)]
pub struct Foundation {
    /// Normal stiffness per area, Pa/m (N/m per m^2), >= 0.
    pub stiffness_pa_per_m: f64,
    /// The supported outer-surface triangles (volume node indices, outward
    /// oriented: right-hand normal pointing out of the tissue).
    pub faces: Vec<[u32; 3]>,
}

/// The foundation's springs kept apart from the element matrices, for the
/// strategies that do not read those (module documentation): per element
/// that bounds a supported triangle, the sum of its triangles' matrices
/// ([`face_matrix`]) in the element's local DOF order (a 12 x 12 matrix,
/// N/m, zero on the corner off the triangle), so that its tangent goes
/// through the element path of the assembly (the element's own pattern
/// entries, node bases, elimination) unchanged.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FoundationSprings {
    /// The elements that bear springs, ascending.
    elements: Vec<usize>,
    /// Their spring matrices, beside `elements`, N/m.
    matrices: Vec<ElementMatrix>,
}

impl FoundationSprings {
    /// Whether no element bears springs.
    pub fn is_empty(&self) -> bool {
        self.elements.is_empty()
    }

    /// Each element that bears springs and its matrix (N/m), ascending.
    pub fn iter(&self) -> impl Iterator<Item = (usize, &ElementMatrix)> + '_ {
        self.elements.iter().copied().zip(&self.matrices)
    }

    /// The spring matrix of element `e`, if it bears springs.
    pub fn matrix_of(&self, e: usize) -> Option<&ElementMatrix> {
        self.elements
            .binary_search(&e)
            .ok()
            .map(|i| &self.matrices[i])
    }

    /// Their energy `1/2 u^T K_f u` at displacement `u` (DOF vector, m) of
    /// a model with elements `tets`, J (>= 0: each matrix is positive
    /// semi-definite).
    pub fn energy(&self, tets: &[[u32; 4]], u: &[f64]) -> f64 {
        self.iter()
            .map(|(e, k)| {
                let ue = gather(&tets[e], u);
                0.5 * ue.dot(&(k * ue))
            })
            .sum()
    }

    /// Adds `K_f x` to `y` (DOF vectors): their internal force (N) at the
    /// displacement `x` (m), and their tangent's product with `x` (the
    /// springs are linear).
    pub fn add_product(&self, tets: &[[u32; 4]], x: &[f64], y: &mut [f64]) {
        for (e, k) in self.iter() {
            let t = &tets[e];
            scatter_add(t, &(k * gather(t, x)), y);
        }
    }
}

/// Outward unit normal and area (m^2) of a triangle.
pub fn normal_area(p: [Point3<f64>; 3]) -> (Vector3<f64>, f64) {
    let c = (p[1] - p[0]).cross(&(p[2] - p[0]));
    let norm = c.norm();
    let n = if norm > 0.0 {
        c / norm
    } else {
        Vector3::zeros()
    };
    (n, 0.5 * norm)
}

/// The consistent 9 x 9 normal-spring matrix of one triangle, N/m, DOF
/// order (node0.x, node0.y, node0.z, node1.x, ...):
/// `K_ij = k A / 12 (1 + delta_ij) n n^T`.
pub fn face_matrix(p: [Point3<f64>; 3], stiffness_pa_per_m: f64) -> SMatrix<f64, 9, 9> {
    let (n, area) = normal_area(p);
    let nn = n * n.transpose();
    let mut k = SMatrix::<f64, 9, 9>::zeros();
    for i in 0..3 {
        for j in 0..3 {
            let w = stiffness_pa_per_m * area / 12.0 * if i == j { 2.0 } else { 1.0 };
            k.fixed_view_mut::<3, 3>(3 * i, 3 * j).copy_from(&(nn * w));
        }
    }
    k
}

/// Adds the foundation's springs to the element matrices of `model` (each
/// triangle into the tetrahedron it bounds) and keeps them apart in
/// [`Model::foundation`] too. Fails on a stiffness that is
/// negative or not finite, a node out of range, or a triangle that bounds
/// no tetrahedron of the model (named by index).
pub fn fold_into(model: &mut Model, foundation: &Foundation) -> Result<(), SolveError> {
    let k = foundation.stiffness_pa_per_m;
    if !(k.is_finite() && k >= 0.0) {
        return Err(SolveError::InvalidModel(format!(
            "foundation stiffness {k} Pa/m is not a finite number >= 0"
        )));
    }
    let n_nodes = model.rest.len();
    let mut owner: HashMap<[u32; 3], usize> = HashMap::with_capacity(4 * model.tets.len());
    for (e, t) in model.tets.iter().enumerate() {
        for skip in 0..4 {
            let mut key = [0u32; 3];
            let mut m = 0;
            for (a, &n) in t.iter().enumerate() {
                if a != skip {
                    key[m] = n;
                    m += 1;
                }
            }
            key.sort_unstable();
            owner.insert(key, e);
        }
    }
    // Each element's springs, summed over its faces (and over the faces of
    // a foundation folded before).
    let mut kept_by_element: BTreeMap<usize, ElementMatrix> =
        model.foundation.iter().map(|(e, k)| (e, *k)).collect();
    for (i, f) in foundation.faces.iter().enumerate() {
        if let Some(&n) = f.iter().find(|&&n| n as usize >= n_nodes) {
            return Err(SolveError::InvalidModel(format!(
                "foundation face {i} refers to node {n} of {n_nodes}"
            )));
        }
        let mut key = *f;
        key.sort_unstable();
        let e = *owner.get(&key).ok_or_else(|| {
            SolveError::InvalidModel(format!(
                "foundation face {i} ({f:?}) bounds no element of the model"
            ))
        })?;
        let t = model.tets[e];
        let local = f.map(|n| t.iter().position(|&m| m == n).expect("face of the tet"));
        let kf = face_matrix(f.map(|n| model.rest[n as usize]), k);
        let kept = kept_by_element
            .entry(e)
            .or_insert_with(ElementMatrix::zeros);
        // Into the element matrix (the linear strategies' stiffness) and
        // beside it (the nonlinear ones').
        for ke in [&mut model.kel[e], kept] {
            for (a, &la) in local.iter().enumerate() {
                for (b, &lb) in local.iter().enumerate() {
                    let block = kf.fixed_view::<3, 3>(3 * a, 3 * b).into_owned();
                    let mut dst = ke.fixed_view_mut::<3, 3>(3 * la, 3 * lb);
                    dst += block;
                }
            }
        }
    }
    model.foundation = FoundationSprings {
        elements: kept_by_element.keys().copied().collect(),
        matrices: kept_by_element.into_values().collect(),
    };
    Ok(())
}

/// The outer triangles of `mesh` (volume node indices, outward) whose
/// centroid satisfies `keep`: a foundation's faces chosen by place.
pub fn outer_faces_where(
    mesh: &crate::mesh::TetMesh,
    keep: impl Fn(Point3<f64>) -> bool,
) -> Vec<[u32; 3]> {
    let s = mesh.boundary();
    s.triangles
        .iter()
        .map(|t| t.map(|v| s.to_volume[v as usize]))
        .filter(|f| {
            let c = f
                .iter()
                .map(|&n| mesh.nodes[n as usize].coords)
                .sum::<Vector3<f64>>()
                / 3.0;
            keep(Point3::from(c))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fem::corotational::IterativeOptions;
    use crate::fem::{AxisSupport, Material, Prescribed, SolverOptions, Strategy, build_solver};
    use crate::mesh::TetMesh;
    use crate::mesh::blocks::cuboid;

    /// A foundation on `faces`, and rollers that take away the rigid
    /// motions a normal-only support on one plane leaves (`compliance`
    /// factors K under its supports alone): node 0 held along x and y, the
    /// node `along_x` (on the x axis) along y. They are statically
    /// determinate for those motions, so they carry no force of their own.
    fn options(faces: Vec<[u32; 3]>, k: f64, along_x: u32) -> SolverOptions {
        SolverOptions {
            foundation: Some(Foundation {
                stiffness_pa_per_m: k,
                faces,
            }),
            axis_supports: vec![
                AxisSupport { node: 0, axis: 0 },
                AxisSupport { node: 0, axis: 1 },
                AxisSupport {
                    node: along_x,
                    axis: 1,
                },
            ],
            ..SolverOptions::default()
        }
    }

    /// The node at `p` of `mesh`.
    fn node_at(mesh: &TetMesh, p: Point3<f64>) -> u32 {
        mesh.nodes
            .iter()
            .position(|q| (q - p).norm() < 1e-12)
            .expect("a node there") as u32
    }

    #[test]
    fn a_face_holds_the_normal_only() {
        // Uniform normal displacement d: total force k A d along n (the
        // consistent weights A/12 (1 + delta_ij) sum to A); a tangential
        // displacement stores nothing (n n^T t = 0).
        let p = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.02, 0.0, 0.0),
            Point3::new(0.0, 0.01, 0.0),
        ];
        let (k, area, d) = (2e6, 1e-4, 1e-3);
        let m = face_matrix(p, k);
        let mut u = SMatrix::<f64, 9, 1>::zeros();
        for a in 0..3 {
            u[3 * a + 2] = d;
        }
        let f = m * u;
        let fz: f64 = (0..3).map(|a| f[3 * a + 2]).sum();
        assert!((fz - k * area * d).abs() < 1e-12 * k * area * d, "{fz}");
        let mut t = SMatrix::<f64, 9, 1>::zeros();
        for a in 0..3 {
            t[3 * a] = 1e-3 * (a as f64 + 1.0);
            t[3 * a + 1] = -2e-3;
        }
        assert!((m * t).norm() < 1e-15 * m.norm());
        // A linear normal displacement: the work u^T K u equals the exact
        // integral k * int (n.u)^2 dA, which the consistent matrix
        // reproduces and a lumped one would not.
        let w = [0.0, 1e-3, 2e-3];
        let mut ul = SMatrix::<f64, 9, 1>::zeros();
        for (a, wa) in w.iter().enumerate() {
            ul[3 * a + 2] = *wa;
        }
        let exact = k * area / 6.0
            * (w.iter().map(|x| x * x).sum::<f64>() + w[0] * w[1] + w[1] * w[2] + w[0] * w[2]);
        let work = (ul.transpose() * m * ul)[0];
        assert!((work - exact).abs() < 1e-12 * exact, "{work} vs {exact}");
    }

    #[test]
    fn a_pressed_block_on_a_foundation_is_two_springs_in_series() {
        // A block of height L and section A on a foundation of stiffness k
        // (bottom face only), nu = 0, its top pressed down by d: uniaxial
        // strain is exact for P1 elements, and the block (E A / L) and the
        // foundation (k A) are two springs in series,
        // F = d / (L / (E A) + 1 / (k A)).
        let (a, l, e, d) = (0.02, 0.03, 3000.0, 1e-3);
        let mesh = cuboid([a, a, l], [3, 3, 4]);
        let area = a * a;
        let material = Material {
            youngs_modulus_pa: e,
            poisson_ratio: 0.0,
        };
        let top: Vec<u32> = (0..mesh.nodes.len() as u32)
            .filter(|&n| (mesh.nodes[n as usize].z - l).abs() < 1e-12)
            .collect();
        let pressed: Vec<Prescribed> = top
            .iter()
            .map(|&node| Prescribed {
                node,
                displacement: Vector3::new(0.0, 0.0, -d),
            })
            .collect();
        assert_eq!(mesh.nodes[0], Point3::origin());
        let along_x = node_at(&mesh, Point3::new(a, 0.0, 0.0));
        for k in [1e4, 1e5, 1e6] {
            let bottom = outer_faces_where(&mesh, |c| c.z < 1e-12);
            for strategy in [Strategy::Direct, Strategy::Compliance] {
                let mut solver = build_solver(
                    strategy,
                    &mesh,
                    material,
                    &[],
                    &options(bottom.clone(), k, along_x),
                )
                .unwrap();
                let sol = solver.solve(&pressed).unwrap();
                let f: f64 = sol.reactions.iter().map(|r| r.z).sum();
                let expected = -d / (l / (e * area) + 1.0 / (k * area));
                assert!(
                    (f - expected).abs() < 1e-9 * expected.abs(),
                    "{strategy:?} k = {k}: {f} N vs {expected} N"
                );
                // The foundation's own displacement: u_b = F / (k A).
                let u_bottom = sol.displacements[0].z;
                assert!((u_bottom - expected / (k * area)).abs() < 1e-9 * d);
            }
        }
    }

    #[test]
    fn a_strip_load_on_a_long_block_decays_away_from_the_load() {
        // A long block (200 mm) on a foundation (its bottom), pressed down
        // by 1 mm over a strip of its top at x = 100 mm: a beam on an elastic
        // foundation, whose deflection decays as exp(-x / l) with
        // l = (4 E I / (k b))^(1/4) (about 10 mm here), so the bottom moves
        // less and less away from the strip and hardly at all near the ends.
        let (len, b, h, e, k, d) = (0.2, 0.02, 0.02, 3000.0, 1e6, 1e-3);
        let mesh = cuboid([len, b, h], [40, 4, 4]);
        let material = Material {
            youngs_modulus_pa: e,
            poisson_ratio: 0.3,
        };
        let x0 = 0.1;
        let pressed: Vec<Prescribed> = (0..mesh.nodes.len() as u32)
            .filter(|&n| {
                let p = mesh.nodes[n as usize];
                (p.z - h).abs() < 1e-12 && (p.x - x0).abs() < 0.006
            })
            .map(|node| Prescribed {
                node,
                displacement: Vector3::new(0.0, 0.0, -d),
            })
            .collect();
        let bottom = outer_faces_where(&mesh, |c| c.z < 1e-12);
        let mut solver = build_solver(
            Strategy::Compliance,
            &mesh,
            material,
            &[],
            &options(bottom, k, node_at(&mesh, Point3::new(len, 0.0, 0.0))),
        )
        .unwrap();
        let sol = solver.solve(&pressed).unwrap();
        // Bottom mid-line nodes, by distance from the strip.
        let mut line: Vec<(f64, f64)> = (0..mesh.nodes.len())
            .filter(|&n| {
                let p = mesh.nodes[n];
                p.z.abs() < 1e-12 && (p.y - b / 2.0).abs() < 1e-12 && p.x >= x0 - 1e-12
            })
            .map(|n| (mesh.nodes[n].x - x0, -sol.displacements[n].z))
            .collect();
        line.sort_by(|p, q| p.0.total_cmp(&q.0));
        let under = line[0].1;
        assert!(under > 0.1 * d, "the bottom under the load moves: {under}");
        for w in line.windows(2).take_while(|w| w[1].0 <= 0.03) {
            assert!(w[1].1 < w[0].1, "decays: {line:?}");
        }
        let end = line.last().unwrap().1.abs();
        assert!(
            end < 0.02 * under,
            "at the end {end} vs {under} under the load"
        );
    }

    /// The block of `a_pressed_block_on_a_foundation_is_two_springs_in_series`
    /// (no fixed node: the foundation on its bottom holds it, the rollers
    /// of [`options`] take the in-plane rigid motions) with its top pressed
    /// down by `d` (m): the solution of `strategy` and the press's total
    /// vertical reaction (N).
    fn press_on_foundation(
        strategy: Strategy,
        nu: f64,
        k: f64,
        d: f64,
    ) -> (Vec<Vector3<f64>>, f64, TetMesh, Vec<[u32; 3]>) {
        let (a, l) = (0.02, 0.03);
        let mesh = cuboid([a, a, l], [2, 2, 3]);
        let material = Material {
            youngs_modulus_pa: 3000.0,
            poisson_ratio: nu,
        };
        let pressed: Vec<Prescribed> = (0..mesh.nodes.len() as u32)
            .filter(|&n| (mesh.nodes[n as usize].z - l).abs() < 1e-12)
            .map(|node| Prescribed {
                node,
                displacement: Vector3::new(0.0, 0.0, -d),
            })
            .collect();
        let bottom = outer_faces_where(&mesh, |c| c.z < 1e-12);
        let along_x = node_at(&mesh, Point3::new(a, 0.0, 0.0));
        let opts = SolverOptions {
            iterative: IterativeOptions::reference(),
            ..options(bottom.clone(), k, along_x)
        };
        let mut solver = build_solver(strategy, &mesh, material, &[], &opts).unwrap();
        let sol = solver.solve(&pressed).unwrap();
        let f = sol.reactions.iter().map(|r| r.z).sum();
        (sol.displacements.clone(), f, mesh, bottom)
    }

    /// Linearization consistency: the nonlinear strategies' foundation is
    /// the linear one's spring energy, so at a small load they meet
    /// `compliance` with the same foundation. At a strain `s` their
    /// displacements differ from the linear ones by `O(s)` relative (the
    /// geometric and material nonlinearity), here 1e-5, plus the solver
    /// tolerance (1e-10): the bound 1e-3 is a hundred times that and far
    /// below the foundation's own share of the displacement (the bottom
    /// moves about a third of the press), so a missing or doubled
    /// foundation fails it.
    #[test]
    fn at_small_load_the_nonlinear_strategies_meet_the_linear_foundation() {
        let (k, d) = (1e5, 3e-7); // strain 1e-5 over the 30 mm block
        let (lin, f_lin, _, _) = press_on_foundation(Strategy::Compliance, 0.3, k, d);
        let scale = lin.iter().fold(0.0f64, |m, u| m.max(u.norm()));
        assert!(lin[0].z < -0.2 * d, "the foundation yields: {}", lin[0].z);
        for strategy in [Strategy::NeoHookean, Strategy::Corotational] {
            let (u, f, _, _) = press_on_foundation(strategy, 0.3, k, d);
            let du = u
                .iter()
                .zip(&lin)
                .fold(0.0f64, |m, (a, b)| m.max((a - b).norm()));
            eprintln!(
                "{strategy:?}: displacement {:.2e}, force {:.2e} relative",
                du / scale,
                (f - f_lin).abs() / f_lin.abs()
            );
            assert!(du < 1e-3 * scale, "{strategy:?}: {du:e} of {scale:e}");
            assert!(
                (f - f_lin).abs() < 1e-3 * f_lin.abs(),
                "{strategy:?}: {f} N vs {f_lin} N"
            );
        }
    }

    /// Equilibrium: on a block held by the foundation alone (its rollers
    /// hold no vertical force), the press's vertical reaction is balanced
    /// by the foundation's, `-k A / 3 sum_j n . u_j` along `n` per bottom
    /// triangle (the consistent matrix's weights sum to `A / 3` a node),
    /// at a 5 % press where the nonlinear answers differ from the linear
    /// one. The tissue's own forces sum to zero, so the balance is that of
    /// the solver's convergence (relative 1e-10 of the reactions).
    #[test]
    fn the_foundation_balances_a_press_in_the_nonlinear_strategies() {
        let (k, d) = (1e5, 1.5e-3);
        let (_, f_lin, _, _) = press_on_foundation(Strategy::Compliance, 0.45, k, d);
        for strategy in [Strategy::NeoHookean, Strategy::Corotational] {
            let (u, f, mesh, bottom) = press_on_foundation(strategy, 0.45, k, d);
            let held: f64 = bottom
                .iter()
                .map(|t| {
                    let (n, area) = normal_area(t.map(|v| mesh.nodes[v as usize]));
                    let un: f64 = t.iter().map(|&v| n.dot(&u[v as usize])).sum();
                    -k * area / 3.0 * un * n.z
                })
                .sum();
            eprintln!(
                "{strategy:?}: press {f:.6e} N, foundation {held:.6e} N, linear {f_lin:.6e} N"
            );
            assert!(f < 0.0 && held > 0.0, "{strategy:?}: {f} N, {held} N");
            assert!(
                (f + held).abs() < 1e-8 * f.abs(),
                "{strategy:?}: press {f} N, foundation {held} N"
            );
            // A nonlinear answer, not the linear one.
            assert!(
                (f - f_lin).abs() > 1e-3 * f_lin.abs(),
                "{strategy:?}: {f} N vs linear {f_lin} N"
            );
        }
    }
}
