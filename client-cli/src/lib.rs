//! Client logic of the `fissure` command: trajectories, replay, the demo, mesh
//! tools, rendering and benchmarks. The binary (`main.rs`) only parses arguments.

pub mod bench_collision;
pub mod bench_fem;
pub mod demo;
pub mod mesh_cmd;
pub mod render;
pub mod replay;
pub mod report;
pub mod study;
pub mod trajectory;
