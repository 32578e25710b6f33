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
//!   `g_t = t . (x_free_v - a) + t . u_v`. A new contact anchors where the
//!   last solve left its tissue point, carried with the plate since then
//!   (it moves with the plate as its neighbours do). A polygon point's
//!   tangent rows hold the tissue point it anchored (its weights kept in
//!   the [`Anchor`]), since the outline slides over the tissue.
//! * **Paper**: each enforced displacement `U` of node `v` gives three
//!   bilateral rows along the axes with `g = u_a - U_a`.
//!
//! Rows on fixed nodes are dropped (a fixed node stays fixed). Every row
//! has a key (node, owner, face, component) that names it from one sample
//! to the next.

use crate::collide::contact::{Candidate, EdgeCandidate, Enforced};
use crate::collide::tool::faces::FaceId;
pub use crate::fem::{ContactRow, RowKind};
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::HashMap;

/// The owner of the skull's rows.
pub const SKULL_OWNER: u16 = u16::MAX - 1;

/// The owner of the ties' rows ([`crate::fem::ties`]); a tie row's key
/// names its pair's first tie.
pub const TIE_OWNER: u16 = u16::MAX - 2;

/// One row of the contact problem with its identity and contact point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Row {
    /// Identity across samples ([`key`]).
    pub key: u64,
    /// Instrument index, [`SKULL_OWNER`] or [`TIE_OWNER`].
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
    /// The rest positions, by volume node, m.
    pub fn rest(&self) -> &[Point3<f64>] {
        match self {
            FreePositions::Rest(r) => r,
            FreePositions::Tangent { rest, .. } => rest,
        }
    }

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

/// Rows written on the rest positions (`g = g_free + dir . u`, `u` the
/// displacement from rest) rewritten for a tangent patch, whose unknown is
/// the motion from the free positions (`x = free + C f`): a point row on
/// its heaviest node, as the nonlinear strategies' steps take it (see
/// [`crate::fem::contact`]), so that a sample and a step solve one
/// problem; and every gap shifted by `dir . (free - rest)` of that node
/// (nothing for a node the patch lacks: its free position is its rest
/// one). Frictionless rows only (friction needs a linear strategy).
pub fn to_tangent(rows: &mut [Row], free: &FreePositions<'_>) {
    for r in rows {
        let n = r.row.node;
        let shift = r.row.dir.dot(&(free.of(n) - free.rest()[n as usize]));
        r.row = ContactRow::at_node(n, r.row.dir, r.row.gap_free_m + shift, r.row.kind);
    }
}

/// Where a frictional contact sticks: the point of the instrument the tissue
/// point stuck to (instrument frame, m), and which tissue point (barycentric
/// weights on the row's triangle; `[1, 0, 0]` for a vertex's row).
///
/// A point row's tissue point is where the face's outline crosses a
/// triangle, and it moves over the tissue as the plate moves; its tangent
/// rows hold the anchored tissue point instead (the weights kept here), so
/// a sticking contact drags the same tissue along.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Anchor {
    /// Instrument frame, m.
    pub at: Point3<f64>,
    /// Of the tissue point on the row's triangle (a vertex: `[1, 0, 0]`).
    pub weights: [f64; 3],
}

/// The stick points of frictional contacts, by the key of their normal row,
/// and the instruments' poses of the solve that set them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Anchors {
    by_key: HashMap<u64, Anchor>,
    poses: Vec<Isometry3<f64>>,
}

impl Anchors {
    /// The anchor of the contact whose normal row has key `key`.
    pub fn get(&self, key: u64) -> Option<Anchor> {
        self.by_key.get(&key).copied()
    }

    /// Sets an anchor.
    pub fn set(&mut self, key: u64, anchor: Anchor) {
        self.by_key.insert(key, anchor);
    }

    /// Keeps only the anchors whose key `keep` says yes to.
    pub fn retain(&mut self, mut keep: impl FnMut(u64) -> bool) {
        self.by_key.retain(|&k, _| keep(k));
    }

    /// Records the instruments' poses of the solve that set the anchors.
    pub fn set_poses(&mut self, poses: &[Isometry3<f64>]) {
        self.poses.clear();
        self.poses.extend_from_slice(poses);
    }

    /// Where a tissue point `x` (scene frame, m) at the anchoring solve is
    /// once instrument `instrument` has moved from that solve's pose to
    /// `pose`, carried rigidly with it (`x` itself before any solve).
    pub fn carried(&self, instrument: u16, x: Point3<f64>, pose: &Isometry3<f64>) -> Point3<f64> {
        match self.poses.get(instrument as usize) {
            Some(then) => pose * (then.inverse() * x),
            None => x,
        }
    }

    /// Number of anchors.
    pub fn len(&self) -> usize {
        self.by_key.len()
    }

    /// No anchors.
    pub fn is_empty(&self) -> bool {
        self.by_key.is_empty()
    }
}

/// The key of tangent row `component` (1 or 2) of a point row of key
/// `normal_key` (bits 62-63; a triangle index stays below 2^30).
pub fn tangent_key(normal_key: u64, component: u32) -> u64 {
    normal_key | (u64::from(component & 3) << 62)
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

/// Where a new frictional contact of `instrument` at pose `pose` anchors:
/// the tissue point `x_now` where the last solve left it (m), carried with
/// the instrument since that solve ([`Anchors::carried`]: the contact is
/// taken to have touched then), on the face's plane through `p` with unit
/// normal `n`. Sticking from there moves the tissue with the plate, as its
/// neighbours that were already in contact; anchoring where the tissue is
/// would hold it still against the plate's motion (a friction opposite to
/// theirs).
fn touch_point(
    anchors: &Anchors,
    instrument: u16,
    pose: Option<&Isometry3<f64>>,
    x_now: Point3<f64>,
    n: &Vector3<f64>,
    p: &Point3<f64>,
) -> Point3<f64> {
    let x = pose.map_or(x_now, |pose| anchors.carried(instrument, x_now, pose));
    x - n * n.dot(&(x - p))
}

/// A triangle point of weights `w` on volume nodes `nodes`: its free
/// position (m), and the row's nodes and weights with the fixed nodes left
/// out (they do not move).
fn point_on(
    free: &FreePositions<'_>,
    fixed: &[bool],
    nodes: &[u32; 3],
    w: &[f64; 3],
) -> (Vector3<f64>, [u32; 3], [f64; 3]) {
    let mut x = Vector3::zeros();
    let mut kept = [u32::MAX; 3];
    let mut weights = [0.0; 3];
    for a in 0..3 {
        x += free.of(nodes[a]).coords * w[a];
        if !fixed.get(nodes[a] as usize).copied().unwrap_or(true) {
            kept[a] = nodes[a];
            weights[a] = w[a];
        }
    }
    (x, kept, weights)
}

/// Where the tissue point of weights `w` on volume nodes `nodes` is after
/// a solve with displacements `u` (m; a node past the end of `u`, or
/// `u32::MAX` with weight 0, does not move it): `sum_a w_a (x_rest_a + u_a)`.
pub fn tissue_point(
    rest: &[Point3<f64>],
    u: &[Vector3<f64>],
    nodes: &[u32; 3],
    w: &[f64; 3],
) -> Point3<f64> {
    let x =
        nodes
            .iter()
            .zip(w)
            .filter(|&(_, &wa)| wa != 0.0)
            .fold(Vector3::zeros(), |x, (&n, &wa)| {
                let n = n as usize;
                x + (rest[n].coords + u.get(n).copied().unwrap_or_default()) * wa
            });
    Point3::from(x)
}

/// What the Signorini rule's rows are built from besides the collision
/// output.
#[derive(Debug, Clone, Copy)]
pub struct RowInputs<'a> {
    /// Where the nodes would be without the contact forces.
    pub free: FreePositions<'a>,
    /// The displacements of the last solve, by volume node, m (where a new
    /// frictional contact anchors).
    pub now: &'a [Vector3<f64>],
    /// The Coulomb coefficient (`None`: frictionless).
    pub friction: Option<f64>,
    /// The frictional anchors.
    pub anchors: &'a Anchors,
    /// The instruments' poses.
    pub poses: &'a [Isometry3<f64>],
    /// The fixed volume nodes.
    pub fixed: &'a [bool],
}

/// Rows of the Signorini rule from `candidates` (module documentation).
/// Appends to `out`.
pub fn from_candidates(candidates: &[Candidate], inputs: &RowInputs<'_>, out: &mut Vec<Row>) {
    for c in candidates {
        if inputs
            .fixed
            .get(c.volume_node as usize)
            .copied()
            .unwrap_or(true)
        {
            continue;
        }
        let x = inputs.free.of(c.volume_node);
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
        if let Some(mu) = inputs.friction {
            let anchor = inputs
                .anchors
                .get(key(c.volume_node, c.instrument, face, 0))
                .and_then(|a| inputs.poses.get(c.instrument as usize).map(|p| p * a.at))
                .unwrap_or_else(|| {
                    let x_now = tissue_point(
                        inputs.free.rest(),
                        inputs.now,
                        &[c.volume_node, u32::MAX, u32::MAX],
                        &[1.0, 0.0, 0.0],
                    );
                    touch_point(
                        inputs.anchors,
                        c.instrument,
                        inputs.poses.get(c.instrument as usize),
                        x_now,
                        &c.normal,
                        &c.point,
                    )
                });
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
/// out of the row (they do not move). With friction, two tangent rows on
/// the anchored tissue point ([`Anchor`]; a new contact anchors the row's
/// own tissue point where the last solve left it), gap `t . (sum_a w0_a
/// x_free_a - pose * anchor)`. Appends to `out`.
pub fn from_edges(edges: &[EdgeCandidate], inputs: &RowInputs<'_>, out: &mut Vec<Row>) {
    let on = |nodes: &[u32; 3], w: &[f64; 3]| point_on(&inputs.free, inputs.fixed, nodes, w);
    for e in edges {
        let (x, nodes, weights) = on(&e.nodes, &e.weights);
        if !weights.iter().any(|&w| w > 0.0) {
            continue;
        }
        let normal_key = key(e.triangle, e.instrument, face_code(e.face), 64 + e.feature);
        let normal_index = out.len() as u32;
        out.push(Row {
            key: normal_key,
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
        let Some(mu) = inputs.friction else {
            continue;
        };
        let (w0, anchor) = inputs
            .anchors
            .get(normal_key)
            .and_then(|a| {
                inputs
                    .poses
                    .get(e.instrument as usize)
                    .map(|p| (a.weights, p * a.at))
            })
            .unwrap_or_else(|| {
                let x_now = tissue_point(inputs.free.rest(), inputs.now, &e.nodes, &e.weights);
                (
                    e.weights,
                    touch_point(
                        inputs.anchors,
                        e.instrument,
                        inputs.poses.get(e.instrument as usize),
                        x_now,
                        &e.normal,
                        &e.point,
                    ),
                )
            });
        let (x0, nodes0, weights0) = on(&e.nodes, &w0);
        if !weights0.iter().any(|&w| w > 0.0) {
            continue;
        }
        let (t1, t2) = tangents(&e.normal);
        for (comp, t) in [(1u32, t1), (2u32, t2)] {
            out.push(Row {
                key: tangent_key(normal_key, comp),
                owner: e.instrument,
                row: ContactRow::at_point(
                    nodes0,
                    weights0,
                    t,
                    t.dot(&(x0 - anchor.coords)),
                    RowKind::Tangent {
                        normal: normal_index,
                        mu,
                    },
                ),
                point: e.point,
                triangle: (e.nodes, w0),
            });
        }
    }
}

/// The point row a share `omega` of the way from `a` to `b` (`0`: `a`,
/// `1`: `b`), two shapes' rows of one polygon corner (same key): weights
/// and face point interpolated, the gap recomputed at the free positions
/// (fixed nodes left out as in [`from_edges`]). The step relaxes its
/// contact geometry's fixed point with it (a corner's tissue point depends
/// on the shape it pushes; [`super::engine::relax`]).
pub fn toward(a: &Row, b: &Row, omega: f64, free: &FreePositions<'_>, fixed: &[bool]) -> Row {
    let (tri, wa) = a.triangle;
    let wb = b.triangle.1;
    let w = [0, 1, 2].map(|k| wa[k] + omega * (wb[k] - wa[k]));
    let point = a.point + omega * (b.point - a.point);
    let (x, nodes, weights) = point_on(free, fixed, &tri, &w);
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

    /// A row on the rest positions, rewritten for a tangent patch, gives
    /// the same gap at the same position: `g_free + dir . u` with `u` from
    /// rest equals the new `g_free + dir . (x - free)`; a point row goes to
    /// its heaviest node; a node without a free position keeps its gap.
    #[test]
    fn rows_rewritten_for_a_tangent_patch_keep_their_gaps() {
        let rest = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.01, 0.0, 0.0),
            Point3::new(0.0, 0.01, 0.0),
        ];
        let free_pos = [
            Point3::new(0.0, 0.0, -0.002),
            Point3::new(0.011, 0.0, -0.001),
        ];
        let index = [0u32, 1, u32::MAX];
        let free = FreePositions::Tangent {
            rest: &rest,
            index: &index,
            positions: &free_pos,
        };
        let dir = Vector3::new(0.0, 0.6, 0.8);
        let row = |row| Row {
            key: 0,
            owner: 0,
            row,
            point: Point3::origin(),
            triangle: NO_TRIANGLE,
        };
        let mut rows = vec![
            row(ContactRow::at_node(0, dir, 1e-3, RowKind::Unilateral)),
            row(ContactRow::at_point(
                [2, 1, 0],
                [0.2, 0.5, 0.3],
                dir,
                -5e-4,
                RowKind::Unilateral,
            )),
            row(ContactRow::at_node(2, dir, 2e-4, RowKind::Bilateral)),
        ];
        to_tangent(&mut rows, &free);
        // Node 0 at its free position: u = free - rest, x - free = 0.
        let g = 1e-3 + dir.dot(&(free_pos[0] - rest[0]));
        assert!((rows[0].row.gap_free_m - g).abs() < 1e-18);
        // The point row is now on node 1, shifted by its free motion.
        assert!(!rows[1].row.is_point());
        assert_eq!(rows[1].row.node, 1);
        assert_eq!(rows[1].row.kind, RowKind::Unilateral);
        let g = -5e-4 + dir.dot(&(free_pos[1] - rest[1]));
        assert!((rows[1].row.gap_free_m - g).abs() < 1e-18);
        // Node 2 has no free position: its gap is unchanged.
        assert_eq!(rows[2].row.gap_free_m, 2e-4);
        assert_eq!(rows[2].row.kind, RowKind::Bilateral);
    }

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
