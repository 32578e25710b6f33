//! Strategy `compliance`: factor the stiffness with the fixed supports once,
//! then per step condense onto the contacted DOFs.
//!
//! With `K0` the supported stiffness, the step's constraint rows `G u = g`
//! (see [`super::constraint`]) and multipliers `lambda` (N, the forces the
//! constraints apply), equilibrium is `K0 u = G^T lambda`, so
//! `u = K0^-1 G^T lambda` and `(G K0^-1 G^T) lambda = g`. The columns of
//! `K0^-1` for a contacted node (3 per node) are solved once, when the node
//! first enters contact, and cached (only their rows at the recovered nodes);
//! a step then builds the small dense compliance block `C = G K0^-1 G^T`,
//! factors it (dense Cholesky), solves for `lambda`, and recovers
//! `u = sum_j K0^-1[:, j] r_j` from the node reactions `r_j`. Exact for linear
//! elasticity.
//!
//! Nodes that only ever meet contact along one fixed direction each (the
//! rigid skull surface's nodes along their rest normals) may instead hold
//! their normal compliance, computed once ([`Compliance::hold_normals`],
//! [`super::held_normals`]): a row along such a direction needs no column,
//! its entries of `W` with the other held rows come from the held matrix and
//! with any other row from that row's columns, and a solve with force on a
//! held node recovers `u` by one sparse solve with the factor instead of
//! combining columns. The held matrix is outside the cache and never
//! evicted.
//!
//! The cache is bounded (least recently used node evicted, see
//! [`Compliance::set_cache_limit`]; default [`DEFAULT_CACHE_BYTES`]). Apart
//! from filling the cache for new contact nodes (and growing the block
//! workspaces when a step has more contact rows than any before), a step
//! allocates nothing: `server/tests/fem_alloc.rs` counts allocations over
//! repeated steps with one contact set. The recovery `u = sum_j K0^-1[:, j]
//! r_j` runs over row blocks (in parallel under the caller's [`Par`]).

use super::assembly::node_vec;
use super::column_queue::{SharedQueue, Urgency};
use super::constraint::{Constraint, StepRows};
use super::contact::{self, CompliancePatch, ContactAnswer, ContactRow, SharedBlocks};
use super::factor::{SharedFactor, SparseLlt};
use super::held_normals::HeldNormals;
use super::lcp::{ContactSolver, RowKind, Tolerances};
use super::model::Model;
use super::par::{Par, for_each_chunk};
use super::{DeformationSolver, LocalModel, Prescribed, Solution, SolveError};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::{Mat, MatMut};
use nalgebra::{DMatrix, Vector3};
use std::sync::{Arc, mpsc};

const NONE: u32 = u32::MAX;
/// [`Compliance::asked`]: not asked of the worker.
const NOT_ASKED: u8 = u8::MAX;

/// When a contact solve or a compliance patch needs the columns of a node
/// that are not cached.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ColumnPolicy {
    /// Solve for them at once, on the calling thread (deterministic: every
    /// call sees every column it needs; the default).
    #[default]
    Compute,
    /// Ask a background thread for them and go on without: a contact row
    /// on such a node is left out ([`ContactAnswer::pending`]) and a patch
    /// lacks the node, until a later call finds the columns cached. No
    /// call waits for columns.
    Defer,
}

/// A thread that solves for columns of `K0^-1` in the background: it takes
/// nodes from a [`SharedQueue`], most urgent first, and returns each node's
/// three full columns.
struct ColumnWorker {
    queue: Arc<SharedQueue>,
    rx: mpsc::Receiver<(u32, Vec<f64>)>,
    handle: Option<std::thread::JoinHandle<()>>,
}

/// Nodes a background solve takes at once (48 right-hand sides) for a row
/// or the patch, and for nodes ahead of contact: the smaller batch bounds
/// how long an urgent node waits behind a batch already being solved.
fn worker_batch(urgency: Urgency) -> usize {
    match urgency {
        Urgency::Row | Urgency::Patch => 16,
        Urgency::Ahead => 8,
    }
}

impl ColumnWorker {
    fn spawn(
        factor: SharedFactor,
        n_nodes: usize,
        on_start: Option<Arc<dyn Fn() + Send + Sync>>,
    ) -> Option<Self> {
        let queue = Arc::new(SharedQueue::new(n_nodes));
        let jobs = queue.clone();
        let (done, rx) = mpsc::channel();
        let handle = std::thread::Builder::new()
            .name("compliance-columns".into())
            .spawn(move || {
                if let Some(f) = on_start {
                    f();
                }
                let n_dofs = factor.nrows();
                let mut chunk = Vec::new();
                while jobs.wait_take(worker_batch, &mut chunk).is_some() {
                    let ncols = 3 * chunk.len();
                    let mut block = vec![0.0; n_dofs * ncols];
                    for (k, &n) in chunk.iter().enumerate() {
                        for a in 0..3 {
                            block[(3 * k + a) * n_dofs + 3 * n as usize + a] = 1.0;
                        }
                    }
                    factor.solve_many(&mut block, ncols);
                    // Before the hand-back, so that a node evicted after
                    // it can be asked again.
                    jobs.finish(&chunk);
                    for (k, &n) in chunk.iter().enumerate() {
                        let cols = block[3 * k * n_dofs..3 * (k + 1) * n_dofs].to_vec();
                        if done.send((n, cols)).is_err() {
                            return;
                        }
                    }
                }
            })
            .ok()?;
        Some(Self {
            queue,
            rx,
            handle: Some(handle),
        })
    }
}

impl Drop for ColumnWorker {
    fn drop(&mut self) {
        // The worker finishes the batch it is solving and stops; what still
        // waits is dropped.
        self.queue.close();
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// Default memory bound of the column cache, bytes: each cached contact node
/// holds `3 x 3 x recovered nodes` values (`72 x recovered` bytes; 0.86 MB
/// on the 12k-node paper phantom with every node recovered).
pub const DEFAULT_CACHE_BYTES: usize = 512 << 20;

/// The default cache bound in contact nodes for `recovered` recovered nodes:
/// [`DEFAULT_CACHE_BYTES`] worth, and at least 256.
pub fn default_cache_limit(recovered: usize) -> usize {
    (DEFAULT_CACHE_BYTES / (72 * recovered.max(1))).max(256)
}

/// Which nodes' displacements a `compliance` step recovers.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum Recover {
    /// Every node (for frames of the whole volume, and support reactions).
    #[default]
    All,
    /// The boundary surface nodes only (what the collision stage and the
    /// watchers see); cached columns are shorter in proportion.
    Surface,
    /// An explicit node list.
    Nodes(Vec<u32>),
}

/// A contact row's identity for the kept rows of `W`: its nodes and
/// weights, its direction (bit for bit) and its kind. Its own compliance is
/// kept apart: only the diagonal depends on it.
#[derive(Debug, Clone, Copy, PartialEq)]
struct RowSig {
    nodes: [u32; 3],
    bits: [u64; 6],
    kind: u8,
}

impl RowSig {
    fn of(r: &ContactRow) -> Self {
        Self {
            nodes: [r.node, r.others[0].0, r.others[1].0],
            bits: [
                r.weight.to_bits(),
                r.others[0].1.to_bits(),
                r.others[1].1.to_bits(),
                r.dir.x.to_bits(),
                r.dir.y.to_bits(),
                r.dir.z.to_bits(),
            ],
            kind: match r.kind {
                RowKind::Off => 0,
                RowKind::Unilateral => 1,
                RowKind::Bilateral => 2,
                RowKind::Tangent { .. } => 3,
            },
        }
    }
}

/// The `compliance` strategy.
pub struct Compliance {
    model: Model,
    factor: SparseLlt,
    rec_nodes: Vec<u32>,
    rec_of: Vec<u32>,
    cache_slot: Vec<u32>,
    cols: Vec<f64>,
    n_slots: usize,
    slot_node: Vec<u32>,
    slot_stamp: Vec<u64>,
    stamp: u64,
    cache_limit: usize,
    missing: Vec<u32>,
    /// [`Self::ask`]'s nodes to send (reused).
    todo: Vec<u32>,
    /// A contact solve's nodes that need columns (reused).
    want: Vec<u32>,
    par: Par,
    rows: StepRows,
    cmat: Mat<f64>,
    chol_buf: MemBuffer,
    lambda: Vec<f64>,
    tmp_rows: Vec<f64>,
    node_reaction: Vec<Vector3<f64>>,
    u_rec: Vec<f64>,
    full: Vec<f64>,
    solution: Solution,
    local: LocalModel,
    support_reactions: Vec<Vector3<f64>>,
    support_elems: Vec<usize>,
    /// Nodes whose nodal-pressure star holds a fixed node.
    support_stars: Vec<u32>,
    fixed_index: Vec<u32>,
    prepared: bool,
    policy: ColumnPolicy,
    worker: Option<ColumnWorker>,
    worker_start: Option<Arc<dyn Fn() + Send + Sync>>,
    /// Per node: the highest [`Urgency`] it was asked of the worker at (as
    /// `u8`), not received yet; [`NOT_ASKED`] otherwise.
    asked: Vec<u8>,
    /// Per node: listed in `missing` (deduplication).
    listed: Vec<bool>,
    /// Nodes declared shared by every patch, their blocks once built, and
    /// per node whether it is declared.
    share: Vec<u32>,
    shared: Option<Arc<SharedBlocks>>,
    is_shared: Vec<bool>,
    // Contact solve buffers.
    c_nodes: Vec<u32>,
    c_slot: Vec<u32>,
    c_force: Vec<Vector3<f64>>,
    inc: Vec<usize>,
    inc_of: Vec<u32>,
    /// `W` of the last contact solve's rows (row stride `w_stride`), with
    /// each row's identity and own compliance: the leading rows still the
    /// same keep their entries.
    w: Vec<f64>,
    w_stride: usize,
    w_sig: Vec<RowSig>,
    w_c: Vec<f64>,
    q: Vec<f64>,
    kinds: Vec<RowKind>,
    lam: Vec<f64>,
    lcp: ContactSolver,
    /// The held normal compliance of the skull's nodes
    /// ([`Compliance::hold_normals`]): rows along those normals need no
    /// column.
    held: Option<HeldNormals>,
    /// A full DOF vector for the response of forces at held nodes (one
    /// sparse solve; allocated with `held`).
    held_rhs: Vec<f64>,
    /// Nodes whose columns were solved (here or by the worker) since
    /// construction.
    columns_solved: u64,
}

impl std::fmt::Debug for Compliance {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Compliance")
            .field("recovered_nodes", &self.rec_nodes.len())
            .field("cached_nodes", &self.n_slots)
            .field("cache_limit", &self.cache_limit)
            .finish()
    }
}

impl Compliance {
    /// Factors the supported stiffness (once per scene).
    pub fn new(model: Model, recover: Recover) -> Result<Self, SolveError> {
        let n_nodes = model.n_nodes();
        let mut values = vec![0.0; model.pattern.nnz()];
        let frame = super::constraint::Frame::new(model.support.clone());
        let mut rhs = vec![0.0; model.pattern.n_dofs];
        let lift = vec![0.0; model.pattern.n_dofs];
        for (e, t) in model.tets.iter().enumerate() {
            frame.scatter(
                &model.pattern,
                e,
                t,
                &model.kel[e],
                &lift,
                &mut values,
                &mut rhs,
            );
        }
        if let Some(p) = &model.pressure {
            let mut star = Vec::new();
            p.scatter(
                &frame,
                &model.pattern,
                &lift,
                &mut values,
                &mut rhs,
                &mut star,
            );
        }
        frame.finish(&model.pattern, &lift, &mut values, &mut rhs);
        let mut factor = SparseLlt::new(&model.pattern)?;
        factor
            .factorize(&model.pattern, &values)
            .map_err(|e| match e {
                SolveError::NotPositiveDefinite { matrix, pivot, .. } => {
                    SolveError::NotPositiveDefinite {
                        matrix,
                        pivot,
                        hint: "; the fixed supports must prevent every rigid motion for this strategy",
                    }
                }
                other => other,
            })?;
        let rec_nodes: Vec<u32> = match recover {
            Recover::All => (0..n_nodes as u32).collect(),
            Recover::Surface => {
                let mesh = crate::mesh::TetMesh {
                    nodes: model.rest.clone(),
                    tets: model.tets.clone(),
                    labels: Vec::new(),
                };
                let mut v = mesh.boundary().to_volume;
                v.sort_unstable();
                v
            }
            Recover::Nodes(mut v) => {
                v.sort_unstable();
                v.dedup();
                if let Some(&n) = v.iter().find(|&&n| n as usize >= n_nodes) {
                    return Err(SolveError::BadConstraint {
                        node: n,
                        reason: "recovered node out of range".into(),
                    });
                }
                v
            }
        };
        let mut rec_of = vec![NONE; n_nodes];
        for (i, &n) in rec_nodes.iter().enumerate() {
            rec_of[n as usize] = i as u32;
        }
        let mut fixed_index = vec![NONE; n_nodes];
        for (i, &n) in model.fixed.iter().enumerate() {
            fixed_index[n as usize] = i as u32;
        }
        let support_elems = model
            .tets
            .iter()
            .enumerate()
            .filter(|(_, t)| t.iter().any(|&n| fixed_index[n as usize] != NONE))
            .map(|(e, _)| e)
            .collect();
        let support_stars = model.pressure.as_ref().map_or_else(Vec::new, |p| {
            (0..n_nodes as u32)
                .filter(|&a| {
                    p.star(a as usize)
                        .0
                        .iter()
                        .any(|&n| fixed_index[n as usize] != NONE)
                })
                .collect()
        });
        Ok(Self {
            rows: StepRows::new(n_nodes),
            cache_slot: vec![NONE; n_nodes],
            cols: Vec::new(),
            n_slots: 0,
            slot_node: Vec::new(),
            slot_stamp: Vec::new(),
            stamp: 0,
            cache_limit: default_cache_limit(rec_nodes.len()),
            missing: Vec::new(),
            todo: Vec::new(),
            want: Vec::new(),
            par: Par::Seq,
            cmat: Mat::zeros(0, 0),
            chol_buf: MemBuffer::new(llt::factor::cholesky_in_place_scratch::<f64>(
                0,
                Par::Seq,
                Default::default(),
            )),
            lambda: Vec::new(),
            tmp_rows: Vec::new(),
            node_reaction: Vec::new(),
            u_rec: vec![0.0; 3 * rec_nodes.len()],
            full: if rec_nodes.len() == n_nodes {
                vec![0.0; 3 * n_nodes]
            } else {
                Vec::new()
            },
            solution: Solution {
                displacements: vec![Vector3::zeros(); n_nodes],
                ..Default::default()
            },
            local: LocalModel {
                nodes: Vec::new(),
                compliance: DMatrix::zeros(0, 0),
                displacements: Vec::new(),
                reactions: Vec::new(),
            },
            support_reactions: Vec::new(),
            support_elems,
            support_stars,
            fixed_index,
            prepared: false,
            policy: ColumnPolicy::Compute,
            worker: None,
            worker_start: None,
            asked: vec![NOT_ASKED; n_nodes],
            listed: vec![false; n_nodes],
            share: Vec::new(),
            shared: None,
            is_shared: vec![false; n_nodes],
            c_nodes: Vec::new(),
            c_slot: vec![NONE; n_nodes],
            c_force: Vec::new(),
            inc: Vec::new(),
            inc_of: Vec::new(),
            w: Vec::new(),
            w_stride: 0,
            w_sig: Vec::new(),
            w_c: Vec::new(),
            q: Vec::new(),
            kinds: Vec::new(),
            lam: Vec::new(),
            lcp: ContactSolver::new(),
            held: None,
            held_rhs: Vec::new(),
            columns_solved: 0,
            rec_nodes,
            rec_of,
            factor,
            model,
        })
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Number of nodes whose columns of `K0^-1` are cached.
    pub fn cached_nodes(&self) -> usize {
        self.n_slots
    }

    /// Nodes whose columns of `K0^-1` were solved since construction (on
    /// the calling thread or taken from the background worker; the held
    /// normals of [`Self::hold_normals`] are not columns and not counted).
    pub fn columns_solved(&self) -> u64 {
        self.columns_solved
    }

    /// Computes and holds the normal compliance of `nodes` (volume node and
    /// unit direction: the skull surface's supported nodes and their rest
    /// normals; [`HeldNormals`]). From then on a contact row at one such
    /// node along its direction needs no column of `K0^-1`: its entries of
    /// `W` with other such rows come from the held matrix, with any other
    /// row from that row's nodes' columns, and the response to its force
    /// from one sparse solve per contact solve. The held matrix is never
    /// evicted ([`Self::held_bytes`]). Replaces what was held before.
    pub fn hold_normals(&mut self, nodes: &[(u32, Vector3<f64>)]) -> Result<(), SolveError> {
        let n_nodes = self.model.n_nodes();
        for &(v, d) in nodes {
            if v as usize >= n_nodes || self.rec_of[v as usize] == NONE {
                return Err(SolveError::BadConstraint {
                    node: v,
                    reason: "held normal: the node is out of range or not recovered".into(),
                });
            }
            if self.model.support[3 * v as usize..3 * v as usize + 3]
                .iter()
                .any(|&f| f)
            {
                return Err(SolveError::BadConstraint {
                    node: v,
                    reason: "held normal: the node is a fixed support".into(),
                });
            }
            let len = d.norm();
            if !len.is_finite() || (len - 1.0).abs() > 1e-9 {
                return Err(SolveError::BadConstraint {
                    node: v,
                    reason: format!("held normal: direction of length {len}"),
                });
            }
        }
        let start = std::time::Instant::now();
        let held = HeldNormals::compute(&self.factor.share(), n_nodes, nodes, self.par);
        tracing::info!(
            nodes = held.len(),
            bytes = held.bytes(),
            seconds = start.elapsed().as_secs_f64(),
            "skull compliance held"
        );
        self.held_rhs = vec![0.0; self.model.pattern.n_dofs];
        // The kept rows of `W` may involve the old held entries.
        self.w_sig.clear();
        self.w_c.clear();
        self.lcp.forget();
        self.held = Some(held);
        Ok(())
    }

    /// Bytes of the held normal compliance ([`Self::hold_normals`]; 0
    /// without).
    pub fn held_bytes(&self) -> usize {
        self.held.as_ref().map_or(0, HeldNormals::bytes) + 8 * self.held_rhs.len()
    }

    /// Drops the cached columns (memory: `9 x recovered nodes x 8` bytes per
    /// cached node).
    pub fn clear_cache(&mut self) {
        for n in self.cache_slot.iter_mut() {
            *n = NONE;
        }
        self.cols = Vec::new();
        self.n_slots = 0;
        self.slot_node = Vec::new();
        self.slot_stamp = Vec::new();
    }

    /// Bounds the cache to `nodes` contact nodes (at least 1): when a new
    /// node needs columns and the cache is full, the least recently used
    /// node not in the current step gives its slot up. A step with more
    /// nodes than the bound still caches them all (the cache then holds
    /// exactly the step's nodes). Shrinking below the current size drops
    /// the whole cache. Default: [`DEFAULT_CACHE_BYTES`] worth of columns.
    pub fn set_cache_limit(&mut self, nodes: usize) {
        self.cache_limit = nodes.max(1);
        if self.n_slots > self.cache_limit {
            self.clear_cache();
        }
    }

    /// The bound of the cache, in contact nodes.
    pub fn cache_limit(&self) -> usize {
        self.cache_limit
    }

    /// Whether the columns of `node` are cached.
    pub fn is_cached(&self, node: u32) -> bool {
        self.cache_slot
            .get(node as usize)
            .is_some_and(|&s| s != NONE)
    }

    /// Parallelism of the dense block factorization and of the recovery
    /// (the results do not depend on it). Default [`Par::Seq`].
    pub fn set_parallelism(&mut self, par: Par) {
        self.par = par;
        let cap = self.cmat.nrows();
        self.chol_buf = MemBuffer::new(llt::factor::cholesky_in_place_scratch::<f64>(
            cap,
            par,
            Default::default(),
        ));
    }

    /// Keeps a single-precision copy of the factor of `K0` (`4 x` its
    /// nonzeros in bytes, 40 MB on the 48k phantom) for
    /// `Compliance::constrained_solve`, a preconditioner: a solve with it
    /// reads half the memory. The solution of a step never uses it.
    pub fn keep_single(&mut self) {
        self.factor.keep_single();
    }

    /// Nonzeros of the Cholesky factor of `K0`.
    pub fn factor_nnz(&self) -> usize {
        self.factor.factor_nnz()
    }

    fn nrec3(&self) -> usize {
        3 * self.rec_nodes.len()
    }

    /// Block `(K0^-1)[node i, node j]` (3 x 3) from the cache; `i` recovered,
    /// `j` cached.
    #[inline]
    fn block(&self, i: u32, j: u32) -> nalgebra::Matrix3<f64> {
        let n3 = self.nrec3();
        let ri = 3 * self.rec_of[i as usize] as usize;
        let s = self.cache_slot[j as usize] as usize;
        let mut b = nalgebra::Matrix3::zeros();
        for a in 0..3 {
            let col = &self.cols[(3 * s + a) * n3..(3 * s + a + 1) * n3];
            b[(0, a)] = col[ri];
            b[(1, a)] = col[ri + 1];
            b[(2, a)] = col[ri + 2];
        }
        b
    }

    /// Block `C[i][j]` (3 x 3) for any two recovered nodes of which one is
    /// cached or both are held ([`Self::hold_normals`]); for two held nodes
    /// without columns only its part along their directions,
    /// `n_i N[i][j] n_j^T` (what rows along them read).
    fn any_block(&self, i: u32, j: u32) -> nalgebra::Matrix3<f64> {
        if self.cache_slot[j as usize] != NONE {
            return self.block(i, j);
        }
        if self.cache_slot[i as usize] != NONE {
            return self.block(j, i).transpose();
        }
        match &self.held {
            Some(h) => match (h.index_of(i), h.index_of(j)) {
                (Some(a), Some(b)) => h.normals[a] * h.entry(a, b) * h.normals[b].transpose(),
                _ => nalgebra::Matrix3::zeros(),
            },
            None => nalgebra::Matrix3::zeros(),
        }
    }

    /// A row at one held node along its held direction: its held index and
    /// `weight x dir . n`.
    #[inline]
    fn held_row(&self, r: &ContactRow) -> Option<(usize, f64)> {
        if r.is_point() {
            return None;
        }
        self.held.as_ref()?.along(r.node, &(r.dir * r.weight))
    }

    /// `W` entry of two rows whose nodes are cached or held (held rows):
    /// `sum_ab w_a w_b d_a^T C[a][b] d_b`.
    fn row_pair(&self, ra: &ContactRow, rc: &ContactRow) -> f64 {
        if let (Some(h), Some((ka, sa)), Some((kc, sc))) =
            (&self.held, self.held_row(ra), self.held_row(rc))
        {
            // Both along held directions: from the held matrix whether or
            // not their columns are cached too (the same answer either way).
            return sa * sc * h.entry(ka, kc);
        }
        let mut v = 0.0;
        for (na, wa) in ra.nodes() {
            for (nc, wc) in rc.nodes() {
                let b = self.any_block(na, nc);
                v += wa * wc * ra.dir.dot(&(b * rc.dir));
            }
        }
        v
    }

    /// Marks the step's nodes as used and computes the columns of those not
    /// cached (the equality path always computes).
    fn fill_cache(&mut self) {
        let nodes = std::mem::take(&mut self.rows.nodes);
        self.stamp += 1;
        self.use_columns(&nodes, ColumnPolicy::Compute, Urgency::Row);
        self.rows.nodes = nodes;
    }

    /// How contact solves and patches get columns they lack (default
    /// [`ColumnPolicy::Compute`]). `on_worker_start` runs first on the
    /// background thread of [`ColumnPolicy::Defer`] (e.g. to lower its
    /// priority below the loops').
    pub fn set_column_policy(
        &mut self,
        policy: ColumnPolicy,
        on_worker_start: Option<Arc<dyn Fn() + Send + Sync>>,
    ) {
        self.policy = policy;
        self.worker_start = on_worker_start;
        if policy == ColumnPolicy::Compute {
            self.worker = None;
            self.asked.fill(NOT_ASKED);
        }
    }

    /// Takes the columns the background worker finished into the cache.
    fn receive_columns(&mut self) {
        let Some(worker) = self.worker.as_ref() else {
            return;
        };
        let got: Vec<(u32, Vec<f64>)> = worker.rx.try_iter().collect();
        let n_dofs = self.model.pattern.n_dofs;
        let n3 = self.nrec3();
        self.columns_solved += got.len() as u64;
        for (n, cols) in got {
            self.asked[n as usize] = NOT_ASKED;
            if self.cache_slot[n as usize] != NONE {
                continue;
            }
            let s = self.take_slot();
            self.cache_slot[n as usize] = s as u32;
            self.slot_node[s] = n;
            // Not used by the current step: first in line for eviction
            // after the step's own nodes.
            self.slot_stamp[s] = self.stamp.saturating_sub(1);
            for a in 0..3 {
                let col = &cols[a * n_dofs..(a + 1) * n_dofs];
                let dst = &mut self.cols[(3 * s + a) * n3..(3 * s + a + 1) * n3];
                for (d, &r) in dst.chunks_exact_mut(3).zip(&self.rec_nodes) {
                    let r = 3 * r as usize;
                    d.copy_from_slice(&col[r..r + 3]);
                }
            }
        }
    }

    /// Asks the background worker for the columns of `nodes` at `urgency`
    /// (those not cached and not asked at that urgency or above yet).
    fn ask(&mut self, nodes: &[u32], urgency: Urgency) {
        let level = urgency as u8;
        self.todo.clear();
        self.todo.extend(nodes.iter().copied().filter(|&n| {
            let a = self.asked[n as usize];
            self.cache_slot[n as usize] == NONE && (a == NOT_ASKED || a < level)
        }));
        if self.todo.is_empty() {
            return;
        }
        if self.worker.is_none() {
            self.worker = ColumnWorker::spawn(
                self.factor.share(),
                self.model.n_nodes(),
                self.worker_start.clone(),
            );
        }
        if let Some(w) = &self.worker {
            w.queue.ask(&self.todo, urgency);
            for &n in &self.todo {
                self.asked[n as usize] = level;
            }
        }
    }

    /// Marks `nodes` as used by the current step (call after bumping
    /// `stamp` once per step) and makes their columns available: solved now
    /// ([`ColumnPolicy::Compute`]), or asked of the worker at `urgency`
    /// ([`ColumnPolicy::Defer`]; those stay uncached on return).
    fn use_columns(&mut self, nodes: &[u32], policy: ColumnPolicy, urgency: Urgency) {
        self.receive_columns();
        self.missing.clear();
        for &n in nodes {
            match self.cache_slot[n as usize] {
                NONE => {
                    if !self.listed[n as usize] {
                        self.listed[n as usize] = true;
                        self.missing.push(n);
                    }
                }
                s => self.slot_stamp[s as usize] = self.stamp,
            }
        }
        let missing = std::mem::take(&mut self.missing);
        for &n in &missing {
            self.listed[n as usize] = false;
        }
        if missing.is_empty() {
            self.missing = missing;
            return;
        }
        if policy == ColumnPolicy::Defer {
            self.ask(&missing, urgency);
            self.missing = missing;
            return;
        }
        let n_dofs = self.model.pattern.n_dofs;
        let n3 = self.nrec3();
        // In batches, to bound the dense right-hand-side block.
        for chunk in missing.chunks(64) {
            let ncols = 3 * chunk.len();
            let mut block = vec![0.0; n_dofs * ncols];
            for (k, &n) in chunk.iter().enumerate() {
                for a in 0..3 {
                    block[(3 * k + a) * n_dofs + 3 * n as usize + a] = 1.0;
                }
            }
            self.factor.solve_many(&mut block, ncols);
            self.columns_solved += chunk.len() as u64;
            for (k, &n) in chunk.iter().enumerate() {
                let s = self.take_slot();
                self.cache_slot[n as usize] = s as u32;
                self.slot_node[s] = n;
                self.slot_stamp[s] = self.stamp;
                for a in 0..3 {
                    let col = &block[(3 * k + a) * n_dofs..(3 * k + a + 1) * n_dofs];
                    let dst = &mut self.cols[(3 * s + a) * n3..(3 * s + a + 1) * n3];
                    for (d, &r) in dst.chunks_exact_mut(3).zip(&self.rec_nodes) {
                        let r = 3 * r as usize;
                        d.copy_from_slice(&col[r..r + 3]);
                    }
                }
            }
        }
        self.missing = missing;
    }

    /// A free slot: a new one below the bound, else the least recently used
    /// slot not in the current step, else a new one past the bound.
    fn take_slot(&mut self) -> usize {
        if self.n_slots >= self.cache_limit {
            let lru = (0..self.n_slots)
                .filter(|&s| self.slot_stamp[s] < self.stamp)
                .min_by_key(|&s| (self.slot_stamp[s], s));
            if let Some(s) = lru {
                self.cache_slot[self.slot_node[s] as usize] = NONE;
                return s;
            }
        }
        let s = self.n_slots;
        self.n_slots += 1;
        self.slot_node.push(NONE);
        self.slot_stamp.push(0);
        self.cols.resize(self.n_slots * 3 * self.nrec3(), 0.0);
        s
    }

    /// Validates the step, caches missing columns, builds and factors the
    /// compliance block of the step's rows.
    fn prepare<C: Into<Constraint> + Copy>(&mut self, cons: &[C]) -> Result<(), SolveError> {
        self.prepared = false;
        self.rows.set(cons, &self.model.support)?;
        if let Some(&n) = self
            .rows
            .nodes
            .iter()
            .find(|&&n| self.rec_of[n as usize] == NONE)
        {
            return Err(SolveError::BadConstraint {
                node: n,
                reason: "the node is not among the recovered nodes of this compliance solver"
                    .into(),
            });
        }
        self.fill_cache();
        let k = self.rows.rows.len();
        if k > self.cmat.nrows() {
            let cap = k.max(2 * self.cmat.nrows());
            self.cmat = Mat::zeros(cap, cap);
            self.chol_buf = MemBuffer::new(llt::factor::cholesky_in_place_scratch::<f64>(
                cap,
                self.par,
                Default::default(),
            ));
            self.lambda.resize(cap, 0.0);
            self.tmp_rows.resize(cap, 0.0);
        }
        // C[r, s] = d_r . (K0^-1)[node_r, node_s] d_s, per node pair.
        let ns = self.rows.nodes.len();
        for si in 0..ns {
            for sj in 0..=si {
                let b = self.block(self.rows.nodes[si], self.rows.nodes[sj]);
                for r in self.rows.start[si]..self.rows.start[si + 1] {
                    let dr = self.rows.rows[r].dir;
                    let bt = b.transpose() * dr;
                    for s in self.rows.start[sj]..self.rows.start[sj + 1].min(r + 1) {
                        let v = bt.dot(&self.rows.rows[s].dir);
                        self.cmat[(r, s)] = v;
                    }
                }
            }
        }
        let cm = self.cmat.as_mut().submatrix_mut(0, 0, k, k);
        llt::factor::cholesky_in_place(
            cm,
            Default::default(),
            self.par,
            MemStack::new(&mut self.chol_buf),
            Default::default(),
        )
        .map_err(|e| match e {
            llt::factor::LltError::NonPositivePivot { index } => SolveError::NotPositiveDefinite {
                matrix: "the compliance block",
                pivot: Some(index),
                hint: " (redundant constraints?)",
            },
        })?;
        self.prepared = true;
        Ok(())
    }

    /// Solves `C x = b` in place on the first `k` entries with the factored block.
    fn block_solve(cmat: &Mat<f64>, buf: &mut MemBuffer, b: &mut [f64]) {
        let k = b.len();
        llt::solve::solve_in_place(
            cmat.as_ref().submatrix(0, 0, k, k),
            MatMut::from_column_major_slice_mut(b, k, 1),
            Par::Seq,
            MemStack::new(buf),
        );
    }

    /// Adds `sign * sum_j K0^-1[:, j] r_j` over the step nodes to `out`
    /// (recovered rows, length `3 x recovered`), by row blocks that stay in
    /// cache (in parallel under `Par::Rayon`; each row sums the columns in
    /// the same order whatever the parallelism).
    fn combine(&self, nodes: &[u32], r: &[Vector3<f64>], sign: f64, out: &mut [f64]) {
        let n3 = self.nrec3();
        let (slots, cols) = (&self.cache_slot, &self.cols);
        for_each_chunk(self.par, out, 1, 4096, |first, o| {
            for (k, &n) in nodes.iter().enumerate() {
                let s = slots[n as usize] as usize;
                for a in 0..3 {
                    let c = sign * r[k][a];
                    if c == 0.0 {
                        continue;
                    }
                    let base = (3 * s + a) * n3 + first;
                    let col = &cols[base..base + o.len()];
                    for (o, v) in o.iter_mut().zip(col) {
                        *o += c * v;
                    }
                }
            }
        });
    }

    /// Adds `sign * K0^-1 (sum_j e_j r_j)` (the response to the node forces
    /// `r` at the step nodes) to `out`, by whichever is cheaper: combining
    /// the cached columns (`3 x nodes x recovered` products) or, when every
    /// node is recovered, one sparse solve (about `2 x` the factor's
    /// nonzeros). Both are exact.
    ///
    /// With `approximate` (a preconditioner) and a single-precision copy of
    /// the factor ([`Compliance::keep_single`]), the sparse solve runs in
    /// single precision (half the memory traffic, so it wins from half the
    /// combine cost).
    fn add_response(&mut self, r: &[Vector3<f64>], sign: f64, out: &mut [f64], approximate: bool) {
        let nodes = std::mem::take(&mut self.rows.nodes);
        self.add_response_at(&nodes, r, sign, out, approximate);
        self.rows.nodes = nodes;
    }

    /// [`Self::add_response`] for the forces `r` at `nodes` (cached).
    fn add_response_at(
        &mut self,
        nodes: &[u32],
        r: &[Vector3<f64>],
        sign: f64,
        out: &mut [f64],
        approximate: bool,
    ) {
        let single = approximate && self.factor.has_single();
        let combine_cost = 3 * nodes.len() * self.nrec3();
        let solve_cost = if single { 1 } else { 2 } * self.factor.factor_nnz();
        if self.full.is_empty() || combine_cost <= solve_cost {
            self.combine(nodes, r, sign, out);
            return;
        }
        self.full.fill(0.0);
        for (k, &n) in nodes.iter().enumerate() {
            let n = 3 * n as usize;
            for a in 0..3 {
                self.full[n + a] = sign * r[k][a];
            }
        }
        if single {
            self.factor.solve_single(&mut self.full);
        } else {
            self.factor.solve(&mut self.full);
        }
        for (o, v) in out.iter_mut().zip(&self.full) {
            *o += v;
        }
    }

    fn finish_step(&mut self) -> Result<&Solution, SolveError> {
        let k = self.rows.rows.len();
        for (l, r) in self.lambda[..k].iter_mut().zip(&self.rows.rows) {
            *l = r.value;
        }
        Self::block_solve(&self.cmat, &mut self.chol_buf, &mut self.lambda[..k]);
        if !self.lambda[..k].iter().all(|v| v.is_finite()) {
            return Err(SolveError::NonFinite("contact multipliers".into()));
        }
        let ns = self.rows.nodes.len();
        self.node_reaction.clear();
        self.node_reaction.resize(ns, Vector3::zeros());
        for (r, l) in self.rows.rows.iter().zip(&self.lambda[..k]) {
            self.node_reaction[self.rows.slot[r.node as usize] as usize] += r.dir * *l;
        }
        let mut u = std::mem::take(&mut self.u_rec);
        u.fill(0.0);
        let nr = std::mem::take(&mut self.node_reaction);
        self.add_response(&nr, 1.0, &mut u, false);
        self.node_reaction = nr;
        self.u_rec = u;
        if !self.u_rec.iter().all(|v| v.is_finite()) {
            return Err(SolveError::NonFinite("recovered displacement".into()));
        }
        // Commit.
        for (i, &n) in self.rec_nodes.iter().enumerate() {
            self.solution.displacements[n as usize] = node_vec(&self.u_rec, i);
        }
        self.rows
            .reactions_from_multipliers(&self.lambda[..k], &mut self.solution.reactions);
        self.solution.iterations = 1;
        // Local model: full 3m x 3m compliance of the contact nodes.
        let mut data: Vec<f64> =
            std::mem::replace(&mut self.local.compliance, DMatrix::zeros(0, 0))
                .data
                .into();
        data.clear();
        data.resize(9 * ns * ns, 0.0);
        let mut c = DMatrix::from_vec(3 * ns, 3 * ns, data);
        for si in 0..ns {
            for sj in 0..ns {
                let b = self.block(self.rows.nodes[si], self.rows.nodes[sj]);
                c.fixed_view_mut::<3, 3>(3 * si, 3 * sj).copy_from(&b);
            }
        }
        self.local.compliance = c;
        self.local.nodes.clear();
        self.local.nodes.extend_from_slice(&self.rows.nodes);
        self.local.displacements.clear();
        self.local.displacements.extend(
            self.rows
                .nodes
                .iter()
                .map(|&n| self.solution.displacements[n as usize]),
        );
        self.local.reactions.clear();
        self.local.reactions.extend_from_slice(&self.node_reaction);
        self.update_support_reactions();
        Ok(&self.solution)
    }

    /// Support reactions of the solution (they need every node's
    /// displacement: empty unless every node is recovered).
    fn update_support_reactions(&mut self) {
        self.support_reactions.clear();
        if self.rec_nodes.len() == self.model.n_nodes() {
            self.support_reactions
                .resize(self.model.fixed.len(), Vector3::zeros());
            for &e in &self.support_elems {
                let t = &self.model.tets[e];
                let mut ue = nalgebra::SVector::<f64, 12>::zeros();
                for a in 0..4 {
                    ue.fixed_rows_mut::<3>(3 * a)
                        .copy_from(&self.solution.displacements[t[a] as usize]);
                }
                let fe = self.model.kel[e] * ue;
                for a in 0..4 {
                    let fi = self.fixed_index[t[a] as usize];
                    if fi != NONE {
                        self.support_reactions[fi as usize] += fe.fixed_rows::<3>(3 * a);
                    }
                }
            }
            if let Some(p) = &self.model.pressure {
                let (index, out) = (&self.fixed_index, &mut self.support_reactions);
                p.for_each_force(
                    self.support_stars.iter().copied(),
                    &self.solution.displacements,
                    |b, f| {
                        let fi = index[b as usize];
                        if fi != NONE {
                            out[fi as usize] += f;
                        }
                    },
                );
            }
        }
    }

    /// Prepares a step (for a caller that applies the constrained inverse
    /// repeatedly, see [`Compliance::constrained_solve`]).
    pub(crate) fn prepare_constraints<C: Into<Constraint> + Copy>(
        &mut self,
        cons: &[C],
    ) -> Result<(), SolveError> {
        self.prepare(cons)
    }

    /// Rows of the prepared step.
    pub(crate) fn step_rows(&self) -> &StepRows {
        &self.rows
    }

    /// Applies the inverse of the supported stiffness restricted to the
    /// subspace where the prepared rows vanish: `z = K0^-1 b - K0^-1 G^T C^-1
    /// G K0^-1 b`, in place on a full DOF vector (requires [`Recover::All`]).
    /// After [`Compliance::keep_single`] the sparse solves run in single
    /// precision: then `z` is that operator to about `cond(K0) x 6e-8`
    /// (relative), and `G z` vanishes to that accuracy only (a
    /// preconditioner; the caller projects).
    pub(crate) fn constrained_solve(&mut self, b: &mut [f64]) {
        debug_assert!(self.prepared && self.rec_nodes.len() == self.model.n_nodes());
        if self.factor.has_single() {
            self.factor.solve_single(b);
        } else {
            self.factor.solve(b);
        }
        let k = self.rows.rows.len();
        for (t, r) in self.tmp_rows[..k].iter_mut().zip(&self.rows.rows) {
            *t = r.dir.dot(&node_vec(b, r.node as usize));
        }
        Self::block_solve(&self.cmat, &mut self.chol_buf, &mut self.tmp_rows[..k]);
        let ns = self.rows.nodes.len();
        self.node_reaction.clear();
        self.node_reaction.resize(ns, Vector3::zeros());
        for (r, l) in self.rows.rows.iter().zip(&self.tmp_rows[..k]) {
            self.node_reaction[self.rows.slot[r.node as usize] as usize] += r.dir * *l;
        }
        let nr = std::mem::take(&mut self.node_reaction);
        self.add_response(&nr, -1.0, b, true);
        self.node_reaction = nr;
    }

    /// Adds to `u` (full DOF vector) the linear response that closes the gap
    /// of the prepared rows: `K0^-1 G^T C^-1 (g - G u)` (requires
    /// [`Recover::All`]).
    pub(crate) fn lift(&mut self, u: &mut [f64]) {
        debug_assert!(self.prepared && self.rec_nodes.len() == self.model.n_nodes());
        let k = self.rows.rows.len();
        for (t, r) in self.tmp_rows[..k].iter_mut().zip(&self.rows.rows) {
            *t = r.value - r.dir.dot(&node_vec(u, r.node as usize));
        }
        Self::block_solve(&self.cmat, &mut self.chol_buf, &mut self.tmp_rows[..k]);
        let ns = self.rows.nodes.len();
        self.node_reaction.clear();
        self.node_reaction.resize(ns, Vector3::zeros());
        for (r, l) in self.rows.rows.iter().zip(&self.tmp_rows[..k]) {
            self.node_reaction[self.rows.slot[r.node as usize] as usize] += r.dir * *l;
        }
        let nr = std::mem::take(&mut self.node_reaction);
        self.add_response(&nr, 1.0, u, false);
        self.node_reaction = nr;
    }
}

impl Compliance {
    /// The Delassus solve of a contact problem ([`super::contact`],
    /// [`super::lcp`]): `W = H C H^T` from the cached columns, the
    /// complementarity problem, then `u = C H^T lambda`.
    fn contact_solve(
        &mut self,
        rows: &[ContactRow],
        answer: &mut ContactAnswer,
    ) -> Result<(), SolveError> {
        let n_nodes = self.model.n_nodes();
        contact::validate_rows(rows, n_nodes, true)?;
        for (i, r) in rows.iter().enumerate() {
            for (n, _) in r.nodes() {
                let b = 3 * n as usize;
                if self.model.support[b..b + 3].iter().any(|&f| f) {
                    return Err(SolveError::BadConstraint {
                        node: n,
                        reason: format!("contact row {i}: the node is a fixed support"),
                    });
                }
                if self.rec_of[n as usize] == NONE {
                    return Err(SolveError::BadConstraint {
                        node: n,
                        reason: format!(
                            "contact row {i}: the node is not among the recovered nodes of this compliance solver"
                        ),
                    });
                }
            }
        }
        for &n in &self.c_nodes {
            self.c_slot[n as usize] = NONE;
        }
        self.c_nodes.clear();
        for r in rows {
            for (n, _) in r.nodes() {
                if self.c_slot[n as usize] == NONE {
                    self.c_slot[n as usize] = self.c_nodes.len() as u32;
                    self.c_nodes.push(n);
                }
            }
        }
        self.stamp += 1;
        // Rows along a held direction need no column.
        let mut want = std::mem::take(&mut self.want);
        want.clear();
        for r in rows {
            if self.held_row(r).is_none() {
                want.extend(r.nodes().map(|(n, _)| n));
            }
        }
        self.use_columns(&want, self.policy, Urgency::Row);
        self.want = want;
        // Rows whose nodes all have their columns take part; the others wait.
        // Rows with their own compliance (ties) come first: they are the same
        // rows from one solve to the next, so the rows of `W` and the place
        // in the solver's factor that the last solve gave its leading rows
        // are kept while those rows are unchanged (`kept`), and only the
        // rows after them are computed again.
        answer.pending.clear();
        self.inc.clear();
        self.inc_of.clear();
        self.inc_of.resize(rows.len(), NONE);
        for pass in [true, false] {
            for (i, r) in rows.iter().enumerate() {
                if (r.compliance_m_per_n > 0.0) != pass {
                    continue;
                }
                if self.held_row(r).is_none()
                    && r.nodes().any(|(n, _)| self.cache_slot[n as usize] == NONE)
                {
                    answer.pending.push(i as u32);
                    continue;
                }
                self.inc_of[i] = self.inc.len() as u32;
                self.inc.push(i);
            }
        }
        answer.pending.sort_unstable();
        let n = self.inc.len();
        let old_n = self.w_sig.len();
        let mut kept = 0;
        while kept < n.min(old_n) && self.w_sig[kept] == RowSig::of(&rows[self.inc[kept]]) {
            kept += 1;
        }
        if n > self.w_stride {
            let stride = n.max(2 * self.w_stride);
            let mut w = vec![0.0; stride * stride];
            for a in 0..kept {
                w[a * stride..a * stride + kept]
                    .copy_from_slice(&self.w[a * self.w_stride..a * self.w_stride + kept]);
            }
            self.w = w;
            self.w_stride = stride;
        }
        let stride = self.w_stride;
        // A kept row whose own compliance changed (a pair of ties lost one)
        // keeps its off-diagonal entries.
        for a in 0..kept {
            let c = rows[self.inc[a]].compliance_m_per_n;
            if c != self.w_c[a] {
                self.w[a * stride + a] += c - self.w_c[a];
                self.lcp.changed(a);
            }
        }
        for a in kept..n.max(old_n) {
            self.lcp.changed(a);
        }
        self.w_sig.truncate(kept);
        self.w_c.truncate(kept);
        for a in kept..n {
            let ra = &rows[self.inc[a]];
            for c in 0..=a {
                let rc = &rows[self.inc[c]];
                let v = self.row_pair(ra, rc);
                self.w[a * stride + c] = v;
                self.w[c * stride + a] = v;
            }
            // A row's own compliance (a tie's spring): `W + diag(c)`.
            self.w[a * stride + a] += ra.compliance_m_per_n;
            self.w_sig.push(RowSig::of(ra));
        }
        self.w_c.clear();
        self.w_c
            .extend(self.inc.iter().map(|&i| rows[i].compliance_m_per_n));
        self.q.clear();
        self.kinds.clear();
        self.lam.clear();
        let warm = answer.multipliers.len() == rows.len();
        for &i in &self.inc {
            let r = &rows[i];
            self.q.push(r.gap_free_m);
            self.kinds.push(match r.kind {
                RowKind::Tangent { normal, mu } => RowKind::Tangent {
                    normal: self.inc_of[normal as usize],
                    mu,
                },
                k => k,
            });
            self.lam
                .push(if warm { answer.multipliers[i] } else { 0.0 });
        }
        let tol = Tolerances::for_gaps(&self.q, &self.kinds);
        let report = match self.lcp.solve(
            &self.w,
            stride,
            n,
            &self.q,
            &self.kinds,
            &mut self.lam,
            &tol,
        ) {
            Ok(r) => r,
            Err(e) => {
                // Nothing of a failed solve is kept.
                self.lcp.forget();
                self.w_sig.clear();
                self.w_c.clear();
                return Err(e.into());
            }
        };
        // Node forces and the response.
        self.c_force.clear();
        self.c_force.resize(self.c_nodes.len(), Vector3::zeros());
        for (a, &i) in self.inc.iter().enumerate() {
            let r = &rows[i];
            for (nd, w) in r.nodes() {
                self.c_force[self.c_slot[nd as usize] as usize] += r.dir * (w * self.lam[a]);
            }
        }
        let mut u = std::mem::take(&mut self.u_rec);
        u.fill(0.0);
        let (nodes, force) = (
            std::mem::take(&mut self.c_nodes),
            std::mem::take(&mut self.c_force),
        );
        // Forces at held nodes without columns: the whole response by one
        // sparse solve (exact; pending nodes carry no force).
        let zero = Vector3::zeros();
        let by_solve = nodes
            .iter()
            .zip(&force)
            .any(|(n, f)| self.cache_slot[*n as usize] == NONE && *f != zero);
        if by_solve {
            self.held_rhs.fill(0.0);
            for (&n, f) in nodes.iter().zip(&force) {
                let b = 3 * n as usize;
                for a in 0..3 {
                    self.held_rhs[b + a] += f[a];
                }
            }
            self.factor.solve(&mut self.held_rhs);
            for (i, &nd) in self.rec_nodes.iter().enumerate() {
                let b = 3 * nd as usize;
                u[3 * i..3 * i + 3].copy_from_slice(&self.held_rhs[b..b + 3]);
            }
        } else {
            // Pending nodes have no columns: they carry no force.
            let cached: Vec<(u32, Vector3<f64>)> = nodes
                .iter()
                .zip(&force)
                .filter(|(n, _)| self.cache_slot[**n as usize] != NONE)
                .map(|(n, f)| (*n, *f))
                .collect();
            let (cn, cf): (Vec<u32>, Vec<Vector3<f64>>) = cached.into_iter().unzip();
            self.add_response_at(&cn, &cf, 1.0, &mut u, false);
        }
        self.c_nodes = nodes;
        self.c_force = force;
        if !u.iter().all(|v| v.is_finite()) {
            self.u_rec = u;
            return Err(SolveError::NonFinite("recovered displacement".into()));
        }
        self.u_rec = u;
        for (i, &nd) in self.rec_nodes.iter().enumerate() {
            self.solution.displacements[nd as usize] = node_vec(&self.u_rec, i);
        }
        answer.multipliers.clear();
        answer.multipliers.resize(rows.len(), 0.0);
        self.solution.reactions.clear();
        self.solution.reactions.resize(rows.len(), Vector3::zeros());
        for (a, &i) in self.inc.iter().enumerate() {
            answer.multipliers[i] = self.lam[a];
            self.solution.reactions[i] = rows[i].dir * self.lam[a];
        }
        answer.report = report;
        answer.rounds = 1;
        self.solution.iterations = 1;
        self.update_support_reactions();
        Ok(())
    }

    /// Builds the shared blocks of the declared nodes
    /// ([`DeformationSolver::share_patch_nodes`]) once all of them have
    /// columns (asked by the column policy until then).
    fn build_shared(&mut self) {
        if self.shared.is_some() || self.share.is_empty() {
            return;
        }
        let nodes = std::mem::take(&mut self.share);
        // Under the patch's stamp: the patch's own columns stay.
        self.use_columns(&nodes, self.policy, Urgency::Patch);
        if nodes.iter().all(|&n| self.cache_slot[n as usize] != NONE) {
            let s = nodes.len();
            let s3 = 3 * s;
            let mut blocks = vec![0.0; s3 * s3];
            for i in 0..s {
                for j in 0..=i {
                    let b = self.block(nodes[i], nodes[j]);
                    for a in 0..3 {
                        for c in 0..3 {
                            blocks[(3 * i + a) * s3 + 3 * j + c] = b[(a, c)];
                            blocks[(3 * j + c) * s3 + 3 * i + a] = b[(a, c)];
                        }
                    }
                }
            }
            self.shared = Some(Arc::new(SharedBlocks {
                nodes: nodes.clone(),
                blocks,
            }));
        }
        self.share = nodes;
    }

    /// The compliance blocks over `nodes` ([`CompliancePatch`]); nodes
    /// without columns are computed or left out by the column policy.
    fn patch(&mut self, nodes: &[u32], patch: &mut CompliancePatch) {
        self.stamp += 1;
        let mut distinct: Vec<u32> = Vec::with_capacity(nodes.len());
        for &n in nodes {
            if (n as usize) < self.model.n_nodes()
                && self.rec_of[n as usize] != NONE
                && !self.listed[n as usize]
            {
                self.listed[n as usize] = true;
                distinct.push(n);
            }
        }
        for &n in &distinct {
            self.listed[n as usize] = false;
        }
        // Held nodes take part without columns (rows along their
        // directions only; `patch.axes`).
        let mut want = std::mem::take(&mut self.want);
        want.clear();
        want.extend(
            distinct
                .iter()
                .copied()
                .filter(|&n| self.held.as_ref().is_none_or(|h| h.index_of(n).is_none())),
        );
        self.use_columns(&want, self.policy, Urgency::Patch);
        self.want = want;
        self.build_shared();
        patch.nodes.clear();
        patch.shared = self.shared.clone();
        if let Some(sh) = &self.shared {
            patch.nodes.extend_from_slice(&sh.nodes);
        }
        let s = patch.nodes.len();
        let held = |n: u32| self.held.as_ref().and_then(|h| h.index_of(n));
        for &n in &distinct {
            if (self.cache_slot[n as usize] != NONE || held(n).is_some())
                && !(s > 0 && self.is_shared[n as usize])
            {
                patch.nodes.push(n);
            }
        }
        patch.axes.clear();
        patch.axes.extend(patch.nodes.iter().map(|&n| {
            match (self.cache_slot[n as usize], held(n), &self.held) {
                (NONE, Some(k), Some(h)) => h.normals[k],
                _ => Vector3::zeros(),
            }
        }));
        let m = patch.nodes.len();
        let m3 = 3 * m;
        patch.blocks.clear();
        patch.blocks.resize(3 * (m - s) * m3, 0.0);
        // Rows of the other nodes (cached) against every node: `C[i][j] =
        // C[j][i]^T`, read from node `i`'s column.
        for i in s..m {
            let r = 3 * (i - s);
            for j in 0..m {
                if j >= s && j > i {
                    continue;
                }
                let b = self.any_block(patch.nodes[j], patch.nodes[i]);
                for a in 0..3 {
                    for c in 0..3 {
                        patch.blocks[(r + a) * m3 + 3 * j + c] = b[(c, a)];
                        if j >= s {
                            patch.blocks[(3 * (j - s) + c) * m3 + 3 * i + a] = b[(c, a)];
                        }
                    }
                }
            }
        }
        patch.free_positions.clear();
        patch
            .free_positions
            .extend(patch.nodes.iter().map(|&n| self.model.rest[n as usize]));
        patch.linear = true;
    }
}

/// The `compliance` strategy ([`super::StrategyKind`]).
pub const KIND: super::StrategyKind = super::StrategyKind {
    name: "compliance",
    label: "lin",
    linear: true,
    material_model: "linear",
    build: |model, options| {
        // The skull tests every surface node each round
        // (`skull::SkullSolver`): a narrower recovery gives it the surface.
        let recover = if options.skull.is_some() && options.recover != Recover::All {
            Recover::Surface
        } else {
            options.recover.clone()
        };
        let mut c = Compliance::new(model, recover)?;
        c.set_parallelism(options.parallelism);
        if let Some(n) = options.cache_nodes {
            c.set_cache_limit(n);
        }
        Ok(Box::new(c))
    },
};

impl DeformationSolver for Compliance {
    fn name(&self) -> &'static str {
        KIND.name
    }

    fn cache_bytes(&self) -> usize {
        // The length, not the capacity: growth writes the new slots' zeros,
        // so what is resident is what is in use.
        let words = self.cols.len() * std::mem::size_of::<f64>();
        words + self.slot_node.len() * 4 + self.slot_stamp.len() * 8
    }

    fn solve(&mut self, prescribed: &[Prescribed]) -> Result<&Solution, SolveError> {
        self.prepare(prescribed)?;
        self.finish_step()
    }

    fn solve_constraints(&mut self, constraints: &[Constraint]) -> Result<&Solution, SolveError> {
        self.prepare(constraints)?;
        self.finish_step()
    }

    fn local_model(&self) -> Option<&LocalModel> {
        Some(&self.local)
    }

    fn support_reactions(&self) -> &[Vector3<f64>] {
        &self.support_reactions
    }

    fn last_solution(&self) -> Option<&Solution> {
        Some(&self.solution)
    }

    fn node_count(&self) -> usize {
        self.model.n_nodes()
    }

    fn solve_contact(
        &mut self,
        rows: &[ContactRow],
        answer: &mut ContactAnswer,
    ) -> Result<(), SolveError> {
        self.contact_solve(rows, answer)
    }

    fn share_patch_nodes(&mut self, nodes: &[u32]) {
        for &n in &self.share {
            self.is_shared[n as usize] = false;
        }
        self.shared = None;
        self.share.clear();
        for &n in nodes {
            let nu = n as usize;
            if nu < self.model.n_nodes()
                && self.rec_of[nu] != NONE
                && !self.model.support[3 * nu..3 * nu + 3].iter().any(|&f| f)
                && !self.is_shared[nu]
            {
                self.is_shared[nu] = true;
                self.share.push(n);
            }
        }
    }

    fn compliance_patch(&mut self, nodes: &[u32], patch: &mut CompliancePatch) -> bool {
        self.patch(nodes, patch);
        true
    }

    fn set_column_policy(
        &mut self,
        policy: ColumnPolicy,
        hook: Option<Arc<dyn Fn() + Send + Sync>>,
    ) {
        Compliance::set_column_policy(self, policy, hook);
    }

    fn hold_normals(&mut self, nodes: &[(u32, Vector3<f64>)]) -> Result<bool, SolveError> {
        Compliance::hold_normals(self, nodes)?;
        Ok(true)
    }

    fn held_bytes(&self) -> usize {
        Compliance::held_bytes(self)
    }

    fn columns_solved(&self) -> u64 {
        Compliance::columns_solved(self)
    }

    fn prefetch(&mut self, nodes: &[u32]) {
        if self.policy == ColumnPolicy::Defer {
            self.receive_columns();
            let nodes: Vec<u32> = nodes
                .iter()
                .copied()
                .filter(|&n| (n as usize) < self.model.n_nodes() && self.rec_of[n as usize] != NONE)
                .collect();
            self.ask(&nodes, Urgency::Ahead);
        }
    }
}
