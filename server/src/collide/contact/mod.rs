//! The collision pipeline of one query: [`detect`] (one instrument, the
//! force loop) or [`detect_many`] (all instruments, the deformation loop)
//! runs its named stages in order over plain data:
//!
//! 1. [`cast`](cast): one ray per source node (`S + t N_R`, scene
//!    frame after the pose), cast once for all instruments; the nearest hit
//!    behind (`t <= 0`) and in front (`t > 0`), each only as far as a later
//!    stage can use it ([`DetectOptions::bounded_rays`]).
//! 2. [`pair`](pair) (A1, A2): the nearest triangle behind a node,
//!    within its reach, whose outward normal opposes the face normal; with
//!    the Signorini rule also the nearest triangle *in front* within
//!    [`DetectOptions::band_m`] (tissue about to be touched, or that the
//!    face is leaving).
//! 3. [`cull`](cull) (B1-B3), per instrument: flagged nodes mark
//!    their nearest triangle in front as infeasible, and the pairs holding
//!    one are cancelled.
//! 4. renew ([`History::renew`]): a node's flag is set exactly when it
//!    holds a surviving pair (when the history renews at this [`Stage`]).
//! 5. By the contact rule ([`ContactRule`]):
//!    * [`gap`](gap) (Signorini, the default): the surface vertices
//!      each face may push ([`Candidate`]: covered by the face, within the
//!      band), with the face's normal and point; the pierced triangles not
//!      all of whose vertices a face covers ([`EdgeCandidate`]); and the
//!      vertices near the faces whose compliance should be ready
//!      ([`Nearby`]);
//!    * [`enforce`](enforce) (the paper's rule): every vertex of a
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

pub(crate) mod cast;
pub(crate) mod cull;
pub(crate) mod enforce;
pub(crate) mod gap;
pub mod history;
pub(crate) mod pair;
pub mod types;
pub mod workspace;

pub use types::{
    Candidate, ContactError, ContactOutput, ContactQuery, ContactRule, DEFAULT_AHEAD_M,
    DEFAULT_BAND_M, DEFAULT_COVER_TOLERANCE_M, DEFAULT_SKIN_M, DetectOptions, EdgeCandidate,
    Enforced, Nearby, Pair, entry_depth_m,
};
pub use workspace::{Tool, Workspace};

use crate::collide::rays::RayBackend;
use crate::collide::tool::instrument::Instrument;
use history::{History, Stage};
use nalgebra::Isometry3;

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
    cast::cast(backend, tools, opts, ws);
    pair::pair(query, tools, opts, ws)?;
    cast::recast_for_culling(backend, query, tools, opts, ws);
    cull::cull(query, tools, opts, ws, out);
    for (k, tool) in tools.iter_mut().enumerate() {
        tool.history.renew(stage, out.pairs_of(k as u16));
    }
    match opts.rule {
        ContactRule::Paper => enforce::project(query, opts, ws, out),
        ContactRule::Signorini => gap::candidates(query, tools, opts, ws, out),
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
