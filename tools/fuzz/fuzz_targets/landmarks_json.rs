#![no_main]
//! Landmark JSON files, and the 2D/3D structures derived from them.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data)
        && let Ok(landmarks) = splineface::landmarks::parse_landmarks_json(text)
    {
        let _ = landmarks.structure_2d();
        let _ = landmarks.structure_3d();
    }
});
