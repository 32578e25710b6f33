//! Client logic of the `fissure` command: trajectories, replay, the UDP bridge,
//! the watcher, the demo, mesh tools, rendering and benchmarks. The binary
//! (`main.rs`) only parses arguments.

pub mod bench_collision;
pub mod bench_fem;
pub mod bench_haptic;
pub mod bench_loop;
pub mod bridge;
pub mod demo;
pub mod mesh_cmd;
pub mod progress;
pub mod render;
pub mod replay;
pub mod report;
pub mod study;
pub mod trajectory;
pub mod watch;
