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

use super::colormap::Colormap;
use super::{Image, RenderError, Rgb};
use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};
use rayon::prelude::*;

/// A pinhole camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub eye: Point3<f64>,
    /// Point looked at.
    pub target: Point3<f64>,
    /// Approximate up direction (need not be orthogonal to the view).
    pub up: Vector3<f64>,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
    /// Near clipping distance, same unit as positions (> 0).
    pub near: f64,
}

impl Camera {
    /// A camera at `eye` looking at `target`, with the near plane at a
    /// thousandth of their distance.
    pub fn look_at(
        eye: Point3<f64>,
        target: Point3<f64>,
        up: Vector3<f64>,
        fov_y_deg: f64,
    ) -> Self {
        let near = ((eye - target).norm() * 1e-3).max(1e-9);
        Self {
            eye,
            target,
            up,
            fov_y_deg,
            near,
        }
    }

    /// The world-to-view isometry (camera at the origin looking along -z).
    pub fn view(&self) -> Isometry3<f64> {
        let dir = self.target - self.eye;
        // Fall back to another up vector when `up` is parallel to the view.
        let up = if dir.cross(&self.up).norm_squared()
            > 1e-20 * dir.norm_squared() * self.up.norm_squared()
        {
            self.up
        } else if dir.cross(&Vector3::y()).norm_squared() > 1e-12 * dir.norm_squared() {
            Vector3::y()
        } else {
            Vector3::x()
        };
        Isometry3::look_at_rh(&self.eye, &self.target, &up)
    }

    /// `f = 1 / tan(fov_y / 2)`.
    fn focal(&self) -> f64 {
        1.0 / (0.5 * self.fov_y_deg.clamp(1e-3, 179.0).to_radians()).tan()
    }

    /// Pixel coordinates (x right, y down) of world point `p` in a
    /// `width` x `height` image, or `None` when `p` is not in front of the
    /// near plane.
    pub fn project(&self, p: &Point3<f64>, width: u32, height: u32) -> Option<[f64; 2]> {
        let v = self.view() * p;
        let w = -v.z;
        if w.is_nan() || w < self.near {
            return None;
        }
        let f = self.focal();
        let aspect = width as f64 / height as f64;
        let (xn, yn) = (f * v.x / (aspect * w), f * v.y / w);
        Some([
            (xn + 1.0) * 0.5 * width as f64,
            (1.0 - yn) * 0.5 * height as f64,
        ])
    }

    /// A camera that looks at the box [`lo`, `hi`] from direction `from`
    /// (pointing from the box towards the eye), with `up` roughly up, placed
    /// so that the box's eight corners fill the central `fill` fraction
    /// (0 < fill <= 1) of an image of aspect `aspect` = width / height, and
    /// centred on them.
    pub fn frame_box(
        lo: Point3<f64>,
        hi: Point3<f64>,
        from: Vector3<f64>,
        up: Vector3<f64>,
        fov_y_deg: f64,
        aspect: f64,
        fill: f64,
    ) -> Self {
        let corners: Vec<Point3<f64>> = (0..8)
            .map(|i| {
                Point3::new(
                    if i & 1 == 0 { lo.x } else { hi.x },
                    if i & 2 == 0 { lo.y } else { hi.y },
                    if i & 4 == 0 { lo.z } else { hi.z },
                )
            })
            .collect();
        Self::frame_points(&corners, from, up, fov_y_deg, aspect, fill)
    }

    /// Like [`Camera::frame_box`], fitting the given points themselves
    /// (tighter than their bounding box). Non-finite points are ignored; no
    /// point gives a camera on the unit box.
    pub fn frame_points(
        points: &[Point3<f64>],
        from: Vector3<f64>,
        up: Vector3<f64>,
        fov_y_deg: f64,
        aspect: f64,
        fill: f64,
    ) -> Self {
        let mut lo = Point3::from(Vector3::repeat(f64::INFINITY));
        let mut hi = Point3::from(Vector3::repeat(f64::NEG_INFINITY));
        let finite = |p: &&Point3<f64>| p.coords.iter().all(|c| c.is_finite());
        for p in points.iter().filter(finite) {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        if lo.x > hi.x {
            (lo, hi) = (Point3::origin(), Point3::new(1.0, 1.0, 1.0));
        }
        let unit_box = [lo, hi];
        let corners: Vec<&Point3<f64>> = if points.iter().any(|p| finite(&p)) {
            points.iter().filter(finite).collect()
        } else {
            unit_box.iter().collect()
        };
        let centre = nalgebra::center(&lo, &hi);
        let size = (hi - lo).norm().max(1e-12);
        let from = if from.norm() > 0.0 {
            from.normalize()
        } else {
            Vector3::z()
        };
        let mut cam = Camera::look_at(centre + from * size, centre, up, fov_y_deg);
        let f = cam.focal();
        let fill = fill.clamp(0.05, 1.0);
        let aspect = if aspect.is_finite() && aspect > 0.0 {
            aspect
        } else {
            1.0
        };
        // Two passes: fit the distance, then re-centre the projected extents.
        for _ in 0..3 {
            let view = cam.view();
            // The distance d from the target such that every corner (a, b, c)
            // in the camera basis (c towards the eye) satisfies
            // f |a| / (aspect (d - c)) <= fill and f |b| / (d - c) <= fill.
            let t = view * cam.target;
            let mut d: f64 = 0.0;
            for &p in &corners {
                let q = view * p - t;
                let need = q.z + (f * q.x.abs() / aspect).max(f * q.y.abs()) / fill;
                d = d.max(need);
            }
            d = d.max(1e-9);
            let back = (cam.eye - cam.target).normalize();
            cam.eye = cam.target + back * d;
            cam.near = (d * 1e-3).max(1e-12);
            // Re-centre: shift the target (and eye) by the middle of the
            // projected extents, measured at the target's depth.
            let view = cam.view();
            let (mut xlo, mut xhi, mut ylo, mut yhi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
            for &p in &corners {
                let v = view * p;
                let w = (-v.z).max(cam.near);
                let (xn, yn) = (f * v.x / (aspect * w), f * v.y / w);
                xlo = xlo.min(xn);
                xhi = xhi.max(xn);
                ylo = ylo.min(yn);
                yhi = yhi.max(yn);
            }
            let (mx, my) = (0.5 * (xlo + xhi), 0.5 * (ylo + yhi));
            let inv = view.inverse();
            let shift = inv.rotation * Vector3::new(mx * aspect * d / f, my * d / f, 0.0);
            cam.target += shift;
            cam.eye += shift;
        }
        cam
    }

    /// [`Camera::frame_box`] from spherical angles about a z-up world:
    /// azimuth from +x towards +y, elevation above the xy plane, degrees.
    pub fn orbit_box(
        lo: Point3<f64>,
        hi: Point3<f64>,
        azimuth_deg: f64,
        elevation_deg: f64,
        fov_y_deg: f64,
        aspect: f64,
    ) -> Self {
        Self::frame_box(
            lo,
            hi,
            orbit_direction(azimuth_deg, elevation_deg),
            Vector3::z(),
            fov_y_deg,
            aspect,
            0.9,
        )
    }

    /// [`Camera::frame_points`] from spherical angles about a z-up world.
    pub fn orbit_points(
        points: &[Point3<f64>],
        azimuth_deg: f64,
        elevation_deg: f64,
        fov_y_deg: f64,
        aspect: f64,
    ) -> Self {
        Self::frame_points(
            points,
            orbit_direction(azimuth_deg, elevation_deg),
            Vector3::z(),
            fov_y_deg,
            aspect,
            0.9,
        )
    }
}

/// Unit vector at azimuth (from +x towards +y) and elevation (above the xy
/// plane), degrees.
pub fn orbit_direction(azimuth_deg: f64, elevation_deg: f64) -> Vector3<f64> {
    let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin())
}

/// How a mesh is coloured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Colouring<'a> {
    /// One colour.
    Uniform(Rgb),
    /// A colour per vertex, interpolated across triangles.
    PerVertex(&'a [Rgb]),
    /// A scalar per vertex, interpolated across triangles and mapped per pixel
    /// through `map` over `range` (value at t = 0, value at t = 1).
    Scalar {
        /// One value per vertex.
        values: &'a [f64],
        /// The colour map.
        map: Colormap,
        /// Values shown at the two ends of the map.
        range: (f64, f64),
    },
}

/// Normals used for lighting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Shading {
    /// One normal per triangle: facets visible.
    Flat,
    /// Area-weighted vertex normals interpolated per pixel, averaged only
    /// over faces within [`CREASE_DEG`] of each other: sharp edges (a block's
    /// corners, a groove's rim) stay sharp.
    #[default]
    Smooth,
}

/// Faces meeting at a larger angle than this (degrees) are not smoothed
/// across their shared vertex.
pub const CREASE_DEG: f64 = 40.0;

/// Lines drawn along triangle edges.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeStyle {
    /// Line colour.
    pub colour: Rgb,
    /// Width in output pixels (each triangle draws its side of the edge, so a
    /// shared edge shows about twice this).
    pub width: f64,
    /// Opacity in [0, 1].
    pub opacity: f64,
}

impl Default for EdgeStyle {
    fn default() -> Self {
        Self {
            colour: [20, 20, 20],
            width: 0.5,
            opacity: 0.35,
        }
    }
}

/// A surface mesh to draw, borrowed from the caller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshRef<'a> {
    /// Vertex positions.
    pub positions: &'a [Point3<f64>],
    /// Triangles as vertex indices (either orientation; lighting is two-sided).
    pub triangles: &'a [[u32; 3]],
    /// Colouring.
    pub colouring: Colouring<'a>,
    /// Normals.
    pub shading: Shading,
    /// Edge lines, if any.
    pub edges: Option<EdgeStyle>,
    /// Specular strength in [0, 1] (0 for matte tissue, about 0.5 for metal).
    pub specular: f64,
    /// Drawn after all other meshes, over them (its own depth test only):
    /// for force arrows that would otherwise hide inside the tissue.
    pub on_top: bool,
}

impl<'a> MeshRef<'a> {
    /// A smooth-shaded, matte mesh without edge lines.
    pub fn new(
        positions: &'a [Point3<f64>],
        triangles: &'a [[u32; 3]],
        colouring: Colouring<'a>,
    ) -> Self {
        Self {
            positions,
            triangles,
            colouring,
            shading: Shading::Smooth,
            edges: None,
            specular: 0.15,
            on_top: false,
        }
    }

    /// The same mesh drawn over all others.
    pub fn on_top(mut self) -> Self {
        self.on_top = true;
        self
    }

    /// The same mesh with per-face normals.
    pub fn flat(mut self) -> Self {
        self.shading = Shading::Flat;
        self
    }

    /// The same mesh with edge lines.
    pub fn with_edges(mut self, edges: EdgeStyle) -> Self {
        self.edges = Some(edges);
        self
    }

    /// The same mesh with another specular strength.
    pub fn with_specular(mut self, specular: f64) -> Self {
        self.specular = specular;
        self
    }
}

/// An owned single-colour mesh: instruments, arrows, markers.
#[derive(Debug, Clone, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub positions: Vec<Point3<f64>>,
    /// Triangles, outward oriented.
    pub triangles: Vec<[u32; 3]>,
    /// Colour.
    pub colour: Rgb,
    /// Normals.
    pub shading: Shading,
    /// Specular strength.
    pub specular: f64,
}

impl TriMesh {
    /// A box with half-extents `half` along the local axes, placed by `pose`
    /// (local to world): 8 vertices, 12 outward triangles, flat shaded. A
    /// spatula is such a plate: thickness along one axis, width and length
    /// along the others.
    pub fn cuboid(pose: &Isometry3<f64>, half: Vector3<f64>, colour: Rgb) -> Self {
        let positions = (0..8)
            .map(|i| {
                let local = Point3::new(
                    if i & 1 == 0 { -half.x } else { half.x },
                    if i & 2 == 0 { -half.y } else { half.y },
                    if i & 4 == 0 { -half.z } else { half.z },
                );
                pose * local
            })
            .collect();
        // Corner i has bit 0 = +x, bit 1 = +y, bit 2 = +z.
        let triangles = vec![
            [0, 2, 3],
            [0, 3, 1], // -z
            [4, 5, 7],
            [4, 7, 6], // +z
            [0, 1, 5],
            [0, 5, 4], // -y
            [2, 6, 7],
            [2, 7, 3], // +y
            [0, 4, 6],
            [0, 6, 2], // -x
            [1, 3, 7],
            [1, 7, 5], // +x
        ];
        Self {
            positions,
            triangles,
            colour,
            shading: Shading::Flat,
            specular: 0.5,
        }
    }

    /// An arrow from `origin` along `vector` (its tip at `origin + vector`):
    /// a cylinder of radius `radius` and a cone head 3 radii wide and up to 8
    /// radii long (at most 40 % of the arrow). An empty mesh when the vector
    /// is zero or not finite. To draw a force F (N) with a scale s (m/N), pass
    /// `vector = s F`.
    pub fn arrow(origin: Point3<f64>, vector: Vector3<f64>, radius: f64, colour: Rgb) -> Self {
        const SEG: u32 = 20;
        let mut m = Self {
            positions: Vec::new(),
            triangles: Vec::new(),
            colour,
            shading: Shading::Smooth,
            specular: 0.35,
        };
        let len = vector.norm();
        let usable = len.is_finite()
            && len > 0.0
            && radius.is_finite()
            && radius > 0.0
            && origin.coords.iter().all(|c| c.is_finite());
        if !usable {
            return m;
        }
        let axis = vector / len;
        let rot = UnitQuaternion::rotation_between(&Vector3::z(), &axis).unwrap_or_else(|| {
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
        });
        let pose = Isometry3::from_parts(origin.coords.into(), rot);
        let head_len = (8.0 * radius).min(0.4 * len);
        let shaft_len = len - head_len;
        let head_r = 3.0 * radius;
        let ring = |r: f64, z: f64| -> Vec<Point3<f64>> {
            (0..SEG)
                .map(|k| {
                    let a = k as f64 / SEG as f64 * std::f64::consts::TAU;
                    pose * Point3::new(r * a.cos(), r * a.sin(), z)
                })
                .collect()
        };
        let push_ring = |m: &mut Self, pts: Vec<Point3<f64>>| -> u32 {
            let base = m.positions.len() as u32;
            m.positions.extend(pts);
            base
        };
        // Shaft side (own rings so that smooth normals stay radial).
        let s0 = push_ring(&mut m, ring(radius, 0.0));
        let s1 = push_ring(&mut m, ring(radius, shaft_len));
        for k in 0..SEG {
            let k1 = (k + 1) % SEG;
            m.triangles.push([s0 + k, s0 + k1, s1 + k1]);
            m.triangles.push([s0 + k, s1 + k1, s1 + k]);
        }
        // Bottom cap.
        let c0 = push_ring(&mut m, ring(radius, 0.0));
        let centre0 = m.positions.len() as u32;
        m.positions.push(pose * Point3::origin());
        for k in 0..SEG {
            m.triangles.push([centre0, c0 + (k + 1) % SEG, c0 + k]);
        }
        // Head base disc.
        let h0 = push_ring(&mut m, ring(head_r, shaft_len));
        let centre1 = m.positions.len() as u32;
        m.positions.push(pose * Point3::new(0.0, 0.0, shaft_len));
        for k in 0..SEG {
            m.triangles.push([centre1, h0 + (k + 1) % SEG, h0 + k]);
        }
        // Cone: one apex per segment so each facet's normal stays its own.
        let h1 = push_ring(&mut m, ring(head_r, shaft_len));
        for k in 0..SEG {
            let apex = m.positions.len() as u32;
            m.positions.push(pose * Point3::new(0.0, 0.0, len));
            m.triangles.push([h1 + k, h1 + (k + 1) % SEG, apex]);
        }
        m
    }

    /// Appends `other`'s triangles (keeping this mesh's colour).
    pub fn append(&mut self, other: &TriMesh) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.triangles
            .extend(other.triangles.iter().map(|t| t.map(|i| i + base)));
    }

    /// A view of this mesh for [`Renderer::render`].
    pub fn as_mesh(&self) -> MeshRef<'_> {
        MeshRef {
            positions: &self.positions,
            triangles: &self.triangles,
            colouring: Colouring::Uniform(self.colour),
            shading: self.shading,
            edges: None,
            specular: self.specular,
            on_top: false,
        }
    }
}

/// A directional light fixed in the view frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    /// Direction towards the light in view space (x right, y up, z towards
    /// the viewer); need not be normalised.
    pub direction: Vector3<f64>,
    /// Diffuse intensity.
    pub intensity: f64,
}

/// Lights and material constants.
#[derive(Debug, Clone, PartialEq)]
pub struct Lighting {
    /// Ambient term.
    pub ambient: f64,
    /// Directional lights; the first one also makes the specular highlight.
    pub lights: Vec<Light>,
    /// Specular exponent (an integer, so that the highlight costs a few
    /// multiplications a pixel).
    pub shininess: i32,
    /// Factor on the base colour of faces seen from behind, in [0, 1].
    pub back_factor: f64,
}

impl Default for Lighting {
    /// A key light from the upper left, a weaker fill from the right and a
    /// soft ambient term.
    fn default() -> Self {
        Self {
            ambient: 0.46,
            lights: vec![
                Light {
                    direction: Vector3::new(-0.45, 0.65, 0.75),
                    intensity: 0.48,
                },
                Light {
                    direction: Vector3::new(0.7, -0.1, 0.5),
                    intensity: 0.18,
                },
            ],
            shininess: 32,
            back_factor: 0.7,
        }
    }
}

/// What lies behind the meshes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Background {
    /// One colour.
    Solid(Rgb),
    /// A vertical gradient from `top` to `bottom`.
    Gradient {
        /// Colour of the top row.
        top: Rgb,
        /// Colour of the bottom row.
        bottom: Rgb,
    },
}

impl Background {
    /// Colour of output row `y` of an image `height` rows high.
    pub fn at(&self, y: usize, height: u32) -> Rgb {
        match *self {
            Background::Solid(c) => c,
            Background::Gradient { top, bottom } => {
                super::draw::mix(top, bottom, y as f64 / (height.max(2) - 1) as f64)
            }
        }
    }
}

impl Default for Background {
    fn default() -> Self {
        Background::Gradient {
            top: [250, 251, 253],
            bottom: [214, 220, 228],
        }
    }
}

/// Options of a [`Renderer`].
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    /// Output width, px.
    pub width: u32,
    /// Output height, px.
    pub height: u32,
    /// Supersampling factor per axis (1 = none, 2 = 2 x 2 samples, up to 4).
    pub supersample: u32,
    /// Background.
    pub background: Background,
    /// Lighting.
    pub lighting: Lighting,
}

impl RenderOptions {
    /// `width` x `height` with 2 x 2 supersampling, the default background
    /// and lighting.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            supersample: 2,
            background: Background::default(),
            lighting: Lighting::default(),
        }
    }

    /// Aspect ratio width / height.
    pub fn aspect(&self) -> f64 {
        self.width as f64 / self.height as f64
    }
}

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
    if let Some(i) = m
        .positions
        .iter()
        .position(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(RenderError::NonFinite {
            what: format!("mesh {mi}: vertex {i}"),
        });
    }
    for (ti, t) in m.triangles.iter().enumerate() {
        if let Some(&vertex) = t.iter().find(|&&i| i as usize >= nv) {
            return Err(RenderError::IndexOutOfRange {
                mesh: mi,
                triangle: ti,
                vertex,
                vertices: nv,
            });
        }
    }
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
mod tests {
    use super::*;

    const BG: Rgb = [10, 20, 30];

    fn opts(w: u32, h: u32, ss: u32) -> RenderOptions {
        RenderOptions {
            supersample: ss,
            background: Background::Solid(BG),
            ..RenderOptions::new(w, h)
        }
    }

    /// Camera on +z looking at the origin.
    fn front_camera() -> Camera {
        Camera::look_at(
            Point3::new(0.0, 0.0, 10.0),
            Point3::origin(),
            Vector3::y(),
            30.0,
        )
    }

    fn quad(z: f64, half: f64) -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
        (
            vec![
                Point3::new(-half, -half, z),
                Point3::new(half, -half, z),
                Point3::new(half, half, z),
                Point3::new(-half, half, z),
            ],
            vec![[0, 1, 2], [0, 2, 3]],
        )
    }

    fn is_bg(p: Rgb) -> bool {
        p == BG
    }

    #[test]
    fn a_triangle_covers_its_projection_and_nothing_else() {
        let (w, h) = (200, 150);
        let cam = front_camera();
        let pos = [
            Point3::new(-1.0, -1.0, 0.0),
            Point3::new(1.5, -0.8, 0.0),
            Point3::new(0.2, 1.2, 0.0),
        ];
        let tri = [[0u32, 1, 2]];
        let mut r = Renderer::new(opts(w, h, 1)).unwrap();
        let img = r
            .render(
                &cam,
                &[MeshRef::new(
                    &pos,
                    &tri,
                    Colouring::Uniform([200, 200, 200]),
                )],
            )
            .unwrap();
        let s = pos.map(|p| cam.project(&p, w, h).unwrap());
        let edge = |a: [f64; 2], b: [f64; 2], p: [f64; 2]| {
            (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
        };
        let area = edge(s[0], s[1], s[2]);
        let mut mismatches = 0;
        let mut covered = 0;
        for y in 0..h {
            for x in 0..w {
                let p = [x as f64 + 0.5, y as f64 + 0.5];
                let e = [
                    edge(s[1], s[2], p),
                    edge(s[2], s[0], p),
                    edge(s[0], s[1], p),
                ]
                .map(|v| v / area.signum());
                let inside = e.iter().all(|&v| v > 1e-6);
                let outside = e.iter().any(|&v| v < -1e-6);
                let bg = is_bg(img.get(x, y).unwrap());
                if !bg {
                    covered += 1;
                }
                if (inside && bg) || (outside && !bg) {
                    mismatches += 1;
                }
            }
        }
        assert_eq!(mismatches, 0);
        let expected = area.abs() / 2.0;
        assert!(
            (covered as f64 - expected).abs() < 0.02 * expected + 10.0,
            "{covered} vs {expected}"
        );
        // A lit front face is brighter than the ambient term alone.
        let c = [
            (s[0][0] + s[1][0] + s[2][0]) / 3.0,
            (s[0][1] + s[1][1] + s[2][1]) / 3.0,
        ];
        let px = img.get(c[0] as u32, c[1] as u32).unwrap();
        assert!(px[0] > (200.0 * 0.5) as u8, "centre {px:?}");
    }

    #[test]
    fn a_nearer_triangle_hides_a_farther_one_in_either_order() {
        let (near_p, near_t) = quad(1.0, 1.0);
        let (far_p, far_t) = quad(-1.0, 2.0);
        let red = MeshRef::new(&near_p, &near_t, Colouring::Uniform([255, 0, 0])).flat();
        let green = MeshRef::new(&far_p, &far_t, Colouring::Uniform([0, 255, 0])).flat();
        let mut r = Renderer::new(opts(120, 120, 2)).unwrap();
        for order in [[red, green], [green, red]] {
            let img = r.render(&front_camera(), &order).unwrap();
            let c = img.get(60, 60).unwrap();
            assert!(c[0] > 100 && c[0] > c[1] + 100, "centre {c:?}");
            // Outside the near quad but inside the far one: green.
            let s = front_camera()
                .project(&Point3::new(1.6, 0.0, -1.0), 120, 120)
                .unwrap();
            let g = img.get(s[0] as u32, s[1] as u32).unwrap();
            assert!(g[1] > 100 && g[1] > g[0] + 100, "far {g:?}");
        }
    }

    #[test]
    fn shared_edges_leave_no_gaps_and_back_faces_are_darker() {
        let (p, t) = quad(0.0, 1.0);
        let mut r = Renderer::new(opts(64, 64, 1)).unwrap();
        let cam = front_camera();
        let img = r
            .render(
                &cam,
                &[MeshRef::new(&p, &t, Colouring::Uniform([180, 180, 180])).flat()],
            )
            .unwrap();
        let lo = cam.project(&p[3], 64, 64).unwrap();
        let hi = cam.project(&p[1], 64, 64).unwrap();
        for y in (lo[1].ceil() as u32 + 1)..(hi[1].floor() as u32 - 1) {
            for x in (lo[0].ceil() as u32 + 1)..(hi[0].floor() as u32 - 1) {
                assert!(!is_bg(img.get(x, y).unwrap()), "gap at {x}, {y}");
            }
        }
        let front = img.get(32, 32).unwrap();
        // The same quad seen from behind (camera on -z).
        let back_cam = Camera::look_at(
            Point3::new(0.0, 0.0, -10.0),
            Point3::origin(),
            Vector3::y(),
            30.0,
        );
        let img = r
            .render(
                &back_cam,
                &[MeshRef::new(&p, &t, Colouring::Uniform([180, 180, 180])).flat()],
            )
            .unwrap();
        let back = img.get(32, 32).unwrap();
        assert!(!is_bg(back));
        assert!(back[0] < front[0], "back {back:?} front {front:?}");
    }

    #[test]
    fn triangles_through_the_camera_plane_are_clipped() {
        let pos = [
            Point3::new(-1.0, -0.5, 5.0),
            Point3::new(1.0, -0.5, 5.0),
            Point3::new(0.0, -0.5, 20.0),
        ];
        let tri = [[0u32, 1, 2]];
        let mut r = Renderer::new(opts(80, 60, 2)).unwrap();
        let img = r
            .render(
                &front_camera(),
                &[MeshRef::new(&pos, &tri, Colouring::Uniform([255; 3]))],
            )
            .unwrap();
        let drawn = img.pixels().iter().filter(|p| !is_bg(**p)).count();
        assert!(drawn > 0 && drawn < 80 * 60);
    }

    #[test]
    fn scalar_colouring_follows_the_map() {
        let (p, t) = quad(0.0, 1.0);
        let values = [0.0, 1.0, 1.0, 0.0];
        let mesh = MeshRef::new(
            &p,
            &t,
            Colouring::Scalar {
                values: &values,
                map: Colormap::Viridis,
                range: (0.0, 1.0),
            },
        );
        let mut r = Renderer::new(opts(100, 100, 2)).unwrap();
        let img = r.render(&front_camera(), &[mesh.flat()]).unwrap();
        let left = img.get(35, 50).unwrap();
        let right = img.get(65, 50).unwrap();
        // Viridis: purple-blue at 0 (blue > green), yellow-green at 1.
        assert!(left[2] > left[1], "left {left:?}");
        assert!(right[1] > right[2], "right {right:?}");
    }

    #[test]
    fn bad_meshes_are_reported() {
        let (p, _) = quad(0.0, 1.0);
        let mut r = Renderer::new(opts(10, 10, 1)).unwrap();
        let bad_tri = [[0u32, 1, 9]];
        let e = r.render(
            &front_camera(),
            &[MeshRef::new(&p, &bad_tri, Colouring::Uniform([0; 3]))],
        );
        assert!(matches!(
            e,
            Err(RenderError::IndexOutOfRange {
                triangle: 0,
                vertex: 9,
                ..
            })
        ));
        let ok_tri = [[0u32, 1, 2]];
        let cols = [[0u8; 3]; 2];
        let e = r.render(
            &front_camera(),
            &[MeshRef::new(&p, &ok_tri, Colouring::PerVertex(&cols))],
        );
        assert!(matches!(
            e,
            Err(RenderError::LengthMismatch {
                got: 2,
                vertices: 4,
                ..
            })
        ));
        let mut nan = p.clone();
        nan[2].x = f64::NAN;
        let e = r.render(
            &front_camera(),
            &[MeshRef::new(&nan, &ok_tri, Colouring::Uniform([0; 3]))],
        );
        assert!(matches!(e, Err(RenderError::NonFinite { .. })));
        // Degenerate triangles draw nothing and do not fail.
        let flat = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 1.0, 0.0),
            Point3::new(2.0, 2.0, 0.0),
        ];
        let img = r
            .render(
                &front_camera(),
                &[MeshRef::new(&flat, &ok_tri, Colouring::Uniform([255; 3]))],
            )
            .unwrap();
        assert!(img.pixels().iter().all(|p| is_bg(*p)));
        assert!(Renderer::new(opts(0, 10, 1)).is_err());
    }

    #[test]
    fn frame_box_fits_every_corner_and_fills_the_image() {
        let (lo, hi) = (Point3::new(0.0, 0.0, 0.0), Point3::new(0.06, 0.03, 0.03));
        for (az, el) in [(-60.0, 30.0), (0.0, 0.0), (90.0, 89.0), (200.0, -20.0)] {
            let cam = Camera::orbit_box(lo, hi, az, el, 35.0, 4.0 / 3.0);
            let (mut xl, mut xh, mut yl, mut yh) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
            for i in 0..8 {
                let p = Point3::new(
                    if i & 1 == 0 { lo.x } else { hi.x },
                    if i & 2 == 0 { lo.y } else { hi.y },
                    if i & 4 == 0 { lo.z } else { hi.z },
                );
                let s = cam.project(&p, 800, 600).unwrap();
                xl = xl.min(s[0]);
                xh = xh.max(s[0]);
                yl = yl.min(s[1]);
                yh = yh.max(s[1]);
            }
            assert!(
                xl >= -0.5 && yl >= -0.5 && xh <= 800.5 && yh <= 600.5,
                "({az}, {el}): {xl} {xh} {yl} {yh}"
            );
            // Tight in at least one direction (90 % fill), roughly centred.
            let fill = ((xh - xl) / 800.0).max((yh - yl) / 600.0);
            assert!(fill > 0.85 && fill < 0.95, "({az}, {el}): fill {fill}");
            assert!(((xl + xh) / 2.0 - 400.0).abs() < 8.0 && ((yl + yh) / 2.0 - 300.0).abs() < 8.0);
        }
    }

    #[test]
    fn cuboid_is_closed_and_outward() {
        let pose = Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.3, -0.2, 0.5));
        let half = Vector3::new(0.5, 1.0, 2.0);
        let m = TriMesh::cuboid(&pose, half, [0; 3]);
        // Signed volume by the divergence theorem: sum over faces of
        // (a . (b x c)) / 6; positive for outward orientation.
        let vol: f64 = m
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize].coords);
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum();
        assert!(
            (vol - 8.0 * half.x * half.y * half.z).abs() < 1e-12,
            "volume {vol}"
        );
    }

    #[test]
    fn arrow_reaches_its_tip_and_zero_arrows_are_empty() {
        let o = Point3::new(0.1, 0.2, 0.3);
        let v = Vector3::new(0.0, -0.03, 0.04);
        let m = TriMesh::arrow(o, v, 0.001, [0; 3]);
        let along = m
            .positions
            .iter()
            .map(|p| (p - o).dot(&v.normalize()))
            .fold(f64::MIN, f64::max);
        assert!((along - v.norm()).abs() < 1e-12);
        let behind = m
            .positions
            .iter()
            .map(|p| (p - o).dot(&v.normalize()))
            .fold(f64::MAX, f64::min);
        assert!(behind.abs() < 1e-12);
        assert!(
            m.triangles
                .iter()
                .flatten()
                .all(|&i| (i as usize) < m.positions.len())
        );
        assert!(
            TriMesh::arrow(o, Vector3::zeros(), 0.001, [0; 3])
                .triangles
                .is_empty()
        );
        assert!(
            TriMesh::arrow(o, Vector3::new(f64::NAN, 0.0, 0.0), 0.001, [0; 3])
                .triangles
                .is_empty()
        );
        // Pointing straight down (antiparallel to the build axis).
        let down = TriMesh::arrow(o, Vector3::new(0.0, 0.0, -0.05), 0.001, [0; 3]);
        let lowest = down.positions.iter().map(|p| p.z).fold(f64::MAX, f64::min);
        assert!((lowest - (o.z - 0.05)).abs() < 1e-12);
    }
}
