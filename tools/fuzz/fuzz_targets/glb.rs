#![no_main]
//! glTF meshes, binary and text, from memory (buffers in other files are refused without a
//! folder, so the fuzzer never touches the disk).
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = splineface::mesh::parse_gltf(data, None);
});
