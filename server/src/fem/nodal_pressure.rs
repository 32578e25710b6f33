//! The average-nodal-pressure tetrahedron (Bonet and Burton 1998), linear
//! version: a locking-free option for nearly incompressible tissue on the
//! same 4-node mesh. SI units (m, Pa, N).
//!
//! The strain energy of linear elasticity splits into a deviatoric and a
//! volumetric part,
//! `W = mu dev(eps) : dev(eps) + kappa / 2 tr(eps)^2`, with the bulk modulus
//! `kappa = lambda + 2 mu / 3`. The deviatoric part stays on the elements
//! (the element stiffness of [`super::element::TetGeometry::stiffness`] with
//! `lambda = -2 mu / 3`). The volumetric part moves to the nodes: each node
//! `a` owns the volume `V_a = sum_{e ∋ a} V_e / 4` and the averaged
//! volumetric strain
//!
//! `theta_a = (1 / V_a) sum_{e ∋ a} (V_e / 4) tr(eps_e) = sum_b w_ab . u_b`,
//! `w_ab = (1 / V_a) sum_{e ∋ a, b ∈ e} (V_e / 4) g_b^e` (1/m),
//!
//! over the nodes `b` of `a`'s star (the elements around `a`), with `g_b^e`
//! the shape-function gradients. Then `W_vol = sum_a kappa / 2 V_a theta_a^2`
//! and its Hessian is a rank-one matrix per node,
//! `K_vol = sum_a kappa V_a w_a w_a^T`, coupling the nodes of a star (the
//! stiffness pattern widens from the elements' one ring to two rings).
//!
//! Why it does not lock: P1 tetrahedra impose one volumetric constraint per
//! element, about 5 to 6 per node on a tetrahedral mesh, against 3 DOFs per
//! node, so as `nu -> 0.5` the constraints freeze the mesh. Averaging over
//! the nodes leaves one constraint per node. A uniform strain gives
//! `theta_a = tr(eps)` at every node, so the patch test holds and a uniform
//! press still gives `E A d / L`.
//!
//! Written here, not taken from a crate: no Rust FEM crate offers the
//! element on a caller's assembly, and the operator is a few lines over the
//! rest geometry the model already holds.

use super::assembly::Pattern;
use super::constraint::Frame;
use super::element::TetGeometry;
use nalgebra::Vector3;

/// The volumetric part of the average-nodal-pressure tetrahedron: per node
/// its star, the weights `w_ab` and the nodal volume `V_a`.
#[derive(Debug, Clone, PartialEq)]
pub struct NodalPressure {
    /// Bulk modulus per node, Pa: `kappa_a = (1 / V_a) sum_{e ∋ a}
    /// (V_e / 4) kappa_e`, the volume-weighted mean of its elements'
    /// `kappa_e = lambda_e + 2 mu_e / 3` (one value on a mesh of one
    /// material).
    pub bulk_modulus_pa: Vec<f64>,
    /// Per node, the range of its star in `nodes` / `weights`.
    start: Vec<usize>,
    /// Star nodes, sorted within each star.
    nodes: Vec<u32>,
    /// `w_ab`, 1/m, beside `nodes`.
    weights: Vec<Vector3<f64>>,
    /// `V_a`, m^3 (0 for a node in no element).
    volume_m3: Vec<f64>,
}

impl NodalPressure {
    /// The operator of a mesh of `n_nodes` nodes, tetrahedra `tets` with rest
    /// geometry `geoms` (indices already validated), bulk modulus `kappa`
    /// per element, Pa.
    pub fn new(n_nodes: usize, tets: &[[u32; 4]], geoms: &[TetGeometry], kappa: &[f64]) -> Self {
        // Elements around each node (compressed rows).
        let mut count = vec![0usize; n_nodes + 1];
        for t in tets {
            for &a in t {
                count[a as usize + 1] += 1;
            }
        }
        for i in 0..n_nodes {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        let mut around = vec![0u32; count[n_nodes]];
        for (e, t) in tets.iter().enumerate() {
            for &a in t {
                around[fill[a as usize]] = e as u32;
                fill[a as usize] += 1;
            }
        }
        let mut start = Vec::with_capacity(n_nodes + 1);
        let mut nodes = Vec::new();
        let mut weights = Vec::new();
        let mut volume_m3 = vec![0.0; n_nodes];
        let mut bulk_modulus_pa = vec![0.0; n_nodes];
        let mut scratch: Vec<(u32, Vector3<f64>)> = Vec::new();
        start.push(0);
        for a in 0..n_nodes {
            scratch.clear();
            let (mut va, mut ka) = (0.0, 0.0);
            for &e in &around[count[a]..count[a + 1]] {
                let (t, g) = (&tets[e as usize], &geoms[e as usize]);
                let quarter = g.volume / 4.0;
                va += quarter;
                ka += quarter * kappa[e as usize];
                for k in 0..4 {
                    scratch.push((t[k], quarter * g.grads[k]));
                }
            }
            scratch.sort_unstable_by_key(|&(b, _)| b);
            if va > 0.0 {
                let mut i = 0;
                while i < scratch.len() {
                    let b = scratch[i].0;
                    let mut w = Vector3::zeros();
                    while i < scratch.len() && scratch[i].0 == b {
                        w += scratch[i].1;
                        i += 1;
                    }
                    nodes.push(b);
                    weights.push(w / va);
                }
            }
            volume_m3[a] = va;
            if va > 0.0 {
                bulk_modulus_pa[a] = ka / va;
            }
            start.push(nodes.len());
        }
        Self {
            bulk_modulus_pa,
            start,
            nodes,
            weights,
            volume_m3,
        }
    }

    /// Number of nodes.
    pub fn n_nodes(&self) -> usize {
        self.volume_m3.len()
    }

    /// The star of node `a`: its nodes (sorted) and weights `w_ab` (1/m).
    pub fn star(&self, a: usize) -> (&[u32], &[Vector3<f64>]) {
        let r = self.start[a]..self.start[a + 1];
        (&self.nodes[r.clone()], &self.weights[r])
    }

    /// Every node's star (node lists), for the stiffness pattern.
    pub fn stars(&self) -> impl Iterator<Item = &[u32]> + '_ {
        (0..self.n_nodes()).map(|a| self.star(a).0)
    }

    /// Nodal volume `V_a`, m^3.
    pub fn volume_m3(&self, a: usize) -> f64 {
        self.volume_m3[a]
    }

    /// Averaged volumetric strain `theta_a` (dimensionless) under the
    /// displacements `u` (m, one vector a node).
    pub fn volumetric_strain(&self, a: usize, u: &[Vector3<f64>]) -> f64 {
        let (nodes, w) = self.star(a);
        nodes
            .iter()
            .zip(w)
            .map(|(&b, w)| w.dot(&u[b as usize]))
            .sum()
    }

    /// Volumetric strain energy `sum_a kappa / 2 V_a theta_a^2`, J.
    pub fn energy(&self, u: &[Vector3<f64>]) -> f64 {
        (0..self.n_nodes())
            .map(|a| {
                let th = self.volumetric_strain(a, u);
                0.5 * self.bulk_modulus_pa[a] * self.volume_m3[a] * th * th
            })
            .sum()
    }

    /// Calls `f(b, force)` with the forces `K_vol u` (N) of the stars of the
    /// nodes `owners` only (each star's contribution to its nodes).
    pub fn for_each_force(
        &self,
        owners: impl IntoIterator<Item = u32>,
        u: &[Vector3<f64>],
        mut f: impl FnMut(u32, Vector3<f64>),
    ) {
        for a in owners {
            let a = a as usize;
            let s = self.bulk_modulus_pa[a] * self.volume_m3[a] * self.volumetric_strain(a, u);
            let (nodes, w) = self.star(a);
            for (&b, w) in nodes.iter().zip(w) {
                f(b, s * w);
            }
        }
    }

    /// `y += K_vol x` for DOF vectors (`3 n + i`).
    pub fn add_matvec(&self, x: &[f64], y: &mut [f64]) {
        for a in 0..self.n_nodes() {
            let (nodes, w) = self.star(a);
            let th: f64 = nodes
                .iter()
                .zip(w)
                .map(|(&b, w)| w.dot(&super::assembly::node_vec(x, b as usize)))
                .sum();
            let s = self.bulk_modulus_pa[a] * self.volume_m3[a] * th;
            for (&b, w) in nodes.iter().zip(w) {
                let n = 3 * b as usize;
                for i in 0..3 {
                    y[n + i] += s * w[i];
                }
            }
        }
    }

    /// Scatters `K_vol` into an eliminated system as
    /// [`Frame::scatter`] does an element: entries between free DOFs (and
    /// the diagonal of constrained ones) into `values` (lower triangle of
    /// `pattern`, which must hold the stars), the coupling to constrained
    /// DOFs as `-K_fc g_c` into `rhs` (`lift` in node bases). Weights are
    /// rotated into the frame's node bases. `scratch` is a workspace.
    pub fn scatter(
        &self,
        frame: &Frame,
        pattern: &Pattern,
        lift: &[f64],
        values: &mut [f64],
        rhs: &mut [f64],
        scratch: &mut Vec<Vector3<f64>>,
    ) {
        for a in 0..self.n_nodes() {
            let (nodes, w) = self.star(a);
            let c = self.bulk_modulus_pa[a] * self.volume_m3[a];
            scratch.clear();
            scratch.extend(nodes.iter().zip(w).map(|(&b, w)| {
                if frame.rotated[b as usize] {
                    frame.basis[b as usize].transpose() * w
                } else {
                    *w
                }
            }));
            // Local DOF p = 3 k + i of star node k; sorted nodes make the
            // local order the global order, so p <= q is the lower triangle.
            let m = 3 * nodes.len();
            let dof = |p: usize| 3 * nodes[p / 3] as usize + p % 3;
            for q in 0..m {
                let gq = dof(q);
                let wq = scratch[q / 3][q % 3];
                if wq == 0.0 {
                    continue;
                }
                for p in q..m {
                    let gp = dof(p);
                    let v = c * scratch[p / 3][p % 3] * wq;
                    let (cp, cq) = (frame.fixed[gp], frame.fixed[gq]);
                    if !cp && !cq || p == q {
                        values[pattern.index(gp, gq)] += v;
                    } else if !cp && cq {
                        rhs[gp] -= v * lift[gq];
                    } else if cp && !cq {
                        rhs[gq] -= v * lift[gp];
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::blocks::cube;

    fn operator(n: usize) -> (crate::mesh::TetMesh, NodalPressure) {
        let mesh = cube(0.01, n);
        let geoms: Vec<_> = mesh
            .tets
            .iter()
            .map(|t| TetGeometry::new(t.map(|i| mesh.nodes[i as usize])).unwrap())
            .collect();
        let p = NodalPressure::new(
            mesh.nodes.len(),
            &mesh.tets,
            &geoms,
            &vec![2e5; mesh.tets.len()],
        );
        (mesh, p)
    }

    #[test]
    fn a_uniform_strain_gives_its_trace_at_every_node() {
        let (mesh, p) = operator(3);
        let grad = nalgebra::Matrix3::new(1e-3, 2e-4, 0.0, -1e-4, -3e-3, 5e-4, 0.0, 7e-4, 4e-3);
        let u: Vec<_> = mesh.nodes.iter().map(|x| grad * x.coords).collect();
        for a in 0..mesh.nodes.len() {
            let th = p.volumetric_strain(a, &u);
            assert!((th - grad.trace()).abs() < 1e-15, "node {a}: {th}");
        }
    }

    #[test]
    fn nodal_volumes_sum_to_the_mesh_volume() {
        let (mesh, p) = operator(2);
        let v: f64 = (0..mesh.nodes.len()).map(|a| p.volume_m3(a)).sum();
        assert!((v - 1e-6).abs() < 1e-18, "{v}");
    }

    #[test]
    fn the_matvec_is_the_gradient_of_the_energy() {
        let (mesh, p) = operator(2);
        let n = mesh.nodes.len();
        let u: Vec<Vector3<f64>> = (0..n)
            .map(|i| Vector3::new((i % 5) as f64, (i % 3) as f64 - 1.0, (i % 7) as f64) * 1e-5)
            .collect();
        let x: Vec<f64> = u.iter().flat_map(|v| v.iter().copied()).collect();
        let mut y = vec![0.0; 3 * n];
        p.add_matvec(&x, &mut y);
        // Energy is quadratic: u . K u = 2 W.
        let uku: f64 = x.iter().zip(&y).map(|(a, b)| a * b).sum();
        assert!((uku - 2.0 * p.energy(&u)).abs() < 1e-12 * uku.abs());
        // Forces of every star summed equal the matvec.
        let mut z = vec![Vector3::zeros(); n];
        p.for_each_force(0..n as u32, &u, |b, f| z[b as usize] += f);
        for b in 0..n {
            let yb = super::super::assembly::node_vec(&y, b);
            assert!((z[b] - yb).norm() <= 1e-12 * yb.norm().max(1e-30));
        }
    }
}
