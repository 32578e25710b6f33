//! Inside/outside and distance for a closed triangle surface: the generalised
//! winding number (Jacobson et al. 2013) for the sign, the unsigned distance to
//! the triangles for the magnitude, both accelerated by a bounding volume
//! hierarchy.
//!
//! # Math
//! The winding number of a surface about `p` is `w(p) = (1 / 4 pi) sum_t
//! Omega_t(p)`, with the signed solid angle of triangle `(a, b, c)` seen from
//! `p` (Van Oosterom & Strackee 1983), `A = a - p` etc.:
//! `tan(Omega / 2) = A . (B x C) / (|A||B||C| + (A . B)|C| + (B . C)|A| + (C . A)|B|)`.
//! For a closed, consistently oriented surface `w` is 1 inside (or -1 when the
//! triangles face inward) and 0 outside; `|w| >= 1/2` is the inside test,
//! robust to small gaps and rounding. Far from a cluster of triangles (at
//! `|p - c| > beta r`, `c` the area-weighted centroid of the cluster and `r`
//! the radius of its vertices about `c`), the cluster's contribution is its
//! dipole term `N . (c - p) / (4 pi |c - p|^3)` with `N` the sum of the
//! triangles' area vectors (Barill et al., "Fast winding numbers for soups
//! and clouds", 2018, first order); `beta = 2` keeps the error well under
//! 0.1 on the closed surfaces checked by [`super::from_surface`].
//!
//! # Why hand-written
//! The winding number needs per-node moments (area vector, centroid, radius)
//! in the hierarchy; parry's BVH does not carry user data per internal node,
//! and its mesh containment test uses pseudo-normals, which needs the
//! topology this module is used to validate. The hierarchy here is a plain
//! median-split tree over triangle centroids, built once.

use super::sdf::Sdf;
use nalgebra::{Point3, Vector3};

/// Leaf size of the hierarchy.
const LEAF: usize = 4;
/// Far-field acceptance ratio `beta` for the dipole approximation.
const BETA: f64 = 2.0;

#[derive(Debug, Clone)]
struct Node {
    lo: Point3<f64>,
    hi: Point3<f64>,
    /// Sum of area vectors (half cross products), m^2.
    area: Vector3<f64>,
    /// Area-weighted centroid, m.
    centre: Point3<f64>,
    /// Largest distance from `centre` to a vertex of the node's triangles, m.
    radius: f64,
    /// Leaf: range `start..start + count` of `order`; inner: `count == 0`,
    /// children `start` and `start + 1`.
    start: u32,
    count: u32,
}

/// A triangle surface with a bounding volume hierarchy for winding numbers,
/// distances and overlap queries.
#[derive(Debug, Clone)]
pub struct SurfaceField {
    vertices: Vec<Point3<f64>>,
    triangles: Vec<[u32; 3]>,
    order: Vec<u32>,
    nodes: Vec<Node>,
}

impl SurfaceField {
    /// Builds the hierarchy. Indices must be in range (checked by
    /// [`super::from_surface::check_closed_surface`]); out-of-range triangles are
    /// ignored here.
    pub fn new(vertices: &[Point3<f64>], triangles: &[[u32; 3]]) -> Self {
        let triangles: Vec<[u32; 3]> = triangles
            .iter()
            .copied()
            .filter(|t| t.iter().all(|&v| (v as usize) < vertices.len()))
            .collect();
        let mut s = Self {
            vertices: vertices.to_vec(),
            triangles,
            order: Vec::new(),
            nodes: Vec::new(),
        };
        s.order = (0..s.triangles.len() as u32).collect();
        if !s.triangles.is_empty() {
            s.nodes.push(s.make_node(0, s.triangles.len()));
            s.split(0);
        }
        s
    }

    fn tri(&self, t: u32) -> [Point3<f64>; 3] {
        self.triangles[t as usize].map(|v| self.vertices[v as usize])
    }

    fn make_node(&self, start: usize, end: usize) -> Node {
        let mut lo = Point3::from(Vector3::repeat(f64::INFINITY));
        let mut hi = Point3::from(Vector3::repeat(f64::NEG_INFINITY));
        let mut area = Vector3::zeros();
        let mut weighted = Vector3::zeros();
        let mut total = 0.0;
        for &t in &self.order[start..end] {
            let [a, b, c] = self.tri(t);
            for p in [a, b, c] {
                lo = lo.inf(&p);
                hi = hi.sup(&p);
            }
            let av = 0.5 * (b - a).cross(&(c - a));
            let w = av.norm();
            area += av;
            weighted += (a.coords + b.coords + c.coords) / 3.0 * w;
            total += w;
        }
        let centre = if total > 0.0 {
            Point3::from(weighted / total)
        } else {
            nalgebra::center(&lo, &hi)
        };
        let mut radius: f64 = 0.0;
        for &t in &self.order[start..end] {
            for p in self.tri(t) {
                radius = radius.max((p - centre).norm());
            }
        }
        Node {
            lo,
            hi,
            area,
            centre,
            radius,
            start: start as u32,
            count: (end - start) as u32,
        }
    }

    fn split(&mut self, node: usize) {
        let (start, count) = (
            self.nodes[node].start as usize,
            self.nodes[node].count as usize,
        );
        if count <= LEAF {
            return;
        }
        let (lo, hi) = (self.nodes[node].lo, self.nodes[node].hi);
        let axis = (hi - lo).imax();
        let mid = start + count / 2;
        let key = |t: &u32, s: &Self| -> f64 {
            let [a, b, c] = s.tri(*t);
            a[axis] + b[axis] + c[axis]
        };
        let mut slice = std::mem::take(&mut self.order);
        slice[start..start + count]
            .select_nth_unstable_by(count / 2, |x, y| key(x, self).total_cmp(&key(y, self)));
        self.order = slice;
        let left = self.nodes.len();
        let l = self.make_node(start, mid);
        let r = self.make_node(mid, start + count);
        self.nodes.push(l);
        self.nodes.push(r);
        self.nodes[node].start = left as u32;
        self.nodes[node].count = 0;
        self.split(left);
        self.split(left + 1);
    }

    /// The vertices, m.
    pub fn vertices(&self) -> &[Point3<f64>] {
        &self.vertices
    }

    /// The triangles.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Bounds of the vertices, m.
    pub fn bounds(&self) -> (Point3<f64>, Point3<f64>) {
        self.nodes
            .first()
            .map(|n| (n.lo, n.hi))
            .unwrap_or((Point3::origin(), Point3::origin()))
    }

    /// The winding number about `p` with the far-field approximation.
    pub fn winding_number(&self, p: &Point3<f64>) -> f64 {
        if self.nodes.is_empty() {
            return 0.0;
        }
        let mut stack = Vec::with_capacity(64);
        stack.push(0usize);
        let mut sum = 0.0;
        while let Some(n) = stack.pop() {
            let node = &self.nodes[n];
            let d = node.centre - p;
            let dist = d.norm();
            if dist > BETA * node.radius {
                sum += node.area.dot(&d) / (dist * dist * dist);
                continue;
            }
            if node.count == 0 {
                stack.push(node.start as usize);
                stack.push(node.start as usize + 1);
            } else {
                for &t in &self.order[node.start as usize..(node.start + node.count) as usize] {
                    sum += solid_angle(&self.tri(t), p);
                }
            }
        }
        sum / (4.0 * std::f64::consts::PI)
    }

    /// The winding number about `p`, summed exactly over all triangles.
    pub fn winding_number_exact(&self, p: &Point3<f64>) -> f64 {
        (0..self.triangles.len() as u32)
            .map(|t| solid_angle(&self.tri(t), p))
            .sum::<f64>()
            / (4.0 * std::f64::consts::PI)
    }

    /// Unsigned distance from `p` to the surface (m) and the nearest triangle.
    pub fn nearest(&self, p: &Point3<f64>) -> Option<(f64, usize)> {
        if self.nodes.is_empty() {
            return None;
        }
        let mut best = (f64::INFINITY, 0usize);
        let mut stack = Vec::with_capacity(64);
        stack.push(0usize);
        while let Some(n) = stack.pop() {
            let node = &self.nodes[n];
            if box_dist2(&node.lo, &node.hi, p) >= best.0 {
                continue;
            }
            if node.count == 0 {
                let (l, r) = (node.start as usize, node.start as usize + 1);
                let dl = box_dist2(&self.nodes[l].lo, &self.nodes[l].hi, p);
                let dr = box_dist2(&self.nodes[r].lo, &self.nodes[r].hi, p);
                // Visit the nearer child first.
                if dl < dr {
                    stack.push(r);
                    stack.push(l);
                } else {
                    stack.push(l);
                    stack.push(r);
                }
            } else {
                for &t in &self.order[node.start as usize..(node.start + node.count) as usize] {
                    let q = closest_on_triangle(p, &self.tri(t));
                    let d2 = (q - p).norm_squared();
                    if d2 < best.0 {
                        best = (d2, t as usize);
                    }
                }
            }
        }
        Some((best.0.sqrt(), best.1))
    }

    /// Unsigned distance from `p` to the surface, m (infinite when empty).
    pub fn unsigned_distance(&self, p: &Point3<f64>) -> f64 {
        self.nearest(p).map_or(f64::INFINITY, |(d, _)| d)
    }

    /// Calls `visit` with each triangle whose bounding box overlaps `[lo, hi]`.
    pub fn overlapping(&self, lo: &Point3<f64>, hi: &Point3<f64>, mut visit: impl FnMut(usize)) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = vec![0usize];
        while let Some(n) = stack.pop() {
            let node = &self.nodes[n];
            if (0..3).any(|i| node.lo[i] > hi[i] || node.hi[i] < lo[i]) {
                continue;
            }
            if node.count == 0 {
                stack.push(node.start as usize);
                stack.push(node.start as usize + 1);
            } else {
                for &t in &self.order[node.start as usize..(node.start + node.count) as usize] {
                    let [a, b, c] = self.tri(t);
                    let (tl, th) = (a.inf(&b).inf(&c), a.sup(&b).sup(&c));
                    if (0..3).all(|i| tl[i] <= hi[i] && th[i] >= lo[i]) {
                        visit(t as usize);
                    }
                }
            }
        }
    }
}

impl Sdf for SurfaceField {
    /// Unsigned distance, negative where `|w| >= 1/2`.
    fn distance(&self, p: &Point3<f64>) -> f64 {
        let d = self.unsigned_distance(p);
        if self.winding_number(p).abs() >= 0.5 {
            -d
        } else {
            d
        }
    }
}

/// Signed solid angle of triangle `t` seen from `p` (steradians), positive
/// when `p` is behind the triangle's right-hand normal.
pub fn solid_angle(t: &[Point3<f64>; 3], p: &Point3<f64>) -> f64 {
    let (a, b, c) = (t[0] - p, t[1] - p, t[2] - p);
    let (la, lb, lc) = (a.norm(), b.norm(), c.norm());
    let num = a.dot(&b.cross(&c));
    let den = la * lb * lc + a.dot(&b) * lc + b.dot(&c) * la + c.dot(&a) * lb;
    if num == 0.0 && den == 0.0 {
        return 0.0;
    }
    2.0 * num.atan2(den)
}

fn box_dist2(lo: &Point3<f64>, hi: &Point3<f64>, p: &Point3<f64>) -> f64 {
    let mut d2 = 0.0;
    for i in 0..3 {
        let e = (lo[i] - p[i]).max(p[i] - hi[i]).max(0.0);
        d2 += e * e;
    }
    d2
}

/// The point of triangle `t` closest to `p` (Ericson, Real-Time Collision
/// Detection, 5.1.5), by Voronoi regions; degenerate triangles fall back on
/// their edges.
pub fn closest_on_triangle(p: &Point3<f64>, t: &[Point3<f64>; 3]) -> Point3<f64> {
    let [a, b, c] = *t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return a + ab * v;
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return a + ac * w;
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return b + (c - b) * w;
    }
    let denom = va + vb + vc;
    if denom.abs() <= f64::MIN_POSITIVE || !denom.is_finite() {
        // Degenerate: nearest of the three edges.
        let seg = |u: Point3<f64>, v: Point3<f64>| {
            let d = v - u;
            let l2 = d.norm_squared();
            let s = if l2 > 0.0 {
                ((p - u).dot(&d) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            u + d * s
        };
        return [seg(a, b), seg(b, c), seg(c, a)]
            .into_iter()
            .min_by(|x, y| (x - p).norm_squared().total_cmp(&(y - p).norm_squared()))
            .unwrap_or(a);
    }
    let v = vb / denom;
    let w = vc / denom;
    a + ab * v + ac * w
}

/// Two triangle surfaces as one: the vertices of `b` after those of `a`,
/// its triangles renumbered (for tests and examples: several bodies, or
/// bodies crossing each other, in one surface).
pub fn join_surfaces(
    a: (Vec<Point3<f64>>, Vec<[u32; 3]>),
    b: (Vec<Point3<f64>>, Vec<[u32; 3]>),
) -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
    let (mut v, mut t) = a;
    let n = v.len() as u32;
    v.extend(b.0);
    t.extend(b.1.iter().map(|x| x.map(|k| k + n)));
    (v, t)
}

/// A closed, outward-oriented triangulation of a sphere (geodesic: an
/// icosahedron subdivided `level` times and projected), for tests and examples.
pub fn icosphere(
    centre: Point3<f64>,
    radius: f64,
    level: u32,
) -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<Vector3<f64>> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|c| Vector3::new(c[0], c[1], c[2]).normalize())
    .collect();
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..level {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::with_capacity(f.len() * 4);
        let mut m = |a: u32, b: u32, v: &mut Vec<Vector3<f64>>| -> u32 {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push(((v[a as usize] + v[b as usize]) * 0.5).normalize());
                (v.len() - 1) as u32
            })
        };
        for [a, b, c] in f {
            let (ab, bc, ca) = (m(a, b, &mut v), m(b, c, &mut v), m(c, a, &mut v));
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = next;
    }
    (v.into_iter().map(|d| centre + d * radius).collect(), f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn winding_number_inside_outside_and_fast_matches_exact() {
        let (v, f) = icosphere(Point3::new(0.01, 0.02, -0.01), 0.05, 3);
        let s = SurfaceField::new(&v, &f);
        assert!((s.winding_number_exact(&Point3::new(0.01, 0.02, -0.01)) - 1.0).abs() < 1e-9);
        assert!(s.winding_number_exact(&Point3::new(0.2, 0.0, 0.0)).abs() < 1e-9);
        for i in 0..200 {
            let x = (i as f64 * 0.61803).fract() * 0.16 - 0.07;
            let y = (i as f64 * 0.41421).fract() * 0.16 - 0.06;
            let z = (i as f64 * 0.73205).fract() * 0.16 - 0.09;
            let p = Point3::new(x, y, z);
            let (fast, exact) = (s.winding_number(&p), s.winding_number_exact(&p));
            assert!((fast - exact).abs() < 0.05, "{p:?}: {fast} vs {exact}");
            let inside = (p - Point3::new(0.01, 0.02, -0.01)).norm() < 0.05;
            let d = s.distance(&p);
            if (p - Point3::new(0.01, 0.02, -0.01)).norm() - 0.05 > 0.001
                || inside && d.abs() > 0.001
            {
                assert_eq!(d < 0.0, inside, "{p:?}");
            }
        }
    }

    #[test]
    fn distance_matches_brute_force() {
        let (v, f) = icosphere(Point3::origin(), 0.05, 2);
        let s = SurfaceField::new(&v, &f);
        for i in 0..100 {
            let p = Point3::new(
                (i as f64 * 0.3719).sin() * 0.08,
                (i as f64 * 0.7713).cos() * 0.08,
                (i as f64 * 1.1131).sin() * 0.08,
            );
            let brute = f
                .iter()
                .map(|t| {
                    let tri = t.map(|k| v[k as usize]);
                    (closest_on_triangle(&p, &tri) - p).norm()
                })
                .fold(f64::INFINITY, f64::min);
            assert!((s.unsigned_distance(&p) - brute).abs() < 1e-15);
        }
    }

    #[test]
    fn closest_point_handles_regions_and_degenerate_triangles() {
        let t = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
        ];
        let q = closest_on_triangle(&Point3::new(0.2, 0.2, 3.0), &t);
        assert!((q - Point3::new(0.2, 0.2, 0.0)).norm() < 1e-15);
        assert_eq!(closest_on_triangle(&Point3::new(-1.0, -1.0, 0.0), &t), t[0]);
        assert_eq!(
            closest_on_triangle(&Point3::new(0.5, -1.0, 0.0), &t),
            Point3::new(0.5, 0.0, 0.0)
        );
        let q = closest_on_triangle(&Point3::new(1.0, 1.0, 0.0), &t);
        assert!((q - Point3::new(0.5, 0.5, 0.0)).norm() < 1e-15);
        // Collinear (zero-area) triangle: still a point of the segment.
        let d = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(2.0, 0.0, 0.0),
        ];
        let q = closest_on_triangle(&Point3::new(1.5, 1.0, 0.0), &d);
        assert!((q - Point3::new(1.5, 0.0, 0.0)).norm() < 1e-12);
        assert_eq!(solid_angle(&d, &Point3::new(0.0, 0.0, 0.0)), 0.0);
    }
}
