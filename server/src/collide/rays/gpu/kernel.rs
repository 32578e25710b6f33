//! What the two ray-casting kernels share: the device and the [`Frame`]
//! (positions, rays, candidate buffers and the f64 decision on the host), a
//! cast pipeline with its uniform block, and its bind group over
//! `[params, positions, surface buffers..., rays, candidates]` (rebound when
//! the ray buffers grow). A kernel differs only in its surface buffers (the
//! triangles; the BVH's nodes too), its workgroups per ray and what it
//! encodes before the cast (the BVH's refit).

use nalgebra::{Point3, Vector3};

use super::runtime::{Device, Frame, Params, grid};
use crate::collide::NodeHits;

/// A cast pipeline over a frame.
pub(crate) struct CastKernel {
    pub dev: Device,
    pub frame: Frame,
    pipeline: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    /// The surface buffers, bound after the positions, in the shader's order.
    pub surface: Vec<wgpu::Buffer>,
    group: wgpu::BindGroup,
    label: &'static str,
}

/// Uploads `words` into a new storage buffer of `dev` (one of at least 16
/// bytes' worth when `words` is empty).
pub(crate) fn upload<T: bytemuck::Pod>(dev: &Device, label: &str, words: &[T]) -> wgpu::Buffer {
    let buf = dev.storage(
        label,
        std::mem::size_of_val(words) as u64,
        wgpu::BufferUsages::empty(),
    );
    if !words.is_empty() {
        dev.queue.write_buffer(&buf, 0, bytemuck::cast_slice(words));
    }
    buf
}

impl CastKernel {
    /// The kernel of `pipeline` over `frame`, with `surface` bound after the
    /// positions.
    pub fn new(
        dev: Device,
        frame: Frame,
        pipeline: wgpu::ComputePipeline,
        surface: Vec<wgpu::Buffer>,
        label: &'static str,
    ) -> Self {
        let params = dev.uniform(label, &Params::default());
        let group = Self::bind(&dev, &pipeline, &params, &frame, &surface, label);
        Self {
            dev,
            frame,
            pipeline,
            params,
            surface,
            group,
            label,
        }
    }

    fn bind(
        dev: &Device,
        pipeline: &wgpu::ComputePipeline,
        params: &wgpu::Buffer,
        frame: &Frame,
        surface: &[wgpu::Buffer],
        label: &str,
    ) -> wgpu::BindGroup {
        let mut buffers = Vec::with_capacity(surface.len() + 4);
        buffers.push(params);
        buffers.push(&frame.positions_buf);
        buffers.extend(surface);
        buffers.push(&frame.rays_buf);
        buffers.push(&frame.out_buf);
        dev.bind_buffers(label, pipeline, &buffers)
    }

    /// The adapter's full description.
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.dev.info
    }

    /// Ray sides answered by the f64 brute force on the host since creation.
    pub fn fallbacks(&self) -> u64 {
        self.frame.fallbacks
    }

    /// Casts `origins` along `dirs` into `out` (`what` names the kernel in a
    /// fallback's log): uploads the rays, fills `params`' ray count, triangle
    /// count and error bounds, encodes `before` (given the device, the frame
    /// and the surface buffers), then the cast pass of `workgroups(n)`
    /// workgroups, reads the candidates back and decides them in f64.
    pub fn cast(
        &mut self,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        out: &mut Vec<NodeHits>,
        params: Params,
        workgroups: fn(usize) -> usize,
        before: impl FnOnce(&Device, &Frame, &[wgpu::Buffer], &mut wgpu::CommandEncoder),
    ) {
        let n = origins.len().min(dirs.len());
        let (origins, dirs) = (&origins[..n], &dirs[..n]);
        if n == 0 {
            out.clear();
            return;
        }
        let run = self.run(origins, dirs, params, workgroups(n), before);
        self.frame.answer(run, self.label, origins, dirs, out);
    }

    fn run(
        &mut self,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        params: Params,
        workgroups: usize,
        before: impl FnOnce(&Device, &Frame, &[wgpu::Buffer], &mut wgpu::CommandEncoder),
    ) -> Result<(), super::runtime::ReadbackError> {
        let n = origins.len();
        if self.frame.reserve_rays(&self.dev, n) {
            self.group = Self::bind(
                &self.dev,
                &self.pipeline,
                &self.params,
                &self.frame,
                &self.surface,
                self.label,
            );
        }
        let (m_err, box_pad) = self.frame.upload_rays(&self.dev, origins, dirs);
        let params = Params {
            n_rays: n as u32,
            n_tris: self.frame.triangles.len() as u32,
            m_err,
            box_pad,
            ..params
        };
        self.dev
            .queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        let mut encoder = self
            .dev
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some(self.label),
            });
        before(&self.dev, &self.frame, &self.surface, &mut encoder);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(self.label),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.group, &[]);
            let (x, y) = grid(workgroups);
            pass.dispatch_workgroups(x, y, 1);
        }
        self.frame.encode_readback(&mut encoder, n);
        self.dev.queue.submit([encoder.finish()]);
        self.frame.read_candidates(&self.dev, n)
    }
}
