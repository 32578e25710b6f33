//! What a simulation reports as it runs, for whoever records it.
//!
//! The engine knows nothing of files or of the wire format: it tells a
//! [`Journal`] what happens — every published frame (the rest frame first),
//! every accepted pose with the force sample that answered it — and the
//! journal (the service's session recorder, `service::recording`) encodes and
//! stores it. A journal is opened by an [`OpenJournal`] once the model is
//! built, with the scene as run (the effective stepped mode), so that it can
//! describe the session before its first entry.
//!
//! Calls come from the loops' threads (the force loops, the deformation
//! loop): a journal must never make them wait (on a disk, on a lock held
//! across I/O); when it cannot keep up it drops entries and counts them
//! ([`Journal::lost`]).

use super::ForceOut;
use super::engine::Model;
use super::pose::RawPose;
use super::snapshot::Frame;
use crate::scene::Scene;
use std::path::Path;
use std::sync::Arc;

/// Receives what a running simulation does.
pub trait Journal: Send + Sync {
    /// A frame was published (frame summaries, positions left to the
    /// journal to keep or not).
    fn frame(&self, frame: &Frame);
    /// A pose of `instrument` was accepted and answered with `answer`.
    fn sample(&self, instrument: &str, pose: &RawPose, answer: &ForceOut);
    /// Entries dropped so far (all kinds together).
    fn lost(&self) -> u64;
    /// Stores what was reported so far; false when that could not be done
    /// in time (a stalled disk) or the journal has failed.
    fn flush(&self) -> bool;
    /// Stores what was reported and closes the journal; later reports are
    /// ignored.
    fn finish(&self) -> std::io::Result<()>;
}

/// Opens a [`Journal`] for a simulation about to start.
pub trait OpenJournal: Send + Sync + std::fmt::Debug {
    /// Where the journal goes (named in errors).
    fn path(&self) -> &Path;
    /// Opens the journal for `scene` (as run) and its `model`.
    fn open(&self, scene: &Scene, model: &Model) -> std::io::Result<Arc<dyn Journal>>;
}
