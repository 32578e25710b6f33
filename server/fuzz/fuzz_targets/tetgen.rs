//! Fuzzes the TetGen reader. The input is the `.node` file, a NUL byte, then
//! the `.ele` file (TetGen files are text and never hold a NUL); without a NUL
//! the whole input is the `.node` file and the `.ele` file is empty.
#![no_main]

use fissure_engine::mesh::io::{finish_volume, tetgen};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let (node, ele) = match data.iter().position(|&b| b == 0) {
        Some(i) => (&data[..i], &data[i + 1..]),
        None => (data, &[][..]),
    };
    if let Ok(raw) = tetgen::parse(node, ele) {
        let _ = finish_volume(raw);
    }
});
