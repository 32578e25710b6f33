//! Region of interest: crop the FEM model to the tetrahedra near the working
//! fissure, holding the cut surface fixed, as a speed option.
//!
//! A tetrahedron is kept when its centroid lies within `distance` (m) of the
//! region's centre (a point, or a plane for a fissure). Nodes on the *cut*
//! (faces that are boundary in the crop but interior in the full mesh) are
//! fixed, which is exact when the tissue beyond the cut moves little.

use super::SolveError;
use crate::mesh::TetMesh;
use nalgebra::{Point3, Vector3};
use std::collections::HashMap;

/// Centre of a region of interest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RoiCentre {
    /// Distance to a point.
    Point(Point3<f64>),
    /// Distance to the plane through `point` with unit `normal`.
    Plane {
        point: Point3<f64>,
        normal: Vector3<f64>,
    },
}

impl RoiCentre {
    /// Distance from `x` to the centre, m.
    pub fn distance(&self, x: &Point3<f64>) -> f64 {
        match self {
            Self::Point(p) => (x - p).norm(),
            Self::Plane { point, normal } => normal.dot(&(x - point)).abs() / normal.norm(),
        }
    }
}

/// A cropped model and its maps to the full mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct Roi {
    /// The cropped mesh (nodes renumbered compactly).
    pub mesh: TetMesh,
    /// Cropped node -> full node.
    pub to_full: Vec<u32>,
    /// Full node -> cropped node, `u32::MAX` when outside.
    pub to_crop: Vec<u32>,
    /// Cropped tetrahedron -> full tetrahedron.
    pub tets_to_full: Vec<u32>,
    /// Cropped nodes on the cut surface (to be fixed).
    pub cut_nodes: Vec<u32>,
    /// Cropped nodes to fix: the cut plus the full model's fixed nodes that
    /// lie in the crop, sorted.
    pub fixed: Vec<u32>,
}

/// Crops `mesh` to the tetrahedra whose centroid is within `distance` of
/// `centre`. `fixed` are the full model's fixed nodes. Fails when nothing is
/// kept or `distance` is not a positive number.
pub fn crop(
    mesh: &TetMesh,
    centre: RoiCentre,
    distance: f64,
    fixed: &[u32],
) -> Result<Roi, SolveError> {
    if !(distance > 0.0 && distance.is_finite()) {
        return Err(SolveError::InvalidModel(format!(
            "ROI distance {distance} m is not positive"
        )));
    }
    let kept: Vec<u32> = (0..mesh.tets.len() as u32)
        .filter(|&e| {
            let t = mesh.tets[e as usize];
            let c = t.iter().fold(Vector3::zeros(), |acc, &n| {
                acc + mesh.nodes[n as usize].coords
            }) / 4.0;
            centre.distance(&Point3::from(c)) <= distance
        })
        .collect();
    if kept.is_empty() {
        return Err(SolveError::InvalidModel(format!(
            "no element within {distance} m of the ROI centre"
        )));
    }
    let key = |t: &[u32; 4], f: usize| {
        let mut k = [t[(f + 1) % 4], t[(f + 2) % 4], t[(f + 3) % 4]];
        k.sort_unstable();
        k
    };
    let mut full_count: HashMap<[u32; 3], u8> = HashMap::new();
    for t in &mesh.tets {
        for f in 0..4 {
            *full_count.entry(key(t, f)).or_default() += 1;
        }
    }
    let mut crop_count: HashMap<[u32; 3], u8> = HashMap::new();
    for &e in &kept {
        for f in 0..4 {
            *crop_count
                .entry(key(&mesh.tets[e as usize], f))
                .or_default() += 1;
        }
    }
    let mut to_crop = vec![u32::MAX; mesh.nodes.len()];
    let mut to_full = Vec::new();
    let mut tets = Vec::with_capacity(kept.len());
    for &e in &kept {
        let t = mesh.tets[e as usize].map(|n| {
            if to_crop[n as usize] == u32::MAX {
                to_crop[n as usize] = to_full.len() as u32;
                to_full.push(n);
            }
            to_crop[n as usize]
        });
        tets.push(t);
    }
    let mut cut_nodes: Vec<u32> = crop_count
        .iter()
        .filter(|(k, c)| **c == 1 && full_count[*k] == 2)
        .flat_map(|(k, _)| k.map(|n| to_crop[n as usize]))
        .collect();
    cut_nodes.sort_unstable();
    cut_nodes.dedup();
    let mut all_fixed = cut_nodes.clone();
    all_fixed.extend(
        fixed
            .iter()
            .filter_map(|&n| to_crop.get(n as usize).copied().filter(|&c| c != u32::MAX)),
    );
    all_fixed.sort_unstable();
    all_fixed.dedup();
    let nodes = to_full.iter().map(|&n| mesh.nodes[n as usize]).collect();
    let labels = if mesh.labels.is_empty() {
        Vec::new()
    } else {
        kept.iter().map(|&e| mesh.labels[e as usize]).collect()
    };
    let cropped = TetMesh::new(nodes, tets)
        .and_then(|m| m.with_labels(labels))
        .map_err(|e| SolveError::InvalidModel(format!("cropped mesh: {e}")))?;
    Ok(Roi {
        mesh: cropped,
        to_full,
        to_crop,
        tets_to_full: kept,
        cut_nodes,
        fixed: all_fixed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::blocks::cube;

    #[test]
    fn crop_maps_and_cut() {
        let mesh = cube(0.04, 8);
        let centre = RoiCentre::Plane {
            point: Point3::new(0.02, 0.0, 0.0),
            normal: Vector3::x(),
        };
        let roi = crop(&mesh, centre, 0.0101, &[]).unwrap();
        // Two cell layers each side of x = 0.02: 4 x 8 x 8 cells.
        assert_eq!(roi.mesh.tets.len(), 6 * 4 * 8 * 8);
        for (c, &f) in roi.to_full.iter().enumerate() {
            assert_eq!(roi.to_crop[f as usize], c as u32);
            assert_eq!(roi.mesh.nodes[c], mesh.nodes[f as usize]);
        }
        // The cut nodes are exactly those on x = 0.01 and x = 0.03.
        for (c, p) in roi.mesh.nodes.iter().enumerate() {
            let on_cut = (p.x - 0.01).abs() < 1e-12 || (p.x - 0.03).abs() < 1e-12;
            assert_eq!(
                roi.cut_nodes.binary_search(&(c as u32)).is_ok(),
                on_cut,
                "node {c} at {p}"
            );
        }
        assert!(
            crop(
                &mesh,
                RoiCentre::Point(Point3::new(1.0, 1.0, 1.0)),
                0.01,
                &[]
            )
            .is_err()
        );
    }
}
