//! Client logic of the `fissure` command: replay, demo, mesh tools, benchmarks.
pub mod render;
