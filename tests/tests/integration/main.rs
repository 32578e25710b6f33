//! Integration tests of fissure against in-process servers (and the server
//! binary), one module a former test file, in one test binary so that the
//! server, the client and their dependencies are linked once for all of
//! them. The tests run in parallel, beside each other, as any tests of one
//! binary do.
//!
//! Tests that measure the process (its memory, its threads, its log, latency
//! percentiles that other tests' load would distort) are in the `isolated`
//! binary instead (`tests/isolated/main.rs`), which runs them one at a time.
//!
//! Run one file's tests with a filter: `cargo test -p fissure-tests --test
//! integration service_contract::`.

#[path = "../raw_h2/mod.rs"]
mod raw_h2;
#[path = "../reliability_common/mod.rs"]
mod reliability_common;

mod client_bridge;
mod client_demo;
mod client_trajectories;
mod client_watch;
mod reliability_bridge;
mod reliability_faults;
mod reliability_security;
mod scene_model_files;
mod scenes;
mod server_claims;
mod server_recording;
mod server_security;
mod server_sessions;
mod service_contract;
mod walking_skeleton;
