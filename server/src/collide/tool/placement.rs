//! Spatula poses in a fissure of the brain phantom, from its landmarks.
//!
//! A [`FissureLandmark`] gives the fissure's entry point `E`, its unit depth
//! direction `d`, the unit normal `n` of its mid-plane (the walls lie at
//! `+- width / 2` along `n`) and its width. A flat plate *in the fissure* lies
//! in a plane parallel to the mid-plane: in the instrument frame
//! ([`instrument`](super::instrument)) `+z` (length, to the tip) maps to `d`,
//! `+x` (face A's outward normal) to `n` and `+y` (width) to `d x n`, a proper
//! rotation because `n . d = 0`. The handle point is
//! `E + (insertion - L) d + across (d x n) + offset n`, so the tip is
//! `insertion` past the entry and the plate's mid-plane sits `offset` from the
//! fissure's mid-plane. Metres throughout.

use crate::mesh::phantom::FissureLandmark;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion};

/// Where a plate sits in a fissure (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FissurePlacement {
    /// Depth of the tip past the entry, along the fissure's direction.
    pub insertion: f64,
    /// Offset of the plate's centre line along `d x n` (across the fissure's
    /// length, in its plane).
    pub across: f64,
    /// Offset of the plate's mid-plane from the fissure's mid-plane, along `n`.
    pub offset: f64,
}

impl FissurePlacement {
    /// The pose (instrument frame -> phantom frame) of a plate of length
    /// `length` placed so in the fissure `f` (module documentation).
    pub fn pose(&self, f: &FissureLandmark, length: f64) -> Isometry3<f64> {
        let (d, n) = (f.direction.into_inner(), f.normal.into_inner());
        let w = d.cross(&n);
        let rot = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[n, w, d]));
        let handle = f.entry + d * (self.insertion - length) + w * self.across + n * self.offset;
        Isometry3::from_parts(
            Translation3::from(handle.coords),
            UnitQuaternion::from_rotation_matrix(&rot),
        )
    }

    /// The mid-plane offset that puts face A (thickness `thickness`) `push`
    /// into the wall at `+width / 2` along `n`: `width / 2 + push - thickness / 2`.
    pub fn into_wall(f: &FissureLandmark, thickness: f64, push: f64) -> f64 {
        0.5 * f.width + push - 0.5 * thickness
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Unit, Vector3};

    #[test]
    fn plate_axes_follow_the_landmark() {
        let f = FissureLandmark {
            entry: Point3::new(-0.065, 0.01, 0.0),
            direction: Unit::new_normalize(Vector3::new(1.0, 0.0, 0.0)),
            normal: Vector3::z_axis(),
            depth: 0.025,
            width: 0.003,
        };
        let p = FissurePlacement {
            insertion: 0.01,
            across: 0.002,
            offset: FissurePlacement::into_wall(&f, 0.001, 0.0005),
        };
        let pose = p.pose(&f, 0.03);
        // Face A normal -> +z, length -> +x, width -> d x n = -y.
        assert!((pose * Vector3::x() - Vector3::z()).norm() < 1e-15);
        assert!((pose * Vector3::z() - Vector3::x()).norm() < 1e-15);
        assert!((pose * Vector3::y() + Vector3::y()).norm() < 1e-15);
        // Tip 10 mm past the entry, plate centre 1.5 mm above the mid-plane
        // (face A at 2.0 mm: 0.5 mm into the wall at 1.5 mm).
        let tip = pose * Point3::new(0.0, 0.0, 0.03);
        assert!((tip - Point3::new(-0.055, 0.008, 0.0015)).norm() < 1e-15);
    }
}
