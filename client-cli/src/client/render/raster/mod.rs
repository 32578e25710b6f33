//! A software triangle rasteriser for shaded views of surface meshes.
//!
//! **Camera.** A pinhole camera at `eye` looking at `target` (right-handed
//! view frame: x right, y up, the camera looks along -z). A view-space point
//! (x, y, z) with depth w = -z > 0 maps to normalised coordinates
//! `x_n = f x / (a w)`, `y_n = f y / w` with `f = 1 / tan(fov_y / 2)` and
//! aspect `a = width / height`, and to pixels `sx = (x_n + 1) W / 2`,
//! `sy = (1 - y_n) H / 2`. Triangles are clipped against the near plane
//! `w = near` in view space.
//!
//! **Rasterisation.** Edge functions `E_i(p)` over pixel centres, with the
//! usual tie rule (a pixel centre on a shared edge belongs to exactly one of
//! the two triangles). Depth is tested on `1/w`, which is affine in screen
//! space; attributes (colour or scalar, normal) are interpolated perspective
//! correctly with weights `b_i / w_i`. The image is rendered at `s x s` times
//! the output resolution (supersampling, default s = 2) and box-filtered down.
//! Each mesh's triangles are set up once, sorted front to back (so hidden
//! samples fail the depth test before shading), then rasterised in parallel
//! over bands of 16 sample rows (rayon).
//!
//! **Shading.** Per pixel: `c = base (ambient + sum_k I_k max(0, n . l_k))
//! + spec max(0, n . h)^shininess`, with lights fixed in the view frame (so a
//! view from any side is lit alike). Lighting is two-sided: a face seen from
//! behind has its normal flipped and its base colour darkened by
//! `back_factor`. Normals are per face (`Shading::Flat`) or area-weighted
//! vertex normals (`Shading::Smooth`). Optional edge lines darken pixels closer
//! than a given width to a triangle edge (distance `E_i / |edge_i|`).
//!
//! Lengths are in whatever unit the positions use (m in fissure); angles in
//! degrees at the API, radians inside.
//!
//! [`camera`] places the view, [`mesh`] holds what is drawn, [`light`] how it
//! is lit; this module sets up and rasterises.

mod camera;
mod light;
mod mesh;

pub use camera::{Camera, orbit_direction};
pub use light::{Background, Light, Lighting, RenderOptions};
pub use mesh::{CREASE_DEG, Colouring, EdgeStyle, MeshRef, Shading, TriMesh};

use super::{Image, RenderError};
use fissure_shared::surface::check_surface;
use nalgebra::{Isometry3, Vector3};
use rayon::prelude::*;

/// A vertex after transformation: view-space position and attributes.
#[derive(Debug, Clone, Copy)]
struct Vert {
    p: Vector3<f64>,
    /// Colour (0..1) or, for scalar colouring, [t, 0, 0].
    attr: [f32; 3],
    n: Vector3<f64>,
}

impl Vert {
    fn lerp(&self, o: &Vert, t: f64) -> Vert {
        let tf = t as f32;
        Vert {
            p: self.p + (o.p - self.p) * t,
            attr: [0, 1, 2].map(|i| self.attr[i] + (o.attr[i] - self.attr[i]) * tf),
            n: self.n + (o.n - self.n) * t,
        }
    }
}

/// Per-mesh constants of the pixel loop.
struct MeshShade<'l> {
    scalar: bool,
    lut: &'l [[f32; 3]; 256],
    smooth: bool,
    edges: Option<(f64, [f32; 3], f32)>,
    specular: f32,
}

/// Renders meshes into images, keeping its buffers between frames.
pub struct Renderer {
    opts: RenderOptions,
    /// Supersampled width and height.
    sw: usize,
    sh: usize,
    colour: Vec<[f32; 3]>,
    /// 1 / w of the nearest sample so far (0 = empty).
    depth: Vec<f32>,
    verts: Vec<Vert>,
    /// Area-weighted face normals (|n| = 2 area), view space.
    face_normals: Vec<Vector3<f64>>,
    /// Vertex -> incident triangles (CSR).
    adj_start: Vec<u32>,
    adj: Vec<u32>,
    adj_fill: Vec<u32>,
    /// Triangles sorted by depth: (sum of vertex depths, index).
    order: Vec<(f32, u32)>,
    /// Triangles of the current mesh set up for rasterisation.
    queue: Vec<Setup>,
    /// Per-triangle corner normals (smooth shading).
    corner_normals: Vec<[Vector3<f64>; 3]>,
    lut: Box<[[f32; 3]; 256]>,
    /// Lights in view space, normalised, with intensities; and the half
    /// vector of the first light.
    lights: Vec<(Vector3<f64>, f64)>,
    half: Vector3<f64>,
}

impl Renderer {
    /// A renderer for `opts`; fails on an empty or too large image.
    pub fn new(opts: RenderOptions) -> Result<Self, RenderError> {
        let ss = opts.supersample.clamp(1, 4);
        let sw = opts.width as u64 * ss as u64;
        let sh = opts.height as u64 * ss as u64;
        if opts.width == 0
            || opts.height == 0
            || sw > super::MAX_SIDE as u64 * 2
            || sh > super::MAX_SIDE as u64 * 2
        {
            return Err(RenderError::BadSize {
                width: opts.width,
                height: opts.height,
            });
        }
        let (sw, sh) = (sw as usize, sh as usize);
        let lights: Vec<(Vector3<f64>, f64)> = opts
            .lighting
            .lights
            .iter()
            .filter(|l| l.direction.norm() > 0.0 && l.direction.iter().all(|c| c.is_finite()))
            .map(|l| (l.direction.normalize(), l.intensity))
            .collect();
        let half = lights
            .first()
            .map(|(d, _)| (d + Vector3::z()).normalize())
            .unwrap_or(Vector3::z());
        Ok(Self {
            sw,
            sh,
            colour: vec![[0.0; 3]; sw * sh],
            depth: vec![0.0; sw * sh],
            verts: Vec::new(),
            face_normals: Vec::new(),
            adj_start: Vec::new(),
            adj: Vec::new(),
            adj_fill: Vec::new(),
            order: Vec::new(),
            queue: Vec::new(),
            corner_normals: Vec::new(),
            lut: Box::new([[0.0; 3]; 256]),
            lights,
            half,
            opts,
        })
    }

    /// The options.
    pub fn options(&self) -> &RenderOptions {
        &self.opts
    }

    /// Renders `meshes` seen by `camera` into a new image.
    pub fn render(
        &mut self,
        camera: &Camera,
        meshes: &[MeshRef<'_>],
    ) -> Result<Image, RenderError> {
        let mut img = Image::new(self.opts.width, self.opts.height, [0; 3])?;
        self.render_into(camera, meshes, &mut img)?;
        Ok(img)
    }

    /// Renders into `out`, which must have the options' size. Checks every
    /// mesh first (indices, lengths, finiteness) and draws nothing when one
    /// is bad.
    pub fn render_into(
        &mut self,
        camera: &Camera,
        meshes: &[MeshRef<'_>],
        out: &mut Image,
    ) -> Result<(), RenderError> {
        if out.width() != self.opts.width || out.height() != self.opts.height {
            return Err(RenderError::BadSize {
                width: out.width(),
                height: out.height(),
            });
        }
        for (mi, m) in meshes.iter().enumerate() {
            validate(mi, m)?;
        }
        if !(camera
            .eye
            .coords
            .iter()
            .chain(camera.target.coords.iter())
            .all(|c| c.is_finite()))
            || camera.eye == camera.target
        {
            return Err(RenderError::NonFinite {
                what: "camera eye/target (or they coincide)".into(),
            });
        }
        self.clear();
        let view = camera.view();
        let f = camera.focal();
        for m in meshes.iter().filter(|m| !m.on_top) {
            self.draw_mesh(&view, f, camera.near, m);
        }
        if meshes.iter().any(|m| m.on_top) {
            self.depth.fill(0.0);
            for m in meshes.iter().filter(|m| m.on_top) {
                self.draw_mesh(&view, f, camera.near, m);
            }
        }
        self.resolve(out);
        Ok(())
    }

    fn clear(&mut self) {
        let sw = self.sw;
        let ss = sw / self.opts.width as usize;
        for y in 0..self.sh {
            // The gradient is constant over each output row so that images
            // stacked or cut by rows join seamlessly.
            let c = self
                .opts
                .background
                .at(y / ss, self.opts.height)
                .map(|v| v as f32 / 255.0);
            self.colour[y * sw..(y + 1) * sw].fill(c);
        }
        self.depth.fill(0.0);
    }

    fn resolve(&self, out: &mut Image) {
        let ss = (self.sw / out.width() as usize).max(1);
        let w = out.width() as usize;
        let inv = 1.0 / (ss * ss) as f32;
        for (i, px) in out.pixels_mut().iter_mut().enumerate() {
            let (x, y) = (i % w, i / w);
            let mut acc = [0.0f32; 3];
            for sy in 0..ss {
                let row = (y * ss + sy) * self.sw + x * ss;
                for sx in 0..ss {
                    let c = self.colour[row + sx];
                    acc[0] += c[0];
                    acc[1] += c[1];
                    acc[2] += c[2];
                }
            }
            *px = acc.map(|a| (a * inv * 255.0).round().clamp(0.0, 255.0) as u8);
        }
    }

    fn draw_mesh(&mut self, view: &Isometry3<f64>, f: f64, near: f64, m: &MeshRef<'_>) {
        // Vertices to view space with their attributes.
        let mut verts = std::mem::take(&mut self.verts);
        verts.clear();
        let (scalar, range) = match m.colouring {
            Colouring::Scalar { map, range, .. } => {
                for (k, e) in self.lut.iter_mut().enumerate() {
                    *e = map.sample(k as f64 / 255.0).map(|v| v as f32 / 255.0);
                }
                (true, range)
            }
            _ => (false, (0.0, 1.0)),
        };
        for (i, p) in m.positions.iter().enumerate() {
            let attr = match m.colouring {
                Colouring::Uniform(c) => c.map(|v| v as f32 / 255.0),
                Colouring::PerVertex(cs) => cs[i].map(|v| v as f32 / 255.0),
                Colouring::Scalar { values, .. } => {
                    let t = super::colormap::normalise(values[i], range.0, range.1);
                    [
                        if t.is_nan() {
                            f32::NAN
                        } else {
                            t.clamp(0.0, 1.0) as f32
                        },
                        0.0,
                        0.0,
                    ]
                }
            };
            verts.push(Vert {
                p: (view * p).coords,
                attr,
                n: Vector3::zeros(),
            });
        }
        let smooth = m.shading == Shading::Smooth;
        if smooth {
            self.corner_normals(&verts, m.triangles);
        }
        let ss = (self.sw / self.opts.width as usize).max(1) as f64;
        let lut = *self.lut;
        let shade = MeshShade {
            scalar,
            lut: &lut,
            smooth,
            edges: m.edges.map(|e| {
                (
                    e.width.max(0.0) * ss,
                    e.colour.map(|v| v as f32 / 255.0),
                    e.opacity.clamp(0.0, 1.0) as f32,
                )
            }),
            specular: m.specular.clamp(0.0, 1.0) as f32,
        };
        // Front to back, so that the depth test rejects hidden samples before
        // they are shaded (a closed surface is otherwise shaded about twice).
        let mut order = std::mem::take(&mut self.order);
        order.clear();
        order.extend(m.triangles.iter().enumerate().map(|(ti, t)| {
            let w: f64 = t.iter().map(|&i| -verts[i as usize].p.z).sum();
            (w as f32, ti as u32)
        }));
        order.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        for &(_, ti) in &order {
            let ti = ti as usize;
            let t = &m.triangles[ti];
            let mut tri = t.map(|i| verts[i as usize]);
            if smooth {
                for k in 0..3 {
                    tri[k].n = self.corner_normals[ti][k];
                }
            }
            let face = (tri[1].p - tri[0].p).cross(&(tri[2].p - tri[0].p));
            let Some(face_n) = face.try_normalize(1e-300) else {
                continue;
            };
            // Seen from the front when the normal points towards the eye.
            let centroid = (tri[0].p + tri[1].p + tri[2].p) / 3.0;
            let back = face_n.dot(&-centroid) < 0.0;
            let inside = tri.map(|v| -v.p.z >= near);
            if inside.iter().all(|&b| b) {
                self.raster(&tri, &face_n, back, f);
            } else if inside.iter().any(|&b| b) {
                // Clip the polygon against the near plane w = near.
                let mut poly: [Vert; 4] = [tri[0]; 4];
                let mut n = 0;
                for k in 0..3 {
                    let (a, b) = (tri[k], tri[(k + 1) % 3]);
                    let (ia, ib) = (inside[k], inside[(k + 1) % 3]);
                    if ia {
                        poly[n] = a;
                        n += 1;
                    }
                    if ia != ib {
                        let (wa, wb) = (-a.p.z, -b.p.z);
                        poly[n] = a.lerp(&b, (wa - near) / (wa - wb));
                        n += 1;
                    }
                }
                for k in 1..n.saturating_sub(1) {
                    self.raster(&[poly[0], poly[k], poly[k + 1]], &face_n, back, f);
                }
            }
        }
        self.raster_queued(&shade);
        self.verts = verts;
        self.order = order;
    }

    /// Fills `corner_normals`: for each corner of each triangle, the sum of
    /// the area-weighted normals of the triangles at that vertex whose unit
    /// normal is within `CREASE_DEG` of this triangle's, normalised.
    fn corner_normals(&mut self, verts: &[Vert], triangles: &[[u32; 3]]) {
        let nv = verts.len();
        self.face_normals.clear();
        self.face_normals.extend(triangles.iter().map(|t| {
            let [a, b, c] = t.map(|i| verts[i as usize].p);
            (b - a).cross(&(c - a))
        }));
        // CSR adjacency, vertex -> triangles.
        self.adj_start.clear();
        self.adj_start.resize(nv + 1, 0);
        for t in triangles {
            for &i in t {
                self.adj_start[i as usize + 1] += 1;
            }
        }
        for i in 0..nv {
            self.adj_start[i + 1] += self.adj_start[i];
        }
        self.adj.clear();
        self.adj.resize(3 * triangles.len(), 0);
        self.adj_fill.clear();
        self.adj_fill.extend_from_slice(&self.adj_start[..nv]);
        for (ti, t) in triangles.iter().enumerate() {
            for &i in t {
                let slot = &mut self.adj_fill[i as usize];
                self.adj[*slot as usize] = ti as u32;
                *slot += 1;
            }
        }
        let cos_crease = CREASE_DEG.to_radians().cos();
        self.corner_normals.clear();
        for (ti, t) in triangles.iter().enumerate() {
            let own = self.face_normals[ti];
            let own_len = own.norm();
            let corners = t.map(|v| {
                let (a, b) = (
                    self.adj_start[v as usize] as usize,
                    self.adj_start[v as usize + 1] as usize,
                );
                let mut sum = Vector3::zeros();
                for &f in &self.adj[a..b] {
                    let n = self.face_normals[f as usize];
                    // cos(angle) >= cos_crease, without normalising.
                    if n.dot(&own) >= cos_crease * n.norm() * own_len {
                        sum += n;
                    }
                }
                sum.try_normalize(1e-300)
                    .unwrap_or_else(|| own.try_normalize(1e-300).unwrap_or_else(Vector3::z))
            });
            self.corner_normals.push(corners);
        }
    }

    /// Projects one triangle (all vertices in front of the near plane) and
    /// queues its screen-space setup for [`Renderer::raster_queued`].
    fn raster(&mut self, tri: &[Vert; 3], face_n: &Vector3<f64>, back: bool, f: f64) {
        let (sw, sh) = (self.sw as f64, self.sh as f64);
        let aspect = self.opts.aspect();
        let mut s = [[0.0f64; 2]; 3];
        let mut inv_w = [0.0f64; 3];
        for k in 0..3 {
            let w = -tri[k].p.z;
            inv_w[k] = 1.0 / w;
            let (xn, yn) = (f * tri[k].p.x / (aspect * w), f * tri[k].p.y / w);
            s[k] = [(xn + 1.0) * 0.5 * sw, (1.0 - yn) * 0.5 * sh];
        }
        let edge = |a: [f64; 2], b: [f64; 2], p: [f64; 2]| {
            (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
        };
        let area = edge(s[0], s[1], s[2]);
        if area.is_nan() || area.abs() <= 1e-12 {
            return;
        }
        // Order so that the area is positive.
        let (o, s, inv_w) = if area > 0.0 {
            ([0, 1, 2], s, inv_w)
        } else {
            (
                [0, 2, 1],
                [s[0], s[2], s[1]],
                [inv_w[0], inv_w[2], inv_w[1]],
            )
        };
        let area = area.abs();
        let v = [tri[o[0]], tri[o[1]], tri[o[2]]];
        let x0 = s
            .iter()
            .map(|p| p[0])
            .fold(f64::MAX, f64::min)
            .floor()
            .max(0.0) as usize;
        let x1 = (s
            .iter()
            .map(|p| p[0])
            .fold(f64::MIN, f64::max)
            .ceil()
            .min(sw) as usize)
            .min(self.sw);
        let y0 = s
            .iter()
            .map(|p| p[1])
            .fold(f64::MAX, f64::min)
            .floor()
            .max(0.0) as usize;
        let y1 = (s
            .iter()
            .map(|p| p[1])
            .fold(f64::MIN, f64::max)
            .ceil()
            .min(sh) as usize)
            .min(self.sh);
        if x0 >= x1 || y0 >= y1 {
            return;
        }
        // Edge i is opposite vertex i: from s[i+1] to s[i+2].
        let e = [(1, 2), (2, 0), (0, 1)].map(|(a, b)| (s[a], s[b]));
        // w_i = A_i x + B_i y + C_i.
        let coef = e.map(|(a, b)| {
            let ca = -(b[1] - a[1]);
            let cb = b[0] - a[0];
            (ca, cb, -(ca * a[0] + cb * a[1]))
        });
        let owns_zero = coef.map(|(ca, cb, _)| ca > 0.0 || (ca == 0.0 && cb > 0.0));
        let inv_len = e.map(|(a, b)| 1.0 / ((b[0] - a[0]).hypot(b[1] - a[1])).max(1e-300));
        // Face normal as lit: flipped towards the viewer when seen from behind.
        let fn_lit = if back { -face_n } else { *face_n };
        self.queue.push(Setup {
            v,
            inv_w,
            area,
            coef,
            owns_zero,
            inv_len,
            bbox: [x0, x1, y0, y1],
            fn_lit,
            back,
        });
    }

    /// Rasterises the queued triangles of one mesh, in parallel over bands of
    /// rows (each band keeps the queue's front-to-back order).
    fn raster_queued(&mut self, shade: &MeshShade<'_>) {
        const BAND: usize = 16;
        let queue = std::mem::take(&mut self.queue);
        let ctx = Ctx {
            sw: self.sw,
            lights: &self.lights,
            half: self.half,
            ambient: self.opts.lighting.ambient as f32,
            back_factor: self.opts.lighting.back_factor as f32,
            shininess: self.opts.lighting.shininess,
        };
        let sw = self.sw;
        self.colour
            .par_chunks_mut(BAND * sw)
            .zip(self.depth.par_chunks_mut(BAND * sw))
            .enumerate()
            .for_each(|(bi, (colour, depth))| {
                let (ya, yb) = (bi * BAND, bi * BAND + depth.len() / sw);
                for t in &queue {
                    if t.bbox[2] < yb && t.bbox[3] > ya {
                        raster_rows(&ctx, t, shade, colour, depth, ya, yb);
                    }
                }
            });
        self.queue = queue;
        self.queue.clear();
    }
}

/// A triangle set up in screen space (supersampled pixels).
#[derive(Debug, Clone, Copy)]
struct Setup {
    v: [Vert; 3],
    inv_w: [f64; 3],
    area: f64,
    /// Edge functions w_i = A_i x + B_i y + C_i, edge i opposite vertex i.
    coef: [(f64, f64, f64); 3],
    owns_zero: [bool; 3],
    inv_len: [f64; 3],
    /// x0, x1, y0, y1 (half-open).
    bbox: [usize; 4],
    fn_lit: Vector3<f64>,
    back: bool,
}

/// Constants of the pixel loop shared by all triangles.
struct Ctx<'a> {
    sw: usize,
    lights: &'a [(Vector3<f64>, f64)],
    half: Vector3<f64>,
    ambient: f32,
    back_factor: f32,
    shininess: i32,
}

/// Rasterises rows [ya, yb) of triangle `t` into a band whose first row is
/// `ya`.
fn raster_rows(
    ctx: &Ctx<'_>,
    t: &Setup,
    shade: &MeshShade<'_>,
    colour: &mut [[f32; 3]],
    depth: &mut [f32],
    ya: usize,
    yb: usize,
) {
    let Setup {
        v,
        inv_w,
        area,
        coef,
        owns_zero,
        inv_len,
        bbox,
        fn_lit,
        back,
    } = *t;
    let [x0, x1, y0, y1] = bbox;
    let base_k = if back { ctx.back_factor } else { 1.0 };
    let (ambient, shininess) = (ctx.ambient, ctx.shininess);
    let inv_area = 1.0 / area;
    for y in y0.max(ya)..y1.min(yb) {
        let py = y as f64 + 0.5;
        let row = (y - ya) * ctx.sw;
        for x in x0..x1 {
            let px = x as f64 + 0.5;
            let w = coef.map(|(a, b, c)| a * px + b * py + c);
            if !(0..3).all(|i| w[i] > 0.0 || (w[i] == 0.0 && owns_zero[i])) {
                continue;
            }
            let b = [w[0] * inv_area, w[1] * inv_area, w[2] * inv_area];
            let iw = b[0] * inv_w[0] + b[1] * inv_w[1] + b[2] * inv_w[2];
            let idx = row + x;
            let d = iw as f32;
            if d <= depth[idx] {
                continue;
            }
            depth[idx] = d;
            // Perspective-correct weights.
            let r = 1.0 / iw;
            let pc = [
                b[0] * inv_w[0] * r,
                b[1] * inv_w[1] * r,
                b[2] * inv_w[2] * r,
            ];
            let pcf = pc.map(|v| v as f32);
            let mut base = if shade.scalar {
                let t = pcf[0] * v[0].attr[0] + pcf[1] * v[1].attr[0] + pcf[2] * v[2].attr[0];
                if t.is_nan() {
                    super::colormap::NAN_COLOUR.map(|c| c as f32 / 255.0)
                } else {
                    shade.lut[(t.clamp(0.0, 1.0) * 255.0).round() as usize]
                }
            } else {
                [0, 1, 2]
                    .map(|c| pcf[0] * v[0].attr[c] + pcf[1] * v[1].attr[c] + pcf[2] * v[2].attr[c])
            };
            let n = if shade.smooth {
                let n = v[0].n * pc[0] + v[1].n * pc[1] + v[2].n * pc[2];
                match n.try_normalize(1e-300) {
                    // Keep the interpolated normal on the viewer's side of the face.
                    Some(n) => {
                        let n = if back { -n } else { n };
                        if n.dot(&fn_lit) < 0.0 { fn_lit } else { n }
                    }
                    None => fn_lit,
                }
            } else {
                fn_lit
            };
            let mut diffuse = ambient;
            for (l, k) in ctx.lights {
                diffuse += (*k * n.dot(l).max(0.0)) as f32;
            }
            let nh = n.dot(&ctx.half);
            let spec = if shade.specular > 0.0 && nh > 0.5 {
                shade.specular * (nh as f32).powi(shininess)
            } else {
                0.0
            };
            for c in &mut base {
                *c = (*c * base_k * diffuse + spec).min(1.0);
            }
            if let Some((width, ecol, opacity)) = shade.edges {
                let dist = (0..3).map(|i| w[i] * inv_len[i]).fold(f64::MAX, f64::min);
                if dist < width + 0.5 {
                    let a = opacity * ((width + 0.5 - dist).min(1.0) as f32);
                    for c in 0..3 {
                        base[c] += (ecol[c] - base[c]) * a;
                    }
                }
            }
            colour[idx] = base;
        }
    }
}

fn validate(mi: usize, m: &MeshRef<'_>) -> Result<(), RenderError> {
    let nv = m.positions.len();
    check_surface(m.triangles, m.positions)
        .map_err(|source| RenderError::Surface { mesh: mi, source })?;
    match m.colouring {
        Colouring::PerVertex(c) if c.len() != nv => Err(RenderError::LengthMismatch {
            mesh: mi,
            what: "per-vertex colours",
            got: c.len(),
            vertices: nv,
        }),
        Colouring::Scalar { values, .. } if values.len() != nv => {
            Err(RenderError::LengthMismatch {
                mesh: mi,
                what: "scalar values",
                got: values.len(),
                vertices: nv,
            })
        }
        Colouring::Scalar { range, .. } if !(range.0.is_finite() && range.1.is_finite()) => {
            Err(RenderError::NonFinite {
                what: format!("mesh {mi}: colour range"),
            })
        }
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests;
