//! The pinhole camera of the rasteriser: placement (eye, target, up, vertical
//! field of view), framing a box from a direction, and the projection to
//! pixels described in the module above.

use nalgebra::{Isometry3, Point3, Vector3};

/// A pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub eye: Point3<f64>,
    /// Point looked at.
    pub target: Point3<f64>,
    /// Approximate up direction (need not be orthogonal to the view).
    pub up: Vector3<f64>,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
    /// Near clipping distance, same unit as positions (> 0).
    pub near: f64,
}

impl Camera {
    /// A camera at `eye` looking at `target`, with the near plane at a
    /// thousandth of their distance.
    pub fn look_at(
        eye: Point3<f64>,
        target: Point3<f64>,
        up: Vector3<f64>,
        fov_y_deg: f64,
    ) -> Self {
        let near = ((eye - target).norm() * 1e-3).max(1e-9);
        Self {
            eye,
            target,
            up,
            fov_y_deg,
            near,
        }
    }

    /// The world-to-view isometry (camera at the origin looking along -z).
    pub fn view(&self) -> Isometry3<f64> {
        let dir = self.target - self.eye;
        // Fall back to another up vector when `up` is parallel to the view.
        let up = if dir.cross(&self.up).norm_squared()
            > 1e-20 * dir.norm_squared() * self.up.norm_squared()
        {
            self.up
        } else if dir.cross(&Vector3::y()).norm_squared() > 1e-12 * dir.norm_squared() {
            Vector3::y()
        } else {
            Vector3::x()
        };
        Isometry3::look_at_rh(&self.eye, &self.target, &up)
    }

    /// `f = 1 / tan(fov_y / 2)`.
    pub(super) fn focal(&self) -> f64 {
        1.0 / (0.5 * self.fov_y_deg.clamp(1e-3, 179.0).to_radians()).tan()
    }

    /// Pixel coordinates (x right, y down) of world point `p` in a
    /// `width` x `height` image, or `None` when `p` is not in front of the
    /// near plane.
    pub fn project(&self, p: &Point3<f64>, width: u32, height: u32) -> Option<[f64; 2]> {
        let v = self.view() * p;
        let w = -v.z;
        if w.is_nan() || w < self.near {
            return None;
        }
        let f = self.focal();
        let aspect = width as f64 / height as f64;
        let (xn, yn) = (f * v.x / (aspect * w), f * v.y / w);
        Some([
            (xn + 1.0) * 0.5 * width as f64,
            (1.0 - yn) * 0.5 * height as f64,
        ])
    }

    /// A camera that looks at the box [`lo`, `hi`] from direction `from`
    /// (pointing from the box towards the eye), with `up` roughly up, placed
    /// so that the box's eight corners fill the central `fill` fraction
    /// (0 < fill <= 1) of an image of aspect `aspect` = width / height, and
    /// centred on them.
    pub fn frame_box(
        lo: Point3<f64>,
        hi: Point3<f64>,
        from: Vector3<f64>,
        up: Vector3<f64>,
        fov_y_deg: f64,
        aspect: f64,
        fill: f64,
    ) -> Self {
        let corners: Vec<Point3<f64>> = (0..8)
            .map(|i| {
                Point3::new(
                    if i & 1 == 0 { lo.x } else { hi.x },
                    if i & 2 == 0 { lo.y } else { hi.y },
                    if i & 4 == 0 { lo.z } else { hi.z },
                )
            })
            .collect();
        Self::frame_points(&corners, from, up, fov_y_deg, aspect, fill)
    }

    /// Like [`Camera::frame_box`], fitting the given points themselves
    /// (tighter than their bounding box). Non-finite points are ignored; no
    /// point gives a camera on the unit box.
    pub fn frame_points(
        points: &[Point3<f64>],
        from: Vector3<f64>,
        up: Vector3<f64>,
        fov_y_deg: f64,
        aspect: f64,
        fill: f64,
    ) -> Self {
        let mut lo = Point3::from(Vector3::repeat(f64::INFINITY));
        let mut hi = Point3::from(Vector3::repeat(f64::NEG_INFINITY));
        let finite = |p: &&Point3<f64>| p.coords.iter().all(|c| c.is_finite());
        for p in points.iter().filter(finite) {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        if lo.x > hi.x {
            (lo, hi) = (Point3::origin(), Point3::new(1.0, 1.0, 1.0));
        }
        let unit_box = [lo, hi];
        let corners: Vec<&Point3<f64>> = if points.iter().any(|p| finite(&p)) {
            points.iter().filter(finite).collect()
        } else {
            unit_box.iter().collect()
        };
        let centre = nalgebra::center(&lo, &hi);
        let size = (hi - lo).norm().max(1e-12);
        let from = if from.norm() > 0.0 {
            from.normalize()
        } else {
            Vector3::z()
        };
        let mut cam = Camera::look_at(centre + from * size, centre, up, fov_y_deg);
        let f = cam.focal();
        let fill = fill.clamp(0.05, 1.0);
        let aspect = if aspect.is_finite() && aspect > 0.0 {
            aspect
        } else {
            1.0
        };
        // Two passes: fit the distance, then re-centre the projected extents.
        for _ in 0..3 {
            let view = cam.view();
            // The distance d from the target such that every corner (a, b, c)
            // in the camera basis (c towards the eye) satisfies
            // f |a| / (aspect (d - c)) <= fill and f |b| / (d - c) <= fill.
            let t = view * cam.target;
            let mut d: f64 = 0.0;
            for &p in &corners {
                let q = view * p - t;
                let need = q.z + (f * q.x.abs() / aspect).max(f * q.y.abs()) / fill;
                d = d.max(need);
            }
            d = d.max(1e-9);
            let back = (cam.eye - cam.target).normalize();
            cam.eye = cam.target + back * d;
            cam.near = (d * 1e-3).max(1e-12);
            // Re-centre: shift the target (and eye) by the middle of the
            // projected extents, measured at the target's depth.
            let view = cam.view();
            let (mut xlo, mut xhi, mut ylo, mut yhi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
            for &p in &corners {
                let v = view * p;
                let w = (-v.z).max(cam.near);
                let (xn, yn) = (f * v.x / (aspect * w), f * v.y / w);
                xlo = xlo.min(xn);
                xhi = xhi.max(xn);
                ylo = ylo.min(yn);
                yhi = yhi.max(yn);
            }
            let (mx, my) = (0.5 * (xlo + xhi), 0.5 * (ylo + yhi));
            let inv = view.inverse();
            let shift = inv.rotation * Vector3::new(mx * aspect * d / f, my * d / f, 0.0);
            cam.target += shift;
            cam.eye += shift;
        }
        cam
    }

    /// [`Camera::frame_box`] from spherical angles about a z-up world:
    /// azimuth from +x towards +y, elevation above the xy plane, degrees.
    pub fn orbit_box(
        lo: Point3<f64>,
        hi: Point3<f64>,
        azimuth_deg: f64,
        elevation_deg: f64,
        fov_y_deg: f64,
        aspect: f64,
    ) -> Self {
        Self::frame_box(
            lo,
            hi,
            orbit_direction(azimuth_deg, elevation_deg),
            Vector3::z(),
            fov_y_deg,
            aspect,
            0.9,
        )
    }

    /// [`Camera::frame_points`] from spherical angles about a z-up world.
    pub fn orbit_points(
        points: &[Point3<f64>],
        azimuth_deg: f64,
        elevation_deg: f64,
        fov_y_deg: f64,
        aspect: f64,
    ) -> Self {
        Self::frame_points(
            points,
            orbit_direction(azimuth_deg, elevation_deg),
            Vector3::z(),
            fov_y_deg,
            aspect,
            0.9,
        )
    }
}

/// Unit vector at azimuth (from +x towards +y) and elevation (above the xy
/// plane), degrees.
pub fn orbit_direction(azimuth_deg: f64, elevation_deg: f64) -> Vector3<f64> {
    let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin())
}
