#![no_main]
//! Photo decoding up to where the project takes over and beyond: `align::decode_photo_bytes`
//! (the image crate with the project's limits), then `GreyImage`'s checks, mirroring and
//! gradients, and face detection on small images. `decode_photo_bytes` catches a decoder's
//! panic (the photo is then refused); libfuzzer-sys's panic hook still aborts on it, so such a
//! panic is reported here rather than hidden.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(decoded) = splineface::align::decode_photo_bytes(data) {
        if let Ok(grey) = splineface::align::GreyImage::from_dynamic(&decoded) {
            let _ = grey.mirrored().gradients();
        }
        if decoded.width() <= 256 && decoded.height() <= 256 {
            let _ = splineface::detect::detect_faces(&decoded.to_luma8());
        }
    }
});
