//! The tonic adapter of `fissure.v1`: moves messages, holds no logic.
