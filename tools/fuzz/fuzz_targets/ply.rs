#![no_main]
//! PLY meshes, ASCII and binary.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = splineface::mesh::parse_ply(data);
});
