//! The core of a simulation: what a deformation step and a force sample
//! compute, over plain data. Nothing here starts a thread or reads a clock
//! to decide what to compute; the [`super::runtime`] drives it.
//!
//! * [`engine`]: the model, the collision query, the contact rules, the
//!   deformation and the step as named stages ([`engine::StepEngine::step`]);
//! * [`rows`]: the contact rows of the instruments, the skull and the ties;
//! * [`force_loop`]: one instrument's force sample and the row exchange that
//!   couples the instruments; [`local_model`]: its compliance patch;
//! * [`snapshot`]: what a step publishes; [`injury`]: what it did to the
//!   tissue; [`motion`]: its rigid and non-rigid parts;
//! * [`pose`]: validation of incoming poses;
//! * [`stepped`]: the stepped runner (the session on pose time).

pub mod engine;
pub mod force_loop;
pub mod injury;
pub mod local_model;
pub mod motion;
pub mod pose;
pub mod rows;
pub mod snapshot;
pub mod stepped;

pub use stepped::step_before;

/// Safety flags of a force sample (same bits as `fissure.v1.SafetyFlag`).
pub mod flags {
    /// Force above the scene's safe threshold.
    pub const FORCE_ABOVE_THRESHOLD: u32 = 1;
    /// Force clamped to the scene's maximum.
    pub const FORCE_CLAMPED: u32 = 2;
    /// Deformation model older than 10 deformation intervals.
    pub const MODEL_STALE: u32 = 4;
    /// The last deformation step failed.
    pub const SOLVER_FAILED: u32 = 8;
    /// The pose jumped farther than the scene allows in one sample.
    pub const POSE_JUMP: u32 = 16;
    /// A vertex the instrument touches has no compliance yet: its force is
    /// a penalty estimate until its columns are computed.
    pub const COLUMNS_PENDING: u32 = 32;
    /// The sample's contact problem was not solved: the last good force is
    /// repeated.
    pub const CONTACT_UNSOLVED: u32 = 64;
    /// The instrument tore a bridging vessel (sticky until a reset).
    pub const VESSEL_TORN: u32 = 128;
}
