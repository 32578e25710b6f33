//! wgpu compute backends of the collision stage (the paper's all-pairs kernel and
//! a BVH traversal kernel), both implementing [`RayBackend`].
//!
//! * [`GpuBruteForce`]: every ray against every triangle, one workgroup per ray;
//!   the per-node reduction (nearest hit behind and in front) runs in the same
//!   pass, in workgroup shared memory.
//! * [`GpuBvh`]: a BVH built once on the host from the rest surface (topology is
//!   fixed), refitted every step (on the GPU, level by level, or on the host),
//!   traversed per ray along the whole line.
//!
//! # Equal answers from f32 kernels
//!
//! The engine is f64; the kernels run in f32. They do not decide the answer, they
//! narrow it down, and the host decides in f64 with the CPU pipeline's own test,
//! [`WatertightRay::intersect`](crate::collide::rays::ray::WatertightRay::intersect)
//! (Woop, Benthin and Wald 2013, with the tie rule of [`crate::collide::rays::ray`]):
//!
//! 1. **Conservative f32 filter.** The kernel evaluates the watertight test's edge
//!    functions `e_i` in f32 together with a bound `tol_i` of their error, and
//!    keeps a triangle as a *candidate* when the origin, projected along the
//!    line, lies within `m` of the box of the projected vertices and all
//!    `e_i >= -tol_i` or all `e_i <= tol_i`. The bounds come from `m = 32 eps s`,
//!    a bound on the error of the sheared vertex coordinates (`eps = 2^-23`, `s`
//!    the largest coordinate of positions and origins after the host subtracts
//!    the rest surface's centre; a first-order count gives about `14 eps s`): for
//!    an edge `P -> Q`, `tol = 2 (m (|Px|+|Py|+|Qx|+|Qy|+2m) + 2 eps (|Qx Py| +
//!    |Qy Px|))`. So every triangle the exact line meets (what the f64 test can
//!    report) is a candidate. The filter also gives an interval `[t_lo, t_hi]`
//!    holding the exact `t` (the error of `T / det` propagated from the same
//!    bounds), or the whole line when the determinant is within its error of
//!    zero; and marks a candidate *sure* when every `e_i` is beyond its error
//!    with one sign (the exact line passes strictly inside, so the f64 test
//!    reports it).
//! 2. **Per-side lists.** For each side the kernel keeps the `K = 8` candidates
//!    with the smallest lower bound of the side's key (`-t` behind, `t` in front)
//!    and a threshold `theta`: every exact hit of that side missing from the list
//!    has key `>= theta` (`theta = +inf` when no candidate was dropped, else the
//!    `K`-th key bound). The all-pairs kernel merges the per-thread lists in
//!    shared memory. The BVH kernel skips, per side, the boxes whose parameter
//!    interval lies strictly beyond the key upper bound of a sure candidate:
//!    every hit in such a box is strictly worse than one that is listed or
//!    dropped, so it is never the answer and `theta` is unaffected.
//! 3. **f64 decision on the host.** The host evaluates the listed triangles with
//!    the watertight test on the f64 positions and keeps the nearest per side
//!    with [`keep_nearest`](crate::collide::rays::brute::keep_nearest) (ties in `|t|`:
//!    lower triangle index). The answer is final when the list was complete or
//!    when its key is `< theta`; otherwise that ray's side is answered by the
//!    CPU reference [`cast_line`](crate::collide::rays::brute::cast_line). This happens only
//!    when more than `K` candidates tie within the f32 bounds: a line lying in
//!    the plane of several triangles (unknown `t`), a line through a vertex
//!    shared by more than `K` triangles, coincident triangles.
//!    [`GpuBruteForce::fallbacks`] and [`GpuBvh::fallbacks`] count those sides.
//!
//! The answers are therefore exactly those of the CPU reference
//! [`BruteForce`](crate::collide::BruteForce) with the watertight test: same
//! triangle ids, and `t, u, v` computed by the same f64 code. The f32 filter
//! does not depend on the tie rule (it keeps every triangle the exact line
//! meets, edges and vertices included), and the f64 test's rejection of
//! parallel lines and degenerate triangles only removes hits, none of them
//! *sure* (a sure candidate's projected area is far above the rejection's
//! 1e-12 relative tolerance).
//!
//! Boxes of the BVH are padded by `64 eps s` and the slab test widens its
//! interval by `8 eps (|t0| + |t1|)`, so a box test never drops a triangle the
//! filter would keep.
//!
//! # Buffers
//!
//! All buffers persist. A step uploads the positions (`update_positions`) and the
//! rays (`cast`) with `Queue::write_buffer` into existing buffers; the ray, output
//! and readback buffers grow (to the next power of two) only when the ray count
//! grows. `cast` submits, maps the readback buffer, waits with `Device::poll` and
//! returns when the answers are in `out`: it is synchronous and complete.

mod brute;
mod bvh;
mod kernel;
mod lbvh;
mod runtime;

pub use brute::GpuBruteForce;
pub use bvh::{GpuBvh, RefitMode};
pub use lbvh::{Lbvh, LbvhNode};

use super::{RayBackend, SurfaceError};

/// Why a GPU backend could not be created.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No wgpu adapter (GPU or software rasteriser such as lavapipe) was found.
    #[error("no GPU adapter found: {0}")]
    NoAdapter(#[source] wgpu::RequestAdapterError),
    /// The adapter refused to create a device.
    #[error("GPU adapter {adapter:?} refused a device: {source}")]
    RequestDevice {
        /// Adapter name.
        adapter: String,
        /// wgpu's error.
        #[source]
        source: wgpu::RequestDeviceError,
    },
    /// The surface has a vertex index out of range, a non-finite position,
    /// or more triangles or vertices than the kernels address with `u32`.
    #[error(transparent)]
    Surface(#[from] SurfaceError),
}

/// Which GPU kernel [`backend_or_cpu`] should try.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GpuMethod {
    /// [`GpuBruteForce`].
    Brute,
    /// [`GpuBvh`].
    Bvh,
}

/// A GPU backend of the requested kind, or the CPU backend made by `cpu` when no
/// GPU backend can be created (logged with `tracing::warn!`).
pub fn backend_or_cpu(
    method: GpuMethod,
    triangles: &[[u32; 3]],
    positions: &[nalgebra::Point3<f64>],
    cpu: impl FnOnce() -> Box<dyn RayBackend>,
) -> Box<dyn RayBackend> {
    let gpu: Result<Box<dyn RayBackend>, GpuError> = match method {
        GpuMethod::Brute => GpuBruteForce::try_new(triangles, positions).map(|b| Box::new(b) as _),
        GpuMethod::Bvh => GpuBvh::try_new(triangles, positions).map(|b| Box::new(b) as _),
    };
    match gpu {
        Ok(b) => b,
        Err(GpuError::NoAdapter(reason)) => {
            tracing::warn!(%reason, "no GPU adapter, using the CPU backend");
            cpu()
        }
        Err(e) => {
            tracing::warn!(error = %e, "GPU backend unavailable, using the CPU backend");
            cpu()
        }
    }
}
