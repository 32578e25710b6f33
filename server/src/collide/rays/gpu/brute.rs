//! The paper's all-pairs kernel on the GPU: every source-node ray against every
//! surface triangle, with the per-node reduction in the same pass.

use nalgebra::{Point3, Vector3};

use super::GpuError;
use super::kernel::{CastKernel, upload};
use super::runtime::{Device, Frame, GpuRay, Params, validate};
use crate::collide::{NodeHits, RayBackend};

/// All-pairs ray casting on the GPU (one workgroup of 64 invocations per ray,
/// candidate lists merged in shared memory), answers decided in f64 on the host
/// (see the parent module's doc).
pub struct GpuBruteForce {
    kernel: CastKernel,
}

impl GpuBruteForce {
    /// Uploads the surface (`triangles` index `positions`, m) to the first GPU
    /// adapter. Errors: no adapter or device, indices out of range, non-finite
    /// positions.
    pub fn try_new(triangles: &[[u32; 3]], positions: &[Point3<f64>]) -> Result<Self, GpuError> {
        validate(triangles, positions)?;
        let dev = Device::new()?;
        let frame = Frame::new(&dev, triangles, positions);
        let tri_words: Vec<[u32; 4]> = triangles.iter().map(|t| [t[0], t[1], t[2], 0]).collect();
        let tris = upload(&dev, "triangles", &tri_words);
        let module = dev.module("brute", include_str!("shaders/brute.wgsl"));
        let pipeline = dev.pipeline(&module, "cast_brute");
        Ok(Self {
            kernel: CastKernel::new(dev, frame, pipeline, vec![tris], "all-pairs"),
        })
    }

    /// Name of the adapter the kernel runs on (`wgpu::AdapterInfo::name`).
    pub fn adapter_name(&self) -> &str {
        &self.kernel.adapter_info().name
    }

    /// The adapter's full description.
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        self.kernel.adapter_info()
    }

    /// Ray sides answered by the f64 brute force on the host since creation,
    /// because the GPU candidates did not settle them.
    pub fn fallbacks(&self) -> u64 {
        self.kernel.fallbacks()
    }
}

impl RayBackend for GpuBruteForce {
    fn method(&self) -> &'static str {
        "brute"
    }

    fn backend(&self) -> &'static str {
        "gpu"
    }

    fn update_positions(&mut self, positions: &[Point3<f64>]) {
        let k = &mut self.kernel;
        k.frame.set_positions(&k.dev, positions);
    }

    fn cast(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>], out: &mut Vec<NodeHits>) {
        // One workgroup a ray.
        self.kernel.cast(
            origins,
            dirs,
            out,
            Params::default(),
            |n| n,
            |_, _, _, _| {},
        );
    }
}

// GpuRay is part of the upload layout; keep the size the kernels expect.
const _: () = assert!(size_of::<GpuRay>() == 32);
