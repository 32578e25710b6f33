//! The command-line client's integration tests, one module a former test
//! file, in one test binary so that the client, the engine and their
//! dependencies are linked once for all of them. All but `igtl_corpus` run
//! the engine in process and need the `lab` feature (a default one).
//!
//! Run one file's tests with a filter: `cargo test -p fissure-cli --test cli
//! igtl_peers::`.

#[cfg(feature = "lab")]
mod assessment;
#[cfg(feature = "lab")]
mod bench_bridge;
#[cfg(feature = "lab")]
mod bench_haptic;
#[cfg(feature = "lab")]
mod bridge_ties;
mod igtl_corpus;
#[cfg(feature = "lab")]
mod igtl_peers;
#[cfg(feature = "lab")]
mod render_examples;
#[cfg(feature = "lab")]
mod scene_from_image;
#[cfg(feature = "lab")]
mod study_quick;
#[cfg(feature = "lab")]
mod study_slurm;
