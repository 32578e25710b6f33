//! The collision pipeline of Fukuhara et al. (2014), DESIGN.md section 2.
//!
//! Stages, each a plain function or struct over plain data:
//! pose -> source-node rays (instrument frame to scene frame) -> per-node nearest
//! hit behind and in front ([`RayBackend`]) -> collision pairs (A1, A2) ->
//! history culling (B1-B3) -> history renewal -> the candidates of the
//! contact problem (the faces' normals and points over the vertices they
//! cover; DESIGN.md section 3b) or, by the paper's rule, enforced
//! displacements.
//!
//! Three groups, each importing only the ones before it:
//!
//! * [`rays`]: the ray stage: line-triangle tests with signed `t`
//!   ([`rays::ray`], watertight by default), the [`RayBackend`] trait and
//!   its backends: the paper's all-pairs reference ([`rays::brute`]), the
//!   refitted BVH ([`rays::bvh`]) and the wgpu backends (`rays::gpu`, the
//!   `gpu` feature, on by default).
//! * [`tool`]: the instruments: spatula plates (flat, trapezoid, curved)
//!   and blades, source nodes, the instrument frame and the pose
//!   ([`tool::instrument`]); the plate's contact faces and the projection
//!   onto them ([`tool::faces`]); spatula poses in a fissure of the
//!   phantom ([`tool::placement`]); the blade's swept segments
//!   ([`tool::sweep`]).
//! * [`contact`]: the pipeline of one query ([`contact::detect`]) over
//!   its plain data ([`contact::types`], [`contact::workspace`]); its
//!   stages are `cast`, `pair`, `cull`, the history's renewal
//!   ([`contact::history`]), and `gap` (Signorini) or `enforce` (paper).

pub mod contact;
pub mod rays;
pub mod tool;

pub use contact::history::{History, HistoryMode, Stage};
pub use contact::{
    Candidate, ContactError, ContactOutput, ContactQuery, ContactRule, DetectOptions, Enforced,
    Nearby, Pair, Tool, Workspace, detect, detect_many,
};
pub use rays::brute::BruteForce;
pub use rays::bvh::{Bvh, RefitStats};
pub use rays::ray::RayTest;
pub use rays::{Hit, NodeHits, RayBackend, RayRange, SurfaceError};
pub use tool::faces::{FaceId, FacePoint};
pub use tool::instrument::{
    Instrument, InstrumentError, NodeKind, NodeLayout, Plate, RimNodes, SourceNode,
};
pub use tool::placement::FissurePlacement;
