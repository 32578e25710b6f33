//! The fissure gRPC contract, `fissure.v1`.
//!
//! The `.proto` source in `proto/fissure/v1/` is the reference: every message and
//! field is documented there with its units. This crate re-exports the types that
//! prost and tonic generate from it, plus the encoded file descriptor set used to
//! serve gRPC reflection, and the reader of session recordings ([`recording`]).
//!
//! What the engine and its clients both compute on the contract's data (the
//! rigid part of a frame's motion, surface checks, the VTU writer, the
//! assessment's levels) is `fissure-shared`'s: this crate is the contract
//! alone.

pub mod recording;

/// Generated types of package `fissure.v1`.
#[allow(missing_docs, clippy::all, clippy::pedantic, rust_2018_idioms)]
pub mod v1 {
    tonic::include_proto!("fissure.v1");
}

impl v1::PoseSample {
    /// A pose at client time `t_s` (s) with its `sequence`: the handle
    /// point's position (m) and the orientation quaternion `[w, x, y, z]`.
    pub fn new(t_s: f64, sequence: u64, position_m: [f64; 3], orientation: [f64; 4]) -> Self {
        let [x, y, z] = position_m;
        let [w, qx, qy, qz] = orientation;
        Self {
            t_s,
            sequence,
            position_m: Some(v1::Vec3 { x, y, z }),
            orientation: Some(v1::Quaternion {
                w,
                x: qx,
                y: qy,
                z: qz,
            }),
        }
    }
}

/// Encoded `FileDescriptorSet` of `fissure.v1`, for `tonic-reflection`.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/fissure_descriptor.bin"));

/// gRPC metadata key carrying the instrument a haptic stream claims.
pub const INSTRUMENT_METADATA_KEY: &str = "fissure-instrument";

/// gRPC metadata key carrying the bearer token (`authorization: Bearer <token>`).
pub const AUTHORIZATION_METADATA_KEY: &str = "authorization";
