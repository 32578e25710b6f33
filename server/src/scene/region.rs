//! Named regions of a scene resolved on the model, the faces of the
//! elastic foundation (`[foundation]`) and the nodes of the skull surface
//! (`[skull.surface]`), DESIGN.md section 3c.
//!
//! A region is geometric (a box, a sphere, or a landmark of the phantom: a
//! sphere for `brain-stem`, a slab for a fissure's walls) or a list of
//! volume nodes read from a file (for a user's mesh). An outer-surface
//! triangle is *open* (carries no spring) when its centroid lies in a
//! geometric open region, or when its three nodes all belong to a listed
//! open region. Triangles whose three nodes are fixed carry no spring
//! either (they cannot move).

use super::{FoundationSpec, Region, SkullSurfaceSpec};
use crate::fem::foundation::Foundation;
use crate::fem::skull::SkullSurface;
use crate::mesh::phantom::{FissureLandmark, Landmarks};
use crate::mesh::{BoundarySurface, TetMesh};
use nalgebra::{Point3, Vector3};
use std::path::Path;

/// The landmarks a phantom names, for error messages.
pub const PHANTOM_LANDMARKS: &str =
    "\"brain-stem\", \"sylvian-left\", \"sylvian-right\", \"interhemispheric\"";

/// How far a fissure's landmark region reaches beyond its walls and its
/// floor, m: the wall nodes lie exactly at half the fissure's width.
pub const FISSURE_MARGIN_M: f64 = 0.001;

/// Why a region cannot be resolved.
#[derive(Debug, thiserror::Error)]
pub enum RegionError {
    /// A landmark the model does not have.
    #[error("`{field}`: the model has no landmark named {name:?} ({known})")]
    UnknownLandmark {
        field: String,
        name: String,
        known: String,
    },
    /// A vertex list that cannot be read.
    #[error("`{field}`: cannot read vertex list {path}: {source}")]
    Io {
        field: String,
        path: String,
        source: std::io::Error,
    },
    /// A bad line of a vertex list.
    #[error("`{field}`: vertex list {path}, line {line}: {reason}")]
    BadVertex {
        field: String,
        path: String,
        line: usize,
        reason: String,
    },
}

/// A region resolved on a model.
#[derive(Debug, Clone)]
pub enum Resolved {
    /// Points inside a box, sphere or landmark shape.
    Shape(Shape),
    /// Per volume node of the model: in the list.
    Nodes(Vec<bool>),
}

/// A geometric region, m.
#[derive(Debug, Clone)]
pub enum Shape {
    /// An axis-aligned box (bounds included).
    Box(Point3<f64>, Point3<f64>),
    /// A sphere (centre, radius).
    Sphere(Point3<f64>, f64),
    /// A fissure's walls: points within `half_width` of its mid-plane and
    /// between `-margin` and `depth` along its depth direction from the
    /// entry.
    Slab {
        entry: Point3<f64>,
        direction: Vector3<f64>,
        normal: Vector3<f64>,
        depth: f64,
        half_width: f64,
        margin: f64,
    },
}

impl Shape {
    /// Whether `p` lies in the shape.
    pub fn contains(&self, p: &Point3<f64>) -> bool {
        match self {
            Shape::Box(lo, hi) => (0..3).all(|i| p[i] >= lo[i] && p[i] <= hi[i]),
            Shape::Sphere(c, r) => (p - c).norm_squared() <= r * r,
            Shape::Slab {
                entry,
                direction,
                normal,
                depth,
                half_width,
                margin,
            } => {
                let r = p - entry;
                let s = r.dot(direction);
                s >= -margin && s <= depth + margin && r.dot(normal).abs() <= *half_width
            }
        }
    }

    fn fissure(f: &FissureLandmark) -> Self {
        Shape::Slab {
            entry: f.entry,
            direction: f.direction.into_inner(),
            normal: f.normal.into_inner(),
            depth: f.depth,
            half_width: 0.5 * f.width + FISSURE_MARGIN_M,
            margin: FISSURE_MARGIN_M,
        }
    }
}

/// Resolves `region` (named `field` in errors) on a model of `n_nodes`
/// nodes. `landmarks`: the phantom's, when the model is one. `to_full`:
/// with a region of interest, each node's index in the uncropped model
/// (vertex lists index that one).
pub fn resolve(
    region: &Region,
    field: &str,
    n_nodes: usize,
    landmarks: Option<&Landmarks>,
    to_full: Option<&[u32]>,
) -> Result<Resolved, RegionError> {
    Ok(Resolved::Shape(match region {
        Region::Box {
            box_min_m,
            box_max_m,
        } => Shape::Box(Point3::from(*box_min_m), Point3::from(*box_max_m)),
        Region::Sphere { centre_m, radius_m } => Shape::Sphere(Point3::from(*centre_m), *radius_m),
        Region::Landmark { landmark } => {
            let unknown = || RegionError::UnknownLandmark {
                field: field.to_owned(),
                name: landmark.clone(),
                known: match landmarks {
                    Some(_) => format!("the phantom has {PHANTOM_LANDMARKS}"),
                    None => "only the phantom model has landmarks".into(),
                },
            };
            let l = landmarks.ok_or_else(unknown)?;
            match landmark.as_str() {
                "brain-stem" => Shape::Sphere(l.brain_stem.centre, l.brain_stem.radius),
                "sylvian-left" => Shape::fissure(&l.sylvian_left),
                "sylvian-right" => Shape::fissure(&l.sylvian_right),
                "interhemispheric" => Shape::fissure(&l.interhemispheric),
                _ => return Err(unknown()),
            }
        }
        Region::Vertices { vertices_file } => {
            return read_vertices(vertices_file, field, n_nodes, to_full).map(Resolved::Nodes);
        }
    }))
}

/// The lines of a list file that hold data, with their 1-based numbers:
/// `#` starts a comment, blank lines are skipped, the rest is trimmed.
pub fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().filter_map(|(i, line)| {
        let line = line.split('#').next().unwrap_or("").trim();
        (!line.is_empty()).then_some((i + 1, line))
    })
}

/// Reads a vertex list: one volume node index (0-based, of the model as
/// the file describes it) a line; blank lines and `#` comments skipped.
fn read_vertices(
    path: &Path,
    field: &str,
    n_nodes: usize,
    to_full: Option<&[u32]>,
) -> Result<Vec<bool>, RegionError> {
    let shown = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| RegionError::Io {
        field: field.to_owned(),
        path: shown.clone(),
        source,
    })?;
    let full_n = to_full.map_or(n_nodes, |t| {
        t.iter().map(|&i| i as usize + 1).max().unwrap_or(0)
    });
    let mut listed_full = Vec::new();
    for (line_no, line) in data_lines(&text) {
        let bad = |reason: String| RegionError::BadVertex {
            field: field.to_owned(),
            path: shown.clone(),
            line: line_no,
            reason,
        };
        let n: usize = line
            .parse()
            .map_err(|_| bad(format!("{line:?} is not a node index")))?;
        if to_full.is_none() && n >= n_nodes {
            return Err(bad(format!("node {n} of a model with {n_nodes} nodes")));
        }
        listed_full.push(n);
    }
    let mut mask = vec![false; n_nodes];
    match to_full {
        None => listed_full.iter().for_each(|&n| mask[n] = true),
        Some(t) => {
            let mut full = vec![false; full_n.max(listed_full.iter().max().map_or(0, |m| m + 1))];
            listed_full.iter().for_each(|&n| full[n] = true);
            for (local, &f) in t.iter().enumerate() {
                mask[local] = full[f as usize];
            }
        }
    }
    Ok(mask)
}

/// The model a support's regions are resolved on.
#[derive(Debug, Clone, Copy)]
pub struct OnModel<'a> {
    /// The volume mesh, m.
    pub mesh: &'a TetMesh,
    /// Its boundary.
    pub surface: &'a BoundarySurface,
    /// Per volume node: fixed.
    pub fixed: &'a [bool],
    /// The phantom's landmarks, when the model is one.
    pub landmarks: Option<&'a Landmarks>,
    /// With a region of interest, each node's index in the uncropped model.
    pub to_full: Option<&'a [u32]>,
}

impl OnModel<'_> {
    /// Resolves the list `regions`, named `field[i]` in errors.
    pub fn resolve_all(
        &self,
        regions: &[Region],
        field: &str,
    ) -> Result<Vec<Resolved>, RegionError> {
        regions
            .iter()
            .enumerate()
            .map(|(i, r)| {
                resolve(
                    r,
                    &format!("{field}[{i}]"),
                    self.mesh.nodes.len(),
                    self.landmarks,
                    self.to_full,
                )
            })
            .collect()
    }
}

/// The skull surface of `spec` on the model `on`: every outer-surface node
/// neither fixed nor in an open
/// region, with its unit outward area-weighted rest normal. Unlike the
/// foundation's faces, the open test is per node (the node's own position,
/// or its membership of a vertex list).
pub fn skull_surface(
    spec: &SkullSurfaceSpec,
    on: &OnModel<'_>,
) -> Result<SkullSurface, RegionError> {
    let OnModel {
        mesh,
        surface,
        fixed,
        ..
    } = *on;
    let open = on.resolve_all(&spec.open, "skull.surface.open")?;
    let mut normals = vec![Vector3::zeros(); surface.to_volume.len()];
    for t in &surface.triangles {
        let [a, b, c] = t.map(|v| mesh.nodes[surface.to_volume[v as usize] as usize]);
        let n = (b - a).cross(&(c - a));
        for &v in t {
            normals[v as usize] += n;
        }
    }
    let nodes = surface
        .to_volume
        .iter()
        .zip(&normals)
        .filter_map(|(&node, n)| {
            let p = mesh.nodes[node as usize];
            let is_open = open.iter().any(|r| match r {
                Resolved::Shape(s) => s.contains(&p),
                Resolved::Nodes(m) => m[node as usize],
            });
            let len = n.norm();
            (!fixed[node as usize] && !is_open && len > 0.0).then(|| (node, n / len))
        })
        .collect();
    Ok(SkullSurface {
        csf_gap_m: spec.csf_gap_m,
        nodes,
    })
}

/// The supported faces of `spec` on the model `on`: every outer triangle
/// neither open nor fixed.
pub fn foundation(spec: &FoundationSpec, on: &OnModel<'_>) -> Result<Foundation, RegionError> {
    let OnModel {
        mesh,
        surface,
        fixed,
        ..
    } = *on;
    let open = on.resolve_all(&spec.open, "foundation.open")?;
    let faces = surface
        .triangles
        .iter()
        .map(|t| t.map(|v| surface.to_volume[v as usize]))
        .filter(|f| {
            if f.iter().all(|&n| fixed[n as usize]) {
                return false;
            }
            let c = Point3::from(
                f.iter()
                    .map(|&n| mesh.nodes[n as usize].coords)
                    .sum::<Vector3<f64>>()
                    / 3.0,
            );
            !open.iter().any(|r| match r {
                Resolved::Shape(s) => s.contains(&c),
                Resolved::Nodes(m) => f.iter().all(|&n| m[n as usize]),
            })
        })
        .collect();
    Ok(Foundation {
        stiffness_pa_per_m: spec.stiffness_pa_per_m,
        faces,
    })
}
