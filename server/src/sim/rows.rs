//! The rows of the contact problem from the collision stage's output
//! (DESIGN.md section 3b): one stage between `collide` and `fem`.
//!
//! * **Frictionless / Coulomb** (the Signorini rule): each candidate
//!   (vertex `i` of volume node `v`, face normal `n`, face point `p`) gives a
//!   unilateral row along `n` with the free gap `g_free = n . (x_free_v - p)`,
//!   where `x_free` is where the node would be with the contact forces
//!   removed (its rest position for linear strategies, [`FreePositions`]):
//!   the gap is then exact for any displacement the forces cause,
//!   `g = g_free + n . u_v`, so a vertex stays in contact while the tissue
//!   pushes, whatever the deformed surface looked like. With friction two
//!   tangent rows follow (an orthonormal pair `t1, t2` perpendicular to `n`)
//!   whose gap is the slip from the contact's anchor `a` (the point of the
//!   plate the vertex stuck to, kept in the instrument frame, [`Anchors`]):
//!   `g_t = t . (x_free_v - a) + t . u_v`. A new contact's anchor is its
//!   face point.
//! * **Paper**: each enforced displacement `U` of node `v` gives three
//!   bilateral rows along the axes with `g = u_a - U_a`.
//!
//! Rows on fixed nodes are dropped (a fixed node stays fixed). Every row
//! has a key (node, owner, face, component) that names it from one sample
//! to the next.

use crate::collide::contact::{Candidate, EdgeCandidate, Enforced};
use crate::collide::faces::FaceId;
pub use crate::fem::{ContactRow, RowKind};
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::HashMap;

/// The owner of the skull's rows.
pub const SKULL_OWNER: u16 = u16::MAX - 1;

/// One row of the contact problem with its identity and contact point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Row {
    /// Identity across samples ([`key`]).
    pub key: u64,
    /// Instrument index, or [`SKULL_OWNER`].
    pub owner: u16,
    /// The solver's row. A tangent row's `normal` is the index of its
    /// normal row within the same row list.
    pub row: ContactRow,
    /// Where the force acts, scene frame, m (the face point).
    pub point: Point3<f64>,
    /// A point row's triangle: its three volume nodes and the weights of
    /// the tissue point (fixed nodes included, which the solver's row
    /// leaves out).
    pub triangle: ([u32; 3], [f64; 3]),
}

/// No triangle (rows on one node).
pub const NO_TRIANGLE: ([u32; 3], [f64; 3]) = ([u32::MAX; 3], [0.0; 3]);

/// The key of a row: node (or triangle), owner, face (0-4, 6 the paper's
/// rule, 7 the skull) and component (0 normal or x, 1 and 2 tangents or y
/// and z; `64 + feature` for a point row, [`EdgeCandidate::feature`]).
pub fn key(node: u32, owner: u16, face: u8, component: u32) -> u64 {
    ((node as u64) << 32)
        | ((owner as u64) << 16)
        | ((face as u64 & 0xf) << 12)
        | (component as u64 & 0xfff)
}

/// Where each volume node would be with the contact forces removed.
#[derive(Debug, Clone, Copy)]
pub enum FreePositions<'a> {
    /// Linear strategies: the rest positions, m.
    Rest(&'a [Point3<f64>]),
    /// Tangent models: positions of the nodes that have one, by volume node
    /// (`index[node]` into `positions`, `u32::MAX` for none; those fall back
    /// to `rest`).
    Tangent {
        rest: &'a [Point3<f64>],
        index: &'a [u32],
        positions: &'a [Point3<f64>],
    },
}

impl FreePositions<'_> {
    /// The free position of volume node `v`, m.
    pub fn of(&self, v: u32) -> Point3<f64> {
        match self {
            FreePositions::Rest(r) => r[v as usize],
            FreePositions::Tangent {
                rest,
                index,
                positions,
            } => match index.get(v as usize) {
                Some(&i) if i != u32::MAX => positions[i as usize],
                _ => rest[v as usize],
            },
        }
    }
}

/// The stick points of frictional contacts, in the instrument frame, by
/// (instrument, volume node).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Anchors(HashMap<(u16, u32), Point3<f64>>);

impl Anchors {
    /// The anchor of `node` on `instrument`, instrument frame.
    pub fn get(&self, instrument: u16, node: u32) -> Option<Point3<f64>> {
        self.0.get(&(instrument, node)).copied()
    }

    /// Sets an anchor.
    pub fn set(&mut self, instrument: u16, node: u32, at: Point3<f64>) {
        self.0.insert((instrument, node), at);
    }

    /// Keeps only the anchors `keep` says yes to.
    pub fn retain(&mut self, mut keep: impl FnMut(u16, u32) -> bool) {
        self.0.retain(|&(i, n), _| keep(i, n));
    }

    /// Number of anchors.
    pub fn len(&self) -> usize {
        self.0.len()
    }

    /// No anchors.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

/// An orthonormal tangent pair of unit `n` (deterministic: `t1` is
/// perpendicular to `n` and to the axis least aligned with it).
pub fn tangents(n: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let a = n.abs();
    let axis = if a.x <= a.y && a.x <= a.z {
        Vector3::x()
    } else if a.y <= a.z {
        Vector3::y()
    } else {
        Vector3::z()
    };
    let t1 = n.cross(&axis).normalize();
    (t1, n.cross(&t1))
}

/// Rows of the Signorini rule from `candidates` (module documentation):
/// `friction` is the Coulomb coefficient, `poses` the instruments' poses
/// (for the anchors), `fixed` the fixed volume nodes. Appends to `out`.
pub fn from_candidates(
    candidates: &[Candidate],
    free: &FreePositions<'_>,
    friction: Option<f64>,
    anchors: &Anchors,
    poses: &[Isometry3<f64>],
    fixed: &[bool],
    out: &mut Vec<Row>,
) {
    for c in candidates {
        if fixed.get(c.volume_node as usize).copied().unwrap_or(true) {
            continue;
        }
        let x = free.of(c.volume_node);
        let face = face_code(c.face);
        let normal_index = out.len() as u32;
        out.push(Row {
            key: key(c.volume_node, c.instrument, face, 0),
            owner: c.instrument,
            row: ContactRow::at_node(
                c.volume_node,
                c.normal,
                c.normal.dot(&(x - c.point)),
                RowKind::Unilateral,
            ),
            point: c.point,
            triangle: NO_TRIANGLE,
        });
        if let Some(mu) = friction {
            let anchor = anchors
                .get(c.instrument, c.volume_node)
                .and_then(|a| poses.get(c.instrument as usize).map(|p| p * a))
                .unwrap_or(c.point);
            let (t1, t2) = tangents(&c.normal);
            for (comp, t) in [(1u32, t1), (2u32, t2)] {
                out.push(Row {
                    key: key(c.volume_node, c.instrument, face, comp),
                    owner: c.instrument,
                    row: ContactRow::at_node(
                        c.volume_node,
                        t,
                        t.dot(&(x - anchor)),
                        RowKind::Tangent {
                            normal: normal_index,
                            mu,
                        },
                    ),
                    point: c.point,
                    triangle: NO_TRIANGLE,
                });
            }
        }
    }
}

/// Rows of the plate points that pierce triangles no face covers a vertex
/// of ([`EdgeCandidate`]): a unilateral row on the tissue point, shared out
/// over the triangle's nodes by its barycentric weights, with the free gap
/// `n . (sum_a w_a x_free_a - p)` (`p` the plate point). Fixed nodes drop
/// out of the row (they do not move). Frictionless (no tangent rows).
/// Appends to `out`.
pub fn from_edges(
    edges: &[EdgeCandidate],
    free: &FreePositions<'_>,
    fixed: &[bool],
    out: &mut Vec<Row>,
) {
    for e in edges {
        let mut x = nalgebra::Vector3::zeros();
        let mut nodes = [u32::MAX; 3];
        let mut weights = [0.0; 3];
        for a in 0..3 {
            x += free.of(e.nodes[a]).coords * e.weights[a];
            if !fixed.get(e.nodes[a] as usize).copied().unwrap_or(true) {
                nodes[a] = e.nodes[a];
                weights[a] = e.weights[a];
            }
        }
        if !weights.iter().any(|&w| w > 0.0) {
            continue;
        }
        out.push(Row {
            key: key(e.triangle, e.instrument, face_code(e.face), 64 + e.feature),
            owner: e.instrument,
            row: ContactRow::at_point(
                nodes,
                weights,
                e.normal,
                e.normal.dot(&(x - e.point.coords)),
                RowKind::Unilateral,
            ),
            point: e.point,
            triangle: (e.nodes, e.weights),
        });
    }
}

/// The point row half-way between `a` and `b`, two shapes' rows of one
/// polygon corner (same key): weights and face point averaged, the gap
/// recomputed at the free positions (fixed nodes left out as in
/// [`from_edges`]). The step relaxes its contact geometry's fixed point
/// with it (a corner's tissue point depends on the shape it pushes).
pub fn midway(a: &Row, b: &Row, free: &FreePositions<'_>, fixed: &[bool]) -> Row {
    let (tri, wa) = a.triangle;
    let wb = b.triangle.1;
    let w = [0.0, 1.0, 2.0].map(|k: f64| 0.5 * (wa[k as usize] + wb[k as usize]));
    let point = Point3::from(0.5 * (a.point.coords + b.point.coords));
    let mut x = Vector3::zeros();
    let mut nodes = [u32::MAX; 3];
    let mut weights = [0.0; 3];
    for k in 0..3 {
        x += free.of(tri[k]).coords * w[k];
        if !fixed.get(tri[k] as usize).copied().unwrap_or(true) {
            nodes[k] = tri[k];
            weights[k] = w[k];
        }
    }
    let dir = b.row.dir;
    Row {
        key: b.key,
        owner: b.owner,
        row: ContactRow::at_point(
            nodes,
            weights,
            dir,
            dir.dot(&(x - point.coords)),
            b.row.kind,
        ),
        point,
        triangle: (tri, w),
    }
}

/// The face index of a row's key (0-4 the plate's faces, 6 the paper's
/// rule, 7 the skull).
pub fn face_of_key(key: u64) -> u8 {
    ((key >> 12) & 0xf) as u8
}

/// Whether a row's key is a point row's (a pierced triangle).
pub fn is_point_key(key: u64) -> bool {
    key & 0xfff >= 64 && face_of_key(key) < 6
}

/// Rows of the paper's rule: three bilateral rows per enforced
/// displacement (`rest` the volume nodes' rest positions). Appends to `out`.
pub fn from_enforced(
    enforced: &[Enforced],
    rest: &[Point3<f64>],
    fixed: &[bool],
    out: &mut Vec<Row>,
) {
    for e in enforced {
        if fixed.get(e.volume_node as usize).copied().unwrap_or(true) {
            continue;
        }
        let point = rest[e.volume_node as usize] + e.displacement;
        for a in 0..3 {
            out.push(Row {
                key: key(e.volume_node, e.instrument, 6, a as u32),
                owner: e.instrument,
                row: ContactRow::at_node(
                    e.volume_node,
                    Vector3::ith(a, 1.0),
                    -e.displacement[a],
                    RowKind::Bilateral,
                ),
                point,
                triangle: NO_TRIANGLE,
            });
        }
    }
}

/// The face code of a key (0-4).
fn face_code(face: FaceId) -> u8 {
    face.index() as u8
}

/// The tissue `owner`'s face rows push (a positive multiplier), as
/// (face index, surface vertex) for [`crate::collide::History::set_seeds`]:
/// a node row's vertex, a point row's triangle's vertices (`triangles` the
/// surface's, `from_volume` volume node to surface vertex).
pub fn seeds_of<'a>(
    rows: &'a [Row],
    lambda: &'a [f64],
    owner: u16,
    triangles: &'a [[u32; 3]],
    from_volume: &'a [u32],
) -> impl Iterator<Item = (u8, u32)> + 'a {
    rows.iter()
        .zip(lambda)
        .filter(move |(r, l)| {
            r.owner == owner
                && **l > 0.0
                && r.row.kind == RowKind::Unilateral
                && face_of_key(r.key) < 5
        })
        .flat_map(move |(r, _)| {
            let face = face_of_key(r.key);
            let vs: [u32; 3] = if is_point_key(r.key) {
                triangles
                    .get((r.key >> 32) as usize)
                    .copied()
                    .unwrap_or([u32::MAX; 3])
            } else {
                [
                    from_volume
                        .get(r.row.node as usize)
                        .copied()
                        .unwrap_or(u32::MAX),
                    u32::MAX,
                    u32::MAX,
                ]
            };
            vs.into_iter()
                .filter(|&v| v != u32::MAX)
                .map(move |v| (face, v))
        })
}

/// Appends `src` to `dst`, shifting tangent rows' normal indices.
pub fn append(dst: &mut Vec<Row>, src: &[Row]) {
    let base = dst.len() as u32;
    dst.extend(src.iter().map(|r| {
        let mut r = *r;
        if let RowKind::Tangent { normal, mu } = r.row.kind {
            r.row.kind = RowKind::Tangent {
                normal: normal + base,
                mu,
            };
        }
        r
    }));
}

/// Appends the rows of `owner` from `src` to `dst` (a tangent row's
/// normal, always of the same owner and before it, is mapped to its new
/// place).
pub fn append_owner(dst: &mut Vec<Row>, src: &[Row], owner: u16) {
    let base = dst.len();
    let mut first_src = None;
    for (i, r) in src.iter().enumerate() {
        if r.owner != owner {
            continue;
        }
        let start = *first_src.get_or_insert(i);
        let mut r = *r;
        if let RowKind::Tangent { normal, mu } = r.row.kind {
            // Rows of one owner from the candidates are contiguous.
            let shift = normal as usize - start;
            r.row.kind = RowKind::Tangent {
                normal: (base + shift) as u32,
                mu,
            };
        }
        dst.push(r);
    }
}

/// Force and torque on `owner` (about `handle`, m) of the multipliers
/// `lambda` of `rows`: minus the forces the rows apply to the tissue.
pub fn owner_force(
    rows: &[Row],
    lambda: &[f64],
    owner: u16,
    handle: &Vector3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    let (mut f, mut t) = (Vector3::zeros(), Vector3::zeros());
    for (r, &l) in rows.iter().zip(lambda) {
        if r.owner != owner || l == 0.0 {
            continue;
        }
        let on_plate = -r.row.dir * l;
        f += on_plate;
        t += (r.point.coords - handle).cross(&on_plate);
    }
    (f, t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tangents_are_orthonormal_and_deterministic() {
        for n in [
            Vector3::x(),
            -Vector3::z(),
            Vector3::new(0.3, -0.4, 0.866).normalize(),
        ] {
            let (t1, t2) = tangents(&n);
            assert!((t1.norm() - 1.0).abs() < 1e-15 && (t2.norm() - 1.0).abs() < 1e-15);
            assert!(t1.dot(&n).abs() < 1e-15 && t2.dot(&n).abs() < 1e-15);
            assert!(t1.dot(&t2).abs() < 1e-15);
            assert_eq!(tangents(&n), (t1, t2));
        }
    }

    #[test]
    fn keys_name_node_owner_face_and_component() {
        let k = key(123_456, 2, 3, 1);
        assert_eq!(k >> 32, 123_456);
        assert_eq!((k >> 16) & 0xffff, 2);
        assert_ne!(k, key(123_456, 2, 3, 2));
        assert_ne!(k, key(123_456, SKULL_OWNER, 3, 1));
    }
}
