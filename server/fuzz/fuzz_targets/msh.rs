//! Fuzzes the MSH volume reader: any bytes give a mesh or a typed error,
//! never a panic; a parsed mesh then goes through `finish_volume`
//! (orientation fix, unused nodes, `TetMesh::new` checks).
#![no_main]

use fissure_engine::mesh::io::{VolumeFormat, finish_volume, parse_volume};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(raw) = parse_volume(data, VolumeFormat::Msh) {
        let _ = finish_volume(raw);
    }
});
