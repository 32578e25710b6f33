//! The ray stage: for every source-node ray, the nearest surface hit behind
//! and in front ([`RayBackend`]), by the line-triangle tests of [`ray`].
//!
//! * [`ray`]: line-triangle tests with signed `t` (watertight by default).
//! * [`brute`]: the paper's all-pairs reference backend.
//! * [`bvh`]: the refitted BVH backend.
//! * `gpu`: wgpu backends (the `gpu` feature, on by default).

pub mod brute;
pub mod bvh;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod ray;

use nalgebra::{Point3, Vector3};

/// One ray-triangle hit: the ray `origin + t * dir` meets triangle `triangle` at
/// barycentric coordinates `(1 - u - v, u, v)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Triangle index into the surface triangles.
    pub triangle: u32,
    /// Ray parameter, m when `dir` is unit length; negative behind the origin.
    pub t: f64,
    /// Barycentric coordinate of the triangle's second vertex.
    pub u: f64,
    /// Barycentric coordinate of the triangle's third vertex.
    pub v: f64,
}

/// The two answers one pass keeps for a source node: the nearest hit behind
/// (`t < 0`, smallest `|t|`) and the nearest in front (`t > 0`, smallest `t`).
/// A hit at exactly `t = 0` counts as behind.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NodeHits {
    /// Nearest hit with `t <= 0`.
    pub behind: Option<Hit>,
    /// Nearest hit with `t > 0`.
    pub front: Option<Hit>,
}

/// How far along its line a cast looks, m: behind up to `behind`
/// (`-behind <= t <= 0`) and in front up to `front` (`0 < t <= front`). A
/// negative bound looks nowhere on that side; [`RayRange::LINE`] is the whole
/// line.
///
/// The nearest hit within a range is the nearest hit of the whole line when
/// that one lies within the range, and none otherwise ([`RayRange::clip`]): a
/// ranged cast answers a question of the whole-line cast exactly, while a
/// backend may skip everything beyond the bounds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayRange {
    /// Largest `|t|` of a hit behind (`t <= 0`), m.
    pub behind: f64,
    /// Largest `t` of a hit in front (`t > 0`), m.
    pub front: f64,
}

impl RayRange {
    /// The whole line.
    pub const LINE: Self = Self {
        behind: f64::INFINITY,
        front: f64::INFINITY,
    };

    /// Whether a hit at `t` lies within the range.
    #[inline]
    pub fn contains(&self, t: f64) -> bool {
        if t <= 0.0 {
            -t <= self.behind
        } else {
            t <= self.front
        }
    }

    /// The whole-line answer restricted to the range.
    #[inline]
    pub fn clip(&self, hits: NodeHits) -> NodeHits {
        NodeHits {
            behind: hits.behind.filter(|h| self.contains(h.t)),
            front: hits.front.filter(|h| self.contains(h.t)),
        }
    }
}

/// A ray-casting backend over a deforming triangle surface: the stage that
/// answers, for every source-node ray, the nearest hit behind and in front.
///
/// Implementations: CPU brute force (the paper's reference), CPU BVH, and the
/// wgpu backends in `gpu` (the `gpu` feature). All must give the same answers.
pub trait RayBackend: Send {
    /// Name for logs and benchmarks, e.g. "brute" or "bvh".
    fn method(&self) -> &'static str;
    /// Name of the device, e.g. "cpu" or "gpu".
    fn backend(&self) -> &'static str;
    /// Sets the current surface vertex positions (m), same order and count as the
    /// triangles' indices refer to. Called whenever the surface deformed; a BVH
    /// refits here.
    fn update_positions(&mut self, positions: &[Point3<f64>]);
    /// Casts one ray per source node: `origins[i] + t * dirs[i]`, `dirs` unit
    /// length. Writes `out[i]` for every `i` (`out` is resized to the ray count).
    fn cast(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>], out: &mut Vec<NodeHits>);
    /// As [`RayBackend::cast`], each ray looking only within `ranges[i]`: the
    /// answer is the whole-line answer clipped to the range ([`RayRange`]).
    /// The default casts whole lines and clips; a backend that can skip work
    /// beyond the bounds overrides it.
    fn cast_ranged(
        &mut self,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        ranges: &[RayRange],
        out: &mut Vec<NodeHits>,
    ) {
        self.cast(origins, dirs, out);
        for (h, r) in out.iter_mut().zip(ranges) {
            *h = r.clip(*h);
        }
    }
}

/// The box `[lo, hi]` (m) widened on every side by a margin far above the
/// rounding of the points it was built from and of the tests run against it
/// (`1e-9` of its extent plus its largest coordinate, plus 1 pm): a box meant
/// to hold every point of some segments or triangles must not lose one to
/// rounding.
pub(crate) fn widen_box(lo: Point3<f64>, hi: Point3<f64>) -> (Point3<f64>, Point3<f64>) {
    let size = lo.coords.abs().max().max(hi.coords.abs().max());
    let margin = 1e-9 * ((hi - lo).max() + size) + 1e-12;
    (lo.map(|x| x - margin), hi.map(|x| x + margin))
}

/// Errors in a surface handed to a backend (and to the contact pipeline):
/// the one surface-validation error of the engine and its clients.
pub use fissure_shared::surface::SurfaceError;

/// Checks indices and finiteness; returns one more than the largest vertex
/// index used (the number of positions a backend needs).
pub(crate) use fissure_shared::surface::check_surface;
