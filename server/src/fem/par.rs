//! Caller-chosen parallelism of the per-element and per-node loops, in the
//! style of faer: [`Par::Seq`] runs on the calling thread, `Par::Rayon(n)`
//! splits a loop into about `4 n` chunks on the current rayon pool (the
//! global one unless the caller installs its own).
//!
//! Results do not depend on the choice: every loop writes disjoint outputs
//! (per element, then per node through [`NodeGather`]), and no reduction is
//! reordered, so `Seq` and `Rayon(n)` give bitwise the same numbers.

pub use faer::Par;
use rayon::prelude::*;

/// The default of the solvers: every thread of the current rayon pool.
pub fn default_par() -> Par {
    Par::rayon(0)
}

/// Chunk length: a multiple of `unit`, at least `min` units.
fn chunk_len(par: Par, len: usize, unit: usize, min: usize) -> usize {
    let units = len.div_ceil(unit);
    let per = match par {
        Par::Seq => units,
        Par::Rayon(n) => units.div_ceil(4 * n.get()).max(min),
    };
    unit * per.max(1)
}

/// Calls `f(first_index, chunk)` on disjoint chunks of `data` covering it,
/// in parallel under `Par::Rayon`. Chunk lengths are multiples of `unit`
/// (`data.len()` should be one too); `min` units is the smallest chunk
/// worth a task.
pub fn for_each_chunk<T: Send>(
    par: Par,
    data: &mut [T],
    unit: usize,
    min: usize,
    f: impl Fn(usize, &mut [T]) + Sync + Send,
) {
    let len = chunk_len(par, data.len(), unit, min);
    match par {
        Par::Seq => {
            if !data.is_empty() {
                f(0, data);
            }
        }
        Par::Rayon(_) => data
            .par_chunks_mut(len)
            .enumerate()
            .for_each(|(i, c)| f(i * len, c)),
    }
}

/// Like [`for_each_chunk`] over two slices split at the same item
/// boundaries, where `f` may report a failure at an index (the failure with
/// the smallest index is returned, the same under any `par`): item `i` owns `a[i * ua .. (i + 1) * ua]` and
/// `b[i * ub .. (i + 1) * ub]`; `f(first_item, a_chunk, b_chunk)`.
pub fn try_for_each_chunk_pair<A: Send, B: Send, E: Send>(
    par: Par,
    a: &mut [A],
    ua: usize,
    b: &mut [B],
    ub: usize,
    min: usize,
    f: impl Fn(usize, &mut [A], &mut [B]) -> Option<(usize, E)> + Sync + Send,
) -> Option<(usize, E)> {
    let items = a.len() / ua.max(1);
    debug_assert_eq!(items * ub, b.len());
    let per = chunk_len(par, items, 1, min);
    match par {
        Par::Seq => {
            if items == 0 {
                None
            } else {
                f(0, a, b)
            }
        }
        Par::Rayon(_) => a
            .par_chunks_mut(per * ua)
            .zip(b.par_chunks_mut(per * ub))
            .enumerate()
            .filter_map(|(i, (ca, cb))| f(i * per, ca, cb))
            .min_by_key(|(i, _)| *i),
    }
}

/// Node-to-element incidence, for summing per-element 12-vectors into a
/// global DOF vector without write conflicts: node `n` reads the entries
/// `12 e + 3 a .. 12 e + 3 a + 3` for each `(e, a)` with `tets[e][a] == n`.
#[derive(Debug, Clone)]
pub struct NodeGather {
    start: Vec<u32>,
    entries: Vec<u32>,
}

impl NodeGather {
    /// Incidence of `tets` over `n_nodes` nodes.
    pub fn new(n_nodes: usize, tets: &[[u32; 4]]) -> Self {
        let mut start = vec![0u32; n_nodes + 1];
        for t in tets {
            for &n in t {
                start[n as usize + 1] += 1;
            }
        }
        for i in 0..n_nodes {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut entries = vec![0u32; 4 * tets.len()];
        for (e, t) in tets.iter().enumerate() {
            for (a, &n) in t.iter().enumerate() {
                entries[fill[n as usize] as usize] = (12 * e + 3 * a) as u32;
                fill[n as usize] += 1;
            }
        }
        Self { start, entries }
    }

    /// `y[node] = sum of its element entries` of `elem` (12 values per
    /// element), over all nodes; entries are summed in element order.
    pub fn gather(&self, par: Par, elem: &[f64], y: &mut [f64]) {
        for_each_chunk(par, y, 3, 256, |first, out| {
            let n0 = first / 3;
            for (k, o) in out.chunks_exact_mut(3).enumerate() {
                let n = n0 + k;
                let mut acc = [0.0; 3];
                for &p in &self.entries[self.start[n] as usize..self.start[n + 1] as usize] {
                    let p = p as usize;
                    acc[0] += elem[p];
                    acc[1] += elem[p + 1];
                    acc[2] += elem[p + 2];
                }
                o.copy_from_slice(&acc);
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::blocks::cube;

    #[test]
    fn gather_equals_scatter_and_par_is_bitwise_seq() {
        let mesh = cube(0.01, 4);
        let g = NodeGather::new(mesh.nodes.len(), &mesh.tets);
        let elem: Vec<f64> = (0..12 * mesh.tets.len())
            .map(|i| ((i * 7919) % 101) as f64 * 0.013 - 0.6)
            .collect();
        let mut want = vec![0.0; 3 * mesh.nodes.len()];
        for (e, t) in mesh.tets.iter().enumerate() {
            for (a, &n) in t.iter().enumerate() {
                for i in 0..3 {
                    want[3 * n as usize + i] += elem[12 * e + 3 * a + i];
                }
            }
        }
        let mut seq = vec![0.0; want.len()];
        let mut par = vec![1.0; want.len()];
        g.gather(Par::Seq, &elem, &mut seq);
        g.gather(Par::rayon(3), &elem, &mut par);
        assert_eq!(seq, par);
        for (a, b) in seq.iter().zip(&want) {
            assert!((a - b).abs() < 1e-12);
        }
    }
}
