//! The rigid and the non-rigid parts of a surface displacement (how much of
//! a frame's motion is the whole brain swinging on its support, and how much
//! is deformation), DESIGN.md section 3c. The engine reports it with each
//! frame (`fissure.v1.RigidPart`); clients that draw frames take the same
//! rigid motion away ([`RigidFit`]) without linking the engine.
//!
//! **Method.** The best-fit rigid motion of the surface vertices, rest `X_i`
//! to current `x_i` (least squares, each vertex weighted alike: Kabsch):
//! with the centroids `c = mean X`, `c' = mean x` and
//! `H = sum (X_i - c)(x_i - c')^T = U S V^T`, the rotation is
//! `R = V diag(1, 1, det(V U^T)) U^T` and the motion
//! `x ~ c' + R (X - c)`; its translation is `t = c' - c` (the centroid's)
//! and its angle `acos((tr R - 1) / 2)`. The non-rigid displacement of a
//! vertex is what the rigid motion leaves: `x_i - c' - R (X_i - c)`.
//! Its largest value is reported within [`NEAR_RADIUS_M`] of a centre (the
//! fissure: the mean of the instruments' tips) and beyond it.

use nalgebra::{Matrix3, Point3, Vector3};

/// Radius about the centre inside which displacement counts as "near the
/// fissure", m.
pub const NEAR_RADIUS_M: f64 = 0.04;

/// A best-fit rigid motion `x ~ c' + R (X - c)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidFit {
    /// Rest centroid `c`, m.
    pub rest_centroid: Point3<f64>,
    /// Current centroid `c'`, m.
    pub centroid: Point3<f64>,
    /// Rotation `R`.
    pub rotation: Matrix3<f64>,
}

impl RigidFit {
    /// Fits the rigid motion taking `rest` to `current` (same length, at
    /// least one point; fewer than three non-collinear points leave the
    /// rotation undetermined and give the identity part of it).
    pub fn new(rest: &[Point3<f64>], current: &[Point3<f64>]) -> Self {
        let n = rest.len().max(1) as f64;
        let c = rest.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
        let cc = current.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n;
        let mut h = Matrix3::zeros();
        for (x0, x) in rest.iter().zip(current) {
            h += (x0.coords - c) * (x.coords - cc).transpose();
        }
        let svd = h.svd(true, true);
        let rotation = match (svd.u, svd.v_t) {
            (Some(u), Some(v_t)) => {
                let v = v_t.transpose();
                let d = (v * u.transpose()).determinant().signum();
                v * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose()
            }
            _ => Matrix3::identity(),
        };
        Self {
            rest_centroid: Point3::from(c),
            centroid: Point3::from(cc),
            rotation,
        }
    }

    /// Translation of the centroid, m.
    pub fn translation(&self) -> Vector3<f64> {
        self.centroid - self.rest_centroid
    }

    /// Rotation angle, degrees.
    pub fn angle_deg(&self) -> f64 {
        ((self.rotation.trace() - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees()
    }

    /// Where the rigid motion takes rest point `x0`, m.
    pub fn apply(&self, x0: &Point3<f64>) -> Point3<f64> {
        self.centroid + self.rotation * (x0 - self.rest_centroid)
    }

    /// The non-rigid displacement of a point at rest `x0` now at `x`, m.
    pub fn non_rigid(&self, x0: &Point3<f64>, x: &Point3<f64>) -> Vector3<f64> {
        x - self.apply(x0)
    }
}

/// The rigid part of a frame and the largest non-rigid displacement near
/// and away from a centre.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RigidPart {
    /// Best-fit rotation angle, degrees.
    pub rotation_deg: f64,
    /// Best-fit translation (of the surface centroid), m.
    pub translation_m: Vector3<f64>,
    /// Largest rigid displacement of a surface vertex, m.
    pub max_rigid_m: f64,
    /// The centre distances are measured from, m.
    pub centre_m: Point3<f64>,
    /// Largest non-rigid displacement within [`NEAR_RADIUS_M`] of the
    /// centre (rest positions), m.
    pub max_non_rigid_near_m: f64,
    /// Largest non-rigid displacement beyond it, m.
    pub max_non_rigid_far_m: f64,
}

impl RigidPart {
    /// Splits the motion `rest` -> `current` about `centre`.
    pub fn of(rest: &[Point3<f64>], current: &[Point3<f64>], centre: Point3<f64>) -> Self {
        let fit = RigidFit::new(rest, current);
        let mut out = Self {
            rotation_deg: fit.angle_deg(),
            translation_m: fit.translation(),
            centre_m: centre,
            ..Self::default()
        };
        for (x0, x) in rest.iter().zip(current) {
            let d = fit.non_rigid(x0, x).norm();
            out.max_rigid_m = out.max_rigid_m.max((fit.apply(x0) - x0).norm());
            if (x0 - centre).norm() <= NEAR_RADIUS_M {
                out.max_non_rigid_near_m = out.max_non_rigid_near_m.max(d);
            } else {
                out.max_non_rigid_far_m = out.max_non_rigid_far_m.max(d);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn cloud() -> Vec<Point3<f64>> {
        (0..200)
            .map(|i| {
                let t = i as f64 * 0.37;
                Point3::new(
                    0.05 * t.sin(),
                    0.04 * (1.3 * t).cos(),
                    0.03 * (0.7 * t).sin(),
                )
            })
            .collect()
    }

    #[test]
    fn a_rigid_motion_is_all_rigid() {
        // x = R X + b: the fit recovers R's angle and the centroid's
        // translation R c + b - c, and leaves no non-rigid displacement.
        let rest = cloud();
        let r = Rotation3::from_axis_angle(&Vector3::y_axis(), 3f64.to_radians());
        let b = Vector3::new(1e-3, -2e-3, 0.5e-3);
        let cur: Vec<_> = rest.iter().map(|p| r * p + b).collect();
        let part = RigidPart::of(&rest, &cur, Point3::origin());
        assert!(
            (part.rotation_deg - 3.0).abs() < 1e-9,
            "{}",
            part.rotation_deg
        );
        let c = rest.iter().map(|p| p.coords).sum::<Vector3<f64>>() / rest.len() as f64;
        assert!((part.translation_m - (r * c + b - c)).norm() < 1e-12);
        assert!(part.max_non_rigid_near_m < 1e-12 && part.max_non_rigid_far_m < 1e-12);
    }

    #[test]
    fn a_local_dent_is_non_rigid_and_near() {
        // One vertex pushed 1 mm: the fit barely moves (1 of 200), and the
        // dent shows as non-rigid, near its centre, nearly nothing far.
        let rest = cloud();
        let mut cur = rest.clone();
        cur[10].z += 1e-3;
        let part = RigidPart::of(&rest, &cur, rest[10]);
        assert!(part.max_non_rigid_near_m > 0.95e-3, "{part:?}");
        assert!(part.max_non_rigid_far_m < 0.05 * part.max_non_rigid_near_m);
        assert!(part.rotation_deg < 0.05);
    }
}
