#![no_main]
//! Landmark vertex-index files (`fit-reference --landmarks`): 68 indices, one a line, with `#`
//! comments, checked against a mesh's vertex count taken from the input's first byte.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    if let Ok(text) = std::str::from_utf8(rest) {
        let vertices = usize::from(first) * 1000;
        let _ = splineface::landmarks::parse_vertex_indices(text, 68, vertices);
    }
});
