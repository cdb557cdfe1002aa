#![no_main]
//! dlib shape_predictor models, then a prediction with what parses.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(model) = splineface::landmarker::ShapePredictor::parse(data) {
        let image = image::RgbImage::from_pixel(48, 48, image::Rgb([90, 120, 150]));
        let intensity = splineface::landmarker::Intensity::from_rgb(&image);
        let _ = model.predict(&intensity, splineface::landmarker::FaceBox::from_size(4, 4, 40, 40));
    }
});
