//! Fuzzes the OBJ surface reader: any bytes give a surface whose triangles
//! index its vertices, or a typed error; never a panic.
#![no_main]

use fissure_engine::mesh::io::{SurfaceFormat, parse_surface};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(surface) = parse_surface(data, SurfaceFormat::Obj) {
        let n = surface.vertices.len();
        for t in &surface.triangles {
            assert!(
                t.iter().all(|&i| (i as usize) < n),
                "triangle {t:?} indexes past {n} vertices"
            );
        }
    }
});
