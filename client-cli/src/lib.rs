//! Client logic of the `fissure` command. The binary (`main.rs`) only parses
//! arguments.
//!
//! Two layers, one module each:
//!
//! * [`client`] (always built) talks to a server and reads files, with the
//!   contract crate and `fissure-shared` alone: trajectories, replay, the
//!   UDP and OpenIGTLink bridge, the watcher, session reports and
//!   rendering.
//! * `lab` (feature `lab`, on by default) runs the engine in process: the
//!   demo, mesh and scene tools, the study, the benchmarks and the progress
//!   display of long engine work.
//!
//! Lab modules use client modules, never the other way.

pub mod client;
#[cfg(feature = "lab")]
pub mod lab;
