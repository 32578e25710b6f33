//! The engine's integration tests (collision, FEM, contact mechanics, mesh
//! generation and files), one module a former test file, in one test binary
//! so that the engine and its dependencies are linked once for all of them.
//!
//! `fem_alloc` stays a binary of its own (`tests/fem_alloc.rs`): it installs
//! a counting global allocator, and no other test may allocate while it
//! counts.
//!
//! Run one file's tests with a filter: `cargo test -p fissure-engine --test
//! engine fem_contact::`.

mod common;

mod collide_bounded;
mod collide_bundle;
mod collide_bvh;
mod collide_contact;
#[cfg(feature = "gpu")]
mod collide_gpu;
mod collide_paper;
mod collide_phantom;
#[cfg(feature = "gpu")]
mod collide_scene;
mod collide_sweep;
mod contact_mechanics;
mod fem_contact;
mod fem_convergence;
mod fem_extremes;
mod fem_nodal_pressure;
mod fem_solvers;
mod fem_tangent;
mod fem_ties;
mod fem_tissues;
mod fem_validation;
mod mesh_generation;
mod mesh_io;
mod sim_injury;
mod sim_ties;
