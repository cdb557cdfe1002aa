#![no_main]
//! Binary glTF meshes, through the file reader (each input written to a scratch file).
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = std::env::temp_dir().join(format!("splineface-fuzz-{}.glb", std::process::id()));
    if std::fs::write(&path, data).is_ok() {
        let _ = splineface::mesh::read_mesh(&path);
    }
});
