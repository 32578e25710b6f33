//! What both GPU backends share: the device, the persistent buffers of positions,
//! rays, candidate output and readback, the f64 -> f32 conversion, and the host's
//! f64 decision over the candidates (see the parent module's doc).

use std::sync::{Arc, Mutex};

use bytemuck::{Pod, Zeroable};
use nalgebra::{Point3, Vector3};

use super::GpuError;

/// Why a kernel's answers could not be read back (the rays are then
/// answered on the host).
#[derive(Debug, thiserror::Error)]
pub enum ReadbackError {
    /// A thread panicked while holding the readback slot.
    #[error("the readback slot's lock is poisoned")]
    Poisoned,
    /// Waiting for the device failed.
    #[error("device poll failed: {0}")]
    Poll(#[from] wgpu::PollError),
    /// Mapping the readback buffer failed.
    #[error("mapping the readback buffer failed: {0}")]
    Map(#[source] wgpu::BufferAsyncError),
    /// The map callback had not run after the poll returned.
    #[error("readback not mapped after the device poll")]
    NotMapped,
    /// The mapped range could not be viewed.
    #[error("viewing the mapped readback failed: {0}")]
    View(#[from] wgpu::MapRangeError),
}

use crate::collide::rays::brute::{cast_line, keep_nearest};
use crate::collide::rays::ray::{RayTest, WatertightRay};
use crate::collide::rays::{Hit, NodeHits, SurfaceError, check_surface};

/// Candidates kept per ray and side (the kernels' `K`).
pub(crate) const K: usize = 8;
/// u32 words per ray in the output: per side `K` ids, `K` key bounds, threshold.
pub(crate) const OUT_WORDS: usize = 2 * (2 * K + 1);
const NO_TRI: u32 = u32::MAX;
/// Keys at or above this are "empty" / "complete" in the kernels.
const KEY_EMPTY: f32 = 3.0e38;
const EPS32: f64 = f32::EPSILON as f64;

/// The kernels' uniform block (`Params` in `common.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub(crate) struct Params {
    pub n_rays: u32,
    pub n_tris: u32,
    pub n_nodes: u32,
    pub level_first: u32,
    pub level_count: u32,
    pub m_err: f32,
    pub box_pad: f32,
    pub pad: u32,
}

/// One ray as the kernels read it (`Ray` in `common.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub(crate) struct GpuRay {
    pub origin: [f32; 4],
    pub dir: [f32; 4],
}

/// The device and queue of one adapter.
pub(crate) struct Device {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
}

impl Device {
    /// The first adapter wgpu offers (high-performance preference; a software
    /// adapter such as lavapipe when nothing else exists). Backends follow
    /// `WGPU_BACKEND` when set, else Vulkan, Metal, DX12.
    pub fn new() -> Result<Self, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
        let instance = wgpu::Instance::new(desc);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        }))
        .map_err(GpuError::NoAdapter)?;
        let info = adapter.get_info();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("fissure collide"),
            required_features: wgpu::Features::empty(),
            required_limits: wgpu::Limits::default(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|source| GpuError::RequestDevice {
            adapter: info.name.clone(),
            source,
        })?;
        Ok(Self {
            device,
            queue,
            info,
        })
    }

    pub fn storage(&self, label: &str, size: u64, extra: wgpu::BufferUsages) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: size.max(16),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | extra,
            mapped_at_creation: false,
        })
    }

    pub fn uniform(&self, label: &str, params: &Params) -> wgpu::Buffer {
        let buf = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: size_of::<Params>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.queue.write_buffer(&buf, 0, bytemuck::bytes_of(params));
        buf
    }

    /// A bind group of `buffers` at bindings `0, 1, ...` of group 0 of `pipeline`.
    pub fn bind_buffers(
        &self,
        label: &str,
        pipeline: &wgpu::ComputePipeline,
        buffers: &[&wgpu::Buffer],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry<'_>> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    pub fn pipeline(&self, module: &wgpu::ShaderModule, entry: &str) -> wgpu::ComputePipeline {
        self.device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: None,
                module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
    }

    pub fn module(&self, label: &str, kernel: &str) -> wgpu::ShaderModule {
        let source = format!("{}\n{}", include_str!("shaders/common.wgsl"), kernel);
        self.device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            })
    }
}

/// Checks the surface: indices in range, positions finite, counts addressable.
pub(crate) fn validate(triangles: &[[u32; 3]], positions: &[Point3<f64>]) -> Result<(), GpuError> {
    if triangles.len() >= (u32::MAX / 2) as usize {
        return Err(SurfaceError::TooLarge {
            what: "triangles",
            count: triangles.len(),
        }
        .into());
    }
    if positions.len() >= u32::MAX as usize {
        return Err(SurfaceError::TooLarge {
            what: "vertices",
            count: positions.len(),
        }
        .into());
    }
    check_surface(triangles, positions)?;
    Ok(())
}

/// Persistent per-step state shared by both backends.
pub(crate) struct Frame {
    pub triangles: Vec<[u32; 3]>,
    /// Current f64 positions (the host decides on these).
    pub positions: Vec<Point3<f64>>,
    /// Centre of the rest surface's box, subtracted before rounding to f32.
    pub centre: Vector3<f64>,
    /// Largest |coordinate| of the centred positions.
    pub pos_scale: f64,
    pos_f32: Vec<[f32; 4]>,
    rays_f32: Vec<GpuRay>,
    pub words: Vec<u32>,
    pub positions_buf: wgpu::Buffer,
    pub rays_buf: wgpu::Buffer,
    pub out_buf: wgpu::Buffer,
    readback: wgpu::Buffer,
    /// Rays the ray/output/readback buffers hold.
    pub ray_capacity: usize,
    map_result: Arc<Mutex<Option<Result<(), wgpu::BufferAsyncError>>>>,
    /// Sides answered by the f64 brute force because the candidates did not
    /// settle them.
    pub fallbacks: u64,
}

impl Frame {
    pub fn new(dev: &Device, triangles: &[[u32; 3]], positions: &[Point3<f64>]) -> Self {
        let (lo, hi) = positions.iter().fold(
            (
                Vector3::repeat(f64::INFINITY),
                Vector3::repeat(f64::NEG_INFINITY),
            ),
            |(lo, hi), p| (lo.inf(&p.coords), hi.sup(&p.coords)),
        );
        let centre = if positions.is_empty() {
            Vector3::zeros()
        } else {
            0.5 * (lo + hi)
        };
        let ray_capacity = 64;
        let mut frame = Self {
            triangles: triangles.to_vec(),
            positions: positions.to_vec(),
            centre,
            pos_scale: 0.0,
            pos_f32: Vec::with_capacity(positions.len()),
            rays_f32: Vec::with_capacity(ray_capacity),
            words: Vec::with_capacity(ray_capacity * OUT_WORDS),
            positions_buf: dev.storage(
                "positions",
                (positions.len() * 16) as u64,
                wgpu::BufferUsages::empty(),
            ),
            rays_buf: dev.storage(
                "rays",
                (ray_capacity * size_of::<GpuRay>()) as u64,
                wgpu::BufferUsages::empty(),
            ),
            out_buf: dev.storage(
                "candidates",
                (ray_capacity * OUT_WORDS * 4) as u64,
                wgpu::BufferUsages::COPY_SRC,
            ),
            readback: readback(dev, ray_capacity),
            ray_capacity,
            map_result: Arc::new(Mutex::new(None)),
            fallbacks: 0,
        };
        frame.upload_positions(dev);
        frame
    }

    /// Replaces the positions; `false` (and nothing changed) when the count
    /// differs from the surface's or a position is not finite.
    pub fn set_positions(&mut self, dev: &Device, positions: &[Point3<f64>]) -> bool {
        if positions.len() != self.positions.len() {
            tracing::error!(
                given = positions.len(),
                expected = self.positions.len(),
                "GPU collide backend: position count differs from the surface's, update ignored"
            );
            return false;
        }
        if let Some(vertex) = positions
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            tracing::error!(
                vertex,
                "GPU collide backend: non-finite position, update ignored"
            );
            return false;
        }
        self.positions.copy_from_slice(positions);
        self.upload_positions(dev);
        true
    }

    fn upload_positions(&mut self, dev: &Device) {
        self.pos_f32.clear();
        let mut scale = 0.0f64;
        for p in &self.positions {
            let c = p.coords - self.centre;
            scale = scale.max(c.amax());
            self.pos_f32.push([c.x as f32, c.y as f32, c.z as f32, 0.0]);
        }
        self.pos_scale = scale;
        if !self.pos_f32.is_empty() {
            dev.queue
                .write_buffer(&self.positions_buf, 0, bytemuck::cast_slice(&self.pos_f32));
        }
    }

    /// Grows the ray-sized buffers to hold `n` rays; `true` when they were
    /// replaced (bind groups must be rebuilt).
    pub fn reserve_rays(&mut self, dev: &Device, n: usize) -> bool {
        if n <= self.ray_capacity {
            return false;
        }
        let cap = n.next_power_of_two();
        self.rays_buf = dev.storage(
            "rays",
            (cap * size_of::<GpuRay>()) as u64,
            wgpu::BufferUsages::empty(),
        );
        self.out_buf = dev.storage(
            "candidates",
            (cap * OUT_WORDS * 4) as u64,
            wgpu::BufferUsages::COPY_SRC,
        );
        self.readback = readback(dev, cap);
        self.ray_capacity = cap;
        true
    }

    /// Converts and uploads the rays; returns the `Params` error bounds
    /// `(m_err, box_pad)` for this step.
    pub fn upload_rays(
        &mut self,
        dev: &Device,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
    ) -> (f32, f32) {
        self.rays_f32.clear();
        let mut scale = self.pos_scale;
        for (o, d) in origins.iter().zip(dirs) {
            let c = o.coords - self.centre;
            if c.iter().all(|x| x.is_finite()) {
                scale = scale.max(c.amax());
            }
            self.rays_f32.push(GpuRay {
                origin: [c.x as f32, c.y as f32, c.z as f32, 0.0],
                dir: [d.x as f32, d.y as f32, d.z as f32, 0.0],
            });
        }
        if !self.rays_f32.is_empty() {
            dev.queue
                .write_buffer(&self.rays_buf, 0, bytemuck::cast_slice(&self.rays_f32));
        }
        // Bounds in f32 rounded up: a bound of the sheared-coordinate error and the
        // box padding (see the parent module's doc).
        let m = (32.0 * EPS32 * scale) as f32 * (1.0 + 1e-6) + f32::MIN_POSITIVE;
        let pad = (64.0 * EPS32 * scale) as f32 * (1.0 + 1e-6) + f32::MIN_POSITIVE;
        (m, pad)
    }

    /// Appends the copy of the candidates into the readback buffer.
    pub fn encode_readback(&self, encoder: &mut wgpu::CommandEncoder, n: usize) {
        encoder.copy_buffer_to_buffer(
            &self.out_buf,
            0,
            &self.readback,
            0,
            (n * OUT_WORDS * 4) as u64,
        );
    }

    /// Maps the readback buffer, waits, and copies the candidates into `words`.
    pub fn read_candidates(&mut self, dev: &Device, n: usize) -> Result<(), ReadbackError> {
        let bytes = (n * OUT_WORDS * 4) as u64;
        *self
            .map_result
            .lock()
            .map_err(|_| ReadbackError::Poisoned)? = None;
        let slot = Arc::clone(&self.map_result);
        self.readback
            .map_async(wgpu::MapMode::Read, 0..bytes, move |r| {
                if let Ok(mut s) = slot.lock() {
                    *s = Some(r);
                }
            });
        dev.device.poll(wgpu::PollType::wait_indefinitely())?;
        let result = self
            .map_result
            .lock()
            .map_err(|_| ReadbackError::Poisoned)?
            .take();
        match result {
            Some(Ok(())) => {}
            Some(Err(e)) => return Err(ReadbackError::Map(e)),
            None => return Err(ReadbackError::NotMapped),
        }
        {
            let view = self.readback.get_mapped_range(0..bytes)?;
            self.words.clear();
            self.words.extend_from_slice(bytemuck::cast_slice(&view));
        }
        self.readback.unmap();
        Ok(())
    }

    /// The host's f64 decision over the candidates in `words` (see the parent
    /// module's doc). Writes `out[i]` for every ray.
    pub fn decide(
        &mut self,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        out: &mut Vec<NodeHits>,
    ) {
        out.clear();
        let mut fallbacks = 0;
        for (i, (o, d)) in origins.iter().zip(dirs).enumerate() {
            let w = &self.words[i * OUT_WORDS..(i + 1) * OUT_WORDS];
            let ray = WatertightRay::new(*o, *d);
            let mut hits = NodeHits::default();
            let mut brute: Option<NodeHits> = None;
            for side in 0..2 {
                let s = &w[side * (2 * K + 1)..(side + 1) * (2 * K + 1)];
                let mut best = NodeHits::default();
                for &tri in &s[..K] {
                    if tri == NO_TRI {
                        continue;
                    }
                    let [a, b, c] =
                        self.triangles[tri as usize].map(|k| &self.positions[k as usize]);
                    if let Some(h) = ray.intersect(a, b, c) {
                        keep_nearest(
                            &mut best,
                            Hit {
                                triangle: tri,
                                t: h.t,
                                u: h.u,
                                v: h.v,
                            },
                        );
                    }
                }
                let best = if side == 0 { best.behind } else { best.front };
                let theta = f32::from_bits(s[2 * K]);
                let settled =
                    theta >= KEY_EMPTY || best.is_some_and(|h| h.t.abs() < f64::from(theta));
                let answer = if settled {
                    best
                } else {
                    fallbacks += 1;
                    let all = brute.get_or_insert_with(|| {
                        cast_line(
                            &self.triangles,
                            &self.positions,
                            RayTest::Watertight,
                            *o,
                            *d,
                        )
                    });
                    if side == 0 { all.behind } else { all.front }
                };
                if side == 0 {
                    hits.behind = answer;
                } else {
                    hits.front = answer;
                }
            }
            out.push(hits);
        }
        self.fallbacks += fallbacks;
    }

    /// Answers every ray after a kernel run: the f64 decision over the
    /// candidates, or, when the run failed (logged, naming `kernel`), the CPU
    /// reference on the host.
    pub fn answer(
        &mut self,
        run: Result<(), ReadbackError>,
        kernel: &str,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        out: &mut Vec<NodeHits>,
    ) {
        match run {
            Ok(()) => self.decide(origins, dirs, out),
            Err(e) => {
                tracing::error!(error = %e, kernel, "GPU kernel failed, answering on the host");
                self.decide_on_host(origins, dirs, out);
            }
        }
    }

    /// Answers every ray with the f64 brute force (used when the device failed).
    pub fn decide_on_host(
        &mut self,
        origins: &[Point3<f64>],
        dirs: &[Vector3<f64>],
        out: &mut Vec<NodeHits>,
    ) {
        out.clear();
        out.extend(origins.iter().zip(dirs).map(|(o, d)| {
            cast_line(
                &self.triangles,
                &self.positions,
                RayTest::Watertight,
                *o,
                *d,
            )
        }));
        self.fallbacks += 2 * origins.len() as u64;
    }
}

fn readback(dev: &Device, rays: usize) -> wgpu::Buffer {
    dev.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("candidates readback"),
        size: (rays * OUT_WORDS * 4) as u64,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Workgroup counts `(x, y)` covering `n` groups within the 65535 limit per axis.
pub(crate) fn grid(n: usize) -> (u32, u32) {
    let x = n.clamp(1, 65535);
    (x as u32, n.div_ceil(65535).max(1) as u32)
}
