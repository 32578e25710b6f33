//! A procedural brain phantom: a cerebrum with temporal lobes and a brain
//! stem, split at the top by the inter-hemispheric fissure and on each side
//! by a Sylvian fissure, meshed by isosurface stuffing ([`super::stuffing`]).
//!
//! # Frame and geometry
//! Metres; x to the right, y to the front, z up; the origin is the centre of
//! the cerebrum's bounding ellipsoid at the height of the Sylvian fissures.
//! * Cerebrum: the ellipsoid of semi-axes `(67, 79, 50)` mm centred at
//!   `(0, 0, 8)` mm (134 mm wide, 67 mm per hemisphere; 158 mm front to back).
//! * Temporal lobes: ellipsoids of semi-axes `(22, 38, 19)` mm at
//!   `(+-46, 12, -20)` mm, smooth-unioned (radius 10 mm).
//! * Brain stem: a capsule of radius 12 mm from `(0, -12, -20)` to
//!   `(0, -24, -72)` mm, smooth-unioned (radius 8 mm). Its lower end is the
//!   fixed region [`Landmarks::brain_stem`].
//! * Inter-hemispheric fissure: the slab `|x| < w/2` (default `w` 3 mm)
//!   outside the cerebrum shrunk by the fissure depth `d` (default 25 mm) in y
//!   and z, above `z = -10` mm: it opens along the whole crest, front and back
//!   poles, and is exactly `d` deep at the vertex `(0, 0, 58)` mm.
//! * Sylvian fissures: the slab `|z| < w/2` (default 3 mm), lateral of the
//!   plane `|x| = x_entry - d` (default `d` 25 mm, `x_entry` the lateral
//!   surface at `(y, z) = (10, 0)` mm), for `|y - 10 mm| < 25` mm.
//!
//! Fissure mid-planes (`x = 0`, `z = 0`) are planes of the stuffing lattice
//! (its anchor is the origin), so each slit has a row of lattice vertices at
//! its centre; the finest spacing must satisfy `w > 2 alpha_long h` (about
//! `h < 2 w`, so that warping does not snap the centre row onto a wall), which
//! [`generate_with`] checks. The presets' meshes have no tetrahedron inside
//! a gap (measured by the `mesh_generation` bench).
//!
//! The mesh is graded: spacing `h` within `band` of the surface, growing by
//! `rate` per metre of depth, to `h 2^levels` inside.

use super::TetMesh;
use super::sdf::{Aabb, Capsule, Ellipsoid, Sdf, Sphere, difference, smooth_union};
use super::stuffing::{self, ALPHA_LONG, Lattice, SizeField, StuffingError, SurfaceGrading};
use nalgebra::{Point3, Unit, Vector3};

/// Names accepted by [`preset`].
pub const PRESETS: &[&str] = &["coarse", "paper-34k", "paper-48k"];

/// Errors of the phantom generator.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum PhantomError {
    /// The preset name is unknown.
    #[error("unknown brain phantom preset {name:?} (known: coarse, paper-34k, paper-48k)")]
    UnknownPreset { name: String },
    /// A parameter is out of range.
    #[error("phantom parameter {name} = {value} is out of range: {why}")]
    BadParameter {
        name: &'static str,
        value: f64,
        why: &'static str,
    },
    /// The mesher failed.
    #[error("meshing the phantom: {0}")]
    Stuffing(#[from] StuffingError),
    /// The mesh's boundary could not be made a closed manifold.
    #[error("meshing the phantom: {0}")]
    Boundary(#[from] crate::mesh::manifold::BoundaryError),
}

/// A fissure as seen by an instrument: where it opens and how it lies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FissureLandmark {
    /// The point of the fissure's mid-plane on the outer surface, m.
    pub entry: Point3<f64>,
    /// Unit direction from the entry into the fissure (its depth direction).
    pub direction: Unit<Vector3<f64>>,
    /// Unit normal of the fissure's mid-plane: the walls lie at
    /// `+- width / 2` along it and are pushed apart along it.
    pub normal: Unit<Vector3<f64>>,
    /// Depth of the fissure from `entry` along `direction`, m.
    pub depth: f64,
    /// Gap between the walls at rest, m.
    pub width: f64,
}

/// Landmarks of the phantom, in its frame (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Landmarks {
    /// Sylvian fissure of the left hemisphere (x < 0).
    pub sylvian_left: FissureLandmark,
    /// Sylvian fissure of the right hemisphere (x > 0).
    pub sylvian_right: FissureLandmark,
    /// The inter-hemispheric fissure, entered from the top.
    pub interhemispheric: FissureLandmark,
    /// Region of the brain stem whose nodes are fixed.
    pub brain_stem: Sphere,
}

/// A meshed phantom and its landmarks.
#[derive(Debug, Clone)]
pub struct Phantom {
    /// The mesh, m; its boundary is a closed manifold.
    pub mesh: TetMesh,
    /// Where the fissures and the fixed region are.
    pub landmarks: Landmarks,
    /// How the mesher's output was repaired to make its boundary a closed
    /// manifold (where a fissure wall comes closer to another surface than
    /// the lattice resolves; paper-34k has four such edges).
    pub repair: crate::mesh::manifold::BoundaryRepair,
}

/// Fissure sizes (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FissureSizes {
    /// Inter-hemispheric fissure gap, m.
    pub interhemispheric_width: f64,
    /// Inter-hemispheric fissure depth at the vertex, m.
    pub interhemispheric_depth: f64,
    /// Sylvian fissure gap, m.
    pub sylvian_width: f64,
    /// Sylvian fissure depth at its entry, m.
    pub sylvian_depth: f64,
}

impl Default for FissureSizes {
    fn default() -> Self {
        Self {
            interhemispheric_width: 0.003,
            interhemispheric_depth: 0.025,
            sylvian_width: 0.003,
            sylvian_depth: 0.025,
        }
    }
}

/// Generation parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhantomParams {
    /// Finest lattice spacing, used at the fissure walls, m.
    pub spacing: f64,
    /// Edge length wanted on the rest of the surface, m (at least `spacing`).
    pub surface_size: f64,
    /// Grading levels (coarsest spacing `spacing * 2^levels`).
    pub levels: u32,
    /// Depth below the surface kept at the finest spacing, m.
    pub band: f64,
    /// Growth of the tetrahedron size per metre of depth (dimensionless).
    pub rate: f64,
    /// Fissure sizes.
    pub fissures: FissureSizes,
    /// Mesh with [`stuffing::stuff_proven`]: the whole surface at `spacing`
    /// (`surface_size` ignored), the interior graded by `band` and `rate`,
    /// dihedral angles within the proven bounds. The presets leave it off:
    /// their counts need a coarser surface away from the fissures, which
    /// only the surface-graded lattice gives (angles measured, not proven).
    pub proven: bool,
}

/// The geometry of the phantom as a signed distance field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BrainShape {
    cerebrum: Ellipsoid,
    temporal: [Ellipsoid; 2],
    stem: Capsule,
    ih_inner: Ellipsoid,
    ih_floor: f64,
    sizes: FissureSizes,
    /// |x| of the Sylvian fissure's bottom plane.
    sylvian_inner_x: f64,
    sylvian_y: f64,
    sylvian_half_length: f64,
}

const TEMPORAL_BLEND: f64 = 0.010;
const STEM_BLEND: f64 = 0.008;

impl BrainShape {
    /// The phantom with the given fissure sizes.
    pub fn new(sizes: FissureSizes) -> Self {
        let cerebrum = Ellipsoid {
            centre: Point3::new(0.0, 0.0, 0.008),
            radii: Vector3::new(0.067, 0.079, 0.050),
        };
        let temporal = [-1.0, 1.0].map(|s| Ellipsoid {
            centre: Point3::new(s * 0.046, 0.012, -0.020),
            radii: Vector3::new(0.022, 0.038, 0.019),
        });
        let stem = Capsule {
            a: Point3::new(0.0, -0.012, -0.020),
            b: Point3::new(0.0, -0.024, -0.072),
            radius: 0.012,
        };
        let d = sizes.interhemispheric_depth;
        let ih_inner = Ellipsoid {
            centre: cerebrum.centre,
            radii: Vector3::new(cerebrum.radii.x, cerebrum.radii.y - d, cerebrum.radii.z - d),
        };
        let mut shape = Self {
            cerebrum,
            temporal,
            stem,
            ih_inner,
            ih_floor: -0.010,
            sizes,
            sylvian_inner_x: 0.0,
            sylvian_y: 0.010,
            sylvian_half_length: 0.025,
        };
        let entry_x = shape.surface_along(Point3::new(0.0, shape.sylvian_y, 0.0), Vector3::x());
        shape.sylvian_inner_x = entry_x - sizes.sylvian_depth;
        shape
    }

    /// The solid without fissures, m.
    pub fn body(&self, p: &Point3<f64>) -> f64 {
        let mut f = self.cerebrum.distance(p);
        for t in &self.temporal {
            f = smooth_union(f, t.distance(p), TEMPORAL_BLEND);
        }
        smooth_union(f, self.stem.distance(p), STEM_BLEND)
    }

    /// The fissures (negative inside the gaps), m.
    pub fn fissures(&self, p: &Point3<f64>) -> f64 {
        let s = &self.sizes;
        let ih = (p.x.abs() - 0.5 * s.interhemispheric_width)
            .max(-self.ih_inner.distance(p))
            .max(self.ih_floor - p.z);
        let sy = (p.z.abs() - 0.5 * s.sylvian_width)
            .max(self.sylvian_inner_x - p.x.abs())
            .max((p.y - self.sylvian_y).abs() - self.sylvian_half_length);
        ih.min(sy)
    }

    /// Finds where the body's surface crosses the ray `from + t dir`, `t >= 0`,
    /// starting inside (`from` must be inside), to 1e-12 m.
    fn surface_along(&self, from: Point3<f64>, dir: Vector3<f64>) -> f64 {
        let (mut lo, mut hi) = (0.0, 0.2);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if self.body(&(from + dir * mid)) < 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let t = 0.5 * (lo + hi);
        (from + dir * t).coords.dot(&dir)
    }

    /// Bounds of the solid, m.
    pub fn bounds(&self) -> Aabb {
        let c = &self.cerebrum;
        let lo = Point3::new(-c.radii.x, -c.radii.y, self.stem.b.z - self.stem.radius);
        let hi = Point3::new(c.radii.x, c.radii.y, c.centre.z + c.radii.z);
        Aabb { lo, hi }.inflated(0.004)
    }

    /// Landmarks of this geometry.
    pub fn landmarks(&self) -> Landmarks {
        let s = &self.sizes;
        let top = self.cerebrum.centre.z + self.cerebrum.radii.z;
        let interhemispheric = FissureLandmark {
            entry: Point3::new(0.0, 0.0, top),
            direction: -Vector3::z_axis(),
            normal: Vector3::x_axis(),
            depth: s.interhemispheric_depth,
            width: s.interhemispheric_width,
        };
        let x_entry = self.sylvian_inner_x + s.sylvian_depth;
        let sylvian = |side: f64| FissureLandmark {
            entry: Point3::new(side * x_entry, self.sylvian_y, 0.0),
            direction: Unit::new_unchecked(Vector3::new(-side, 0.0, 0.0)),
            normal: Vector3::z_axis(),
            depth: s.sylvian_depth,
            width: s.sylvian_width,
        };
        Landmarks {
            sylvian_left: sylvian(-1.0),
            sylvian_right: sylvian(1.0),
            interhemispheric,
            brain_stem: Sphere {
                centre: self.stem.b,
                radius: self.stem.radius + 0.004,
            },
        }
    }
}

impl Sdf for BrainShape {
    fn distance(&self, p: &Point3<f64>) -> f64 {
        difference(self.body(p), self.fissures(p))
    }
}

/// Parameters of a named preset.
pub fn preset_params(name: &str) -> Result<PhantomParams, PhantomError> {
    let fissures = FissureSizes::default();
    let p = match name {
        // Wide fissures (6.5 mm) so that a 12 mm lattice resolves them.
        "coarse" => PhantomParams {
            spacing: 0.012,
            surface_size: 0.012,
            levels: 1,
            band: 0.0,
            rate: 1.0,
            fissures: FissureSizes {
                interhemispheric_width: 0.0065,
                sylvian_width: 0.0065,
                ..fissures
            },
            proven: false,
        },
        "paper-34k" => PhantomParams {
            spacing: 0.0044,
            surface_size: 0.0088,
            levels: 2,
            band: 0.0,
            rate: 2.0,
            fissures,
            proven: false,
        },
        "paper-48k" => PhantomParams {
            spacing: 0.004,
            surface_size: 0.008,
            levels: 2,
            band: 0.0,
            rate: 1.0,
            fissures,
            proven: false,
        },
        _ => {
            return Err(PhantomError::UnknownPreset {
                name: name.to_string(),
            });
        }
    };
    Ok(p)
}

/// The phantom of a named preset (see [`PRESETS`]).
pub fn preset(name: &str) -> Result<Phantom, PhantomError> {
    preset_meshed(name, false, None)
}

/// The phantom of a named preset, meshed by the proven mesher when `proven`
/// (see [`PhantomParams::proven`]), at the finest lattice spacing
/// `spacing_m` (m) when given: the preset's spacing and surface size scale
/// by the same factor, so the grading keeps its shape.
pub fn preset_meshed(
    name: &str,
    proven: bool,
    spacing_m: Option<f64>,
) -> Result<Phantom, PhantomError> {
    let mut params = PhantomParams {
        proven,
        ..preset_params(name)?
    };
    if let Some(h) = spacing_m {
        // A non-positive or non-finite spacing is refused by
        // `generate_with`, which names it.
        let scale = h / params.spacing;
        params.spacing = h;
        params.surface_size *= scale;
    }
    generate_with(&params)
}

/// Generates the phantom with custom parameters.
pub fn generate_with(params: &PhantomParams) -> Result<Phantom, PhantomError> {
    let f = &params.fissures;
    for (name, value) in [
        ("spacing", params.spacing),
        ("interhemispheric_width", f.interhemispheric_width),
        ("interhemispheric_depth", f.interhemispheric_depth),
        ("sylvian_width", f.sylvian_width),
        ("sylvian_depth", f.sylvian_depth),
    ] {
        if !(value.is_finite() && value > 0.0) {
            return Err(PhantomError::BadParameter {
                name,
                value,
                why: "must be positive",
            });
        }
    }
    let grading_ok = params.rate.is_finite()
        && params.rate >= 0.0
        && params.band.is_finite()
        && params.band >= 0.0;
    if !grading_ok {
        return Err(PhantomError::BadParameter {
            name: "rate",
            value: params.rate,
            why: "rate and band must be >= 0",
        });
    }
    if f.interhemispheric_depth > 0.040 || f.sylvian_depth > 0.040 {
        return Err(PhantomError::BadParameter {
            name: "depth",
            value: f.interhemispheric_depth.max(f.sylvian_depth),
            why: "a fissure deeper than 40 mm would cut the phantom apart",
        });
    }
    let narrowest = f.interhemispheric_width.min(f.sylvian_width);
    if narrowest <= 2.0 * ALPHA_LONG * params.spacing * 1.05 {
        return Err(PhantomError::BadParameter {
            name: "spacing",
            value: params.spacing,
            why: "the lattice cannot resolve the fissures: need width > 2 * 0.241 * spacing",
        });
    }
    let shape = BrainShape::new(*f);
    let lattice = Lattice {
        spacing: params.spacing,
        levels: params.levels,
        anchor: Point3::origin(),
        bounds: shape.bounds(),
    };
    let surface = SurfaceGrading {
        fine: params.surface_size.max(params.spacing),
        band: params.band,
        rate: params.rate,
    };
    let fissure = SurfaceGrading {
        fine: params.spacing,
        band: params.band,
        rate: params.rate,
    };
    let size = |p: &Point3<f64>, f: f64| -> f64 {
        // Distance to the fissure gaps (zero at the walls).
        let to_gap = shape.fissures(p).max(0.0);
        surface.size(p, f).min(fissure.size(p, to_gap))
    };
    crate::progress::stage(format_args!(
        "meshing the brain phantom (isosurface stuffing{}, spacing {} m)",
        if params.proven { ", proven" } else { "" },
        params.spacing
    ));
    let mesh = if params.proven {
        stuffing::stuff_proven(&shape, &lattice, &fissure)?
    } else {
        stuffing::stuff(&shape, &lattice, &size)?
    };
    let (mesh, repair) = crate::mesh::manifold::repair_boundary(mesh)?;
    if !repair.is_empty() {
        tracing::info!("brain phantom: {repair}");
    }
    Ok(Phantom {
        mesh,
        landmarks: shape.landmarks(),
        repair,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn landmarks_match_the_geometry() {
        let shape = BrainShape::new(FissureSizes::default());
        let lm = shape.landmarks();
        for fl in [lm.sylvian_left, lm.sylvian_right, lm.interhemispheric] {
            let (e, d, n) = (fl.entry, fl.direction.into_inner(), fl.normal.into_inner());
            assert!(d.dot(&n).abs() < 1e-12);
            // The entry is on the outer surface of the body.
            assert!(shape.body(&e).abs() < 1e-9, "{e:?}: {}", shape.body(&e));
            // Along the depth, the mid-plane is gap, the walls at +-width are tissue.
            for k in 1..10 {
                let t = fl.depth * k as f64 / 10.0;
                let p = e + d * t;
                assert!(shape.distance(&p) > 0.0, "gap at depth {t}");
                for side in [-1.0, 1.0] {
                    assert!(
                        shape.distance(&(p + n * side * fl.width)) < 0.0,
                        "wall at depth {t}"
                    );
                }
            }
            // Beyond the depth: tissue.
            assert!(shape.distance(&(e + d * (fl.depth + 0.002))) < 0.0);
            // The gap is exactly `width`: the wall surface is at +-width/2.
            let p = e + d * (0.5 * fl.depth);
            assert!(shape.distance(&(p + n * 0.5 * fl.width)).abs() < 1e-12);
        }
        assert!(lm.sylvian_left.entry.x < -0.05 && lm.sylvian_right.entry.x > 0.05);
        assert!(shape.distance(&lm.brain_stem.centre) < 0.0);
        let left_dir = lm.sylvian_left.direction.into_inner();
        assert!((left_dir - Vector3::x()).norm() < 1e-15);
    }

    #[test]
    fn coarse_preset_is_a_valid_phantom() {
        let p = preset("coarse").expect("generates");
        let m = &p.mesh;
        let (lo, hi) = m.bounds();
        let size = hi - lo;
        assert!((0.14..=0.17).contains(&size.y), "length {}", size.y);
        assert!((0.12..=0.14).contains(&size.x), "width {}", size.x);
        let (dlo, dhi) = stuffing::dihedral_range(m);
        assert!(
            dlo > stuffing::MIN_DIHEDRAL_DEG && dhi < stuffing::MAX_DIHEDRAL_DEG,
            "{dlo}..{dhi}"
        );
        assert!(m.tets.len() < 20_000, "{}", m.tets.len());
        // The fissures are open in the mesh: no tetrahedron's centroid in a gap.
        let lm = p.landmarks;
        for fl in [lm.sylvian_left, lm.sylvian_right, lm.interhemispheric] {
            let probe = fl.entry + fl.direction.into_inner() * (0.5 * fl.depth);
            let hw = 0.5 * fl.width;
            for t in &m.tets {
                let c = t
                    .iter()
                    .fold(Vector3::zeros(), |a, &v| a + m.nodes[v as usize].coords)
                    / 4.0;
                let off = c - probe.coords;
                let along_n = off.dot(&fl.normal);
                let r = (off - fl.normal.into_inner() * along_n).norm();
                assert!(
                    !(along_n.abs() < hw * 0.9 && r < 0.003),
                    "tissue in the gap at {c:?}"
                );
            }
        }
        let fixed = m
            .nodes
            .iter()
            .filter(|q| lm.brain_stem.distance(q) < 0.0)
            .count();
        assert!(fixed >= 10, "{fixed} fixed nodes");
    }

    #[test]
    fn presets_and_errors() {
        assert!(matches!(
            preset("huge"),
            Err(PhantomError::UnknownPreset { .. })
        ));
        let mut p = preset_params("paper-48k").expect("known");
        p.spacing = 0.008;
        assert!(matches!(
            generate_with(&p),
            Err(PhantomError::BadParameter {
                name: "spacing",
                ..
            })
        ));
        p.spacing = -1.0;
        assert!(matches!(
            generate_with(&p),
            Err(PhantomError::BadParameter { .. })
        ));
        for name in PRESETS {
            assert!(preset_params(name).is_ok());
        }
    }
}
