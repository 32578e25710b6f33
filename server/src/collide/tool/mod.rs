//! The instruments of a query: their plates and source nodes, their contact
//! faces, their placement in a fissure and the blade's swept segments.
//!
//! * [`instrument`]: spatula plates (flat, trapezoid, curved) and blades,
//!   source nodes, the instrument frame and the pose.
//! * [`faces`]: the plate's contact faces and the projection onto them.
//! * [`placement`]: spatula poses in a fissure of the phantom (landmarks).
//! * [`sweep`]: the segments a blade's edge sweeps between two samples.

pub mod faces;
pub mod instrument;
pub mod placement;
pub mod sweep;
