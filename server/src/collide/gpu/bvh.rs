//! BVH traversal on the GPU over the refitted surface.

use nalgebra::{Point3, Vector3};

use super::GpuError;
use super::lbvh::{Lbvh, LbvhNode};
use super::runtime::{Device, Frame, Params, grid, validate};
use crate::collide::{NodeHits, RayBackend};

/// Where [`GpuBvh`] refits its boxes after `update_positions`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RefitMode {
    /// One compute dispatch per tree level, deepest first, on the uploaded
    /// positions (only positions cross the bus).
    #[default]
    Gpu,
    /// On the host from the f32 positions; the whole node array is uploaded.
    Cpu,
}

/// BVH ray casting on the GPU: one invocation per ray walks the tree with a
/// stack along the whole line (both directions) and keeps the candidate lists
/// per side; answers decided in f64 on the host (see the parent module's doc).
pub struct GpuBvh {
    dev: Device,
    frame: Frame,
    bvh: Lbvh,
    refit_mode: RefitMode,
    cast_pipeline: wgpu::ComputePipeline,
    refit_pipeline: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    tris: wgpu::Buffer,
    nodes: wgpu::Buffer,
    cast_group: wgpu::BindGroup,
    /// One uniform block and bind group per level for the refit passes.
    refit_groups: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
    /// Positions changed since the last refit.
    stale: bool,
    pos_f32: Vec<[f32; 4]>,
}

impl GpuBvh {
    /// Builds the BVH from the rest surface (`triangles` index `positions`, m) and
    /// uploads it to the first GPU adapter. Errors as
    /// [`GpuBruteForce::try_new`](super::GpuBruteForce::try_new).
    pub fn try_new(triangles: &[[u32; 3]], positions: &[Point3<f64>]) -> Result<Self, GpuError> {
        validate(triangles, positions)?;
        let dev = Device::new()?;
        let frame = Frame::new(&dev, triangles, positions);
        let bvh = Lbvh::build(triangles, positions);
        let tri_words: Vec<[u32; 4]> = bvh
            .order
            .iter()
            .map(|&t| {
                let v = triangles[t as usize];
                [v[0], v[1], v[2], t]
            })
            .collect();
        let tris = dev.storage(
            "bvh triangles",
            (tri_words.len() * 16) as u64,
            wgpu::BufferUsages::empty(),
        );
        if !tri_words.is_empty() {
            dev.queue
                .write_buffer(&tris, 0, bytemuck::cast_slice(&tri_words));
        }
        let nodes = dev.storage(
            "bvh nodes",
            (bvh.nodes.len() * size_of::<LbvhNode>()) as u64,
            wgpu::BufferUsages::empty(),
        );
        if !bvh.nodes.is_empty() {
            dev.queue
                .write_buffer(&nodes, 0, bytemuck::cast_slice(&bvh.nodes));
        }
        let params = dev.uniform("bvh params", &Params::default());
        let module = dev.module("bvh", include_str!("shaders/bvh.wgsl"));
        let cast_pipeline = dev.pipeline(&module, "cast_bvh");
        let refit_pipeline = dev.pipeline(&module, "refit_level");
        let refit_groups = bvh
            .levels
            .iter()
            .map(|&(first, count)| {
                let p = Params {
                    n_tris: triangles.len() as u32,
                    n_nodes: bvh.nodes.len() as u32,
                    level_first: first,
                    level_count: count,
                    ..Params::default()
                };
                let buf = dev.uniform("refit level", &p);
                let group = dev.bind_buffers(
                    "refit level",
                    &refit_pipeline,
                    &[&buf, &frame.positions_buf, &tris, &nodes],
                );
                (buf, group)
            })
            .collect();
        let cast_group = Self::bind(&dev, &cast_pipeline, &params, &frame, &tris, &nodes);
        Ok(Self {
            dev,
            frame,
            bvh,
            refit_mode: RefitMode::default(),
            cast_pipeline,
            refit_pipeline,
            params,
            tris,
            nodes,
            cast_group,
            refit_groups,
            stale: true,
            pos_f32: Vec::with_capacity(positions.len()),
        })
    }

    fn bind(
        dev: &Device,
        pipeline: &wgpu::ComputePipeline,
        params: &wgpu::Buffer,
        frame: &Frame,
        tris: &wgpu::Buffer,
        nodes: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        let buffers = [
            params,
            &frame.positions_buf,
            tris,
            nodes,
            &frame.rays_buf,
            &frame.out_buf,
        ];
        dev.bind_buffers("bvh cast", pipeline, &buffers)
    }

    /// Name of the adapter the kernels run on (`wgpu::AdapterInfo::name`).
    pub fn adapter_name(&self) -> &str {
        &self.dev.info.name
    }

    /// The adapter's full description.
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.dev.info
    }

    /// Ray sides answered by the f64 brute force on the host since creation.
    pub fn fallbacks(&self) -> u64 {
        self.frame.fallbacks
    }

    /// Chooses where boxes are refitted (default [`RefitMode::Gpu`]).
    pub fn set_refit_mode(&mut self, mode: RefitMode) {
        self.refit_mode = mode;
        self.stale = true;
    }

    /// The tree (topology from the rest surface; boxes as of the last host refit).
    pub fn tree(&self) -> &Lbvh {
        &self.bvh
    }

    /// Refits now (otherwise done by the next `cast`) and waits for it: lets a
    /// benchmark time the refit alone.
    pub fn refit_now(&mut self) {
        let mut encoder = self
            .dev
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("refit"),
            });
        self.encode_refit(&mut encoder);
        self.dev.queue.submit([encoder.finish()]);
        if let Err(e) = self.dev.device.poll(wgpu::PollType::wait_indefinitely()) {
            tracing::error!(error = %e, "GPU refit wait failed");
        }
    }

    fn encode_refit(&mut self, encoder: &mut wgpu::CommandEncoder) {
        if !self.stale {
            return;
        }
        self.stale = false;
        match self.refit_mode {
            RefitMode::Cpu => {
                self.pos_f32.clear();
                let c = self.frame.centre;
                self.pos_f32.extend(self.frame.positions.iter().map(|p| {
                    let q = p.coords - c;
                    [q.x as f32, q.y as f32, q.z as f32, 0.0]
                }));
                self.bvh.refit(&self.frame.triangles, &self.pos_f32);
                if !self.bvh.nodes.is_empty() {
                    self.dev.queue.write_buffer(
                        &self.nodes,
                        0,
                        bytemuck::cast_slice(&self.bvh.nodes),
                    );
                }
            }
            RefitMode::Gpu => {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("refit"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(&self.refit_pipeline);
                for (&(_, count), (_, group)) in
                    self.bvh.levels.iter().zip(&self.refit_groups).rev()
                {
                    pass.set_bind_group(0, group, &[]);
                    let (x, y) = grid((count as usize).div_ceil(64));
                    debug_assert_eq!(y, 1);
                    pass.dispatch_workgroups(x, y, 1);
                }
            }
        }
    }

    fn run(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>]) -> Result<(), String> {
        let n = origins.len();
        if self.frame.reserve_rays(&self.dev, n) {
            self.cast_group = Self::bind(
                &self.dev,
                &self.cast_pipeline,
                &self.params,
                &self.frame,
                &self.tris,
                &self.nodes,
            );
        }
        let (m_err, box_pad) = self.frame.upload_rays(&self.dev, origins, dirs);
        let params = Params {
            n_rays: n as u32,
            n_tris: self.frame.triangles.len() as u32,
            n_nodes: self.bvh.nodes.len() as u32,
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
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("bvh") });
        self.encode_refit(&mut encoder);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("bvh cast"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.cast_pipeline);
            pass.set_bind_group(0, &self.cast_group, &[]);
            let (x, y) = grid(n.div_ceil(64));
            pass.dispatch_workgroups(x, y, 1);
        }
        self.frame.encode_readback(&mut encoder, n);
        self.dev.queue.submit([encoder.finish()]);
        self.frame.read_candidates(&self.dev, n)
    }
}

impl RayBackend for GpuBvh {
    fn method(&self) -> &'static str {
        "bvh"
    }

    fn backend(&self) -> &'static str {
        "gpu"
    }

    fn update_positions(&mut self, positions: &[Point3<f64>]) {
        if self.frame.set_positions(&self.dev, positions) {
            self.stale = true;
        }
    }

    fn cast(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>], out: &mut Vec<NodeHits>) {
        let n = origins.len().min(dirs.len());
        let (origins, dirs) = (&origins[..n], &dirs[..n]);
        if n == 0 {
            out.clear();
            return;
        }
        let run = self.run(origins, dirs);
        self.frame.answer(run, "bvh", origins, dirs, out);
    }
}
