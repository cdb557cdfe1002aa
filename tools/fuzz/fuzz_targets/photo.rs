#![no_main]
//! Photo decoding up to where the project takes over: the image crate decodes (its own
//! limits), then GreyImage validates.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut reader = image::ImageReader::new(std::io::Cursor::new(data));
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(64 * 1024 * 1024);
    reader.limits(limits);
    if let Ok(reader) = reader.with_guessed_format()
        && let Ok(decoded) = reader.decode()
    {
        if let Ok(grey) = splineface::align::GreyImage::from_dynamic(&decoded) {
            let _ = grey.mirrored().gradients();
        }
        if decoded.width() <= 256 && decoded.height() <= 256 {
            let _ = splineface::detect::detect_faces(&decoded.to_luma8());
        }
    }
});
