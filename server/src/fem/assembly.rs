//! Sparse assembly of the global stiffness: a sparsity pattern computed once per
//! mesh (lower triangle, compressed sparse columns, the storage faer's sparse
//! Cholesky reads with `Side::Lower`) and an element -> nonzero scatter map, so
//! that re-assembling values each step allocates nothing.
//!
//! Global DOF of node `n` along axis `i` is `3 n + i`.
//!
//! The groups a pattern may couple beyond the elements (the stars of the
//! nodal-pressure element) get a scatter map too, one value index per node
//! pair ([`Pattern::group_pairs`]): their rank-one matrices are scattered
//! every Newton iteration, and a binary search of the column per entry cost
//! more than the arithmetic.

use super::element::ElementMatrix;
use faer::sparse::SymbolicSparseColMatRef;
use nalgebra::Vector3;

/// The 78 local pairs `(p, q)`, `p <= q`, of a 12 x 12 element matrix.
pub const LOCAL_PAIRS: [(u8, u8); 78] = {
    let mut out = [(0u8, 0u8); 78];
    let mut k = 0;
    let mut p = 0;
    while p < 12 {
        let mut q = p;
        while q < 12 {
            out[k] = (p as u8, q as u8);
            k += 1;
            q += 1;
        }
        p += 1;
    }
    out
};

/// Lower-triangular CSC pattern of the 3n x 3n stiffness of a tet mesh.
#[derive(Debug, Clone)]
pub struct Pattern {
    /// Number of DOFs (3 x nodes).
    pub n_dofs: usize,
    /// Column pointers (length `n_dofs + 1`).
    pub col_ptr: Vec<usize>,
    /// Row indices, sorted within each column, all `>=` the column.
    pub row_idx: Vec<usize>,
    /// Index of the diagonal entry of each column.
    pub diag: Vec<usize>,
    /// Per element, the value index of each pair of [`LOCAL_PAIRS`].
    pub scatter: Vec<[u32; 78]>,
    /// Per group of [`Pattern::with_groups`], the range of its node pairs
    /// in `group_pair_index` (length groups + 1).
    group_start: Vec<usize>,
    /// Per group with sorted nodes `n_0 < n_1 < ...`, for each pair `k < l`
    /// (`k` ascending, then `l`), the value index of entry `(3 n_l, 3 n_k)`
    /// ([`Pattern::group_pairs`]).
    group_pair_index: Vec<u32>,
}

impl Pattern {
    /// Builds the pattern of a mesh with `n_nodes` nodes and tetrahedra `tets`
    /// (indices already validated). Every DOF has a diagonal entry.
    pub fn new(n_nodes: usize, tets: &[[u32; 4]]) -> Self {
        Self::with_groups(n_nodes, tets, std::iter::empty())
    }

    /// The pattern of [`Pattern::new`] widened to couple every pair of nodes
    /// within each of `groups` too (the stars of
    /// [`super::nodal_pressure::NodalPressure`], each sorted ascending); the
    /// element scatter map is the same, and each group gets its pairs' map
    /// ([`Pattern::group_pairs`]).
    pub fn with_groups<'a>(
        n_nodes: usize,
        tets: &[[u32; 4]],
        groups: impl Iterator<Item = &'a [u32]> + Clone,
    ) -> Self {
        Self::coupled(n_nodes, tets, groups, &[])
    }

    /// The pattern of the elements `tets`, the sorted `groups` and the node
    /// `pairs` (see [`Pattern::with_groups`], [`Pattern::with_pairs`]).
    fn coupled<'a>(
        n_nodes: usize,
        tets: &[[u32; 4]],
        groups: impl Iterator<Item = &'a [u32]> + Clone,
        pairs: &[[u32; 2]],
    ) -> Self {
        // Node adjacency (j >= i), sorted and deduplicated.
        let mut adj: Vec<Vec<u32>> = (0..n_nodes).map(|i| vec![i as u32]).collect();
        let mut couple = |group: &[u32]| {
            for &a in group {
                for &b in group {
                    if b > a {
                        adj[a as usize].push(b);
                    }
                }
            }
        };
        for t in tets {
            couple(t);
        }
        for g in groups.clone() {
            couple(g);
        }
        for p in pairs {
            couple(p);
        }
        for a in &mut adj {
            a.sort_unstable();
            a.dedup();
        }
        let n_dofs = 3 * n_nodes;
        let mut col_ptr = Vec::with_capacity(n_dofs + 1);
        let mut row_idx = Vec::new();
        let mut diag = Vec::with_capacity(n_dofs);
        col_ptr.push(0);
        for (i, a) in adj.iter().enumerate() {
            for ci in 0..3 {
                let c = 3 * i + ci;
                diag.push(row_idx.len());
                for &j in a {
                    for rj in 0..3 {
                        let r = 3 * j as usize + rj;
                        if r >= c {
                            row_idx.push(r);
                        }
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        let mut pattern = Self {
            n_dofs,
            col_ptr,
            row_idx,
            diag,
            scatter: Vec::new(),
            group_start: vec![0],
            group_pair_index: Vec::new(),
        };
        pattern.scatter = tets.iter().map(|t| pattern.scatter_of(t)).collect();
        for g in groups {
            assert!(
                g.windows(2).all(|w| w[0] < w[1]),
                "a coupled group's nodes are sorted and distinct"
            );
            for (k, &a) in g.iter().enumerate() {
                for &b in &g[k + 1..] {
                    let idx = pattern.index(3 * b as usize, 3 * a as usize) as u32;
                    pattern.group_pair_index.push(idx);
                }
            }
            pattern.group_start.push(pattern.group_pair_index.len());
        }
        pattern
    }

    /// The pattern of [`Pattern::new`] widened to couple each node pair of
    /// `pairs` (the ties' pairs of a nonlinear strategy,
    /// [`super::ties::TieSprings`]), with a scatter map per pair after the
    /// elements': pair `i` is the pseudo-element `tets.len() + i` on the
    /// nodes `[a, b, a, b]`, so that its tangent goes through the element
    /// path (node bases, elimination) unchanged.
    pub fn with_pairs(n_nodes: usize, tets: &[[u32; 4]], pairs: &[[u32; 2]]) -> Self {
        Self::with_groups_and_pairs(n_nodes, tets, std::iter::empty(), pairs)
    }

    /// [`Pattern::with_groups`] and [`Pattern::with_pairs`] at once: the
    /// stars of the nodal-pressure element and the ties' pairs.
    pub fn with_groups_and_pairs<'a>(
        n_nodes: usize,
        tets: &[[u32; 4]],
        groups: impl Iterator<Item = &'a [u32]> + Clone,
        pairs: &[[u32; 2]],
    ) -> Self {
        let mut pattern = Self::coupled(n_nodes, tets, groups, pairs);
        let extra: Vec<[u32; 78]> = pairs
            .iter()
            .map(|&[a, b]| pattern.scatter_of(&[a, b, a, b]))
            .collect();
        pattern.scatter.extend(extra);
        pattern
    }

    /// The value index of each pair of [`LOCAL_PAIRS`] of the element on
    /// nodes `t` (every pair of them coupled in the pattern).
    fn scatter_of(&self, t: &[u32; 4]) -> [u32; 78] {
        let mut s = [0u32; 78];
        for (k, &(p, q)) in LOCAL_PAIRS.iter().enumerate() {
            let gp = 3 * t[p as usize / 3] as usize + p as usize % 3;
            let gq = 3 * t[q as usize / 3] as usize + q as usize % 3;
            s[k] = self.index(gp.max(gq), gp.min(gq)) as u32;
        }
        s
    }

    /// Value index of entry `(row, col)`, `row >= col`; panics when absent
    /// (only called on entries the mesh creates).
    pub(crate) fn index(&self, row: usize, col: usize) -> usize {
        let (a, b) = (self.col_ptr[col], self.col_ptr[col + 1]);
        a + self.row_idx[a..b]
            .binary_search(&row)
            .expect("entry in the mesh pattern")
    }

    /// The value indices of group `g`'s node pairs (`k < l`, `k`
    /// ascending, then `l`): entry `(3 n_l, 3 n_k)` of its sorted nodes
    /// `n_0 < n_1 < ...`. The other entries of the pair's block follow from
    /// it ([`Pattern::group_column_offset`]); those of a node's own block
    /// from [`Pattern::diag`].
    pub fn group_pairs(&self, g: usize) -> &[u32] {
        &self.group_pair_index[self.group_start[g]..self.group_start[g + 1]]
    }

    /// The offset of column `3 n + c` (`c` < 3) from column `3 n` for the
    /// rows of a node `m > n`: entry `(3 m + r, 3 n + c)` lies at
    /// `index(3 m, 3 n) + offset + r`. Each node's rows are stored as one
    /// block of three in every column it couples with (sorted rows), and
    /// column `3 n + c` holds `c` rows fewer of node `n`'s own block.
    #[inline]
    pub fn group_column_offset(&self, n: usize, c: usize) -> usize {
        self.col_ptr[3 * n + c] - self.col_ptr[3 * n] - c
    }

    /// Number of stored nonzeros.
    pub fn nnz(&self) -> usize {
        self.row_idx.len()
    }

    /// The faer view of the symbolic structure.
    pub fn symbolic(&self) -> SymbolicSparseColMatRef<'_, usize> {
        SymbolicSparseColMatRef::new_checked(
            self.n_dofs,
            self.n_dofs,
            &self.col_ptr,
            None,
            &self.row_idx,
        )
    }

    /// Adds element `e`'s matrix into `values` (unconstrained assembly).
    pub fn add_element(&self, e: usize, k: &ElementMatrix, values: &mut [f64]) {
        for (s, &(p, q)) in self.scatter[e].iter().zip(LOCAL_PAIRS.iter()) {
            values[*s as usize] += k[(p as usize, q as usize)];
        }
    }

    /// `y = A x` for the symmetric matrix whose lower triangle is `values`.
    pub fn sym_matvec(&self, values: &[f64], x: &[f64], y: &mut [f64]) {
        y.fill(0.0);
        for c in 0..self.n_dofs {
            let xc = x[c];
            let mut acc = 0.0;
            for k in self.col_ptr[c]..self.col_ptr[c + 1] {
                let r = self.row_idx[k];
                let v = values[k];
                y[r] += v * xc;
                if r != c {
                    acc += v * x[r];
                }
            }
            y[c] += acc;
        }
    }
}

/// Gathers the 12 local values of element `t` from a global DOF vector.
#[inline]
pub fn gather(t: &[u32; 4], x: &[f64]) -> nalgebra::SVector<f64, 12> {
    let mut out = nalgebra::SVector::<f64, 12>::zeros();
    for a in 0..4 {
        let n = 3 * t[a] as usize;
        out[3 * a] = x[n];
        out[3 * a + 1] = x[n + 1];
        out[3 * a + 2] = x[n + 2];
    }
    out
}

/// Adds the 12 local values `v` of element `t` into a global DOF vector.
#[inline]
pub fn scatter_add(t: &[u32; 4], v: &nalgebra::SVector<f64, 12>, y: &mut [f64]) {
    for a in 0..4 {
        let n = 3 * t[a] as usize;
        y[n] += v[3 * a];
        y[n + 1] += v[3 * a + 1];
        y[n + 2] += v[3 * a + 2];
    }
}

/// `y = sum_e K_e x_e` over the element matrices (the global product without
/// the assembled matrix).
pub fn element_matvec(tets: &[[u32; 4]], kel: &[ElementMatrix], x: &[f64], y: &mut [f64]) {
    y.fill(0.0);
    for (t, k) in tets.iter().zip(kel) {
        let xe = gather(t, x);
        scatter_add(t, &(k * xe), y);
    }
}

/// Node vector of a DOF vector.
#[inline]
pub fn node_vec(x: &[f64], n: usize) -> Vector3<f64> {
    Vector3::new(x[3 * n], x[3 * n + 1], x[3 * n + 2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fem::element::TetGeometry;
    use crate::mesh::blocks::cube;

    #[test]
    fn assembled_matvec_equals_element_matvec() {
        let mesh = cube(0.01, 3);
        let pattern = Pattern::new(mesh.nodes.len(), &mesh.tets);
        let kel: Vec<_> = mesh
            .tets
            .iter()
            .map(|t| {
                TetGeometry::new(t.map(|i| mesh.nodes[i as usize]))
                    .unwrap()
                    .stiffness(3e3, 1e3)
            })
            .collect();
        let mut values = vec![0.0; pattern.nnz()];
        for (e, k) in kel.iter().enumerate() {
            pattern.add_element(e, k, &mut values);
        }
        let x: Vec<f64> = (0..pattern.n_dofs)
            .map(|i| ((i * 37 % 11) as f64 - 5.0) * 1e-3)
            .collect();
        let (mut y1, mut y2) = (vec![0.0; x.len()], vec![0.0; x.len()]);
        pattern.sym_matvec(&values, &x, &mut y1);
        element_matvec(&mesh.tets, &kel, &x, &mut y2);
        let scale = y2.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (a, b) in y1.iter().zip(&y2) {
            assert!((a - b).abs() < 1e-12 * scale);
        }
    }
}
