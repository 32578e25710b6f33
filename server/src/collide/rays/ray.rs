//! Ray-triangle intersection along a whole line (signed `t`).
//!
//! Two tests, both returning the signed line parameter `t` of `origin + t * dir`
//! (negative behind the origin: the collision method casts *lines*, and hits
//! behind a source node count) and the barycentric coordinates `(u, v)` of the
//! second and third vertex, so that the hit point is
//! `(1 - u - v) a + u b + v c`.
//!
//! * [`moller_trumbore`]: the classic test of Möller and Trumbore (1997) that the
//!   paper used. Edges are closed on both sides, so a ray through a shared edge
//!   can report both triangles, and rounding can let a ray slip between two
//!   triangles. Kept for comparison.
//! * [`WatertightRay`] / [`watertight`]: the watertight test of Woop, Benthin and
//!   Wald, "Watertight ray/triangle intersection", JCGT 2(1), 2013. The ray is
//!   sheared so that it becomes the `+z` axis; the three 2D edge functions
//!   `U = Cx By - Cy Bx`, `V = Ax Cy - Ay Cx`, `W = Bx Ay - By Ax` of the sheared
//!   vertices are computed from per-vertex values only, so the edge function of
//!   an edge shared by two triangles is the exact negation of the other's and no
//!   ray can fall through the crack. Where an edge function is exactly zero (the
//!   ray passes exactly through an edge or a vertex) a *tie rule* decides: the
//!   edge, oriented so that the triangle's inside is on its right, is owned when
//!   its sheared direction `e` satisfies `e.y > 0 || (e.y == 0 && e.x > 0)`.
//!   Two triangles on opposite sides of a shared edge see the edge in opposite
//!   directions, so exactly one owns it; around a shared vertex (a complete fan
//!   of non-overlapping triangles) exactly one triangle owns both its edges
//!   through the vertex (the half-plane argument of the rasteriser's top-left
//!   rule). The pipeline uses this test by default.
//!
//! Both tests reject, without producing NaN or infinity:
//! * rays parallel to the triangle's plane, `|n . d| <= 1e-12 |n| |d|` (`n` the
//!   triangle's normal), i.e. within 1e-12 rad of grazing;
//! * degenerate triangles, `|n| <= 1e-12 * (longest edge)^2` (zero area,
//!   collinear or repeated vertices).
//!
//! Units: whatever the positions use (m in fissure); `t` is in units of `|dir|`.

use nalgebra::{Point3, Vector3};

/// Relative tolerance of the parallel-ray and degenerate-triangle rejections.
pub const DEGENERACY_TOL: f64 = 1e-12;

/// Which ray-triangle test a backend uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RayTest {
    /// Woop, Benthin, Wald (2013) with the tie rule of this module (default).
    #[default]
    Watertight,
    /// Möller and Trumbore (1997), closed edges.
    MollerTrumbore,
}

/// A line-triangle hit: signed parameter and barycentric coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayHit {
    /// Signed line parameter: the hit is at `origin + t * dir`.
    pub t: f64,
    /// Barycentric coordinate of the second vertex.
    pub u: f64,
    /// Barycentric coordinate of the third vertex.
    pub v: f64,
}

/// Returns `true` when the triangle is degenerate or the line is parallel to
/// it (see the module documentation for the tolerances). A function of the
/// direction and the triangle only: parallel rays may share one evaluation
/// ([`WatertightRay::intersect_from`]).
#[inline]
pub(crate) fn degenerate_or_parallel(
    dir: &Vector3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> bool {
    let e1 = b - a;
    let e2 = c - a;
    let e3 = c - b;
    let n = e1.cross(&e2);
    let n2 = n.norm_squared();
    let longest2 = e1
        .norm_squared()
        .max(e2.norm_squared())
        .max(e3.norm_squared());
    // |n| <= tol * longest^2  <=>  n2 <= tol^2 * longest^4
    if n2 <= DEGENERACY_TOL * DEGENERACY_TOL * longest2 * longest2 || n2.is_nan() || n2 <= 0.0 {
        return true;
    }
    let nd = n.dot(dir);
    nd * nd <= DEGENERACY_TOL * DEGENERACY_TOL * n2 * dir.norm_squared()
}

/// Möller–Trumbore line-triangle test with closed edges (`u >= 0`, `v >= 0`,
/// `u + v <= 1`); `t` is signed. `None` for a miss, a parallel line or a
/// degenerate triangle.
pub fn moller_trumbore(
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> Option<RayHit> {
    let e1 = b - a;
    let e2 = c - a;
    let p = dir.cross(&e2);
    let det = e1.dot(&p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - a;
    let u = s.dot(&p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(&e1);
    let v = dir.dot(&q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    if degenerate_or_parallel(dir, a, b, c) {
        return None;
    }
    let t = e2.dot(&q) * inv;
    t.is_finite().then_some(RayHit { t, u, v })
}

/// A line prepared for the watertight test: the permutation that makes the
/// dominant direction component the `z` axis, and the shear that maps the
/// direction onto it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WatertightRay {
    /// Line origin.
    pub origin: Point3<f64>,
    /// Line direction (not necessarily unit).
    pub dir: Vector3<f64>,
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f64,
    sy: f64,
    sz: f64,
}

impl WatertightRay {
    /// Prepares the line `origin + t * dir`. `dir` must be non-zero and finite;
    /// a zero direction gives a line that hits nothing.
    pub fn new(origin: Point3<f64>, dir: Vector3<f64>) -> Self {
        let abs = dir.abs();
        let kz = if abs.x >= abs.y && abs.x >= abs.z {
            0
        } else if abs.y >= abs.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        // Keep the winding of the sheared triangle independent of the sign of
        // the dominant component.
        if dir[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let dz = dir[kz];
        let (sx, sy, sz) = if dz != 0.0 && dz.is_finite() {
            (dir[kx] / dz, dir[ky] / dz, 1.0 / dz)
        } else {
            (0.0, 0.0, 0.0)
        };
        Self {
            origin,
            dir,
            kx,
            ky,
            kz,
            sx,
            sy,
            sz,
        }
    }

    /// Sheared 2D position of a vertex relative to the origin, and its
    /// unscaled depth along the line (times `sz`: the scaled depth, which
    /// only a hit needs).
    #[inline(always)]
    fn shear(&self, origin: &Point3<f64>, p: &Point3<f64>) -> (f64, f64, f64) {
        let d = p - origin;
        let z = d[self.kz];
        (d[self.kx] - self.sx * z, d[self.ky] - self.sy * z, z)
    }

    /// The watertight line-triangle test with the module's tie rule; `t` is
    /// signed. `None` for a miss, a parallel line or a degenerate triangle.
    #[inline]
    pub fn intersect(&self, a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>) -> Option<RayHit> {
        self.intersect_from(&self.origin, a, b, c, || {
            degenerate_or_parallel(&self.dir, a, b, c)
        })
    }

    /// [`Self::intersect`] for the parallel line through `origin` (the same
    /// direction, hence the same permutation and shear): the same operations
    /// on the same values, so the same answer bit for bit as a ray prepared
    /// at `origin`. `degenerate` must return
    /// `degenerate_or_parallel(dir, a, b, c)`; it is called at most once,
    /// only for a line that passes the edge tests, so that the rays of a
    /// bundle can share one evaluation per triangle.
    #[inline(always)]
    pub(crate) fn intersect_from(
        &self,
        origin: &Point3<f64>,
        a: &Point3<f64>,
        b: &Point3<f64>,
        c: &Point3<f64>,
        degenerate: impl FnOnce() -> bool,
    ) -> Option<RayHit> {
        if self.sz == 0.0 {
            return None;
        }
        let (ax, ay, az) = self.shear(origin, a);
        let (bx, by, bz) = self.shear(origin, b);
        let (cx, cy, cz) = self.shear(origin, c);
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        // Quick rejection: mixed strict signs.
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let s = det.signum();
        // Tie rule on edges through the line: each edge, oriented with the
        // inside on its right, is owned when its direction lies in the half-open
        // half plane {y > 0} U {y == 0, x > 0}.
        let owned = |sx0: f64, sy0: f64, sx1: f64, sy1: f64| {
            let ex = s * (sx1 - sx0);
            let ey = s * (sy1 - sy0);
            ey > 0.0 || (ey == 0.0 && ex > 0.0)
        };
        // U: edge B -> C, V: edge C -> A, W: edge A -> B.
        if u == 0.0 && !owned(bx, by, cx, cy) {
            return None;
        }
        if v == 0.0 && !owned(cx, cy, ax, ay) {
            return None;
        }
        if w == 0.0 && !owned(ax, ay, bx, by) {
            return None;
        }
        if degenerate() {
            return None;
        }
        let (az, bz, cz) = (self.sz * az, self.sz * bz, self.sz * cz);
        let t = (u * az + v * bz + w * cz) / det;
        let inv = 1.0 / det;
        let hit = RayHit {
            t,
            u: v * inv,
            v: w * inv,
        };
        (t.is_finite() && hit.u.is_finite() && hit.v.is_finite()).then_some(hit)
    }
}

/// One-off watertight test; prefer [`WatertightRay`] when one line meets many
/// triangles.
pub fn watertight(
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> Option<RayHit> {
    WatertightRay::new(*origin, *dir).intersect(a, b, c)
}

/// A line prepared for either test.
#[derive(Debug, Clone, Copy)]
pub struct PreparedRay {
    test: RayTest,
    ray: WatertightRay,
}

impl PreparedRay {
    /// Prepares `origin + t * dir` for `test`.
    #[inline]
    pub fn new(test: RayTest, origin: Point3<f64>, dir: Vector3<f64>) -> Self {
        Self {
            test,
            ray: WatertightRay::new(origin, dir),
        }
    }

    /// Intersects the line with triangle `(a, b, c)`.
    #[inline]
    pub fn intersect(&self, a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>) -> Option<RayHit> {
        match self.test {
            RayTest::Watertight => self.ray.intersect(a, b, c),
            RayTest::MollerTrumbore => moller_trumbore(&self.ray.origin, &self.ray.dir, a, b, c),
        }
    }

    /// Line origin.
    pub fn origin(&self) -> &Point3<f64> {
        &self.ray.origin
    }

    /// Line direction.
    pub fn dir(&self) -> &Vector3<f64> {
        &self.ray.dir
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(x: f64, y: f64, z: f64) -> Point3<f64> {
        Point3::new(x, y, z)
    }

    fn both(
        o: Point3<f64>,
        d: Vector3<f64>,
        a: Point3<f64>,
        b: Point3<f64>,
        c: Point3<f64>,
    ) -> [Option<RayHit>; 2] {
        [
            watertight(&o, &d, &a, &b, &c),
            moller_trumbore(&o, &d, &a, &b, &c),
        ]
    }

    #[test]
    fn signed_t_and_barycentrics_agree() {
        let (a, b, c) = (p(0.0, 0.0, 1.0), p(1.0, 0.0, 1.0), p(0.0, 1.0, 1.0));
        for (oz, t) in [(0.0, 1.0), (3.0, -2.0)] {
            let o = p(0.2, 0.3, oz);
            for h in both(o, Vector3::z(), a, b, c) {
                let h = h.expect("hit");
                assert!((h.t - t).abs() < 1e-15, "{h:?}");
                assert!(
                    (h.u - 0.2).abs() < 1e-15 && (h.v - 0.3).abs() < 1e-15,
                    "{h:?}"
                );
            }
            // Reversed direction: same point, opposite sign of t.
            for h in both(o, -Vector3::z(), a, b, c) {
                assert!((h.expect("hit").t + t).abs() < 1e-15);
            }
        }
        // A miss.
        for h in both(p(0.8, 0.8, 0.0), Vector3::z(), a, b, c) {
            assert!(h.is_none());
        }
    }

    #[test]
    fn parallel_ray_gives_no_hit_and_no_nan() {
        let (a, b, c) = (p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0), p(0.0, 1.0, 0.0));
        // In the plane, through the interior; above the plane; nearly parallel.
        for (o, d) in [
            (p(-1.0, 0.25, 0.0), Vector3::x()),
            (p(-1.0, 0.25, 0.0), Vector3::new(1.0, 1.0, 0.0).normalize()),
            (p(-1.0, 0.25, 1e-3), Vector3::x()),
            (
                p(-1.0, 0.25, 0.0),
                Vector3::new(1.0, 0.0, 1e-14).normalize(),
            ),
        ] {
            for h in both(o, d, a, b, c) {
                assert!(h.is_none(), "{o} {d} {h:?}");
            }
        }
    }

    #[test]
    fn degenerate_triangles_give_no_hit() {
        let o = p(0.5, 0.0, -1.0);
        let d = Vector3::z();
        let cases = [
            // repeated vertex
            (p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0), p(1.0, 0.0, 0.0)),
            // all equal
            (p(0.5, 0.0, 0.0), p(0.5, 0.0, 0.0), p(0.5, 0.0, 0.0)),
            // collinear, the line passes through the segment
            (p(0.0, 0.0, 0.0), p(0.5, 0.0, 0.0), p(1.0, 0.0, 0.0)),
            // collinear up to rounding
            (p(0.0, 0.0, 0.0), p(1.0 / 3.0, 1e-17, 0.0), p(1.0, 0.0, 0.0)),
        ];
        for (a, b, c) in cases {
            for h in both(o, d, a, b, c) {
                assert!(h.is_none(), "{a} {b} {c} {h:?}");
            }
        }
    }

    /// A ray exactly through a shared edge hits exactly one of the two
    /// triangles, whatever the orientation of the quad and the ray.
    #[test]
    fn shared_edge_hits_exactly_one() {
        // Quad split along its diagonal (0,0)-(1,1), consistently oriented.
        let q = [
            p(0.0, 0.0, 0.0),
            p(1.0, 0.0, 0.0),
            p(1.0, 1.0, 0.0),
            p(0.0, 1.0, 0.0),
        ];
        let tris = [[0, 1, 2], [0, 2, 3]];
        for dz in [1.0, -1.0] {
            for s in [0.25, 0.5, 0.75, 0.0, 1.0] {
                // Axis-aligned rays through the diagonal (exact in floating point),
                // and through the outer edges (owned by one triangle or none).
                let o = p(s, s, -dz);
                let d = Vector3::new(0.0, 0.0, dz);
                let n = tris
                    .iter()
                    .filter(|t| watertight(&o, &d, &q[t[0]], &q[t[1]], &q[t[2]]).is_some())
                    .count();
                if s > 0.0 && s < 1.0 {
                    assert_eq!(n, 1, "s {s} dz {dz}");
                } else {
                    assert!(n <= 1, "corner s {s}");
                }
            }
        }
        // Möller–Trumbore with closed edges reports both: why it is not the default.
        let o = p(0.5, 0.5, -1.0);
        let n = tris
            .iter()
            .filter(|t| moller_trumbore(&o, &Vector3::z(), &q[t[0]], &q[t[1]], &q[t[2]]).is_some())
            .count();
        assert_eq!(n, 2);
    }

    /// Oblique rays aimed at points of a shared edge: the edge functions of the
    /// two triangles are exact negations, so exactly one triangle is hit (no
    /// crack, no double hit) even where rounding moves the ray off the edge.
    #[test]
    fn oblique_rays_through_shared_edges_hit_exactly_one() {
        let q = [
            p(0.1, -0.2, 0.3),
            p(1.3, 0.1, 0.2),
            p(1.1, 1.2, 0.5),
            p(-0.1, 0.9, 0.1),
        ];
        let tris = [[0, 1, 2], [0, 2, 3]];
        let mut rnd = crate::test_rng::unit(0);
        for _ in 0..2000 {
            let s = rnd();
            let target = q[0] + (q[2] - q[0]) * s;
            let d = Vector3::new(rnd() - 0.5, rnd() - 0.5, 0.5 + rnd()).normalize();
            let o = target - d * (0.5 + rnd());
            let n = tris
                .iter()
                .filter(|t| watertight(&o, &d, &q[t[0]], &q[t[1]], &q[t[2]]).is_some())
                .count();
            assert_eq!(n, 1, "s {s} d {d}");
        }
    }

    /// A ray exactly through a vertex shared by a closed fan hits exactly one
    /// triangle of the fan, for both ray directions and several fan shapes.
    #[test]
    fn shared_vertex_hits_exactly_one() {
        for sides in [3usize, 4, 5, 6, 8] {
            for rot in 0..sides {
                let c = p(0.0, 0.0, 0.0);
                let ring: Vec<Point3<f64>> = (0..sides)
                    .map(|i| {
                        // Irregular ring with exactly representable coordinates.
                        let ang = std::f64::consts::TAU * ((i + rot) as f64 + 0.3 * (i % 2) as f64)
                            / sides as f64;
                        p(
                            (ang.cos() * 8.0).round() / 8.0,
                            (ang.sin() * 8.0).round() / 8.0,
                            0.25,
                        )
                    })
                    .collect();
                for dz in [1.0, -1.0] {
                    let o = p(0.0, 0.0, -2.0 * dz);
                    let d = Vector3::new(0.0, 0.0, dz);
                    let n = (0..sides)
                        .filter(|&i| {
                            let (a, b) = (ring[i], ring[(i + 1) % sides]);
                            let c = p(c.x, c.y, 0.0);
                            watertight(&o, &d, &c, &a, &b).is_some()
                        })
                        .count();
                    assert_eq!(n, 1, "sides {sides} rot {rot} dz {dz}");
                }
            }
        }
    }

    #[test]
    fn prepared_ray_matches_free_functions() {
        let (a, b, c) = (p(0.0, 0.0, 1.0), p(1.0, 0.0, 1.5), p(0.0, 1.0, 0.5));
        let o = p(0.2, 0.2, -1.0);
        let d = Vector3::new(0.1, 0.05, 1.0).normalize();
        let w = PreparedRay::new(RayTest::Watertight, o, d)
            .intersect(&a, &b, &c)
            .unwrap();
        let m = PreparedRay::new(RayTest::MollerTrumbore, o, d)
            .intersect(&a, &b, &c)
            .unwrap();
        assert!(
            (w.t - m.t).abs() < 1e-14 && (w.u - m.u).abs() < 1e-14 && (w.v - m.v).abs() < 1e-14
        );
        assert_eq!(Some(w), watertight(&o, &d, &a, &b, &c));
    }
}
