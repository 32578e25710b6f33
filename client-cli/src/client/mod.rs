//! The client layer: what talks to a server and reads its files, without
//! the engine.
//!
//! * [`bridge`]: the UDP bridge with its lanes, and the OpenIGTLink bridge.
//! * [`replay`]: pose trajectories streamed to a server, with pacing.
//! * [`watch`]: frames from `Watch` into VTU series, pictures and GIFs,
//!   through the frame sinks it shares with the demo ([`watch::sink`]).
//! * [`report`]: a recording's summary, its assessment and the HTML page.
//! * [`render`]: headless software rendering (images, plots, GIFs).
//! * [`trajectory`]: the bundled pose trajectories and the CSV format.

pub mod bridge;
pub mod render;
pub mod replay;
pub mod report;
pub mod trajectory;
pub mod watch;
