//! Client logic of the `fissure` command. The binary (`main.rs`) only parses
//! arguments.
//!
//! Two layers. The client (always built) talks to a server and reads files,
//! with the contract crate alone: trajectories, replay, the UDP bridge, the
//! watcher, session reports and rendering. The lab (feature `lab`, on by
//! default) runs the engine in process: the demo, mesh tools, the study,
//! benchmarks and the progress display of long engine work. Lab modules use
//! client modules, never the other way.

pub mod bridge;
pub mod render;
pub mod replay;
pub mod report;
pub mod trajectory;
pub mod watch;

#[cfg(feature = "lab")]
pub mod bench_bridge;
#[cfg(feature = "lab")]
pub mod bench_collision;
#[cfg(feature = "lab")]
pub mod bench_fem;
#[cfg(feature = "lab")]
pub mod bench_haptic;
#[cfg(feature = "lab")]
pub mod bench_loop;
#[cfg(feature = "lab")]
pub mod bench_rays;
#[cfg(feature = "lab")]
pub mod demo;
#[cfg(feature = "lab")]
pub mod mesh_cmd;
#[cfg(feature = "lab")]
pub mod progress;
#[cfg(feature = "lab")]
pub mod scene_cmd;
#[cfg(feature = "lab")]
pub mod study;
