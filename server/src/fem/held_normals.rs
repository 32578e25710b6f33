//! The normal compliance of a fixed set of nodes that only ever meet contact
//! along one known direction each (the rigid skull surface's supported
//! nodes, [`super::skull::SkullSurface`]), computed once and held.
//!
//! Method: for each held node `l` with unit direction `n_l`, one sparse
//! solve `x_l = K0^-1 (n_l e_l)` (a right-hand side per node, solved in
//! batches of [`BATCH`] right-hand sides on the shared factor, the batches
//! spread over the caller's [`Par`]); of `x_l` only the normal components
//! at the held nodes are kept, `N[k][l] = n_k . x_l[node_k]` (m/N). `N` is
//! the symmetric `S x S` matrix of `n_k^T C[k][l] n_l` with `C = K0^-1`:
//! exactly the entries of the Delassus operator `W` between two rows along
//! the held directions, so those rows need no column of `K0^-1` at all.
//! Memory: `8 S^2` bytes (S held nodes), against `72 S R` bytes for the
//! three full columns per node over `R` recovered nodes; time: `S` solves
//! with one right-hand side each instead of `3 S`.
//!
//! Why not the full columns: on the 12.3k-node `paper-48k` phantom the
//! skull surface supports about 6k nodes, whose three columns over every
//! node take 5.3 GB, ten times the column cache's default bound; `N` takes
//! 0.3 GB. The response of the held nodes' forces is one sparse solve
//! instead ([`super::compliance`]).

use super::factor::SharedFactor;
use super::par::Par;
use nalgebra::Vector3;
use rayon::prelude::*;
use std::time::Instant;

/// Right-hand sides per sparse solve (a batch's dense block is
/// `8 x BATCH x DOFs` bytes: 24 MB on the 12.3k-node phantom).
pub const BATCH: usize = 64;

/// [`HeldNormals::index`]: not held.
const NONE: u32 = u32::MAX;

/// The held nodes, their directions and `N` (see the module documentation).
#[derive(Debug, Clone, Default)]
pub struct HeldNormals {
    /// The held nodes, in the order of `N`.
    pub nodes: Vec<u32>,
    /// Each held node's unit direction.
    pub normals: Vec<Vector3<f64>>,
    /// Per model node: its index among [`Self::nodes`], or `u32::MAX`.
    index: Vec<u32>,
    /// `N`, `S x S`, column `l` at `l * S` (symmetric up to round-off).
    n: Vec<f64>,
}

impl HeldNormals {
    /// Solves for `N` over `nodes` (volume node and unit direction; a node
    /// listed twice keeps its first direction) with `factor` of a
    /// stiffness over `n_nodes` nodes. Logs its progress (tracing, `info`)
    /// every tenth of the nodes.
    pub fn compute(
        factor: &SharedFactor,
        n_nodes: usize,
        nodes: &[(u32, Vector3<f64>)],
        par: Par,
    ) -> Self {
        let mut index = vec![NONE; n_nodes];
        let mut held = Vec::with_capacity(nodes.len());
        let mut normals = Vec::with_capacity(nodes.len());
        for &(v, d) in nodes {
            if (v as usize) < n_nodes && index[v as usize] == NONE {
                index[v as usize] = held.len() as u32;
                held.push(v);
                normals.push(d);
            }
        }
        let s = held.len();
        let mut n = vec![0.0; s * s];
        let start = Instant::now();
        let done = std::sync::atomic::AtomicUsize::new(0);
        let tenth = s.div_ceil(10).max(1);
        let n_dofs = factor.nrows();
        let batch = |first: usize, out: &mut [f64]| {
            let cols = out.len() / s.max(1);
            let mut block = vec![0.0; n_dofs * cols];
            for c in 0..cols {
                let l = first + c;
                let b = 3 * held[l] as usize;
                for a in 0..3 {
                    block[c * n_dofs + b + a] = normals[l][a];
                }
            }
            factor.solve_many(&mut block, cols);
            for c in 0..cols {
                let x = &block[c * n_dofs..(c + 1) * n_dofs];
                for (k, (&v, nk)) in held.iter().zip(&normals).enumerate() {
                    let b = 3 * v as usize;
                    out[c * s + k] = nk.x * x[b] + nk.y * x[b + 1] + nk.z * x[b + 2];
                }
            }
            let before = done.fetch_add(cols, std::sync::atomic::Ordering::Relaxed);
            if (before + cols) / tenth != before / tenth {
                tracing::info!(
                    done = before + cols,
                    nodes = s,
                    elapsed_s = start.elapsed().as_secs_f64(),
                    "skull compliance"
                );
            }
        };
        if s > 0 {
            match par {
                Par::Seq => {
                    for (i, out) in n.chunks_mut(BATCH * s).enumerate() {
                        batch(i * BATCH, out);
                    }
                }
                Par::Rayon(_) => {
                    n.par_chunks_mut(BATCH * s)
                        .enumerate()
                        .for_each(|(i, out)| batch(i * BATCH, out));
                }
            }
        }
        Self {
            nodes: held,
            normals,
            index,
            n,
        }
    }

    /// Number of held nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// Whether no node is held.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Bytes held (`N` and the per-node index).
    pub fn bytes(&self) -> usize {
        8 * self.n.len() + 4 * self.index.len() + 28 * self.nodes.len()
    }

    /// Index of `node` among the held nodes.
    #[inline]
    pub fn index_of(&self, node: u32) -> Option<usize> {
        match self.index.get(node as usize) {
            Some(&k) if k != NONE => Some(k as usize),
            _ => None,
        }
    }

    /// `N[k][l] = n_k^T C[k][l] n_l`, m/N (held indices).
    #[inline]
    pub fn entry(&self, k: usize, l: usize) -> f64 {
        self.n[l * self.nodes.len() + k]
    }

    /// The held index of a single-node direction `d` (weight included) at
    /// `node` along its held direction, and `d . n`: `Some` when `node` is
    /// held and `d` is parallel to its direction to 1e-12 of `|d|`.
    #[inline]
    pub fn along(&self, node: u32, d: &Vector3<f64>) -> Option<(usize, f64)> {
        let k = self.index_of(node)?;
        let n = self.normals[k];
        let s = d.dot(&n);
        ((d - n * s).norm() <= 1e-12 * d.norm()).then_some((k, s))
    }
}
