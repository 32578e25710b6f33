//! A bounding-volume hierarchy over the deforming surface, refitted each step.
//!
//! Binary tree of axis-aligned boxes, built once by median splits of triangle
//! centroids along the longest axis (leaves of at most [`LEAF_SIZE`]
//! triangles), stored depth-first so that a node's left child is the next node
//! and children always follow their parent. Large deformations make the boxes
//! overlap more and the queries slower, never wrong; [`Bvh::rebuild`] rebuilds
//! the topology.
//!
//! # Refit
//! [`RayBackend::update_positions`] refits without changing the topology, and
//! only where the surface moved: each vertex whose position differs (bit for
//! bit) from the one the tree last saw is written into the leaf-order copy of
//! the triangles' vertices (through a vertex -> triangle-corner table) and marks
//! its leaves; only those leaf boxes are recomputed from their vertices, then
//! their ancestors are re-unioned in one reverse sweep. Unchanged positions (the
//! force loop between two published surfaces) cost one comparison per vertex; a
//! deformation local to the fissure refits a few hundred boxes; a global one
//! costs what a full refit costs. [`Bvh::refit_stats`] reports how many leaves
//! the last update refitted.
//!
//! Boxes are stored in `f32` (32 bytes a node, half the cache footprint),
//! rounded outwards from the `f64` box: the stored box always contains the
//! exact one. The slab test runs in `f64` on the widened values.
//!
//! # Why our own tree
//! The collision method asks, per source node, for the nearest hit *behind*
//! (`t <= 0`) and the nearest *in front* (`t > 0`) on a whole line, in one
//! pass. parry3d's BVH ray casts are for half rays (`t >= 0` up to a maximum
//! time of impact) and keep one best hit; answering the method's question with
//! them takes two casts per node (one per direction) and still needs our
//! tie-breaking and our watertight triangle test. The traversal here visits each
//! box once for both answers: a box is entered while its slab interval
//! `[t0, t1]` (over the whole line) still intersects `[-|t_behind|, t_front]`,
//! children nearest to `t = 0` first. Ties in `|t|` go to the smaller triangle
//! index, exactly as in the brute force ([`keep_nearest`]), and the triangle
//! test is the same code on the same `f64` positions, so answers are identical
//! to the reference, bit for bit.
//!
//! Robustness: leaf boxes are padded by `1e-10 (extent + max |coordinate|)`,
//! several orders of magnitude above the rounding of the slab and triangle
//! tests, so that a triangle whose computed hit lies on its box's boundary is
//! never culled; direction components that are exactly zero are handled by a
//! containment test instead of an infinite inverse.

use super::brute::keep_nearest;
use super::ray::{PreparedRay, RayTest};
use super::{Hit, NodeHits, RayBackend, SurfaceError, check_surface};
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

/// Largest number of triangles in a leaf.
pub const LEAF_SIZE: usize = 4;

/// Relative padding of leaf boxes (module documentation).
const PAD: f64 = 1e-10;

/// No node (the root's parent).
const NONE: u32 = u32::MAX;

/// Largest `f32` not above `x` (finite `x`).
#[inline]
fn round_down(x: f64) -> f32 {
    let f = x as f32;
    if f64::from(f) <= x {
        f
    } else if f == 0.0 {
        -f32::from_bits(1)
    } else if f > 0.0 {
        f32::from_bits(f.to_bits() - 1)
    } else {
        f32::from_bits(f.to_bits() + 1)
    }
}

/// Smallest `f32` not below `x` (finite `x`).
#[inline]
fn round_up(x: f64) -> f32 {
    -round_down(-x)
}

/// A tree node: an `f32` box rounded outwards, and its children or triangles.
#[derive(Debug, Clone, Copy)]
struct Node {
    lo: [f32; 3],
    /// Leaf: first triangle (leaf order). Inner: index of the right child (the
    /// left child is the next node).
    index: u32,
    hi: [f32; 3],
    /// Leaf: number of triangles. Inner: 0.
    count: u32,
}

/// What the last [`RayBackend::update_positions`] of a [`Bvh`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RefitStats {
    /// Surface vertices whose position changed.
    pub moved_vertices: usize,
    /// Leaf boxes recomputed.
    pub refitted_leaves: usize,
    /// Leaves in the tree.
    pub leaves: usize,
}

/// BVH backend (CPU).
#[derive(Debug, Clone)]
pub struct Bvh {
    /// Triangles in leaf order.
    triangles: Vec<[u32; 3]>,
    /// Leaf order -> original triangle index.
    ids: Vec<u32>,
    /// Vertex positions of the triangles, leaf order (kept current by refit).
    verts: Vec<[Point3<f64>; 3]>,
    nodes: Vec<Node>,
    /// Parent of each node ([`NONE`] for the root).
    parent: Vec<u32>,
    /// Leaf node holding each leaf-order triangle.
    leaf_of: Vec<u32>,
    /// Vertex -> corners `3 * slot + corner` of the leaf-order triangles using
    /// it (CSR: corners of vertex `v` are `corners[start[v]..start[v + 1]]`).
    corner_start: Vec<u32>,
    corners: Vec<u32>,
    /// The positions of the last update (the first `needed` vertices).
    seen: Vec<Point3<f64>>,
    /// Per node: box must be recomputed (always all false between updates).
    dirty: Vec<bool>,
    dirty_leaves: Vec<u32>,
    /// Vertices moved by the current update.
    moved: Vec<u32>,
    stats: RefitStats,
    test: RayTest,
    needed: usize,
    valid: bool,
}

impl Bvh {
    /// Builds the tree over `triangles` at `positions` with the watertight test.
    pub fn new(triangles: &[[u32; 3]], positions: &[Point3<f64>]) -> Result<Self, SurfaceError> {
        Self::with_test(triangles, positions, RayTest::Watertight)
    }

    /// As [`Bvh::new`] with a chosen ray-triangle test.
    pub fn with_test(
        triangles: &[[u32; 3]],
        positions: &[Point3<f64>],
        test: RayTest,
    ) -> Result<Self, SurfaceError> {
        let needed = check_surface(triangles, positions)?;
        if triangles.len() >= (u32::MAX / 3) as usize {
            return Err(SurfaceError::TooLarge {
                triangles: triangles.len(),
            });
        }
        let mut bvh = Self {
            triangles: triangles.to_vec(),
            ids: (0..triangles.len() as u32).collect(),
            verts: Vec::new(),
            nodes: Vec::new(),
            parent: Vec::new(),
            leaf_of: Vec::new(),
            corner_start: Vec::new(),
            corners: Vec::new(),
            seen: Vec::new(),
            dirty: Vec::new(),
            dirty_leaves: Vec::new(),
            moved: Vec::new(),
            stats: RefitStats::default(),
            test,
            needed,
            valid: true,
        };
        bvh.build(positions);
        bvh.refit_all(positions);
        Ok(bvh)
    }

    /// Number of tree nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// What the last position update refitted.
    pub fn refit_stats(&self) -> RefitStats {
        self.stats
    }

    /// Rebuilds the topology for the current `positions` (after large
    /// deformations), then refits.
    pub fn rebuild(&mut self, positions: &[Point3<f64>]) {
        if positions.len() < self.needed {
            self.valid = false;
            return;
        }
        self.build(positions);
        self.refit_all(positions);
        self.valid = true;
    }

    fn build(&mut self, positions: &[Point3<f64>]) {
        // Restore the original order so that a rebuild is independent of history.
        let mut order: Vec<(u32, [u32; 3])> = self
            .ids
            .iter()
            .copied()
            .zip(self.triangles.iter().copied())
            .collect();
        order.sort_unstable_by_key(|e| e.0);
        let mut items: Vec<(Point3<f64>, u32, [u32; 3])> = order
            .into_iter()
            .map(|(id, t)| {
                let [a, b, c] = t.map(|v| positions[v as usize]);
                (Point3::from((a.coords + b.coords + c.coords) / 3.0), id, t)
            })
            .collect();
        self.nodes.clear();
        self.parent.clear();
        if !items.is_empty() {
            self.nodes.reserve(2 * items.len() / LEAF_SIZE + 1);
            Self::split(&mut self.nodes, &mut self.parent, &mut items, 0, NONE);
        }
        self.ids = items.iter().map(|e| e.1).collect();
        self.triangles = items.iter().map(|e| e.2).collect();
        // Leaf of each slot.
        self.leaf_of.clear();
        self.leaf_of.resize(self.triangles.len(), 0);
        for (k, n) in self.nodes.iter().enumerate() {
            if n.count > 0 {
                let first = n.index as usize;
                self.leaf_of[first..first + n.count as usize].fill(k as u32);
            }
        }
        // Vertex -> corners (counting sort).
        self.corner_start.clear();
        self.corner_start.resize(self.needed + 1, 0);
        for t in &self.triangles {
            for &v in t {
                self.corner_start[v as usize + 1] += 1;
            }
        }
        for v in 0..self.needed {
            self.corner_start[v + 1] += self.corner_start[v];
        }
        self.corners.clear();
        self.corners.resize(3 * self.triangles.len(), 0);
        let mut fill = self.corner_start.clone();
        for (slot, t) in self.triangles.iter().enumerate() {
            for (corner, &v) in t.iter().enumerate() {
                self.corners[fill[v as usize] as usize] = (3 * slot + corner) as u32;
                fill[v as usize] += 1;
            }
        }
        self.dirty.clear();
        self.dirty.resize(self.nodes.len(), false);
        self.dirty_leaves.clear();
        self.dirty_leaves.reserve(self.nodes.len());
        self.moved.clear();
        self.moved.reserve(self.needed);
    }

    /// Emits the subtree of `items` (which start at leaf-order index `first`).
    fn split(
        nodes: &mut Vec<Node>,
        parent: &mut Vec<u32>,
        items: &mut [(Point3<f64>, u32, [u32; 3])],
        first: usize,
        up: u32,
    ) {
        let me = nodes.len();
        nodes.push(Node {
            lo: [0.0; 3],
            index: first as u32,
            hi: [0.0; 3],
            count: items.len() as u32,
        });
        parent.push(up);
        if items.len() <= LEAF_SIZE {
            return;
        }
        let mut lo = items[0].0;
        let mut hi = items[0].0;
        for it in items.iter() {
            lo = lo.inf(&it.0);
            hi = hi.sup(&it.0);
        }
        let ext = hi - lo;
        let axis = if ext.x >= ext.y && ext.x >= ext.z {
            0
        } else if ext.y >= ext.z {
            1
        } else {
            2
        };
        let mid = items.len() / 2;
        items.select_nth_unstable_by(mid, |a, b| {
            a.0[axis].total_cmp(&b.0[axis]).then(a.1.cmp(&b.1))
        });
        let (left, right) = items.split_at_mut(mid);
        Self::split(nodes, parent, left, first, me as u32);
        let r = nodes.len() as u32;
        Self::split(nodes, parent, right, first + mid, me as u32);
        nodes[me].index = r;
        nodes[me].count = 0;
    }

    /// Recomputes leaf `k`'s box from the leaf-order vertices: the padded
    /// `f64` box, rounded outwards to `f32`.
    #[inline]
    fn fit_leaf(&mut self, k: usize) {
        let n = self.nodes[k];
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for tri in &self.verts[n.index as usize..(n.index + n.count) as usize] {
            for p in tri {
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
        }
        let mut scale = 0.0f64;
        for a in 0..3 {
            scale = scale.max(hi[a] - lo[a]).max(lo[a].abs()).max(hi[a].abs());
        }
        let pad = PAD * scale;
        let node = &mut self.nodes[k];
        node.lo = lo.map(|x| round_down(x - pad));
        node.hi = hi.map(|x| round_up(x + pad));
    }

    /// Unions the children of inner node `k`.
    #[inline]
    fn fit_inner(&mut self, k: usize) {
        let n = self.nodes[k];
        let (l, r) = (self.nodes[k + 1], self.nodes[n.index as usize]);
        let node = &mut self.nodes[k];
        node.lo = [0, 1, 2].map(|a| l.lo[a].min(r.lo[a]));
        node.hi = [0, 1, 2].map(|a| l.hi[a].max(r.hi[a]));
    }

    /// Takes every position and recomputes every box.
    fn refit_all(&mut self, positions: &[Point3<f64>]) {
        self.seen.clear();
        self.seen.extend_from_slice(&positions[..self.needed]);
        self.verts
            .resize(self.triangles.len(), [Point3::origin(); 3]);
        for (v, t) in self.verts.iter_mut().zip(&self.triangles) {
            *v = t.map(|i| positions[i as usize]);
        }
        for k in (0..self.nodes.len()).rev() {
            if self.nodes[k].count > 0 {
                self.fit_leaf(k);
            } else {
                self.fit_inner(k);
            }
        }
        let leaves = self.nodes.len().div_ceil(2);
        self.stats = RefitStats {
            moved_vertices: self.needed,
            refitted_leaves: leaves,
            leaves,
        };
    }

    /// Refits the leaves whose vertices moved since the last update, and their
    /// ancestors (module documentation). When more than a quarter of the
    /// vertices moved, a full refit (a sequential gather) is cheaper than the
    /// scattered partial one and is done instead. No allocation.
    fn refit_moved(&mut self, positions: &[Point3<f64>]) {
        self.moved.clear();
        for (v, (seen, p)) in self.seen.iter_mut().zip(positions).enumerate() {
            let same = seen.x.to_bits() == p.x.to_bits()
                && seen.y.to_bits() == p.y.to_bits()
                && seen.z.to_bits() == p.z.to_bits();
            if !same {
                *seen = *p;
                self.moved.push(v as u32);
            }
        }
        let moved = self.moved.len();
        if 4 * moved > self.needed {
            self.refit_all(positions);
            self.stats.moved_vertices = moved;
            return;
        }
        self.dirty_leaves.clear();
        for &v in &self.moved {
            let v = v as usize;
            let p = positions[v];
            let corners =
                &self.corners[self.corner_start[v] as usize..self.corner_start[v + 1] as usize];
            for &e in corners {
                let slot = (e / 3) as usize;
                self.verts[slot][(e % 3) as usize] = p;
                let leaf = self.leaf_of[slot] as usize;
                if !self.dirty[leaf] {
                    self.dirty[leaf] = true;
                    self.dirty_leaves.push(leaf as u32);
                }
            }
        }
        let refitted = self.dirty_leaves.len();
        let mut lowest = self.nodes.len();
        for i in 0..self.dirty_leaves.len() {
            let leaf = self.dirty_leaves[i] as usize;
            self.fit_leaf(leaf);
            self.dirty[leaf] = false;
            let mut k = self.parent[leaf];
            while k != NONE && !self.dirty[k as usize] {
                self.dirty[k as usize] = true;
                lowest = lowest.min(k as usize);
                k = self.parent[k as usize];
            }
        }
        if refitted > 0 {
            // Children follow their parents: a reverse sweep unions bottom-up.
            for k in (lowest..self.nodes.len()).rev() {
                if self.dirty[k] {
                    self.dirty[k] = false;
                    self.fit_inner(k);
                }
            }
        }
        self.stats = RefitStats {
            moved_vertices: moved,
            refitted_leaves: refitted,
            leaves: self.nodes.len().div_ceil(2),
        };
    }

    /// Slab interval `[t0, t1]` of the whole line in node `k`'s box, or `None`.
    #[inline(always)]
    fn interval(
        &self,
        k: usize,
        o: &Point3<f64>,
        inv: &[f64; 3],
        zero: &[bool; 3],
    ) -> Option<(f64, f64)> {
        let n = &self.nodes[k];
        let mut t0 = f64::NEG_INFINITY;
        let mut t1 = f64::INFINITY;
        for a in 0..3 {
            if zero[a] {
                if o[a] < f64::from(n.lo[a]) || o[a] > f64::from(n.hi[a]) {
                    return None;
                }
            } else {
                let ta = (f64::from(n.lo[a]) - o[a]) * inv[a];
                let tb = (f64::from(n.hi[a]) - o[a]) * inv[a];
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        (t0 <= t1).then_some((t0, t1))
    }

    fn cast_one(&self, origin: Point3<f64>, dir: Vector3<f64>) -> NodeHits {
        let mut hits = NodeHits::default();
        if self.nodes.is_empty() {
            return hits;
        }
        let ray = PreparedRay::new(self.test, origin, dir);
        let zero = [dir.x == 0.0, dir.y == 0.0, dir.z == 0.0];
        if zero.iter().all(|&z| z) {
            return hits;
        }
        let inv = [0, 1, 2].map(|a| if zero[a] { 0.0 } else { 1.0 / dir[a] });
        // Is an interval still able to improve an answer?
        let useful = |t0: f64, t1: f64, hits: &NodeHits| {
            let front = hits.front.map_or(f64::INFINITY, |h| h.t);
            let behind = hits.behind.map_or(f64::INFINITY, |h| -h.t);
            (t1 > 0.0 && t0 <= front) || (t0 <= 0.0 && t1 >= -behind)
        };
        let dist = |t0: f64, t1: f64| {
            if t0 > 0.0 {
                t0
            } else if t1 < 0.0 {
                -t1
            } else {
                0.0
            }
        };
        let mut stack = [(0u32, 0.0f64, 0.0f64); 96];
        let mut top = 0usize;
        if let Some((t0, t1)) = self.interval(0, &origin, &inv, &zero) {
            stack[0] = (0, t0, t1);
            top = 1;
        }
        while top > 0 {
            top -= 1;
            let (k, t0, t1) = stack[top];
            if !useful(t0, t1, &hits) {
                continue;
            }
            let n = &self.nodes[k as usize];
            if n.count > 0 {
                let first = n.index as usize;
                for j in first..first + n.count as usize {
                    let [a, b, c] = &self.verts[j];
                    if let Some(h) = ray.intersect(a, b, c) {
                        keep_nearest(
                            &mut hits,
                            Hit {
                                triangle: self.ids[j],
                                t: h.t,
                                u: h.u,
                                v: h.v,
                            },
                        );
                    }
                }
                continue;
            }
            let l = k as usize + 1;
            let r = n.index as usize;
            let il = self.interval(l, &origin, &inv, &zero);
            let ir = self.interval(r, &origin, &inv, &zero);
            let mut push = |e: (u32, f64, f64)| {
                // The tree is balanced (median splits): depth <= log2(n) + 2.
                stack[top] = e;
                top += 1;
            };
            match (il, ir) {
                (Some(a), Some(b)) => {
                    if dist(a.0, a.1) <= dist(b.0, b.1) {
                        push((r as u32, b.0, b.1));
                        push((l as u32, a.0, a.1));
                    } else {
                        push((l as u32, a.0, a.1));
                        push((r as u32, b.0, b.1));
                    }
                }
                (Some(a), None) => push((l as u32, a.0, a.1)),
                (None, Some(b)) => push((r as u32, b.0, b.1)),
                (None, None) => {}
            }
        }
        hits
    }
}

impl RayBackend for Bvh {
    fn method(&self) -> &'static str {
        "bvh"
    }

    fn backend(&self) -> &'static str {
        "cpu"
    }

    fn update_positions(&mut self, positions: &[Point3<f64>]) {
        if positions.len() < self.needed {
            self.valid = false;
        } else if self.valid {
            self.refit_moved(positions);
        } else {
            self.refit_all(positions);
            self.valid = true;
        }
    }

    fn cast(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>], out: &mut Vec<NodeHits>) {
        let n = origins.len().min(dirs.len());
        out.clear();
        out.resize(n, NodeHits::default());
        if !self.valid {
            return;
        }
        let this = &*self;
        out.par_iter_mut()
            .with_min_len(32)
            .zip(origins[..n].par_iter().zip(dirs[..n].par_iter()))
            .for_each(|(slot, (o, d))| *slot = this.cast_one(*o, *d));
    }
}
