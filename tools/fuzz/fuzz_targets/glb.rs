#![no_main]
//! glTF meshes, binary and text, from memory (buffers in other files are refused without a
//! folder, so the fuzzer never touches the disk).
//!
//! `parse_gltf` turns a panic inside the `gltf` crate into an error (a known one: gltf-json
//! mesh.rs:151). libfuzzer-sys's panic hook would abort on that caught panic, so this target
//! installs a silent hook; a panic that escapes `parse_gltf` still aborts (libfuzzer-sys
//! aborts when the target unwinds).
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| std::panic::set_hook(Box::new(|_| {})));
    let _ = splineface::mesh::parse_gltf(data, None);
});
