//! Closed-manifold boundaries: the check a model passes before it is
//! simulated, and the repair the meshers apply to their output.
//!
//! The boundary of a tetrahedral mesh (the faces used by one tetrahedron) is
//! a closed 2-manifold when no face is shared by more than two tetrahedra,
//! every boundary edge belongs to exactly two boundary triangles and the
//! boundary triangles around every boundary node form one fan. The collision
//! stage needs it: its surface normals, the outward orientation of its
//! triangles and the contact history all assume each surface edge has one
//! triangle on either side.
//!
//! Isosurface stuffing can pinch the boundary where two sheets of the shape
//! come closer than its lattice resolves (the folds of a cortex surface, a
//! slit narrower than the spacing): two groups of tetrahedra then meet at an
//! edge, or at a node, and nothing else. [`repair_boundary`] separates them:
//! at each pinched edge it removes the tetrahedra around the edge that are
//! not in its largest face-connected group (by volume); at a pinched node
//! (when no edge is pinched), those around the node outside its largest
//! group, or all of them when they form one group whose boundary is still
//! pinched there. It repeats until the boundary is a closed manifold (a
//! removal can, rarely, pinch a neighbour) and drops the nodes left unused.
//! No node moves, so the tetrahedra kept keep their shapes and angles; the
//! fold opens by one layer of tetrahedra where it was pinched (it does not
//! close: in a fissure model the gap is the point).

use super::adjacency::Csr;
use super::validate::{Problem, boundary_findings};
use super::{MeshError, TetMesh};
use nalgebra::Point3;
use std::collections::HashSet;

/// Most repair passes before [`repair_boundary`] gives up.
pub const MAX_REPAIR_PASSES: usize = 32;

/// Why a mesh's boundary is refused or could not be repaired.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BoundaryError {
    /// The boundary is not a closed 2-manifold.
    #[error(
        "the model's boundary is not a closed manifold: {problem} (at {at}); \
         {total} such problems in all (`fissure mesh inspect` lists them)"
    )]
    NotManifold {
        /// The first problem, in the order of [`boundary_findings`].
        problem: Problem,
        /// Where it is: the positions of the nodes it names, m.
        at: String,
        /// All boundary problems.
        total: usize,
    },
    /// The repair did not converge.
    #[error(
        "the boundary is still pinched at {left} places after {passes} passes of repair \
         ({removed} tetrahedra removed)"
    )]
    RepairStalled {
        left: usize,
        passes: usize,
        removed: usize,
    },
    /// The repaired mesh is not a mesh (every tetrahedron removed).
    #[error("repairing the boundary: {0}")]
    Mesh(#[from] MeshError),
}

/// What [`repair_boundary`] changed.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct BoundaryRepair {
    /// Pinched edges found in the mesh as given.
    pub pinched_edges: usize,
    /// Pinched nodes found in the mesh as given.
    pub pinched_nodes: usize,
    /// Where the first pinch was, m.
    pub first_at_m: Option<[f64; 3]>,
    /// Tetrahedra removed.
    pub removed_tets: usize,
    /// Their volume, m^3.
    pub removed_volume_m3: f64,
    /// Volume of the mesh as given, m^3.
    pub volume_m3: f64,
    /// Passes of the repair (0: nothing to repair).
    pub passes: usize,
}

impl BoundaryRepair {
    /// Whether the mesh was already a closed manifold.
    pub fn is_empty(&self) -> bool {
        self.removed_tets == 0
    }
}

impl std::fmt::Display for BoundaryRepair {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.is_empty() {
            return write!(f, "the boundary is a closed manifold");
        }
        let plural = |n: usize, one: &str| format!("{n} {one}{}", if n == 1 { "" } else { "s" });
        write!(
            f,
            "the boundary was pinched at {} and {} (two sheets closer than the lattice \
             resolves",
            plural(self.pinched_edges, "edge"),
            plural(self.pinched_nodes, "node")
        )?;
        if let Some([x, y, z]) = self.first_at_m {
            write!(f, "; the first at ({x:.4}, {y:.4}, {z:.4}) m")?;
        }
        write!(
            f,
            "); repaired by removing {} tetrahedra there ({:.3e} m^3, {:.4}% of the volume)",
            self.removed_tets,
            self.removed_volume_m3,
            100.0 * self.removed_volume_m3 / self.volume_m3.max(f64::MIN_POSITIVE)
        )
    }
}

fn pos(mesh: &TetMesh, node: u32) -> String {
    mesh.nodes.get(node as usize).map_or_else(
        || format!("node {node}: out of range"),
        |p| format!("node {node} ({:.6}, {:.6}, {:.6}) m", p.x, p.y, p.z),
    )
}

/// Checks that the boundary of `mesh` is a closed 2-manifold; the error names
/// the first offending face, edge or node and where it is.
pub fn check_closed_manifold(mesh: &TetMesh) -> Result<(), BoundaryError> {
    let found = boundary_findings(&mesh.tets, 1);
    let Some(problem) = found.problems.into_iter().next() else {
        return Ok(());
    };
    let nodes: Vec<u32> = match &problem {
        Problem::NonManifoldFace { face, .. } => face.to_vec(),
        Problem::OpenEdge { edge } | Problem::NonManifoldEdge { edge, .. } => edge.to_vec(),
        Problem::NonManifoldVertex { node, .. } => vec![*node],
        _ => Vec::new(),
    };
    Err(BoundaryError::NotManifold {
        at: nodes
            .iter()
            .map(|&n| pos(mesh, n))
            .collect::<Vec<_>>()
            .join(", "),
        problem,
        total: found.total,
    })
}

/// The pinched edges and nodes of the boundary of `tets`.
fn pinches(tets: &[[u32; 4]]) -> (Vec<[u32; 2]>, Vec<u32>) {
    let found = boundary_findings(tets, usize::MAX);
    let mut edges = Vec::new();
    let mut nodes = Vec::new();
    for p in found.problems {
        match p {
            Problem::NonManifoldEdge { edge, .. } => edges.push(edge),
            Problem::NonManifoldVertex { node, .. } => nodes.push(node),
            _ => {}
        }
    }
    (edges, nodes)
}

fn volume(nodes: &[Point3<f64>], t: &[u32; 4]) -> f64 {
    let [a, b, c, d] = t.map(|i| nodes[i as usize]);
    (b - a).cross(&(c - a)).dot(&(d - a)) / 6.0
}

/// The groups of `star` (tetrahedron indices) joined through shared faces:
/// two tetrahedra of the star of an edge or a node that share a face share
/// three nodes, the edge's or the node's among them.
fn face_groups(tets: &[[u32; 4]], star: &[u32]) -> Vec<Vec<u32>> {
    let mut parent: Vec<usize> = (0..star.len()).collect();
    fn find(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    for i in 0..star.len() {
        for j in (i + 1)..star.len() {
            let (a, b) = (tets[star[i] as usize], tets[star[j] as usize]);
            let shared = a.iter().filter(|v| b.contains(v)).count();
            if shared == 3 {
                let (ri, rj) = (find(&mut parent, i), find(&mut parent, j));
                parent[ri] = rj;
            }
        }
    }
    let mut groups: Vec<Vec<u32>> = Vec::new();
    let mut root_group = vec![usize::MAX; star.len()];
    for i in 0..star.len() {
        let r = find(&mut parent, i);
        if root_group[r] == usize::MAX {
            root_group[r] = groups.len();
            groups.push(Vec::new());
        }
        groups[root_group[r]].push(star[i]);
    }
    groups
}

/// Marks for removal the groups of `star` other than the largest by volume
/// (ties: the group holding the lowest tetrahedron index); with
/// `all_if_one`, the whole star when it is a single group.
fn remove_minor_groups(
    nodes: &[Point3<f64>],
    tets: &[[u32; 4]],
    star: &[u32],
    all_if_one: bool,
    remove: &mut HashSet<u32>,
) {
    let groups = face_groups(tets, star);
    if groups.len() == 1 {
        if all_if_one {
            remove.extend(star.iter().copied());
        }
        return;
    }
    let size = |g: &Vec<u32>| -> f64 { g.iter().map(|&t| volume(nodes, &tets[t as usize])).sum() };
    let keep = (0..groups.len())
        .max_by(|&a, &b| {
            size(&groups[a])
                .total_cmp(&size(&groups[b]))
                .then_with(|| groups[b].iter().min().cmp(&groups[a].iter().min()))
        })
        .unwrap_or(0);
    for (k, g) in groups.iter().enumerate() {
        if k != keep {
            remove.extend(g.iter().copied());
        }
    }
}

/// Makes the boundary of `mesh` a closed 2-manifold by removing the
/// tetrahedra that pinch it (see the module doc); returns the mesh (unused
/// nodes dropped, the others in their order) and what was changed.
pub fn repair_boundary(mesh: TetMesh) -> Result<(TetMesh, BoundaryRepair), BoundaryError> {
    let mut report = BoundaryRepair {
        volume_m3: (0..mesh.tets.len()).map(|t| mesh.signed_volume(t)).sum(),
        ..Default::default()
    };
    let TetMesh {
        nodes,
        mut tets,
        mut labels,
    } = mesh;
    let mut left = 0;
    for pass in 0..=MAX_REPAIR_PASSES {
        let (edges, pinched_nodes) = pinches(&tets);
        if pass == 0 {
            report.pinched_edges = edges.len();
            report.pinched_nodes = pinched_nodes.len();
            let first = edges
                .first()
                .map(|e| e[0])
                .or(pinched_nodes.first().copied());
            report.first_at_m = first.map(|n| nodes[n as usize].coords.into());
        }
        left = edges.len() + pinched_nodes.len();
        if left == 0 || pass == MAX_REPAIR_PASSES {
            break;
        }
        report.passes = pass + 1;
        // Node -> tetrahedra of the current mesh.
        let around = Csr::from_pairs(
            nodes.len(),
            tets.iter()
                .enumerate()
                .flat_map(|(t, tet)| tet.iter().map(move |&n| (n, t as u32))),
        );
        let mut remove = HashSet::new();
        if !edges.is_empty() {
            for [a, b] in &edges {
                let star: Vec<u32> = around
                    .row(*a as usize)
                    .iter()
                    .copied()
                    .filter(|&t| tets[t as usize].contains(b))
                    .collect();
                remove_minor_groups(&nodes, &tets, &star, false, &mut remove);
            }
        } else {
            for &v in &pinched_nodes {
                let star = around.row(v as usize).to_vec();
                remove_minor_groups(&nodes, &tets, &star, true, &mut remove);
            }
        }
        report.removed_tets += remove.len();
        report.removed_volume_m3 += remove
            .iter()
            .map(|&t| volume(&nodes, &tets[t as usize]))
            .sum::<f64>();
        if !labels.is_empty() {
            let mut k = 0u32;
            labels.retain(|_| {
                k += 1;
                !remove.contains(&(k - 1))
            });
        }
        let mut k = 0u32;
        tets.retain(|_| {
            k += 1;
            !remove.contains(&(k - 1))
        });
    }
    if left > 0 {
        return Err(BoundaryError::RepairStalled {
            left,
            passes: MAX_REPAIR_PASSES,
            removed: report.removed_tets,
        });
    }
    if report.removed_tets == 0 {
        return Ok((TetMesh::new(nodes, tets)?.with_labels(labels)?, report));
    }
    let kept: Vec<_> = super::drop_unused_nodes(nodes.len(), &mut tets)
        .into_iter()
        .map(|n| nodes[n as usize])
        .collect();
    Ok((TetMesh::new(kept, tets)?.with_labels(labels)?, report))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::blocks::cube;

    /// Two unit cubes of 6 tetrahedra each, the second shifted by `shift`:
    /// along a diagonal so that they share one edge or one corner only.
    fn two_cubes(shift: [f64; 3]) -> TetMesh {
        let a = cube(1.0, 1);
        let n = a.nodes.len() as u32;
        let mut nodes = a.nodes.clone();
        nodes.extend(
            a.nodes
                .iter()
                .map(|p| Point3::new(p.x + shift[0], p.y + shift[1], p.z + shift[2])),
        );
        let mut tets = a.tets.clone();
        tets.extend(a.tets.iter().map(|t| t.map(|v| v + n)));
        // Merge coincident nodes (the shared edge or corner).
        let mut map: Vec<u32> = (0..nodes.len() as u32).collect();
        for j in n as usize..nodes.len() {
            if let Some(i) = (0..n as usize).find(|&i| (nodes[i] - nodes[j]).norm() < 1e-12) {
                map[j] = i as u32;
            }
        }
        let tets = tets.iter().map(|t| t.map(|v| map[v as usize])).collect();
        let mut m = TetMesh {
            nodes,
            tets,
            labels: Vec::new(),
        };
        // Drop the merged duplicates (unused now).
        let used: HashSet<u32> = m.tets.iter().flatten().copied().collect();
        let mut index = vec![u32::MAX; m.nodes.len()];
        let mut kept = Vec::new();
        for (i, p) in m.nodes.iter().enumerate() {
            if used.contains(&(i as u32)) {
                index[i] = kept.len() as u32;
                kept.push(*p);
            }
        }
        m.tets = m
            .tets
            .iter()
            .map(|t| t.map(|v| index[v as usize]))
            .collect();
        m.nodes = kept;
        TetMesh::new(m.nodes, m.tets).unwrap()
    }

    /// Cubes sharing an edge: the check names the edge and its nodes'
    /// positions; the repair removes the tetrahedra of the smaller side of
    /// the edge (one cube's tetrahedra at that edge), leaves a closed
    /// manifold with every remaining tetrahedron unchanged, and reports it.
    #[test]
    fn an_edge_shared_by_two_solids_is_named_and_repaired() {
        let m = two_cubes([1.0, 1.0, 0.0]);
        let e = check_closed_manifold(&m).unwrap_err().to_string();
        assert!(
            e.contains("boundary edge") && e.contains("4 boundary triangles"),
            "{e}"
        );
        assert!(e.contains("(1.000000, 1.000000, 0.000000) m"), "{e}");
        assert!(e.contains("(1.000000, 1.000000, 1.000000) m"), "{e}");
        let total: f64 = (0..m.tets.len()).map(|t| m.signed_volume(t)).sum();
        let (fixed, r) = repair_boundary(m.clone()).unwrap();
        assert_eq!(check_closed_manifold(&fixed), Ok(()));
        assert_eq!(r.pinched_edges, 1, "{r:?}");
        assert!(r.passes >= 1, "{r:?}");
        assert!(r.removed_tets > 0 && r.removed_tets < 6, "{r:?}");
        let left: f64 = (0..fixed.tets.len()).map(|t| fixed.signed_volume(t)).sum();
        assert!((total - left - r.removed_volume_m3).abs() < 1e-12);
        assert_eq!(r.volume_m3, total);
        // Every tetrahedron kept is one of the originals, node for node.
        let original: HashSet<[[u64; 3]; 4]> = m
            .tets
            .iter()
            .map(|t| t.map(|v| m.nodes[v as usize].coords.map(f64::to_bits).into()))
            .collect();
        assert!(fixed.tets.iter().all(|t| {
            original.contains(&t.map(|v| fixed.nodes[v as usize].coords.map(f64::to_bits).into()))
        }));
        assert!(
            r.to_string().contains("pinched at 1 edge and 0 nodes"),
            "{r}"
        );
    }

    /// Cubes sharing a corner: a pinched node, repaired the same way; a
    /// closed manifold is returned as it is.
    #[test]
    fn a_corner_shared_by_two_solids_is_repaired_and_a_manifold_is_kept() {
        let m = two_cubes([1.0, 1.0, 1.0]);
        let e = check_closed_manifold(&m).unwrap_err().to_string();
        assert!(e.contains("joins 2 separate fans"), "{e}");
        let (fixed, r) = repair_boundary(m).unwrap();
        assert_eq!(check_closed_manifold(&fixed), Ok(()));
        assert_eq!((r.pinched_edges, r.pinched_nodes), (0, 1), "{r:?}");
        assert!(r.removed_tets >= 1);
        let c = cube(0.01, 3);
        let (same, r) = repair_boundary(c.clone()).unwrap();
        assert_eq!(same, c);
        assert!(r.is_empty() && r.passes == 0);
        assert_eq!(r.to_string(), "the boundary is a closed manifold");
    }
}
