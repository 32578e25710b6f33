//! The scene's `[assessment]`: the thresholds a session's injury measures
//! ([`crate::sim::core::injury`]) are scored against, with their cited defaults.
//! Defined in [`fissure_shared::assessment`], beside the messages that carry
//! them, so that clients score recordings with the same levels.

pub use fissure_shared::assessment::*;
