//! The force loop's local model: the contact problem of one force sample,
//! solved on the compliance the last deformation step published
//! (DESIGN.md sections 3b and 4).
//!
//! A step publishes a [`ForceModel`]: the compliance blocks `C` over the
//! nodes near the plates (a [`CompliancePatch`]: the step's rows and the
//! vertices within the band of every face), the step's rows with their
//! multipliers, and the friction anchors. A sample then solves the
//! problem of its rows `r` (its instrument's rows at the fresh pose, the
//! other instruments' rows at their latest poses, the skull's): `W_rs =
//! d_r^T C[node_r][node_s] d_s` (m/N), free gaps `q_r` from the rows, and
//! the complementarity conditions of [`crate::fem::lcp`]. For linear
//! elasticity this is the problem a full solve at the sample's poses
//! poses, so a sample equals that solve (to the solver's tolerance) as long
//! as every row's node is in the patch. For a nonlinear strategy the patch
//! is the tangent compliance of the last step ([`crate::fem::tangent`]) and
//! the rows are rewritten for it ([`super::rows::to_tangent`]): a sample
//! then solves the first-order expansion of the step's problem.
//!
//! [`ForceSolver`] keeps, from one sample to the next, the rows it has seen
//! in slots of a dense `W` and the solver's Cholesky factor of the working
//! set. Within one frame always; across frames while the patches are
//! linear, since a linear strategy's patch holds blocks of one constant
//! compliance (a row's entries of `W` depend on its nodes, weights,
//! direction and own compliance alone, whatever patch they are read from):
//! the ties' hundreds of rows, identical in every step, then keep their
//! entries and their place in the factor from the first frame on, and a
//! new frame costs only the rows that changed. A row that is still there
//! with the same direction
//! (within [`DIRECTION_TOLERANCE`]) and the same weights keeps its row of
//! `W`; a new row, one whose direction turned farther, or a point row whose
//! weights changed at all (a polygon point that slid on its triangle), gets
//! its row computed (one `3 x 3` block product per node of the sample and
//! node of the row, then a dot product per slot) and leaves the factor; a
//! row gone leaves it. A sample with an unchanged contact set costs one pair
//! of triangular solves. The gaps always use the rows' exact directions;
//! only `W` may lag the rotation of a plate by up to
//! [`DIRECTION_TOLERANCE`]: an error of that order on the coupling terms of
//! `W`, amplified where rows nearly depend on each other. (A point's weights
//! get no such tolerance: rows on one triangle nearly depend on each other,
//! and a 1e-3 lag in the weights moved the V block insertion's samples by
//! 2.1% of the peak.) Rows whose node has no
//! compliance in the patch are reported ([`SampleAnswer::pending`]); the
//! caller answers them with a penalty and a flag.

use super::rows::{Anchors, Row};
use crate::fem::CompliancePatch;
use crate::fem::lcp::{ContactSolver, LcpError, Report, RowKind, Tolerances};
use nalgebra::Vector3;
use std::collections::HashMap;
use std::sync::Arc;

const NONE: u32 = u32::MAX;

/// How far (radians, as the chord between unit vectors) a row's direction
/// may turn before its row of `W` is recomputed within one frame.
pub const DIRECTION_TOLERANCE: f64 = 1e-3;

/// What a deformation step publishes for the force loops.
#[derive(Debug, Clone, Default)]
pub struct ForceModel {
    /// The frame that built it (identifies it for the force loops' caches).
    pub frame: u64,
    /// Compliance blocks over the nodes near the plates.
    pub patch: Arc<CompliancePatch>,
    /// Volume node -> index in `patch.nodes` (`u32::MAX`: not in the patch).
    pub patch_index: Arc<Vec<u32>>,
    /// The step's rows (every owner).
    pub step_rows: Vec<Row>,
    /// Their multipliers, N.
    pub step_lambda: Vec<f64>,
    step_lookup: HashMap<u64, usize>,
    /// Stick points of frictional contacts after the step.
    pub anchors: Anchors,
    /// Whether the strategy gave a compliance patch (without one the force
    /// loop holds the step's forces).
    pub has_patch: bool,
    /// The step's force and torque on each instrument (N, N m).
    pub step_force: Vec<(Vector3<f64>, Vector3<f64>)>,
    /// The ties at the step and the blades' cuts since (scenes with ties).
    pub ties: Option<Arc<crate::sim::core::engine::TiesAtStep>>,
}

impl ForceModel {
    /// A model from a step's results; `patch_index` must index `patch`.
    pub fn new(
        frame: u64,
        patch: Arc<CompliancePatch>,
        patch_index: Arc<Vec<u32>>,
        step_rows: Vec<Row>,
        step_lambda: Vec<f64>,
        anchors: Anchors,
        has_patch: bool,
        step_force: Vec<(Vector3<f64>, Vector3<f64>)>,
    ) -> Self {
        let step_lookup = step_rows
            .iter()
            .enumerate()
            .map(|(i, r)| (r.key, i))
            .collect();
        Self {
            frame,
            patch,
            patch_index,
            step_rows,
            step_lambda,
            step_lookup,
            anchors,
            has_patch,
            step_force,
            ties: None,
        }
    }

    /// The step's multiplier of the row with `key`, if the step had it.
    pub fn step_multiplier(&self, key: u64) -> Option<f64> {
        self.step_lookup.get(&key).map(|&i| self.step_lambda[i])
    }

    /// Index of volume node `v` in the patch.
    pub fn patch_slot(&self, v: u32) -> Option<usize> {
        match self.patch_index.get(v as usize) {
            Some(&i) if i != NONE => Some(i as usize),
            _ => None,
        }
    }
}

/// Whether `row` may read the blocks of patch node `ix`: the node's blocks
/// hold for every direction ([`crate::fem::CompliancePatch::axes`]), or
/// the row is at that node alone along its direction.
#[inline]
fn along_axis(axes: &[Vector3<f64>], ix: usize, row: &crate::fem::ContactRow) -> bool {
    let Some(n) = axes.get(ix).filter(|n| **n != Vector3::zeros()) else {
        return true;
    };
    let d = row.dir * row.weight;
    !row.is_point() && (d - n * d.dot(n)).norm() <= 1e-12 * d.norm()
}

/// The answer of one sample's contact problem (buffers reused).
#[derive(Debug, Clone, Default)]
pub struct SampleAnswer {
    /// Multiplier of each row, N (0 for pending rows).
    pub lambda: Vec<f64>,
    /// Rows whose node has no compliance in the patch.
    pub pending: Vec<u32>,
    /// The solver's check of the answer.
    pub report: Report,
}

/// The force loop's contact solver with its cache (module documentation).
/// No allocation once its buffers have grown to the largest row set.
#[derive(Debug, Default)]
pub struct ForceSolver {
    frame: Option<u64>,
    slot_of: HashMap<u64, u32>,
    slot_key: Vec<u64>,
    /// Whether the slots' entries of `W` were read from linear patches
    /// (then they hold across frames).
    linear: bool,
    /// Per slot: the row's volume nodes (`NONE`: unused), the patch indices
    /// of those nodes in the present frame, and their weights.
    slot_nodes: Vec<[u32; 3]>,
    slot_patch: Vec<[u32; 3]>,
    slot_w: Vec<[f64; 3]>,
    slot_dir: Vec<Vector3<f64>>,
    /// Per slot: the row's own compliance, m/N (a tie's spring).
    slot_c: Vec<f64>,
    slot_seen: Vec<u32>,
    free_slots: Vec<u32>,
    /// Slots in use are below `n`.
    n: usize,
    cap: usize,
    w: Vec<f64>,
    q: Vec<f64>,
    kinds: Vec<RowKind>,
    lambda: Vec<f64>,
    row_slot: Vec<u32>,
    dirty: Vec<u32>,
    is_dirty: Vec<bool>,
    done: Vec<bool>,
    in_use: Vec<bool>,
    stamp: u32,
    /// Per patch node: the stamp of the sample that listed it, and its
    /// index in `sample_nodes`.
    node_stamp: Vec<u32>,
    node_local: Vec<u32>,
    /// The patch nodes of this sample's rows, each once.
    sample_nodes: Vec<u32>,
    /// `e[k] = sum_a w_a C[k][node_a] d` of the row being computed, over
    /// `sample_nodes` (m/N times unit: m/N).
    e: Vec<Vector3<f64>>,
    lcp: ContactSolver,
}

impl ForceSolver {
    /// An empty solver.
    pub fn new() -> Self {
        Self::default()
    }

    fn reset(&mut self, frame: u64) {
        self.frame = Some(frame);
        self.slot_of.clear();
        self.slot_key.clear();
        self.slot_nodes.clear();
        self.slot_patch.clear();
        self.slot_w.clear();
        self.slot_dir.clear();
        self.slot_c.clear();
        self.slot_seen.clear();
        self.free_slots.clear();
        self.kinds.clear();
        self.q.clear();
        self.lambda.clear();
        self.is_dirty.clear();
        self.done.clear();
        self.in_use.clear();
        self.n = 0;
        self.lcp.forget();
    }

    fn grow(&mut self, n: usize) {
        if n > self.cap {
            let cap = n.max(2 * self.cap).max(16);
            let mut w = vec![0.0; cap * cap];
            for i in 0..self.n {
                w[i * cap..i * cap + self.n]
                    .copy_from_slice(&self.w[i * self.cap..i * self.cap + self.n]);
            }
            self.w = w;
            self.cap = cap;
        }
    }

    /// A slot for a new row.
    fn take_slot(&mut self) -> u32 {
        if let Some(s) = self.free_slots.pop() {
            self.in_use[s as usize] = true;
            return s;
        }
        let s = self.n;
        self.grow(s + 1);
        self.n += 1;
        self.slot_key.push(0);
        self.slot_nodes.push([NONE; 3]);
        self.slot_patch.push([NONE; 3]);
        self.slot_w.push([0.0; 3]);
        self.slot_dir.push(Vector3::zeros());
        self.slot_c.push(0.0);
        self.slot_seen.push(0);
        self.kinds.push(RowKind::Off);
        self.q.push(0.0);
        self.lambda.push(0.0);
        self.is_dirty.push(false);
        self.done.push(false);
        self.in_use.push(true);
        s as u32
    }

    /// Lists the patch nodes of the slots seen at `stamp` into
    /// `sample_nodes` (each once; `node_local` their index), for a patch of
    /// `patch_nodes` nodes, and sizes `e` to them.
    fn list_sample_nodes(&mut self, patch_nodes: usize, stamp: u32) {
        if self.node_stamp.len() < patch_nodes {
            self.node_stamp.resize(patch_nodes, 0);
            self.node_local.resize(patch_nodes, 0);
        }
        self.sample_nodes.clear();
        for s in 0..self.n {
            if self.slot_seen[s] != stamp {
                continue;
            }
            for &p in &self.slot_patch[s] {
                if p != NONE && self.node_stamp[p as usize] != stamp {
                    self.node_stamp[p as usize] = stamp;
                    self.node_local[p as usize] = self.sample_nodes.len() as u32;
                    self.sample_nodes.push(p);
                }
            }
        }
        if self.e.len() < self.sample_nodes.len() {
            self.e.resize(self.sample_nodes.len(), Vector3::zeros());
        }
    }

    /// Solves the contact problem of `rows` on `model` into `answer`.
    pub fn solve(
        &mut self,
        model: &ForceModel,
        rows: &[Row],
        answer: &mut SampleAnswer,
    ) -> Result<(), LcpError> {
        if self.frame != Some(model.frame) {
            // Entries read from a linear patch hold in the next linear one
            // (module documentation); a tangent patch's do not.
            if self.frame.is_some() && self.linear && model.patch.linear {
                self.frame = Some(model.frame);
            } else {
                self.reset(model.frame);
                self.linear = model.patch.linear;
            }
        }
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            // Wrapped: no old stamp may equal a new one.
            self.slot_seen.fill(0);
            self.node_stamp.fill(0);
            self.stamp = 1;
        }
        let stamp = self.stamp;
        self.dirty.clear();
        self.row_slot.clear();
        answer.pending.clear();
        for (i, r) in rows.iter().enumerate() {
            // The row's nodes in the patch (all of them, or the row waits).
            let mut p = [NONE; 3];
            let mut v = [NONE; 3];
            let mut w = [0.0; 3];
            let mut complete = true;
            for (a, (n, wn)) in r.row.nodes().enumerate() {
                match model.patch_slot(n) {
                    // A node whose blocks hold along one direction only (a
                    // held skull node) serves rows along it.
                    Some(ix) if !along_axis(&model.patch.axes, ix, &r.row) => complete = false,
                    Some(ix) => {
                        p[a] = ix as u32;
                        v[a] = n;
                        w[a] = wn;
                    }
                    None => complete = false,
                }
            }
            if !complete {
                self.row_slot.push(NONE);
                answer.pending.push(i as u32);
                continue;
            }
            let s = match self.slot_of.get(&r.key) {
                Some(&s) => {
                    let su = s as usize;
                    let turned = (self.slot_dir[su] - r.row.dir).norm() > DIRECTION_TOLERANCE;
                    // A point that slid on its triangle gets its row again
                    // (module documentation).
                    let moved = self.slot_nodes[su] != v || self.slot_w[su] != w;
                    // The same nodes' places in this frame's patch.
                    self.slot_patch[su] = p;
                    let c = r.row.compliance_m_per_n;
                    if !(turned || moved) && self.slot_c[su] != c && !self.is_dirty[su] {
                        // Only the row's own compliance changed (a blade cut
                        // a tie of its pair): only its diagonal entry.
                        self.w[su * self.cap + su] += c - self.slot_c[su];
                        self.slot_c[su] = c;
                        self.lcp.changed(su);
                    }
                    if turned || moved {
                        self.slot_dir[su] = r.row.dir;
                        self.slot_c[su] = r.row.compliance_m_per_n;
                        self.slot_nodes[su] = v;
                        self.slot_w[su] = w;
                        if !self.is_dirty[su] {
                            self.is_dirty[su] = true;
                            self.dirty.push(s);
                        }
                    }
                    s
                }
                None => {
                    let s = self.take_slot();
                    let su = s as usize;
                    self.slot_of.insert(r.key, s);
                    self.slot_key[su] = r.key;
                    self.slot_nodes[su] = v;
                    self.slot_patch[su] = p;
                    self.slot_w[su] = w;
                    self.slot_dir[su] = r.row.dir;
                    self.slot_c[su] = r.row.compliance_m_per_n;
                    self.lambda[su] = model.step_multiplier(r.key).unwrap_or(0.0);
                    if !self.is_dirty[su] {
                        self.is_dirty[su] = true;
                        self.dirty.push(s);
                    }
                    s
                }
            };
            self.slot_seen[s as usize] = stamp;
            self.row_slot.push(s);
        }
        // Rows gone since the last sample free their slots.
        for s in 0..self.n {
            if self.in_use[s] && self.slot_seen[s] != stamp {
                self.in_use[s] = false;
                self.slot_of.remove(&self.slot_key[s]);
                self.kinds[s] = RowKind::Off;
                self.lambda[s] = 0.0;
                self.lcp.changed(s);
                self.free_slots.push(s as u32);
            }
        }
        // Rows of W of the new and turned rows: `W_ds = d_d^T (sum_ab w_a
        // w_b C[a][b]) d_s`, through the node vectors `e_d[k] = sum_a w_a
        // C[k][a] d_d` over the sample's nodes (one pass of `3 x 3` blocks
        // per node instead of one per node pair of every row pair: rows
        // share their nodes, a vertex's row with the points on its
        // triangles).
        let (n, cap) = (self.n, self.cap);
        for &d in &self.dirty {
            self.lcp.changed(d as usize);
        }
        if !self.dirty.is_empty() {
            self.list_sample_nodes(model.patch.nodes.len(), stamp);
        }
        for di in 0..self.dirty.len() {
            let d = self.dirty[di] as usize;
            let dir = self.slot_dir[d];
            for (k, &pk) in self.sample_nodes.iter().enumerate() {
                let mut v = Vector3::zeros();
                for (&pa, &wa) in self.slot_patch[d].iter().zip(&self.slot_w[d]) {
                    if pa != NONE {
                        v += model.patch.block_mul(pk as usize, pa as usize, &(dir * wa));
                    }
                }
                self.e[k] = v;
            }
            for s in 0..n {
                // Skip slots not in this sample, and pairs with a dirty
                // slot done before (computed once: W stays symmetric).
                if self.slot_seen[s] != stamp || (self.is_dirty[s] && self.done[s]) {
                    continue;
                }
                let mut v = 0.0;
                for (&pb, &wb) in self.slot_patch[s].iter().zip(&self.slot_w[s]) {
                    if pb != NONE {
                        v += wb
                            * self.slot_dir[s].dot(&self.e[self.node_local[pb as usize] as usize]);
                    }
                }
                if s == d {
                    // A row's own compliance (a tie's spring).
                    v += self.slot_c[d];
                }
                self.w[d * cap + s] = v;
                self.w[s * cap + d] = v;
            }
            self.done[d] = true;
        }
        for &d in &self.dirty {
            self.is_dirty[d as usize] = false;
            self.done[d as usize] = false;
        }
        // Kinds and gaps of this sample.
        for (i, r) in rows.iter().enumerate() {
            let s = self.row_slot[i];
            if s == NONE {
                continue;
            }
            let s = s as usize;
            self.q[s] = r.row.gap_free_m;
            self.kinds[s] = match r.row.kind {
                RowKind::Tangent { normal, mu } => match self.row_slot[normal as usize] {
                    NONE => RowKind::Off,
                    ns => RowKind::Tangent { normal: ns, mu },
                },
                k => k,
            };
        }
        let tol = Tolerances::for_gaps(&self.q[..n], &self.kinds[..n]);
        let report = self.lcp.solve(
            &self.w,
            cap,
            n,
            &self.q[..n],
            &self.kinds[..n],
            &mut self.lambda[..n],
            &tol,
        )?;
        answer.lambda.clear();
        answer.lambda.extend(self.row_slot.iter().map(|&s| {
            if s == NONE {
                0.0
            } else {
                self.lambda[s as usize]
            }
        }));
        answer.report = report;
        Ok(())
    }
}
