//! Fuzzes the scene (TOML) parser and its validation: any text gives a scene
//! or a typed error naming the key, never a panic.
#![no_main]

use fissure_engine::scene::Scene;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = Scene::parse(text, "fuzz");
    }
});
