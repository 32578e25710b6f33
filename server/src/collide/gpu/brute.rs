//! The paper's all-pairs kernel on the GPU: every source-node ray against every
//! surface triangle, with the per-node reduction in the same pass.

use nalgebra::{Point3, Vector3};

use super::GpuError;
use super::runtime::{Device, Frame, GpuRay, Params, grid, validate};
use crate::collide::{NodeHits, RayBackend};

/// All-pairs ray casting on the GPU (one workgroup of 64 invocations per ray,
/// candidate lists merged in shared memory), answers decided in f64 on the host
/// (see the parent module's doc).
pub struct GpuBruteForce {
    dev: Device,
    frame: Frame,
    pipeline: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    tris: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
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
        let tris = dev.storage(
            "triangles",
            (tri_words.len() * 16) as u64,
            wgpu::BufferUsages::empty(),
        );
        if !tri_words.is_empty() {
            dev.queue
                .write_buffer(&tris, 0, bytemuck::cast_slice(&tri_words));
        }
        let params = dev.uniform("brute params", &Params::default());
        let module = dev.module("brute", include_str!("shaders/brute.wgsl"));
        let pipeline = dev.pipeline(&module, "cast_brute");
        let bind_group = Self::bind(&dev, &pipeline, &params, &frame, &tris);
        Ok(Self {
            dev,
            frame,
            pipeline,
            params,
            tris,
            bind_group,
        })
    }

    fn bind(
        dev: &Device,
        pipeline: &wgpu::ComputePipeline,
        params: &wgpu::Buffer,
        frame: &Frame,
        tris: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        let buffers = [
            params,
            &frame.positions_buf,
            tris,
            &frame.rays_buf,
            &frame.out_buf,
        ];
        dev.bind_buffers("brute", pipeline, &buffers)
    }

    /// Name of the adapter the kernel runs on (`wgpu::AdapterInfo::name`).
    pub fn adapter_name(&self) -> &str {
        &self.dev.info.name
    }

    /// The adapter's full description.
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.dev.info
    }

    /// Ray sides answered by the f64 brute force on the host since creation,
    /// because the GPU candidates did not settle them.
    pub fn fallbacks(&self) -> u64 {
        self.frame.fallbacks
    }

    fn run(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>]) -> Result<(), String> {
        let n = origins.len();
        if self.frame.reserve_rays(&self.dev, n) {
            self.bind_group = Self::bind(
                &self.dev,
                &self.pipeline,
                &self.params,
                &self.frame,
                &self.tris,
            );
        }
        let (m_err, box_pad) = self.frame.upload_rays(&self.dev, origins, dirs);
        let params = Params {
            n_rays: n as u32,
            n_tris: self.frame.triangles.len() as u32,
            m_err,
            box_pad,
            ..Params::default()
        };
        self.dev
            .queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        let mut encoder = self
            .dev
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("brute"),
            });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("brute"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.bind_group, &[]);
            let (x, y) = grid(n);
            pass.dispatch_workgroups(x, y, 1);
        }
        self.frame.encode_readback(&mut encoder, n);
        self.dev.queue.submit([encoder.finish()]);
        self.frame.read_candidates(&self.dev, n)
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
        self.frame.set_positions(&self.dev, positions);
    }

    fn cast(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>], out: &mut Vec<NodeHits>) {
        let n = origins.len().min(dirs.len());
        let (origins, dirs) = (&origins[..n], &dirs[..n]);
        if n == 0 {
            out.clear();
            return;
        }
        let run = self.run(origins, dirs);
        self.frame.answer(run, "all-pairs", origins, dirs, out);
    }
}

// GpuRay is part of the upload layout; keep the size the kernels expect.
const _: () = assert!(size_of::<GpuRay>() == 32);
