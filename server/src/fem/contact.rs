//! The contact problem of a deformation step in the solver's terms
//! (DESIGN.md section 3b): rows `g = gap_free + dir . u_node` (m) on volume
//! nodes, each unilateral (Signorini), bilateral (an enforced value) or a
//! tangent row of a frictional contact, and their multipliers (N, the force
//! a row applies to the tissue along `dir`).
//!
//! [`DeformationSolver::solve_contact`](super::DeformationSolver::solve_contact)
//! solves it. Strategies with a compliance operator (`compliance`) solve it
//! on the Delassus operator `W = H C H^T` ([`super::lcp`]); the others use
//! [`solve_by_active_set`]: rounds of equality solves
//! ([`DeformationSolver::solve_constraints`](super::DeformationSolver::solve_constraints))
//! with the working set's rows as normal constraints, adding every row whose
//! gap is negative and releasing every unilateral row whose multiplier pulls
//! (a primal-dual active set; from the tenth round one row changes per
//! round, the worst, so that it cannot cycle). For a nonlinear strategy
//! the gaps come from its nonlinear solution: each round is a full solve.
//! Friction needs the compliance operator. A row on a triangle's point is
//! exact with `compliance` and `direct` (which superposes the responses to
//! point loads); the nonlinear strategies take it on its heaviest node (an
//! approximation: the gap then follows that node's displacement instead of
//! the point's).

// Negated comparisons are deliberate: NaN must fail the checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub use super::lcp::{Report, RowKind, Tolerances};
use super::{Constraint, ConstraintKind, DeformationSolver, SolveError};
use nalgebra::{Matrix3, Point3, Vector3};
use std::sync::Arc;

/// No node (an unused entry of [`ContactRow::others`]).
pub const NO_NODE: (u32, f64) = (u32::MAX, 0.0);

/// One row of a contact problem: on one node (`g = gap_free + dir . u_node`),
/// or on a point of a surface triangle (`g = gap_free + dir . sum_a w_a
/// u_a` over the triangle's nodes with barycentric weights `w_a`; the
/// row's force is shared out the same way).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactRow {
    /// Volume node (of a point row, its heaviest node).
    pub node: u32,
    /// Its weight (1 for a node row).
    pub weight: f64,
    /// The other nodes of a point row and their weights ([`NO_NODE`]: none).
    pub others: [(u32, f64); 2],
    /// Unit direction: the direction of the force the row applies to the
    /// tissue, and of the gap.
    pub dir: Vector3<f64>,
    /// The gap at zero displacement, m (negative: the rest position
    /// violates the row).
    pub gap_free_m: f64,
    /// What the row constrains.
    pub kind: RowKind,
    /// The row's own compliance `c`, m/N (0: a rigid row): the row's gap is
    /// `g = gap_free + dir . sum_a w_a u_a + c lambda`. A unilateral row with
    /// `c = 1 / k` is a tension-only spring of stiffness `k` (N/m) whose
    /// stretch is `-(gap_free + dir . sum_a w_a u_a)`: the conditions
    /// `lambda >= 0`, `g >= 0`, `lambda g = 0` give `lambda = k max(0,
    /// stretch)` ([`super::ties`]). On the Delassus operator it is a diagonal
    /// term, `W + diag(c)`.
    pub compliance_m_per_n: f64,
}

impl ContactRow {
    /// A row on one node.
    pub fn at_node(node: u32, dir: Vector3<f64>, gap_free_m: f64, kind: RowKind) -> Self {
        Self {
            node,
            weight: 1.0,
            others: [NO_NODE; 2],
            dir,
            gap_free_m,
            kind,
            compliance_m_per_n: 0.0,
        }
    }

    /// A row between two nodes, `a` pulled along `dir` and `b` along
    /// `-dir` (weights `+1` and `-1`): with `dir` the unit vector from `a`
    /// to `b`, the gap is `gap_free + dir . (u_a - u_b)`, the shortening of
    /// the segment from `a` to `b` beyond `gap_free`.
    pub fn between(
        a: u32,
        b: u32,
        dir: Vector3<f64>,
        gap_free_m: f64,
        kind: RowKind,
        compliance_m_per_n: f64,
    ) -> Self {
        Self {
            node: a,
            weight: 1.0,
            others: [(b, -1.0), NO_NODE],
            dir,
            gap_free_m,
            kind,
            compliance_m_per_n,
        }
    }

    /// A row on a point of a triangle: `nodes[a]` with weight `weights[a]`
    /// (summing to 1).
    pub fn at_point(
        nodes: [u32; 3],
        weights: [f64; 3],
        dir: Vector3<f64>,
        gap_free_m: f64,
        kind: RowKind,
    ) -> Self {
        let mut order = [0usize, 1, 2];
        order.sort_by(|&a, &b| weights[b].total_cmp(&weights[a]));
        let e = |k: usize| (nodes[order[k]], weights[order[k]]);
        Self {
            node: nodes[order[0]],
            weight: weights[order[0]],
            others: [e(1), e(2)],
            dir,
            gap_free_m,
            kind,
            compliance_m_per_n: 0.0,
        }
    }

    /// The row's nodes with their weights.
    pub fn nodes(&self) -> impl Iterator<Item = (u32, f64)> + '_ {
        std::iter::once((self.node, self.weight)).chain(
            self.others
                .iter()
                .copied()
                .filter(|&(n, w)| n != u32::MAX && w != 0.0),
        )
    }

    /// Whether the row is on a point of a triangle (several nodes).
    pub fn is_point(&self) -> bool {
        self.others.iter().any(|&(n, w)| n != u32::MAX && w != 0.0)
    }

    /// `dir . sum_a w_a u_a` for the node displacements `u`.
    pub fn normal_motion(&self, u: &[Vector3<f64>]) -> f64 {
        self.nodes()
            .map(|(n, w)| w * self.dir.dot(&u[n as usize]))
            .sum()
    }
}

/// The answer of a contact solve (buffers reused across steps).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ContactAnswer {
    /// On entry, a warm start (one per row; any other length is a cold
    /// start); on return, the multiplier of each row, N.
    pub multipliers: Vec<f64>,
    /// Rows left out of the solve because their node's compliance is not
    /// computed yet (strategies that defer it): their multiplier is 0.
    pub pending: Vec<u32>,
    /// The final check of the conditions.
    pub report: Report,
    /// Equality solves (1 for a Delassus solve).
    pub rounds: u32,
}

/// Compliance blocks over a set of nodes, for the force loop's local
/// contact problem: `C[i][j]` (3 x 3, m/N) is the displacement of node `i`
/// under a unit force at node `j`, in the tangent of the last step, and
/// `free_positions[i]` the position node `i` would take with the contact
/// forces of the last step removed (the rest position for linear
/// strategies). Rows on these nodes then have gaps
/// `g = dir . (free - point) + dir . (C f)`.
///
/// A linear strategy's patch may lead with shared nodes ([`SharedBlocks`]:
/// the ties' nodes, in every step's patch): their blocks among themselves
/// are computed once and shared by every patch, and a patch holds only the
/// rows of its other nodes, against all its nodes; the blocks of a shared
/// node's row against the others are those rows' transposes (`C` is
/// symmetric).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CompliancePatch {
    /// Nodes with blocks (of the nodes asked for, those whose compliance is
    /// available), in block order: the shared nodes first.
    pub nodes: Vec<u32>,
    /// The rows of the nodes after the `s` shared ones, `3 (m - s) x 3 m`,
    /// row-major: entry `(3 (i - s) + a, 3 j + b)` is `C[i][j][(a, b)]`.
    pub blocks: Vec<f64>,
    /// The blocks among the leading shared nodes (`None`: none).
    pub shared: Option<Arc<SharedBlocks>>,
    /// Per node, m.
    pub free_positions: Vec<Point3<f64>>,
    /// Whether the strategy is linear (then `free_positions` are the rest
    /// positions and the blocks never change).
    pub linear: bool,
    /// Per node, the only direction its blocks hold for (a held skull node
    /// without columns: `C[i][j]` is given as `n_i (n_i^T C[i][j] n_j)
    /// n_j^T` between two such nodes), or zero: every direction. Empty:
    /// zero for every node. A row at such a node along another direction
    /// must wait like a row on a node outside the patch.
    pub axes: Vec<Vector3<f64>>,
}

/// Blocks of a linear strategy's compliance among a fixed set of nodes
/// that lead every patch ([`CompliancePatch`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SharedBlocks {
    /// The nodes, in block order.
    pub nodes: Vec<u32>,
    /// `3 s x 3 s`, row-major: entry `(3 i + a, 3 j + b)` is
    /// `C[i][j][(a, b)]`.
    pub blocks: Vec<f64>,
}

impl CompliancePatch {
    /// The number of leading shared nodes.
    #[inline]
    pub fn shared_nodes(&self) -> usize {
        self.shared.as_ref().map_or(0, |s| s.nodes.len())
    }

    /// Block `(i, j)` (indices into `nodes`).
    #[inline]
    pub fn block(&self, i: usize, j: usize) -> Matrix3<f64> {
        Matrix3::from_fn(|a, b| self.entry(i, a, j, b))
    }

    /// `C[i][j][(a, b)]`.
    #[inline]
    fn entry(&self, i: usize, a: usize, j: usize, b: usize) -> f64 {
        let s = self.shared_nodes();
        let m3 = 3 * self.nodes.len();
        if i >= s {
            self.blocks[(3 * (i - s) + a) * m3 + 3 * j + b]
        } else if j >= s {
            self.blocks[(3 * (j - s) + b) * m3 + 3 * i + a]
        } else {
            let sh = self
                .shared
                .as_ref()
                .expect("shared nodes have shared blocks");
            sh.blocks[(3 * i + a) * 3 * s + 3 * j + b]
        }
    }

    /// `C[i][j] v` (m/N times N: m), read straight from the blocks (the
    /// force loop's inner product; no `3 x 3` copy).
    #[inline]
    pub fn block_mul(&self, i: usize, j: usize, v: &Vector3<f64>) -> Vector3<f64> {
        let s = self.shared_nodes();
        let m3 = 3 * self.nodes.len();
        let by_rows = |blocks: &[f64], first: usize, stride: usize| {
            let row = |a: usize| {
                let r = &blocks[(first + a) * stride + 3 * j..(first + a) * stride + 3 * j + 3];
                r[0] * v.x + r[1] * v.y + r[2] * v.z
            };
            Vector3::new(row(0), row(1), row(2))
        };
        if i >= s {
            by_rows(&self.blocks, 3 * (i - s), m3)
        } else if j >= s {
            // The transpose of block (j, i).
            let col = |b: usize| &self.blocks[(3 * (j - s) + b) * m3 + 3 * i..][..3];
            let (c0, c1, c2) = (col(0), col(1), col(2));
            Vector3::new(
                c0[0] * v.x + c1[0] * v.y + c2[0] * v.z,
                c0[1] * v.x + c1[1] * v.y + c2[1] * v.z,
                c0[2] * v.x + c1[2] * v.y + c2[2] * v.z,
            )
        } else {
            let sh = self
                .shared
                .as_ref()
                .expect("shared nodes have shared blocks");
            by_rows(&sh.blocks, 3 * i, 3 * s)
        }
    }
}

/// Checks rows for finiteness and unit directions; friction is refused
/// unless `friction` is allowed.
pub fn validate_rows(
    rows: &[ContactRow],
    n_nodes: usize,
    friction: bool,
) -> Result<(), SolveError> {
    for (i, r) in rows.iter().enumerate() {
        for (n, w) in r.nodes() {
            if n as usize >= n_nodes {
                return Err(SolveError::BadConstraint {
                    node: n,
                    reason: format!("contact row {i}: out of range (the mesh has {n_nodes} nodes)"),
                });
            }
            if !w.is_finite() {
                return Err(SolveError::NonFinite(format!("weight of contact row {i}")));
            }
        }
        if !(r.compliance_m_per_n >= 0.0 && r.compliance_m_per_n.is_finite()) {
            return Err(SolveError::BadConstraint {
                node: r.node,
                reason: format!(
                    "contact row {i}: compliance {} m/N (must be finite and >= 0)",
                    r.compliance_m_per_n
                ),
            });
        }
        if !r.gap_free_m.is_finite() || !r.dir.iter().all(|v| v.is_finite()) {
            return Err(SolveError::NonFinite(format!(
                "contact row {i} on node {}",
                r.node
            )));
        }
        if (r.dir.norm() - 1.0).abs() > 1e-6 {
            return Err(SolveError::BadConstraint {
                node: r.node,
                reason: format!(
                    "contact row {i}: direction of length {}, not 1",
                    r.dir.norm()
                ),
            });
        }
        if let RowKind::Tangent { normal, .. } = r.kind {
            if !friction {
                return Err(SolveError::InvalidModel(
                    "Coulomb friction needs the compliance strategy".into(),
                ));
            }
            // A point row's tangent rows hold the anchored tissue point,
            // which need not be the normal row's point (rows::Anchor).
            if rows
                .get(normal as usize)
                .is_none_or(|n| n.kind != RowKind::Unilateral)
            {
                return Err(SolveError::BadConstraint {
                    node: r.node,
                    reason: format!(
                        "contact row {i}: tangent of row {normal}, which is not a unilateral row"
                    ),
                });
            }
        }
    }
    Ok(())
}

/// Most rounds of [`solve_by_active_set`].
pub const MAX_ROUNDS: u32 = 60;

/// The generic contact solve (module documentation): on return the
/// solver's last solution holds the displacements and `answer` the
/// multipliers. Rows on a triangle's point are exact with a strategy that
/// takes nodal loads ([`DeformationSolver::takes_loads`]): in each round
/// their multipliers solve `B K^-1 B^T mu = -(g_free + B u_0)` from the
/// responses to unit point loads with the round's node rows held, and the
/// round's solution carries the loads `B^T mu`; other strategies take each
/// such row on its heaviest node.
pub fn solve_by_active_set<S: DeformationSolver + ?Sized>(
    solver: &mut S,
    rows: &[ContactRow],
    n_nodes: usize,
    answer: &mut ContactAnswer,
) -> Result<(), SolveError> {
    validate_rows(rows, n_nodes, false)?;
    let exact_points = solver.takes_loads();
    // A row between nodes or with its own compliance (a tie) has no
    // heaviest-node form: it needs the point rows' exact path.
    if !exact_points
        && rows
            .iter()
            .any(|r| r.compliance_m_per_n > 0.0 || r.nodes().any(|(_, w)| w < 0.0))
    {
        return Err(SolveError::InvalidModel(format!(
            "strategy {} cannot take tie rows (rows between two nodes with a compliance of their own; it holds ties as springs of its energy, DeformationSolver::set_tie_springs): rows need a strategy that takes nodal loads (compliance, direct)",
            solver.name()
        )));
    }
    let approx: Vec<ContactRow>;
    let rows = if !exact_points && rows.iter().any(|r| r.is_point()) {
        approx = rows
            .iter()
            .map(|r| ContactRow::at_node(r.node, r.dir, r.gap_free_m, r.kind))
            .collect();
        &approx[..]
    } else {
        rows
    };
    let n = rows.len();
    answer.pending.clear();
    let cold = answer.multipliers.len() != n;
    if cold {
        answer.multipliers.clear();
        answer.multipliers.resize(n, 0.0);
    }
    let q: Vec<f64> = rows.iter().map(|r| r.gap_free_m).collect();
    let kinds: Vec<RowKind> = rows.iter().map(|r| r.kind).collect();
    let tol = Tolerances::for_gaps(&q, &kinds);
    let mut active: Vec<bool> = rows
        .iter()
        .zip(&answer.multipliers)
        .map(|(r, &l)| match r.kind {
            RowKind::Bilateral => true,
            RowKind::Unilateral => {
                if cold {
                    r.gap_free_m < 0.0
                } else {
                    l > 0.0
                }
            }
            _ => false,
        })
        .collect();
    let mut grouping = NodeRows::default();
    let mut cons = Vec::new();
    let mut gaps = vec![0.0; n];
    let mut node_active = vec![false; n];
    let mut responses: Vec<Vec<Vector3<f64>>> = Vec::new();
    let mut resp_reactions: Vec<Vec<Vector3<f64>>> = Vec::new();
    let mut loads: Vec<(u32, Vector3<f64>)> = Vec::new();
    for round in 1..=MAX_ROUNDS {
        for i in 0..n {
            node_active[i] = active[i] && !rows[i].is_point();
        }
        grouping.build(rows, &node_active);
        grouping.constraints(rows, &mut cons)?;
        let points: Vec<usize> = (0..n)
            .filter(|&i| active[i] && rows[i].is_point())
            .collect();
        let mut mu = Vec::new();
        if points.is_empty() {
            solver.solve_constraints(&cons)?;
        } else {
            // u_0 with the node rows, then the responses to unit point
            // loads with the same rows held at zero.
            let u0 = solver.solve_constraints(&cons)?.displacements.clone();
            responses.resize_with(points.len(), Vec::new);
            resp_reactions.resize_with(points.len(), Vec::new);
            for (k, &p) in points.iter().enumerate() {
                loads.clear();
                loads.extend(rows[p].nodes().map(|(nd, w)| (nd, rows[p].dir * w)));
                let (v, rv) = (&mut responses[k], &mut resp_reactions[k]);
                if !solver.load_response(&loads, v, rv) {
                    return Err(SolveError::InvalidModel(
                        "the strategy gave no load response".into(),
                    ));
                }
            }
            let m = points.len();
            let a = nalgebra::DMatrix::from_fn(m, m, |i, j| {
                let own = if i == j {
                    rows[points[i]].compliance_m_per_n
                } else {
                    0.0
                };
                rows[points[i]].normal_motion(&responses[j]) + own
            });
            let b = nalgebra::DVector::from_fn(m, |i, _| {
                -(rows[points[i]].gap_free_m + rows[points[i]].normal_motion(&u0))
            });
            // Point rows may be dependent (two corners of one polygon on
            // one triangle, or a triangle whose vertices the node rows
            // already hold): the least-norm solution, singular values
            // below 1e-10 of the largest taken as zero, gives such a row
            // no load beyond what the others need.
            let x = match a.clone().cholesky() {
                Some(c) => c.solve(&b),
                None => {
                    let svd = a.svd(true, true);
                    let eps = 1e-10 * svd.singular_values.max();
                    svd.solve(&b, eps).map_err(|reason| SolveError::Singular {
                        matrix: "the point rows of a contact solve",
                        reason,
                    })?
                }
            };
            mu.extend(x.iter().copied());
            loads.clear();
            for (k, &p) in points.iter().enumerate() {
                loads.extend(
                    rows[p]
                        .nodes()
                        .map(|(nd, w)| (nd, rows[p].dir * (w * mu[k]))),
                );
            }
            solver.solve_loaded(&cons, &loads)?;
        }
        let sol = solver
            .last_solution()
            .ok_or_else(|| SolveError::InvalidModel("the strategy keeps no solution".into()))?;
        grouping.multipliers(rows, &sol.reactions, &mut answer.multipliers);
        for (k, &p) in points.iter().enumerate() {
            answer.multipliers[p] = mu[k];
        }
        for (i, r) in rows.iter().enumerate() {
            if !active[i] {
                answer.multipliers[i] = 0.0;
            }
            gaps[i] = r.gap_free_m
                + r.normal_motion(&sol.displacements)
                + r.compliance_m_per_n * answer.multipliers[i];
        }
        let scale = answer
            .multipliers
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()));
        // Violations: a unilateral row pulling, a row held at zero with a
        // negative gap.
        let mut worst: Option<(usize, f64)> = None;
        let mut changes = Vec::new();
        for i in 0..n {
            if rows[i].kind != RowKind::Unilateral {
                continue;
            }
            let badness = if active[i] {
                let l = answer.multipliers[i];
                (l < -1e-12 * scale).then(|| -l / scale.max(f64::MIN_POSITIVE))
            } else {
                (gaps[i] < -tol.gap_m).then(|| -gaps[i] / tol.gap_m.max(f64::MIN_POSITIVE))
            };
            if let Some(b) = badness {
                changes.push(i);
                if worst.is_none_or(|(_, w)| b > w) {
                    worst = Some((i, b));
                }
            }
        }
        if changes.is_empty() {
            for (i, r) in rows.iter().enumerate() {
                if r.kind == RowKind::Unilateral && answer.multipliers[i] < 0.0 {
                    answer.multipliers[i] = 0.0;
                }
            }
            answer.rounds = round;
            answer.report = measure(rows, &answer.multipliers, &gaps);
            return Ok(());
        }
        if round < 10 {
            for i in changes {
                active[i] = !active[i];
            }
        } else if let Some((i, _)) = worst {
            active[i] = !active[i];
        }
    }
    Err(SolveError::NotConverged {
        iterations: MAX_ROUNDS,
        residual: f64::NAN,
    })
}

/// The report of an answer from its gaps.
fn measure(rows: &[ContactRow], lambda: &[f64], gaps: &[f64]) -> Report {
    let mut r = Report::default();
    for (i, row) in rows.iter().enumerate() {
        if lambda[i] != 0.0 {
            r.active += 1;
        }
        match row.kind {
            RowKind::Unilateral => {
                r.max_gap_violation_m = r.max_gap_violation_m.max((-gaps[i]).max(0.0));
                r.max_complementarity = r.max_complementarity.max((lambda[i] * gaps[i]).abs());
            }
            RowKind::Bilateral => {
                r.max_gap_violation_m = r.max_gap_violation_m.max(gaps[i].abs());
            }
            _ => {}
        }
    }
    r
}

/// The working set's rows grouped by node, with an orthonormal basis of
/// each node's directions (Gram-Schmidt): the equality solve takes at most
/// three mutually orthogonal rows a node.
#[derive(Debug, Default)]
struct NodeRows {
    /// Distinct nodes of active rows, with the range of their rows in `order`.
    nodes: Vec<(u32, usize, usize)>,
    /// Active row indices grouped by node.
    order: Vec<usize>,
    /// Per entry of `order`: the basis vector and whether it is independent.
    basis: Vec<(Vector3<f64>, bool)>,
    /// First constraint index of each node.
    first: Vec<usize>,
}

impl NodeRows {
    fn build(&mut self, rows: &[ContactRow], active: &[bool]) {
        self.nodes.clear();
        self.order.clear();
        let mut idx: Vec<usize> = (0..rows.len()).filter(|&i| active[i]).collect();
        idx.sort_by_key(|&i| (rows[i].node, i));
        let mut s = 0;
        while s < idx.len() {
            let node = rows[idx[s]].node;
            let mut e = s;
            while e < idx.len() && rows[idx[e]].node == node {
                e += 1;
            }
            self.nodes
                .push((node, self.order.len(), self.order.len() + (e - s)));
            self.order.extend_from_slice(&idx[s..e]);
            s = e;
        }
    }

    fn constraints(
        &mut self,
        rows: &[ContactRow],
        out: &mut Vec<Constraint>,
    ) -> Result<(), SolveError> {
        out.clear();
        self.basis.clear();
        self.first.clear();
        for &(node, a, b) in &self.nodes {
            self.first.push(out.len());
            let mut es: Vec<(Vector3<f64>, f64)> = Vec::with_capacity(3);
            for &i in &self.order[a..b] {
                let r = &rows[i];
                let mut e = r.dir;
                let mut c = -r.gap_free_m;
                for (ek, ck) in &es {
                    let p = ek.dot(&r.dir);
                    e -= ek * p;
                    c -= ck * p;
                }
                let len = e.norm();
                if len > 1e-6 && es.len() < 3 {
                    let (e, c) = (e / len, c / len);
                    es.push((e, c));
                    self.basis.push((e, true));
                    out.push(Constraint {
                        node,
                        kind: ConstraintKind::Normal {
                            normal: e,
                            displacement: c,
                        },
                    });
                } else {
                    // A direction the node's other rows already fix.
                    self.basis.push((Vector3::zeros(), false));
                }
            }
        }
        Ok(())
    }

    /// Row multipliers from the node reactions of the constraints: with
    /// `D` the node's independent row directions, `D lambda = R`, solved by
    /// least squares (`D` has full column rank); dependent rows get 0.
    fn multipliers(&self, rows: &[ContactRow], reactions: &[Vector3<f64>], out: &mut [f64]) {
        for (k, &(_, a, b)) in self.nodes.iter().enumerate() {
            let f = self.first[k];
            let indep: Vec<usize> = (a..b).filter(|&j| self.basis[j].1).collect();
            let mut r = Vector3::zeros();
            for c in 0..indep.len() {
                r += reactions[f + c];
            }
            let m = indep.len();
            let d: Vec<Vector3<f64>> = indep.iter().map(|&j| rows[self.order[j]].dir).collect();
            let gram = nalgebra::DMatrix::from_fn(m, m, |p, s| d[p].dot(&d[s]));
            let rhs = nalgebra::DVector::from_fn(m, |p, _| d[p].dot(&r));
            let lambda = gram
                .cholesky()
                .map(|ch| ch.solve(&rhs))
                .unwrap_or_else(|| nalgebra::DVector::zeros(m));
            for j in a..b {
                out[self.order[j]] = 0.0;
            }
            for (p, &j) in indep.iter().enumerate() {
                out[self.order[j]] = lambda[p];
            }
        }
    }
}
