//! Fuzzes the NIfTI-1/NIfTI-2 reader (plain or gzip): any bytes give an
//! image whose values match its dims and whose affine is finite, or a typed
//! error; never a panic, and never an allocation the bytes do not back.
#![no_main]

use fissure_engine::mesh::image::parse_nifti;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(image) = parse_nifti(data) {
        assert_eq!(
            image.values.len(),
            image.dims.iter().product::<usize>(),
            "values and dims disagree"
        );
        assert!(
            image.voxel_to_world_m.iter().all(|x| x.is_finite()),
            "non-finite affine accepted"
        );
    }
});
