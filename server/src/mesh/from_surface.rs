//! Meshing a user's closed triangle surface: validation (closed, manifold,
//! consistently oriented, free of self-intersections) and isosurface
//! stuffing of the field of [`super::winding::SurfaceField`] (winding number
//! for the sign, distance to the triangles for the magnitude).
//!
//! Input: vertices (m) and triangles as indices, as read by `mesh::io`.
//! Either orientation of the whole surface is accepted (`|w| >= 1/2` is
//! inside); an inside-out one is meshed and said so ([`Meshed::inside_out`]).
//! A surface over [`units::MAX_MODEL_EXTENT_M`] across is refused as being in
//! another unit (millimetres, most often) before any lattice is built.
//!
//! The stuffed mesh's boundary is made a closed manifold
//! ([`manifold::repair_boundary`]: where two folds of the surface come closer
//! than the spacing the mesher can pinch it) and the repair is reported
//! ([`Meshed::repair`]).

use super::TetMesh;
use super::manifold::{self, BoundaryError, BoundaryRepair};
use super::sdf::Aabb;
use super::stuffing::{self, Lattice, StuffingError, SurfaceGrading};
use super::units::{self, ImplausibleSize};
use super::winding::SurfaceField;
use nalgebra::Point3;
use rayon::prelude::*;
use std::collections::HashMap;

/// What is wrong with an input surface; each names the offending element.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum ClosedSurfaceError {
    /// No triangles.
    #[error("the surface has no triangles")]
    Empty,
    /// A triangle refers to a vertex that does not exist, or a vertex
    /// coordinate is NaN or infinite (the engine's one check of a surface's
    /// indices and values).
    #[error(transparent)]
    Values(#[from] fissure_shared::surface::SurfaceError),
    /// A triangle repeats a vertex or has zero area.
    #[error("triangle {triangle} is degenerate (repeated vertex or zero area)")]
    DegenerateTriangle { triangle: usize },
    /// An edge belongs to one triangle only: the surface is open there.
    #[error("edge ({a}, {b}) of triangle {triangle} is a border: the surface is not closed")]
    OpenEdge { a: u32, b: u32, triangle: usize },
    /// An edge belongs to more than two triangles.
    #[error("edge ({a}, {b}) is shared by {count} triangles: the surface is not manifold")]
    NonManifoldEdge { a: u32, b: u32, count: usize },
    /// Two triangles run along their shared edge in the same direction.
    #[error("triangles {first} and {second} have opposite orientations across edge ({a}, {b})")]
    InconsistentOrientation {
        a: u32,
        b: u32,
        first: usize,
        second: usize,
    },
    /// The triangles around a vertex form more than one fan.
    #[error("vertex {vertex} joins {fans} separate fans of triangles: the surface is not manifold")]
    NonManifoldVertex { vertex: u32, fans: usize },
    /// Two triangles intersect.
    #[error("triangles {first} and {second} intersect")]
    SelfIntersection { first: usize, second: usize },
    /// The surface is too large to be in metres.
    #[error(transparent)]
    Units(#[from] ImplausibleSize),
    /// The mesher failed.
    #[error("meshing the surface: {0}")]
    Stuffing(#[from] StuffingError),
    /// The mesh's boundary could not be made a closed manifold.
    #[error("the mesh of the surface: {0}")]
    Boundary(#[from] BoundaryError),
}

/// A meshed surface and what was noticed on the way.
#[derive(Debug, Clone, PartialEq)]
pub struct Meshed {
    /// The tetrahedral mesh of the inside, m; its boundary is a closed
    /// manifold.
    pub mesh: TetMesh,
    /// How its boundary was repaired (empty when it needed nothing).
    pub repair: BoundaryRepair,
    /// The input's triangles face inward (clockwise seen from outside); the
    /// inside was meshed all the same.
    pub inside_out: bool,
}

/// Parameters of the proven mesher with a graded inside: the tetrahedron
/// size at the surface and how it grows inward (meshing a closed surface
/// here, an image's brain in [`super::image`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceMeshing {
    /// Lattice spacing at the surface, m.
    pub spacing: f64,
    /// Grading levels (0: uniform).
    pub levels: u32,
    /// Growth of the tetrahedron size per metre of depth (used when
    /// `levels > 0`).
    pub rate: f64,
}

impl SurfaceMeshing {
    /// Meshes `field` by [`stuffing::stuff_proven`] on a lattice through
    /// `anchor` covering `bounds`, `spacing` at the surface (within a band
    /// of one spacing) and growing by `rate` inward, up to `levels`
    /// halvings coarser.
    pub fn stuff(
        &self,
        field: &dyn super::sdf::Sdf,
        anchor: Point3<f64>,
        bounds: Aabb,
    ) -> Result<TetMesh, StuffingError> {
        let lattice = Lattice {
            spacing: self.spacing,
            levels: self.levels,
            anchor,
            bounds,
        };
        let grading = SurfaceGrading {
            fine: self.spacing,
            band: self.spacing,
            rate: self.rate,
        };
        stuffing::stuff_proven(field, &lattice, &grading)
    }
}

/// Checks that the surface is a closed, consistently oriented 2-manifold
/// without degenerate or intersecting triangles.
pub fn check_closed_surface(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
) -> Result<(), ClosedSurfaceError> {
    if triangles.is_empty() {
        return Err(ClosedSurfaceError::Empty);
    }
    fissure_shared::surface::check_surface(triangles, vertices)?;
    for (triangle, t) in triangles.iter().enumerate() {
        let [a, b, c] = t.map(|v| vertices[v as usize]);
        if t[0] == t[1]
            || t[1] == t[2]
            || t[2] == t[0]
            || (b - a).cross(&(c - a)).norm_squared() == 0.0
        {
            return Err(ClosedSurfaceError::DegenerateTriangle { triangle });
        }
    }
    // Edges: each undirected edge in exactly two triangles, once each way.
    let mut directed: HashMap<(u32, u32), Vec<usize>> = HashMap::with_capacity(triangles.len() * 3);
    for (ti, t) in triangles.iter().enumerate() {
        for i in 0..3 {
            directed.entry((t[i], t[(i + 1) % 3])).or_default().push(ti);
        }
    }
    let mut keys: Vec<(u32, u32)> = directed.keys().copied().collect();
    keys.sort_unstable();
    for &(a, b) in &keys {
        let fwd = &directed[&(a, b)];
        let back = directed.get(&(b, a)).map_or(0, Vec::len);
        let count = fwd.len() + back;
        if count > 2 {
            return Err(ClosedSurfaceError::NonManifoldEdge {
                a: a.min(b),
                b: a.max(b),
                count,
            });
        }
        if fwd.len() == 2 {
            return Err(ClosedSurfaceError::InconsistentOrientation {
                a,
                b,
                first: fwd[0],
                second: fwd[1],
            });
        }
        if back == 0 {
            return Err(ClosedSurfaceError::OpenEdge {
                a,
                b,
                triangle: fwd[0],
            });
        }
    }
    // Vertices: the link of each vertex is one cycle. With manifold, oriented
    // edges, each triangle (v, a, b) gives the link edge a -> b, and each link
    // vertex has one outgoing and one incoming link edge.
    let mut link: Vec<Vec<(u32, u32)>> = vec![Vec::new(); vertices.len()];
    for t in triangles {
        for i in 0..3 {
            link[t[i] as usize].push((t[(i + 1) % 3], t[(i + 2) % 3]));
        }
    }
    for (v, edges) in link.iter().enumerate() {
        if edges.is_empty() {
            continue;
        }
        let next: HashMap<u32, u32> = edges.iter().copied().collect();
        let mut seen = 0usize;
        let mut fans = 0usize;
        let mut visited: HashMap<u32, bool> = HashMap::new();
        for &(start, _) in edges {
            if visited.contains_key(&start) {
                continue;
            }
            fans += 1;
            let mut cur = start;
            while visited.insert(cur, true).is_none() {
                seen += 1;
                match next.get(&cur) {
                    Some(&n) => cur = n,
                    None => break,
                }
            }
        }
        if fans > 1 || seen != edges.len() {
            return Err(ClosedSurfaceError::NonManifoldVertex {
                vertex: v as u32,
                fans,
            });
        }
    }
    if let Some((first, second)) = first_intersection(vertices, triangles) {
        return Err(ClosedSurfaceError::SelfIntersection { first, second });
    }
    Ok(())
}

/// The first pair `(i, j)`, `i < j`, of intersecting triangles. Triangles
/// sharing an edge intersect when they are coplanar and folded onto each
/// other; triangles sharing one vertex when an opposite edge of one crosses
/// the other; others when any edge of one meets the other (touching counts).
pub fn first_intersection(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
) -> Option<(usize, usize)> {
    pairs_intersecting(vertices, triangles, true)
        .into_iter()
        .next()
}

/// Every pair `(i, j)`, `i < j`, of intersecting triangles (as
/// [`first_intersection`] defines it), sorted. Triangles must index
/// existing vertices.
pub fn intersections(vertices: &[Point3<f64>], triangles: &[[u32; 3]]) -> Vec<(usize, usize)> {
    pairs_intersecting(vertices, triangles, false)
}

/// The intersecting pairs, sorted; with `first_only`, only each triangle's
/// first partner and then only the smallest pair.
fn pairs_intersecting(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    first_only: bool,
) -> Vec<(usize, usize)> {
    let field = SurfaceField::new(vertices, triangles);
    let pts = |t: usize| triangles[t].map(|v| vertices[v as usize]);
    let mut pairs: Vec<(usize, usize)> = (0..triangles.len())
        .into_par_iter()
        .flat_map_iter(|i| {
            let ti = pts(i);
            let lo = ti[0].inf(&ti[1]).inf(&ti[2]);
            let hi = ti[0].sup(&ti[1]).sup(&ti[2]);
            let mut hits: Vec<usize> = Vec::new();
            field.overlapping(&lo, &hi, |j| {
                if j <= i || (first_only && hits.first().is_some_and(|&h| h < j)) {
                    return;
                }
                if triangles_intersect(triangles[i], triangles[j], &ti, &pts(j)) {
                    if first_only {
                        hits.clear();
                    }
                    hits.push(j);
                }
            });
            hits.into_iter().map(move |j| (i, j))
        })
        .collect();
    pairs.sort_unstable();
    pairs.dedup();
    if first_only {
        pairs.truncate(1);
    }
    pairs
}

fn triangles_intersect(
    a: [u32; 3],
    b: [u32; 3],
    pa: &[Point3<f64>; 3],
    pb: &[Point3<f64>; 3],
) -> bool {
    let shared: Vec<(usize, usize)> = (0..3)
        .flat_map(|i| (0..3).filter(move |&j| a[i] == b[j]).map(move |j| (i, j)))
        .collect();
    match shared.len() {
        0 => (0..3).any(|k| {
            segment_triangle(&pa[k], &pa[(k + 1) % 3], pb)
                || segment_triangle(&pb[k], &pb[(k + 1) % 3], pa)
        }),
        1 => {
            let (i, j) = shared[0];
            let (a1, a2) = (pa[(i + 1) % 3], pa[(i + 2) % 3]);
            let (b1, b2) = (pb[(j + 1) % 3], pb[(j + 2) % 3]);
            segment_triangle(&a1, &a2, pb) || segment_triangle(&b1, &b2, pa)
        }
        2 => {
            // Folded: the opposite vertex of b lies in a's plane on the same
            // side of the shared edge as a's opposite vertex.
            let oa = (0..3).find(|&i| !b.contains(&a[i])).unwrap_or(0);
            let ob = (0..3).find(|&j| !a.contains(&b[j])).unwrap_or(0);
            let (e0, e1) = (pa[(oa + 1) % 3], pa[(oa + 2) % 3]);
            if orient(&pa[0], &pa[1], &pa[2], &pb[ob]) != 0.0 {
                return false;
            }
            let n = (e1 - e0).cross(&(pa[oa] - e0));
            let side = |p: &Point3<f64>| (e1 - e0).cross(&(p - e0)).dot(&n);
            side(&pb[ob]) > 0.0
        }
        _ => true,
    }
}

fn orient(a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>, d: &Point3<f64>) -> f64 {
    (b - a).cross(&(c - a)).dot(&(d - a))
}

/// Whether the closed segment `[p, q]` meets the closed triangle `t`.
fn segment_triangle(p: &Point3<f64>, q: &Point3<f64>, t: &[Point3<f64>; 3]) -> bool {
    let [a, b, c] = t;
    let (dp, dq) = (orient(a, b, c, p), orient(a, b, c, q));
    if (dp > 0.0 && dq > 0.0) || (dp < 0.0 && dq < 0.0) {
        return false;
    }
    if dp == 0.0 && dq == 0.0 {
        return coplanar_segment_triangle(p, q, t);
    }
    let e = [orient(p, q, a, b), orient(p, q, b, c), orient(p, q, c, a)];
    e.iter().all(|&x| x >= 0.0) || e.iter().all(|&x| x <= 0.0)
}

fn coplanar_segment_triangle(p: &Point3<f64>, q: &Point3<f64>, t: &[Point3<f64>; 3]) -> bool {
    let n = (t[1] - t[0]).cross(&(t[2] - t[0]));
    let drop = n.iamax();
    let (u, v) = ((drop + 1) % 3, (drop + 2) % 3);
    let f = |x: &Point3<f64>| [x[u], x[v]];
    let (p, q) = (f(p), f(q));
    let t2 = [f(&t[0]), f(&t[1]), f(&t[2])];
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let inside = |x: [f64; 2]| {
        let s = [
            cross(t2[0], t2[1], x),
            cross(t2[1], t2[2], x),
            cross(t2[2], t2[0], x),
        ];
        s.iter().all(|&k| k >= 0.0) || s.iter().all(|&k| k <= 0.0)
    };
    if inside(p) || inside(q) {
        return true;
    }
    (0..3).any(|k| {
        let (a, b) = (t2[k], t2[(k + 1) % 3]);
        let (d1, d2) = (cross(p, q, a), cross(p, q, b));
        let (d3, d4) = (cross(a, b, p), cross(a, b, q));
        d1 * d2 <= 0.0 && d3 * d4 <= 0.0 && !(d1 == 0.0 && d2 == 0.0)
    })
}

/// Validates the surface and meshes the solid it bounds with isosurface
/// stuffing ([`stuffing::stuff_proven`]: uniform at the surface, graded inside
/// by `rate`, dihedral angles within the proven bounds). Boundary vertices of the result lie on the input surface to
/// within `1e-6 * spacing` (cut points) or exactly on it (warped vertices at
/// cut points); sharp edges and corners of the input are rounded off at the
/// scale of the spacing.
pub fn mesh_surface(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    params: &SurfaceMeshing,
) -> Result<Meshed, ClosedSurfaceError> {
    units::check_extent(vertices, units::MAX_MODEL_EXTENT_M)?;
    crate::progress::stage(format_args!(
        "checking the surface ({} triangles): closed, manifold, no self-intersection",
        triangles.len()
    ));
    check_closed_surface(vertices, triangles)?;
    // Negative when inside out.
    let enclosed = super::enclosed_volume(vertices, triangles);
    crate::progress::stage(format_args!(
        "meshing the inside: isosurface stuffing at {} m",
        params.spacing
    ));
    let field = SurfaceField::new(vertices, triangles);
    let (lo, hi) = field.bounds();
    let mesh = params.stuff(&field, lo, Aabb { lo, hi })?;
    crate::progress::stage(format_args!(
        "checking the boundary of {} tetrahedra",
        mesh.tets.len()
    ));
    let (mesh, repair) = manifold::repair_boundary(mesh)?;
    Ok(Meshed {
        mesh,
        repair,
        inside_out: enclosed < 0.0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::winding::{icosphere, join_surfaces};

    #[test]
    fn sphere_volume() {
        let r = 0.04;
        let (v, f) = icosphere(Point3::new(0.001, 0.002, 0.003), r, 3);
        let m = mesh_surface(
            &v,
            &f,
            &SurfaceMeshing {
                spacing: 0.008,
                levels: 0,
                rate: 0.0,
            },
        )
        .expect("meshes")
        .mesh;
        let vol: f64 = (0..m.tets.len()).map(|t| m.signed_volume(t)).sum();
        // Volume of the polyhedron (the icosphere is slightly inside the sphere).
        let poly = crate::mesh::enclosed_volume(&v, &f);
        assert!((vol - poly).abs() < 0.03 * poly, "{vol} vs {poly}");
        let (lo, hi) = stuffing::dihedral_range(&m);
        assert!(
            lo > stuffing::MIN_DIHEDRAL_DEG && hi < stuffing::MAX_DIHEDRAL_DEG,
            "{lo}..{hi}"
        );
    }

    #[test]
    fn inward_orientation_is_accepted() {
        let (v, mut f) = icosphere(Point3::origin(), 0.03, 1);
        for t in &mut f {
            t.swap(1, 2);
        }
        let m = mesh_surface(
            &v,
            &f,
            &SurfaceMeshing {
                spacing: 0.01,
                levels: 0,
                rate: 0.0,
            },
        )
        .expect("meshes");
        assert!(!m.mesh.tets.is_empty());
        assert!(m.inside_out);
    }

    /// Two spheres (r = 20 mm) 1.5 mm apart, meshed at 3 mm: closer than
    /// the lattice resolves, so the stuffed mesh's boundary is pinched at
    /// edges between them (the defect the folds of a cortex surface show).
    /// The result's boundary is a closed manifold, the repair says where and
    /// how much it removed (well under 1% of the volume), the tetrahedra keep
    /// the proven angles, and the volume is the two spheres' within the
    /// discretisation error.
    #[test]
    fn surfaces_closer_than_the_spacing_mesh_to_a_closed_manifold() {
        let r = 0.02;
        let (v1, f1) = icosphere(Point3::origin(), r, 3);
        let (v, f) = join_surfaces(
            (v1, f1),
            icosphere(Point3::new(2.0 * r + 0.0015, 0.0013, 0.0007), r, 3),
        );
        let params = SurfaceMeshing {
            spacing: 0.003,
            levels: 1,
            rate: 0.5,
        };
        // The mesher's own output is pinched.
        let field = SurfaceField::new(&v, &f);
        let (lo, hi) = field.bounds();
        let raw = stuffing::stuff_proven(
            &field,
            &Lattice {
                spacing: params.spacing,
                levels: params.levels,
                anchor: lo,
                bounds: Aabb { lo, hi },
            },
            &SurfaceGrading {
                fine: params.spacing,
                band: params.spacing,
                rate: params.rate,
            },
        )
        .unwrap();
        assert!(manifold::check_closed_manifold(&raw).is_err());

        let m = mesh_surface(&v, &f, &params).unwrap();
        assert_eq!(manifold::check_closed_manifold(&m.mesh), Ok(()));
        assert_eq!(
            crate::mesh::validate::validate_mesh(&m.mesh, &Default::default()),
            vec![]
        );
        let rep = &m.repair;
        assert!(rep.pinched_edges > 0 && rep.removed_tets > 0, "{rep:?}");
        assert!(rep.removed_volume_m3 < 0.01 * rep.volume_m3, "{rep}");
        let [x, _, _] = rep.first_at_m.unwrap();
        assert!((x - (r + 0.00075)).abs() < 0.003, "first pinch at x = {x}");
        assert_eq!(m.mesh.tets.len(), raw.tets.len() - rep.removed_tets);
        let (lo, hi) = stuffing::dihedral_range(&m.mesh);
        assert!(
            lo >= stuffing::PROVEN_MIN_DIHEDRAL_DEG && hi <= stuffing::PROVEN_MAX_DIHEDRAL_DEG,
            "{lo}..{hi}"
        );
        let vol: f64 = (0..m.mesh.tets.len())
            .map(|t| m.mesh.signed_volume(t))
            .sum();
        let spheres = 2.0 * 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
        assert!((vol / spheres - 1.0).abs() < 0.05, "{vol} vs {spheres}");
        assert!(!m.inside_out);
    }

    /// A surface in millimetres is refused before any lattice is built, with
    /// the unit and the scale named.
    #[test]
    fn a_surface_in_millimetres_is_refused_naming_the_unit() {
        let (v, f) = icosphere(Point3::origin(), 70.0, 2);
        let params = SurfaceMeshing {
            spacing: 0.003,
            levels: 2,
            rate: 0.5,
        };
        match mesh_surface(&v, &f, &params) {
            Err(ClosedSurfaceError::Units(e)) => {
                assert_eq!((e.unit, e.scale), ("millimetres", 1e-3));
                assert!((e.extent_m - 140.0).abs() < 1.0, "{e}");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn open_surface_is_rejected() {
        let (v, mut f) = icosphere(Point3::origin(), 0.03, 1);
        let removed = f.remove(7);
        let err = check_closed_surface(&v, &f).unwrap_err();
        match err {
            ClosedSurfaceError::OpenEdge { a, b, .. } => {
                assert!(
                    removed.contains(&a) && removed.contains(&b),
                    "{a} {b} not in {removed:?}"
                );
            }
            e => panic!("wrong error {e}"),
        }
    }

    #[test]
    fn flipped_triangle_is_rejected() {
        let (v, mut f) = icosphere(Point3::origin(), 0.03, 1);
        f[3].swap(0, 1);
        assert!(matches!(
            check_closed_surface(&v, &f),
            Err(ClosedSurfaceError::InconsistentOrientation { .. })
        ));
    }

    #[test]
    fn self_intersection_is_rejected_and_named() {
        // Two closed spheres overlapping: each is closed and manifold, together
        // they intersect.
        let (v1, f1) = icosphere(Point3::origin(), 0.03, 1);
        let (n, f1_len) = (v1.len() as u32, f1.len());
        let (v, f) = join_surfaces((v1, f1), icosphere(Point3::new(0.02, 0.0, 0.0), 0.03, 1));
        match check_closed_surface(&v, &f) {
            Err(ClosedSurfaceError::SelfIntersection { first, second }) => {
                assert!(first < f1_len && second >= f1_len, "{first} {second}");
            }
            other => panic!("wrong result {other:?}"),
        }
        // Disjoint spheres are fine.
        let (v2, _) = icosphere(Point3::new(0.1, 0.0, 0.0), 0.03, 1);
        let v: Vec<_> = v[..n as usize].iter().copied().chain(v2).collect();
        assert!(check_closed_surface(&v, &f).is_ok());
    }

    #[test]
    fn degenerate_and_bad_indices_are_rejected() {
        let (mut v, mut f) = icosphere(Point3::origin(), 0.03, 1);
        f[0][1] = 999;
        assert!(matches!(
            check_closed_surface(&v, &f),
            Err(ClosedSurfaceError::Values(
                fissure_shared::surface::SurfaceError::VertexOutOfRange {
                    triangle: 0,
                    vertex: 999,
                    ..
                }
            ))
        ));
        f[0][1] = f[0][0];
        assert!(matches!(
            check_closed_surface(&v, &f),
            Err(ClosedSurfaceError::DegenerateTriangle { triangle: 0 })
        ));
        v[2].x = f64::NAN;
        assert!(matches!(
            check_closed_surface(&v, &f),
            Err(ClosedSurfaceError::Values(
                fissure_shared::surface::SurfaceError::NonFinite { vertex: 2 }
            ))
        ));
        assert!(matches!(
            check_closed_surface(&v, &[]),
            Err(ClosedSurfaceError::Empty)
        ));
    }

    #[test]
    fn pinched_vertex_is_rejected() {
        // Two tetrahedra surfaces sharing one vertex (index 0).
        let v = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(0.0, 0.0, 1.0),
            Point3::new(-1.0, 0.0, 0.0),
            Point3::new(0.0, -1.0, 0.0),
            Point3::new(0.0, 0.0, -1.0),
        ];
        let tet = |a: u32, b: u32, c: u32, d: u32| vec![[a, c, b], [a, b, d], [a, d, c], [b, c, d]];
        let mut f = tet(0, 1, 2, 3);
        f.extend(tet(0, 4, 5, 6));
        assert!(matches!(
            check_closed_surface(&v, &f),
            Err(ClosedSurfaceError::NonManifoldVertex { vertex: 0, fans: 2 })
        ));
    }

    /// Whether the scaled point `p` (coordinates times `S`) lies in the
    /// closed 2D triangle `t` (integer coordinates), exactly.
    fn in_closed(p: [i64; 2], t: &[[i64; 2]; 3]) -> bool {
        const S: i64 = 48;
        let c = |o: [i64; 2], a: [i64; 2]| {
            let (ox, oy) = (o[0] * S, o[1] * S);
            let (ax, ay) = (a[0] * S, a[1] * S);
            (ax - ox) * (p[1] - oy) - (ay - oy) * (p[0] - ox)
        };
        let s = [c(t[0], t[1]), c(t[1], t[2]), c(t[2], t[0])];
        s.iter().all(|&k| k >= 0) || s.iter().all(|&k| k <= 0)
    }

    /// Reference overlap of two coplanar triangles beyond what they share:
    /// a point of one (barycentric samples at steps of 1/48, edges and
    /// vertices included) other than a shared vertex or a point of a shared
    /// edge, inside the other, closed. Finds every overlap of positive area
    /// wider than the sampling, every overlapping collinear edge and every
    /// vertex touching the other triangle.
    fn reference_overlap(a: &[[i64; 2]; 3], b: &[[i64; 2]; 3], shared: &[[i64; 2]]) -> bool {
        const S: i64 = 48;
        let on_shared = |p: [i64; 2]| match shared {
            [v] => p == [v[0] * S, v[1] * S],
            [v, w] => {
                let (v, w) = ([v[0] * S, v[1] * S], [w[0] * S, w[1] * S]);
                let cross = (w[0] - v[0]) * (p[1] - v[1]) - (w[1] - v[1]) * (p[0] - v[0]);
                let dot = (p[0] - v[0]) * (w[0] - v[0]) + (p[1] - v[1]) * (w[1] - v[1]);
                let len2 = (w[0] - v[0]).pow(2) + (w[1] - v[1]).pow(2);
                cross == 0 && (0..=len2).contains(&dot)
            }
            _ => false,
        };
        let samples = |t: &[[i64; 2]; 3]| {
            let t = *t;
            (0..=S).flat_map(move |i| {
                (0..=S - i).map(move |j| {
                    let k = S - i - j;
                    [
                        i * t[0][0] + j * t[1][0] + k * t[2][0],
                        i * t[0][1] + j * t[1][1] + k * t[2][1],
                    ]
                })
            })
        };
        samples(b).any(|p| !on_shared(p) && in_closed(p, a))
            || samples(a).any(|p| !on_shared(p) && in_closed(p, b))
    }

    #[test]
    fn coplanar_overlaps_are_found_whatever_the_triangles_share() {
        // Random coplanar pairs on a small integer grid of a tilted plane
        // (exact coordinates, so `orient` is exactly zero): sharing nothing,
        // one vertex or one edge. Every overlap the exact reference sees
        // must be reported, and no other (pairs that only share their common
        // vertex or edge, side by side, are not intersections).
        let embed = |p: [i64; 2]| {
            let (x, y) = (p[0] as f64, p[1] as f64);
            Point3::new(x, y, x + 2.0 * y)
        };
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = |n: i64| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % n as u64) as i64
        };
        let area2 = |t: &[[i64; 2]; 3]| {
            (t[1][0] - t[0][0]) * (t[2][1] - t[0][1]) - (t[1][1] - t[0][1]) * (t[2][0] - t[0][0])
        };
        let (mut overlapping, mut apart) = (0, 0);
        for case in 0..6000 {
            let mut pt = || [next(7), next(7)];
            let a = [pt(), pt(), pt()];
            let shared_n = case % 3;
            let mut b = [pt(), pt(), pt()];
            b[..shared_n].copy_from_slice(&a[..shared_n]);
            if area2(&a) == 0 || area2(&b) == 0 {
                continue;
            }
            // Distinct positions except the shared ones (a repeated position
            // under another index is a different defect).
            if (shared_n..3).any(|k| a.contains(&b[k])) {
                continue;
            }
            // Indices: shared corners share indices, in scrambled order.
            let ia = [0u32, 1, 2];
            let mut ib = [3u32, 4, 5];
            ib[..shared_n].copy_from_slice(&ia[..shared_n]);
            let rot = next(3) as usize;
            let (pb, ib) = (
                [b[rot], b[(rot + 1) % 3], b[(rot + 2) % 3]],
                [ib[rot], ib[(rot + 1) % 3], ib[(rot + 2) % 3]],
            );
            let pa3 = a.map(embed);
            let pb3 = pb.map(embed);
            let got = triangles_intersect(ia, ib, &pa3, &pb3);
            let want = reference_overlap(&a, &b, &a[..shared_n]);
            if want {
                overlapping += 1;
                assert!(
                    got,
                    "case {case}: missed overlap a {a:?} b {b:?} sharing {shared_n}"
                );
            } else {
                apart += 1;
                assert!(
                    !got,
                    "case {case}: overlap reported for a {a:?} b {b:?} sharing {shared_n}"
                );
            }
        }
        assert!(overlapping > 500 && apart > 500, "{overlapping} {apart}");
    }
}
