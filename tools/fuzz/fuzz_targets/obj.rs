#![no_main]
//! OBJ meshes.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = splineface::mesh::parse_obj(text);
    }
});
