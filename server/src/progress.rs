//! Progress of long work (loading a scene: meshing or reading the model,
//! factorizing the solver), reported as `tracing` events of one target,
//! [`TARGET`].
//!
//! The server's log shows them (at `info`, with their times); front ends turn
//! them into a progress display: `fissure` shows the latest stage beside a
//! spinner and the time spent while a scene loads. An event whose field
//! `done` is true closes the display.

/// The `tracing` target of progress events.
pub const TARGET: &str = "fissure::progress";

/// Reports that a stage of long work starts, e.g. "factorizing the solver".
pub fn stage(what: impl std::fmt::Display) {
    tracing::info!(target: TARGET, done = false, "{what}");
}

/// Reports that the long work is over (`what` says what was done, e.g.
/// "scene loaded in 17.2 s").
pub fn done(what: impl std::fmt::Display) {
    tracing::info!(target: TARGET, done = true, "{what}");
}
