//! The benchmarks of `fissure bench`, each printing JSON and a table.
//!
//! * [`bridge`]: the UDP and OpenIGTLink bridges' added latency.
//! * [`collision`]: the collision query per ray backend and placement.
//! * [`fem`]: the FEM strategies' step and solve.
//! * [`haptic`]: the force samples against full solves (error, ripple).
//! * [`loops`]: the server's force loops under clients and watchers.
//! * [`rays`]: ray casts per backend.

pub mod bridge;
pub mod collision;
pub mod fem;
pub mod haptic;
pub mod loops;
pub mod rays;
