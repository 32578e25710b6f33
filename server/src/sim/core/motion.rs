//! The rigid and the non-rigid parts of a surface displacement
//! (DESIGN.md section 3c). The fit lives in [`fissure_shared::motion`], beside
//! the `fissure.v1.RigidPart` message it fills, so that a client drawing
//! frames takes away the same rigid motion without linking the engine.

pub use fissure_shared::motion::{NEAR_RADIUS_M, RigidFit, RigidPart};
