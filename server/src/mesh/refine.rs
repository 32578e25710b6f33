//! Uniform (red) refinement: every tetrahedron split into eight at its edge
//! midpoints, so a mesh's shape is kept exactly while its elements halve in
//! size.
//!
//! # Method
//! Each edge gets one new node at its midpoint (shared by every
//! tetrahedron around the edge, so the result is conforming). A
//! tetrahedron `[v0, v1, v2, v3]` with midpoints `m_ij` becomes:
//! * four corner tetrahedra, each the parent scaled by 1/2 about one of its
//!   vertices (`[v0, m01, m02, m03]`, `[m01, v1, m12, m13]`,
//!   `[m02, m12, v2, m23]`, `[m03, m13, m23, v3]`), oriented as the parent;
//! * the inner octahedron `m01 m02 m03 m12 m13 m23`, cut along its shortest
//!   diagonal into four (Bey's rule of thumb for bounded shape degradation;
//!   the octahedron's faces are whole triangles whichever diagonal is
//!   chosen, so neighbours stay conforming), each oriented positively.
//!
//! Every face of the parent becomes four faces in its own plane, so the
//! boundary surface is the same point set, the volume is the same, and a
//! refined mesh differs from its parent only in the resolution of the
//! solution on it: the family a mesh-convergence study needs when the
//! geometry must not change between levels. Old nodes keep their indices;
//! new ones follow in the order their edges are first met. Tissue labels
//! are inherited.
//!
//! Hand-written because the mesh crates of the ecosystem either remesh
//! (changing the surface) or do not keep our node order and labels; the
//! rule is 60 lines.

use super::{MeshError, TetMesh};
use std::collections::HashMap;

/// Largest number of uniform refinements a scene may ask for: each one
/// multiplies the tetrahedra by 8 (a 48k mesh twice refined is 3.2 M).
pub const MAX_REFINEMENTS: u32 = 2;

/// The six edges of a tetrahedron, as local vertex pairs, in the order the
/// midpoints are numbered (`m01, m02, m03, m12, m13, m23`).
const EDGES: [[usize; 2]; 6] = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];

/// `mesh` refined once (module documentation).
pub fn uniform(mesh: &TetMesh) -> Result<TetMesh, MeshError> {
    let mut nodes = mesh.nodes.clone();
    let mut midpoint: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.tets.len() * 2);
    let mut tets = Vec::with_capacity(mesh.tets.len() * 8);
    let mut labels = Vec::with_capacity(if mesh.labels.is_empty() {
        0
    } else {
        mesh.tets.len() * 8
    });
    for (e, t) in mesh.tets.iter().enumerate() {
        let m = EDGES.map(|[a, b]| {
            let key = (t[a].min(t[b]), t[a].max(t[b]));
            *midpoint.entry(key).or_insert_with(|| {
                let p = nalgebra::center(&mesh.nodes[t[a] as usize], &mesh.nodes[t[b] as usize]);
                nodes.push(p);
                (nodes.len() - 1) as u32
            })
        });
        let [m01, m02, m03, m12, m13, m23] = m;
        let [v0, v1, v2, v3] = *t;
        tets.extend_from_slice(&[
            [v0, m01, m02, m03],
            [m01, v1, m12, m13],
            [m02, m12, v2, m23],
            [m03, m13, m23, v3],
        ]);
        // The octahedron: the shortest of its three diagonals, and the
        // cycle of the other four vertices around it.
        let len2 = |a: u32, b: u32| (nodes[a as usize] - nodes[b as usize]).norm_squared();
        let choices = [
            ((m01, m23), [m02, m12, m13, m03]),
            ((m02, m13), [m01, m12, m23, m03]),
            ((m03, m12), [m01, m02, m23, m13]),
        ];
        let ((a, b), ring) = choices
            .into_iter()
            .min_by(|x, y| len2(x.0.0, x.0.1).total_cmp(&len2(y.0.0, y.0.1)))
            .expect("three diagonals");
        for k in 0..4 {
            let (c, d) = (ring[k], ring[(k + 1) % 4]);
            let [pa, pb, pc, pd] = [a, b, c, d].map(|i| nodes[i as usize]);
            let six_v = (pb - pa).cross(&(pc - pa)).dot(&(pd - pa));
            tets.push(if six_v > 0.0 {
                [a, b, c, d]
            } else {
                [a, b, d, c]
            });
        }
        if !mesh.labels.is_empty() {
            labels.extend(std::iter::repeat_n(mesh.labels[e], 8));
        }
    }
    TetMesh::new(nodes, tets)?.with_labels(labels)
}

/// `mesh` refined `times` times.
pub fn uniform_times(mesh: TetMesh, times: u32) -> Result<TetMesh, MeshError> {
    (0..times).try_fold(mesh, |m, _| uniform(&m))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::blocks;
    use nalgebra::Point3;

    fn volume(m: &TetMesh) -> f64 {
        (0..m.tets.len()).map(|t| m.signed_volume(t)).sum()
    }

    fn boundary_area(m: &TetMesh) -> f64 {
        let b = m.boundary();
        b.triangles
            .iter()
            .map(|t| {
                let [a, b_, c] = t.map(|v| m.nodes[b.to_volume[v as usize] as usize]);
                (b_ - a).cross(&(c - a)).norm() / 2.0
            })
            .sum()
    }

    fn edges(m: &TetMesh) -> usize {
        let mut e: Vec<(u32, u32)> = m
            .tets
            .iter()
            .flat_map(|t| EDGES.map(|[a, b]| (t[a].min(t[b]), t[a].max(t[b]))))
            .collect();
        e.sort_unstable();
        e.dedup();
        e.len()
    }

    #[test]
    fn one_refinement_gives_eight_children_a_tetrahedron_and_a_node_an_edge() {
        let m = blocks::v_valley();
        let r = uniform(&m).unwrap();
        assert_eq!(r.tets.len(), 8 * m.tets.len());
        assert_eq!(r.nodes.len(), m.nodes.len() + edges(&m));
        // Old nodes keep their place.
        assert_eq!(&r.nodes[..m.nodes.len()], &m.nodes[..]);
        // Every child is positively oriented (TetMesh::new checked it) and
        // the children of a parent fill exactly its volume.
        for (e, _) in m.tets.iter().enumerate() {
            let children: f64 = (8 * e..8 * e + 8).map(|c| r.signed_volume(c)).sum();
            let parent = m.signed_volume(e);
            assert!(
                (children - parent).abs() <= 1e-12 * parent,
                "tet {e}: {children} vs {parent}"
            );
        }
    }

    #[test]
    fn refinement_keeps_the_shape_its_volume_and_its_boundary() {
        let m = blocks::u_valley();
        let r = uniform_times(m.clone(), 2).unwrap();
        assert_eq!(r.tets.len(), 64 * m.tets.len());
        // Equal but for the rounding of sums of 64 times the terms.
        let (v0, v2) = (volume(&m), volume(&r));
        assert!((v2 - v0).abs() <= 1e-10 * v0, "{v2} vs {v0}");
        let (a0, a2) = (boundary_area(&m), boundary_area(&r));
        assert!((a2 - a0).abs() <= 1e-10 * a0, "{a2} vs {a0}");
        // Each boundary face became 16 (4 per refinement), all in the
        // parent faces' planes: the new boundary vertices lie on the old
        // surface.
        let (b0, b2) = (m.boundary(), r.boundary());
        assert_eq!(b2.triangles.len(), 16 * b0.triangles.len());
        let old: Vec<[Point3<f64>; 3]> = b0
            .triangles
            .iter()
            .map(|t| t.map(|v| m.nodes[b0.to_volume[v as usize] as usize]))
            .collect();
        for &v in &b2.to_volume {
            let p = r.nodes[v as usize];
            let on = old.iter().any(|[a, b, c]| {
                let n = (b - a).cross(&(c - a));
                let plane = n.dot(&(p - a)).abs() / n.norm();
                // Inside the triangle: barycentric coordinates >= 0.
                let inside = [(a, b), (b, c), (c, a)]
                    .iter()
                    .all(|(x, y)| (*y - *x).cross(&(p - *x)).dot(&n) >= -1e-18);
                plane < 1e-12 && inside
            });
            assert!(on, "boundary vertex {v} at {p} is off the parent surface");
        }
    }

    #[test]
    fn the_inner_octahedron_is_cut_along_its_shortest_diagonal_and_keeps_quality() {
        // Twice refined, the cube's tetrahedra keep their smallest dihedral
        // angle within a fixed factor (the shortest diagonal bounds the
        // degradation; another diagonal may make slivers).
        let cube = blocks::cube(0.01, 2);
        let r = uniform_times(cube.clone(), 2).unwrap();
        let (lo0, _) = crate::mesh::stuffing::dihedral_range(&cube);
        let (lo2, _) = crate::mesh::stuffing::dihedral_range(&r);
        assert!(lo2 >= 0.5 * lo0, "{lo2} against {lo0} degrees");
    }

    #[test]
    fn labels_are_inherited_by_the_children() {
        let m = blocks::cube(0.01, 1);
        let labels: Vec<u32> = (0..m.tets.len() as u32).collect();
        let m = m.with_labels(labels).unwrap();
        let r = uniform(&m).unwrap();
        for (c, &l) in r.labels.iter().enumerate() {
            assert_eq!(l, (c / 8) as u32);
        }
        // One tissue stays one tissue.
        let plain = uniform(&blocks::cube(0.01, 1)).unwrap();
        assert!(plain.labels.is_empty());
    }
}
