#![no_main]
//! `.pts` landmark files: any text must parse or be an error, never panic.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = splineface::landmarks::parse_pts(text);
        let _ = splineface::landmarks::parse_vertex_indices(text, 68, 1000);
    }
});
