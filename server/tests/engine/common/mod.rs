//! Fixtures shared by the FEM integration tests.

use fissure_engine::fem::Prescribed;
use fissure_engine::mesh::TetMesh;
use fissure_engine::mesh::blocks::cube;
use nalgebra::{Point3, Vector3};

/// A 2 cm cube (`n` cells a side), bottom fixed, and the `contacts` top
/// nodes nearest the top centre.
pub fn block(n: usize, contacts: usize) -> (TetMesh, Vec<u32>, Vec<u32>) {
    let l = 0.02;
    let mesh = cube(l, n);
    let fixed: Vec<u32> = (0..mesh.nodes.len() as u32)
        .filter(|&i| mesh.nodes[i as usize].z < 1e-12)
        .collect();
    let centre = Point3::new(0.5 * l, 0.5 * l, l);
    let mut top: Vec<u32> = (0..mesh.nodes.len() as u32)
        .filter(|&i| (mesh.nodes[i as usize].z - l).abs() < 1e-12)
        .collect();
    top.sort_by(|&a, &b| {
        (mesh.nodes[a as usize] - centre)
            .norm()
            .total_cmp(&(mesh.nodes[b as usize] - centre).norm())
            .then(a.cmp(&b))
    });
    top.truncate(contacts);
    (mesh, fixed, top)
}

pub fn push(nodes: &[u32], d: Vector3<f64>) -> Vec<Prescribed> {
    nodes
        .iter()
        .map(|&node| Prescribed {
            node,
            displacement: d,
        })
        .collect()
}
