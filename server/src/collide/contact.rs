//! The collision pipeline of one query: [`detect`] (one instrument, the
//! force loop) or [`detect_many`] (all instruments, the deformation loop)
//! runs its named stages in order over plain data:
//!
//! 1. [`cast`](super::cast): one ray per source node (`S + t N_R`, scene
//!    frame after the pose), cast once for all instruments; the nearest hit
//!    behind (`t <= 0`) and in front (`t > 0`), each only as far as a later
//!    stage can use it ([`DetectOptions::bounded_rays`]).
//! 2. [`pair`](super::pair) (A1, A2): the nearest triangle behind a node,
//!    within its reach, whose outward normal opposes the face normal; with
//!    the Signorini rule also the nearest triangle *in front* within
//!    [`DetectOptions::band_m`] (tissue about to be touched, or that the
//!    face is leaving).
//! 3. [`cull`](super::cull) (B1-B3), per instrument: flagged nodes mark
//!    their nearest triangle in front as infeasible, and the pairs holding
//!    one are cancelled.
//! 4. renew ([`History::renew`]): a node's flag is set exactly when it
//!    holds a surviving pair (when the history renews at this [`Stage`]).
//! 5. By the contact rule ([`ContactRule`]):
//!    * [`gap`](super::gap) (Signorini, the default): the surface vertices
//!      each face may push ([`Candidate`]: covered by the face, within the
//!      band), with the face's normal and point; the pierced triangles not
//!      all of whose vertices a face covers ([`EdgeCandidate`]); and the
//!      vertices near the faces whose compliance should be ready
//!      ([`Nearby`]);
//!    * [`enforce`](super::enforce) (the paper's rule): every vertex of a
//!      paired triangle projected onto the face plane ([`Enforced`]).
//!
//! The caller keeps the backend's positions current: call
//! [`RayBackend::update_positions`] with the same positions as
//! [`ContactQuery::positions`] whenever the surface changed (a BVH refits
//! then). The force loop at 1 kHz does not refit between two published
//! surfaces.
//!
//! Steady state allocates nothing: every buffer lives in the [`Workspace`]
//! or in the [`ContactOutput`] and is cleared, not freed.

use super::faces::FaceId;
use super::history::{History, Stage};
use super::instrument::Instrument;
use super::{NodeHits, RayBackend, RayRange, SurfaceError};
use crate::mesh::adjacency::Csr;
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
    #[error(transparent)]
    Surface(#[from] SurfaceError),
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
    /// Where the last solve put the surface vertices, m, when the search
    /// runs on another shape (the rest shape of a linearized contact): a
    /// vertex that no face pushed last time becomes a large face's
    /// candidate only where its solved position is at most
    /// [`entry_depth_m`] behind the face.
    pub solved: Option<&'a [Point3<f64>]>,
}

/// How far behind a large face a vertex's solved position may lie when it
/// first becomes the face's candidate on the rest shape, m: the band (the
/// plate's travel within one deformation interval), and less than the
/// plate's thickness (`thickness_m`). Tissue that comes under the face
/// deeper than that did not meet the face: the plate's outline swept over
/// it (its edge plows through the tissue, or the tissue lies beyond the
/// opposite face), and pushing it onto the face would drag it through the
/// plate.
pub fn entry_depth_m(band_m: f64, thickness_m: f64) -> f64 {
    band_m.min(0.95 * thickness_m)
}

/// What the last stage makes of the surviving pairs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ContactRule {
    /// Candidates of a unilateral (Signorini) contact problem: the vertices
    /// each face covers, with the face's normal and point (the default).
    #[default]
    Signorini,
    /// The paper's projection: every vertex of a paired triangle gets the
    /// displacement onto the face plane.
    Paper,
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
    /// in front up to the band ([`Self::band_m`], Signorini rule) and, from
    /// nodes whose history flag is on, up to the node's reach (the culling
    /// reads their front). The culling only asks whether a flagged node's
    /// nearest front hit is one of the instrument's candidate pair
    /// triangles, so a flagged line with nothing in front within reach is
    /// cast again, beyond it, only when it meets the box of those
    /// triangles. The output is the same as with whole lines (`false`, the
    /// paper's pass), which is kept for comparison.
    pub bounded_rays: bool,
    /// The contact rule.
    pub rule: ContactRule,
    /// Signorini rule: how far in front of a face (or beside its outline) a
    /// vertex is a candidate, m. Motion of the plate within one deformation
    /// interval should stay below it (the force loop answers from the
    /// candidates of the last step's surface).
    pub band_m: f64,
    /// Signorini rule: how far in front of a face or beside its outline a
    /// vertex is reported [`Nearby`] (its compliance is wanted soon), m.
    pub ahead_m: f64,
    /// Signorini rule: how far outside a face's outline a vertex may lie and
    /// still be covered by the face, m.
    pub cover_tolerance_m: f64,
    /// Signorini rule: a vertex is a face's candidate only where its normal
    /// opposes the face's (the tissue faces the face), seeds included. On
    /// the rest shape (a linearized contact) tissue the plate has entered
    /// lies inside the plate's slab, in reach of both large faces; the one
    /// it faces is the one that pushes it. Off, a pair's triangle gives its
    /// vertices to the face whatever their normals (the search on a pushed
    /// shape, where the tissue lies on the face).
    pub facing_only: bool,
}

/// Default contact skin, m (0.1 um: far above rounding, far below any
/// modelled length).
pub const DEFAULT_SKIN_M: f64 = 1e-7;
/// Default [`DetectOptions::band_m`], m.
pub const DEFAULT_BAND_M: f64 = 1e-3;
/// Default [`DetectOptions::ahead_m`], m.
pub const DEFAULT_AHEAD_M: f64 = 4e-3;
/// Default [`DetectOptions::cover_tolerance_m`], m (1 um: far above
/// rounding, far below any modelled length; a vertex exactly on an edge of
/// the face is covered).
pub const DEFAULT_COVER_TOLERANCE_M: f64 = 1e-6;

impl Default for DetectOptions {
    fn default() -> Self {
        Self {
            culling: true,
            skin_m: DEFAULT_SKIN_M,
            bounded_rays: true,
            rule: ContactRule::Signorini,
            band_m: DEFAULT_BAND_M,
            ahead_m: DEFAULT_AHEAD_M,
            cover_tolerance_m: DEFAULT_COVER_TOLERANCE_M,
            facing_only: false,
        }
    }
}

impl DetectOptions {
    /// The paper's pipeline: projection rule (with the given culling and
    /// bounded rays).
    pub fn paper() -> Self {
        Self {
            rule: ContactRule::Paper,
            ..Self::default()
        }
    }

    /// The skin, made safe (finite, non-negative).
    pub(crate) fn skin(&self) -> f64 {
        if self.skin_m.is_finite() {
            self.skin_m.max(0.0)
        } else {
            0.0
        }
    }

    /// How far in front pairs form, m (0 for the paper's rule).
    pub(crate) fn front_band(&self) -> f64 {
        match self.rule {
            ContactRule::Signorini if self.band_m.is_finite() => self.band_m.max(0.0),
            _ => 0.0,
        }
    }

    /// How far in front every node looks, m: the band and the nearby
    /// vertices' distance (0 for the paper's rule).
    pub(crate) fn front_look(&self) -> f64 {
        match self.rule {
            ContactRule::Signorini if self.ahead_m.is_finite() => {
                self.ahead_m.max(self.front_band())
            }
            _ => self.front_band(),
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

/// A collision pair: source node and its nearest triangle behind (or, with
/// the Signorini rule, in front within the band).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pair {
    /// Index of the instrument in the query.
    pub instrument: u16,
    /// Source node index within its instrument.
    pub node: u32,
    /// Surface triangle index.
    pub triangle: u32,
    /// Signed line parameter of the hit, m (`<= 0`: behind the face; `> 0`:
    /// in front, within the band).
    pub t: f64,
    /// Barycentric coordinates of the hit on the triangle's second and third
    /// vertices (the first has `1 - u - v`).
    pub u: f64,
    /// See `u`.
    pub v: f64,
}

/// An enforced displacement of one surface vertex (a Dirichlet condition),
/// the paper's rule.
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

/// A surface vertex a face may push (the Signorini rule): the face covers
/// it and it lies within the band in front of the face, or behind it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    /// Surface vertex index.
    pub surface_vertex: u32,
    /// Volume node index.
    pub volume_node: u32,
    /// Instrument of the face.
    pub instrument: u16,
    /// The face.
    pub face: FaceId,
    /// Unit outward normal of the face at the vertex's projection, scene
    /// frame: the direction the face pushes the tissue.
    pub normal: Vector3<f64>,
    /// The face point the vertex projects to, scene frame, m.
    pub point: Point3<f64>,
    /// `normal . (x - point)` at the query's positions, m (negative: behind
    /// the face).
    pub gap_now_m: f64,
}

/// A point of a triangle pierced by a face where the faces do not cover
/// every vertex of the triangle (the contact's boundary, or a plate's edge
/// in a triangle larger than the contact; the Signorini rule): the face
/// pushes the tissue point under one corner of the polygon the face's
/// outline cuts out of the triangle ([`super::gap`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeCandidate {
    /// Instrument of the face.
    pub instrument: u16,
    /// The face.
    pub face: FaceId,
    /// Which corner of the polygon: `16 + 4 e + c` where triangle edge `e`
    /// crosses outline side `c`, `4 + k` for corner `k` of the outline,
    /// `32 + i` for a source node `i` (a curved plate's faces and the rim
    /// faces, whose point is where the node's line meets the triangle).
    pub feature: u32,
    /// Surface triangle index.
    pub triangle: u32,
    /// Volume nodes of the triangle's vertices.
    pub nodes: [u32; 3],
    /// Barycentric weights of the tissue point on them (summing to 1).
    pub weights: [f64; 3],
    /// Unit outward normal of the face (the node's), scene frame.
    pub normal: Vector3<f64>,
    /// The source node's point on the face, scene frame, m.
    pub point: Point3<f64>,
    /// `normal . (tissue point - point)` at the query's positions, m.
    pub gap_now_m: f64,
}

/// A surface vertex near a face but not a candidate of it: within
/// [`DetectOptions::ahead_m`] in front of the face or beside its outline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Nearby {
    /// Volume node index.
    pub volume_node: u32,
    /// Its distance to the face's box (the larger of the gap in front and
    /// the distance outside the outline), m.
    pub distance_m: f64,
}

/// What a query returns (buffers reused across calls).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ContactOutput {
    /// Surviving pairs, in (instrument, node) order.
    pub pairs: Vec<Pair>,
    /// Pairs cancelled by culling.
    pub cancelled: Vec<Pair>,
    /// The paper's rule: one enforced displacement per contacted surface vertex.
    pub enforced: Vec<Enforced>,
    /// The Signorini rule: the candidates, in (instrument, face) order, at
    /// most one per vertex along a direction (of two claims with normals
    /// within 5 degrees, parallel or opposed, the deeper stays).
    pub candidates: Vec<Candidate>,
    /// The Signorini rule: pierced triangles not every vertex of which a
    /// face of the instrument covers, one per (instrument, face, triangle):
    /// the deepest node's.
    pub edges: Vec<EdgeCandidate>,
    /// The Signorini rule: vertices near the faces (may repeat).
    pub nearby: Vec<Nearby>,
}

impl ContactOutput {
    pub(crate) fn clear(&mut self) {
        self.pairs.clear();
        self.cancelled.clear();
        self.enforced.clear();
        self.candidates.clear();
        self.edges.clear();
        self.nearby.clear();
    }

    /// Surviving pairs of instrument `k`.
    pub fn pairs_of(&self, k: u16) -> impl Iterator<Item = &Pair> {
        self.pairs.iter().filter(move |p| p.instrument == k)
    }

    /// Surface vertices the query's rule would push: the enforced ones
    /// (paper) or the candidates (Signorini), counted once. `buf` is
    /// scratch, reused so that a force sample allocates nothing.
    pub fn contact_vertices(&self, buf: &mut Vec<u32>) -> usize {
        if self.enforced.is_empty() {
            buf.clear();
            buf.extend(
                self.candidates
                    .iter()
                    .map(|c| c.volume_node)
                    .chain(self.edges.iter().flat_map(|e| e.nodes)),
            );
            buf.sort_unstable();
            buf.dedup();
            buf.len()
        } else {
            self.enforced.len()
        }
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
    pub(crate) offsets: Vec<usize>,
    pub(crate) ranges: Vec<RayRange>,
    /// Second pass of flagged rays: ray index, then its origin, direction
    /// and answer.
    pub(crate) recast: Vec<usize>,
    pub(crate) recast_origins: Vec<Point3<f64>>,
    pub(crate) recast_dirs: Vec<Vector3<f64>>,
    pub(crate) recast_ranges: Vec<RayRange>,
    pub(crate) recast_hits: Vec<NodeHits>,
    pub(crate) candidates: Vec<Pair>,
    pub(crate) mark: Vec<u32>,
    pub(crate) stamp: u32,
    pub(crate) slot: Vec<u32>,
    /// Surface topology for the gap stage (built on first use for a
    /// triangle list, identified by its address and length).
    pub(crate) topology: Option<Topology>,
    pub(crate) visit: Vec<u32>,
    pub(crate) visit_stamp: u32,
    pub(crate) queue: Vec<u32>,
    pub(crate) order: Vec<usize>,
    pub(crate) keep: Vec<bool>,
    pub(crate) covered: Vec<u32>,
    pub(crate) covered_stamp: u32,
    /// Per surface vertex covered at `covered_stamp`: the large face (A or
    /// B, as [`FaceId::index`]) whose candidate it is, or `u8::MAX`.
    ///
    /// [`FaceId::index`]: super::faces::FaceId::index
    pub(crate) claimed: Vec<u8>,
    /// Per surface triangle, the `covered_stamp` at which faces A and B
    /// clipped it.
    pub(crate) clipped: Vec<[u32; 2]>,
}

/// Vertex neighbours and vertex triangles of a surface.
#[derive(Debug, Clone, Default)]
pub(crate) struct Topology {
    pub key: (usize, usize),
    pub neighbours: Csr,
    pub triangles: Csr,
}

impl Workspace {
    /// An empty workspace; buffers grow on first use.
    pub fn new() -> Self {
        Self::default()
    }

    pub(crate) fn next_stamp(&mut self, triangles: usize) {
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

pub(crate) const NONE: u32 = u32::MAX;

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

/// All instruments in one cast (the deformation loop): the stages of the
/// module documentation, in order. On error, `out` is left empty and no
/// history is changed.
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
    check(query, tools)?;
    super::cast::cast(backend, tools, opts, ws);
    super::pair::pair(query, tools, opts, ws)?;
    super::cast::recast_for_culling(backend, query, tools, opts, ws);
    super::cull::cull(query, tools, opts, ws, out);
    for (k, tool) in tools.iter_mut().enumerate() {
        tool.history.renew(stage, out.pairs_of(k as u16));
    }
    match opts.rule {
        ContactRule::Paper => super::enforce::project(query, opts, ws, out),
        ContactRule::Signorini => super::gap::candidates(query, tools, opts, ws, out),
    }
    Ok(())
}

/// Consistent lengths, finite poses, a countable number of instruments.
fn check(query: &ContactQuery<'_>, tools: &[Tool<'_>]) -> Result<(), ContactError> {
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
    Ok(())
}

/// `x` plus a relative margin far above the rounding of the tests it bounds
/// (a bound that is slightly loose only costs time; a tight one could drop an
/// answer the whole-line cast gives).
#[inline]
pub(crate) fn widen(x: f64) -> f64 {
    x * (1.0 + 1e-9) + 1e-12
}
