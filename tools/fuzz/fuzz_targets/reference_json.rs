#![no_main]
//! Reference face files.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = splineface::reference::ReferenceFace::from_json(text);
    }
});
