#![no_main]
//! glTF meshes, binary and text, from memory (buffers in other files are refused without a
//! folder, so the fuzzer never touches the disk). `parse_gltf` catches a panic inside the
//! `gltf` crate (the file is then refused); libfuzzer-sys's panic hook still aborts on it, so
//! such a panic is reported here rather than hidden (the known one, gltf-json mesh.rs:151, is
//! now refused before it can happen).
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = splineface::mesh::parse_gltf(data, None);
});
