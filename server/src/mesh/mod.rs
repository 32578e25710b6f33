//! The tetrahedral brain model: nodes, positively oriented tetrahedra and the
//! boundary surface that the collision pipeline sees.
//!
//! Positions are in metres. A tetrahedron `[a, b, c, d]` is positively oriented
//! when `(b - a) x (c - a) . (d - a) > 0` (six times its signed volume).

pub mod adjacency;
pub mod blocks;
pub mod fissure;
pub mod from_surface;
pub mod image;
pub mod io;
pub mod manifold;
pub mod phantom;
pub mod quality;
pub mod refine;
pub mod sdf;
pub mod stuffing;
pub mod units;
pub mod validate;
pub mod winding;

use nalgebra::{Point3, Vector3};
use std::collections::HashMap;

/// Errors in building or validating a mesh; each names the offending element.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum MeshError {
    /// A tetrahedron refers to a node index that does not exist.
    #[error("tetrahedron {tet} refers to node {node}, but the mesh has {nodes} nodes")]
    NodeOutOfRange { tet: usize, node: u32, nodes: usize },
    /// A tetrahedron has zero or negative volume.
    #[error("tetrahedron {tet} is inverted or degenerate (signed volume {volume:e} m^3)")]
    Inverted { tet: usize, volume: f64 },
    /// The labels do not match the tetrahedra one to one.
    #[error("{labels} tissue labels for {tets} tetrahedra (one per tetrahedron, or none)")]
    LabelCount { labels: usize, tets: usize },
    /// A node coordinate is NaN or infinite.
    #[error("node {node} has a non-finite coordinate")]
    NonFinite { node: usize },
    /// The mesh has no tetrahedra.
    #[error("the mesh has no tetrahedra")]
    Empty,
}

/// A tetrahedral mesh: node positions (m) and positively oriented tetrahedra.
#[derive(Debug, Clone, PartialEq)]
pub struct TetMesh {
    /// Node positions, m.
    pub nodes: Vec<Point3<f64>>,
    /// Tetrahedra as node indices, positively oriented.
    pub tets: Vec<[u32; 4]>,
    /// Tissue label of each tetrahedron (parallel to `tets`), or empty when
    /// the mesh is one tissue. Labels name materials in a scene's
    /// `[[material.tissue]]`; meshes made from a label image carry the
    /// image's labels.
    pub labels: Vec<u32>,
}

impl TetMesh {
    /// Builds a mesh, checking indices, finiteness and orientation.
    pub fn new(nodes: Vec<Point3<f64>>, tets: Vec<[u32; 4]>) -> Result<Self, MeshError> {
        if tets.is_empty() {
            return Err(MeshError::Empty);
        }
        if let Some(node) = nodes
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(MeshError::NonFinite { node });
        }
        for (tet, t) in tets.iter().enumerate() {
            if let Some(&node) = t.iter().find(|&&n| n as usize >= nodes.len()) {
                return Err(MeshError::NodeOutOfRange {
                    tet,
                    node,
                    nodes: nodes.len(),
                });
            }
        }
        let mesh = Self {
            nodes,
            tets,
            labels: Vec::new(),
        };
        for tet in 0..mesh.tets.len() {
            let volume = mesh.signed_volume(tet);
            if volume <= 0.0 {
                return Err(MeshError::Inverted { tet, volume });
            }
        }
        Ok(mesh)
    }

    /// Sets the tissue label of each tetrahedron (`labels` parallel to
    /// `tets`; empty for one tissue).
    pub fn with_labels(mut self, labels: Vec<u32>) -> Result<Self, MeshError> {
        if !labels.is_empty() && labels.len() != self.tets.len() {
            return Err(MeshError::LabelCount {
                labels: labels.len(),
                tets: self.tets.len(),
            });
        }
        self.labels = labels;
        Ok(self)
    }

    /// Tissue label of tetrahedron `tet` (0 when the mesh is one tissue).
    pub fn label(&self, tet: usize) -> u32 {
        self.labels.get(tet).copied().unwrap_or(0)
    }

    /// Signed volume of tetrahedron `tet`, m^3 (positive when well oriented).
    pub fn signed_volume(&self, tet: usize) -> f64 {
        let [a, b, c, d] = self.tets[tet].map(|i| self.nodes[i as usize]);
        (b - a).cross(&(c - a)).dot(&(d - a)) / 6.0
    }

    /// Axis-aligned bounds of the nodes, m.
    pub fn bounds(&self) -> (Point3<f64>, Point3<f64>) {
        let mut lo = Point3::from(Vector3::repeat(f64::INFINITY));
        let mut hi = Point3::from(Vector3::repeat(f64::NEG_INFINITY));
        for p in &self.nodes {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        (lo, hi)
    }

    /// Extracts the boundary: faces used by exactly one tetrahedron, oriented
    /// outward (counter-clockwise seen from outside).
    pub fn boundary(&self) -> BoundarySurface {
        // Faces of a positively oriented tet [a,b,c,d], each listed so that its
        // right-hand normal points away from the opposite vertex.
        const FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];
        let mut count: HashMap<[u32; 3], (u32, [u32; 3], u32)> = HashMap::new();
        for (e, t) in self.tets.iter().enumerate() {
            for f in FACES {
                let tri = [t[f[0]], t[f[1]], t[f[2]]];
                let mut key = tri;
                key.sort_unstable();
                count
                    .entry(key)
                    .and_modify(|c| c.0 += 1)
                    .or_insert((1, tri, e as u32));
            }
        }
        let mut faces: Vec<([u32; 3], u32)> = count
            .into_values()
            .filter(|(n, _, _)| *n == 1)
            .map(|(_, tri, e)| (tri, e))
            .collect();
        faces.sort_unstable();
        let face_tets = faces.iter().map(|&(_, e)| e).collect();
        let mut local = HashMap::new();
        let mut to_volume = Vec::new();
        let triangles = faces
            .iter()
            .map(|(tri, _)| {
                tri.map(|v| {
                    *local.entry(v).or_insert_with(|| {
                        to_volume.push(v);
                        (to_volume.len() - 1) as u32
                    })
                })
            })
            .collect();
        BoundarySurface {
            triangles,
            to_volume,
            face_tets,
        }
    }
}

/// Drops the nodes no tetrahedron uses: renumbers `tets` in place (the
/// kept nodes keep their order) and returns, for each kept node, its index
/// among the old ones. An index out of range becomes `u32::MAX`, which
/// [`TetMesh::new`] then reports.
pub fn drop_unused_nodes(n_nodes: usize, tets: &mut [[u32; 4]]) -> Vec<u32> {
    let mut index = vec![u32::MAX; n_nodes];
    for t in tets.iter() {
        for &i in t {
            if let Some(n) = index.get_mut(i as usize) {
                *n = 0;
            }
        }
    }
    let mut kept = Vec::new();
    for (i, n) in index.iter_mut().enumerate() {
        if *n == 0 {
            *n = kept.len() as u32;
            kept.push(i as u32);
        }
    }
    for t in tets.iter_mut() {
        for i in t.iter_mut() {
            *i = index.get(*i as usize).copied().unwrap_or(u32::MAX);
        }
    }
    kept
}

/// The volume a closed triangle surface encloses, m^3 (vertices in m), by the
/// divergence theorem: the sum over triangles `(a, b, c)` of
/// `a . (b x c) / 6`. Positive for an outward (counter-clockwise seen from
/// outside) surface, negative for one that is inside out.
pub fn enclosed_volume(vertices: &[Point3<f64>], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| vertices[i as usize].coords);
            a.dot(&b.cross(&c)) / 6.0
        })
        .sum()
}

/// The boundary surface of a [`TetMesh`].
#[derive(Debug, Clone, PartialEq)]
pub struct BoundarySurface {
    /// Triangles as indices into the surface vertices, outward oriented.
    pub triangles: Vec<[u32; 3]>,
    /// Surface vertex -> volume node index.
    pub to_volume: Vec<u32>,
    /// Triangle -> the tetrahedron whose face it is.
    pub face_tets: Vec<u32>,
}

impl BoundarySurface {
    /// Positions of the surface vertices taken from volume node positions.
    pub fn gather(&self, nodes: &[Point3<f64>], out: &mut Vec<Point3<f64>>) {
        out.clear();
        out.extend(self.to_volume.iter().map(|&v| nodes[v as usize]));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_boundary_triangle_names_the_tetrahedron_it_bounds() {
        let mesh = blocks::cube(0.02, 3);
        let b = mesh.boundary();
        assert_eq!(b.face_tets.len(), b.triangles.len());
        for (t, &e) in b.triangles.iter().zip(&b.face_tets) {
            let tet = mesh.tets[e as usize];
            assert!(t.iter().all(|&v| tet.contains(&b.to_volume[v as usize])));
        }
    }
}
