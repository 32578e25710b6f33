//! Stage 5 of the pipeline ([`super`], the contact module) with the Signorini rule:
//! the candidates of the contact problem (DESIGN.md section 3b).
//!
//! The pairs decide which face a patch of tissue belongs to (after the
//! culling); the candidates are the vertices that face may push. Per
//! instrument and face, the vertices of the face's paired triangles (and of
//! the triangles its nodes see in front within [`DetectOptions::ahead_m`])
//! seed a breadth-first walk over the surface's vertex neighbours. A
//! vertex `x` reached is projected onto the face ([`Plate::project`],
//! instrument frame): it is
//!
//! * a **candidate** when the face covers it (outside the outline by at most
//!   [`DetectOptions::cover_tolerance_m`]) and its gap `n . (x - p)` is at
//!   most [`DetectOptions::band_m`] (and no deeper than the face's reach),
//!   with the face normal `n` and point `p` in the scene frame; a vertex
//!   beyond the face's outline is a candidate of a rim face (a side strip or
//!   the tip) that covers it the same way, within the plate's thickness (or
//!   the rim nodes' reach) behind it: the plate's edges push too, whether
//!   or not the instrument has rim nodes. A rim face claims a vertex deeper
//!   than the entry depth ([`super::types::entry_depth_m`]: what the
//!   plate travels in a step) behind it only where it pushed it last time:
//!   deeper tissue came in through a large face, and the rim would push it
//!   out across the plate's width;
//! * **nearby** otherwise, when within [`DetectOptions::ahead_m`] of the
//!   face's box (in front of it, or beside its outline): its compliance is
//!   wanted soon.
//!
//! The walk goes on from every vertex within the box whose normal (the
//! area-weighted normal of its triangles at the current positions) faces
//! the face (`n_v . n < 0`), so it fills the covered patch between the
//! source-node rays and never crosses to tissue that faces away (the other
//! wall of a fissure). Of two candidates of one vertex whose normals lie
//! within 5 degrees of each other, parallel or opposed (two plates pushing
//! one vertex the same way, or pinching it), the one with the smaller gap
//! stays: the contact problem then never holds a vertex twice along one
//! direction.
//!
//! [`Plate::project`]: crate::collide::tool::instrument::Plate::project

use super::types::{Candidate, ContactOutput, ContactQuery, DetectOptions, EdgeCandidate, Nearby};
use super::workspace::{Tool, Topology, Workspace};
use crate::collide::tool::faces::FaceId;
use crate::mesh::adjacency::{Csr, surface_vertex_neighbours};
use nalgebra::Vector3;

/// The rim faces.
const RIM: [FaceId; 3] = [FaceId::SidePlusY, FaceId::SideMinusY, FaceId::Tip];

/// How far behind both large faces (a share of the plate's thickness) a
/// vertex must lie to be a rim face's candidate.
const RIM_MARGIN: f64 = 0.05;

/// `cos(5 degrees)`: candidates of one vertex with normals closer than this
/// to parallel or opposed are one claim too many.
const PARALLEL_COS: f64 = 0.996_194_698_091_745_5;

/// `out.candidates` and `out.nearby` from `out.pairs` and the front hits.
pub(crate) fn candidates(
    query: &ContactQuery<'_>,
    tools: &[Tool<'_>],
    opts: &DetectOptions,
    ws: &mut Workspace,
    out: &mut ContactOutput,
) {
    let nv = query.positions.len();
    ensure_topology(ws, query.triangles, nv);
    if ws.visit.len() != nv {
        ws.visit.clear();
        ws.visit.resize(nv, 0);
        ws.visit_stamp = 0;
    }
    let band = opts.front_band();
    let ahead = if opts.ahead_m.is_finite() {
        opts.ahead_m.max(band)
    } else {
        band
    };
    let tol = if opts.cover_tolerance_m.is_finite() {
        opts.cover_tolerance_m.max(0.0)
    } else {
        0.0
    };
    let topo = ws.topology.take().expect("built above");
    for (k, tool) in tools.iter().enumerate() {
        let inst = tool.instrument;
        let inv = tool.pose.inverse();
        let first = ws.offsets[k];
        let entry = super::types::entry_depth_m(band, inst.plate.thickness);
        // How deep behind a rim face a vertex may lie and still be its
        // candidate: its nodes' reach, at least the plate's thickness.
        // And each face's deepest node reach (none: the face has no nodes).
        let mut rim_reach = [inst.plate.thickness; 5];
        let mut face_reach = [f64::NEG_INFINITY; 5];
        for n in &inst.nodes {
            let f = FaceId::of(n.kind).index();
            rim_reach[f] = rim_reach[f].max(n.reach);
            face_reach[f] = face_reach[f].max(n.reach);
        }
        for face in FaceId::ALL {
            let reach = face_reach[face.index()];
            if reach == f64::NEG_INFINITY {
                continue;
            }
            next_visit(ws);
            let stamp = ws.visit_stamp;
            ws.queue.clear();
            let seed = |ws: &mut Workspace, triangle: u32| {
                for v in query.triangles[triangle as usize] {
                    if ws.visit[v as usize] != stamp {
                        ws.visit[v as usize] = stamp;
                        ws.queue.push(v);
                    }
                }
            };
            for pi in 0..out.pairs.len() {
                let p = out.pairs[pi];
                if p.instrument as usize != k {
                    continue;
                }
                if FaceId::of(inst.nodes[p.node as usize].kind) == face {
                    seed(ws, p.triangle);
                }
            }
            // Tissue the last contact solve found this face pushing.
            for v in tool.history.seeds_of(face.index() as u8) {
                if (v as usize) < nv && ws.visit[v as usize] != stamp {
                    ws.visit[v as usize] = stamp;
                    ws.queue.push(v);
                }
            }
            // Tissue seen in front beyond the band, within `ahead`.
            for (i, node) in inst.nodes.iter().enumerate() {
                if FaceId::of(node.kind) != face {
                    continue;
                }
                let Some(h) = ws.hits[first + i].front else {
                    continue;
                };
                if h.t > band && h.t <= ahead {
                    let [a, b, c] =
                        query.triangles[h.triangle as usize].map(|v| query.positions[v as usize]);
                    if ws.dirs[first + i].dot(&(b - a).cross(&(c - a))) < 0.0 {
                        seed(ws, h.triangle);
                    }
                }
            }
            let seeds = ws.queue.len();
            let mut head = 0;
            while head < ws.queue.len() {
                let v = ws.queue[head];
                let is_seed = head < seeds;
                head += 1;
                let x = inv * query.positions[v as usize];
                let fp = inst.plate.project(face, &x);
                if !(fp.outside_m <= ahead && fp.gap_m <= ahead && fp.gap_m >= -reach) {
                    continue;
                }
                let normal = tool.pose.rotation * fp.normal;
                let faces_it = vertex_normal(query, &topo.triangles, v).dot(&normal) < 0.0;
                // A seed (its triangle was paired) that does not face the
                // face by its vertex normal (a crease between two walls)
                // is still pushed; on the rest shape only where one of its
                // triangles faces the face.
                let claimable = faces_it
                    || (is_seed
                        && (!opts.facing_only
                            || topo
                                .triangles
                                .row(v as usize)
                                .iter()
                                .any(|&t| facing(query, t, &normal))));
                if !claimable {
                    continue;
                }
                // The face itself, or else a rim face (the plate's edges
                // push what lies beyond the face's outline; tissue under
                // the outline between covered vertices is pushed at the
                // polygon points of [`edges`]).
                // A rim face (a side strip, the tip) meets tissue by moving
                // sideways or forwards, at most the entry depth a step: a
                // vertex deeper behind it that it did not push last time
                // came in through a large face, and the rim would push it
                // across the plate's width.
                let rim_meets =
                    |r: FaceId, gap: f64| gap >= -entry || tool.history.is_seed(r.index() as u8, v);
                let mut covered = (fp.outside_m <= tol
                    && fp.gap_m <= band
                    && (matches!(face, FaceId::A | FaceId::B) || rim_meets(face, fp.gap_m)))
                .then_some((face, fp));
                if let (Some(solved), Some((f, p))) = (query.solved, covered) {
                    let large = matches!(f, FaceId::A | FaceId::B);
                    if large && !tool.history.is_seed(f.index() as u8, v) {
                        let g = normal.dot(&(solved[v as usize] - tool.pose * p.point));
                        if g < -entry {
                            covered = None;
                        }
                    }
                }
                // A rim face takes tissue beside the plate's body only:
                // behind both large faces by a margin. Tissue at the level
                // of face A or B beyond the outline is that face's, at the
                // polygon points of the triangles the outline crosses (at
                // the corner where both could claim it, the choice must
                // not flip with a micrometre of the tissue's shape).
                let beside = || {
                    let margin = RIM_MARGIN * inst.plate.thickness;
                    inst.plate.project(FaceId::A, &x).gap_m <= -margin
                        && inst.plate.project(FaceId::B, &x).gap_m <= -margin
                };
                if covered.is_none() && beside() {
                    covered = RIM.iter().filter(|&&r| r != face).find_map(|&r| {
                        let rp = inst.plate.project(r, &x);
                        // On another shape than the solved one, the same
                        // test on the solved position.
                        let solved_gap = query.solved.map(|solved| {
                            (tool.pose.rotation * rp.normal)
                                .dot(&(solved[v as usize] - tool.pose * rp.point))
                        });
                        (rp.outside_m <= tol
                            && rp.gap_m <= band
                            && rp.gap_m >= -rim_reach[r.index()]
                            && rim_meets(r, rp.gap_m)
                            && solved_gap.is_none_or(|g| rim_meets(r, g)))
                        .then_some((r, rp))
                    });
                }
                match covered {
                    Some((f, p)) => out.candidates.push(Candidate {
                        surface_vertex: v,
                        volume_node: query.to_volume[v as usize],
                        instrument: k as u16,
                        face: f,
                        normal: tool.pose.rotation * p.normal,
                        point: tool.pose * p.point,
                        gap_now_m: p.gap_m,
                    }),
                    None => out.nearby.push(Nearby {
                        volume_node: query.to_volume[v as usize],
                        distance_m: fp.outside_m.max(fp.gap_m.max(0.0)),
                    }),
                }
                if !faces_it {
                    continue;
                }
                for &w in topo.neighbours.row(v as usize) {
                    if ws.visit[w as usize] != stamp {
                        ws.visit[w as usize] = stamp;
                        ws.queue.push(w);
                    }
                }
            }
        }
    }
    ws.topology = Some(topo);
    drop_parallel_claims(&mut out.candidates, &mut ws.order, &mut ws.keep);
    edges(query, tools, ahead, band, opts.facing_only, ws, out);
}

/// The pierced triangles of which a face of the same instrument does not
/// cover every vertex (the contact's boundary, or a triangle larger than
/// the contact) give [`EdgeCandidate`]s, once per (instrument, face,
/// triangle) whatever number of nodes pierce it:
///
/// * on a flat plate's face A or B, the triangle (current positions,
///   instrument frame) is projected onto the face's plane and clipped by
///   the face's outline (Sutherland-Hodgman, carrying the barycentric
///   coordinates and the gap, both affine on the triangle); every corner
///   of the polygon that is not a vertex of the triangle (where a triangle
///   edge crosses the outline, or an outline corner inside the triangle)
///   and lies within the band is a candidate point. The corners move
///   continuously with the plate and the tissue, so the point the face
///   pushes does too: a step's answer does not jump with the choice of a
///   node;
/// * on a curved face and on the rim faces, the deepest node's line meets
///   the triangle at the candidate point; a rim face's only within the
///   entry depth ([`super::types::entry_depth_m`]) behind it (deeper, the
///   tissue came in through a large face, and the rim node's line crosses
///   the plate's width to it).
///
/// (Where covered vertices hold the triangle on the face, a point's gap is
/// closed by them and its row stays inactive.)
fn edges(
    query: &ContactQuery<'_>,
    tools: &[Tool<'_>],
    ahead: f64,
    band: f64,
    facing_only: bool,
    ws: &mut Workspace,
    out: &mut ContactOutput,
) {
    let nv = query.positions.len();
    let nt = query.triangles.len();
    if ws.covered.len() != nv || ws.clipped.len() != nt || ws.claimed.len() != nv {
        ws.covered.clear();
        ws.covered.resize(nv, 0);
        ws.claimed.clear();
        ws.claimed.resize(nv, u8::MAX);
        ws.clipped.clear();
        ws.clipped.resize(nt, [0; 2]);
        ws.covered_stamp = 0;
    }
    let mut c = 0;
    for (k, tool) in tools.iter().enumerate() {
        if ws.covered_stamp == u32::MAX {
            ws.covered.fill(0);
            ws.clipped.fill([0; 2]);
            ws.covered_stamp = 0;
        }
        ws.covered_stamp += 1;
        let stamp = ws.covered_stamp;
        let first_candidate = c;
        while c < out.candidates.len() && out.candidates[c].instrument as usize == k {
            let cand = out.candidates[c];
            ws.covered[cand.surface_vertex as usize] = stamp;
            ws.claimed[cand.surface_vertex as usize] = match cand.face {
                FaceId::A | FaceId::B => cand.face.index() as u8,
                _ => u8::MAX,
            };
            c += 1;
        }
        // Read by every clipping of this tool (see [`clip_triangle`]).
        let claims = facing_only.then_some((&ws.covered[..], &ws.claimed[..]));
        let inst = tool.instrument;
        let flat = inst.plate.bend_radius.is_none();
        let first_edge = out.edges.len();
        let first = ws.offsets[k];
        for pi in 0..out.pairs.len() {
            let p = out.pairs[pi];
            if p.instrument as usize != k {
                continue;
            }
            let tri = query.triangles[p.triangle as usize];
            if tri.iter().all(|&v| ws.covered[v as usize] == stamp) {
                continue;
            }
            let face = FaceId::of(inst.nodes[p.node as usize].kind);
            if facing_only && !facing(query, p.triangle, &ws.dirs[first + p.node as usize]) {
                continue;
            }
            let polygon = flat && matches!(face, FaceId::A | FaceId::B);
            if polygon {
                // The pierced triangle and those around it: no node's ray
                // need pierce a triangle the outline crosses (a sliver
                // beside the outline, or tissue already on the face), and
                // the tissue under the outline there stays a candidate for
                // as long as it is within the band.
                let topo = ws.topology.as_ref().expect("built by candidates");
                let sign = if face == FaceId::A { 1.0 } else { -1.0 };
                let normal = tool.pose.rotation * (Vector3::x() * sign);
                clip_triangle(
                    query,
                    tool,
                    k,
                    face,
                    p.triangle,
                    band,
                    &mut ws.clipped,
                    claims,
                    stamp,
                    out,
                );
                for v in tri {
                    for &t in topo.triangles.row(v as usize) {
                        if facing(query, t, &normal)
                            && !query.triangles[t as usize]
                                .iter()
                                .all(|&v| ws.covered[v as usize] == stamp)
                        {
                            clip_triangle(
                                query,
                                tool,
                                k,
                                face,
                                t,
                                band,
                                &mut ws.clipped,
                                claims,
                                stamp,
                                out,
                            );
                        }
                    }
                }
                continue;
            }
            // A rim face's point deeper behind it than the plate travels
            // in a deformation interval did not meet that face: the plate
            // moved into the tissue through a large face, and the rim
            // node's line crosses the plate's width to it (a row on it
            // would push the tissue out through the plate's other side).
            if matches!(face, FaceId::SidePlusY | FaceId::SideMinusY | FaceId::Tip)
                && p.t < -super::types::entry_depth_m(band, inst.plate.thickness)
            {
                continue;
            }
            let g = first + p.node as usize;
            let (s, n) = (ws.origins[g], ws.dirs[g]);
            let e = EdgeCandidate {
                instrument: k as u16,
                face,
                feature: 32 + p.node,
                triangle: p.triangle,
                nodes: tri.map(|v| query.to_volume[v as usize]),
                weights: [1.0 - p.u - p.v, p.u, p.v],
                normal: n,
                point: s,
                gap_now_m: p.t,
            };
            match out.edges[first_edge..]
                .iter_mut()
                .find(|o| o.triangle == e.triangle && o.face == e.face && o.feature >= 32)
            {
                Some(o) => {
                    if e.gap_now_m < o.gap_now_m {
                        *o = e;
                    }
                }
                None => out.edges.push(e),
            }
        }
        // The boundary of a flat face's covered patch: triangles of its
        // candidates that it does not cover whole, facing the face; and
        // the triangles around the tissue the last solve found it pushing.
        if flat {
            let topo = ws.topology.as_ref().expect("built by candidates");
            for face in [FaceId::A, FaceId::B] {
                let sign = if face == FaceId::A { 1.0 } else { -1.0 };
                let normal = tool.pose.rotation * (Vector3::x() * sign);
                for v in tool.history.seeds_of(face.index() as u8) {
                    if v as usize >= nv {
                        continue;
                    }
                    for &t in topo.triangles.row(v as usize) {
                        let tri = query.triangles[t as usize];
                        if tri.iter().all(|&v| ws.covered[v as usize] == stamp)
                            || !facing(query, t, &normal)
                        {
                            continue;
                        }
                        clip_triangle(
                            query,
                            tool,
                            k,
                            face,
                            t,
                            band,
                            &mut ws.clipped,
                            claims,
                            stamp,
                            out,
                        );
                    }
                }
            }
            for ci in first_candidate..c {
                let cand = out.candidates[ci];
                if !matches!(cand.face, FaceId::A | FaceId::B) {
                    continue;
                }
                for &t in topo.triangles.row(cand.surface_vertex as usize) {
                    let tri = query.triangles[t as usize];
                    if tri.iter().all(|&v| ws.covered[v as usize] == stamp)
                        || !facing(query, t, &cand.normal)
                    {
                        continue;
                    }
                    clip_triangle(
                        query,
                        tool,
                        k,
                        cand.face,
                        t,
                        band,
                        &mut ws.clipped,
                        claims,
                        stamp,
                        out,
                    );
                }
            }
        }
        // Triangles without every vertex covered that the faces see in
        // front within `ahead`: the plate's edges may pierce them soon, so
        // their vertices are nearby, at the distance of the hit.
        for i in 0..inst.nodes.len() {
            let Some(h) = ws.hits[first + i].front else {
                continue;
            };
            if h.t > ahead {
                continue;
            }
            let tri = query.triangles[h.triangle as usize];
            if tri.iter().all(|&v| ws.covered[v as usize] == stamp) {
                continue;
            }
            let [a, b, cc] = tri.map(|v| query.positions[v as usize]);
            if ws.dirs[first + i].dot(&(b - a).cross(&(cc - a))) >= 0.0 {
                continue;
            }
            for v in tri {
                out.nearby.push(Nearby {
                    volume_node: query.to_volume[v as usize],
                    distance_m: h.t,
                });
            }
        }
    }
}

/// Whether surface triangle `t` faces a face of outward normal `normal`
/// (scene frame): the tissue's outward normal opposes it.
fn facing(query: &ContactQuery<'_>, t: u32, normal: &Vector3<f64>) -> bool {
    let [a, b, c] = query.triangles[t as usize].map(|v| query.positions[v as usize]);
    normal.dot(&(b - a).cross(&(c - a))) < 0.0
}

/// The polygon points of `triangle` on flat face `face` (A or B) of tool
/// `k`, once per triangle and face for the tool (`clipped` marked with
/// `stamp`).
#[allow(clippy::too_many_arguments)]
fn clip_triangle(
    query: &ContactQuery<'_>,
    tool: &Tool<'_>,
    k: usize,
    face: FaceId,
    triangle: u32,
    band: f64,
    clipped: &mut [[u32; 2]],
    claims: Option<(&[u32], &[u8])>,
    stamp: u32,
    out: &mut ContactOutput,
) {
    let slot = &mut clipped[triangle as usize][usize::from(face == FaceId::B)];
    if *slot == stamp {
        return;
    }
    *slot = stamp;
    let tri = query.triangles[triangle as usize];
    // `claims` (covered stamps and claiming faces): a triangle with a
    // vertex the opposite large face pushes gets no points of this face.
    // On the rest shape such a triangle lies across the plate's slab, and
    // rows of both faces on it would pinch the tissue through the plate.
    if let Some((covered, claimed)) = claims {
        let opposite = if face == FaceId::A {
            FaceId::B
        } else {
            FaceId::A
        }
        .index() as u8;
        if tri
            .iter()
            .any(|&v| covered[v as usize] == stamp && claimed[v as usize] == opposite)
        {
            return;
        }
    }
    let inv = tool.pose.inverse();
    let local = tri.map(|v| inv * query.positions[v as usize]);
    let nodes = tri.map(|v| query.to_volume[v as usize]);
    // On another shape than the solved one: a triangle the face did not
    // push last time gives points only where their solved position is
    // within the entry depth (as a vertex, [`candidates`]).
    let entering = query.solved.filter(|_| {
        !tri.iter()
            .any(|&v| tool.history.is_seed(face.index() as u8, v))
    });
    let entry = super::types::entry_depth_m(band, tool.instrument.plate.thickness);
    clip_points(
        &tool.instrument.plate,
        face,
        &local,
        band,
        |feature, w, gap, at| {
            if let Some(solved) = entering {
                let x = solved[tri[0] as usize].coords * w[0]
                    + solved[tri[1] as usize].coords * w[1]
                    + solved[tri[2] as usize].coords * w[2];
                let n = tool.pose.rotation * at.1;
                if n.dot(&(x - (tool.pose * at.0).coords)) < -entry {
                    return;
                }
            }
            out.edges.push(EdgeCandidate {
                instrument: k as u16,
                face,
                feature,
                triangle,
                nodes,
                weights: w,
                normal: tool.pose.rotation * at.1,
                point: tool.pose * at.0,
                gap_now_m: gap,
            });
        },
    );
}

/// One corner of a clipped polygon: position in the face's plane
/// coordinates `(y, s)`, barycentric coordinates on the triangle, gap (m),
/// and what made it (a triangle vertex `a`: `a`; an outline corner `k`:
/// `4 + k`; triangle edge `e` on outline side `c`: `16 + 4 e + c`).
/// A polygon has at most 3 + 4 corners.
#[derive(Debug, Clone, Copy)]
struct Corner {
    y: f64,
    s: f64,
    w: [f64; 3],
    gap: f64,
    feature: u32,
}

/// A clipped polygon's corners with the line each one's outgoing edge lies
/// on (no allocation).
#[derive(Debug, Clone, Copy)]
struct Poly {
    items: [(Corner, u32); 8],
    len: usize,
}

impl Default for Poly {
    fn default() -> Self {
        let zero = Corner {
            y: 0.0,
            s: 0.0,
            w: [0.0; 3],
            gap: 0.0,
            feature: 0,
        };
        Self {
            items: [(zero, 0); 8],
            len: 0,
        }
    }
}

impl Poly {
    fn push(&mut self, item: (Corner, u32)) {
        if self.len < self.items.len() {
            self.items[self.len] = item;
            self.len += 1;
        }
    }
}

/// The corners of a flat face's outline cut out of a triangle (instrument
/// frame `local`) that are not triangle vertices and lie within `band`:
/// `emit(feature, weights, gap, (face point, normal))` for each (features
/// of [`EdgeCandidate::feature`]).
fn clip_points(
    plate: &crate::collide::tool::instrument::Plate,
    face: FaceId,
    local: &[nalgebra::Point3<f64>; 3],
    band: f64,
    mut emit: impl FnMut(u32, [f64; 3], f64, (nalgebra::Point3<f64>, Vector3<f64>)),
) {
    let sign = if face == FaceId::A { 1.0 } else { -1.0 };
    let h2 = 0.5 * plate.thickness;
    let normal = Vector3::x() * sign;
    // Polygon edges carry what they lie on: triangle edge `e` (0-2), or
    // outline side `c` (10 + c).
    let mut poly: Poly = Poly::default();
    for a in 0..3 {
        poly.push({
            let x = local[a];
            let mut w = [0.0; 3];
            w[a] = 1.0;
            (
                Corner {
                    y: x.y,
                    s: x.z,
                    w,
                    gap: sign * x.x - h2,
                    feature: a as u32,
                },
                // Edge from corner a to corner a + 1.
                a as u32,
            )
        });
    }
    // The outline: s >= 0, s <= L, y <= w(s)/2, -y <= w(s)/2, as
    // f(y, s) >= 0 with f affine.
    let (wb, wt, l) = (plate.base_width, plate.tip_width, plate.length);
    let half = move |s: f64| 0.5 * (wb + (wt - wb) * s / l);
    let sides: [&dyn Fn(f64, f64) -> f64; 4] = [
        &|_, s| s,
        &move |_, s| l - s,
        &move |y, s| half(s) - y,
        &move |y, s| half(s) + y,
    ];
    // Outline corners: between consecutive sides in the order the clip
    // makes them (corner k lies on sides given below).
    let corner_id = |c1: u32, c2: u32| -> u32 {
        match (c1.min(c2), c1.max(c2)) {
            (0, 2) => 0,
            (0, 3) => 1,
            (1, 2) => 2,
            (1, 3) => 3,
            _ => 4,
        }
    };
    for (c, f) in sides.iter().enumerate() {
        let c = c as u32;
        let mut next = Poly::default();
        let n = poly.len;
        for i in 0..n {
            let (p, on) = poly.items[i];
            let q = poly.items[(i + 1) % n].0;
            let (fp, fq) = (f(p.y, p.s), f(q.y, q.s));
            if fp >= 0.0 {
                next.push((p, on));
            }
            if (fp >= 0.0) != (fq >= 0.0) {
                let t = fp / (fp - fq);
                let lerp = |a: f64, b: f64| a + (b - a) * t;
                let feature = if on < 10 {
                    16 + 4 * on + c
                } else {
                    4 + corner_id(on - 10, c)
                };
                let x = Corner {
                    y: lerp(p.y, q.y),
                    s: lerp(p.s, q.s),
                    w: [
                        lerp(p.w[0], q.w[0]),
                        lerp(p.w[1], q.w[1]),
                        lerp(p.w[2], q.w[2]),
                    ],
                    gap: lerp(p.gap, q.gap),
                    feature,
                };
                // Entering: the new edge runs along the triangle's edge;
                // leaving: along this side.
                if fp >= 0.0 {
                    next.push((x, 10 + c));
                } else {
                    next.push((x, on));
                }
            }
        }
        poly = next;
        if poly.len == 0 {
            return;
        }
    }
    for &(corner, _) in &poly.items[..poly.len] {
        if corner.feature < 3 || corner.gap > band {
            continue;
        }
        let point = nalgebra::Point3::new(sign * h2, corner.y, corner.s);
        emit(corner.feature, corner.w, corner.gap, (point, normal));
    }
}

/// The area-weighted outward normal at surface vertex `v` (unnormalised).
fn vertex_normal(query: &ContactQuery<'_>, vertex_triangles: &Csr, v: u32) -> Vector3<f64> {
    let mut n = Vector3::zeros();
    for &t in vertex_triangles.row(v as usize) {
        let [a, b, c] = query.triangles[t as usize].map(|i| query.positions[i as usize]);
        n += (b - a).cross(&(c - a));
    }
    n
}

fn next_visit(ws: &mut Workspace) {
    if ws.visit_stamp == u32::MAX {
        ws.visit.fill(0);
        ws.visit_stamp = 0;
    }
    ws.visit_stamp += 1;
}

/// A key that tells one triangle list from another: its address, length,
/// vertex count and a few of its triangles.
fn topology_key(triangles: &[[u32; 3]], nv: usize) -> (usize, usize) {
    let mut h: usize = nv.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    for t in triangles
        .iter()
        .take(8)
        .chain(triangles.iter().rev().take(8))
    {
        for &v in t {
            h = (h ^ v as usize).wrapping_mul(0x0100_0000_01b3);
        }
    }
    (triangles.as_ptr() as usize ^ h, triangles.len())
}

fn ensure_topology(ws: &mut Workspace, triangles: &[[u32; 3]], nv: usize) {
    let key = topology_key(triangles, nv);
    if ws.topology.as_ref().is_some_and(|t| t.key == key) {
        return;
    }
    let neighbours = surface_vertex_neighbours(triangles, nv);
    let pairs = triangles
        .iter()
        .enumerate()
        .flat_map(|(t, tri)| tri.iter().map(move |&v| (v, t as u32)));
    let vertex_triangles = Csr::from_pairs(nv, pairs);
    ws.topology = Some(Topology {
        key,
        neighbours,
        triangles: vertex_triangles,
    });
}

/// Of the candidates of one vertex whose normals are within 5 degrees of
/// parallel or opposed, keeps the one with the smallest gap (the first on
/// ties); the order of the others is kept.
fn drop_parallel_claims(c: &mut Vec<Candidate>, order: &mut Vec<usize>, keep: &mut Vec<bool>) {
    if c.len() < 2 {
        return;
    }
    order.clear();
    order.extend(0..c.len());
    order.sort_unstable_by_key(|&i| (c[i].surface_vertex, i));
    keep.clear();
    keep.resize(c.len(), true);
    let mut s = 0;
    while s < order.len() {
        let v = c[order[s]].surface_vertex;
        let mut e = s;
        while e < order.len() && c[order[e]].surface_vertex == v {
            e += 1;
        }
        for a in s..e {
            for b in a + 1..e {
                let (i, j) = (order[a], order[b]);
                if !keep[i] || !keep[j] {
                    continue;
                }
                if c[i].normal.dot(&c[j].normal).abs() > PARALLEL_COS {
                    if c[j].gap_now_m < c[i].gap_now_m {
                        keep[i] = false;
                    } else {
                        keep[j] = false;
                    }
                }
            }
        }
        s = e;
    }
    let mut i = 0;
    c.retain(|_| {
        i += 1;
        keep[i - 1]
    });
}
