//! BVH traversal on the GPU over the refitted surface.

use nalgebra::{Point3, Vector3};

use super::GpuError;
use super::kernel::{CastKernel, upload};
use super::lbvh::Lbvh;
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
    /// The cast over `[triangles in tree order, nodes]`.
    kernel: CastKernel,
    refit: Refit,
}

/// The tree and how its boxes follow the positions.
struct Refit {
    bvh: Lbvh,
    mode: RefitMode,
    pipeline: wgpu::ComputePipeline,
    /// One uniform block and bind group per level for the refit passes.
    groups: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
    /// Positions changed since the last refit.
    stale: bool,
    pos_f32: Vec<[f32; 4]>,
}

/// Where the node buffer is among the kernel's surface buffers.
const NODES: usize = 1;

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
        let tris = upload(&dev, "bvh triangles", &tri_words);
        let nodes = upload(&dev, "bvh nodes", &bvh.nodes);
        let module = dev.module("bvh", include_str!("shaders/bvh.wgsl"));
        let cast_pipeline = dev.pipeline(&module, "cast_bvh");
        let refit_pipeline = dev.pipeline(&module, "refit_level");
        let groups = bvh
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
        Ok(Self {
            kernel: CastKernel::new(dev, frame, cast_pipeline, vec![tris, nodes], "bvh"),
            refit: Refit {
                bvh,
                mode: RefitMode::default(),
                pipeline: refit_pipeline,
                groups,
                stale: true,
                pos_f32: Vec::with_capacity(positions.len()),
            },
        })
    }

    /// Name of the adapter the kernels run on (`wgpu::AdapterInfo::name`).
    pub fn adapter_name(&self) -> &str {
        &self.kernel.adapter_info().name
    }

    /// The adapter's full description.
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        self.kernel.adapter_info()
    }

    /// Ray sides answered by the f64 brute force on the host since creation.
    pub fn fallbacks(&self) -> u64 {
        self.kernel.fallbacks()
    }

    /// Chooses where boxes are refitted (default [`RefitMode::Gpu`]).
    pub fn set_refit_mode(&mut self, mode: RefitMode) {
        self.refit.mode = mode;
        self.refit.stale = true;
    }

    /// The tree (topology from the rest surface; boxes as of the last host refit).
    pub fn tree(&self) -> &Lbvh {
        &self.refit.bvh
    }

    /// Refits now (otherwise done by the next `cast`) and waits for it: lets a
    /// benchmark time the refit alone.
    pub fn refit_now(&mut self) {
        let k = &self.kernel;
        let mut encoder = k
            .dev
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("refit"),
            });
        self.refit
            .encode(&k.dev, &k.frame, &k.surface[NODES], &mut encoder);
        k.dev.queue.submit([encoder.finish()]);
        if let Err(e) = k.dev.device.poll(wgpu::PollType::wait_indefinitely()) {
            tracing::error!(error = %e, "GPU refit wait failed");
        }
    }
}

impl Refit {
    /// Encodes the refit of the boxes to the frame's positions, if they
    /// changed since the last one.
    fn encode(
        &mut self,
        dev: &Device,
        frame: &Frame,
        nodes: &wgpu::Buffer,
        encoder: &mut wgpu::CommandEncoder,
    ) {
        if !self.stale {
            return;
        }
        self.stale = false;
        match self.mode {
            RefitMode::Cpu => {
                self.pos_f32.clear();
                let c = frame.centre;
                self.pos_f32.extend(frame.positions.iter().map(|p| {
                    let q = p.coords - c;
                    [q.x as f32, q.y as f32, q.z as f32, 0.0]
                }));
                self.bvh.refit(&frame.triangles, &self.pos_f32);
                if !self.bvh.nodes.is_empty() {
                    dev.queue
                        .write_buffer(nodes, 0, bytemuck::cast_slice(&self.bvh.nodes));
                }
            }
            RefitMode::Gpu => {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("refit"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(&self.pipeline);
                for (&(_, count), (_, group)) in self.bvh.levels.iter().zip(&self.groups).rev() {
                    pass.set_bind_group(0, group, &[]);
                    let (x, y) = grid((count as usize).div_ceil(64));
                    debug_assert_eq!(y, 1);
                    pass.dispatch_workgroups(x, y, 1);
                }
            }
        }
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
        let k = &mut self.kernel;
        if k.frame.set_positions(&k.dev, positions) {
            self.refit.stale = true;
        }
    }

    fn cast(&mut self, origins: &[Point3<f64>], dirs: &[Vector3<f64>], out: &mut Vec<NodeHits>) {
        let params = Params {
            n_nodes: self.refit.bvh.nodes.len() as u32,
            ..Params::default()
        };
        let refit = &mut self.refit;
        // One invocation a ray, 64 a workgroup; the refit goes first in the
        // same submission.
        self.kernel.cast(
            origins,
            dirs,
            out,
            params,
            |n| n.div_ceil(64),
            |dev, frame, surface, encoder| refit.encode(dev, frame, &surface[NODES], encoder),
        );
    }
}
