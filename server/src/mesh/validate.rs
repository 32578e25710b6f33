//! Validation of a tetrahedral mesh: a list of typed problems, each naming
//! the element, node, face or edge at fault.
//!
//! Checks, on raw connectivity (so that files that [`super::TetMesh::new`]
//! would reject can still be inspected):
//! * a size implausible for metres: the bounding box longer than
//!   [`ValidateOptions::max_extent_m`] (the model is probably in mm, see
//!   [`super::units`]);
//! * node indices out of range and non-finite coordinates;
//! * inverted tetrahedra (signed volume `< 0`) and degenerate ones: the
//!   normalised volume `6 sqrt(2) |V| / l_rms^3` (1 for the regular
//!   tetrahedron, `l_rms` the root-mean-square edge length) below
//!   [`ValidateOptions::degenerate_ratio`];
//! * faces shared by more than two tetrahedra (non-manifold volume);
//! * the boundary surface (faces used once): open edges (one boundary
//!   triangle), non-manifold edges (more than two), and non-manifold vertices
//!   (the boundary triangles around a vertex form more than one fan, such as
//!   two tetrahedra touching at a corner);
//! * duplicate nodes: two nodes closer than [`ValidateOptions::duplicate_tolerance`]
//!   (m), found with a uniform hash grid of that cell size;
//! * unused nodes (in no tetrahedron).
//!
//! Surfaces ([`validate_surface`]) get the same size, boundary, duplicate and
//! unused checks, plus degenerate triangles, inconsistently oriented
//! neighbours, an inside-out orientation (a closed surface enclosing a
//! negative volume: its normals point inward) and self-intersections.
//!
//! Every problem is counted ([`Findings::total`]); the first
//! [`ValidateOptions::max_problems`] are kept in the list.

use super::TetMesh;
use super::adjacency::TET_FACES;
use nalgebra::Point3;
use std::collections::HashMap;

/// Tolerances of [`validate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ValidateOptions {
    /// Two nodes closer than this (m) are duplicates. Default 1e-9 m.
    pub duplicate_tolerance: f64,
    /// A tetrahedron whose normalised volume is below this is degenerate.
    /// Default 1e-6.
    pub degenerate_ratio: f64,
    /// Keep this many problems in the list (a broken file can have
    /// millions); all are counted. Default 10,000.
    pub max_problems: usize,
    /// A model whose bounding box is longer than this (m) is reported as
    /// [`Problem::ImplausibleSize`]. Default [`super::units::MAX_MODEL_EXTENT_M`]
    /// (1 m); infinite turns the check off.
    pub max_extent_m: f64,
}

impl Default for ValidateOptions {
    fn default() -> Self {
        Self {
            duplicate_tolerance: 1e-9,
            degenerate_ratio: 1e-6,
            max_problems: 10_000,
            max_extent_m: super::units::MAX_MODEL_EXTENT_M,
        }
    }
}

/// One problem found by [`validate`].
#[derive(Debug, Clone, PartialEq, thiserror::Error, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Problem {
    /// The model is too large to be in metres.
    #[error(
        "{0}: a scale of {scale} converts it to metres (`--scale {scale}`, or `scale = {scale}` in a scene's [model])",
        scale = .0.scale
    )]
    ImplausibleSize(super::units::ImplausibleSize),
    /// A tetrahedron names a node that does not exist.
    #[error("tetrahedron {tet} refers to node {node}, but the mesh has {nodes} nodes")]
    NodeOutOfRange { tet: usize, node: u32, nodes: usize },
    /// A node coordinate is NaN or infinite.
    #[error("node {node} has a non-finite coordinate")]
    NonFiniteNode { node: usize },
    /// A tetrahedron has negative signed volume.
    #[error("tetrahedron {tet} is inverted (signed volume {volume:e} m^3)")]
    Inverted { tet: usize, volume: f64 },
    /// A tetrahedron is flat or collapsed.
    #[error(
        "tetrahedron {tet} is degenerate (signed volume {volume:e} m^3, normalised volume {normalised:e})"
    )]
    Degenerate {
        tet: usize,
        volume: f64,
        normalised: f64,
    },
    /// A tetrahedron uses one node twice.
    #[error("tetrahedron {tet} repeats node {node}")]
    RepeatedNode { tet: usize, node: u32 },
    /// A face (sorted node triple) is shared by more than two tetrahedra.
    #[error("face {face:?} is shared by {tets} tetrahedra")]
    NonManifoldFace { face: [u32; 3], tets: usize },
    /// A boundary edge (sorted node pair) belongs to only one boundary triangle:
    /// the boundary surface is open there.
    #[error("boundary edge {edge:?} belongs to one boundary triangle (open surface)")]
    OpenEdge { edge: [u32; 2] },
    /// A boundary edge belongs to more than two boundary triangles.
    #[error("boundary edge {edge:?} belongs to {triangles} boundary triangles")]
    NonManifoldEdge { edge: [u32; 2], triangles: usize },
    /// The boundary triangles around a node form several fans.
    #[error("boundary node {node} joins {fans} separate fans of boundary triangles")]
    NonManifoldVertex { node: u32, fans: usize },
    /// Two nodes closer than the tolerance.
    #[error("node {node} duplicates node {of} (distance {distance:e} m)")]
    DuplicateNode {
        node: usize,
        of: usize,
        distance: f64,
    },
    /// A node used by no tetrahedron (or, for a surface, by no triangle).
    #[error("node {node} is used by no element")]
    UnusedNode { node: usize },
    /// A surface triangle names a vertex that does not exist.
    #[error(
        "triangle {triangle} refers to vertex {vertex}, but the surface has {vertices} vertices"
    )]
    TriangleOutOfRange {
        triangle: usize,
        vertex: u32,
        vertices: usize,
    },
    /// A surface triangle has (near) zero area: `2 A / l_max^2` below
    /// [`ValidateOptions::degenerate_ratio`], or a repeated vertex.
    #[error("triangle {triangle} is degenerate (area {area:e} m^2)")]
    DegenerateTriangle { triangle: usize, area: f64 },
    /// Two surface triangles run along the same edge in the same direction:
    /// their orientations disagree.
    #[error("edge {edge:?} is used twice in the same direction (inconsistent orientation)")]
    InconsistentOrientation { edge: [u32; 2] },
    /// A closed surface whose triangles are ordered clockwise seen from
    /// outside: the volume it encloses by the divergence theorem is negative.
    #[error(
        "the surface is inside out: its triangles face inward (enclosed volume {volume_m3:e} m^3); \
         reverse their vertex order"
    )]
    InsideOut { volume_m3: f64 },
    /// Two triangles of a surface intersect (other than along the edge or
    /// at the vertex they share).
    #[error("triangles {first} and {second} intersect")]
    SelfIntersection { first: usize, second: usize },
}

/// The problems found: all counted, the first kept.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Findings {
    /// The first [`ValidateOptions::max_problems`] problems, in the order of
    /// the checks.
    pub problems: Vec<Problem>,
    /// Every problem found.
    pub total: usize,
}

/// Validates a [`TetMesh`].
pub fn validate_mesh(mesh: &TetMesh, opts: &ValidateOptions) -> Vec<Problem> {
    validate(&mesh.nodes, &mesh.tets, opts)
}

/// Validates raw nodes (m) and tetrahedra: the first `opts.max_problems`
/// problems of [`findings`].
pub fn validate(nodes: &[Point3<f64>], tets: &[[u32; 4]], opts: &ValidateOptions) -> Vec<Problem> {
    findings(nodes, tets, opts).problems
}

/// Validates raw nodes (m) and tetrahedra. Problems come in the order of the
/// list in the module doc, each kind in increasing element or node order;
/// all are counted, the first `opts.max_problems` kept.
pub fn findings(nodes: &[Point3<f64>], tets: &[[u32; 4]], opts: &ValidateOptions) -> Findings {
    let mut out = Problems::new(opts.max_problems);
    check_extent(nodes, opts.max_extent_m, &mut out);
    let n = nodes.len();
    let finite: Vec<bool> = nodes
        .iter()
        .map(|p| p.coords.iter().all(|c| c.is_finite()))
        .collect();
    for (node, ok) in finite.iter().enumerate() {
        if !ok {
            out.push(Problem::NonFiniteNode { node });
        }
    }

    // Per-tet checks; `good[t]` marks tets usable for the topology checks.
    let mut good = vec![true; tets.len()];
    for (tet, t) in tets.iter().enumerate() {
        if let Some(&node) = t.iter().find(|&&i| i as usize >= n) {
            out.push(Problem::NodeOutOfRange {
                tet,
                node,
                nodes: n,
            });
            good[tet] = false;
            continue;
        }
        if let Some(k) = (1..4).find(|&k| t[..k].contains(&t[k])) {
            out.push(Problem::RepeatedNode { tet, node: t[k] });
            good[tet] = false;
            continue;
        }
        if t.iter().any(|&i| !finite[i as usize]) {
            continue;
        }
        let p = t.map(|i| nodes[i as usize]);
        let volume = (p[1] - p[0]).cross(&(p[2] - p[0])).dot(&(p[3] - p[0])) / 6.0;
        let mut l2 = 0.0;
        for i in 0..4 {
            for j in (i + 1)..4 {
                l2 += (p[i] - p[j]).norm_squared();
            }
        }
        let l_rms = (l2 / 6.0).sqrt();
        let normalised = if l_rms > 0.0 {
            6.0 * 2f64.sqrt() * volume.abs() / l_rms.powi(3)
        } else {
            0.0
        };
        if normalised < opts.degenerate_ratio {
            out.push(Problem::Degenerate {
                tet,
                volume,
                normalised,
            });
        } else if volume < 0.0 {
            out.push(Problem::Inverted { tet, volume });
        }
    }

    let usable: Vec<[u32; 4]> = tets
        .iter()
        .zip(&good)
        .filter(|(_, g)| **g)
        .map(|(t, _)| *t)
        .collect();
    check_topology(&usable, &mut out);

    check_duplicates(nodes, &finite, opts.duplicate_tolerance, &mut out);
    check_unused(n, tets, &mut out);
    out.finish()
}

/// Nodes of `0..n` that no element uses.
fn check_unused<const K: usize>(n: usize, elements: &[[u32; K]], out: &mut Problems) {
    let mut used = vec![false; n];
    for e in elements {
        for &i in e {
            if let Some(u) = used.get_mut(i as usize) {
                *u = true;
            }
        }
    }
    for (node, u) in used.iter().enumerate() {
        if !u {
            out.push(Problem::UnusedNode { node });
        }
    }
}

/// The topology checks of tetrahedra whose node indices are in range and
/// distinct: faces shared by more than two of them, then the boundary
/// surface's open and non-manifold edges and non-manifold vertices (node
/// indices of the mesh). A mesh whose boundary is a closed 2-manifold has
/// none of these.
pub fn boundary_findings(tets: &[[u32; 4]], max_problems: usize) -> Findings {
    let mut out = Problems::new(max_problems);
    check_topology(tets, &mut out);
    out.finish()
}

fn check_topology(tets: &[[u32; 4]], out: &mut Problems) {
    // Faces: count uses; the boundary is the faces used once.
    let mut faces: HashMap<[u32; 3], (u32, [u32; 3])> = HashMap::with_capacity(2 * tets.len());
    for t in tets {
        for f in TET_FACES {
            let tri = [t[f[0]], t[f[1]], t[f[2]]];
            let mut key = tri;
            key.sort_unstable();
            faces
                .entry(key)
                .and_modify(|e| e.0 += 1)
                .or_insert((1, tri));
        }
    }
    let mut shared: Vec<([u32; 3], usize)> = faces
        .iter()
        .filter(|(_, v)| v.0 > 2)
        .map(|(k, v)| (*k, v.0 as usize))
        .collect();
    shared.sort_unstable();
    for (face, tets) in shared {
        out.push(Problem::NonManifoldFace { face, tets });
    }
    let boundary: Vec<[u32; 3]> = {
        let mut b: Vec<[u32; 3]> = faces.values().filter(|v| v.0 == 1).map(|v| v.1).collect();
        b.sort_unstable();
        b
    };

    check_surface(&boundary, out);
}

fn check_extent(points: &[Point3<f64>], max_extent_m: f64, out: &mut Problems) {
    if let Err(e) = super::units::check_extent(points, max_extent_m) {
        out.push(Problem::ImplausibleSize(e));
    }
}

/// Validates a triangle surface (vertices in m): the first
/// `opts.max_problems` problems of [`surface_findings`].
pub fn validate_surface(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    opts: &ValidateOptions,
) -> Vec<Problem> {
    surface_findings(vertices, triangles, opts).problems
}

/// Validates a triangle surface (vertices in m): an implausible size,
/// out-of-range and degenerate triangles, open and non-manifold edges,
/// non-manifold vertices, inconsistently oriented neighbours, an inside-out
/// orientation (checked on a closed, manifold, consistently oriented
/// surface), self-intersections (on in-range triangles), duplicate and unused
/// vertices. A surface that bounds a solid, outward, has none of these.
pub fn surface_findings(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    opts: &ValidateOptions,
) -> Findings {
    let mut out = Problems::new(opts.max_problems);
    check_extent(vertices, opts.max_extent_m, &mut out);
    let n = vertices.len();
    let finite: Vec<bool> = vertices
        .iter()
        .map(|p| p.coords.iter().all(|c| c.is_finite()))
        .collect();
    for (node, ok) in finite.iter().enumerate() {
        if !ok {
            out.push(Problem::NonFiniteNode { node });
        }
    }
    let mut good = Vec::with_capacity(triangles.len());
    for (triangle, t) in triangles.iter().enumerate() {
        if let Some(&vertex) = t.iter().find(|&&i| i as usize >= n) {
            out.push(Problem::TriangleOutOfRange {
                triangle,
                vertex,
                vertices: n,
            });
            continue;
        }
        let [a, b, c] = t.map(|i| vertices[i as usize]);
        let area = 0.5 * (b - a).cross(&(c - a)).norm();
        let l2 = (b - a)
            .norm_squared()
            .max((c - b).norm_squared())
            .max((a - c).norm_squared());
        let repeated = t[0] == t[1] || t[1] == t[2] || t[0] == t[2];
        if repeated
            || l2.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
            || 2.0 * area / l2 < opts.degenerate_ratio
        {
            out.push(Problem::DegenerateTriangle { triangle, area });
        }
        if !repeated {
            good.push(*t);
        }
    }
    let before = out.total;
    check_surface(&good, &mut out);
    let manifold = out.total == before;
    let mut directed: HashMap<(u32, u32), usize> = HashMap::with_capacity(3 * good.len());
    for t in &good {
        for k in 0..3 {
            *directed.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    let mut twice: Vec<[u32; 2]> = directed
        .iter()
        .filter(|(_, c)| **c > 1)
        .map(|((a, b), _)| [*a.min(b), *a.max(b)])
        .collect();
    twice.sort_unstable();
    twice.dedup();
    let oriented = twice.is_empty();
    for edge in twice {
        out.push(Problem::InconsistentOrientation { edge });
    }
    let all_finite = finite.iter().all(|f| *f);
    if manifold && oriented && all_finite && !good.is_empty() {
        let volume_m3 = super::enclosed_volume(vertices, &good);
        if volume_m3 < 0.0 {
            out.push(Problem::InsideOut { volume_m3 });
        }
    }
    if all_finite && good.len() == triangles.len() {
        for (first, second) in super::from_surface::intersections(vertices, triangles) {
            out.push(Problem::SelfIntersection { first, second });
        }
    }
    check_duplicates(vertices, &finite, opts.duplicate_tolerance, &mut out);
    check_unused(n, triangles, &mut out);
    out.finish()
}

/// Boundary-surface checks shared by volume and surface validation: open and
/// non-manifold edges, non-manifold vertices.
fn check_surface(boundary: &[[u32; 3]], out: &mut Problems) {
    // Boundary edges.
    let mut edges: HashMap<[u32; 2], usize> = HashMap::with_capacity(boundary.len() * 2);
    for t in boundary {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry([a.min(b), a.max(b)]).or_insert(0) += 1;
        }
    }
    let mut bad_edges: Vec<([u32; 2], usize)> = edges
        .iter()
        .filter(|(_, c)| **c != 2)
        .map(|(e, c)| (*e, *c))
        .collect();
    bad_edges.sort_unstable();
    for (edge, c) in bad_edges {
        if c == 1 {
            out.push(Problem::OpenEdge { edge });
        } else {
            out.push(Problem::NonManifoldEdge { edge, triangles: c });
        }
    }

    // Boundary vertex fans: the triangles around a vertex, joined when they
    // share an edge through the vertex; more than one group is non-manifold.
    let mut around: Vec<(u32, u32)> = Vec::with_capacity(boundary.len() * 3);
    for (i, t) in boundary.iter().enumerate() {
        for &v in t {
            around.push((v, i as u32));
        }
    }
    around.sort_unstable();
    let mut start = 0;
    while start < around.len() {
        let v = around[start].0;
        let mut end = start;
        while end < around.len() && around[end].0 == v {
            end += 1;
        }
        let tris: Vec<u32> = around[start..end].iter().map(|x| x.1).collect();
        let fans = count_fans(v, &tris, boundary);
        if fans > 1 {
            out.push(Problem::NonManifoldVertex { node: v, fans });
        }
        start = end;
    }
}

/// Duplicate nodes: each node is compared with the earlier nodes kept in the
/// grid cells around it; a node found to duplicate one is reported once.
fn check_duplicates(nodes: &[Point3<f64>], finite: &[bool], tol: f64, out: &mut Problems) {
    // Duplicate nodes with a hash grid of cell size `tol`.
    if tol > 0.0 && tol.is_finite() {
        let cell = |p: &Point3<f64>| p.coords.map(|c| (c / tol).floor() as i64);
        let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
        for (i, p) in nodes.iter().enumerate() {
            if !finite[i] {
                continue;
            }
            let c = cell(p);
            let mut found = None;
            'search: for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        if let Some(list) = grid.get(&[c.x + dx, c.y + dy, c.z + dz]) {
                            for &j in list {
                                let d = (nodes[j] - p).norm();
                                if d < tol {
                                    found = Some((j, d));
                                    break 'search;
                                }
                            }
                        }
                    }
                }
            }
            if let Some((of, distance)) = found {
                out.push(Problem::DuplicateNode {
                    node: i,
                    of,
                    distance,
                });
            } else {
                grid.entry([c.x, c.y, c.z]).or_default().push(i);
            }
        }
    }
}

/// Number of edge-connected groups among the triangles `tris` around vertex
/// `v` (union-find over the few triangles of one vertex).
fn count_fans(v: u32, tris: &[u32], boundary: &[[u32; 3]]) -> usize {
    let mut parent: Vec<usize> = (0..tris.len()).collect();
    fn find(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    // Each triangle has two edges through v, named by their other endpoint.
    let mut by_other: HashMap<u32, usize> = HashMap::with_capacity(tris.len() * 2);
    for (k, &t) in tris.iter().enumerate() {
        for &w in &boundary[t as usize] {
            if w == v {
                continue;
            }
            if let Some(&j) = by_other.get(&w) {
                let (a, b) = (find(&mut parent, j), find(&mut parent, k));
                parent[a] = b;
            } else {
                by_other.insert(w, k);
            }
        }
    }
    (0..tris.len())
        .filter(|&i| find(&mut parent, i) == i)
        .count()
}

/// The problem list with a cap on what is kept; everything is counted.
struct Problems {
    list: Vec<Problem>,
    max: usize,
    total: usize,
}

impl Problems {
    fn new(max: usize) -> Self {
        Self {
            list: Vec::new(),
            max,
            total: 0,
        }
    }

    fn push(&mut self, p: Problem) {
        self.total += 1;
        if self.list.len() < self.max {
            self.list.push(p);
        }
    }

    fn finish(self) -> Findings {
        Findings {
            problems: self.list,
            total: self.total,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::blocks::cube;

    /// The defaults, without the size check (these meshes are 1 to 2 m).
    fn opts() -> ValidateOptions {
        ValidateOptions {
            max_extent_m: f64::INFINITY,
            ..Default::default()
        }
    }

    /// A 2 m cube is reported as too large for metres (first), with the
    /// scale; at 1 m and with the check off it is not; every problem is
    /// counted beyond the list's cap.
    #[test]
    fn implausible_sizes_are_reported_and_every_problem_counted() {
        let mesh = cube(2.0, 1);
        let p = validate_mesh(&mesh, &ValidateOptions::default());
        match p.as_slice() {
            [Problem::ImplausibleSize(e)] => assert_eq!((e.unit, e.scale), ("centimetres", 0.01)),
            other => panic!("{other:?}"),
        }
        assert!(p[0].to_string().contains("`--scale 0.01`"), "{}", p[0]);
        assert_eq!(
            validate_mesh(&cube(1.0, 1), &ValidateOptions::default()),
            vec![]
        );
        assert_eq!(validate_mesh(&mesh, &opts()), vec![]);
        // 30 unused nodes, a list capped at 10: all 30 counted.
        let mut nodes = cube(0.01, 1).nodes;
        nodes.extend((0..30).map(|k| Point3::new(0.1 + k as f64 * 1e-3, 0.0, 0.0)));
        let f = findings(
            &nodes,
            &cube(0.01, 1).tets,
            &ValidateOptions {
                max_problems: 10,
                ..Default::default()
            },
        );
        assert_eq!((f.problems.len(), f.total), (10, 30));
    }

    /// A closed surface facing inward is inside out (with its negative
    /// volume); two crossing spheres intersect, every crossing pair listed.
    #[test]
    fn inside_out_and_self_intersecting_surfaces_are_problems() {
        use crate::mesh::winding::{icosphere, join_surfaces};
        let (v, mut f) = icosphere(Point3::origin(), 0.03, 1);
        assert_eq!(validate_surface(&v, &f, &opts()), vec![]);
        for t in &mut f {
            t.swap(1, 2);
        }
        match validate_surface(&v, &f, &opts()).as_slice() {
            [Problem::InsideOut { volume_m3 }] => assert!(*volume_m3 < 0.0),
            other => panic!("{other:?}"),
        }
        let (v1, f1) = icosphere(Point3::origin(), 0.03, 1);
        let f1_len = f1.len();
        let (v, f) = join_surfaces((v1, f1), icosphere(Point3::new(0.02, 0.0, 0.0), 0.03, 1));
        let p = validate_surface(&v, &f, &opts());
        let pairs: Vec<(usize, usize)> = p
            .iter()
            .filter_map(|x| match x {
                Problem::SelfIntersection { first, second } => Some((*first, *second)),
                _ => None,
            })
            .collect();
        assert!(pairs.len() > 10, "{p:?}");
        assert!(pairs.iter().all(|&(a, b)| a < f1_len && b >= f1_len));
        assert_eq!(
            pairs.first().copied(),
            crate::mesh::from_surface::first_intersection(&v, &f)
        );
        assert_eq!(pairs.len(), p.len(), "only intersections: {p:?}");
    }

    #[test]
    fn a_generated_cube_has_no_problem() {
        let mesh = cube(0.01, 3);
        assert_eq!(validate_mesh(&mesh, &opts()), vec![]);
    }

    #[test]
    fn inverted_and_degenerate_tets_are_named() {
        let mut mesh = cube(1.0, 1);
        mesh.tets[2].swap(0, 1);
        let mut nodes = mesh.nodes.clone();
        // A fifth tet that is flat: four corners of the bottom face.
        nodes.push(Point3::new(0.5, 0.5, 0.0));
        let mut tets = mesh.tets.clone();
        tets.push([0, 1, 3, 8]);
        let p = validate(&nodes, &tets, &opts());
        assert!(
            p.iter()
                .any(|x| matches!(x, Problem::Inverted { tet: 2, .. })),
            "{p:?}"
        );
        assert!(
            p.iter()
                .any(|x| matches!(x, Problem::Degenerate { tet: 6, .. })),
            "{p:?}"
        );
    }

    #[test]
    fn open_surface_and_unused_and_duplicate_nodes() {
        let mesh = cube(1.0, 1);
        let mut nodes = mesh.nodes.clone();
        nodes.push(Point3::new(0.0, 0.0, 1e-12)); // duplicate of node 0, unused
        let tets = vec![mesh.tets[0]];
        let p = validate(&nodes, &tets, &opts());
        // A single tet is a closed surface; nodes not in it are unused.
        assert!(!p.iter().any(|x| matches!(x, Problem::OpenEdge { .. })));
        assert!(p.contains(&Problem::UnusedNode { node: 8 }));
        assert!(
            p.iter()
                .any(|x| matches!(x, Problem::DuplicateNode { node: 8, of: 0, .. })),
            "{p:?}"
        );
        let used: Vec<u32> = tets[0].to_vec();
        for node in 0..8u32 {
            let unused = p.contains(&Problem::UnusedNode {
                node: node as usize,
            });
            assert_eq!(unused, !used.contains(&node));
        }
    }

    #[test]
    fn non_manifold_face_edge_and_vertex() {
        let base = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(0.2, 0.2, 1.0),
            Point3::new(0.3, 0.2, 2.0),
            Point3::new(0.2, 0.2, -1.0),
        ];
        let p = validate(&base, &[[0, 1, 2, 3], [0, 1, 2, 4], [0, 2, 1, 5]], &opts());
        assert!(
            p.contains(&Problem::NonManifoldFace {
                face: [0, 1, 2],
                tets: 3
            }),
            "{p:?}"
        );

        // Two tets sharing only the edge (0, 1): a non-manifold boundary edge.
        let nodes = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(0.0, 0.0, 1.0),
            Point3::new(0.0, -1.0, 0.0),
            Point3::new(0.0, 0.0, -1.0),
        ];
        let mut tets = vec![[0, 1, 2, 3], [0, 1, 4, 5]];
        for t in &mut tets {
            let q = crate::mesh::quality::tet_quality(t.map(|i| nodes[i as usize]));
            if q.volume < 0.0 {
                t.swap(2, 3);
            }
        }
        let p = validate(&nodes, &tets, &opts());
        assert!(
            p.contains(&Problem::NonManifoldEdge {
                edge: [0, 1],
                triangles: 4
            }),
            "{p:?}"
        );

        // Two tets sharing only node 0: a non-manifold vertex.
        let nodes = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(0.0, 0.0, 1.0),
            Point3::new(-1.0, 0.0, 0.0),
            Point3::new(0.0, -1.0, 0.0),
            Point3::new(0.0, 0.0, -1.0),
        ];
        let mut tets = vec![[0, 1, 2, 3], [0, 4, 5, 6]];
        for t in &mut tets {
            let q = crate::mesh::quality::tet_quality(t.map(|i| nodes[i as usize]));
            if q.volume < 0.0 {
                t.swap(2, 3);
            }
        }
        let p = validate(&nodes, &tets, &opts());
        assert_eq!(p, vec![Problem::NonManifoldVertex { node: 0, fans: 2 }]);
    }

    #[test]
    fn surface_checks() {
        let mesh = cube(1.0, 2);
        let b = mesh.boundary();
        let mut v = Vec::new();
        b.gather(&mesh.nodes, &mut v);
        assert_eq!(validate_surface(&v, &b.triangles, &opts()), vec![]);
        // A hole: drop one triangle; its three edges are open.
        let open = &b.triangles[1..];
        let p = validate_surface(&v, open, &opts());
        let t = b.triangles[0];
        for k in 0..3 {
            let (a, c) = (t[k], t[(k + 1) % 3]);
            assert!(
                p.contains(&Problem::OpenEdge {
                    edge: [a.min(c), a.max(c)]
                }),
                "{p:?}"
            );
        }
        // Flip one triangle: its edges are used twice in one direction.
        let mut flipped = b.triangles.clone();
        flipped[0].swap(1, 2);
        let p = validate_surface(&v, &flipped, &opts());
        assert_eq!(
            p.iter()
                .filter(|x| matches!(x, Problem::InconsistentOrientation { .. }))
                .count(),
            3
        );
        // Degenerate and out-of-range triangles.
        let mut bad = b.triangles.clone();
        bad.push([0, 0, 1]);
        bad.push([0, 1, 1000]);
        let p = validate_surface(&v, &bad, &opts());
        assert!(p.contains(&Problem::DegenerateTriangle {
            triangle: bad.len() - 2,
            area: 0.0
        }));
        assert!(
            p.iter()
                .any(|x| matches!(x, Problem::TriangleOutOfRange { vertex: 1000, .. }))
        );
    }

    #[test]
    fn bad_tets_are_named_and_kept_out_of_topology() {
        let mesh = cube(1.0, 1);
        let mut tets = mesh.tets.clone();
        tets.push([0, 1, 2, 99]);
        let p = validate(&mesh.nodes, &tets, &opts());
        assert_eq!(
            p,
            vec![Problem::NodeOutOfRange {
                tet: 6,
                node: 99,
                nodes: 8
            }]
        );
        let p = validate(&mesh.nodes, &[[0, 0, 1, 2]], &opts());
        assert!(p.contains(&Problem::RepeatedNode { tet: 0, node: 0 }));
    }
}
