//! The collision pipeline of Fukuhara et al. (2014), DESIGN.md section 2.
//!
//! Stages, each a plain function or struct over plain data:
//! pose -> source-node rays (instrument frame to scene frame) -> per-node nearest
//! hit behind and in front ([`RayBackend`]) -> collision pairs (A1, A2) ->
//! history culling (B1-B3) -> enforced displacements.

pub mod gpu;

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

/// A ray-casting backend over a deforming triangle surface: the stage that
/// answers, for every source-node ray, the nearest hit behind and in front.
///
/// Implementations: CPU brute force (the paper's reference), CPU BVH, and the
/// wgpu backends in [`gpu`]. All must give the same answers.
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
}
