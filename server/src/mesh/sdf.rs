//! Signed distance functions and constructive solid geometry.
//!
//! A shape is a scalar field `f: R^3 -> R` (m), negative inside, positive
//! outside, zero on the surface. The primitives below are exact Euclidean
//! distances ([`Sphere`], [`Aabb`] box, [`Slab`], [`HalfSpace`], [`Capsule`]) or
//! distance bounds ([`Ellipsoid`]: the first-order estimate `(k - 1) k / |grad k|`
//! with `k = |p / r|`, exact on the surface and on the axes). Combinators:
//! `min` (union), `max` (intersection), `max(a, -b)` (difference), and the
//! polynomial smooth union of radius `k`, `min(a, b) - h^2 k / 4` with
//! `h = max(k - |a - b|, 0) / k`, which changes the field only where both
//! arguments are within `k` of each other.
//!
//! The mesher ([`super::stuffing`]) only needs the sign of the field and its
//! roots along lattice edges; it uses magnitudes only for grading and for
//! discarding far-away cells, where a field within a factor 2 of the true
//! distance is enough.

use nalgebra::{Point3, Vector3};

/// A signed distance field: negative inside, m.
pub trait Sdf: Send + Sync {
    /// The signed distance (or a distance estimate of the same sign) at `p`, m.
    fn distance(&self, p: &Point3<f64>) -> f64;
}

impl<F: Fn(&Point3<f64>) -> f64 + Send + Sync> Sdf for F {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        self(p)
    }
}

impl Sdf for Box<dyn Sdf> {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        (**self).distance(p)
    }
}

/// A ball of `radius` (m) about `centre`. Exact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    pub centre: Point3<f64>,
    pub radius: f64,
}

impl Sdf for Sphere {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        (p - self.centre).norm() - self.radius
    }
}

/// An axis-aligned ellipsoid with semi-axes `radii` (m) about `centre`.
/// Distance estimate `k (k - 1) / |grad k|`, `k = |(p - c) / r|`: exact on the
/// surface and along the axes, within a factor `max r / min r` elsewhere.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ellipsoid {
    pub centre: Point3<f64>,
    pub radii: Vector3<f64>,
}

impl Sdf for Ellipsoid {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        let q = p - self.centre;
        let k0 = q.component_div(&self.radii).norm();
        let k1 = q
            .component_div(&self.radii.component_mul(&self.radii))
            .norm();
        if k1 == 0.0 {
            // At the centre: the distance to the surface is the smallest semi-axis.
            return -self.radii.min();
        }
        k0 * (k0 - 1.0) / k1
    }
}

/// An axis-aligned box `[lo, hi]` (m). Exact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub lo: Point3<f64>,
    pub hi: Point3<f64>,
}

impl Aabb {
    /// Grows the box by `margin` (m) on every side.
    pub fn inflated(&self, margin: f64) -> Self {
        let m = Vector3::repeat(margin);
        Self {
            lo: self.lo - m,
            hi: self.hi + m,
        }
    }
}

impl Sdf for Aabb {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        let c = nalgebra::center(&self.lo, &self.hi);
        let half = (self.hi - self.lo) * 0.5;
        let d = (p - c).abs() - half;
        let outside = d.sup(&Vector3::zeros()).norm();
        outside + d.max().min(0.0)
    }
}

/// The half-space `(p - point) . normal <= 0`; `normal` must be a unit vector.
/// Exact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HalfSpace {
    pub point: Point3<f64>,
    pub normal: Vector3<f64>,
}

impl Sdf for HalfSpace {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        (p - self.point).dot(&self.normal)
    }
}

/// The slab `|(p - centre) . normal| <= width / 2` (unit `normal`, m). Exact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Slab {
    pub centre: Point3<f64>,
    pub normal: Vector3<f64>,
    pub width: f64,
}

impl Sdf for Slab {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        (p - self.centre).dot(&self.normal).abs() - 0.5 * self.width
    }
}

/// All points within `radius` (m) of the segment `[a, b]`. Exact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Capsule {
    pub a: Point3<f64>,
    pub b: Point3<f64>,
    pub radius: f64,
}

impl Sdf for Capsule {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        let ab = self.b - self.a;
        let len2 = ab.norm_squared();
        let t = if len2 > 0.0 {
            ((p - self.a).dot(&ab) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (p - (self.a + ab * t)).norm() - self.radius
    }
}

/// Difference `a \ b`: `max(a, -b)`.
pub fn difference(a: f64, b: f64) -> f64 {
    a.max(-b)
}

/// Polynomial smooth union of radius `k` (m): `min(a, b) - h^2 k / 4`,
/// `h = max(k - |a - b|, 0) / k`. Equal to `min(a, b)` where `|a - b| >= k`;
/// never larger than `min(a, b)`, so it only adds material.
pub fn smooth_union(a: f64, b: f64, k: f64) -> f64 {
    if k <= 0.0 {
        return a.min(b);
    }
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

/// Finds the root of `f` on the segment `[a, b]` given `fa = f(a) < 0 < fb = f(b)`
/// (or the reverse) by the Illinois variant of regula falsi, stopping when the
/// bracket is shorter than `tol` (m) or after 60 evaluations. Returns the
/// parameter `t` in `[0, 1]` of the root `a + t (b - a)`.
pub fn edge_root(
    f: &dyn Fn(&Point3<f64>) -> f64,
    a: &Point3<f64>,
    b: &Point3<f64>,
    fa: f64,
    fb: f64,
    tol: f64,
) -> f64 {
    let len = (b - a).norm();
    if len == 0.0 {
        return 0.0;
    }
    let (mut t0, mut f0, mut t1, mut f1) = (0.0, fa, 1.0, fb);
    let mut side = 0i8;
    for _ in 0..60 {
        if (t1 - t0) * len <= tol {
            break;
        }
        let mut t = (t0 * f1 - t1 * f0) / (f1 - f0);
        if !t.is_finite() || t <= t0 || t >= t1 {
            t = 0.5 * (t0 + t1);
        }
        let ft = f(&(a + (b - a) * t));
        if ft == 0.0 {
            return t;
        }
        if (ft < 0.0) == (f0 < 0.0) {
            t0 = t;
            f0 = ft;
            if side == -1 {
                f1 *= 0.5;
            }
            side = -1;
        } else {
            t1 = t;
            f1 = ft;
            if side == 1 {
                f0 *= 0.5;
            }
            side = 1;
        }
    }
    // The point of the final bracket nearest the interpolated root.
    let t = (t0 * f1 - t1 * f0) / (f1 - f0);
    if t.is_finite() {
        t.clamp(t0, t1)
    } else {
        0.5 * (t0 + t1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_primitives() {
        let s = Sphere {
            centre: Point3::new(1.0, 0.0, 0.0),
            radius: 0.5,
        };
        assert!((s.distance(&Point3::new(3.0, 0.0, 0.0)) - 1.5).abs() < 1e-15);
        assert!((s.distance(&Point3::new(1.0, 0.0, 0.0)) + 0.5).abs() < 1e-15);
        let b = Aabb {
            lo: Point3::new(0.0, 0.0, 0.0),
            hi: Point3::new(1.0, 2.0, 3.0),
        };
        assert!((b.distance(&Point3::new(0.5, 1.0, 1.5)) + 0.5).abs() < 1e-15);
        assert!((b.distance(&Point3::new(2.0, 3.0, 1.0)) - 2f64.sqrt()).abs() < 1e-15);
        let slab = Slab {
            centre: Point3::origin(),
            normal: Vector3::x(),
            width: 0.002,
        };
        assert!((slab.distance(&Point3::new(-0.003, 5.0, 1.0)) - 0.002).abs() < 1e-15);
        let c = Capsule {
            a: Point3::origin(),
            b: Point3::new(0.0, 0.0, 1.0),
            radius: 0.1,
        };
        assert!((c.distance(&Point3::new(0.0, 0.0, -1.0)) - 0.9).abs() < 1e-15);
        assert!((c.distance(&Point3::new(0.3, 0.0, 0.5)) - 0.2).abs() < 1e-15);
    }

    #[test]
    fn ellipsoid_is_exact_on_surface_and_axes_and_bounded() {
        let e = Ellipsoid {
            centre: Point3::origin(),
            radii: Vector3::new(0.03, 0.08, 0.05),
        };
        assert!(e.distance(&Point3::new(0.03, 0.0, 0.0)).abs() < 1e-15);
        assert!((e.distance(&Point3::new(0.0, 0.1, 0.0)) - 0.02).abs() < 1e-12);
        assert!((e.distance(&Point3::new(0.0, 0.0, 0.04)) + 0.01).abs() < 1e-12);
        assert!((e.distance(&Point3::origin()) + 0.03).abs() < 1e-15);
        // On a surface point off the axes the estimate is zero too.
        let (u, v) = (0.3f64, 1.1f64);
        let p = Point3::new(
            0.03 * u.cos() * v.sin(),
            0.08 * u.sin() * v.sin(),
            0.05 * v.cos(),
        );
        assert!(e.distance(&p).abs() < 1e-15);
    }

    #[test]
    fn smooth_union_only_adds_material_near_the_seam() {
        assert_eq!(smooth_union(0.5, -0.2, 0.1), -0.2);
        assert!(smooth_union(0.01, 0.01, 0.1) < 0.01);
        assert!((smooth_union(0.0, 0.0, 0.1) + 0.025).abs() < 1e-15);
        assert_eq!(difference(-1.0, -0.5), 0.5);
    }

    #[test]
    fn edge_root_finds_the_surface() {
        let s = Sphere {
            centre: Point3::origin(),
            radius: 1.0,
        };
        let f = |p: &Point3<f64>| s.distance(p);
        let (a, b) = (Point3::new(0.2, 0.1, 0.0), Point3::new(3.0, -0.4, 0.5));
        let t = edge_root(&f, &a, &b, f(&a), f(&b), 1e-12);
        assert!(f(&(a + (b - a) * t)).abs() < 1e-10);
        // Reversed sign order.
        let t = edge_root(&f, &b, &a, f(&b), f(&a), 1e-12);
        assert!(f(&(b + (a - b) * t)).abs() < 1e-10);
    }
}
