//! A bounding-volume hierarchy over the deforming surface, refitted each step.
//!
//! Binary tree of axis-aligned boxes, built once by binned SAH splits of the
//! triangles (median splits of the centroids below a depth limit; leaves of at
//! most [`LEAF_SIZE`] triangles), stored depth-first so that a node's left child is the next node
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
//! rounded outwards from the `f64` box (by at most two `f32` units): the
//! stored box always contains the exact one. The slab test runs in `f64` on
//! the widened values.
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
//! A batch of rays that all look within finite ranges (a spatula's bounded
//! rays) starts below the root: at the deepest frontier of at most eight nodes
//! covering the box of all their segments, found once per batch (when the
//! first ray walks alone: a batch cast as bundles needs none), so the top
//! levels of the tree are not walked again for every ray (exact: any hit
//! within a ray's range lies in that box).
//!
//! Robustness: leaf boxes are padded by `1e-10 (extent + max |coordinate|)`,
//! several orders of magnitude above the rounding of the slab and triangle
//! tests, so that a triangle whose computed hit lies on its box's boundary is
//! never culled; direction components that are exactly zero are handled by a
//! containment test instead of an infinite inverse.

mod bundle;

pub use bundle::{BUNDLE_MIN, Traversal};

use super::brute::keep_nearest;
use super::ray::{PreparedRay, RayTest};
use super::{Hit, NodeHits, RayBackend, RayRange, SurfaceError, check_surface};
use faer::Par;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use std::sync::OnceLock;

/// Largest number of triangles in a leaf.
pub const LEAF_SIZE: usize = 4;

/// Relative padding of leaf boxes (module documentation).
const PAD: f64 = 1e-10;

/// Depth below which splits are median splits: SAH trees may be unbalanced,
/// and the traversal stack (96 entries) must hold the deepest path. Median
/// splits below this depth add at most `log2(n) + 2` levels.
const SAH_DEPTH: usize = 40;

/// Traversal stack of one ray: node, and its box's slab interval `[t0, t1]`.
/// Depth <= SAH_DEPTH + log2(n) + 2, and the stack grows by at most one
/// entry a level.
type Stack = [(u32, f64, f64); 96];

const EMPTY_STACK: Stack = [(0, 0.0, 0.0); 96];

/// Bins per axis of the SAH split.
const SAH_BINS: usize = 16;

/// One triangle while building: centroid, box, original index, vertices.
#[derive(Debug, Clone, Copy)]
struct Item {
    centroid: Point3<f64>,
    lo: Point3<f64>,
    hi: Point3<f64>,
    id: u32,
    tri: [u32; 3],
}

/// Half the surface area of the box `[lo, hi]` (empty boxes: 0).
fn half_area(lo: &Point3<f64>, hi: &Point3<f64>) -> f64 {
    let e = (hi - lo).map(|x| x.max(0.0));
    e.x * e.y + e.y * e.z + e.z * e.x
}

/// Box `(lo, hi)` of the centroids of `items` (not empty).
fn centroid_bounds(items: &[Item]) -> (Point3<f64>, Point3<f64>) {
    let mut lo = items[0].centroid;
    let mut hi = items[0].centroid;
    for it in items.iter() {
        lo = lo.inf(&it.centroid);
        hi = hi.sup(&it.centroid);
    }
    (lo, hi)
}

/// Median split of the centroids (box `[lo, hi]`) along their longest axis;
/// returns the size of the left part.
fn median_split(items: &mut [Item], (lo, hi): (Point3<f64>, Point3<f64>)) -> usize {
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
        a.centroid[axis]
            .total_cmp(&b.centroid[axis])
            .then(a.id.cmp(&b.id))
    });
    mid
}

/// Bin of centroid coordinate `c` among [`SAH_BINS`] equal slabs of
/// `[lo, lo + ext]` (`ext > 0`).
#[inline]
fn sah_bin(c: f64, lo: f64, ext: f64) -> usize {
    (((c - lo) / ext * SAH_BINS as f64) as usize).min(SAH_BINS - 1)
}

/// Binned surface-area-heuristic split (Wald 2007): centroids binned into
/// [`SAH_BINS`] slabs per axis; the plane between two bins minimising
/// `A(left) n(left) + A(right) n(right)` (the expected number of triangle
/// tests of a ray that reaches the node) is chosen. Thin, close sheets such as
/// the two walls of a fissure end up in separate boxes, where median splits
/// keep boxes that span the gap. Returns the size of the left part, or `None`
/// when every centroid falls in one bin on every axis.
fn sah_split(items: &mut [Item], (clo, chi): (Point3<f64>, Point3<f64>)) -> Option<usize> {
    let empty = (
        Point3::from([f64::INFINITY; 3]),
        Point3::from([f64::NEG_INFINITY; 3]),
    );
    let mut best: Option<(f64, usize, usize)> = None;
    for axis in 0..3 {
        let ext = chi[axis] - clo[axis];
        // Also skips a NaN extent.
        if ext.is_nan() || ext <= 0.0 {
            continue;
        }
        let bin = |it: &Item| sah_bin(it.centroid[axis], clo[axis], ext);
        let mut count = [0usize; SAH_BINS];
        let mut boxes = [empty; SAH_BINS];
        for it in items.iter() {
            let b = bin(it);
            count[b] += 1;
            boxes[b].0 = boxes[b].0.inf(&it.lo);
            boxes[b].1 = boxes[b].1.sup(&it.hi);
        }
        // Right-to-left sweep of areas and counts, then left-to-right.
        let mut right_area = [0.0f64; SAH_BINS];
        let mut acc = empty;
        let mut n = 0;
        let mut right_count = [0usize; SAH_BINS];
        for b in (1..SAH_BINS).rev() {
            acc.0 = acc.0.inf(&boxes[b].0);
            acc.1 = acc.1.sup(&boxes[b].1);
            n += count[b];
            right_area[b] = half_area(&acc.0, &acc.1);
            right_count[b] = n;
        }
        let mut acc = empty;
        let mut n = 0;
        for b in 1..SAH_BINS {
            acc.0 = acc.0.inf(&boxes[b - 1].0);
            acc.1 = acc.1.sup(&boxes[b - 1].1);
            n += count[b - 1];
            if n == 0 || right_count[b] == 0 {
                continue;
            }
            let cost = half_area(&acc.0, &acc.1) * n as f64 + right_area[b] * right_count[b] as f64;
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, b));
            }
        }
    }
    let (_, axis, split) = best?;
    let ext = chi[axis] - clo[axis];
    let side = |it: &Item| sah_bin(it.centroid[axis], clo[axis], ext) >= split;
    items.sort_unstable_by(|a, b| side(a).cmp(&side(b)).then(a.id.cmp(&b.id)));
    let mid = items.iter().filter(|it| !side(it)).count();
    (mid > 0 && mid < items.len()).then_some(mid)
}

/// No node (the root's parent).
const NONE: u32 = u32::MAX;

/// An `f32` not above `x` (finite `x`, `|x| < f32::MAX / 2`), at most two
/// `f32` units below it: `x` less a margin of one unit (`2^-23 |x|`, plus
/// the least normal `f32` for `x` near zero), rounded to nearest, lands
/// within half a unit of `x - margin`, hence below `x`. Branch-free: an
/// exact rounding tests whether the nearest `f32` overshot, a branch that a
/// refit mispredicts about every other coordinate.
#[inline]
fn round_down(x: f64) -> f32 {
    const UNIT: f64 = 1.0 / (1u32 << 23) as f64;
    (x - (x.abs() * UNIT + f64::from(f32::MIN_POSITIVE))) as f32
}

/// An `f32` not below `x`, at most two units above it ([`round_down`]).
#[inline]
fn round_up(x: f64) -> f32 {
    -round_down(-x)
}

/// The `f64` box of a leaf's vertices while it is fitted.
#[derive(Clone, Copy)]
struct LeafBox {
    lo: [f64; 3],
    hi: [f64; 3],
}

impl LeafBox {
    const EMPTY: Self = Self {
        lo: [f64::INFINITY; 3],
        hi: [f64::NEG_INFINITY; 3],
    };

    /// Takes in a triangle's vertices. Plain comparisons (one min/max
    /// instruction each) skip a NaN coordinate as `f64::min` does: `lo` and
    /// `hi` are never NaN.
    #[inline]
    fn add(&mut self, tri: &[Point3<f64>; 3]) {
        for p in tri {
            for a in 0..3 {
                self.lo[a] = if p[a] < self.lo[a] { p[a] } else { self.lo[a] };
                self.hi[a] = if p[a] > self.hi[a] { p[a] } else { self.hi[a] };
            }
        }
    }

    /// Writes the box, padded ([`PAD`]) and rounded outwards to `f32`, into
    /// `node`.
    #[inline]
    fn store(&self, node: &mut Node) {
        let mut scale = 0.0f64;
        for a in 0..3 {
            for x in [self.hi[a] - self.lo[a], self.lo[a].abs(), self.hi[a].abs()] {
                scale = if x > scale { x } else { scale };
            }
        }
        let pad = PAD * scale;
        node.lo = self.lo.map(|x| round_down(x - pad));
        node.hi = self.hi.map(|x| round_up(x + pad));
    }
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
    /// How bounded runs of parallel rays are cast.
    traversal: Traversal,
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
                what: "triangles",
                count: triangles.len(),
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
            traversal: Traversal::default(),
            needed,
            valid: true,
        };
        bvh.build(positions);
        bvh.refit_all(positions);
        Ok(bvh)
    }

    /// What the last position update refitted.
    pub fn traversal(&self) -> Traversal {
        self.traversal
    }

    /// Chooses how bounded runs of parallel rays are cast (answers are the
    /// same either way; [`Traversal`]).
    pub fn set_traversal(&mut self, traversal: Traversal) {
        self.traversal = traversal;
    }

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
        let mut items: Vec<Item> = order
            .into_iter()
            .map(|(id, tri)| {
                let [a, b, c] = tri.map(|v| positions[v as usize]);
                Item {
                    centroid: Point3::from((a.coords + b.coords + c.coords) / 3.0),
                    lo: a.inf(&b).inf(&c),
                    hi: a.sup(&b).sup(&c),
                    id,
                    tri,
                }
            })
            .collect();
        self.nodes.clear();
        self.parent.clear();
        if !items.is_empty() {
            self.nodes.reserve(2 * items.len() / LEAF_SIZE + 1);
            Self::split(&mut self.nodes, &mut self.parent, &mut items, 0, NONE, 0);
        }
        self.ids = items.iter().map(|e| e.id).collect();
        self.triangles = items.iter().map(|e| e.tri).collect();
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

    /// Emits the subtree of `items` (which start at leaf-order index `first`)
    /// at depth `depth`: a binned SAH split ([`sah_split`]) while `depth <
    /// SAH_DEPTH`, a median split of the centroids along their longest axis
    /// below that or when SAH finds no split. Deterministic: every partition
    /// orders by (side, triangle id).
    fn split(
        nodes: &mut Vec<Node>,
        parent: &mut Vec<u32>,
        items: &mut [Item],
        first: usize,
        up: u32,
        depth: usize,
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
        let bounds = centroid_bounds(items);
        let mid = match (depth < SAH_DEPTH)
            .then(|| sah_split(items, bounds))
            .flatten()
        {
            Some(mid) => mid,
            None => median_split(items, bounds),
        };
        let (left, right) = items.split_at_mut(mid);
        Self::split(nodes, parent, left, first, me as u32, depth + 1);
        let r = nodes.len() as u32;
        Self::split(nodes, parent, right, first + mid, me as u32, depth + 1);
        nodes[me].index = r;
        nodes[me].count = 0;
    }

    /// Recomputes leaf `k`'s box from the leaf-order vertices: the padded
    /// `f64` box, rounded outwards to `f32`.
    #[inline]
    fn fit_leaf(&mut self, k: usize) {
        let n = self.nodes[k];
        let mut b = LeafBox::EMPTY;
        for tri in &self.verts[n.index as usize..(n.index + n.count) as usize] {
            b.add(tri);
        }
        b.store(&mut self.nodes[k]);
    }

    /// Unions the children of inner node `k`.
    #[inline]
    fn fit_inner(&mut self, k: usize) {
        let n = self.nodes[k];
        let (l, r) = (self.nodes[k + 1], self.nodes[n.index as usize]);
        let node = &mut self.nodes[k];
        node.lo = [0, 1, 2].map(|a| if r.lo[a] < l.lo[a] { r.lo[a] } else { l.lo[a] });
        node.hi = [0, 1, 2].map(|a| if r.hi[a] > l.hi[a] { r.hi[a] } else { l.hi[a] });
    }

    /// Takes every position and recomputes every box.
    fn refit_all(&mut self, positions: &[Point3<f64>]) {
        self.seen.clear();
        self.seen.extend_from_slice(&positions[..self.needed]);
        self.refit_all_seen(positions);
    }

    /// Recomputes every box from `positions`, whose first `needed` entries
    /// `seen` already holds. Each leaf gathers its own triangles' vertices
    /// just before its box is fitted, so they are still in cache.
    fn refit_all_seen(&mut self, positions: &[Point3<f64>]) {
        self.verts
            .resize(self.triangles.len(), [Point3::origin(); 3]);
        for k in (0..self.nodes.len()).rev() {
            let n = self.nodes[k];
            if n.count > 0 {
                let slots = n.index as usize..(n.index + n.count) as usize;
                let mut b = LeafBox::EMPTY;
                for (v, t) in self.verts[slots.clone()]
                    .iter_mut()
                    .zip(&self.triangles[slots])
                {
                    *v = t.map(|i| positions[i as usize]);
                    b.add(v);
                }
                b.store(&mut self.nodes[k]);
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
            // `seen` took every moved position above.
            self.refit_all_seen(positions);
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

    /// The nearest hits of one line within `range` (module documentation).
    /// `stack` is scratch (reused across rays: no per-ray initialisation).
    #[inline]
    fn cast_one(
        &self,
        origin: Point3<f64>,
        dir: Vector3<f64>,
        range: RayRange,
        entry: &[u32],
        stack: &mut Stack,
    ) -> NodeHits {
        self.cast_beyond(origin, dir, range, 0.0, entry, stack)
    }

    /// [`Self::cast_one`] for a line known to have no hit with
    /// `|t| <= beyond` on the sides it looks at (a bundle found none there):
    /// a box whose slab interval on a side lies within `beyond` of the origin
    /// is not entered (exact: every box holds its triangles with a margin far
    /// above rounding, so a hit past `beyond` lies in an interval reaching
    /// past it).
    fn cast_beyond(
        &self,
        origin: Point3<f64>,
        dir: Vector3<f64>,
        range: RayRange,
        beyond: f64,
        entry: &[u32],
        stack: &mut Stack,
    ) -> NodeHits {
        let mut hits = NodeHits::default();
        if self.nodes.is_empty() || !(range.behind >= 0.0 || range.front > 0.0) {
            return hits;
        }
        let ray = PreparedRay::new(self.test, origin, dir);
        let zero = [dir.x == 0.0, dir.y == 0.0, dir.z == 0.0];
        if zero.iter().all(|&z| z) {
            return hits;
        }
        let inv = [0, 1, 2].map(|a| if zero[a] { 0.0 } else { 1.0 / dir[a] });
        // Is an interval still able to improve an answer?
        // Bounds beyond which nothing is looked for: the range, then the hits
        // found so far.
        let useful = |t0: f64, t1: f64, hits: &NodeHits| {
            let front = hits.front.map_or(range.front, |h| h.t);
            let behind = hits.behind.map_or(range.behind, |h| -h.t);
            (front > 0.0 && t1 > beyond && t0 <= front)
                || (behind >= 0.0 && t0 <= -beyond && t1 >= -behind)
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
        // Entry nodes, the nearest on top (pushed last).
        let mut top = 0usize;
        for &k in entry {
            let Some((t0, t1)) = self.interval(k as usize, &origin, &inv, &zero) else {
                continue;
            };
            let d = dist(t0, t1);
            let mut at = top;
            while at > 0 && dist(stack[at - 1].1, stack[at - 1].2) < d {
                stack[at] = stack[at - 1];
                at -= 1;
            }
            stack[at] = (k, t0, t1);
            top += 1;
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
                    if let Some(h) = ray.intersect(a, b, c)
                        && range.contains(h.t)
                    {
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
                // Depth <= SAH_DEPTH + log2(n) + 2, and the stack grows by
                // at most one entry a level.
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

impl Bvh {
    /// Casts one line per source node within `ranges` (one per ray; rays
    /// without one look along the whole line), parallel over the rays as `par`
    /// says. Read-only: one tree published by the deformation loop serves
    /// every force loop at once. Answers equal [`RayBackend::cast_ranged`]'s.
    pub fn cast_ranged_with(
        &self,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        ranges: &[RayRange],
        par: Par,
        out: &mut Vec<NodeHits>,
    ) {
        let n = origins.len().min(dirs.len());
        out.clear();
        out.resize(n, NodeHits::default());
        if !self.valid {
            return;
        }
        let range = |i: usize| ranges.get(i).copied().unwrap_or(RayRange::LINE);
        // Found when a ray first walks alone: a cast of bundles alone
        // needs none.
        let entry_cell = OnceLock::new();
        let entry = LazyEntry {
            cell: &entry_cell,
            bvh: self,
            origins,
            dirs,
            ranges,
        };
        if self.traversal == Traversal::Bundled && n >= BUNDLE_MIN {
            self.cast_span(0, origins, dirs, ranges, par, &entry, &mut out[..]);
            return;
        }
        let entry = entry.get();
        let start = |i: usize| -> &[u32] {
            if segment(&origins[i], &dirs[i], ranges.get(i)).is_some() {
                entry.nodes()
            } else {
                &[0]
            }
        };
        match par {
            Par::Seq => {
                let mut stack = EMPTY_STACK;
                for (i, slot) in out.iter_mut().enumerate() {
                    *slot = self.cast_one(origins[i], dirs[i], range(i), start(i), &mut stack);
                }
            }
            Par::Rayon(_) => {
                out.par_iter_mut()
                    .enumerate()
                    .with_min_len(32)
                    .for_each_init(
                        || EMPTY_STACK,
                        |stack, (i, slot)| {
                            *slot = self.cast_one(origins[i], dirs[i], range(i), start(i), stack)
                        },
                    );
            }
        }
    }

    /// The rays `first..first + out.len()` of a bundled cast: halves cast in
    /// parallel (`rayon::join`, no allocation) down to spans of
    /// [`SPAN_SEQ`] rays, each cast in sequence by [`Bvh::cast_runs`].
    #[allow(clippy::too_many_arguments)]
    fn cast_span(
        &self,
        first: usize,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        ranges: &[RayRange],
        par: Par,
        entry: &LazyEntry<'_>,
        out: &mut [NodeHits],
    ) {
        if matches!(par, Par::Seq) || out.len() <= SPAN_SEQ {
            self.cast_runs(first, origins, dirs, ranges, entry, out);
            return;
        }
        let mid = out.len() / 2;
        let (a, b) = out.split_at_mut(mid);
        rayon::join(
            || self.cast_span(first, origins, dirs, ranges, par, entry, a),
            || self.cast_span(first + mid, origins, dirs, ranges, par, entry, b),
        );
    }

    /// The rays `first..first + out.len()` in sequence: each run of at least
    /// [`BUNDLE_MIN`] consecutive rays with bitwise-equal directions as one
    /// bundle (the rays it leaves unanswered again alone), every other ray
    /// alone.
    fn cast_runs(
        &self,
        first: usize,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        ranges: &[RayRange],
        entry: &LazyEntry<'_>,
        out: &mut [NodeHits],
    ) {
        let end = first + out.len();
        let bounded = |i: usize| segment(&origins[i], &dirs[i], ranges.get(i)).is_some();
        let same =
            |a: &Vector3<f64>, b: &Vector3<f64>| (0..3).all(|k| a[k].to_bits() == b[k].to_bits());
        let range = |k: usize| ranges.get(k).copied().unwrap_or(RayRange::LINE);
        let mut stack = EMPTY_STACK;
        let mut i = first;
        while i < end {
            let mut j = i + 1;
            while j < end && same(&dirs[j], &dirs[i]) {
                j += 1;
            }
            if j - i >= BUNDLE_MIN {
                let bundle = bundle::cast_bundle(
                    self,
                    &origins[i..j],
                    dirs[i],
                    ranges.get(i..j.min(ranges.len())).unwrap_or(&[]),
                    &mut out[i - first..j - first],
                );
                for k in i..j {
                    let hits = &mut out[k - first];
                    if let Some(again) = bundle.recast_range(&range(k), hits) {
                        let start: &[u32] =
                            if segment(&origins[k], &dirs[k], Some(&again)).is_some() {
                                entry.get().nodes()
                            } else {
                                &[0]
                            };
                        // Nothing on a recast side lies within the
                        // bundle's reach.
                        let more = self.cast_beyond(
                            origins[k],
                            dirs[k],
                            again,
                            bundle.reach,
                            start,
                            &mut stack,
                        );
                        if again.front >= 0.0 {
                            hits.front = more.front;
                        }
                        if again.behind >= 0.0 {
                            hits.behind = more.behind;
                        }
                    }
                }
            } else {
                for k in i..j {
                    let start: &[u32] = if bounded(k) {
                        entry.get().nodes()
                    } else {
                        &[0]
                    };
                    out[k - first] =
                        self.cast_one(origins[k], dirs[k], range(k), start, &mut stack);
                }
            }
            i = j;
        }
    }
}

/// Rays a bundled cast hands to one thread at least.
const SPAN_SEQ: usize = 512;

/// Most entry nodes a batch of bounded rays starts from.
const ENTRY_MAX: usize = 8;

/// The segment `[origin + t_lo dir, origin + t_hi dir]` a ranged ray looks
/// along, when both ends are finite.
#[inline]
fn segment(
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
    range: Option<&RayRange>,
) -> Option<(Point3<f64>, Point3<f64>)> {
    let r = range?;
    let t_lo = if r.behind >= 0.0 { -r.behind } else { 0.0 };
    let t_hi = if r.front > 0.0 { r.front } else { 0.0 };
    let a = origin + dir * t_lo;
    let c = origin + dir * t_hi;
    a.coords
        .iter()
        .chain(c.coords.iter())
        .all(|x| x.is_finite())
        .then_some((a, c))
}

/// Where the bounded rays of one batch start their traversal: instead of the
/// root, the deepest frontier of at most [`ENTRY_MAX`] nodes covering every
/// node whose box meets `Q`, the box of all the bounded rays' segments
/// (widened far above rounding). A hit within a ray's range lies on its
/// segment, hence in `Q`, and inside its leaf's box, so that leaf is below
/// one of the entry nodes: answers are unchanged, while the top levels of
/// the tree (the same for every ray of a spatula) are walked once per batch
/// instead of once per ray. Rays with an unbounded side start at the root.
struct Entry {
    nodes: [u32; ENTRY_MAX],
    len: usize,
}

/// The [`Entry`] of one cast, found on first use.
struct LazyEntry<'a> {
    cell: &'a OnceLock<Entry>,
    bvh: &'a Bvh,
    origins: &'a [Point3<f64>],
    dirs: &'a [Vector3<f64>],
    ranges: &'a [RayRange],
}

impl LazyEntry<'_> {
    fn get(&self) -> &Entry {
        self.cell
            .get_or_init(|| Entry::new(self.bvh, self.origins, self.dirs, self.ranges))
    }
}

impl Entry {
    fn new(bvh: &Bvh, origins: &[Point3<f64>], dirs: &[Vector3<f64>], ranges: &[RayRange]) -> Self {
        let mut entry = Self {
            nodes: [0; ENTRY_MAX],
            len: 0,
        };
        let mut lo = Point3::from([f64::INFINITY; 3]);
        let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
        for ((o, d), r) in origins.iter().zip(dirs).zip(ranges) {
            if let Some((a, c)) = segment(o, d, Some(r)) {
                lo = lo.inf(&a.inf(&c));
                hi = hi.sup(&a.sup(&c));
            }
        }
        if bvh.nodes.is_empty() || lo.x > hi.x {
            return entry;
        }
        let (lo, hi) = super::widen_box(lo, hi);
        let meets = |k: u32| {
            let nd = &bvh.nodes[k as usize];
            (0..3).all(|a| f64::from(nd.lo[a]) <= hi[a] && f64::from(nd.hi[a]) >= lo[a])
        };
        if !meets(0) {
            // No bounded ray can hit anything: they start from no node.
            return entry;
        }
        entry.len = 1;
        loop {
            let mut next = [0u32; ENTRY_MAX];
            let mut len = 0;
            let mut grew = false;
            for &k in entry.nodes() {
                let nd = &bvh.nodes[k as usize];
                let kids = if nd.count > 0 {
                    [Some(k), None]
                } else {
                    grew = true;
                    [Some(k + 1), Some(nd.index)]
                };
                for c in kids.into_iter().flatten() {
                    if nd.count > 0 || meets(c) {
                        if len == ENTRY_MAX {
                            return entry;
                        }
                        next[len] = c;
                        len += 1;
                    }
                }
            }
            if !grew {
                return entry;
            }
            entry.nodes = next;
            entry.len = len;
        }
    }

    fn nodes(&self) -> &[u32] {
        &self.nodes[..self.len]
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
        BvhView::new(self, Par::rayon(0)).cast(origins, dirs, out);
    }

    fn cast_ranged(
        &mut self,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        ranges: &[RayRange],
        out: &mut Vec<NodeHits>,
    ) {
        BvhView::new(self, Par::rayon(0)).cast_ranged(origins, dirs, ranges, out);
    }
}

/// A fitted tree as a read-only [`RayBackend`] casting with a chosen
/// parallelism: one tree published by the deformation loop serves every
/// force loop at once, each casting sequentially on its own thread. Its
/// positions are the tree's as last fitted, so `update_positions` has
/// nothing to do.
pub struct BvhView<'a> {
    tree: &'a Bvh,
    par: Par,
}

impl<'a> BvhView<'a> {
    /// `tree`, cast with `par`.
    pub fn new(tree: &'a Bvh, par: Par) -> Self {
        Self { tree, par }
    }
}

impl RayBackend for BvhView<'_> {
    fn method(&self) -> &'static str {
        self.tree.method()
    }

    fn backend(&self) -> &'static str {
        self.tree.backend()
    }

    fn update_positions(&mut self, _positions: &[Point3<f64>]) {}

    fn cast(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>], out: &mut Vec<NodeHits>) {
        self.tree
            .cast_ranged_with(origins, dirs, &[], self.par, out);
    }

    fn cast_ranged(
        &mut self,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        ranges: &[RayRange],
        out: &mut Vec<NodeHits>,
    ) {
        self.tree
            .cast_ranged_with(origins, dirs, ranges, self.par, out);
    }
}

#[cfg(test)]
mod tests {
    use super::{round_down, round_up};

    /// The outward roundings never cross `x` and stay within two `f32`
    /// units of it, at every scale, both signs and zero.
    #[test]
    fn outward_roundings_bracket_x_within_two_units() {
        let mut xs = vec![0.0, 1e-300, -1e-300, 1e-40, 1e-30, 0.1, 0.3, 1.0, 1e6, 1e30];
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..10_000 {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
            let m = (state >> 11) as f64 / (1u64 << 53) as f64;
            let e = ((state >> 3) % 40) as i32 - 30;
            xs.push(m * 10f64.powi(e));
        }
        for x in xs.iter().flat_map(|&x| [x, -x]) {
            let (lo, hi) = (round_down(x), round_up(x));
            assert!(f64::from(lo) <= x && f64::from(hi) >= x, "{x}: {lo} {hi}");
            let unit = (x.abs() * 2f64.powi(-23)).max(f64::from(f32::MIN_POSITIVE));
            assert!(x - f64::from(lo) <= 3.0 * unit, "{x}: {lo}");
            assert!(f64::from(hi) - x <= 3.0 * unit, "{x}: {hi}");
        }
    }
}
