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
//! # Local refinement ([`local`])
//! The tetrahedra a predicate selects (by centroid, e.g. a ball about the
//! fissure) are split red as above; the rest of the mesh is closed
//! conformingly by red-green rules. Every edge of a selected tetrahedron is
//! marked. A tetrahedron whose marked edges are none, one, the three of
//! one face or all six has a conforming split: none, two children (the
//! marked edge's midpoint joined to the opposite edge), four (the face
//! split into its four midpoint triangles, each joined to the opposite
//! vertex) or the red eight; any other pattern marks all six of its edges,
//! and the marking repeats until every tetrahedron has one of those
//! patterns (it ends: marks are only added). A face then has none, one or
//! all three of its edges marked in both its tetrahedra, and both split it
//! the same way, so the result is conforming. Green children split green
//! again degrade without bound, and the closure does not undo them first,
//! so a repeated local refinement (the scene's list of balls) keeps each
//! later region well inside the red part of the earlier one.
//!
//! Hand-written because the mesh crates of the ecosystem either remesh
//! (changing the surface) or do not keep our node order and labels; the
//! rules are 150 lines.

use super::{MeshError, TetMesh};
use nalgebra::Point3;
use std::collections::{HashMap, HashSet};

/// Largest number of uniform refinements a scene may ask for: each one
/// multiplies the tetrahedra by 8 (a 48k mesh twice refined is 3.2 M).
pub const MAX_REFINEMENTS: u32 = 2;

/// The six edges of a tetrahedron, as local vertex pairs, in the order the
/// midpoints are numbered (`m01, m02, m03, m12, m13, m23`).
const EDGES: [[usize; 2]; 6] = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];

/// `mesh` refined once (module documentation).
pub fn uniform(mesh: &TetMesh) -> Result<TetMesh, MeshError> {
    local(mesh, |_| true)
}

/// The edge key of nodes `a`, `b`.
fn key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// The centroid of tetrahedron `t` of `mesh`.
fn centroid(mesh: &TetMesh, t: &[u32; 4]) -> Point3<f64> {
    Point3::from(
        t.iter()
            .map(|&v| mesh.nodes[v as usize].coords)
            .sum::<nalgebra::Vector3<f64>>()
            / 4.0,
    )
}

/// `[a, b, c, d]`, or `[a, b, d, c]` where that one is positively oriented.
fn oriented(nodes: &[Point3<f64>], [a, b, c, d]: [u32; 4]) -> [u32; 4] {
    let [pa, pb, pc, pd] = [a, b, c, d].map(|i| nodes[i as usize]);
    if (pb - pa).cross(&(pc - pa)).dot(&(pd - pa)) > 0.0 {
        [a, b, c, d]
    } else {
        [a, b, d, c]
    }
}

/// Edge masks (bits in [`EDGES`] order) of the four faces and their local
/// vertices, ascending: the face opposite vertex 3, 2, 1, 0.
const FACES: [(u8, [usize; 3]); 4] = [
    (0b001011, [0, 1, 2]),
    (0b010101, [0, 1, 3]),
    (0b100110, [0, 2, 3]),
    (0b111000, [1, 2, 3]),
];

/// Whether a marked-edge pattern has a conforming split (module
/// documentation).
fn splittable(mask: u8) -> bool {
    mask == 0 || mask == 0b111111 || mask.count_ones() == 1 || FACES.iter().any(|f| f.0 == mask)
}

/// `mesh` refined where `inside` holds at a tetrahedron's centroid, closed
/// conformingly around it (module documentation): red inside, green at
/// the closure, untouched beyond. Old nodes keep their indices; tissue
/// labels are inherited.
pub fn local(mesh: &TetMesh, inside: impl Fn(&Point3<f64>) -> bool) -> Result<TetMesh, MeshError> {
    let tet_edge = |t: &[u32; 4], k: usize| key(t[EDGES[k][0]], t[EDGES[k][1]]);
    let mut marked: HashSet<(u32, u32)> = HashSet::new();
    for t in &mesh.tets {
        let c = centroid(mesh, t);
        if inside(&c) {
            marked.extend((0..6).map(|k| tet_edge(t, k)));
        }
    }
    let mask_of = |t: &[u32; 4], marked: &HashSet<(u32, u32)>| {
        (0..6).fold(0u8, |m, k| {
            m | (u8::from(marked.contains(&tet_edge(t, k))) << k)
        })
    };
    // The closure: marks only grow, so it ends.
    loop {
        let mut grown = false;
        for t in &mesh.tets {
            if !splittable(mask_of(t, &marked)) {
                marked.extend((0..6).map(|k| tet_edge(t, k)));
                grown = true;
            }
        }
        if !grown {
            break;
        }
    }
    let mut nodes = mesh.nodes.clone();
    let mut midpoint: HashMap<(u32, u32), u32> = HashMap::with_capacity(marked.len());
    let mut tets = Vec::with_capacity(mesh.tets.len() + 7 * marked.len());
    let mut labels = Vec::new();
    for (e, t) in mesh.tets.iter().enumerate() {
        let mask = mask_of(t, &marked);
        let m: [u32; 6] = std::array::from_fn(|k| {
            if mask & (1 << k) == 0 {
                return u32::MAX;
            }
            let [a, b] = EDGES[k];
            *midpoint.entry(key(t[a], t[b])).or_insert_with(|| {
                let p = nalgebra::center(&mesh.nodes[t[a] as usize], &mesh.nodes[t[b] as usize]);
                nodes.push(p);
                (nodes.len() - 1) as u32
            })
        });
        let before = tets.len();
        if mask == 0 {
            tets.push(*t);
        } else if mask == 0b111111 {
            red(&nodes, *t, m, &mut tets);
        } else if mask.count_ones() == 1 {
            // Bisection: the parent with one end of the edge moved to its
            // midpoint, then the other (each keeps the parent's orientation).
            let k = mask.trailing_zeros() as usize;
            let [a, b] = EDGES[k];
            for end in [a, b] {
                let mut c = *t;
                c[end] = m[k];
                tets.push(c);
            }
        } else {
            // One face split in four, each piece joined to the apex.
            let (_, [p, q, r]) = *FACES.iter().find(|f| f.0 == mask).expect("a face mask");
            let mid = |p: usize, q: usize| {
                let k = EDGES
                    .iter()
                    .position(|e| *e == [p.min(q), p.max(q)])
                    .expect("an edge of the face");
                m[k]
            };
            for (at, [x, y]) in [(p, [q, r]), (q, [p, r]), (r, [p, q])] {
                let mut c = *t;
                c[x] = mid(at, x);
                c[y] = mid(at, y);
                tets.push(oriented(&nodes, c));
            }
            let mut c = *t;
            c[p] = mid(q, r);
            c[q] = mid(p, r);
            c[r] = mid(p, q);
            tets.push(oriented(&nodes, c));
        }
        if !mesh.labels.is_empty() {
            labels.extend(std::iter::repeat_n(mesh.labels[e], tets.len() - before));
        }
    }
    TetMesh::new(nodes, tets)?.with_labels(labels)
}

/// The red split of `t` with edge midpoints `m` (in [`EDGES`] order) into
/// eight, appended to `tets` (module documentation).
fn red(nodes: &[Point3<f64>], t: [u32; 4], m: [u32; 6], tets: &mut Vec<[u32; 4]>) {
    let [m01, m02, m03, m12, m13, m23] = m;
    let [v0, v1, v2, v3] = t;
    tets.extend_from_slice(&[
        [v0, m01, m02, m03],
        [m01, v1, m12, m13],
        [m02, m12, v2, m23],
        [m03, m13, m23, v3],
    ]);
    // The octahedron: the shortest of its three diagonals, and the cycle of
    // the other four vertices around it.
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
        tets.push(oriented(nodes, [a, b, ring[k], ring[(k + 1) % 4]]));
    }
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

    /// The cube's tetrahedra with centroid within `r` of its centre.
    fn ball(m: &TetMesh, r: f64) -> impl Fn(&Point3<f64>) -> bool + use<> {
        let lo = m.nodes.iter().fold(Point3::origin(), |a, p| a.inf(p));
        let hi = m.nodes.iter().fold(Point3::origin(), |a, p| a.sup(p));
        let c = nalgebra::center(&lo, &hi);
        move |p: &Point3<f64>| (p - c).norm() <= r
    }

    /// Local refinement is conforming and keeps the shape: the volume, the
    /// boundary area (a hanging face would add its area twice) and every
    /// boundary vertex on the parent surface; every edge of a selected
    /// tetrahedron gets its midpoint; the tetrahedra far from the ball are
    /// the parent's, untouched; labels keep their volumes.
    #[test]
    fn local_refinement_is_conforming_red_inside_and_untouched_far_away() {
        let m = blocks::cube(0.04, 6);
        let labels: Vec<u32> = (0..m.tets.len() as u32).map(|t| t % 3).collect();
        let m = m.with_labels(labels).unwrap();
        let inside = ball(&m, 0.012);
        let r = local(&m, &inside).unwrap();
        assert!(r.tets.len() > m.tets.len() && r.tets.len() < 8 * m.tets.len());
        let (v0, v1) = (volume(&m), volume(&r));
        assert!((v1 - v0).abs() <= 1e-12 * v0, "{v1} vs {v0}");
        let (a0, a1) = (boundary_area(&m), boundary_area(&r));
        assert!((a1 - a0).abs() <= 1e-12 * a0, "{a1} vs {a0}");
        // Every new node is the midpoint of a parent edge, and every edge of
        // a selected parent has one.
        let at = |p: &Point3<f64>| p.coords.map(|x| x.to_bits());
        let new: HashSet<_> = r.nodes[m.nodes.len()..].iter().map(at).collect();
        let mut selected = 0;
        for t in &m.tets {
            let c = centroid(&m, t);
            if !inside(&c) {
                continue;
            }
            selected += 1;
            for [a, b] in EDGES {
                let mid = nalgebra::center(&m.nodes[t[a] as usize], &m.nodes[t[b] as usize]);
                assert!(new.contains(&at(&mid)), "a selected edge has no midpoint");
            }
        }
        assert!(selected > 0);
        // Far from the ball (beyond it by two cells) the parent's
        // tetrahedra are kept as they were.
        let far = |t: &[u32; 4], mesh: &TetMesh| {
            t.iter()
                .all(|&v| !ball(&m, 0.012 + 2.0 * 0.04 / 6.0)(&mesh.nodes[v as usize]))
        };
        let parents: HashSet<[u32; 4]> = m.tets.iter().filter(|t| far(t, &m)).copied().collect();
        let kept = r.tets.iter().filter(|t| parents.contains(*t)).count();
        assert!(!parents.is_empty());
        assert_eq!(kept, parents.len());
        // Each label keeps its volume.
        for l in 0..3 {
            let vol = |mesh: &TetMesh| -> f64 {
                (0..mesh.tets.len())
                    .filter(|&t| mesh.labels[t] == l)
                    .map(|t| mesh.signed_volume(t))
                    .sum()
            };
            assert!((vol(&r) - vol(&m)).abs() <= 1e-12 * vol(&m), "label {l}");
        }
        // Nothing selected: the mesh itself.
        let same = local(&m, |_| false).unwrap();
        assert_eq!(same.tets, m.tets);
        assert_eq!(same.nodes, m.nodes);
    }

    /// The green closure keeps the elements usable: the smallest dihedral
    /// angle stays within a fixed factor of the parent's.
    #[test]
    fn the_green_closure_keeps_the_smallest_dihedral_angle_within_a_factor() {
        for (cells, radius) in [(4, 0.01), (6, 0.015), (6, 0.004)] {
            let m = blocks::cube(0.04, cells);
            let r = local(&m, ball(&m, radius)).unwrap();
            let (lo0, _) = crate::mesh::stuffing::dihedral_range(&m);
            let (lo1, _) = crate::mesh::stuffing::dihedral_range(&r);
            assert!(
                lo1 >= 0.4 * lo0,
                "{cells} cells, radius {radius}: {lo1} against {lo0} degrees"
            );
        }
    }
}
