//! Collision pairs, history culling and enforced displacements: one call of
//! [`detect`] (one instrument, the force loop) or [`detect_many`] (all
//! instruments, the deformation loop) runs DESIGN.md section 2 end to end.
//!
//! 1. **Rays.** Each source node `S` with unit face normal `N_R` (scene frame,
//!    after the pose) gives the line `S + t N_R`. One [`RayBackend::cast`] over all
//!    nodes of all instruments returns the nearest hit behind (`t <= 0`) and in
//!    front (`t > 0`), each looked for only as far as the later rules can use
//!    it ([`DetectOptions::bounded_rays`]).
//! 2. **Pairs (A1, A2).** The nearest triangle behind forms a pair with the node
//!    when `N_R . N_tri < 0` (`N_tri` the triangle's outward normal at the current
//!    positions) and `|t|` is within the node's reach (infinite for face nodes).
//! 3. **Culling (B1-B3)**, per instrument, when [`DetectOptions::culling`] is on:
//!    every node whose history flag is on marks its nearest triangle *in front*
//!    as infeasible; every pair of that instrument holding an infeasible triangle
//!    is cancelled (reported in [`ContactOutput::cancelled`]). Culling is per
//!    instrument because a triangle in front of one spatula may be a genuine
//!    contact of the other (two spatulas squeezing a lobe from both sides).
//! 4. **History.** When the [`History`] renews at this [`Stage`], a node's flag is
//!    set exactly when it holds a surviving pair.
//! 5. **Enforced displacements.** For each surviving pair and each vertex `V`
//!    of its triangle, with current position `V` and rest position `V_rest`:
//!    `depth = (S - V) . N_R`, `V_proj = V + depth N_R` (the projection onto the
//!    face plane along `N_R`), `U = V_proj - V_rest`.
//!    With [`DetectOptions::unilateral`] (off by default), a triangle with a
//!    vertex at `depth >= -skin` (behind the face, or on it) enforces only
//!    such vertices: a vertex in front of the face is free, never pulled onto
//!    it. A triangle whose three vertices all lie in front (the face pokes
//!    into a triangle larger than the contact) is projected whole, as in the
//!    paper, so that the contact still gives a force.
//!    **Conflict rule:** when several pairs give one vertex different
//!    displacements, the one with the largest `depth` wins (the face the vertex
//!    has penetrated deepest, so that the vertex ends up outside every face that
//!    claims it as far as one projection can); equal depths keep the first in
//!    (instrument, node) order. Each [`Enforced`] records the instrument and
//!    node that gave it, so reactions can be summed per instrument.
//!
//! The caller keeps the backend's positions current: call
//! [`RayBackend::update_positions`] with the same positions as
//! [`ContactQuery::positions`] whenever the surface changed (a BVH refits then).
//! The force loop at 1 kHz does not refit between two published surfaces.
//!
//! Steady state allocates nothing: every buffer lives in the [`Workspace`] or in
//! the [`ContactOutput`] and is cleared, not freed.

use super::history::{History, Stage};
use super::instrument::Instrument;
use super::{NodeHits, RayBackend, RayRange};
use nalgebra::{Isometry3, Point3, Vector3};

/// Errors of a contact query; each names what is inconsistent.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ContactError {
    /// Two per-vertex arrays of the query have different lengths.
    #[error("{what} has {got} entries, expected {expected} (one per surface vertex)")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    /// A triangle index from the backend, or a vertex index of a triangle, is out of range.
    #[error(
        "triangle {triangle} is out of range or refers to a vertex out of range ({vertices} vertices)"
    )]
    BadTriangle { triangle: u32, vertices: usize },
    /// A pose has a non-finite component.
    #[error("the pose of instrument {instrument} is not finite")]
    NonFinitePose { instrument: usize },
    /// More instruments than a `u16` can number.
    #[error("{0} instruments in one query; at most 65535")]
    TooManyInstruments(usize),
}

/// The surface a query runs against (plain data, borrowed).
#[derive(Debug, Clone, Copy)]
pub struct ContactQuery<'a> {
    /// Current surface vertex positions, m (the ones the backend was last given).
    pub positions: &'a [Point3<f64>],
    /// Rest positions of the surface vertices, m.
    pub rest: &'a [Point3<f64>],
    /// Outward triangles as surface vertex indices.
    pub triangles: &'a [[u32; 3]],
    /// Surface vertex -> volume node.
    pub to_volume: &'a [u32],
}

/// Options of a query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectOptions {
    /// History culling (B1-B3); off reproduces the paper's failure.
    pub culling: bool,
    /// Contact skin, m: a hit up to this far *in front* of a face still counts
    /// as behind it. A vertex projected onto the face plane by the last step lies
    /// on the plane only up to rounding (about 1e-17 m at brain scale); without
    /// a skin its hit would fall in front half of the time and the contact would
    /// flicker from one step to the next. Rays are cast from `S + skin N_R`;
    /// projections still go onto the true face plane through `S`.
    pub skin_m: f64,
    /// Casts each line only as far as an answer can matter (the default):
    /// behind up to the node's reach (the pair rule ignores farther hits), and
    /// in front only from nodes whose history flag is on (the culling reads no
    /// other front), up to the node's reach. The culling only asks whether a
    /// flagged node's nearest front hit is one of the instrument's candidate
    /// pair triangles, so a flagged line with nothing in front within reach
    /// is cast again, beyond it, only when it meets the box of those
    /// triangles. The output is the same as with whole lines (`false`, the
    /// paper's pass), which is kept for comparison.
    pub bounded_rays: bool,
    /// Unilateral contact (off by default, as in the scenes): when a vertex
    /// of a surviving pair's triangle lies behind the face (depth at least
    /// `-skin_m`), only such vertices get enforced displacements; a triangle
    /// with all three vertices in front is projected whole. `false` always projects all
    /// three vertices, as the paper does: with triangles larger than the
    /// contact, a vertex lying in front of the face is pulled onto it (the
    /// tissue is dragged towards the spatula).
    pub unilateral: bool,
}

/// Default contact skin, m (0.1 um: far above rounding, far below any
/// modelled length).
pub const DEFAULT_SKIN_M: f64 = 1e-7;

impl Default for DetectOptions {
    fn default() -> Self {
        Self {
            culling: true,
            skin_m: DEFAULT_SKIN_M,
            bounded_rays: true,
            unilateral: false,
        }
    }
}

/// One instrument in a query: its source nodes, scene pose and history.
#[derive(Debug)]
pub struct Tool<'a> {
    /// The spatula.
    pub instrument: &'a Instrument,
    /// Instrument frame -> scene frame.
    pub pose: Isometry3<f64>,
    /// Its history flags (renewed according to `history.mode` and the stage).
    pub history: &'a mut History,
}

/// A collision pair: source node and its nearest triangle behind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pair {
    /// Index of the instrument in the query.
    pub instrument: u16,
    /// Source node index within its instrument.
    pub node: u32,
    /// Surface triangle index.
    pub triangle: u32,
    /// Signed line parameter of the hit, m (`<= 0`: behind the face).
    pub t: f64,
}

/// An enforced displacement of one surface vertex (a Dirichlet condition).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Enforced {
    /// Surface vertex index.
    pub surface_vertex: u32,
    /// Volume node index (`to_volume[surface_vertex]`).
    pub volume_node: u32,
    /// `U = V_proj - V_rest`, m.
    pub displacement: Vector3<f64>,
    /// Instrument that gives it.
    pub instrument: u16,
    /// Source node that gives it (within its instrument).
    pub node: u32,
    /// Projection depth `(S - V) . N_R`, m, at the current positions.
    pub depth: f64,
}

/// What a query returns (buffers reused across calls).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ContactOutput {
    /// Surviving pairs, in (instrument, node) order.
    pub pairs: Vec<Pair>,
    /// Pairs cancelled by culling.
    pub cancelled: Vec<Pair>,
    /// One enforced displacement per contacted surface vertex.
    pub enforced: Vec<Enforced>,
}

impl ContactOutput {
    fn clear(&mut self) {
        self.pairs.clear();
        self.cancelled.clear();
        self.enforced.clear();
    }

    /// Surviving pairs of instrument `k`.
    pub fn pairs_of(&self, k: u16) -> impl Iterator<Item = &Pair> {
        self.pairs.iter().filter(move |p| p.instrument == k)
    }
}

/// Reused buffers of [`detect`] / [`detect_many`].
#[derive(Debug, Clone, Default)]
pub struct Workspace {
    /// Scene-frame ray origins of all nodes of all instruments (last query).
    pub origins: Vec<Point3<f64>>,
    /// Scene-frame ray directions (last query).
    pub dirs: Vec<Vector3<f64>>,
    /// Backend answers per ray (last query). With bounded rays, a flagged
    /// node's front hit is its nearest one when that lies within the node's
    /// reach or could be a pair's triangle (see [`DetectOptions::bounded_rays`]);
    /// farther ones are not looked for and read `None`.
    pub hits: Vec<NodeHits>,
    offsets: Vec<usize>,
    ranges: Vec<RayRange>,
    /// Second pass of flagged rays: ray index, then its origin, direction
    /// and answer.
    recast: Vec<usize>,
    recast_origins: Vec<Point3<f64>>,
    recast_dirs: Vec<Vector3<f64>>,
    recast_ranges: Vec<RayRange>,
    recast_hits: Vec<NodeHits>,
    candidates: Vec<Pair>,
    mark: Vec<u32>,
    stamp: u32,
    slot: Vec<u32>,
}

impl Workspace {
    /// An empty workspace; buffers grow on first use.
    pub fn new() -> Self {
        Self::default()
    }

    /// First ray of instrument `k` in `origins` / `dirs` / `hits` (last query).
    pub fn first_ray(&self, k: usize) -> usize {
        self.offsets[k]
    }

    fn next_stamp(&mut self, triangles: usize) {
        if self.mark.len() != triangles {
            self.mark.clear();
            self.mark.resize(triangles, 0);
            self.stamp = 0;
        }
        if self.stamp == u32::MAX {
            self.mark.fill(0);
            self.stamp = 0;
        }
        self.stamp += 1;
    }
}

const NONE: u32 = u32::MAX;

/// One instrument (the force loop). See [`detect_many`].
pub fn detect(
    backend: &mut dyn RayBackend,
    query: &ContactQuery<'_>,
    instrument: &Instrument,
    pose: &Isometry3<f64>,
    history: &mut History,
    stage: Stage,
    opts: &DetectOptions,
    ws: &mut Workspace,
    out: &mut ContactOutput,
) -> Result<(), ContactError> {
    let mut tools = [Tool {
        instrument,
        pose: *pose,
        history,
    }];
    detect_many(backend, query, &mut tools, stage, opts, ws, out)
}

/// All instruments in one cast (the deformation loop): rays, pairs, culling,
/// history renewal and enforced displacements (module documentation).
/// On error, `out` is left empty and no history is changed.
pub fn detect_many(
    backend: &mut dyn RayBackend,
    query: &ContactQuery<'_>,
    tools: &mut [Tool<'_>],
    stage: Stage,
    opts: &DetectOptions,
    ws: &mut Workspace,
    out: &mut ContactOutput,
) -> Result<(), ContactError> {
    out.clear();
    let nv = query.positions.len();
    for (what, got) in [
        ("rest", query.rest.len()),
        ("to_volume", query.to_volume.len()),
    ] {
        if got != nv {
            return Err(ContactError::LengthMismatch {
                what,
                expected: nv,
                got,
            });
        }
    }
    if tools.len() > u16::MAX as usize {
        return Err(ContactError::TooManyInstruments(tools.len()));
    }
    for (k, tool) in tools.iter().enumerate() {
        let finite = tool.pose.translation.vector.iter().all(|x| x.is_finite())
            && tool.pose.rotation.coords.iter().all(|x| x.is_finite());
        if !finite {
            return Err(ContactError::NonFinitePose { instrument: k });
        }
    }

    // 1. Rays.
    ws.origins.clear();
    ws.dirs.clear();
    ws.offsets.clear();
    for tool in tools.iter() {
        ws.offsets.push(ws.origins.len());
        tool.instrument
            .place(&tool.pose, &mut ws.origins, &mut ws.dirs);
    }
    ws.offsets.push(ws.origins.len());
    let skin = if opts.skin_m.is_finite() {
        opts.skin_m.max(0.0)
    } else {
        0.0
    };
    if skin > 0.0 {
        for (o, d) in ws.origins.iter_mut().zip(&ws.dirs) {
            *o += d * skin;
        }
    }
    ws.ranges.clear();
    for tool in tools.iter() {
        let flags = tool.history.flags();
        ws.ranges
            .extend(tool.instrument.nodes.iter().enumerate().map(|(i, node)| {
                if opts.bounded_rays {
                    // Pairs need the nearest hit behind only within reach
                    // (from the true face point, hence the skin); the culling
                    // needs the nearest hit in front of flagged nodes only.
                    let flagged = opts.culling && flags.get(i).copied().unwrap_or(false);
                    RayRange {
                        behind: widen(node.reach + skin),
                        front: if flagged {
                            front_reach(node.reach)
                        } else {
                            -1.0
                        },
                    }
                } else {
                    RayRange::LINE
                }
            }));
    }
    backend.cast_ranged(&ws.origins, &ws.dirs, &ws.ranges, &mut ws.hits);
    if skin > 0.0 {
        // Back to the true face points. The shifted origins classified the hits
        // (behind: t_true <= skin); report t from the true face point.
        for (o, d) in ws.origins.iter_mut().zip(&ws.dirs) {
            *o -= d * skin;
        }
        for h in ws.hits.iter_mut() {
            for hit in [&mut h.behind, &mut h.front].into_iter().flatten() {
                hit.t += skin;
            }
        }
    }

    // 2. Pairs (A1, A2).
    ws.candidates.clear();
    let bad = |triangle: u32| ContactError::BadTriangle {
        triangle,
        vertices: nv,
    };
    for (k, tool) in tools.iter().enumerate() {
        let first = ws.offsets[k];
        for (i, node) in tool.instrument.nodes.iter().enumerate() {
            let g = first + i;
            let Some(hit) = ws.hits.get(g).and_then(|h| h.behind) else {
                continue;
            };
            if -hit.t > node.reach {
                continue;
            }
            let tri = query
                .triangles
                .get(hit.triangle as usize)
                .ok_or_else(|| bad(hit.triangle))?;
            if tri.iter().any(|&v| v as usize >= nv) {
                return Err(bad(hit.triangle));
            }
            let [a, b, c] = tri.map(|v| query.positions[v as usize]);
            let n_tri = (b - a).cross(&(c - a));
            if ws.dirs[g].dot(&n_tri) < 0.0 {
                ws.candidates.push(Pair {
                    instrument: k as u16,
                    node: i as u32,
                    triangle: hit.triangle,
                    t: hit.t,
                });
            }
        }
    }

    // 3a. Flagged lines with nothing in front within reach: their nearest
    // front hit matters only if it is a candidate triangle of their
    // instrument, so they are cast again, beyond reach, only when they meet
    // the box of those triangles (which holds any such hit).
    if opts.culling && opts.bounded_rays {
        ws.recast.clear();
        ws.recast_origins.clear();
        ws.recast_dirs.clear();
        ws.recast_ranges.clear();
        let mut c = 0;
        for (k, tool) in tools.iter().enumerate() {
            let first = ws.offsets[k];
            let mut lo = Point3::from([f64::INFINITY; 3]);
            let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
            while c < ws.candidates.len() && ws.candidates[c].instrument as usize == k {
                for v in query.triangles[ws.candidates[c].triangle as usize] {
                    let p = query.positions[v as usize];
                    lo = lo.inf(&p);
                    hi = hi.sup(&p);
                }
                c += 1;
            }
            if lo.x > hi.x {
                continue;
            }
            let (lo, hi) = super::widen_box(lo, hi);
            for (i, &flag) in tool.history.flags().iter().enumerate() {
                let g = first + i;
                if !flag || ws.hits[g].front.is_some() {
                    continue;
                }
                let beyond = ws.ranges[g].front;
                if !beyond.is_finite() {
                    continue;
                }
                let o = ws.origins[g] + ws.dirs[g] * skin;
                if line_meets_box(&o, &ws.dirs[g], beyond, &lo, &hi) {
                    ws.recast.push(g);
                    ws.recast_origins.push(o);
                    ws.recast_dirs.push(ws.dirs[g]);
                    ws.recast_ranges.push(RayRange {
                        behind: -1.0,
                        front: f64::INFINITY,
                    });
                }
            }
        }
        if !ws.recast.is_empty() {
            backend.cast_ranged(
                &ws.recast_origins,
                &ws.recast_dirs,
                &ws.recast_ranges,
                &mut ws.recast_hits,
            );
            for (j, &g) in ws.recast.iter().enumerate() {
                ws.hits[g].front = ws.recast_hits[j].front.map(|mut h| {
                    h.t += skin;
                    h
                });
            }
        }
    }

    // 3. Culling (B1-B3), per instrument.
    let mut c = 0;
    for (k, tool) in tools.iter_mut().enumerate() {
        let first = ws.offsets[k];
        tool.history.ensure_len(tool.instrument.len());
        if opts.culling {
            ws.next_stamp(query.triangles.len());
            for (i, &flag) in tool.history.flags().iter().enumerate() {
                if !flag {
                    continue;
                }
                if let Some(front) = ws.hits.get(first + i).and_then(|h| h.front) {
                    if let Some(m) = ws.mark.get_mut(front.triangle as usize) {
                        *m = ws.stamp;
                    }
                }
            }
        }
        let start = out.pairs.len();
        while c < ws.candidates.len() && ws.candidates[c].instrument as usize == k {
            let p = ws.candidates[c];
            c += 1;
            if opts.culling && ws.mark[p.triangle as usize] == ws.stamp {
                out.cancelled.push(p);
            } else {
                out.pairs.push(p);
            }
        }
        // 4. History renewal from the surviving pairs.
        if tool.history.renews(stage) {
            let flags = tool.history.flags_mut();
            flags.fill(false);
            for p in &out.pairs[start..] {
                flags[p.node as usize] = true;
            }
        }
    }

    // 5. Enforced displacements, deepest projection wins.
    if ws.slot.len() != nv {
        ws.slot.clear();
        ws.slot.resize(nv, NONE);
    }
    for p in &out.pairs {
        let g = ws.offsets[p.instrument as usize] + p.node as usize;
        let (s, n) = (ws.origins[g], ws.dirs[g]);
        let tri = query.triangles[p.triangle as usize];
        // Unilateral: when a vertex lies behind the face, those in front stay
        // free; a triangle the face pokes into with all three vertices in
        // front is projected whole (else that contact would give no force).
        let depths = tri.map(|v| (s - query.positions[v as usize]).dot(&n));
        let pushes = opts.unilateral && depths.iter().any(|&d| d >= -skin);
        for (v, depth) in tri.into_iter().zip(depths) {
            let pos = query.positions[v as usize];
            if pushes && depth < -skin {
                continue;
            }
            let e = Enforced {
                surface_vertex: v,
                volume_node: query.to_volume[v as usize],
                displacement: pos + n * depth - query.rest[v as usize],
                instrument: p.instrument,
                node: p.node,
                depth,
            };
            let slot = &mut ws.slot[v as usize];
            if *slot == NONE {
                *slot = out.enforced.len() as u32;
                out.enforced.push(e);
            } else if depth > out.enforced[*slot as usize].depth {
                out.enforced[*slot as usize] = e;
            }
        }
    }
    for e in &out.enforced {
        ws.slot[e.surface_vertex as usize] = NONE;
    }
    Ok(())
}

/// How far in front a flagged node's line is cast in the first pass, m: its
/// reach (hits there are found with the behind ones, from the same region
/// of the tree).
#[inline]
fn front_reach(reach: f64) -> f64 {
    if reach.is_finite() {
        widen(reach)
    } else {
        f64::INFINITY
    }
}

/// Whether the part `t > beyond` of the line `o + t d` meets the box
/// `[lo, hi]` (slab test; a zero direction component needs `o` within that
/// slab).
fn line_meets_box(
    o: &Point3<f64>,
    d: &Vector3<f64>,
    beyond: f64,
    lo: &Point3<f64>,
    hi: &Point3<f64>,
) -> bool {
    let (mut t0, mut t1) = (beyond, f64::INFINITY);
    for a in 0..3 {
        if d[a] == 0.0 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return false;
            }
        } else {
            let inv = 1.0 / d[a];
            let (ta, tb) = ((lo[a] - o[a]) * inv, (hi[a] - o[a]) * inv);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    // Widened: a hit exactly on the box boundary must not be missed.
    t0 <= t1 + 1e-9 * (t1.abs() + 1.0)
}

/// `x` plus a relative margin far above the rounding of the tests it bounds
/// (a bound that is slightly loose only costs time; a tight one could drop an
/// answer the whole-line cast gives).
#[inline]
fn widen(x: f64) -> f64 {
    x * (1.0 + 1e-9) + 1e-12
}
