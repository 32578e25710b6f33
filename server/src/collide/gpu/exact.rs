//! The f64 line-triangle test that decides every answer of the GPU backends, and
//! the f64 brute force over it (the reference the GPU answers equal).
//!
//! [`intersect`] is the watertight test of Woop, Benthin and Wald, "Watertight
//! ray/triangle intersection", JCGT 2(1), 2013, without back-face culling: with
//! `kz` the axis of the largest `|d|` component (`kx, ky` the next two, swapped
//! when `d[kz] < 0` to keep the winding), the vertices relative to the origin are
//! sheared so the ray becomes the `z` axis:
//! `x = a[kx] - (d[kx]/d[kz]) a[kz]`, `y = a[ky] - (d[ky]/d[kz]) a[kz]`,
//! `z = a[kz] / d[kz]`. The edge functions `U = e(B, C)`, `V = e(C, A)`,
//! `W = e(A, B)` with `e(P, Q) = Qx Py - Qy Px` are the scaled barycentrics; a
//! shared edge gives exactly opposite values in its two triangles.
//!
//! Tie rule (rays through edges and vertices): with `s = sign(U + V + W)`, edge
//! `P -> Q` admits the ray when `s e > 0`, or when `e = 0` and the edge direction
//! `s (Q - P)` is "top-left": `dy > 0 || (dy == 0 && dx < 0)`. Reversed edges give
//! the opposite answer, so of two triangles sharing an edge (consistent
//! orientation, same facing) exactly one is hit, and around a vertex exactly one
//! triangle of the fan is hit. `U + V + W = 0` (a line parallel to the plane, a
//! degenerate triangle) is no hit.
//!
//! `t = (U za + V zb + W zc) / det`, `u = V / det`, `v = W / det` (barycentrics
//! of the second and third vertex), `det = U + V + W`.
//!
//! Nearest per side: behind is `t <= 0` with the smallest `-t`, in front is
//! `t > 0` with the smallest `t`; equal `t` goes to the lower triangle index.

use nalgebra::{Point3, Vector3};

use crate::collide::{Hit, NodeHits};

/// A ray prepared for [`intersect_frame`]: the projection axes and shear.
#[derive(Debug, Clone, Copy)]
pub struct RayFrame {
    origin: Point3<f64>,
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f64,
    sy: f64,
    sz: f64,
}

impl RayFrame {
    /// Frame of the line `origin + t dir`; `None` when `dir` is zero or not finite.
    pub fn new(origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Self> {
        let a = dir.abs();
        let mut kz = 0;
        if a.y > a.x {
            kz = 1;
        }
        if a.z > a.x.max(a.y) {
            kz = 2;
        }
        let dz = dir[kz];
        if dz == 0.0 || !dz.is_finite() || !dir.iter().all(|c| c.is_finite()) {
            return None;
        }
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        if dz < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        Some(Self {
            origin: *origin,
            kx,
            ky,
            kz,
            sx: dir[kx] / dz,
            sy: dir[ky] / dz,
            sz: 1.0 / dz,
        })
    }

    fn shear(&self, p: &Point3<f64>) -> [f64; 3] {
        let a = p - self.origin;
        [
            a[self.kx] - self.sx * a[self.kz],
            a[self.ky] - self.sy * a[self.kz],
            self.sz * a[self.kz],
        ]
    }
}

/// Whether the edge `P -> Q` admits the line, given its edge function `e` and the
/// sign `s` of the determinant (see the module doc).
fn admits(e: f64, s: f64, p: &[f64; 3], q: &[f64; 3]) -> bool {
    let e = s * e;
    if e > 0.0 {
        return true;
    }
    if e < 0.0 {
        return false;
    }
    let dx = s * (q[0] - p[0]);
    let dy = s * (q[1] - p[1]);
    dy > 0.0 || (dy == 0.0 && dx < 0.0)
}

/// The f64 watertight test of a prepared line against triangle `(p0, p1, p2)`:
/// `Some((t, u, v))` on a hit.
pub fn intersect_frame(
    f: &RayFrame,
    p0: &Point3<f64>,
    p1: &Point3<f64>,
    p2: &Point3<f64>,
) -> Option<(f64, f64, f64)> {
    let a = f.shear(p0);
    let b = f.shear(p1);
    let c = f.shear(p2);
    let u = c[0] * b[1] - c[1] * b[0];
    let v = a[0] * c[1] - a[1] * c[0];
    let w = b[0] * a[1] - b[1] * a[0];
    let det = u + v + w;
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let s = det.signum();
    if !(admits(u, s, &b, &c) && admits(v, s, &c, &a) && admits(w, s, &a, &b)) {
        return None;
    }
    let t = (u * a[2] + v * b[2] + w * c[2]) / det;
    Some((t, v / det, w / det))
}

/// The f64 watertight test of the line `origin + t dir` against a triangle.
pub fn intersect(
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
    p0: &Point3<f64>,
    p1: &Point3<f64>,
    p2: &Point3<f64>,
) -> Option<(f64, f64, f64)> {
    intersect_frame(&RayFrame::new(origin, dir)?, p0, p1, p2)
}

/// Keeps `hit` in `hits` when it is nearer on its side (ties: lower index).
pub fn keep_nearest(hits: &mut NodeHits, hit: Hit) {
    let slot = if hit.t <= 0.0 {
        &mut hits.behind
    } else {
        &mut hits.front
    };
    let better = match slot {
        None => true,
        Some(old) => {
            hit.t.abs() < old.t.abs() || (hit.t.abs() == old.t.abs() && hit.triangle < old.triangle)
        }
    };
    if better {
        *slot = Some(hit);
    }
}

/// Nearest hits behind and in front of one line over all triangles (f64 brute
/// force).
pub fn cast_ray(
    triangles: &[[u32; 3]],
    positions: &[Point3<f64>],
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
) -> NodeHits {
    let mut hits = NodeHits::default();
    let Some(f) = RayFrame::new(origin, dir) else {
        return hits;
    };
    for (i, tri) in triangles.iter().enumerate() {
        let [a, b, c] = tri.map(|k| &positions[k as usize]);
        if let Some((t, u, v)) = intersect_frame(&f, a, b, c) {
            keep_nearest(
                &mut hits,
                Hit {
                    triangle: i as u32,
                    t,
                    u,
                    v,
                },
            );
        }
    }
    hits
}

/// f64 brute force over every ray and triangle: the reference answers.
pub fn cast_brute(
    triangles: &[[u32; 3]],
    positions: &[Point3<f64>],
    origins: &[Point3<f64>],
    dirs: &[Vector3<f64>],
    out: &mut Vec<NodeHits>,
) {
    out.clear();
    out.extend(
        origins
            .iter()
            .zip(dirs)
            .map(|(o, d)| cast_ray(triangles, positions, o, d)),
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(x: f64, y: f64, z: f64) -> Point3<f64> {
        Point3::new(x, y, z)
    }

    #[test]
    fn hit_inside_gives_t_and_barycentrics() {
        let (t, u, v) = intersect(
            &p(0.2, 0.3, 1.0),
            &Vector3::new(0.0, 0.0, -1.0),
            &p(0.0, 0.0, 0.0),
            &p(1.0, 0.0, 0.0),
            &p(0.0, 1.0, 0.0),
        )
        .expect("hit");
        assert!((t - 1.0).abs() < 1e-15);
        assert!((u - 0.2).abs() < 1e-15 && (v - 0.3).abs() < 1e-15);
        // The line counts on both sides: reversed direction gives t = -1.
        let (t, _, _) = intersect(
            &p(0.2, 0.3, 1.0),
            &Vector3::new(0.0, 0.0, 1.0),
            &p(0.0, 0.0, 0.0),
            &p(1.0, 0.0, 0.0),
            &p(0.0, 1.0, 0.0),
        )
        .expect("hit");
        assert!((t + 1.0).abs() < 1e-15);
    }

    #[test]
    fn parallel_and_degenerate_give_no_hit() {
        let d = Vector3::new(1.0, 0.0, 0.0);
        assert!(
            intersect(
                &p(-1.0, 0.2, 0.0),
                &d,
                &p(0.0, 0.0, 0.0),
                &p(1.0, 0.0, 0.0),
                &p(0.0, 1.0, 0.0)
            )
            .is_none()
        );
        let down = Vector3::new(0.0, 0.0, -1.0);
        assert!(
            intersect(
                &p(0.5, 0.0, 1.0),
                &down,
                &p(0.0, 0.0, 0.0),
                &p(1.0, 0.0, 0.0),
                &p(2.0, 0.0, 0.0)
            )
            .is_none()
        );
        assert!(
            intersect(
                &p(0.0, 0.0, 1.0),
                &down,
                &p(0.0, 0.0, 0.0),
                &p(0.0, 0.0, 0.0),
                &p(0.0, 0.0, 0.0)
            )
            .is_none()
        );
    }

    #[test]
    fn shared_edge_and_vertex_hit_exactly_one() {
        // A fan of 6 triangles around the origin in the plane z = 0.
        let ring: Vec<Point3<f64>> = (0..6)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 6.0;
                p(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let mut positions = vec![p(0.0, 0.0, 0.0)];
        positions.extend(ring);
        let tris: Vec<[u32; 3]> = (0..6).map(|k| [0, 1 + k, 1 + (k + 1) % 6]).collect();
        for dir in [
            Vector3::new(0.0, 0.0, 1.0),
            Vector3::new(0.0, 0.0, -1.0),
            Vector3::new(0.3, -0.2, 0.9).normalize(),
        ] {
            let o = p(0.0, 0.0, 0.0) - dir * 2.0;
            let n = tris
                .iter()
                .filter(|t| {
                    intersect(
                        &o,
                        &dir,
                        &positions[t[0] as usize],
                        &positions[t[1] as usize],
                        &positions[t[2] as usize],
                    )
                    .is_some()
                })
                .count();
            assert_eq!(n, 1, "vertex, dir {dir:?}");
            // The shared edge between triangle 0 and 1 (towards ring vertex 1).
            let e = p(0.5 * positions[2].x, 0.5 * positions[2].y, 0.0);
            let o = e - dir * 2.0;
            let n = tris
                .iter()
                .filter(|t| {
                    intersect(
                        &o,
                        &dir,
                        &positions[t[0] as usize],
                        &positions[t[1] as usize],
                        &positions[t[2] as usize],
                    )
                    .is_some()
                })
                .count();
            assert_eq!(n, 1, "edge, dir {dir:?}");
        }
    }
}
