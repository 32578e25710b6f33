//! Constraints of one deformation step and their validation.
//!
//! A [`Constraint`] enforces, on one node, either the full displacement vector
//! (the paper's enforced displacement), only its component along a unit normal
//! (tissue sliding along the spatula), or one Cartesian component (a roller).
//! Each constraint becomes one to three *rows* `d . u_node = g` with unit,
//! mutually orthogonal directions `d` per node. The reaction of a constraint is
//! `sum_rows lambda d` where `lambda` is the row's multiplier (N), the force the
//! constraint applies to the tissue along `d`.

use super::{Prescribed, SolveError};
use nalgebra::{Matrix3, Vector3};

/// What a [`Constraint`] enforces on its node (displacements in m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ConstraintKind {
    /// The full displacement vector.
    Full(Vector3<f64>),
    /// Only `normal . u = displacement` (unit `normal`); the node slides freely
    /// in the tangent plane.
    Normal {
        normal: Vector3<f64>,
        displacement: f64,
    },
    /// Only `u[axis] = displacement` (axis 0, 1, 2 = x, y, z): a roller.
    Axis { axis: u8, displacement: f64 },
}

/// A constraint of one deformation step on one node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Constraint {
    /// Volume node index.
    pub node: u32,
    /// What is enforced.
    pub kind: ConstraintKind,
}

impl From<Prescribed> for Constraint {
    fn from(p: Prescribed) -> Self {
        Self {
            node: p.node,
            kind: ConstraintKind::Full(p.displacement),
        }
    }
}

impl From<&Prescribed> for Constraint {
    fn from(p: &Prescribed) -> Self {
        (*p).into()
    }
}

/// One scalar constraint row `dir . u_node = value`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Row {
    /// Volume node.
    pub node: u32,
    /// Unit direction.
    pub dir: Vector3<f64>,
    /// Enforced value, m.
    pub value: f64,
    /// Index of the constraint it comes from.
    pub constraint: u32,
}

/// The rows of one step, grouped by node, with the distinct nodes.
#[derive(Debug, Clone, Default)]
pub struct StepRows {
    /// Rows sorted by node slot (rows of one node are contiguous).
    pub rows: Vec<Row>,
    /// Distinct constrained nodes in order of first appearance.
    pub nodes: Vec<u32>,
    /// Per node of `nodes`, the range of its rows: `rows[start[k]..start[k+1]]`.
    pub start: Vec<usize>,
    /// Per volume node, its index in `nodes` or `u32::MAX`.
    pub slot: Vec<u32>,
    n_constraints: usize,
    sorted: Vec<Row>,
    cursor: Vec<usize>,
}

const NONE: u32 = u32::MAX;

impl StepRows {
    /// Empty rows for a mesh of `n_nodes` nodes.
    pub fn new(n_nodes: usize) -> Self {
        Self {
            slot: vec![NONE; n_nodes],
            ..Default::default()
        }
    }

    /// Number of constraints given to the last [`StepRows::set`].
    pub fn n_constraints(&self) -> usize {
        self.n_constraints
    }

    /// Validates `cons` against the mesh size and the fixed DOFs (`support`,
    /// per DOF) and fills the rows. Allocates only when the step is larger
    /// than any before.
    pub fn set<C: Into<Constraint> + Copy>(
        &mut self,
        cons: &[C],
        support: &[bool],
    ) -> Result<(), SolveError> {
        for &n in &self.nodes {
            self.slot[n as usize] = NONE;
        }
        self.nodes.clear();
        self.rows.clear();
        self.start.clear();
        self.n_constraints = cons.len();
        let n_nodes = self.slot.len();
        let bad = |node: u32, reason: &str| SolveError::BadConstraint {
            node,
            reason: reason.into(),
        };
        for (ci, c) in cons.iter().enumerate() {
            let c: Constraint = (*c).into();
            let node = c.node;
            if node as usize >= n_nodes {
                return Err(bad(
                    node,
                    &format!("out of range (the mesh has {n_nodes} nodes)"),
                ));
            }
            let mut push = |dir: Vector3<f64>, value: f64, axis_dof: Option<usize>| {
                if !value.is_finite() || !dir.iter().all(|v| v.is_finite()) {
                    return Err(SolveError::NonFinite(format!(
                        "constraint {ci} on node {node}"
                    )));
                }
                let base = 3 * node as usize;
                let clash = match axis_dof {
                    Some(a) => support[base + a],
                    None => support[base] || support[base + 1] || support[base + 2],
                };
                if clash {
                    return Err(bad(node, "the node is a fixed support"));
                }
                self.rows.push(Row {
                    node,
                    dir,
                    value,
                    constraint: ci as u32,
                });
                Ok(())
            };
            match c.kind {
                ConstraintKind::Full(v) => {
                    for a in 0..3 {
                        push(Vector3::ith(a, 1.0), v[a], Some(a))?;
                    }
                }
                ConstraintKind::Axis { axis, displacement } => {
                    if axis > 2 {
                        return Err(bad(node, &format!("axis {axis} is not 0, 1 or 2")));
                    }
                    push(
                        Vector3::ith(axis as usize, 1.0),
                        displacement,
                        Some(axis as usize),
                    )?;
                }
                ConstraintKind::Normal {
                    normal,
                    displacement,
                } => {
                    let len = normal.norm();
                    if !len.is_finite() {
                        return Err(SolveError::NonFinite(format!("normal of constraint {ci}")));
                    }
                    if (len - 1.0).abs() > 1e-6 {
                        return Err(bad(node, &format!("normal has length {len}, not 1")));
                    }
                    push(normal / len, displacement, None)?;
                }
            }
        }
        // Group by node (stable: keeps the order of rows within a node).
        for r in &self.rows {
            if self.slot[r.node as usize] == NONE {
                self.slot[r.node as usize] = self.nodes.len() as u32;
                self.nodes.push(r.node);
            }
        }
        // Counting sort by slot (stable, no allocation once warm).
        self.start.resize(self.nodes.len() + 1, 0);
        for r in &self.rows {
            self.start[self.slot[r.node as usize] as usize + 1] += 1;
        }
        for s in 0..self.nodes.len() {
            self.start[s + 1] += self.start[s];
        }
        self.sorted.clear();
        self.sorted.extend_from_slice(&self.rows);
        self.cursor.clear();
        self.cursor
            .extend_from_slice(&self.start[..self.nodes.len()]);
        for r in &self.sorted {
            let s = self.slot[r.node as usize] as usize;
            self.rows[self.cursor[s]] = *r;
            self.cursor[s] += 1;
        }
        // Rows of a node must be orthonormal (at most 3).
        for s in 0..self.nodes.len() {
            let rows = &self.rows[self.start[s]..self.start[s + 1]];
            if rows.len() > 3 {
                return Err(bad(self.nodes[s], "more than three constrained directions"));
            }
            for i in 0..rows.len() {
                for j in 0..i {
                    if rows[i].dir.dot(&rows[j].dir).abs() > 1e-9 {
                        return Err(bad(
                            self.nodes[s],
                            "constrained twice along non-orthogonal directions",
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// Rows of node slot `s`.
    pub fn node_rows(&self, s: usize) -> &[Row] {
        &self.rows[self.start[s]..self.start[s + 1]]
    }

    /// Writes the reaction of every constraint (`sum_rows lambda d`, N) from
    /// the multipliers of the rows (`lambda[k]` for `rows[k]`).
    pub fn reactions_from_multipliers(&self, lambda: &[f64], out: &mut Vec<Vector3<f64>>) {
        out.clear();
        out.resize(self.n_constraints, Vector3::zeros());
        for (r, l) in self.rows.iter().zip(lambda) {
            out[r.constraint as usize] += r.dir * *l;
        }
    }

    /// Writes the reaction of every constraint from the nodal force `f` (N per
    /// DOF) that holds the constrained nodes: row multiplier `d . f_node`.
    pub fn reactions_from_forces(&self, f: &[f64], out: &mut Vec<Vector3<f64>>) {
        out.clear();
        out.resize(self.n_constraints, Vector3::zeros());
        for r in &self.rows {
            let n = 3 * r.node as usize;
            let fv = Vector3::new(f[n], f[n + 1], f[n + 2]);
            out[r.constraint as usize] += r.dir * r.dir.dot(&fv);
        }
    }
}

/// Per-step DOF elimination frame for the solvers that eliminate constrained
/// DOFs: each constrained node gets an orthonormal basis whose first columns
/// are its row directions (the identity when they are Cartesian axes), and
/// the DOFs in that basis are either free or enforced.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Fixed supports per DOF (Cartesian), constant for the solver's life.
    pub support: Vec<bool>,
    /// Constrained per DOF, in the node's basis.
    pub fixed: Vec<bool>,
    /// Enforced value per DOF, in the node's basis (0 for supports), m.
    pub value: Vec<f64>,
    /// Node basis (columns), meaningful where `rotated`.
    pub basis: Vec<Matrix3<f64>>,
    /// Whether a node's basis differs from the identity.
    pub rotated: Vec<bool>,
    touched: Vec<u32>,
}

impl Frame {
    /// A frame with only the supports (per DOF) fixed.
    pub fn new(support: Vec<bool>) -> Self {
        let n_dofs = support.len();
        Self {
            fixed: support.clone(),
            support,
            value: vec![0.0; n_dofs],
            basis: vec![Matrix3::identity(); n_dofs / 3],
            rotated: vec![false; n_dofs / 3],
            touched: Vec::new(),
        }
    }

    /// Sets the step's constraints (rows already validated).
    pub fn set(&mut self, rows: &StepRows) {
        for &n in &self.touched {
            let n = n as usize;
            for a in 0..3 {
                self.fixed[3 * n + a] = self.support[3 * n + a];
                self.value[3 * n + a] = 0.0;
            }
            self.basis[n] = Matrix3::identity();
            self.rotated[n] = false;
        }
        self.touched.clear();
        for (s, &node) in rows.nodes.iter().enumerate() {
            let n = node as usize;
            self.touched.push(node);
            let nr = rows.node_rows(s);
            let cartesian = nr
                .iter()
                .all(|r| r.dir.iter().filter(|&&c| c == 0.0).count() == 2);
            if cartesian {
                for r in nr {
                    let a = r.dir.iamax();
                    self.fixed[3 * n + a] = true;
                    self.value[3 * n + a] = r.value * r.dir[a];
                }
            } else {
                let mut cols: [Vector3<f64>; 3] = [Vector3::zeros(); 3];
                for (k, r) in nr.iter().enumerate() {
                    cols[k] = r.dir;
                    self.fixed[3 * n + k] = true;
                    self.value[3 * n + k] = r.value;
                }
                // Complete with Gram-Schmidt on the Cartesian axes.
                let mut k = nr.len();
                for a in 0..3 {
                    if k == 3 {
                        break;
                    }
                    let mut v = Vector3::ith(a, 1.0);
                    for c in &cols[..k] {
                        v -= c * c.dot(&v);
                    }
                    if v.norm() > 0.3 {
                        cols[k] = v.normalize();
                        k += 1;
                    }
                }
                self.basis[n] = Matrix3::from_columns(&cols);
                self.rotated[n] = true;
            }
        }
    }

    /// Rotates an element matrix (global basis) into the node bases:
    /// `K' = T^T K T`, `T = blockdiag(B_a)`.
    pub fn rotate_element(&self, t: &[u32; 4], k: &mut super::element::ElementMatrix) {
        for a in 0..4 {
            if !self.rotated[t[a] as usize] {
                continue;
            }
            let b = self.basis[t[a] as usize];
            // Columns of node a: K[:, 3a..3a+3] * B; rows: B^T * K[3a..3a+3, :].
            for r in 0..12 {
                let row =
                    nalgebra::RowVector3::new(k[(r, 3 * a)], k[(r, 3 * a + 1)], k[(r, 3 * a + 2)])
                        * b;
                for c in 0..3 {
                    k[(r, 3 * a + c)] = row[c];
                }
            }
            for c in 0..12 {
                let col = b.transpose()
                    * Vector3::new(k[(3 * a, c)], k[(3 * a + 1, c)], k[(3 * a + 2, c)]);
                for r in 0..3 {
                    k[(3 * a + r, c)] = col[r];
                }
            }
        }
    }

    /// Node vector from the global basis into the node's basis (in place).
    pub fn to_node_basis(&self, x: &mut [f64]) {
        for &n in &self.touched {
            let n = n as usize;
            if self.rotated[n] {
                let v = self.basis[n].transpose() * super::assembly::node_vec(x, n);
                x[3 * n..3 * n + 3].copy_from_slice(v.as_slice());
            }
        }
    }

    /// Node vector from the node's basis back to the global basis (in place).
    pub fn to_global_basis(&self, x: &mut [f64]) {
        for &n in &self.touched {
            let n = n as usize;
            if self.rotated[n] {
                let v = self.basis[n] * super::assembly::node_vec(x, n);
                x[3 * n..3 * n + 3].copy_from_slice(v.as_slice());
            }
        }
    }

    /// Scatters element matrix `k` (already in node bases) of element `e`
    /// into the eliminated system: entries between free DOFs go to `values`,
    /// diagonal entries of constrained DOFs too (to keep the scale), and the
    /// coupling to constrained DOFs moves `-K_fc g_c` into `rhs`, where `g` is
    /// `self.value` (or `lift` when given, in node bases).
    pub fn scatter(
        &self,
        pattern: &super::assembly::Pattern,
        e: usize,
        t: &[u32; 4],
        k: &super::element::ElementMatrix,
        lift: &[f64],
        values: &mut [f64],
        rhs: &mut [f64],
    ) {
        let dof = |p: usize| 3 * t[p / 3] as usize + p % 3;
        for (s, &(p, q)) in pattern.scatter[e]
            .iter()
            .zip(super::assembly::LOCAL_PAIRS.iter())
        {
            let (p, q) = (p as usize, q as usize);
            let (gp, gq) = (dof(p), dof(q));
            let (cp, cq) = (self.fixed[gp], self.fixed[gq]);
            let v = k[(p, q)];
            if !cp && !cq || p == q {
                values[*s as usize] += v;
            } else if !cp && cq {
                rhs[gp] -= v * lift[gq];
            } else if cp && !cq {
                rhs[gq] -= v * lift[gp];
            }
        }
    }

    /// After scattering all elements: constrained rows become `diag * x = diag * g`.
    /// A zero diagonal (a node in no element) is replaced by 1.
    pub fn finish(
        &self,
        pattern: &super::assembly::Pattern,
        lift: &[f64],
        values: &mut [f64],
        rhs: &mut [f64],
    ) {
        for d in 0..pattern.n_dofs {
            if self.fixed[d] {
                let i = pattern.diag[d];
                if values[i] == 0.0 {
                    values[i] = 1.0;
                }
                rhs[d] = values[i] * lift[d];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_constraints() {
        let support = vec![true, true, true, false, false, false, false, false, false];
        let mut rows = StepRows::new(3);
        let p = |node, d: [f64; 3]| Prescribed {
            node,
            displacement: Vector3::from(d),
        };
        assert!(matches!(
            rows.set(&[p(7, [0.0; 3])], &support),
            Err(SolveError::BadConstraint { node: 7, .. })
        ));
        assert!(matches!(
            rows.set(&[p(0, [0.0; 3])], &support),
            Err(SolveError::BadConstraint { node: 0, .. })
        ));
        assert!(matches!(
            rows.set(&[p(1, [f64::NAN, 0.0, 0.0])], &support),
            Err(SolveError::NonFinite(_))
        ));
        assert!(matches!(
            rows.set(&[p(1, [0.0; 3]), p(1, [0.0; 3])], &support),
            Err(SolveError::BadConstraint { node: 1, .. })
        ));
        let tilted = Constraint {
            node: 2,
            kind: ConstraintKind::Normal {
                normal: Vector3::new(0.0, 2.0, 0.0),
                displacement: 0.1,
            },
        };
        assert!(matches!(
            rows.set(&[tilted], &support),
            Err(SolveError::BadConstraint { node: 2, .. })
        ));
        // Two rollers on one node are fine.
        let rollers = [
            Constraint {
                node: 2,
                kind: ConstraintKind::Axis {
                    axis: 0,
                    displacement: 0.0,
                },
            },
            Constraint {
                node: 2,
                kind: ConstraintKind::Axis {
                    axis: 2,
                    displacement: 0.1,
                },
            },
        ];
        rows.set(&rollers, &support).unwrap();
        assert_eq!(rows.nodes, vec![2]);
        assert_eq!(rows.rows.len(), 2);
    }
}
