//! The contact faces of a spatula and the projection of a point onto them
//! (DESIGN.md section 3b, "only tissue the face covers is pushed").
//!
//! A plate touches tissue with five faces ([`FaceId`]): its two large faces
//! A and B, its two side strips and its tip strip (the rim). In the
//! instrument frame ([`super::instrument`]), with the mid-surface
//! `m(s, y)`, face-A normal `n(s)`, tangent `T(s)`, half-thickness `h/2`
//! and width `w(s)`:
//!
//! | face | surface | outward normal | outline |
//! |---|---|---|---|
//! | A | `m(s, y) + h/2 n(s)` | `n(s)` | `0 <= s <= L`, `abs(y) <= w(s)/2` |
//! | B | `m(s, y) - h/2 n(s)` | `-n(s)` | the same |
//! | side `+y` | `m(s, w(s)/2) + t n(s)` | `(0, 1, -w'/2)` normalised | `0 <= s <= L`, `abs(t) <= h/2` |
//! | side `-y` | `m(s, -w(s)/2) + t n(s)` | `(0, -1, -w'/2)` normalised | the same |
//! | tip | `m(L, y) + t n(L)` | `T(L)` | `abs(y) <= w(L)/2`, `abs(t) <= h/2` |
//!
//! (`w' = dw/ds`, zero unless the plate is a trapezoid.) The projection of
//! a point `x` onto a face ([`Plate::project`]) takes the face parameters of
//! `x` (`s` from the arc of the mid-surface nearest to `x`, `y` or `t` its
//! offset), clamps them into the outline and reports the clamped face
//! point, the face normal there and how far outside the outline `x` lies
//! (the length of the clamping, m). The gap of `x` on the face is
//! `normal . (x - point)`: negative behind the face (inside the plate, or
//! beyond it), zero on it.

use super::instrument::{NodeKind, Plate};
use nalgebra::{Point3, Vector3};

/// A contact face of a plate (module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FaceId {
    /// Face A (outward normal `+n`).
    A,
    /// Face B (outward normal `-n`).
    B,
    /// The side strip at `y = +w/2`.
    SidePlusY,
    /// The side strip at `y = -w/2`.
    SideMinusY,
    /// The tip strip at `s = L`.
    Tip,
}

impl FaceId {
    /// All faces.
    pub const ALL: [FaceId; 5] = [
        FaceId::A,
        FaceId::B,
        FaceId::SidePlusY,
        FaceId::SideMinusY,
        FaceId::Tip,
    ];

    /// The face a source node sits on.
    pub fn of(kind: NodeKind) -> Self {
        match kind {
            NodeKind::FaceA => FaceId::A,
            NodeKind::FaceB => FaceId::B,
            NodeKind::RimPlusY => FaceId::SidePlusY,
            NodeKind::RimMinusY => FaceId::SideMinusY,
            NodeKind::RimTip => FaceId::Tip,
        }
    }

    /// A small index (0..5).
    pub fn index(self) -> usize {
        self as usize
    }
}

/// A point projected onto a face, instrument frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FacePoint {
    /// Unit outward normal of the face at `point`.
    pub normal: Vector3<f64>,
    /// The face point of the clamped parameters, m.
    pub point: Point3<f64>,
    /// Gap `normal . (x - point)`, m (negative behind the face).
    pub gap_m: f64,
    /// How far outside the face's outline the point's parameters fall, m
    /// (0 inside).
    pub outside_m: f64,
}

impl Plate {
    /// Arc-length parameter `s` (unclamped) of the mid-surface point
    /// nearest to `x` in the bending plane, and the offset of `x` along the
    /// face-A normal there.
    fn arc_coordinates(&self, x: &Point3<f64>) -> (f64, f64) {
        match self.bend_radius {
            None => (x.z, x.x),
            Some(r) => {
                // Centre of curvature (-r, 0, 0); m(s) - c = r (cos, 0, sin).
                let (dx, dz) = (x.x + r, x.z);
                let theta = if r > 0.0 {
                    dz.atan2(dx)
                } else {
                    (-dz).atan2(-dx)
                };
                let radial = dx.hypot(dz);
                (r * theta, radial * r.signum() - r)
            }
        }
    }

    /// Projects `x` (instrument frame, m) onto `face` (module documentation).
    pub fn project(&self, face: FaceId, x: &Point3<f64>) -> FacePoint {
        let h2 = 0.5 * self.thickness;
        let (s_raw, off_raw) = self.arc_coordinates(x);
        let s = s_raw.clamp(0.0, self.length);
        let ds = s_raw - s;
        match face {
            FaceId::A | FaceId::B => {
                let half = 0.5 * self.width_at(s);
                let y = x.y.clamp(-half, half);
                let (m, n, _) = self.frame_at(s, y);
                let sign = if face == FaceId::A { 1.0 } else { -1.0 };
                let normal = n * sign;
                let point = m + normal * h2;
                FacePoint {
                    normal,
                    point,
                    gap_m: normal.dot(&(x - point)),
                    outside_m: ds.hypot(x.y - y),
                }
            }
            FaceId::SidePlusY | FaceId::SideMinusY => {
                let sign = if face == FaceId::SidePlusY { 1.0 } else { -1.0 };
                let t = off_raw.clamp(-h2, h2);
                let (m, n, tangent) = self.frame_at(s, sign * 0.5 * self.width_at(s));
                let slope = 0.5 * (self.tip_width - self.base_width) / self.length;
                let normal = (Vector3::y() * sign - tangent * slope).normalize();
                let point = m + n * t;
                FacePoint {
                    normal,
                    point,
                    gap_m: normal.dot(&(x - point)),
                    outside_m: ds.hypot(off_raw - t),
                }
            }
            FaceId::Tip => {
                let half = 0.5 * self.tip_width;
                let y = x.y.clamp(-half, half);
                let (m, n, tangent) = self.frame_at(self.length, y);
                // Offset across the thickness at the tip.
                let t_raw = n.dot(&(x - m));
                let t = t_raw.clamp(-h2, h2);
                let point = m + n * t;
                FacePoint {
                    normal: tangent,
                    point,
                    gap_m: tangent.dot(&(x - point)),
                    outside_m: (t_raw - t).hypot(x.y - y),
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_faces_project_onto_their_planes_and_measure_the_outline() {
        let p = Plate::flat(1e-3, 0.01, 0.03);
        // Above face A, inside the outline.
        let a = p.project(FaceId::A, &Point3::new(2e-3, 1e-3, 0.01));
        assert_eq!(a.normal, Vector3::x());
        assert!((a.gap_m - 1.5e-3).abs() < 1e-15 && a.outside_m == 0.0);
        // Behind face A (inside the plate): negative gap.
        let a = p.project(FaceId::A, &Point3::new(0.0, 0.0, 0.01));
        assert!((a.gap_m + 0.5e-3).abs() < 1e-15);
        // Beyond the side edge by 1 mm and past the tip by 2 mm.
        let a = p.project(FaceId::A, &Point3::new(1e-3, 6e-3, 0.032));
        assert!((a.outside_m - (1e-3f64).hypot(2e-3)).abs() < 1e-15);
        // Face B mirrors A.
        let b = p.project(FaceId::B, &Point3::new(-2e-3, 0.0, 0.01));
        assert_eq!(b.normal, -Vector3::x());
        assert!((b.gap_m - 1.5e-3).abs() < 1e-15);
        // The side +y: 1 mm beyond the edge, within the thickness.
        let s = p.project(FaceId::SidePlusY, &Point3::new(0.2e-3, 6e-3, 0.01));
        assert!((s.normal - Vector3::y()).norm() < 1e-15);
        assert!((s.gap_m - 1e-3).abs() < 1e-15 && s.outside_m == 0.0);
        // The tip: 0.5 mm beyond it.
        let t = p.project(FaceId::Tip, &Point3::new(0.0, 0.0, 0.0305));
        assert_eq!(t.normal, Vector3::z());
        assert!((t.gap_m - 0.5e-3).abs() < 1e-15 && t.outside_m == 0.0);
    }

    #[test]
    fn curved_faces_use_the_normal_at_the_nearest_arc_point() {
        for r in [0.05, -0.05] {
            let p = Plate::curved(1e-3, 0.01, 0.04, r);
            for s in [0.0, 0.01, 0.025, 0.04] {
                let (m, n, _) = p.frame_at(s, 0.002);
                for d in [-0.4e-3, 0.5e-3, 2e-3] {
                    let x = m + n * d;
                    let a = p.project(FaceId::A, &x);
                    assert!((a.normal - n).norm() < 1e-12, "r {r} s {s}");
                    assert!((a.gap_m - (d - 0.5e-3)).abs() < 1e-12, "r {r} s {s} d {d}");
                    assert!(a.outside_m < 1e-12);
                    let b = p.project(FaceId::B, &x);
                    assert!((b.gap_m - (-d - 0.5e-3)).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn trapezoid_sides_are_tilted_by_the_taper() {
        let p = Plate::trapezoid(1e-3, 0.012, 0.006, 0.04);
        let (m, _, _) = p.frame_at(0.02, 0.5 * p.width_at(0.02));
        let s = p.project(FaceId::SidePlusY, &(m + Vector3::y() * 1e-3));
        // The edge narrows towards the tip: its normal leans to +z.
        assert!(s.normal.y > 0.0 && s.normal.z > 0.0);
        assert!((s.normal.norm() - 1.0).abs() < 1e-15);
        assert!(s.gap_m > 0.0 && s.gap_m < 1e-3);
    }
}
