//! What the rasteriser draws: triangle meshes borrowed ([`MeshRef`]) or owned
//! ([`TriMesh`], with builders for plates, cuboids and arrows), their
//! colouring, shading and edge lines.

use super::super::Rgb;
use super::super::colormap::Colormap;
use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};

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
