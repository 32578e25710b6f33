//! Adjacency of a tetrahedral mesh: node -> tetrahedra, tetrahedron face
//! neighbours, and surface vertex -> surface vertex neighbours.
//!
//! All three are plain data built once from the connectivity; the lists are
//! stored in compressed-row form ([`Csr`]) so that a query is a slice, with no
//! allocation per lookup.

use super::{BoundarySurface, TetMesh};
use std::collections::HashMap;

/// A list of lists in compressed-row form: row `i` is
/// `items[offsets[i]..offsets[i + 1]]`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Csr {
    /// Row starts into `items`; `offsets.len()` is the number of rows plus one.
    pub offsets: Vec<u32>,
    /// The entries of all rows, row after row.
    pub items: Vec<u32>,
}

impl Csr {
    /// Number of rows.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Entries of row `i` (empty when `i` is out of range).
    pub fn row(&self, i: usize) -> &[u32] {
        match (self.offsets.get(i), self.offsets.get(i + 1)) {
            (Some(&a), Some(&b)) => &self.items[a as usize..b as usize],
            _ => &[],
        }
    }

    /// Builds the rows from `(row, item)` pairs; within a row the items keep
    /// the order in which the pairs come. Pairs whose row is `>= rows` are
    /// dropped.
    pub fn from_pairs(rows: usize, pairs: impl Iterator<Item = (u32, u32)> + Clone) -> Self {
        let mut offsets = vec![0u32; rows + 1];
        for (r, _) in pairs.clone() {
            if (r as usize) < rows {
                offsets[r as usize + 1] += 1;
            }
        }
        for i in 0..rows {
            offsets[i + 1] += offsets[i];
        }
        let mut fill = offsets.clone();
        let mut items = vec![0u32; offsets[rows] as usize];
        for (r, item) in pairs {
            if (r as usize) < rows {
                items[fill[r as usize] as usize] = item;
                fill[r as usize] += 1;
            }
        }
        Self { offsets, items }
    }
}

/// The tetrahedra around each node: row `n` lists the tetrahedra using node
/// `n`, in increasing order.
pub fn node_tets(mesh: &TetMesh) -> Csr {
    let pairs = mesh
        .tets
        .iter()
        .enumerate()
        .flat_map(|(t, tet)| tet.iter().map(move |&n| (n, t as u32)));
    Csr::from_pairs(mesh.nodes.len(), pairs)
}

/// The face of a tetrahedron opposite its local vertex `i`, as local indices.
pub const TET_FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// Face neighbours: entry `[t][i]` is the tetrahedron sharing the face of `t`
/// opposite its local vertex `i`, or `None` on the boundary. A face shared by
/// more than two tetrahedra (a non-manifold mesh) gets `None` in all of them;
/// [`super::validate`] reports it.
pub fn tet_neighbours(mesh: &TetMesh) -> Vec<[Option<u32>; 4]> {
    let mut faces: HashMap<[u32; 3], (u32, u8, u32)> = HashMap::with_capacity(2 * mesh.tets.len());
    let mut out = vec![[None; 4]; mesh.tets.len()];
    for (t, tet) in mesh.tets.iter().enumerate() {
        for (i, f) in TET_FACES.iter().enumerate() {
            let mut key = [tet[f[0]], tet[f[1]], tet[f[2]]];
            key.sort_unstable();
            faces
                .entry(key)
                .and_modify(|e| {
                    e.2 += 1;
                    if e.2 == 2 {
                        out[e.0 as usize][e.1 as usize] = Some(t as u32);
                        out[t][i] = Some(e.0);
                    } else if let Some(other) = out[e.0 as usize][e.1 as usize].take() {
                        // Third use: the face is non-manifold; undo the pairing.
                        let j = out[other as usize].iter().position(|n| *n == Some(e.0));
                        if let Some(j) = j {
                            out[other as usize][j] = None;
                        }
                    }
                })
                .or_insert((t as u32, i as u8, 1));
        }
    }
    out
}

/// The largest piece of a mesh: the face-connected component of the most
/// tetrahedra (ties: the one holding the lowest tetrahedron index), with
/// unused nodes dropped (the others keep their order) and the labels kept.
/// Returns the mesh, the number of other components and their
/// tetrahedra. A piece that touches the rest only at an edge or a vertex is
/// its own component (as the boundary repair leaves none of those, an
/// image mesh's pieces are what the image's brain voxels are).
pub fn largest_component(mesh: TetMesh) -> Result<(TetMesh, usize, usize), super::MeshError> {
    let nb = tet_neighbours(&mesh);
    let mut comp = vec![u32::MAX; mesh.tets.len()];
    let mut sizes: Vec<usize> = Vec::new();
    let mut stack = Vec::new();
    for start in 0..mesh.tets.len() {
        if comp[start] != u32::MAX {
            continue;
        }
        let id = sizes.len() as u32;
        let mut size = 0;
        comp[start] = id;
        stack.push(start as u32);
        while let Some(t) = stack.pop() {
            size += 1;
            for n in nb[t as usize].iter().flatten() {
                if comp[*n as usize] == u32::MAX {
                    comp[*n as usize] = id;
                    stack.push(*n);
                }
            }
        }
        sizes.push(size);
    }
    let Some(keep) = (0..sizes.len()).max_by(|&a, &b| sizes[a].cmp(&sizes[b]).then(b.cmp(&a)))
    else {
        return Ok((mesh, 0, 0));
    };
    if sizes.len() == 1 {
        return Ok((mesh, 0, 0));
    }
    let removed_tets = mesh.tets.len() - sizes[keep];
    let keep = keep as u32;
    let labelled = !mesh.labels.is_empty();
    let mut tets = Vec::with_capacity(sizes[keep as usize]);
    let mut labels = Vec::new();
    for (t, tet) in mesh.tets.iter().enumerate() {
        if comp[t] == keep {
            tets.push(*tet);
            if labelled {
                labels.push(mesh.labels[t]);
            }
        }
    }
    let nodes = super::drop_unused_nodes(mesh.nodes.len(), &mut tets)
        .into_iter()
        .map(|n| mesh.nodes[n as usize])
        .collect();
    Ok((
        TetMesh::new(nodes, tets)?.with_labels(labels)?,
        sizes.len() - 1,
        removed_tets,
    ))
}

/// Neighbours of each surface vertex along surface edges: row `v` lists the
/// surface vertices sharing a triangle edge with `v`, sorted, without repeats.
/// `vertices` is the number of surface vertices.
pub fn surface_vertex_neighbours(triangles: &[[u32; 3]], vertices: usize) -> Csr {
    let pairs = triangles.iter().flat_map(|t| {
        (0..3).flat_map(move |k| {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            [(a, b), (b, a)]
        })
    });
    let mut csr = Csr::from_pairs(vertices, pairs);
    // Sort and deduplicate each row in place, then compact.
    let mut write = 0usize;
    let mut new_offsets = Vec::with_capacity(csr.offsets.len());
    new_offsets.push(0u32);
    for r in 0..csr.len() {
        let (a, b) = (csr.offsets[r] as usize, csr.offsets[r + 1] as usize);
        csr.items[a..b].sort_unstable();
        let mut last = None;
        for k in a..b {
            let v = csr.items[k];
            if last != Some(v) {
                csr.items[write] = v;
                write += 1;
                last = Some(v);
            }
        }
        new_offsets.push(write as u32);
    }
    csr.items.truncate(write);
    csr.offsets = new_offsets;
    csr
}

impl BoundarySurface {
    /// Neighbours of each surface vertex along surface edges (see
    /// [`surface_vertex_neighbours`]).
    pub fn vertex_neighbours(&self) -> Csr {
        surface_vertex_neighbours(&self.triangles, self.to_volume.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_largest_component_is_kept_with_its_labels() {
        // Two cubes apart: 48 and 6 tetrahedra.
        let big = crate::mesh::blocks::cube(0.02, 2);
        let small = crate::mesh::blocks::cube(0.01, 1);
        let n = big.nodes.len() as u32;
        let mut nodes = big.nodes.clone();
        nodes.extend(
            small
                .nodes
                .iter()
                .map(|p| p + nalgebra::Vector3::new(0.05, 0.0, 0.0)),
        );
        let mut tets = small
            .tets
            .iter()
            .map(|t| t.map(|v| v + n))
            .collect::<Vec<_>>();
        tets.extend(big.tets.iter().copied());
        let labels: Vec<u32> = (0..tets.len() as u32).collect();
        let mesh = TetMesh::new(nodes, tets)
            .unwrap()
            .with_labels(labels)
            .unwrap();
        let (kept, others, removed) = largest_component(mesh).unwrap();
        assert_eq!((others, removed), (1, 6));
        assert_eq!(kept.tets.len(), 48);
        assert_eq!(kept.nodes, big.nodes);
        assert_eq!(kept.labels, (6..54).collect::<Vec<u32>>());
        // One piece: unchanged.
        let one = crate::mesh::blocks::cube(0.02, 2);
        assert_eq!(largest_component(one.clone()).unwrap(), (one, 0, 0));
    }
    use crate::mesh::blocks::cube;

    #[test]
    fn node_tets_matches_brute_force() {
        let mesh = cube(1.0, 2);
        let csr = node_tets(&mesh);
        assert_eq!(csr.len(), mesh.nodes.len());
        for n in 0..mesh.nodes.len() {
            let brute: Vec<u32> = (0..mesh.tets.len() as u32)
                .filter(|&t| mesh.tets[t as usize].contains(&(n as u32)))
                .collect();
            assert_eq!(csr.row(n), brute.as_slice(), "node {n}");
        }
        // Every tet appears in exactly four rows.
        assert_eq!(csr.items.len(), 4 * mesh.tets.len());
        assert!(csr.row(mesh.nodes.len()).is_empty());
    }

    #[test]
    fn neighbours_are_symmetric_and_share_three_nodes() {
        let mesh = cube(1.0, 3);
        let nb = tet_neighbours(&mesh);
        let mut boundary_faces = 0;
        for (t, row) in nb.iter().enumerate() {
            for (i, n) in row.iter().enumerate() {
                match n {
                    None => boundary_faces += 1,
                    Some(o) => {
                        let o = *o as usize;
                        assert!(nb[o].contains(&Some(t as u32)));
                        let shared = mesh.tets[t]
                            .iter()
                            .filter(|v| mesh.tets[o].contains(v))
                            .count();
                        assert_eq!(shared, 3);
                        // The shared face is the one opposite local vertex i.
                        assert!(!mesh.tets[o].contains(&mesh.tets[t][i]));
                    }
                }
            }
        }
        assert_eq!(boundary_faces, mesh.boundary().triangles.len());
        // 3x3x3 cells, 2 triangles per cell face on 6 sides.
        assert_eq!(boundary_faces, 6 * 9 * 2);
    }

    #[test]
    fn surface_neighbours_of_a_closed_surface_satisfy_euler() {
        let mesh = cube(1.0, 2);
        let s = mesh.boundary();
        let nb = s.vertex_neighbours();
        // Each edge is counted from both ends.
        let edges = nb.items.len() / 2;
        let v = s.to_volume.len() as i64;
        let f = s.triangles.len() as i64;
        assert_eq!(v - edges as i64 + f, 2, "a closed genus-0 surface");
        for r in 0..nb.len() {
            let row = nb.row(r);
            assert!(row.windows(2).all(|w| w[0] < w[1]));
            assert!(!row.contains(&(r as u32)));
        }
    }

    #[test]
    fn non_manifold_face_gets_no_neighbour() {
        use nalgebra::Point3;
        // Three tets on one face [0,1,2]: apexes 3, 4 above and 5 below.
        let nodes = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(0.2, 0.2, 1.0),
            Point3::new(0.3, 0.2, 2.0),
            Point3::new(0.2, 0.2, -1.0),
        ];
        let mesh = TetMesh::new(nodes, vec![[0, 1, 2, 3], [0, 1, 2, 4], [0, 2, 1, 5]]).unwrap();
        let nb = tet_neighbours(&mesh);
        assert!(nb.iter().all(|r| r[3].is_none()));
    }
}
