//! Swept cutting: whether a blade's edge, moving from one pose to the next,
//! crosses a segment (a tie across the fissure).
//!
//! The edge `[a, b]` (instrument frame) sweeps, between poses `P0` and `P1`,
//! the surface `S(s, t) = P(t) (a + s (b - a))`, `s, t in [0, 1]`, with
//! `P(t)` the screw interpolation of the two poses (translation linear,
//! rotation slerped). Under a pure translation `S` is the parallelogram of
//! corners `P0 a, P0 b, P1 b, P1 a`, split into two triangles: the test is
//! then exact whatever the travel (no tunnelling at any speed, as long as
//! the motion between samples is a translation). With a rotation `S` is a
//! ruled surface; it is cut into [`sub_steps`] strips, each taken as its
//! bilinear quad's two triangles, so that the chord error stays under
//! `MAX_CHORD_RAD` radians of turn per strip (the triangles' distance from
//! the true surface is at most `|edge| (1 - cos(theta/2))`: under 0.2 um for
//! a 10 mm edge).
//!
//! A segment crosses a triangle when the segment's line meets the triangle
//! inside or on its boundary at a segment parameter in `[0, 1]`
//! (Moller-Trumbore; a segment lying in the triangle's plane is tested
//! against the triangle's edges, which the sweep's neighbouring triangle
//! shares). Boundary contacts count as crossings (a tie touched by the
//! edge's end is cut), with a tolerance of `1e-12` of the lengths involved.
//!
//! Hand-written: parry's queries answer distance and contact between
//! shapes, not crossings of a swept edge with many free segments, and the
//! test is a few lines of vector algebra.

use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};

/// Largest turn of the edge per strip of the sweep, rad.
pub const MAX_CHORD_RAD: f64 = 0.02;

/// Strips the sweep from `p0` to `p1` is cut into: enough that each turns
/// the edge by at most [`MAX_CHORD_RAD`] (1 under a translation), at most
/// 4096.
pub fn sub_steps(p0: &Isometry3<f64>, p1: &Isometry3<f64>) -> usize {
    let angle = p0.rotation.angle_to(&p1.rotation);
    ((angle / MAX_CHORD_RAD).ceil() as usize).clamp(1, 4096)
}

/// The pose a share `t in [0, 1]` of the way from `p0` to `p1`.
pub fn interpolate(p0: &Isometry3<f64>, p1: &Isometry3<f64>, t: f64) -> Isometry3<f64> {
    let translation = p0.translation.vector.lerp(&p1.translation.vector, t);
    let rotation: UnitQuaternion<f64> = p0
        .rotation
        .try_slerp(&p1.rotation, t, 1e-12)
        .unwrap_or(p1.rotation);
    Isometry3::from_parts(translation.into(), rotation)
}

/// The triangles of the surface the edge `[a, b]` (instrument frame, m)
/// sweeps from pose `p0` to `p1`, in the scene frame, appended to `out`.
pub fn swept_triangles(
    edge: &[Point3<f64>; 2],
    p0: &Isometry3<f64>,
    p1: &Isometry3<f64>,
    out: &mut Vec<[Point3<f64>; 3]>,
) {
    let n = sub_steps(p0, p1);
    let mut prev = [p0 * edge[0], p0 * edge[1]];
    for k in 1..=n {
        let pose = if k == n {
            *p1
        } else {
            interpolate(p0, p1, k as f64 / n as f64)
        };
        let next = [pose * edge[0], pose * edge[1]];
        out.push([prev[0], prev[1], next[1]]);
        out.push([prev[0], next[1], next[0]]);
        prev = next;
    }
}

/// Whether the segment `[p, q]` (m) crosses the triangle `tri` (module
/// documentation).
pub fn segment_crosses_triangle(p: &Point3<f64>, q: &Point3<f64>, tri: &[Point3<f64>; 3]) -> bool {
    let e1 = tri[1] - tri[0];
    let e2 = tri[2] - tri[0];
    let d = q - p;
    let scale = e1.norm().max(e2.norm()).max(d.norm());
    if scale == 0.0 || !scale.is_finite() {
        return false;
    }
    let eps = 1e-12;
    let h = d.cross(&e2);
    let det = e1.dot(&h);
    let normal = e1.cross(&e2);
    if det.abs() <= eps * scale * normal.norm().max(f64::MIN_POSITIVE) {
        // Parallel to the plane: a crossing only if the segment lies in it
        // and meets the triangle's boundary or interior.
        let off = normal.dot(&(p - tri[0]));
        if off.abs() > eps * scale * normal.norm() {
            return false;
        }
        return coplanar_overlap(p, q, tri, &normal);
    }
    let f = 1.0 / det;
    let s = p - tri[0];
    let u = f * s.dot(&h);
    let qv = s.cross(&e1);
    let v = f * d.dot(&qv);
    let t = f * e2.dot(&qv);
    let tol = eps * 8.0;
    u >= -tol && v >= -tol && u + v <= 1.0 + tol && t >= -tol && t <= 1.0 + tol
}

/// A segment in the plane of a triangle (normal `normal`) meets it: an
/// endpoint inside, or an edge crossed.
fn coplanar_overlap(
    p: &Point3<f64>,
    q: &Point3<f64>,
    tri: &[Point3<f64>; 3],
    normal: &Vector3<f64>,
) -> bool {
    let inside = |x: &Point3<f64>| {
        (0..3).all(|i| {
            let (a, b) = (tri[i], tri[(i + 1) % 3]);
            (b - a).cross(&(x - a)).dot(normal) >= 0.0
        })
    };
    if inside(p) || inside(q) {
        return true;
    }
    (0..3).any(|i| segments_cross_in_plane(p, q, &tri[i], &tri[(i + 1) % 3], normal))
}

fn segments_cross_in_plane(
    p: &Point3<f64>,
    q: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    n: &Vector3<f64>,
) -> bool {
    let side = |x: &Point3<f64>, y: &Point3<f64>, z: &Point3<f64>| (y - x).cross(&(z - x)).dot(n);
    let (d1, d2) = (side(a, b, p), side(a, b, q));
    let (d3, d4) = (side(p, q, a), side(p, q, b));
    d1 * d2 <= 0.0 && d3 * d4 <= 0.0
}

/// Whether the edge `[a, b]` (instrument frame) crosses the segment
/// `[p, q]` (scene frame) while moving from `p0` to `p1`.
pub fn edge_sweeps_across(
    edge: &[Point3<f64>; 2],
    p0: &Isometry3<f64>,
    p1: &Isometry3<f64>,
    p: &Point3<f64>,
    q: &Point3<f64>,
) -> bool {
    let mut tris = Vec::new();
    swept_triangles(edge, p0, p1, &mut tris);
    tris.iter().any(|t| segment_crosses_triangle(p, q, t))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn edge() -> [Point3<f64>; 2] {
        [
            Point3::new(0.0, -0.005, 0.03),
            Point3::new(0.0, 0.005, 0.03),
        ]
    }

    #[test]
    fn a_translated_edge_cuts_a_segment_it_passes_and_misses_one_beside_it() {
        let p0 = Isometry3::translation(0.0, 0.0, 0.0);
        let p1 = Isometry3::translation(0.0, 0.0, 0.01);
        // A tie across the path at z = 35 mm, y = 0.
        let (p, q) = (
            Point3::new(-0.002, 0.0, 0.035),
            Point3::new(0.002, 0.0, 0.035),
        );
        assert!(edge_sweeps_across(&edge(), &p0, &p1, &p, &q));
        // Beyond the edge's reach (y = 6 mm) or beyond its travel (z = 41 mm).
        let side = Vector3::new(0.0, 0.006, 0.0);
        assert!(!edge_sweeps_across(
            &edge(),
            &p0,
            &p1,
            &(p + side),
            &(q + side)
        ));
        let far = Vector3::new(0.0, 0.0, 0.006);
        assert!(!edge_sweeps_across(
            &edge(),
            &p0,
            &p1,
            &(p + far),
            &(q + far)
        ));
        // Through the edge's end (y = 5 mm exactly) counts.
        let end = Vector3::new(0.0, 0.005, 0.0);
        assert!(edge_sweeps_across(
            &edge(),
            &p0,
            &p1,
            &(p + end),
            &(q + end)
        ));
    }

    #[test]
    fn a_huge_travel_in_one_sample_does_not_tunnel() {
        let p0 = Isometry3::translation(0.0, 0.0, -100.0);
        let p1 = Isometry3::translation(0.0, 0.0, 100.0);
        let (p, q) = (Point3::new(-1e-4, 0.0, 0.0), Point3::new(1e-4, 0.0, 0.0));
        assert!(edge_sweeps_across(&edge(), &p0, &p1, &p, &q));
    }

    #[test]
    fn a_turning_edge_cuts_what_its_arc_passes() {
        // The edge (y in [-5, 5] mm at z = 30 mm) turns a quarter turn about
        // the handle's x axis: it sweeps a quarter annulus of radii 30 to
        // 30.4 mm in the y-z plane.
        let p0 = Isometry3::identity();
        let p1 = Isometry3::rotation(Vector3::new(std::f64::consts::FRAC_PI_2, 0.0, 0.0));
        assert!(sub_steps(&p0, &p1) >= 78);
        // In the annulus at 45 degrees (radius 30.2 mm), a tie along x.
        let c = 0.0302 * std::f64::consts::FRAC_1_SQRT_2;
        let at = Point3::new(0.0, -c, c);
        let (p, q) = (at - Vector3::x() * 0.001, at + Vector3::x() * 0.001);
        assert!(edge_sweeps_across(&edge(), &p0, &p1, &p, &q));
        // Inside the arc (radius 20 mm): the edge never reaches it.
        let inner = Point3::new(
            0.0,
            -0.02 * std::f64::consts::FRAC_1_SQRT_2,
            0.02 * std::f64::consts::FRAC_1_SQRT_2,
        );
        let (p, q) = (inner - Vector3::x() * 0.001, inner + Vector3::x() * 0.001);
        assert!(!edge_sweeps_across(&edge(), &p0, &p1, &p, &q));
    }

    #[test]
    fn a_segment_in_the_swept_plane_is_cut_where_it_meets_the_sweep() {
        let p0 = Isometry3::translation(0.0, 0.0, 0.0);
        let p1 = Isometry3::translation(0.0, 0.0, 0.01);
        // In the plane x = 0, across the swept rectangle.
        let (p, q) = (
            Point3::new(0.0, -0.01, 0.035),
            Point3::new(0.0, 0.01, 0.035),
        );
        assert!(edge_sweeps_across(&edge(), &p0, &p1, &p, &q));
        let (p, q) = (
            Point3::new(0.0, 0.006, 0.035),
            Point3::new(0.0, 0.01, 0.035),
        );
        assert!(!edge_sweeps_across(&edge(), &p0, &p1, &p, &q));
    }
}
