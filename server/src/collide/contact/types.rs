//! What a contact query reads and returns, as plain data: the surface it
//! runs against ([`ContactQuery`]), its options ([`DetectOptions`], the
//! [`ContactRule`]), its errors, and its results ([`ContactOutput`]: the
//! pairs, the paper's enforced displacements, the Signorini rule's
//! candidates and nearby vertices). Every stage of the pipeline imports
//! these; they import no stage.

use crate::collide::rays::SurfaceError;
use crate::collide::tool::faces::FaceId;
use nalgebra::{Point3, Vector3};

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
/// outline cuts out of the triangle ([`super::gap`], the Signorini rule's stage).
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

/// No index (an empty slot of an index buffer).
pub(crate) const NONE: u32 = u32::MAX;

/// `x` plus a relative margin far above the rounding of the tests it bounds
/// (a bound that is slightly loose only costs time; a tight one could drop an
/// answer the whole-line cast gives).
#[inline]
pub(crate) fn widen(x: f64) -> f64 {
    x * (1.0 + 1e-9) + 1e-12
}
