//! A flat, level-ordered BVH over the surface triangles, laid out for the GPU.
//!
//! Built once from the rest surface (the topology never changes; only positions
//! move) by top-down median splits of the triangle centroids along the longest
//! axis of their box, leaves of at most [`Lbvh::LEAF`] triangles. Nodes are stored
//! breadth first, so every level is a contiguous range and a refit is one pass per
//! level from the deepest up (on the GPU: one dispatch per level). The two
//! children of an internal node are adjacent. Median splits keep the depth at
//! `ceil(log2(n / LEAF)) + 1`, well inside the traversal stack.
//!
//! Written here rather than taken from a crate because the GPU needs this exact
//! flat layout (boxes, child/leaf words, level ranges) to refit and traverse, and
//! the BVHs of parry or bvh crates are neither level-ordered nor uploadable.

use bytemuck::{Pod, Zeroable};
use nalgebra::Point3;

/// One node as the kernels read it (`Node` in `bvh.wgsl`). Boxes are f32 in the
/// centred frame of the backend.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct LbvhNode {
    /// Box minimum (m, centred).
    pub lo: [f32; 3],
    /// Internal: index of the left child (the right child is `a + 1`). Leaf: first
    /// triangle in BVH order.
    pub a: u32,
    /// Box maximum (m, centred).
    pub hi: [f32; 3],
    /// Leaf: triangle count (`>= 1`). Internal: 0.
    pub b: u32,
}

/// The BVH: nodes (breadth first), triangle order, level ranges.
#[derive(Debug, Clone)]
pub struct Lbvh {
    /// Nodes, root first, breadth first.
    pub nodes: Vec<LbvhNode>,
    /// Triangle ids in leaf order: leaf triangles `a..a + b` are `order[a..a + b]`.
    pub order: Vec<u32>,
    /// `(first node, node count)` of each level, root level first.
    pub levels: Vec<(u32, u32)>,
}

impl Lbvh {
    /// Most triangles in a leaf.
    pub const LEAF: usize = 4;

    /// Builds the tree over `triangles` at `positions` (any frame: only the
    /// topology is kept; boxes are set by [`Lbvh::refit`]).
    pub fn build(triangles: &[[u32; 3]], positions: &[Point3<f64>]) -> Self {
        let centroids: Vec<Point3<f64>> = triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|k| positions[k as usize].coords);
                Point3::from((a + b + c) / 3.0)
            })
            .collect();
        let mut order: Vec<u32> = (0..triangles.len() as u32).collect();
        let mut nodes = Vec::new();
        let mut levels = Vec::new();
        if triangles.is_empty() {
            return Self {
                nodes,
                order,
                levels,
            };
        }
        // (node index, first, count) of the current level.
        let mut level = vec![(0usize, 0usize, triangles.len())];
        nodes.push(LbvhNode::default());
        while !level.is_empty() {
            levels.push((level[0].0 as u32, level.len() as u32));
            let mut next = Vec::new();
            for &(node, first, count) in &level {
                if count <= Self::LEAF {
                    nodes[node].a = first as u32;
                    nodes[node].b = count as u32;
                    continue;
                }
                let range = &mut order[first..first + count];
                let (lo, hi) = range.iter().fold(
                    (
                        Point3::from([f64::INFINITY; 3]),
                        Point3::from([f64::NEG_INFINITY; 3]),
                    ),
                    |(lo, hi), &t| {
                        (
                            lo.inf(&centroids[t as usize]),
                            hi.sup(&centroids[t as usize]),
                        )
                    },
                );
                let axis = (hi - lo).imax();
                let half = count / 2;
                range.select_nth_unstable_by(half, |&x, &y| {
                    centroids[x as usize][axis]
                        .total_cmp(&centroids[y as usize][axis])
                        .then(x.cmp(&y))
                });
                let left = nodes.len();
                nodes.push(LbvhNode::default());
                nodes.push(LbvhNode::default());
                nodes[node].a = left as u32;
                nodes[node].b = 0;
                next.push((left, first, half));
                next.push((left + 1, first + half, count - half));
            }
            level = next;
        }
        Self {
            nodes,
            order,
            levels,
        }
    }

    /// Recomputes every box from `positions` (f32, centred, `[x, y, z, _]`),
    /// deepest level first.
    pub fn refit(&mut self, triangles: &[[u32; 3]], positions: &[[f32; 4]]) {
        for &(first, count) in self.levels.iter().rev() {
            for i in first as usize..(first + count) as usize {
                let n = self.nodes[i];
                let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
                if n.b == 0 {
                    let (l, r) = (self.nodes[n.a as usize], self.nodes[n.a as usize + 1]);
                    for k in 0..3 {
                        lo[k] = l.lo[k].min(r.lo[k]);
                        hi[k] = l.hi[k].max(r.hi[k]);
                    }
                } else {
                    for &t in &self.order[n.a as usize..(n.a + n.b) as usize] {
                        for &v in &triangles[t as usize] {
                            let p = positions[v as usize];
                            for k in 0..3 {
                                lo[k] = lo[k].min(p[k]);
                                hi[k] = hi[k].max(p[k]);
                            }
                        }
                    }
                }
                self.nodes[i].lo = lo;
                self.nodes[i].hi = hi;
            }
        }
    }

    /// Depth (number of levels).
    pub fn depth(&self) -> usize {
        self.levels.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_triangle_in_one_leaf_and_boxes_contain_children() {
        let n = 37;
        let positions: Vec<Point3<f64>> = (0..n + 2)
            .map(|i| {
                Point3::new(
                    (i as f64 * 0.37).sin(),
                    (i as f64 * 0.11).cos(),
                    i as f64 * 0.01,
                )
            })
            .collect();
        let triangles: Vec<[u32; 3]> = (0..n as u32).map(|i| [i, i + 1, i + 2]).collect();
        let mut bvh = Lbvh::build(&triangles, &positions);
        let f32pos: Vec<[f32; 4]> = positions
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32, 0.0])
            .collect();
        bvh.refit(&triangles, &f32pos);
        let mut seen = vec![0; n];
        for node in &bvh.nodes {
            if node.b > 0 {
                assert!(node.b as usize <= Lbvh::LEAF);
                for &t in &bvh.order[node.a as usize..(node.a + node.b) as usize] {
                    seen[t as usize] += 1;
                    for &v in &triangles[t as usize] {
                        for k in 0..3 {
                            assert!(
                                node.lo[k] <= f32pos[v as usize][k]
                                    && f32pos[v as usize][k] <= node.hi[k]
                            );
                        }
                    }
                }
            } else {
                for c in [node.a as usize, node.a as usize + 1] {
                    for k in 0..3 {
                        assert!(
                            node.lo[k] <= bvh.nodes[c].lo[k] && bvh.nodes[c].hi[k] <= node.hi[k]
                        );
                    }
                }
            }
        }
        assert!(seen.iter().all(|&s| s == 1));
        assert!(bvh.depth() <= (n as f64 / Lbvh::LEAF as f64).log2().ceil() as usize + 1);
    }
}
