//! The lab layer (feature `lab`): the commands that run the engine in
//! process.
//!
//! * [`demo`]: the in-process demo with both spatulas.
//! * [`mesh`]: `fissure mesh` (meshing, inspection, conversion).
//! * [`scene`]: `fissure scene` (scenes from images).
//! * [`study`]: the speed-accuracy study (plan, run, merge, report).
//! * [`bench`]: the benchmarks (`fissure bench ...`).
//! * [`progress`]: the progress display of long engine work.

pub mod bench;
pub mod demo;
pub mod mesh;
pub mod progress;
pub mod scene;
pub mod study;
