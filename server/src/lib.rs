//! fissure-engine: the simulation engine for opening a brain fissure.
//!
//! The engine is network-free (it links no gRPC, protobuf or HTTP/2 crate:
//! its service is the `fissure-server` crate, which depends on it, never
//! the reverse) and data flows one way (DESIGN.md section 1):
//! pose -> instrument transform -> rays -> pairs -> culled pairs -> enforced
//! displacements -> FEM solve -> positions and reaction forces -> frames and
//! forces out.
//!
//! * [`mesh`]: the tetrahedral brain model, its boundary surface, generators and
//!   file formats.
//! * [`collide`]: the collision method of Fukuhara et al. (2014): source-node
//!   rays from the spatula faces, collision pairs, history culling, enforced
//!   displacements.
//! * [`fem`]: linear-elastic (and large-deformation) FEM with enforced
//!   displacements and reaction forces.
//! * [`scene`]: scene files (TOML) that say what is modelled.
//! * [`sim`]: the force loop and the deformation loop, shared state, recording.
//! * [`progress`]: progress events of long work (scene loading).
//!
//! Units are SI throughout: m, Pa, N, s.
//!
//! Feature `gpu` (on by default, and in the shipped binaries): the wgpu ray
//! backends, `collide::rays::gpu`. Without it the crate builds without wgpu, and a
//! scene asking for `collision.backend = "gpu"` is refused at load
//! ([`scene::SceneError::NotBuilt`]).

pub mod collide;
pub mod fem;
pub mod mesh;
pub mod progress;
pub mod scene;
pub mod sim;
#[cfg(test)]
mod test_rng;
