//! What the fissure engine and its clients both compute on the data of the
//! contract, so that a client reads, draws, writes and scores what the
//! server sends without linking the engine, and the engine uses the same
//! code without linking gRPC:
//!
//! * [`motion`]: the rigid part of a frame's motion (the best-fit rigid
//!   transform of the surface, and what is left of it).
//! * [`surface`]: the checks of a triangle surface (indices in range,
//!   finite coordinates).
//! * [`vtu`]: the VTU (VTK XML) writer of frame series.
//! * [`assessment`]: the levels a session's injury measures are scored
//!   against, with their sources.
//!
//! Units are SI: m, Pa, N, s.

pub mod assessment;
pub mod motion;
pub mod surface;
pub mod vtu;
