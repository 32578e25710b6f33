//! The average-nodal-pressure tetrahedron (Bonet and Burton 1998): a
//! locking-free option for nearly incompressible tissue on the same 4-node
//! mesh, in a linear version ([`NodalPressure`], the linear strategies) and
//! a neo-Hookean one ([`NodalVolumes`], `neo-hookean`). SI units (m, Pa, N).
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
//! The nonlinear version replaces `theta_a` by the logarithm of the nodal
//! volume ratio, `ln J_a` (its energy, gradient and tangent are stated at
//! [`NodalVolumes`]); it linearizes to the linear version.
//!
//! Written here, not taken from a crate: no Rust FEM crate offers the
//! element on a caller's assembly, and the operator is a few lines over the
//! rest geometry the model already holds.

// Negated comparisons are deliberate: NaN must fail the positivity checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::assembly::{Pattern, node_vec};
use super::constraint::Frame;
use super::element::{ElementMatrix, TetGeometry, cofactor_det, det_minus_one};
use nalgebra::{Matrix3, Vector3};

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
    /// Per node, the range of the elements around it in `around` / `slots`.
    around_start: Vec<usize>,
    /// The elements around each node.
    around: Vec<u32>,
    /// Beside `around`: the position of each of the element's corners in the
    /// node's star (an index into `nodes` / `weights`), so that the current
    /// weights of the nonlinear part ([`NodalVolumes`]) need no search.
    slots: Vec<[u32; 4]>,
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
        let mut slots = Vec::with_capacity(around.len());
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
            let star = &nodes[start[a]..];
            for &e in &around[count[a]..count[a + 1]] {
                slots.push(tets[e as usize].map(|b| {
                    (start[a] + star.binary_search(&b).expect("a corner is in the star")) as u32
                }));
            }
            start.push(nodes.len());
        }
        Self {
            bulk_modulus_pa,
            start,
            nodes,
            weights,
            volume_m3,
            around_start: count,
            around,
            slots,
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
    pub fn stars(&self) -> impl Iterator<Item = &[u32]> + Clone + '_ {
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
        let out = Eliminated {
            frame,
            pattern,
            lift,
            values,
            rhs,
        };
        self.scatter_into(out, scratch);
    }

    /// [`Self::scatter`] into `out`.
    pub fn scatter_into(&self, out: Eliminated<'_>, scratch: &mut Vec<Vector3<f64>>) {
        self.scatter_rank_one(
            out,
            &self.weights,
            |a| self.bulk_modulus_pa[a] * self.volume_m3[a],
            scratch,
        );
    }

    /// Scatters `sum_a c_a w_a w_a^T` (N/m) as [`Self::scatter`] does
    /// `K_vol`, for per-node coefficients `c_a = coef(a)` (J) and weights
    /// `weights` (1/m, beside the stars' nodes, as [`Self::star`] gives
    /// them): `K_vol` is `c_a = kappa_a V_a` with the rest weights.
    fn scatter_rank_one(
        &self,
        out: Eliminated<'_>,
        weights: &[Vector3<f64>],
        coef: impl Fn(usize) -> f64,
        scratch: &mut Vec<Vector3<f64>>,
    ) {
        let Eliminated {
            frame,
            pattern,
            lift,
            values,
            rhs,
        } = out;
        for a in 0..self.n_nodes() {
            let r = self.start[a]..self.start[a + 1];
            let (nodes, w) = (&self.nodes[r.clone()], &weights[r]);
            let c = coef(a);
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
            // Column q = 3 k + ci, rows p >= q: node k's own rows from the
            // diagonal, each later node l's three from the pattern's map of
            // the star's pairs (the star is group `a` of the pattern).
            let pairs = pattern.group_pairs(a);
            let s = nodes.len();
            let mut first = 0;
            for k in 0..s {
                let nk = nodes[k] as usize;
                let row_pairs = &pairs[first..first + (s - k - 1)];
                first += s - k - 1;
                for ci in 0..3 {
                    let gq = 3 * nk + ci;
                    let wq = scratch[k][ci];
                    if wq == 0.0 {
                        continue;
                    }
                    let cq = frame.fixed[gq];
                    let mut put = |gp: usize, index: usize, diagonal: bool, v: f64| {
                        let cp = frame.fixed[gp];
                        if !cp && !cq || diagonal {
                            values[index] += v;
                        } else if !cp && cq {
                            rhs[gp] -= v * lift[gq];
                        } else if cp && !cq {
                            rhs[gq] -= v * lift[gp];
                        }
                    };
                    let diag = pattern.diag[gq];
                    for rj in ci..3 {
                        put(
                            3 * nk + rj,
                            diag + rj - ci,
                            rj == ci,
                            c * scratch[k][rj] * wq,
                        );
                    }
                    let offset = pattern.group_column_offset(nk, ci);
                    for (l, &s0) in (k + 1..s).zip(row_pairs) {
                        let gl = 3 * nodes[l] as usize;
                        let base = s0 as usize + offset;
                        for rj in 0..3 {
                            put(gl + rj, base + rj, false, c * scratch[l][rj] * wq);
                        }
                    }
                }
            }
        }
    }
}

/// The eliminated system a scatter adds into ([`Frame::scatter`]): the
/// frame, the pattern, the lift (node bases), the matrix values (lower
/// triangle) and the right-hand side.
pub struct Eliminated<'a> {
    /// The step's frame (node bases, constrained DOFs).
    pub frame: &'a Frame,
    /// The stiffness pattern (holding the stars).
    pub pattern: &'a Pattern,
    /// The remaining gap to the enforced values, node bases, m.
    pub lift: &'a [f64],
    /// Values of the lower triangle of `pattern`, N/m.
    pub values: &'a mut [f64],
    /// Right-hand side, N.
    pub rhs: &'a mut [f64],
}

/// The nonlinear volumetric part of the average-nodal-pressure element, for
/// the compressible neo-Hookean model (`neo-hookean` with
/// `tet4-nodal-pressure`), and the workspace that evaluates it.
///
/// **Energy.** The neo-Hookean density
/// `psi = mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2` splits as the linear
/// one does: each element keeps `psi` with `lambda` replaced by
/// `lambda_dev = -2 mu / 3` (which linearizes to `mu dev(eps) : dev(eps)`
/// exactly), and the volumetric part moves to the nodes,
///
/// `U = sum_a U_a`, `U_a = V_a kappa_a / 2 (ln J_a)^2`, `J_a = v_a / V_a`,
///
/// with `v_a = sum_{e ∋ a} v_e / 4` the current (deformed) nodal volume,
/// `v_e = J_e V_e`, `V_a` the rest one and `kappa_a` the nodal bulk
/// modulus of [`NodalPressure`]. At small strain `ln J_a = theta_a +
/// O(eps^2)`, so `U` linearizes to the linear element's
/// `kappa_a / 2 V_a theta_a^2` and the two elements agree at small load.
///
/// **Gradient.** `dU/dx = sum_a U_a' grad v_a`, `U_a' = dU_a / dv_a =
/// kappa_a ln J_a / J_a` (Pa), and `grad_{x_b} v_e = V_e cof(F_e) g_b`
/// (m^2, the cofactor `cof F = J F^-T`). Summed per element this is
/// `f_b^e = p_e V_e cof(F_e) g_b`, `p_e` the mean of `U_a'` over the
/// element's corners: a pressure force per element.
///
/// **Tangent.** `sum_a [U_a'' grad v_a grad v_a^T + U_a' hess v_a]`: the
/// first term a rank-one matrix per node over its star, `c_a w_a w_a^T`
/// with the current weights `w_ab = grad_{x_b} v_a / V_a` (1/m, the rest
/// ones of [`NodalPressure`] at rest) and `c_a = V_a^2 U_a'' = V_a kappa_a
/// (1 - ln J_a) / J_a^2` (J, `kappa_a V_a` at rest); the second per
/// element, `p_e hess v_e`, with the Hessian of a tetrahedron's volume
/// `d^2 v_e / dx_a dx_b = -V_e [F_e (g_a x g_b)]_x` (skew 3 x 3 blocks,
/// `[c]_x` the cross-product matrix; zero at rest only through `p_e = 0`).
///
/// **Precision.** `J_a - 1 = sum_{e ∋ a} (V_e / 4) (J_e - 1) / V_a` from the
/// cancellation-free `J_e - 1` ([`super::element::det_minus_one`]), and
/// `ln J_a = ln_1p(J_a - 1)`: the nodal energy and force keep full relative
/// precision at light load, as the element's do.
///
/// An element with `J_e <= 0` or a node with `J_a <= 0` is inverted.
#[derive(Debug, Clone, Default)]
pub struct NodalVolumes {
    /// Per element, `J_e - 1`.
    jm1_element: Vec<f64>,
    /// Per element, `grad_{x_b} v_e = V_e cof(F_e) g_b` for its corners, m^2.
    grad_element: Vec<[Vector3<f64>; 4]>,
    /// Per element, `F_e = I + H_e`.
    f_element: Vec<Matrix3<f64>>,
    /// Per node, `J_a - 1`.
    jm1: Vec<f64>,
    /// Per node, `U_a' = kappa_a ln J_a / J_a`, Pa.
    slope: Vec<f64>,
    /// Per node, `c_a = V_a^2 U_a''`, J.
    curvature: Vec<f64>,
    /// The current weights `w_ab`, 1/m, beside the stars' nodes.
    weights: Vec<Vector3<f64>>,
}

/// Where the nonlinear volumetric part failed: an element or a node
/// inverted, with its `J`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Inversion {
    /// Element `e` has `J_e <= 0`.
    Element(usize, f64),
    /// Node `a` has `J_a <= 0`.
    Node(usize, f64),
}

impl From<Inversion> for super::SolveError {
    fn from(i: Inversion) -> Self {
        match i {
            Inversion::Element(element, jacobian) => Self::Inverted { element, jacobian },
            Inversion::Node(node, jacobian) => Self::InvertedNode { node, jacobian },
        }
    }
}

impl NodalVolumes {
    /// A workspace for `p` on `n_elements` elements.
    pub fn new(p: &NodalPressure, n_elements: usize) -> Self {
        let n = p.n_nodes();
        Self {
            jm1_element: vec![0.0; n_elements],
            grad_element: vec![[Vector3::zeros(); 4]; n_elements],
            f_element: vec![Matrix3::identity(); n_elements],
            jm1: vec![0.0; n],
            slope: vec![0.0; n],
            curvature: vec![0.0; n],
            weights: vec![Vector3::zeros(); p.weights.len()],
        }
    }

    /// Evaluates the nodal part of `p` on the elements `tets` (rest
    /// geometry `geoms`) at displacement `u` (DOF vector, m): every
    /// element's and node's `J`, the nodal slopes and curvatures and the
    /// current weights. Fails on the first inverted element, then on the
    /// first inverted node.
    pub fn evaluate(
        &mut self,
        p: &NodalPressure,
        tets: &[[u32; 4]],
        geoms: &[TetGeometry],
        u: &[f64],
    ) -> Result<(), Inversion> {
        for (e, (t, g)) in tets.iter().zip(geoms).enumerate() {
            let h = g.displacement_gradient(&t.map(|n| node_vec(u, n as usize)));
            let jm1 = det_minus_one(&h);
            if !(jm1 > -1.0) {
                return Err(Inversion::Element(e, 1.0 + jm1));
            }
            let f = Matrix3::identity() + h;
            let (cof, _) = cofactor_det(&f);
            self.jm1_element[e] = jm1;
            self.f_element[e] = f;
            self.grad_element[e] = g.grads.map(|gb| g.volume * (cof * gb));
        }
        for a in 0..p.n_nodes() {
            let va = p.volume_m3[a];
            let r = p.around_start[a]..p.around_start[a + 1];
            let w = &mut self.weights[p.start[a]..p.start[a + 1]];
            w.fill(Vector3::zeros());
            if !(va > 0.0) {
                self.jm1[a] = 0.0;
                self.slope[a] = 0.0;
                self.curvature[a] = 0.0;
                continue;
            }
            let mut jm1 = 0.0;
            for (&e, slots) in p.around[r.clone()].iter().zip(&p.slots[r]) {
                let e = e as usize;
                let quarter = geoms[e].volume / 4.0;
                jm1 += quarter * self.jm1_element[e];
                for (k, &s) in slots.iter().enumerate() {
                    w[s as usize - p.start[a]] += self.grad_element[e][k] * (0.25 / va);
                }
            }
            let jm1 = jm1 / va;
            if !(jm1 > -1.0) {
                return Err(Inversion::Node(a, 1.0 + jm1));
            }
            let (j, lj, kappa) = (1.0 + jm1, jm1.ln_1p(), p.bulk_modulus_pa[a]);
            self.jm1[a] = jm1;
            self.slope[a] = kappa * lj / j;
            self.curvature[a] = va * kappa * (1.0 - lj) / (j * j);
        }
        Ok(())
    }

    /// The nodal energy `sum_a V_a kappa_a / 2 (ln J_a)^2` (J, >= 0: its
    /// own rounding magnitude) at the last [`Self::evaluate`].
    pub fn energy(&self, p: &NodalPressure) -> f64 {
        (0..p.n_nodes())
            .map(|a| {
                let lj = self.jm1[a].ln_1p();
                0.5 * p.volume_m3[a] * p.bulk_modulus_pa[a] * lj * lj
            })
            .sum()
    }

    /// The mean nodal slope `p_e` (Pa) over the corners `t` of an element.
    pub fn element_pressure(&self, t: &[u32; 4]) -> f64 {
        0.25 * t.iter().map(|&a| self.slope[a as usize]).sum::<f64>()
    }

    /// The nodal part's force on element `e`'s corners `t`: `p_e grad v_e`
    /// (N, each corner's), at the last [`Self::evaluate`].
    pub fn element_forces(&self, e: usize, t: &[u32; 4]) -> [Vector3<f64>; 4] {
        let pe = self.element_pressure(t);
        self.grad_element[e].map(|g| pe * g)
    }

    /// Adds the nodal part's internal force (N) on every node to `f` (DOF
    /// vector), at the last [`Self::evaluate`].
    pub fn add_forces(&self, tets: &[[u32; 4]], f: &mut [f64]) {
        for (e, t) in tets.iter().enumerate() {
            let fe = self.element_forces(e, t);
            for (a, &n) in t.iter().enumerate() {
                for i in 0..3 {
                    f[3 * n as usize + i] += fe[a][i];
                }
            }
        }
    }

    /// Adds the element part of the tangent, `p_e hess v_e` (N/m), to the
    /// element matrix `k` of element `e` on corners `t` (its local DOF
    /// order, global basis), at the last [`Self::evaluate`].
    pub fn add_element_tangent(
        &self,
        e: usize,
        t: &[u32; 4],
        geom: &TetGeometry,
        k: &mut ElementMatrix,
    ) {
        let pe = self.element_pressure(t);
        if pe == 0.0 {
            return;
        }
        let (f, s) = (&self.f_element[e], pe * geom.volume);
        for a in 0..4 {
            for b in 0..4 {
                if a == b {
                    continue;
                }
                let c = s * (f * geom.grads[a].cross(&geom.grads[b]));
                // -[c]_x.
                let block = Matrix3::new(0.0, c.z, -c.y, -c.z, 0.0, c.x, c.y, -c.x, 0.0);
                let mut dst = k.fixed_view_mut::<3, 3>(3 * a, 3 * b);
                dst += block;
            }
        }
    }

    /// Scatters the rank-one part `sum_a c_a w_a w_a^T` (N/m) into an
    /// eliminated system as [`NodalPressure::scatter`] does `K_vol`, at the
    /// last [`Self::evaluate`].
    pub fn scatter(&self, p: &NodalPressure, out: Eliminated<'_>, scratch: &mut Vec<Vector3<f64>>) {
        p.scatter_rank_one(out, &self.weights, |a| self.curvature[a], scratch);
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

    /// The rank-one scatter as first written: each entry's value index by a
    /// binary search of its column ([`Pattern::index`]), the loop order of
    /// [`NodalPressure::scatter_rank_one`].
    fn scatter_by_search(
        p: &NodalPressure,
        out: Eliminated<'_>,
        weights: &[Vector3<f64>],
        coef: impl Fn(usize) -> f64,
    ) {
        let Eliminated {
            frame,
            pattern,
            lift,
            values,
            rhs,
        } = out;
        for a in 0..p.n_nodes() {
            let r = p.start[a]..p.start[a + 1];
            let nodes = &p.nodes[r.clone()];
            let w: Vec<Vector3<f64>> = nodes
                .iter()
                .zip(&weights[r])
                .map(|(&b, w)| {
                    if frame.rotated[b as usize] {
                        frame.basis[b as usize].transpose() * w
                    } else {
                        *w
                    }
                })
                .collect();
            let c = coef(a);
            let m = 3 * nodes.len();
            let dof = |p: usize| 3 * nodes[p / 3] as usize + p % 3;
            for q in 0..m {
                let (gq, wq) = (dof(q), w[q / 3][q % 3]);
                if wq == 0.0 {
                    continue;
                }
                for pp in q..m {
                    let gp = dof(pp);
                    let v = c * w[pp / 3][pp % 3] * wq;
                    let (cp, cq) = (frame.fixed[gp], frame.fixed[gq]);
                    if !cp && !cq || pp == q {
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

    /// The scatter through the pattern's map of the stars' node pairs adds
    /// the same numbers in the same order as the binary search of each
    /// entry: values and right-hand side equal bit for bit, on a pattern
    /// with the stars alone and one with a tie pair beside them, under a
    /// frame with fixed supports, constrained DOFs and rotated node bases.
    #[test]
    fn the_mapped_scatter_equals_the_searched_one_bit_for_bit() {
        let (mesh, p) = operator(3);
        let n = mesh.nodes.len();
        let mut r = crate::test_rng::unit(29);
        let mut frame = Frame::new((0..3 * n).map(|d| d < 6).collect());
        for node in (0..n).step_by(5) {
            frame.fixed[3 * node + node % 3] = true;
            if node % 2 == 0 {
                frame.rotated[node] = true;
                frame.basis[node] =
                    nalgebra::Rotation3::from_euler_angles(r(), r() - 0.5, 2.0 * r()).into_inner();
            }
        }
        let lift: Vec<f64> = (0..3 * n).map(|_| (r() - 0.5) * 1e-4).collect();
        let weights: Vec<Vector3<f64>> = p.weights.iter().map(|w| w * (1.0 + 0.1 * r())).collect();
        let coef: Vec<f64> = (0..n).map(|_| 1.0 + r()).collect();
        let last = n as u32 - 1;
        for pattern in [
            Pattern::with_groups(n, &mesh.tets, p.stars()),
            Pattern::with_groups_and_pairs(n, &mesh.tets, p.stars(), &[[last, 0]]),
        ] {
            let mut got = (vec![0.0; pattern.nnz()], vec![0.0; 3 * n]);
            let mut want = got.clone();
            fn out<'a>(
                frame: &'a Frame,
                pattern: &'a Pattern,
                lift: &'a [f64],
                v: &'a mut (Vec<f64>, Vec<f64>),
            ) -> Eliminated<'a> {
                Eliminated {
                    frame,
                    pattern,
                    lift,
                    values: &mut v.0,
                    rhs: &mut v.1,
                }
            }
            // Twice, so that the second pass adds into non-zero sums.
            for _ in 0..2 {
                let (f, pt, l) = (&frame, &pattern, &lift[..]);
                p.scatter_rank_one(
                    out(f, pt, l, &mut got),
                    &weights,
                    |a| coef[a],
                    &mut Vec::new(),
                );
                scatter_by_search(&p, out(f, pt, l, &mut want), &weights, |a| coef[a]);
            }
            assert!(got.0.iter().any(|v| *v != 0.0));
            assert!(got.1.iter().any(|v| *v != 0.0));
            for (a, b) in got.0.iter().zip(&want.0).chain(got.1.iter().zip(&want.1)) {
                assert_eq!(a.to_bits(), b.to_bits(), "{a:e} vs {b:e}");
            }
        }
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
