//! Scene files (TOML): what a scene models, and nothing more.
