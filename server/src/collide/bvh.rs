//! A bounding-volume hierarchy over the deforming surface, refitted each step.
//!
//! Binary tree of axis-aligned boxes, built once by median splits of triangle
//! centroids along the longest axis (leaves of at most [`LEAF_SIZE`]
//! triangles), stored depth-first so that a node's left child is the next node
//! and children always follow their parent; [`RayBackend::update_positions`]
//! *refits* (gathers the new vertex positions into leaf order, recomputes the
//! leaf boxes and unions them bottom-up in one reverse sweep) without changing
//! the topology. Large deformations make the boxes overlap more and the
//! queries slower, never wrong; [`Bvh::rebuild`] rebuilds the topology.
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
//! index, exactly as in the brute force ([`keep_nearest`]), so answers are
//! identical to the reference, bit for bit.
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

#[derive(Debug, Clone, Copy)]
struct Node {
    lo: [f64; 3],
    hi: [f64; 3],
    /// Leaf: first triangle (leaf order). Inner: index of the right child (the
    /// left child is the next node).
    index: u32,
    /// Leaf: number of triangles. Inner: 0.
    count: u32,
}

/// BVH backend (CPU).
#[derive(Debug, Clone)]
pub struct Bvh {
    /// Triangles in leaf order.
    triangles: Vec<[u32; 3]>,
    /// Leaf order -> original triangle index.
    ids: Vec<u32>,
    /// Vertex positions of the triangles, leaf order (refreshed by refit).
    verts: Vec<[Point3<f64>; 3]>,
    nodes: Vec<Node>,
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
        let mut bvh = Self {
            triangles: triangles.to_vec(),
            ids: (0..triangles.len() as u32).collect(),
            verts: Vec::new(),
            nodes: Vec::new(),
            test,
            needed,
            valid: true,
        };
        bvh.build(positions);
        bvh.refit(positions);
        Ok(bvh)
    }

    /// Number of tree nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Rebuilds the topology for the current `positions` (after large
    /// deformations), then refits.
    pub fn rebuild(&mut self, positions: &[Point3<f64>]) {
        if positions.len() < self.needed {
            self.valid = false;
            return;
        }
        self.build(positions);
        self.refit(positions);
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
        if !items.is_empty() {
            self.nodes.reserve(2 * items.len() / LEAF_SIZE + 1);
            Self::split(&mut self.nodes, &mut items, 0);
        }
        self.ids = items.iter().map(|e| e.1).collect();
        self.triangles = items.iter().map(|e| e.2).collect();
    }

    /// Emits the subtree of `items` (which start at leaf-order index `first`).
    fn split(nodes: &mut Vec<Node>, items: &mut [(Point3<f64>, u32, [u32; 3])], first: usize) {
        let me = nodes.len();
        nodes.push(Node {
            lo: [0.0; 3],
            hi: [0.0; 3],
            index: first as u32,
            count: items.len() as u32,
        });
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
        Self::split(nodes, left, first);
        let r = nodes.len() as u32;
        Self::split(nodes, right, first + mid);
        nodes[me].index = r;
        nodes[me].count = 0;
    }

    /// Gathers positions and recomputes all boxes (no allocation).
    fn refit(&mut self, positions: &[Point3<f64>]) {
        self.verts
            .resize(self.triangles.len(), [Point3::origin(); 3]);
        for (v, t) in self.verts.iter_mut().zip(&self.triangles) {
            *v = t.map(|i| positions[i as usize]);
        }
        for k in (0..self.nodes.len()).rev() {
            let n = self.nodes[k];
            let (lo, hi) = if n.count > 0 {
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
                (lo.map(|x| x - pad), hi.map(|x| x + pad))
            } else {
                let (l, r) = (&self.nodes[k + 1], &self.nodes[n.index as usize]);
                (
                    [0, 1, 2].map(|a| l.lo[a].min(r.lo[a])),
                    [0, 1, 2].map(|a| l.hi[a].max(r.hi[a])),
                )
            };
            self.nodes[k].lo = lo;
            self.nodes[k].hi = hi;
        }
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
                if o[a] < n.lo[a] || o[a] > n.hi[a] {
                    return None;
                }
            } else {
                let ta = (n.lo[a] - o[a]) * inv[a];
                let tb = (n.hi[a] - o[a]) * inv[a];
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
        self.valid = positions.len() >= self.needed;
        if self.valid {
            self.refit(positions);
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
